"""The photoreceptor low-pass: its closed forms, its events, and a whole sequence with it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from datagen.config import DatagenConfig
from datagen.sampling import sample_sequence
from datagen.textures import TextureSampler
from esim_lite.core.dataconf import ConfigError, load_config
from esim_lite.events.bandwidth import BandwidthConfig, PhotoreceptorLowPass
from esim_lite.events.simulator import EventSimulator
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.sequence import simulate_sequence

ROOT = Path(__file__).resolve().parents[2]
EPS = 1e-3


def test_time_constant_grows_in_the_dark_as_v2e_scales_it():
    cfg = BandwidthConfig(cutoff_hz=300.0)
    tau = cfg.time_constant(np.array([1.0, 0.5, 0.0]))
    assert tau[0] == pytest.approx(1 / (2 * math.pi * 300.0))
    o = cfg.dark_offset
    assert tau[2] / tau[0] == pytest.approx((1 + o) / o)  # ~13.8x slower in the dark
    assert tau[1] / tau[0] == pytest.approx((1 + o) / (0.5 + o))


@pytest.mark.parametrize(("i0", "i1"), [(0.05, 0.8), (0.9, 0.02)])
def test_a_step_of_light_approaches_exponentially_whatever_the_sample_times(i0, i1):
    """``y(t) = L1 + (L0 - L1) exp(-t / tau(I1))`` after a step at t = 0 (a 1 ns ramp),
    sampled at irregular times."""
    cfg = BandwidthConfig(cutoff_hz=200.0)
    l0, l1 = math.log(EPS + i0), math.log(EPS + i1)
    lp = PhotoreceptorLowPass(cfg, np.full((2, 3), l0, np.float32), EPS)
    lp.step(np.full((2, 3), l1, np.float32), 1e-9)
    tau = float(cfg.time_constant(np.array([np.exp(np.float32(l1)) - EPS]))[0])
    rng = np.random.default_rng(0)
    t = 1e-9
    for dt in rng.uniform(1e-5, 2e-3, 60):
        t += dt
        y = lp.step(np.full((2, 3), l1, np.float32), dt)
        expected = np.float32(l1) + (l0 - np.float32(l1)) * math.exp(-t / tau)
        np.testing.assert_allclose(y, expected, atol=2e-6)
    assert t > 5 * tau  # the whole approach was covered


def test_a_linear_input_gives_the_same_state_in_one_step_or_many():
    """The first-order-hold update is the exact solution for a linear input, so a ramp
    taken in one step or in 100 ends in the same state (constant tau: a huge offset)."""
    cfg = BandwidthConfig(cutoff_hz=150.0, dark_offset=1e9)
    start = np.full((1, 4), -2.0, np.float32)
    end = np.array([[-2.0, -1.0, 0.0, -3.5]], np.float32)
    one = PhotoreceptorLowPass(cfg, start, EPS)
    many = PhotoreceptorLowPass(cfg, start, EPS)
    a = one.step(end, 4e-3)
    for k in range(1, 101):
        b = many.step(start + (end - start) * np.float32(k / 100), 4e-5)
    np.testing.assert_allclose(a, b, atol=2e-6)
    assert np.abs(a - end).max() > 0.1  # the filter lags the ramp


def test_max_step_keeps_the_relaxation_within_the_budget():
    cfg = BandwidthConfig(cutoff_hz=300.0)
    lp = PhotoreceptorLowPass(cfg, np.log(EPS + np.linspace(0.01, 1, 12, dtype=np.float32))
                              .reshape(3, 4), EPS)
    target = np.log(EPS + np.linspace(1, 0.01, 12, dtype=np.float32)).reshape(3, 4)
    lp.step(target, 1e-6)
    for _ in range(20):
        dt = lp.max_step(0.06)
        before = lp.state.copy()
        lp.step(target, dt if math.isfinite(dt) else 1e-3)
        if math.isfinite(dt):
            assert np.abs(lp.state - before).max() <= 0.06 * (1 + 1e-9)
            assert np.abs(lp.state - before).max() >= 0.06 * (1 - 1e-6)  # and is tight


def test_step_events_fire_at_the_closed_form_crossing_times():
    """A pixel stepping up by 5.5 C: the noise-free sensor fires its 5 ON events at once;
    with the low-pass, at ``t_k = tau ln(dL / (dL - k C))``, as sampled every 20 us."""
    c = 0.2
    th = ContrastThresholds.uniform(c, c, (1, 1))
    i0 = np.full((1, 1), 0.05, np.float32)
    l0 = math.log(EPS + 0.05)
    i1 = np.full((1, 1), np.float32(math.exp(l0 + 5.5 * c) - EPS), np.float32)
    cfg = BandwidthConfig(cutoff_hz=100.0)
    for bandwidth in (None, cfg):
        sim = EventSimulator(i0, 0, th, log_eps=EPS, bandwidth=bandwidth)
        ts = [sim.step(i1, 1)]
        ts += [sim.step(i1, k * 20_000) for k in range(1, 1500)]
        t = np.concatenate([e.t_ns for e in ts])
        assert len(t) == 5
        if bandwidth is None:
            assert t.max() <= 1
        else:
            tau = float(cfg.time_constant(i1)[0, 0])
            expected = tau * np.log(5.5 / (5.5 - np.arange(1, 6)))
            np.testing.assert_allclose(t * 1e-9, expected, atol=20e-6, rtol=0.01)


def test_a_sequence_with_the_low_pass_lags_and_keeps_its_events():
    """The tiny dataset's sequence with a 60 Hz photoreceptor: its events come later than
    the ideal sensor's (the trails), about as many of them."""
    cfg = load_config(DatagenConfig, ROOT / "configs" / "datagen_tiny.yaml",
                      ["simulation.frames.count=null", "simulation.duration_s=0.3"])
    slow = load_config(DatagenConfig, ROOT / "configs" / "datagen_tiny.yaml",
                       ["simulation.frames.count=null", "simulation.duration_s=0.3",
                        "simulation.events.bandwidth.cutoff_hz=60"])
    runs = []
    for c in (cfg, slow):
        spec = sample_sequence(c.simulation, TextureSampler(c.textures), 3, 0)
        runs.append(simulate_sequence(spec.scene, spec.trajectory, spec.thresholds,
                                      c.simulation, spec.noise_rng))
    ideal, lagged = runs
    assert 0.7 * len(ideal.events) <= len(lagged.events) <= 1.1 * len(ideal.events)
    first_ideal = ideal.events.t_ns[: len(ideal.events) // 10].mean()
    first_lagged = lagged.events.t_ns[: len(lagged.events) // 10].mean()
    assert first_lagged > first_ideal


@pytest.mark.parametrize("value", ["-5", ".nan"])
def test_a_bad_cutoff_fails_at_load_naming_the_key(value):
    with pytest.raises(ConfigError, match="bandwidth.cutoff_hz"):
        load_config(DatagenConfig, None, [f"simulation.events.bandwidth.cutoff_hz={value}"])


def test_max_step_holds_each_pixel_to_the_budget_of_its_own_direction():
    """Rising pixels move by at most their ``budget``, falling ones by their
    ``fall_budget``, per pixel; a scalar budget is the same bound for both."""
    cfg = BandwidthConfig(cutoff_hz=300.0)
    start = np.log(EPS + np.linspace(0.01, 1, 12, dtype=np.float32)).reshape(3, 4)
    target = np.log(EPS + np.linspace(1, 0.01, 12, dtype=np.float32)).reshape(3, 4)
    rise = np.linspace(0.08, 0.2, 12).reshape(3, 4)
    fall = np.linspace(0.3, 0.1, 12).reshape(3, 4)
    lp = PhotoreceptorLowPass(cfg, start, EPS)
    lp.step(target, 1e-6)
    up = lp.input > lp.state
    assert up.any() and (~up).any()
    scalar = lp.max_step(0.06)
    assert scalar == lp.max_step(np.full((3, 4), 0.06), np.full((3, 4), 0.06))
    dt = lp.max_step(rise, fall)
    assert dt > scalar
    before = lp.state.copy()
    lp.step(target, dt)
    moved = np.abs(lp.state - before)
    allowed = np.where(up, rise, fall)
    assert np.all(moved <= allowed * (1 + 1e-9))
    assert np.any(moved >= allowed * (1 - 1e-6))  # and is tight


def test_simulator_max_step_uses_each_polarity_threshold():
    """A step up of the light: the low-passed signal rises, so ``C+`` (not the smaller
    ``C-``) sets the bound on its relaxation."""
    hw = (2, 3)
    i0 = np.full(hw, 0.05, np.float32)
    i1 = np.full(hw, 0.8, np.float32)
    cfg = BandwidthConfig(cutoff_hz=100.0)
    wide = EventSimulator(i0, 0, ContrastThresholds.uniform(0.6, 0.15, hw), log_eps=EPS,
                          bandwidth=cfg)
    narrow = EventSimulator(i0, 0, ContrastThresholds.uniform(0.15, 0.6, hw), log_eps=EPS,
                            bandwidth=cfg)
    for sim in (wide, narrow):
        sim.step(i1, 1000)
    lp = narrow.lowpass
    assert narrow.max_step(0.5) == lp.max_step(0.5 * 0.15)
    assert wide.max_step(0.5) == lp.max_step(0.5 * 0.6) > narrow.max_step(0.5)
