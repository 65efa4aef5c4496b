"""The event model against analytic answers and against two independent implementations."""

from __future__ import annotations

import numpy as np
import pytest

from esim_lite.events.simulator import EventSimulator
from esim_lite.events.thresholds import ContrastThresholds

KERNELS = ["numba", "numpy", "python", "torch"]


def pixel_sim(level: float, c_pos: float, c_neg: float, kernel: str = "numba",
              refractory_ns: int = 0) -> EventSimulator:
    """A 1x1 sensor whose log intensity starts at ``level`` at t = 0."""
    th = ContrastThresholds.uniform(c_pos, c_neg, (1, 1))
    sim = EventSimulator(np.ones((1, 1), np.float32), 0, th, refractory_ns=refractory_ns,
                         kernel=kernel)
    sim.log_prev = np.full((1, 1), level, np.float32)
    sim.ref[:] = sim.log_prev
    return sim


def feed(sim: EventSimulator, levels, times):
    out = [sim.step_log(np.full((1, 1), v, np.float32), t) for v, t in zip(levels, times)]
    return np.concatenate([e.t_ns for e in out]), np.concatenate([e.p for e in out])


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("sign", [1, -1])
def test_ramp_gives_floor_d_over_c_events_at_analytic_times(kernel, sign):
    c, d, dur = 0.15, 1.0, 10_000_000
    sim = pixel_sim(0.0, c, c, kernel)
    t, p = feed(sim, [sign * d], [dur])
    k = np.arange(1, int(np.floor(d / c)) + 1)
    assert len(t) == 6 == int(np.floor(d / c))
    assert np.all(p == sign)
    np.testing.assert_allclose(t, k * c / d * dur, atol=1)


@pytest.mark.parametrize("kernel", KERNELS)
def test_piecewise_sampling_of_a_ramp_gives_the_same_events(kernel):
    """Linear interpolation is exact for a linear signal, however it is sampled."""
    c, dur = 0.2, 1_000_000
    times = np.array([37_000, 210_000, 211_000, 640_000, 999_999, dur])
    levels = 1.3 * times / dur
    t, p = feed(pixel_sim(0.0, c, c, kernel), levels.astype(np.float32), times)
    expected = np.arange(1, 7) * c / 1.3 * dur
    assert len(t) == 6 and np.all(p == 1)
    np.testing.assert_allclose(t, expected, atol=2)


@pytest.mark.parametrize("kernel", KERNELS)
def test_brightening_and_darkening_are_symmetric(kernel):
    up = feed(pixel_sim(0.0, 0.3, 0.3, kernel), [1.0], [1_000_000])
    down = feed(pixel_sim(0.0, 0.3, 0.3, kernel), [-1.0], [1_000_000])
    np.testing.assert_array_equal(up[0], down[0])
    np.testing.assert_array_equal(up[1], -down[1])


@pytest.mark.parametrize("kernel", KERNELS)
def test_exact_tie_fires_once_at_the_sample_time(kernel):
    """Tie rule: a change of exactly C fires one event, stamped at t1. In float32,
    0.7 - 0.6 = 0.099999964 < 0.1, which a strict comparison would miss."""
    sim = pixel_sim(np.float32(0.6), 0.1, 0.1, kernel)
    t, p = feed(sim, [np.float32(0.7)], [500])
    assert t.tolist() == [500] and p.tolist() == [1]
    assert np.isclose(sim.ref[0, 0], 0.7, atol=1e-6)
    t, p = feed(sim, [np.float32(0.6)], [1000])
    assert t.tolist() == [1000] and p.tolist() == [-1]


@pytest.mark.parametrize("kernel", KERNELS)
def test_change_just_below_threshold_fires_nothing(kernel):
    t, _ = feed(pixel_sim(0.0, 0.1, 0.1, kernel), [np.float32(0.0999)], [1000])
    assert len(t) == 0


@pytest.mark.parametrize("kernel", KERNELS)
def test_reference_does_not_drift_over_many_exact_cycles(kernel):
    """10,000 cycles 0 -> 1.3 -> 0 with C+ = 0.13, C- = 0.10: every cycle is an exact tie
    (10 C+ = 13 C- = 1.3). A reference accumulated by float32 additions drifts by ~1e-7 a
    cycle and starts losing tie events within a few hundred cycles."""
    cycles = 10_000
    sim = pixel_sim(0.0, 0.13, 0.10, kernel)
    levels = np.tile(np.array([1.3, 0.0], np.float32), cycles)
    t, p = feed(sim, levels, 1000 * np.arange(1, 2 * cycles + 1))
    assert int((p > 0).sum()) == 10 * cycles
    assert int((p < 0).sum()) == 13 * cycles
    assert abs(sim.ref[0, 0]) < 1e-9


@pytest.mark.parametrize("kernel", KERNELS)
def test_refractory_period_drops_exactly_the_right_events(kernel):
    """Crossings every 1 ms, refractory 2.5 ms: ESIM keeps 1, 4, 7, 10 ms (a dropped
    event does not restart the refractory period) and still moves the reference."""
    sim = pixel_sim(0.0, 0.1, 0.1, kernel, refractory_ns=2_500_000)
    t, p = feed(sim, [np.float32(1.0)], [10_000_000])
    assert t.tolist() == [1_000_000, 4_000_000, 7_000_000, 10_000_000]
    assert np.isclose(sim.ref[0, 0], 1.0, atol=1e-6)
    # refractory exactly equal to the spacing keeps every event
    t, _ = feed(pixel_sim(0.0, 0.1, 0.1, kernel, refractory_ns=1_000_000),
                [np.float32(1.0)], [10_000_000])
    assert len(t) == 10


