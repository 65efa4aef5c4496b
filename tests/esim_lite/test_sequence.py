"""Whole sequences: the event/intensity invariant, determinism, noise statistics."""

from __future__ import annotations

import numpy as np
import pytest

from esim_lite.config import CameraConfig, FrameConfig, SimulationConfig
from esim_lite.core.events import Events
from esim_lite.events.noise import NoiseConfig, NoiseModel
from esim_lite.events.simulator import EventConfig, EventSimulator
from esim_lite.events.thresholds import ContrastThresholds, ThresholdConfig, sample_thresholds
from esim_lite.geometry.trajectory import TrajectoryConfig
from esim_lite.render.renderer import RenderConfig
from esim_lite.sequence import FrameSchedule, frame_times_ns, simulate, simulate_sequence
from tests.conftest import scene_and_trajectory

SMALL = CameraConfig(width=64, height=48, scales=(2,))


def small_config(backend: str = "homography", duration_s: float = 0.2, **events) -> \
        SimulationConfig:
    return SimulationConfig(duration_s=duration_s, frames=FrameConfig(mode="rate", rate_hz=25.0),
                            camera=SMALL,
                            render=RenderConfig(backend=backend), events=EventConfig(**events))


def test_net_events_track_the_log_intensity_at_every_pixel_and_sample():
    """For all pixels and sample times t1 < t2 (no noise, no refractory period):
    |L(t2) - L(t1) - (n_on C+ - n_off C-)| < C+ + C-, with per-pixel mismatched C."""
    cfg = small_config(duration_s=0.25)
    rig = cfg.camera.rig()
    brisk = TrajectoryConfig(speed_m_s=(0.8, 1.2), angular_speed_deg_s=(90, 150))
    scene, traj = scene_and_trajectory(rig.event, 8, cfg.duration_s, brisk)
    rng = np.random.default_rng(8)
    th = sample_thresholds(ThresholdConfig(mismatch_std=0.03), rig.event.hw, rng)
    assert th.has_mismatch
    logs, counts = [], []
    original = EventSimulator.step_log

    def recording(sim, log_img, t_ns):
        if not logs:
            logs.append(sim.log_prev.astype(np.float64))
            counts.append(np.zeros((2,) + rig.event.hw, np.int64))
        ev = original(sim, log_img, t_ns)
        logs.append(log_img.astype(np.float64))
        counts.append(counts[-1] + ev.count_image())
        return ev

    EventSimulator.step_log = recording
    try:
        total = sum(len(c.events) for c in simulate(scene, traj, th, cfg, rng))
    finally:
        EventSimulator.step_log = original
    assert total > 20_000 and len(logs) > 50
    logs, counts = np.array(logs), np.array(counts)
    cp, cn = th.pos_map, th.neg_map
    # from the start: the residual stays inside the (-C-, C+) window
    resid = logs - logs[0] - (counts[:, 0] * cp - counts[:, 1] * cn)
    assert np.all(resid < cp + 1e-6) and np.all(resid > -cn - 1e-6)
    # any two sample times, as the property is stated
    for k1, k2 in np.random.default_rng(0).integers(0, len(logs), (200, 2)):
        k1, k2 = min(k1, k2), max(k1, k2)
        n = counts[k2] - counts[k1]
        gap = logs[k2] - logs[k1] - (n[0] * cp - n[1] * cn)
        assert np.all(np.abs(gap) < cp + cn)


@pytest.mark.parametrize("backend", ["homography", "mitsuba"])
def test_same_seed_same_events_and_frames_bit_for_bit(backend):
    def once(seed):
        cfg = small_config(backend, duration_s=0.1,
                           noise=NoiseConfig(shot_rate_hz=2.0, hot_pixel_fraction=0.01,
                                             hot_pixel_rate_hz=50.0, leak_rate_hz=0.5),
                           thresholds=ThresholdConfig(mismatch_std=0.02))
        rig = cfg.camera.rig()
        scene, traj = scene_and_trajectory(rig.event, seed, cfg.duration_s)
        rng = np.random.default_rng(seed)
        th = sample_thresholds(cfg.events.thresholds, rig.event.hw, rng)
        return simulate_sequence(scene, traj, th, cfg, rng)

    a, b, c = once(3), once(3), once(4)
    assert len(a.events) > 1000
    for field in ("x", "y", "t_ns", "p"):
        np.testing.assert_array_equal(getattr(a.events, field), getattr(b.events, field))
    for name in a.frames:
        np.testing.assert_array_equal(a.frames[name].intensity, b.frames[name].intensity)
    np.testing.assert_array_equal(a.sample_poses, b.sample_poses)
    assert len(c.events) != len(a.events) or not np.array_equal(c.events.t_ns, a.events.t_ns)


