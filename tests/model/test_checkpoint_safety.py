"""A checkpoint is data, not code: a pickle that would run a command when unpickled is refused
by every command that reads a checkpoint, before anything of it runs; a file the user trusts
is converted once, by an explicit opt-in."""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from model import checkpoint
from model.cli import convert_main, evaluate_main, export_main, main, reconstruct_main
from model.inference.pretrained import WEIGHTS

ROOT = Path(__file__).resolve().parents[2]
TINY = str(ROOT / "configs" / "train_tiny.yaml")


class _RunsCommand:
    """Unpickling this runs ``touch marker``: what a hostile checkpoint does."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


def hostile_checkpoint(path: Path, marker: Path, like: dict | None = None) -> Path:
    """A checkpoint shaped like ``like`` (or a bare one) whose model entry runs a command."""
    payload = dict(like or {"config": "", "net": {}})
    payload["model"] = _RunsCommand(marker)
    torch.save(payload, path)
    return path


def test_the_hostile_pickle_really_runs_its_command_when_loaded_unsafely(tmp_path):
    # the fixture is a real attack: a plain torch.load without weights_only runs it
    marker = tmp_path / "ran"
    torch.load(hostile_checkpoint(tmp_path / "evil.pt", marker), weights_only=False)
    assert marker.exists()


def digests(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())
            if p.is_file()}


def refused(capsys, rc: int, path: Path, marker: Path) -> str:
    err = capsys.readouterr().err
    assert rc != 0
    assert not marker.exists(), "the checkpoint's command ran"
    assert str(path) in err and "refused" in err and "posix.system" in err
    assert "convert-checkpoint" in err and "Traceback" not in err
    return err


def test_reconstruct_and_evaluate_refuse_a_hostile_checkpoint(tiny_shards, tmp_path, capsys):
    marker = tmp_path / "ran"
    evil = hostile_checkpoint(tmp_path / "evil.pt", marker)
    shard = str(sorted(tiny_shards.glob("shard_*.h5"))[0])
    rc = reconstruct_main([shard, "--checkpoint", str(evil), "--out", str(tmp_path / "rec"),
                           "--engine", "torch", "--no-progress"])
    refused(capsys, rc, evil, marker)
    rc = evaluate_main(["--checkpoint", str(evil), "--data", str(tiny_shards), "--split", "all",
                        "--out", str(tmp_path / "eval"), "--engine", "torch"])
    refused(capsys, rc, evil, marker)
    assert not (tmp_path / "rec").exists() and not (tmp_path / "eval").exists()


def test_export_refuses_a_hostile_checkpoint_and_writes_nothing(tmp_path, capsys):
    marker = tmp_path / "ran"
    evil = hostile_checkpoint(tmp_path / "evil.pt", marker)
    before = digests(WEIGHTS)
    refused(capsys, export_main([str(evil)]), evil, marker)
    assert digests(WEIGHTS) == before


def test_train_resume_refuses_a_hostile_last_checkpoint(tiny_checkpoint, tiny_shards, tmp_path,
                                                        capsys):
    run = tmp_path / "run"
    shutil.copytree(tiny_checkpoint.parent, run)
    marker = tmp_path / "ran"
    like = checkpoint.load(run / "last.pt")
    hostile_checkpoint(run / "last.pt", marker, like)
    rc = main(["--data", str(tiny_shards), "--config", TINY, "--out", str(run), "--resume",
               "--set", "run.max_steps=5", "--no-progress"])
    refused(capsys, rc, run / "last.pt", marker)


@pytest.mark.parametrize("key", ["run.init_from", "run.flow_init", "run.first_pass"])
def test_train_refuses_a_hostile_warm_start_flow_or_first_pass(key, tiny_shards, tmp_path,
                                                               capsys):
    marker = tmp_path / "ran"
    evil = hostile_checkpoint(tmp_path / "evil.pt", marker)
    extra = {"run.flow_init": ["model.flow=learned"],
             "run.first_pass": ["model.central=first_pass"]}.get(key, [])
    sets = [f"{key}={evil}", "run.max_steps=2", *extra]
    rc = main(["--data", str(tiny_shards), "--config", TINY, "--out", str(tmp_path / "run"),
               "--no-progress"] + [a for s in sets for a in ("--set", s)])
    refused(capsys, rc, evil, marker)
    assert not (tmp_path / "run" / "last.pt").exists()


def test_every_checkpoint_e2sr_writes_and_ships_loads_as_data(tiny_checkpoint):
    for path in (tiny_checkpoint, WEIGHTS / "e2sr_x2.pt", WEIGHTS / "e2sr_x4.pt"):
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        assert "config" in ckpt and "model" in ckpt
    rng = checkpoint.load(tiny_checkpoint)["rng"]
    assert isinstance(rng["torch"], torch.Tensor) and isinstance(rng["python"], tuple)


def old_style(tiny_checkpoint: Path, path: Path) -> Path:
    """A trusted checkpoint as an older writer might have made it: numpy values inside."""
    ckpt = checkpoint.load(tiny_checkpoint)
    ckpt["train_seconds"] = np.float64(12.5)
    ckpt["sensor_hw"] = np.array([48, 64])
    ckpt["numpy_rng"] = np.random.default_rng(3).bit_generator.state["state"]["state"]
    ckpt["model"] = {k: v.numpy() for k, v in ckpt["model"].items()}
    torch.save(ckpt, path)
    return path


def test_a_trusted_old_checkpoint_is_refused_until_converted_then_loads_the_same(
        tiny_checkpoint, tmp_path, capsys):
    old = old_style(tiny_checkpoint, tmp_path / "old.pt")
    with pytest.raises(checkpoint.UnsafeCheckpointError, match="convert-checkpoint"):
        checkpoint.load(old)
    new = tmp_path / "new.pt"
    assert convert_main([str(old), str(new)]) != 0  # no --trust: nothing is unpickled
    assert "--trust" in capsys.readouterr().err and not new.exists()
    assert convert_main([str(old), str(new), "--trust"]) == 0
    converted = checkpoint.load(new)
    assert converted["train_seconds"] == 12.5
    assert converted["sensor_hw"].tolist() == [48, 64]
    original = checkpoint.load_model(tiny_checkpoint).state_dict()
    again = checkpoint.load_model(new).state_dict()
    assert original.keys() == again.keys()
    assert all(torch.equal(original[k], again[k]) for k in original)
    # the converted file is never overwritten, and nothing is left beside it
    assert convert_main([str(old), str(new), "--trust"]) != 0
    assert "exists" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.pt", "old.pt"]


def test_a_file_that_is_not_a_checkpoint_is_named_in_a_clear_error(tmp_path):
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a zip and not a pickle")
    with pytest.raises(ValueError, match="junk.pt: not a readable checkpoint"):
        checkpoint.load(junk)