@pytest.mark.parametrize("refractory_ns", [0, 150_000])
def test_four_implementations_agree_bit_for_bit(refractory_ns):
    rng = np.random.default_rng(7)
    h, w, n = 24, 31, 25
    frames = np.cumsum(rng.normal(0, 0.2, (n, h, w)), axis=0).astype(np.float32)
    th = ContrastThresholds(0.2, 0.3, np.maximum(0.2 + 0.05 * rng.standard_normal((h, w)), .01),
                            np.maximum(0.3 + 0.05 * rng.standard_normal((h, w)), .01))
    times = np.cumsum(rng.integers(1, 200_000, n))
    outs = {}
    for kernel in KERNELS:
        sim = EventSimulator(np.ones((h, w), np.float32), 0, th, refractory_ns=refractory_ns,
                             kernel=kernel)
        sim.log_prev = frames[0].copy()
        sim.ref[:] = frames[0]
        evs = [sim.step_log(f, t) for f, t in zip(frames[1:], times[1:])]
        outs[kernel] = (np.concatenate([e.x for e in evs]), np.concatenate([e.y for e in evs]),
                        np.concatenate([e.t_ns for e in evs]), np.concatenate([e.p for e in evs]),
                        sim.ref.copy(), sim.last_t.copy())
    assert len(outs["numba"][0]) > 1000
    for kernel in ("numpy", "python", "torch"):
        for a, b in zip(outs["numba"], outs[kernel]):
            np.testing.assert_array_equal(a, b)


def test_events_are_sorted_and_typed():
    rng = np.random.default_rng(0)
    th = ContrastThresholds.uniform(0.1, 0.1, (16, 16))
    sim = EventSimulator(rng.random((16, 16)).astype(np.float32), 0, th)
    ev = sim.step(rng.random((16, 16)).astype(np.float32), 1_000_000)
    assert len(ev) > 100 and ev.is_sorted()
    assert (ev.x.dtype, ev.y.dtype, ev.t_ns.dtype, ev.p.dtype) == (
        np.int16, np.int16, np.int64, np.int8)
    assert set(np.unique(ev.p)) <= {-1, 1}
    ev.validate()


def test_samples_must_move_forward():
    sim = pixel_sim(0.0, 0.1, 0.1)
    sim.step_log(np.zeros((1, 1), np.float32), 10)
    with pytest.raises(ValueError, match="forward in time"):
        sim.step_log(np.zeros((1, 1), np.float32), 10)


@pytest.mark.parametrize("span", [1, 255, 256, 70_000, 2**40])
def test_time_order_is_a_stable_sort(span):
    from esim_lite.events.kernel import time_order

    rng = np.random.default_rng(span)
    t0 = 10**12
    t = t0 + rng.integers(0, span + 1, 5000) // max(1, span // 50) * max(1, span // 50)
    t = np.minimum(t, t0 + span)
    assert len(np.unique(t)) < len(t)  # many ties
    np.testing.assert_array_equal(time_order(t, len(t), t0, span),
                                  np.argsort(t, kind="stable"))
    assert len(time_order(t, 0, t0, span)) == 0


def test_simultaneous_events_come_out_by_row_column_then_emission():
    """Linear ramps of whole multiples of C cross their levels at shared fractions of the
    step, so many events of different pixels have the same time: the compiled kernel's own
    time order must equal the reference order np.lexsort((x, y, t)) of the numpy kernel."""
    rng = np.random.default_rng(3)
    h, w = 9, 13
    th = ContrastThresholds.uniform(0.25, 0.25, (h, w))
    k = rng.integers(-4, 5, (h, w)).astype(np.float32)
    outs = []
    for kernel in ("numba", "numpy", "torch"):
        sim = EventSimulator(np.ones((h, w), np.float32), 0, th, kernel=kernel)
        sim.log_prev = np.zeros((h, w), np.float32)
        sim.ref[:] = 0
        outs.append(sim.step_log(k * np.float32(0.25), 1_200))
    a = outs[0]
    assert len(a) == np.abs(k).sum() and len(np.unique(a.t_ns)) < len(a) // 4
    for b in outs[1:]:
        for name in ("x", "y", "t_ns", "p"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


@pytest.mark.parametrize("h, w", [(64, 64), (61, 67)])
def test_a_step_with_more_events_than_the_buffers_matches_the_reference(h, w):
    """The compiled kernel starts with 4,096-event buffers: a step of ~20,000 events must
    grow them and resume where it stopped, losing nothing (against the numpy kernel, bit for
    bit; 61 x 67 pixels do not fill whole 8-pixel words)."""
    rng = np.random.default_rng(5)
    th = ContrastThresholds.uniform(0.2, 0.2, (h, w))
    start = rng.normal(0, 0.05, (h, w)).astype(np.float32)
    jump = start + rng.choice([-1.0, 1.0], (h, w)).astype(np.float32) * np.float32(1.05)
    outs = []
    for kernel in ("numba", "numpy"):
        sim = EventSimulator(np.ones((h, w), np.float32), 0, th, kernel=kernel)
        sim.log_prev = start.copy()
        sim.ref[:] = start
        outs.append([sim.step_log(jump, 50_000), sim.step_log(start, 90_000)])
    assert len(outs[0][0]) == 5 * h * w > 4096
    for a, b in zip(*outs):
        for name in ("x", "y", "t_ns", "p"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