def test_sequence_record_shapes_and_frame_times():
    cfg = small_config(duration_s=0.2)
    rig = cfg.camera.rig()
    scene, traj = scene_and_trajectory(rig.event, 2, cfg.duration_s)
    th = ContrastThresholds.uniform(0.2, 0.2, rig.event.hw)
    seq = simulate_sequence(scene, traj, th, cfg, np.random.default_rng(0))
    np.testing.assert_array_equal(seq.frames["lr"].t_ns, [0, 40e6, 80e6, 120e6, 160e6, 200e6])
    assert seq.frames["lr"].intensity.shape == (6, 48, 64)
    assert seq.frames["hr_x2"].intensity.shape == (6, 96, 128)
    assert seq.frame_poses.shape == (6, 8)
    assert seq.events.is_sorted() and seq.events.t_ns[-1] <= 200_000_000
    seq.events.validate()
    np.testing.assert_allclose(np.diff(seq.sample_poses[:, 0]) > 0, True)


def test_frame_times():
    np.testing.assert_array_equal(frame_times_ns(0.1, 30.0), [0, 33333333, 66666667, 100000000])
    assert len(frame_times_ns(1.0, 50.0)) == 51


def static_simulator(noise: NoiseConfig, hw=(40, 50), seconds=2.0, steps=200, seed=0):
    th = ContrastThresholds.uniform(0.2, 0.2, hw)
    model = NoiseModel(noise, hw, np.random.default_rng(seed))
    img = np.full(hw, 0.5, np.float32)
    sim = EventSimulator(img, 0, th, noise=model)
    dt = int(seconds * 1e9 / steps)
    evs = [sim.step(img, dt * (k + 1)) for k in range(steps)]
    return model, evs


def test_static_scene_without_noise_is_silent():
    _, evs = static_simulator(NoiseConfig())
    assert sum(len(e) for e in evs) == 0


def test_shot_noise_rate_and_polarity_balance():
    _, evs = static_simulator(NoiseConfig(shot_rate_hz=3.0))
    p = np.concatenate([e.p for e in evs])
    expected = 3.0 * 2.0 * 40 * 50
    assert abs(len(p) - expected) < 5 * np.sqrt(expected)
    assert abs((p > 0).mean() - 0.5) < 0.03
    assert all(e.is_sorted() for e in evs)


def test_shot_noise_falls_with_the_light_as_configured():
    """v2e's rule: the dark rate in the dark, ``shot_bright_factor`` of it at full light,
    linear between; each half of a split image fires at its own Poisson rate."""
    hw, seconds, steps = (40, 50), 2.0, 200
    cfg = NoiseConfig(shot_rate_hz=3.0, shot_bright_factor=0.25)
    model = NoiseModel(cfg, hw, np.random.default_rng(1))
    img = np.full(hw, 0.0, np.float32)
    img[:, 25:] = 1.0  # left dark, right full light
    sim = EventSimulator(img, 0, ContrastThresholds.uniform(0.2, 0.2, hw), noise=model)
    dt = int(seconds * 1e9 / steps)
    evs = [sim.step(img, dt * (k + 1)) for k in range(steps)]
    x = np.concatenate([e.x for e in evs])
    for side, rate in ((x < 25, 3.0), (x >= 25, 0.75)):
        expected = rate * seconds * 40 * 25
        assert abs(side.sum() - expected) < 5 * np.sqrt(expected)
    assert all(e.is_sorted() for e in evs)


@pytest.mark.parametrize("value", [-0.1, 1.5])
def test_a_bad_shot_bright_factor_is_refused(value):
    with pytest.raises(ValueError, match="shot_bright_factor"):
        NoiseConfig(shot_rate_hz=1.0, shot_bright_factor=value)


