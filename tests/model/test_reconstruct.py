"""Reconstruction from recordings: streaming equals in-memory, memory stays bounded."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from datagen.recording import open_recording
from esim_lite.core.events import Events
from model.cli import reconstruct_main
from model.inference.reconstruct import EventWindow, Reconstructor, plan_outputs, reconstruct
from tests.conftest import REAL_EVENTS
from tests.datagen.test_recording import events, write_hdf5


def shard(tiny_shards):
    return sorted(tiny_shards.glob("shard_*.h5"))[0]


def test_streamed_output_equals_in_memory_output(tiny_shards, tiny_checkpoint, tmp_path):
    rec = open_recording(shard(tiny_shards), sequence="seq_000001")
    model = Reconstructor.load(tiny_checkpoint, rec.sensor_hw, device="cpu")
    plan = plan_outputs(rec, model.stacks)
    assert plan.at == "frames"
    a = reconstruct(rec, model, tmp_path / "a", plan, show_progress=False, chunk=37)
    b = reconstruct(rec, model, tmp_path / "b", plan, show_progress=False, chunk=10**7)
    assert len(a.frames) == len(rec.frames) == 5
    for pa, pb in zip(a.frames, b.frames):
        ia, ib = cv2.imread(str(pa), 0), cv2.imread(str(pb), 0)
        assert ia.shape == (96, 128)  # x2 of the 64x48 sensor
        np.testing.assert_array_equal(ia, ib)
    times = (tmp_path / "a" / "timestamps.txt").read_text().split("\n")
    assert len([t for t in times if t]) == 5


def test_the_event_window_forgets_what_is_no_longer_needed():
    hw = (10, 10)
    total = 200_000
    chunks = (Events(np.zeros(1000, np.int16), np.zeros(1000, np.int16),
                     np.arange(k, k + 1000, dtype=np.int64), np.ones(1000, np.int8), hw)
              for k in range(0, total, 1000))
    window, biggest = EventWindow(chunks, hw), 0
    for anchor in range(5000, total, 3000):
        ev, first = window.slice(anchor - 4000, anchor + 2000)
        assert first == anchor - 4000 and ev.t_ns[0] == anchor - 4000
        window.forget(anchor - 4000)
        biggest = max(biggest, len(window.buf))
    assert biggest <= 8000  # never the whole stream


def test_outputs_every_stack_or_at_a_rate(tiny_shards, tiny_checkpoint, tmp_path):
    path = tmp_path / "e.h5"
    write_hdf5(path, events(n=20000, hw=(48, 64)), with_frames=False)
    rec = open_recording(path)
    model = Reconstructor.load(tiny_checkpoint, rec.sensor_hw, device="cpu")
    plan = plan_outputs(rec, model.stacks)
    assert plan.at == "events"
    r = reconstruct(rec, model, tmp_path / "ev", plan, show_progress=False, mp4=True)
    assert len(r.frames) == 20000 // model.stacks.events_per_stack
    assert (tmp_path / "ev" / "video.mp4").stat().st_size > 0
    r = reconstruct(rec, model, tmp_path / "rate", plan_outputs(rec, model.stacks, "rate", 1.0),
                    show_progress=False)
    assert len(r.frames) == 2  # 2 s of events at 1 Hz
    with pytest.raises(ValueError, match="no APS frames"):
        plan_outputs(rec, model.stacks, "frames")


def test_modes_must_match_the_checkpoint(tiny_checkpoint):
    with pytest.raises(ValueError, match="cannot run in mode 'complementary'"):
        Reconstructor.load(tiny_checkpoint, (48, 64), mode="complementary")


def test_stacks_scale_with_the_sensor_area(tiny_checkpoint):
    small = Reconstructor.load(tiny_checkpoint, (48, 64)).stacks.events_per_channel
    big = Reconstructor.load(tiny_checkpoint, (96, 128)).stacks.events_per_channel
    assert small == 100 and big == 400  # trained at 64x48 with 100 per channel


@pytest.mark.skipif(not (REAL_EVENTS / "ecd_snippets").is_dir(),
                    reason="real recordings not present")
def test_reconstruct_a_real_snippet(tiny_checkpoint, tmp_path, capsys):
    snippet = REAL_EVENTS / "ecd_snippets" / "shapes_rotation"
    assert reconstruct_main([str(snippet), "--checkpoint", str(tiny_checkpoint), "--out",
                             str(tmp_path), "--sensor-size", "240x180", "--no-progress"]) == 0
    assert "240x180 sensor" in capsys.readouterr().out
    frames = sorted(tmp_path.glob("frame_*.png"))
    assert frames and cv2.imread(str(frames[0]), 0).shape == (360, 480)


def test_cli_errors(tiny_checkpoint, tmp_path, capsys):
    bad = tmp_path / "events.txt"
    bad.write_text("1.0 1 1 1\n0.5 1 1 0\n")
    assert reconstruct_main([str(bad), "--checkpoint", str(tiny_checkpoint), "--out",
                             str(tmp_path / "o"), "--sensor-size", "10x10",
                             "--no-progress"]) == 2
    assert "timestamps go back in time" in capsys.readouterr().err
    assert reconstruct_main([str(bad), "--checkpoint", str(tiny_checkpoint), "--out",
                             str(tmp_path / "o"), "--sensor-size", "ten"]) == 2
    assert "--sensor-size must look like" in capsys.readouterr().err
    # --out naming a file: refused before the model runs, the file untouched
    blocker = tmp_path / "taken.png"
    blocker.write_bytes(b"mine")
    assert reconstruct_main([str(bad), "--checkpoint", str(tiny_checkpoint), "--out",
                             str(blocker), "--sensor-size", "10x10"]) == 2
    assert "taken.png: exists and is not a folder" in capsys.readouterr().err
    assert blocker.read_bytes() == b"mine"
    # too few events for one stack: an error, not "wrote 0 frame(s)", and nothing written
    few = tmp_path / "few.txt"
    few.write_text("".join(f"{1 + k * 1e-4:.6f} {k % 10} {k % 7} {k % 2}\n" for k in range(50)))
    assert reconstruct_main([str(few), "--checkpoint", str(tiny_checkpoint), "--out",
                             str(tmp_path / "f"), "--sensor-size", "10x10",
                             "--events-per-stack", "300", "--no-progress"]) == 2
    assert "too few events for one output" in capsys.readouterr().err
    assert not (tmp_path / "f").exists() or not any((tmp_path / "f").iterdir())


def test_reading_far_ahead_keeps_memory_bounded_unless_pinned():
    hw = (10, 10)

    def stream():
        return (Events(np.zeros(1000, np.int16), np.zeros(1000, np.int16),
                       np.arange(k, k + 1000, dtype=np.int64), np.ones(1000, np.int8), hw)
                for k in range(0, 1_000_000, 1000))

    window = EventWindow(stream(), hw, keep=5000)
    assert window.index_after(900_000) == 900_001
    assert len(window.buf) <= 6000  # not 900,000
    ev, first = window.slice(900_001 - 3000, 900_001)
    assert first == 897_001 and len(ev) == 3000
    pinned = EventWindow(stream(), hw, keep=5000)
    pinned.pin = 100
    pinned.index_after(50_000)
    assert pinned.offset == 100  # what the caller still needs stays


def test_complementary_and_duo_pass_reconstruction(tiny_shards, tiny_checkpoint, tmp_path):
    from model.training.train import train
    from tests.model.conftest import tiny_config

    train(tiny_config("model.central=aps", "run.max_steps=1"), tiny_shards, tmp_path / "comp",
          show_progress=False)
    train(tiny_config("model.central=first_pass", "run.max_steps=1",
                      f"run.first_pass={tiny_checkpoint}"), tiny_shards, tmp_path / "duo",
          show_progress=False)
    rec = open_recording(shard(tiny_shards), sequence="seq_000001")
    for mode, ckpt in (("complementary", tmp_path / "comp" / "last.pt"),
                       ("duo-pass", tmp_path / "duo" / "last.pt")):
        model = Reconstructor.load(ckpt, rec.sensor_hw, mode, device="cpu")
        r = reconstruct(rec, model, tmp_path / mode, plan_outputs(rec, model.stacks),
                        show_progress=False, temporal=0.6)
        assert len(r.frames) == 5
        assert cv2.imread(str(r.frames[-1]), 0).shape == (96, 128)


def test_sbt_models_get_time_stacks_streamed_with_bounded_memory():
    """A model trained on stacks by time gets them at reconstruction too: streamed from small
    chunks they equal the stacks built from the whole recording in memory, while the event
    rate jumps 50x, and the window holds only about the stacks' time span."""
    import torch

    from esim_lite.core.stacking import StackConfig, stack_sequence_by_time
    from model.archs.e2sri_arch import E2SRI, NetConfig

    hw, n = (8, 8), 200_000
    rng = np.random.default_rng(3)
    gaps = np.repeat(np.tile([1_000, 50_000], 10), n // 20)  # ns: 10k fast, 10k slow, ...
    ev = Events(rng.integers(0, 8, n).astype(np.int16), rng.integers(0, 8, n).astype(np.int16),
                np.cumsum(gaps).astype(np.int64), rng.choice([-1, 1], n).astype(np.int8), hw)
    cfg = StackConfig(method="sbt", channels=3, channel_ms=2.0)
    net = E2SRI(NetConfig(base_channels=8, hr_channels=4, c_blocks=1, blocks=1))
    model = Reconstructor(net, None, cfg, torch.device("cpu"))
    window = model.event_window((ev.slice(k, k + 1000) for k in range(0, n, 1000)), hw, 1000)
    biggest = 0
    for t in np.linspace(ev.t_ns[0] + 30_000_000, ev.t_ns[-1] - 30_000_000, 60).astype(int):
        got = model.stacks_at(window, int(t))
        want = stack_sequence_by_time(ev, cfg, int(t), 3)
        np.testing.assert_array_equal(got.stacks, np.stack([s.image for s in want]))
        assert got.anchor == np.searchsorted(ev.t_ns, t, side="right")
        window.forget(got.first)
        biggest = max(biggest, len(window.buf))
    assert biggest <= 4 * 6_000 + 2_000  # (n+1) stack spans of 6 ms at 1 event/us, + a chunk


def test_forgetting_most_of_the_window_keeps_global_indices():
    hw = (4, 4)
    ev = Events(np.zeros(10_000, np.int16), np.zeros(10_000, np.int16),
                np.arange(10_000, dtype=np.int64) * 10, np.ones(10_000, np.int8), hw)
    window = EventWindow(iter([ev]), hw)
    assert window.index_after(0) == 1
    window.forget(9_000)  # more than half of what it holds
    assert window.offset == 9_000 and window.index_after(95_000) == 9_501
    got, first = window.slice(9_500, 9_600)
    assert first == 9_500 and got.t_ns[0] == 95_000
