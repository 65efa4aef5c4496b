"""``train --out``: a folder holding a run is never overwritten by accident, and one live
``train`` per folder (model/training/run_folder.py)."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from model import checkpoint
from model.cli import main
from model.training.run_folder import RunFolder
from tests.model.conftest import ROOT

CFG = str(ROOT / "configs" / "train_tiny.yaml")


def run(shards: Path, out: Path, *extra: str) -> int:
    return main(["--data", str(shards), "--config", CFG, "--out", str(out), "--no-progress",
                 "--set", "run.max_steps=2", *extra])


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_folder_holding_a_run_is_refused_without_resume_or_overwrite(tiny_shards, tmp_path,
                                                                        capsys):
    out = tmp_path / "run"
    assert run(tiny_shards, out) == 0
    kept = {p: digest(out / p) for p in ("last.pt", "val_history.csv", "config.yaml")}
    capsys.readouterr()

    assert run(tiny_shards, out, "--set", "run.seed=9") == 2
    err = capsys.readouterr().err
    assert str(out) in err and "holds a run" in err and "last.pt at step 2" in err
    assert "--resume" in err and "--overwrite" in err and "Traceback" not in err
    assert {p: digest(out / p) for p in kept} == kept  # nothing of the old run was touched

    assert run(tiny_shards, out, "--resume", "--overwrite") == 2
    assert "give one of them" in capsys.readouterr().err

    # --overwrite starts afresh: the new run's seed, one fresh validation history
    assert run(tiny_shards, out, "--set", "run.seed=9", "--overwrite") == 0
    assert yaml.safe_load((out / "config.yaml").read_text())["run"]["seed"] == 9
    assert checkpoint.load(out / "last.pt")["step"] == 2
    assert len((out / "val_history.csv").read_text().splitlines()) == 2  # header + one row
    assert not (out / ".train.owner.json").exists()  # released at the end


def test_resume_continues_in_a_folder_holding_its_run(tiny_shards, tmp_path):
    out = tmp_path / "run"
    assert run(tiny_shards, out) == 0
    assert main(["--data", str(tiny_shards), "--config", CFG, "--out", str(out),
                 "--no-progress", "--set", "run.max_steps=3", "--resume"]) == 0
    assert checkpoint.load(out / "last.pt")["step"] == 3


def test_an_empty_or_foreign_folder_is_not_a_run(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with RunFolder(tmp_path, seed=0):
        assert (tmp_path / ".train.owner.json").is_file()
    assert (tmp_path / "notes.txt").read_text() == "mine"
    (tmp_path / "f").write_text("")
    with pytest.raises(ValueError, match="is not a folder"):
        RunFolder(tmp_path / "f", seed=0).__enter__()


HOLD = """
import sys, time
from model.training.run_folder import RunFolder
with RunFolder(sys.argv[1], seed=42):
    print("holding", flush=True)
    time.sleep(120)
"""


def test_a_second_writer_is_refused_with_the_live_one_named(tiny_shards, tmp_path, capsys):
    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE,
                              text=True, cwd=ROOT)
    try:
        assert holder.stdout.readline().strip() == "holding"
        for extra in ((), ("--resume",), ("--overwrite",)):
            assert run(tiny_shards, out, *extra) == 2
            err = capsys.readouterr().err
            assert "another train is writing to this folder" in err
            assert f"pid {holder.pid}" in err and "seed 42" in err
        assert not (out / "last.pt").exists()
    finally:
        os.kill(holder.pid, signal.SIGKILL)
        holder.wait()
    # the kernel released the dead holder's lock, and its stale owner file does not block
    assert (out / ".train.owner.json").exists()
    assert run(tiny_shards, out) == 0
    assert checkpoint.load(out / "last.pt")["step"] == 2
