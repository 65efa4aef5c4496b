"""Readout latency and jitter: exact shifts, delay statistics, order, determinism, config."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from esim_lite.config import CameraConfig, FrameConfig, SimulationConfig
from esim_lite.core.dataconf import ConfigError, from_mapping, load_yaml_text
from esim_lite.core.events import Events
from esim_lite.events.latency import LatencyConfig, ReadoutDelay, readout_rng
from esim_lite.events.noise import NoiseConfig, NoiseModel
from esim_lite.events.simulator import EventConfig, EventSimulator
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.render.renderer import RenderConfig
from esim_lite.sequence import simulate_sequence
from tests.conftest import scene_and_trajectory

ROOT = Path(__file__).resolve().parents[2]
HW = (16, 20)


def waves(seed: int, duration_s: float = 0.5):
    """Per-pixel sinusoids of the log intensity (5-20 Hz, amplitude 0.5-1.5) sampled at
    random steps of 50-300 us: float32[H, W] images and their int64 times (ns)."""
    rng = np.random.default_rng(seed)
    f = rng.uniform(5, 20, HW)
    a = rng.uniform(0.5, 1.5, HW)
    phase = rng.uniform(0, 2 * np.pi, HW)
    steps = rng.integers(50_000, 300_000, int(duration_s * 1e9 / 50_000))
    times = np.concatenate([[0], np.cumsum(steps)])
    times = times[times <= duration_s * 1e9]
    images = [(-2 + a * np.sin(2 * np.pi * f * t * 1e-9 + phase)).astype(np.float32)
              for t in times]
    return images, times


def run(images, times, latency=None, seed=0, hot_pixels=False):
    """Every step's events, and what :meth:`EventSimulator.finish` returns."""
    th = ContrastThresholds.uniform(0.2, 0.2, HW)
    noise = NoiseModel(NoiseConfig(hot_pixel_fraction=0.05, hot_pixel_rate_hz=20_000.0), HW,
                       np.random.default_rng(seed)) if hot_pixels else None
    sim = EventSimulator(np.exp(images[0]) - 1e-3, int(times[0]), th, noise=noise,
                         latency=latency, latency_rng=np.random.default_rng([seed, 1]))
    batches = [sim.step_log(img, int(t)) for img, t in zip(images[1:], times[1:])]
    return batches, sim.finish()


def by_pixel(ev: Events) -> tuple[np.ndarray, np.ndarray]:
    """The events' order by (pixel, time) and each one's rank among its pixel's events."""
    pix = ev.y.astype(np.int64) * HW[1] + ev.x
    order = np.lexsort((ev.t_ns, pix))
    pix = pix[order]
    first = np.searchsorted(pix, pix, side="left")
    return order, pix * 10**6 + np.arange(len(pix)) - first


