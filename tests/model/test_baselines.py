"""The classical baselines against closed-form answers and against the simulator."""

from __future__ import annotations

import numpy as np
import pytest

from esim_lite.config import CameraConfig, SimulationConfig
from esim_lite.core.events import Events
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.render.renderer import RenderConfig
from esim_lite.sequence import simulate_sequence
from model.inference.baselines import EventFilter, FilterConfig
from tests.conftest import scene_and_trajectory


def one_pixel(t_ns, p):
    n = len(t_ns)
    return Events(np.zeros(n, np.int16), np.zeros(n, np.int16), np.asarray(t_ns, np.int64),
                  np.asarray(p, np.int8), (1, 1))


def test_high_pass_filter_decays_exponentially():
    f = EventFilter("hf", (1, 1), FilterConfig(contrast=0.2, cutoff_hz=2.0))
    f.add_events(one_pixel([0, 100_000_000], [1, 1]))
    alpha = 2 * np.pi * 2.0
    expected = 0.2 * np.exp(-alpha * 0.1) + 0.2  # first event decayed for 0.1 s, plus one
    assert f.log_image(100_000_000)[0, 0] == pytest.approx(expected)
    assert f.log_image(600_000_000)[0, 0] == pytest.approx(expected * np.exp(-alpha * 0.5))


def test_complementary_filter_relaxes_to_the_frame():
    cfg = FilterConfig(contrast=0.2, cutoff_hz=1.0, log_eps=1e-3)
    f = EventFilter("complementary", (1, 1), cfg)
    f.add_frame(np.full((1, 1), 0.5, np.float32), 0)
    f.add_events(one_pixel([0], [1]))
    base = np.log(0.501)
    assert f.log_image(0)[0, 0] == pytest.approx(base + 0.2)
    assert f.log_image(10**9)[0, 0] == pytest.approx(base + 0.2 * np.exp(-2 * np.pi))
    assert f.image(10**10)[0, 0] == pytest.approx(0.5, abs=1e-4)


def test_direct_integration_of_simulated_events_recovers_the_log_change():
    """With the simulator's own threshold, integrating its events gives back
    L(t) - L(0) to within one threshold at every pixel (the event model's invariant) at
    render-sample times; frames fall between samples, where the rendered L may leave the
    straight line that stamps the events by at most one step's change, lambda C."""
    cfg = SimulationConfig(duration_s=0.2, camera=CameraConfig(width=64, height=48),
                           render=RenderConfig(backend="homography"))
    rig = cfg.camera.rig()
    scene, traj = scene_and_trajectory(rig.event, 3, cfg.duration_s)
    th = ContrastThresholds.uniform(0.2, 0.2, rig.event.hw)
    seq = simulate_sequence(scene, traj, th, cfg, np.random.default_rng(0))
    lr = seq.frames["lr"]
    f = EventFilter("direct", rig.event.hw, FilterConfig(contrast=0.2))
    f.add_events(seq.events.slice(0, int(np.searchsorted(seq.events.t_ns, lr.t_ns[-1], "right"))))
    change = np.log(1e-3 + lr.intensity[-1].astype(np.float64)) - np.log(1e-3 + lr.intensity[0])
    error = np.abs(f.log_image(int(lr.t_ns[-1])) - change)
    lam = cfg.sampling.contrast_fraction
    assert len(seq.events) > 5000 and error.max() < 0.2 + lam * 0.2
