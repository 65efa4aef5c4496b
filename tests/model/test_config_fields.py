"""Every training setting is one a kept config uses: the shipped models' chain, the paper's
recipes and the documented ones (configs/). An experiment's switch leaves with its
experiment; checkpoints that stored it still load where it did nothing."""

from __future__ import annotations

import dataclasses
import re
import typing
from pathlib import Path

import pytest
import torch
import yaml

from esim_lite.core.dataconf import to_yaml
from model import checkpoint
from model.config import RETIRED, RETIRED_AT, TrainConfig

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted([*(ROOT / "configs").glob("train_*.yaml"),
                  ROOT / "configs" / "flow_pretrain.yaml"])

NOT_SWITCHES = {
    # how a run runs, not what it learns (train --set, docs/configuration.md)
    "run.seed", "run.max_steps", "run.amp", "run.cpu_amp", "run.channels_last",
    "run.threads",
    # Adam's standard knobs, at the paper's values
    "optim.betas", "optim.weight_decay", "optim.grad_clip",
    # the paper's augmentation, on by default
    "data.flips",
    # equals data.stacks.channels (TrainConfig checks it); stored for the network alone
    "model.stack_channels",
    # the paper's other stacking (SBT, section 3.1), an option of reconstruct and train
    "data.stacks.method", "data.stacks.channel_ms",
}
"""Settings no kept config needs to set, each for the reason given."""


def settings(cls: type, prefix: str = "") -> list[str]:
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(hints[f.name]):
            out += settings(hints[f.name], f"{prefix}{f.name}.")
        else:
            out.append(prefix + f.name)
    return out


def keys(data: dict, prefix: str = "") -> set[str]:
    out = set()
    for k, v in (data or {}).items():
        out.add(prefix + k)
        if isinstance(v, dict):
            out |= keys(v, f"{prefix}{k}.")
    return out


def test_every_setting_is_used_by_a_kept_config():
    used = set().union(*(keys(yaml.safe_load(p.read_text())) for p in CONFIGS))
    unused = [s for s in settings(TrainConfig) if s not in used and s not in NOT_SWITCHES]
    assert not unused, f"settings no kept config uses (an experiment's switch?): {unused}"
    stale = sorted(NOT_SWITCHES - set(settings(TrainConfig)))
    assert not stale, f"NOT_SWITCHES names settings that no longer exist: {stale}"


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_warm_starts_name_a_run_of_the_chain_never_the_package_weights(path):
    """A config replays as written: ``init_from`` names the run before it (whose folder
    the chain's previous command writes), not model/weights/, which a later export
    replaces."""
    run = (yaml.safe_load(path.read_text()) or {}).get("run") or {}
    for key in ("init_from", "first_pass", "flow_init"):
        if run.get(key):
            assert re.fullmatch(r"runs/[\w.-]+/(last|flow_last)\.pt", run[key]), (key, run[key])
            name = run[key].split("/")[1]
            makes = [p for p in CONFIGS if f"--out runs/{name}" in p.read_text()]
            assert makes, f"{path.name}: no kept config says how to make runs/{name}"


def old_checkpoint(tiny_checkpoint: Path, path: Path, **retired) -> Path:
    """The tiny checkpoint as a writer from before the experiments' removal stored it."""
    ckpt = checkpoint.load(tiny_checkpoint)
    config = yaml.safe_load(ckpt["config"])
    net = dict(ckpt["net"])
    for dotted, value in retired.items():
        section, key = dotted.split("__")
        config[section][key] = value
        if section == "model":
            net[key] = value
    ckpt["config"], ckpt["net"] = yaml.safe_dump(config), net
    torch.save(ckpt, path)
    return path


def test_a_checkpoint_storing_retired_settings_at_their_neutral_values_loads_the_same(
        tiny_checkpoint, tmp_path):
    neutral = {k.replace(".", "__"): v for k, v in RETIRED.items() if k != "loss.fill_dilate"}
    old = old_checkpoint(tiny_checkpoint, tmp_path / "old.pt", loss__fill_dilate=3, **neutral)
    assert "model.memory" not in to_yaml(checkpoint.config_of(checkpoint.load(old)))
    x = (torch.rand(1, 3, 3, 16, 20) * 2 - 1, None, torch.randn(1, 3, 2, 16, 20))
    x = (x[0], x[0][:, 1], x[2])
    with torch.no_grad():
        assert torch.equal(checkpoint.load_model(old)(*x),
                           checkpoint.load_model(tiny_checkpoint)(*x))


@pytest.mark.parametrize("setting, value", [("model__history", [4.0, 32.0]),
                                            ("model__memory", True),
                                            ("loss__fill_unseen", True),
                                            ("model__context_far", "dilated")])
def test_a_checkpoint_that_used_a_removed_experiment_is_refused_by_name(
        setting, value, tiny_checkpoint, tmp_path):
    old = old_checkpoint(tiny_checkpoint, tmp_path / "old.pt", **{setting: value})
    with pytest.raises(ValueError, match=rf"old.pt: {setting.replace('__', '.')} = .*"
                                         rf"commit {RETIRED_AT}"):
        state = checkpoint.load(old)
        checkpoint.config_of(state, str(old))
        checkpoint.model_from(state, "cpu", str(old))