def test_hot_pixels_fire_only_where_chosen():
    model, evs = static_simulator(NoiseConfig(hot_pixel_fraction=0.01, hot_pixel_rate_hz=100.0))
    x = np.concatenate([e.x for e in evs]).astype(np.int64)
    y = np.concatenate([e.y for e in evs]).astype(np.int64)
    assert set(np.unique(y * 50 + x)) <= set(model.hot_pixels.tolist())
    assert len(model.hot_pixels) == 20
    assert abs(len(x) - 100 * 2.0 * 20) < 5 * np.sqrt(4000)


def test_leak_makes_on_events_at_the_leak_rate():
    _, evs = static_simulator(NoiseConfig(leak_rate_hz=2.0, leak_rate_jitter=0.0))
    p = np.concatenate([e.p for e in evs])
    assert np.all(p == 1)
    assert len(p) == 2 * 2 * 40 * 50  # a drift of exactly C every 0.5 s at every pixel


def test_event_triggered_frames_sit_on_every_mth_event_and_the_sequence_stops_after_count():
    cfg = SimulationConfig(duration_s=3.0, camera=SMALL, render=RenderConfig(backend="homography"),
                           frames=FrameConfig(mode="events", every_events=500, count=6,
                                              tail_events=1000))
    rig = cfg.camera.rig()
    scene, traj = scene_and_trajectory(rig.event, 5, cfg.duration_s)
    th = ContrastThresholds.uniform(0.2, 0.2, rig.event.hw)
    seq = simulate_sequence(scene, traj, th, cfg, np.random.default_rng(0))
    ft = seq.frames["lr"].t_ns
    assert len(ft) == 6 and ft[0] == 0
    np.testing.assert_array_equal(ft[1:], seq.events.t_ns[np.arange(1, 6) * 500 - 1])
    # stopped at the first sample with 5 * 500 + 1000 events, long before 3 s
    assert len(seq.events) >= 3500
    last_step = seq.events.t_ns >= seq.sample_poses[-2, 0] * 1e9
    assert len(seq.events) - last_step.sum() < 3500
    assert seq.sample_poses[-1, 0] < 3.0


@pytest.mark.parametrize("mode", ["rate", "events"])
def test_a_frame_count_is_never_exceeded_by_one_long_step(mode):
    schedule = FrameSchedule(FrameConfig(mode=mode, every_events=10, rate_hz=100.0, count=3,
                                         tail_events=0), duration_s=1.0)
    n = 1000  # one step over 0.5 s: 50 frame periods and 100 event periods
    batch = Events(np.zeros(n, np.int16), np.zeros(n, np.int16),
                   np.linspace(1, 5e8, n).astype(np.int64), np.ones(n, np.int8), (1, 1))
    assert len(schedule.due(batch, int(5e8))) == 2  # with the one at t = 0: 3
    assert schedule.n_frames == 3 and schedule.done()
    assert schedule.due(batch, int(1e9)) == []


def test_leak_fires_at_its_rate_from_the_start():
    """A sensor has been leaking before the recording starts: in the first 0.25 s at 2 Hz,
    each pixel fires with probability 0.5 (a start at the reference would give none)."""
    _, evs = static_simulator(NoiseConfig(leak_rate_hz=2.0, leak_rate_jitter=0.0),
                              seconds=0.25, steps=25)
    n = sum(len(e) for e in evs)
    assert abs(n - 0.5 * 2000) < 5 * np.sqrt(2000 * 0.25)