def match(ideal: Events, late: Events) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(i, j)``: ``late[j]`` is ``ideal[i]`` read out (a pixel's k-th event)."""
    io, ikey = by_pixel(ideal)
    lo, lkey = by_pixel(late)
    at = np.searchsorted(ikey, lkey)
    assert np.array_equal(ikey[at], lkey)  # every late event is one of the ideal ones
    return io[at], lo


def test_a_constant_latency_shifts_every_event_by_exactly_that():
    images, times = waves(1)
    ideal = Events.concatenate(run(images, times)[0])
    batches, tail = run(images, times, LatencyConfig(latency_us=150.0))
    late = Events.concatenate(batches + [tail])
    t_pix = ideal.t_ns + (ideal.y.astype(np.int64) * 1000 + ideal.x) * 10**10
    assert np.all(np.diff(np.sort(t_pix)) > 0)  # no pixel fires twice in 1 ns: no rule binds
    kept = ideal.t_ns + 150_000 <= times[-1]
    assert len(ideal) > 20_000 and 0 < (~kept).sum() < 0.01 * len(ideal)
    assert len(tail) == 0
    np.testing.assert_array_equal(late.t_ns, ideal.t_ns[kept] + 150_000)
    for name in ("x", "y", "p"):
        np.testing.assert_array_equal(getattr(late, name), getattr(ideal, name)[kept])


def test_jittered_delays_have_the_configured_mean_and_std():
    images, times = waves(2)
    ideal = Events.concatenate(run(images, times)[0])
    late = Events.concatenate(run(images, times, LatencyConfig(200.0, 20.0), seed=5)[0])
    i, j = match(ideal, late)
    np.testing.assert_array_equal(late.p[j], ideal.p[i])
    d = (late.t_ns[j] - ideal.t_ns[i]) * 1e-3  # us
    n = len(d)
    assert n > 0.98 * len(ideal) > 20_000
    assert abs(d.mean() - 200.0) < 4 * 20.0 / np.sqrt(n)
    assert abs(d.std() - 20.0) < 4 * 20.0 / np.sqrt(2 * n)


def test_release_is_sorted_within_and_across_steps_and_pixels_keep_their_order():
    """Hot pixels at 20 kHz with 200 us of jitter: delays would reorder a pixel's own
    events; the readout keeps them in order, 1 ns apart at least."""
    images, times = waves(3, 0.2)
    ideal = Events.concatenate(run(images, times, hot_pixels=True)[0])
    batches, _ = run(images, times, LatencyConfig(300.0, 200.0), hot_pixels=True)
    prev_end, last = -1, -1
    for batch, t_end in zip(batches, times[1:]):
        if len(batch):
            assert np.array_equal(np.lexsort((batch.x, batch.y, batch.t_ns)),
                                  np.arange(len(batch)))
            assert last <= batch.t_ns[0] and prev_end < batch.t_ns[0]
            assert batch.t_ns[-1] <= t_end
            last = batch.t_ns[-1]
        prev_end = t_end
    late = Events.concatenate(batches)
    i, j = match(ideal, late)
    np.testing.assert_array_equal(late.p[j], ideal.p[i])
    assert np.all(late.t_ns[j] >= ideal.t_ns[i])
    order, _ = by_pixel(late)
    pix = late.y.astype(np.int64)[order] * HW[1] + late.x[order]
    gaps = np.diff(late.t_ns[order])[np.diff(pix) == 0]
    assert gaps.min() >= 1 and (gaps == 1).sum() > 10  # the order rule did bind


def test_the_reorder_buffer_releases_events_once_their_readout_time_has_passed():
    delay = ReadoutDelay(LatencyConfig(latency_us=0.01), (1, 3))  # 10 ns

    def ev(x, t):
        return Events(np.array(x, np.int16), np.zeros(len(x), np.int16),
                      np.array(t, np.int64), np.ones(len(x), np.int8), (1, 3))

    assert len(delay.step(ev([2, 2, 0], [100, 100, 103]), 105)) == 0
    out = delay.step(ev([1], [111]), 120)
    np.testing.assert_array_equal(out.t_ns, [110, 111, 113])  # pixel 2: 110, then 1 ns later
    np.testing.assert_array_equal(out.x, [2, 2, 0])
    assert len(delay.finish(120)) == 0 and delay.dropped == 1  # 121 is past the end


def test_same_seed_same_events_and_latency_off_is_no_latency():
    images, times = waves(4, 0.2)
    cfg = LatencyConfig(100.0, 50.0)
    a, b, c = (Events.concatenate(run(images, times, cfg, seed=s, hot_pixels=True)[0])
               for s in (7, 7, 8))
    for name in ("x", "y", "t_ns", "p"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.t_ns, c.t_ns)
    off = Events.concatenate(run(images, times, LatencyConfig(), hot_pixels=True)[0])
    none = Events.concatenate(run(images, times, None, hot_pixels=True)[0])
    for name in ("x", "y", "t_ns", "p"):
        np.testing.assert_array_equal(getattr(off, name), getattr(none, name))


def test_the_readout_stream_leaves_the_sequence_rng_untouched():
    rng, twin = np.random.default_rng(3), np.random.default_rng(3)
    rng.random(5), twin.random(5)
    first, second = readout_rng(rng), readout_rng(rng)
    np.testing.assert_array_equal(first.random(4), second.random(4))
    np.testing.assert_array_equal(rng.random(8), twin.random(8))
    assert not np.array_equal(readout_rng(rng).random(4), np.random.default_rng(3).random(4))


def test_a_sequence_with_latency_is_the_noisy_sequence_shifted():
    """A whole noisy sequence with 250 us of latency: the same events (noise draws
    unchanged), 250 us later, the last ones dropped; same frames and samples."""
    def once(latency):
        cfg = SimulationConfig(
            duration_s=0.1, frames=FrameConfig(mode="rate", rate_hz=25.0),
            camera=CameraConfig(width=64, height=48, scales=(2,)),
            render=RenderConfig(backend="homography"),
            events=EventConfig(noise=NoiseConfig(shot_rate_hz=2.0, hot_pixel_fraction=0.01,
                                                 hot_pixel_rate_hz=50.0), latency=latency))
        rig = cfg.camera.rig()
        scene, traj = scene_and_trajectory(rig.event, 3, cfg.duration_s)
        th = ContrastThresholds.uniform(0.2, 0.2, rig.event.hw)
        return simulate_sequence(scene, traj, th, cfg, np.random.default_rng(3))

    ideal, late = once(LatencyConfig()), once(LatencyConfig(latency_us=250.0))
    kept = ideal.events.t_ns + 250_000 <= 100_000_000
    assert len(ideal.events) > 1000 and (~kept).any()
    np.testing.assert_array_equal(late.events.t_ns, ideal.events.t_ns[kept] + 250_000)
    for name in ("x", "y", "p"):
        np.testing.assert_array_equal(getattr(late.events, name),
                                      getattr(ideal.events, name)[kept])
    np.testing.assert_array_equal(late.sample_poses, ideal.sample_poses)
    np.testing.assert_array_equal(late.frames["lr"].intensity, ideal.frames["lr"].intensity)


@pytest.mark.parametrize(("text", "key"), [
    ("events:\n  latency:\n    jitter_us: -1\n", "latency.jitter_us must be >= 0"),
    ("events:\n  latency:\n    latency_us: -5\n", "latency.latency_us must be >= 0"),
    ("events:\n  latency:\n    latency_us: .nan\n", "latency.latency_us must be >= 0"),
    ("events:\n  latency:\n    delay_us: 3\n", "events.latency.delay_us: unknown key"),
])
def test_bad_latency_values_fail_at_load_naming_the_key(text, key):
    with pytest.raises(ConfigError, match=key):
        load_yaml_text(SimulationConfig, text)


def test_event_config_and_the_default_yaml_load_latency():
    cfg = load_yaml_text(EventConfig, "latency:\n  latency_us: 40\n  jitter_us: 5.5\n")
    assert cfg.latency == LatencyConfig(40.0, 5.5) and cfg.latency.enabled
    with pytest.raises(ConfigError, match="latency.jitter_us"):
        load_yaml_text(EventConfig, "latency:\n  jitter_us: -0.1\n")
    sim = yaml.safe_load((ROOT / "configs" / "datagen.yaml").read_text())["simulation"]
    loaded = from_mapping(SimulationConfig, sim)
    assert loaded.events.latency == LatencyConfig() and not loaded.events.latency.enabled
