"""The recipe's first steps run as written on a fresh clone (issue 54): its dataset command
(`scripts/recipe_data.sh`) at a tiny scale, then a few training steps of its config,
stopped and resumed.

Properties: every part of the mix is generated with its own seed and linked into one
training folder; the parts differ as their configs say (the clean part's sensor has no
noise, the static parts' cameras do not move); training the recipe's config on that
folder runs from scratch (no warm start) with the network the config names, and a
second command resumes the same run."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import torch
import yaml

from datagen.shard import ShardReader
from model import checkpoint
from model.cli import main as train_main

ROOT = Path(__file__).resolve().parents[1]
PARTS = ("plane", "clean", "dynamic", "static", "static_small")
TINY = ["--set", "simulation.frames.count=3", "--set", "simulation.duration_s=0.4",
        "--no-progress"]


def test_recipe_data_then_train_and_resume(tmp_path):
    out = tmp_path / "recipe"
    env = {**os.environ, "TEXTURES": "builtin", "WORKERS": "1", "SEED": "3"}
    run = subprocess.run(["bash", str(ROOT / "scripts/recipe_data.sh"), str(out), "5", *TINY],
                         env=env, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    links = sorted((out / "mix").glob("shard_*.h5"))
    assert [p.name.split("_0")[0] for p in links] == sorted(f"shard_{p}" for p in PARTS)
    assert all(p.is_symlink() for p in links)
    seeds, static, sensors = {}, {}, {}
    for part in PARTS:
        [shard] = sorted((out / part).glob("shard_*.h5"))
        reader = ShardReader(shard)
        try:
            [name] = reader.sequences()
            seeds[part] = reader.seed
            static[part] = reader.static_camera(name)
            sensors[part] = reader.sensor(name)
        finally:
            reader.close()
    assert len(set(seeds.values())) == len(PARTS)  # each part its own seed
    assert static["static"] and static["static_small"]
    assert not static["plane"] and not static["clean"]
    assert sensors["clean"] is None  # the ideal sensor: nothing drawn
    assert all(sensors[p] is not None for p in PARTS if p != "clean")  # randomised

    config = str(ROOT / "configs/train_x2_recipe.yaml")
    small = ["--set", "run.max_steps=2", "--set", "optim.batch_size=2",
             "--set", "run.val_batches=1", "--set", "run.checkpoint_every=1", "--no-progress"]
    assert train_main(["--data", str(out / "mix"), "--config", config,
                       "--out", str(tmp_path / "run"), *small]) == 0
    first = torch.load(tmp_path / "run" / "last.pt", weights_only=True)
    stored = checkpoint.config_of(first)
    recipe = yaml.safe_load(Path(config).read_text())
    assert first["step"] == 2
    assert stored.run.init_from is None  # from scratch
    assert stored.model.base_channels == recipe["model"]["base_channels"]
    assert stored.model.context == recipe["model"]["context"]
    resumed = [*small[:-1], "--set", "run.max_steps=3", "--no-progress"]
    assert train_main(["--data", str(out / "mix"), "--config", config,
                       "--out", str(tmp_path / "run"), "--resume", *resumed[2:]]) == 0
    assert torch.load(tmp_path / "run" / "last.pt", weights_only=True)["step"] == 3
