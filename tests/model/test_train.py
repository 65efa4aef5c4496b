"""Training: data samples, schedules, exact resumption, DDP on gloo, failure handling."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from datagen.shard import find_shards
from esim_lite.core.stacking import StackConfig
from model import checkpoint
from model.cli import main
from model.config import OptimConfig
from model.data.config import DataConfig
from model.data.dataset import ShardSamples, index_samples, split_sequences
from model.training.setup import epoch_batches
from model.training.train import lr_lambda, train
from tests.model.conftest import ROOT, tiny_config


def weights(path: Path) -> dict[str, torch.Tensor]:
    return checkpoint.load(path)["model"]


def assert_same_weights(a: Path, b: Path) -> None:
    wa, wb = weights(a), weights(b)
    assert wa.keys() == wb.keys()
    for k in wa:
        assert torch.equal(wa[k], wb[k]), k


def test_schedules():
    paper = lr_lambda(OptimConfig(schedule="paper", epochs=16), steps_per_epoch=10)
    assert [paper(s) for s in (0, 79, 80, 119, 120, 139, 140, 149, 150)] == pytest.approx(
        [1, 1, 0.1, 0.1, 0.01, 0.01, 1e-3, 1e-3, 1e-4])
    released = lr_lambda(OptimConfig(schedule="released", epochs=100), steps_per_epoch=2)
    assert [released(s) for s in (99, 100, 149, 150)] == pytest.approx([1, 0.1, 0.1, 0.01])
    assert lr_lambda(OptimConfig(schedule="constant"), 5)(10**6) == 1


def test_epoch_batches_are_deterministic_and_split_ranks():
    a = epoch_batches(103, 4, seed=1, epoch=3)
    assert a == epoch_batches(103, 4, seed=1, epoch=3) != epoch_batches(103, 4, 1, 4)
    assert len(a) == 25 and all(len(b) == 4 for b in a)
    r0, r1 = epoch_batches(103, 4, 1, 3, 0, 2), epoch_batches(103, 4, 1, 3, 1, 2)
    seen0, seen1 = {i for b in r0 for i in b}, {i for b in r1 for i in b}
    assert not seen0 & seen1 and len(r0) == len(r1) == 12  # equal steps, or DDP hangs


def test_split_is_deterministic_by_sequence_and_never_empty():
    keys = [f"shard_00000.h5/seq_{i:06d}" for i in range(10)]
    assert split_sequences(keys, 0.1) == split_sequences(list(reversed(keys)), 0.1)
    assert len(split_sequences(keys, 0.1)) == 1 and len(split_sequences(keys[:2], 0.01)) == 1
    assert split_sequences(keys, 0.0) == set()


def test_samples_are_aligned_reproducible_and_augmented(tiny_shards):
    data = DataConfig(stacks=StackConfig(events_per_channel=100), crop=32)
    train_refs, val_refs = index_samples(find_shards(tiny_shards), data, 3, 2)
    assert train_refs and val_refs
    assert not {(r.path, r.sequence) for r in train_refs} & {(r.path, r.sequence)
                                                             for r in val_refs}
    ds = ShardSamples(train_refs, data, 3, 2, train=True, seed=5)
    s = ds[0]
    assert s["stacks"].shape == (3, 3, 32, 32) and s["hr"].shape == (1, 64, 64)
    assert set(s["stacks"].unique().tolist()) <= {-1.0, 0.0, 1.0}
    # the HR crop is the same piece of the scene as the LR crop
    down = cv2.resize(s["hr"][0].numpy(), (32, 32), interpolation=cv2.INTER_AREA)
    assert 10 * np.log10(1 / np.mean((down - s["lr"][0].numpy()) ** 2)) > 30
    again = ShardSamples(train_refs, data, 3, 2, train=True, seed=5)[0]
    for k in s:
        assert torch.equal(s[k], again[k]), k
    ds.set_epoch(1)
    assert not torch.equal(ds[0]["hr"], s["hr"])  # a new crop or flip next epoch
    full = ShardSamples(val_refs, data, 3, 2, train=False)[0]
    assert full["lr"].shape == (1, 48, 64) and full["hr"].shape == (1, 96, 128)


def test_resume_ends_with_the_same_weights_as_an_uninterrupted_run(tiny_shards, tmp_path):
    torch.use_deterministic_algorithms(True)
    try:
        train(tiny_config("run.max_steps=7"), tiny_shards, tmp_path / "straight",
              show_progress=False)
        train(tiny_config("run.max_steps=4"), tiny_shards, tmp_path / "split",
              show_progress=False)
        assert checkpoint.load(tmp_path / "split" / "last.pt")["step"] == 4
        result = train(tiny_config("run.max_steps=7"), tiny_shards, tmp_path / "split",
                       resume=True, show_progress=False)
    finally:
        torch.use_deterministic_algorithms(False)
    assert result["step"] == 7
    assert_same_weights(tmp_path / "straight" / "last.pt", tmp_path / "split" / "last.pt")
    ckpt = checkpoint.load(tmp_path / "split" / "last.pt")
    for key in ("optimizer", "scheduler", "rng", "config", "net", "epoch", "batch_in_epoch"):
        assert key in ckpt
    assert checkpoint.load_model(tmp_path / "split" / "last.pt").config.base_channels == 8


@pytest.mark.slow
def test_a_killed_run_resumes_to_the_same_weights(tiny_shards, tmp_path):
    cmd = [sys.executable, "-m", "model.cli", "--data", str(tiny_shards), "--config",
           str(ROOT / "configs" / "train_tiny.yaml"), "--no-progress",
           "--set", "run.max_steps=40", "--set", "run.checkpoint_every=2"]
    subprocess.run(cmd + ["--out", str(tmp_path / "straight")], check=True)
    proc = subprocess.Popen(cmd + ["--out", str(tmp_path / "killed")])
    last = tmp_path / "killed" / "last.pt"
    deadline = time.time() + 120
    while time.time() < deadline:
        if last.is_file():
            try:
                if checkpoint.load(last)["step"] >= 6:
                    break
            except (ValueError, EOFError):
                pass
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert checkpoint.load(last)["step"] < 40, "killed before the end"
    subprocess.run(cmd + ["--out", str(tmp_path / "killed"), "--resume"], check=True)
    assert_same_weights(tmp_path / "straight" / "last.pt", last)


def _ddp_worker(rank: int, world: int, port: int, shards: str, out: str) -> None:
    os.environ.update({"RANK": str(rank), "WORLD_SIZE": str(world), "LOCAL_RANK": str(rank),
                       "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port)})
    torch.set_num_threads(1)
    result = train(tiny_config("run.max_steps=3", "optim.batch_size=1"), shards, out,
                   show_progress=False)
    (Path(out) / f"digest_rank{rank}.txt").write_text(result["weights_sha256"])
    torch.distributed.destroy_process_group()


def test_ddp_on_two_cpu_processes(tiny_shards, tmp_path):
    out = tmp_path / "ddp"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    torch.multiprocessing.spawn(_ddp_worker, args=(2, port, str(tiny_shards), str(out)),
                                nprocs=2)
    assert checkpoint.load(out / "last.pt")["step"] == 3
    digests = {(out / f"digest_rank{r}.txt").read_text() for r in range(2)}
    assert len(digests) == 1  # both ranks hold the same weights after every step
    from model.archs.e2sri_arch import E2SRI
    from model.training.train import weights_digest

    net = checkpoint.load_model(out / "last.pt")
    assert isinstance(net, E2SRI) and weights_digest(net) in digests


def test_nan_loss_saves_a_checkpoint_and_says_so(tiny_shards, tmp_path, monkeypatch):
    from model.losses import similarity as losses

    monkeypatch.setattr(losses.SimilarityLoss, "forward",
                        lambda self, o, t, stacks=None: (o.mean() * float("nan"), {}))
    with pytest.raises(FloatingPointError, match="loss is nan at step 0"):
        train(tiny_config(), tiny_shards, tmp_path, show_progress=False)
    assert (tmp_path / "nan_step0.pt").is_file()


@pytest.mark.parametrize("central", ["aps", "first_pass"])
def test_extensions_train(tiny_shards, tmp_path, central):
    first = tmp_path / "main"
    sets = [f"model.central={central}", "run.max_steps=2"]
    if central == "first_pass":
        train(tiny_config("run.max_steps=2"), tiny_shards, first, show_progress=False)
        sets.append(f"run.first_pass={first / 'last.pt'}")
    result = train(tiny_config(*sets), tiny_shards, tmp_path / central, show_progress=False)
    assert result["step"] == 2 and "val" in result


def test_cli(tiny_shards, tmp_path, capsys):
    cfg = str(ROOT / "configs" / "train_tiny.yaml")
    assert main(["--data", str(tiny_shards), "--config", cfg, "--out", str(tmp_path / "r"),
                 "--set", "run.max_steps=2", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "trained 2 steps" in out and "PSNR" in out
    assert (tmp_path / "r" / "val_examples.png").is_file()
    assert (tmp_path / "r" / "tb").is_dir() and (tmp_path / "r" / "result.json").is_file()
    assert main(["--data", str(tmp_path / "none"), "--config", cfg, "--out",
                 str(tmp_path / "x")]) == 2
    assert "no shard_*.h5 files" in capsys.readouterr().err
    assert main(["--data", str(tiny_shards), "--config", cfg, "--set", "optim.lrr=1"]) == 2
    assert "optim.lrr: unknown key" in capsys.readouterr().err
    assert main(["--data", str(tiny_shards), "--config", cfg, "--set", "model.scale=4"]) == 2
    assert "no hr_x4 frames" in capsys.readouterr().err


def test_resume_refuses_a_different_network_or_batch_plan(tiny_shards, tmp_path):
    from model.training.train import train

    out = tmp_path / "r"
    train(tiny_config("run.max_steps=2"), tiny_shards, out, show_progress=False)
    with pytest.raises(ValueError, match=r"cannot resume with a different model.base_channels "
                                         r"\(8 -> 16\)"):
        train(tiny_config("run.max_steps=4", "model.base_channels=16"), tiny_shards, out,
              resume=True, show_progress=False)
    with pytest.raises(ValueError, match=r"optim.batch_size \(2 -> 3\)"):
        train(tiny_config("run.max_steps=4", "optim.batch_size=3"), tiny_shards, out,
              resume=True, show_progress=False)
    # how the run runs may change: more steps, other logging
    result = train(tiny_config("run.max_steps=3", "run.log_every=5"), tiny_shards, out,
                   resume=True, show_progress=False)
    assert result["step"] == 3


def test_stacking_by_time_feeds_the_same_pipeline(tiny_shards, tmp_path):
    data = DataConfig(stacks=StackConfig(method="sbt", channels=3, channel_ms=2.0), crop=32)
    refs, _ = index_samples(find_shards(tiny_shards), data, 3, 2)
    assert refs
    sample = ShardSamples(refs, data, 3, 2, train=True)[0]
    assert sample["stacks"].shape == (3, 3, 32, 32) and sample["stacks"].abs().sum() > 0
    result = train(tiny_config("data.stacks.method=sbt", "data.stacks.channel_ms=2.0",
                               "run.max_steps=2"), tiny_shards, tmp_path, show_progress=False)
    assert result["step"] == 2
