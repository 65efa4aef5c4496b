"""The from-video oracle (tests/datagen/video_oracle.py): a sequence our simulator renders at
its own adaptive rate (exact events), written as a 30 fps 16-bit PNG video, turned back into
events by ``from-video``; per-pixel event counts and timing against the exact ones."""

from __future__ import annotations

import pytest

from datagen.shard import ShardReader
from datagen.video.config import FromVideoConfig
from datagen.video.from_video import from_video
from esim_lite.core.dataconf import load_config
from tests.datagen.video_oracle import THRESHOLD, compare, render


def video_events(rendered, interpolator: str, out):
    h, w = rendered.sensor_hw
    cfg = load_config(FromVideoConfig, None, [
        f"simulation.camera.width={w}", f"simulation.camera.height={h}",
        "simulation.camera.scales=[4]",
        f"simulation.events.thresholds.pos_range=[{THRESHOLD},{THRESHOLD}]",
        f"simulation.events.thresholds.neg_range=[{THRESHOLD},{THRESHOLD}]",
        f"video.frames_per_sequence={rendered.n_frames}", f"video.interpolator={interpolator}"])
    from_video([rendered.folder], out, cfg, show_progress=False)
    with ShardReader(out / "shard_00000.h5") as r:
        return r.events("seq_000000")


@pytest.fixture(scope="module")
def fast(tmp_path_factory):
    """8 LR pixels a video frame: far beyond what fading between frames can stand for."""
    return render(tmp_path_factory.mktemp("fast"), px_per_frame=8.0, n_frames=7)


def test_flow_reproduces_the_exact_events_when_motion_is_8_px_a_frame(fast, tmp_path):
    c = compare(fast.events, video_events(fast, "flow", tmp_path / "flow"),
                fast.frame_interval_ns, margin=10)
    assert c.true_events > 20_000
    assert c.count_error < 0.05  # measured 0.022 (bench/bench_from_video.py)
    assert c.timing_error < 0.15  # frame intervals; measured 0.08


def test_linear_loses_most_events_at_8_px_a_frame_and_flow_beats_it(fast, tmp_path):
    linear = compare(fast.events, video_events(fast, "linear", tmp_path / "linear"),
                     fast.frame_interval_ns, margin=10)
    flow = compare(fast.events, video_events(fast, "flow", tmp_path / "flow"),
                   fast.frame_interval_ns, margin=10)
    assert linear.count_error > 0.5  # measured 0.75: an edge fades instead of moving
    assert flow.count_error < linear.count_error / 10
    assert flow.timing_error < linear.timing_error / 10


def test_both_agree_with_the_exact_events_when_nothing_moves_far(tmp_path):
    slow = render(tmp_path / "slow", px_per_frame=0.5, n_frames=5)
    for name in ("linear", "flow"):
        c = compare(slow.events, video_events(slow, name, tmp_path / name),
                    slow.frame_interval_ns, margin=3)
        assert c.count_error < 0.1, name