def test_noise_events_obey_the_refractory_period():
    """Shot and hot-pixel events, like signal events, never come closer than the
    refractory period to a pixel's previous event, within a step and across steps."""
    hw, refractory = (20, 30), 2_000_000
    th = ContrastThresholds.uniform(0.2, 0.2, hw)
    cfg = NoiseConfig(shot_rate_hz=200.0, hot_pixel_fraction=0.05, hot_pixel_rate_hz=2000.0)
    model = NoiseModel(cfg, hw, np.random.default_rng(3))
    rng = np.random.default_rng(4)
    img = np.full(hw, 0.5, np.float32)
    sim = EventSimulator(img, 0, th, noise=model, refractory_ns=refractory)
    evs = []
    for k in range(1, 101):  # a flickering texture: signal and noise together
        img = (0.3 + 0.4 * rng.random(hw)).astype(np.float32)
        evs.append(sim.step(img, k * 1_000_000))
    ev = Events.concatenate(evs, hw)
    pix = ev.y.astype(np.int64) * hw[1] + ev.x
    order = np.lexsort((ev.t_ns, pix))
    same = pix[order][1:] == pix[order][:-1]
    gaps = np.diff(ev.t_ns[order])[same]
    assert len(gaps) > 1000 and gaps.min() >= refractory
    # without the refractory period the same noise crowds far closer
    model2 = NoiseModel(cfg, hw, np.random.default_rng(3))
    sim2 = EventSimulator(np.full(hw, 0.5, np.float32), 0, th, noise=model2)
    ev2 = Events.concatenate([sim2.step(np.full(hw, 0.5, np.float32), k * 1_000_000)
                              for k in range(1, 101)], hw)
    pix2 = ev2.y.astype(np.int64) * hw[1] + ev2.x
    order2 = np.lexsort((ev2.t_ns, pix2))
    gaps2 = np.diff(ev2.t_ns[order2])[pix2[order2][1:] == pix2[order2][:-1]]
    assert (gaps2 < refractory).mean() > 0.3


def test_random_start_spreads_pixels_between_their_levels():
    """With a random start a pixel's log intensity stands uniformly between C- below and
    C+ above its reference, so a rise of dL <= C+ + C- fires at a share dL / (C+ + C-) of
    the pixels."""
    hw, c_pos, c_neg = (60, 80), 0.2, 0.3
    th = ContrastThresholds.uniform(c_pos, c_neg, hw)
    phase = np.random.default_rng(0).random(hw)
    img0 = np.full(hw, 0.4, np.float32)
    for rise in (0.1, 0.25, 0.4):
        sim = EventSimulator(img0, 0, th, start_phase=phase)
        ev = sim.step_log(np.log(1e-3 + img0) + np.float32(rise), 1_000_000)
        fired = np.zeros(hw, bool)
        fired[ev.y, ev.x] = True
        assert np.all(ev.p == 1)
        expected = rise / (c_pos + c_neg)
        assert abs(fired.mean() - expected) < 5 * np.sqrt(expected * (1 - expected) / fired.size)
    # without it every pixel sits at its reference: nothing below C+
    sim = EventSimulator(img0, 0, th)
    assert len(sim.step_log(np.log(1e-3 + img0) + np.float32(0.15), 1_000_000)) == 0


def test_relative_mismatch_scales_with_each_threshold():
    cfg = ThresholdConfig(pos_range=(0.2, 0.2), neg_range=(0.6, 0.6), mismatch_relative=0.1)
    th = sample_thresholds(cfg, (200, 200), np.random.default_rng(0))
    assert abs(th.pos_map.std() / 0.02 - 1) < 0.03 and abs(th.neg_map.std() / 0.06 - 1) < 0.03
    assert abs(th.pos_map.mean() - 0.2) < 1e-3 and abs(th.neg_map.mean() - 0.6) < 2e-3
    both = sample_thresholds(ThresholdConfig(pos_range=(0.2, 0.2), neg_range=(0.2, 0.2),
                                             mismatch_std=0.01, mismatch_relative=0.1),
                             (200, 200), np.random.default_rng(0))
    assert abs(both.pos_map.std() / 0.03 - 1) < 0.03  # the two add: 0.01 + 10% of 0.2


def test_leak_keeps_its_rate_with_a_random_start():
    """A random start must not delay the leak: over 0.25 s at 2 Hz half the pixels fire,
    as without it (a start below the reference would give C+ / (C+ + C-) of that)."""
    hw = (40, 50)
    th = ContrastThresholds.uniform(0.2, 0.6, hw)
    model = NoiseModel(NoiseConfig(leak_rate_hz=2.0, leak_rate_jitter=0.0), hw,
                       np.random.default_rng(0))
    img = np.full(hw, 0.5, np.float32)
    sim = EventSimulator(img, 0, th, noise=model,
                         start_phase=np.random.default_rng(1).random(hw))
    n = sum(len(sim.step(img, k * 10_000_000)) for k in range(1, 26))
    assert abs(n - 0.5 * 2000) < 5 * np.sqrt(2000 * 0.25)
