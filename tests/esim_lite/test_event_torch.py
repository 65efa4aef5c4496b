"""The torch event camera against the compiled kernel's simulator (bit for bit), on the CPU
and, where torch sees one, on a GPU."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from esim_lite.events.simulator import EventSimulator
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.events.torch_kernel import TorchEventCamera, default_device, torch_step

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def random_video(seed: int, n: int, h: int, w: int, sigma: float):
    rng = np.random.default_rng(seed)
    logs = np.cumsum(rng.normal(0, sigma, (n, h, w)), axis=0).astype(np.float32)
    th = ContrastThresholds(0.2, 0.3, np.maximum(0.2 + 0.05 * rng.standard_normal((h, w)), .01),
                            np.maximum(0.3 + 0.05 * rng.standard_normal((h, w)), .01))
    return logs, np.cumsum(rng.integers(1, 200_000, n)), th


def numba_stream(logs, times, th, refractory_ns):
    sim = EventSimulator(np.ones(logs.shape[1:], np.float32), int(times[0]), th,
                         refractory_ns=refractory_ns)
    sim.log_prev = logs[0].copy()
    sim.ref[:] = logs[0]
    evs = [sim.step_log(f, t) for f, t in zip(logs[1:], times[1:])]
    return [np.concatenate([getattr(e, n) for e in evs]) for n in ("x", "y", "t_ns", "p")], sim


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("refractory_ns", [0, 150_000])
@pytest.mark.parametrize("sigma", [0.05, 0.4])  # sparse, and several events per pixel
def test_camera_gives_the_simulators_events_bit_for_bit(device, refractory_ns, sigma):
    logs, times, th = random_video(11, 30, 23, 37, sigma)
    want, sim = numba_stream(logs, times, th, refractory_ns)
    cam = TorchEventCamera(th, refractory_ns=refractory_ns, device=device)
    # in three calls of different lengths: the state carries over between calls
    got = [cam.simulate(logs[a:b], times[a:b]) for a, b in ((0, 1), (1, 12), (12, 30))]
    assert len(got[0]) == 0
    density = len(want[0]) / ((len(logs) - 1) * logs[0].size)  # events per pixel per step
    assert sum(len(e) for e in got) == len(want[0]) and density > (0.02 if sigma < .1 else .3)
    for name, w in zip(("x", "y", "t_ns", "p"), want):
        np.testing.assert_array_equal(np.concatenate([getattr(e, name) for e in got]), w)
    np.testing.assert_array_equal(cam.ref.cpu().numpy(), sim.ref)
    np.testing.assert_array_equal(cam.last_t.cpu().numpy(), sim.last_t)
    if refractory_ns:
        assert (cam.last_t.cpu().numpy() > 0).any()


def test_ramp_gives_floor_d_over_c_events_at_analytic_times():
    """A log-intensity ramp of 1.05 over 1 ms with C = 0.2: 5 ON events at the crossings
    k * 0.2 / 1.05 ms (rounded to the ns)."""
    th = ContrastThresholds.uniform(0.2, 0.2, (1, 1))
    cam = TorchEventCamera(th, device="cpu")
    ev = cam.simulate(np.array([[[0.0]], [[1.05]]], np.float32), [0, 1_000_000])
    want = np.floor(np.arange(1, 6) * 0.2 / np.float64(np.float32(1.05)) * 1e6 + 0.5)
    np.testing.assert_array_equal(ev.t_ns, want.astype(np.int64))
    assert (ev.p == 1).all() and ev.is_sorted()


def test_step_leaves_quiet_pixels_alone_and_returns_typed_empties():
    ref = torch.zeros(4, 5, dtype=torch.float64)
    last = torch.full((4, 5), -7, dtype=torch.int64)
    c = torch.full((4, 5), 0.2, dtype=torch.float64)
    l0 = torch.zeros(4, 5)
    out = torch_step(l0, l0 + 0.1, ref, last, c, c, 0, 100, 0, 1e-6)
    assert [v.dtype for v in out] == [torch.int16, torch.int16, torch.int64, torch.int8]
    assert all(v.numel() == 0 for v in out)
    assert (ref == 0).all() and (last == -7).all()


def test_bad_input_is_refused_with_the_shapes():
    th = ContrastThresholds.uniform(0.2, 0.2, (4, 4))
    cam = TorchEventCamera(th, device="cpu")
    with pytest.raises(ValueError, match=r"\(T, 4, 4\)"):
        cam.simulate(np.zeros((2, 4, 5), np.float32), [0, 1])
    with pytest.raises(ValueError, match="2 images but 3 timestamps"):
        cam.simulate(np.zeros((2, 4, 4), np.float32), [0, 1, 2])
    cam.simulate(np.zeros((2, 4, 4), np.float32), [0, 10])
    with pytest.raises(ValueError, match="forward in time"):
        cam.simulate(np.zeros((1, 4, 4), np.float32), [10])


def test_default_device_follows_cuda():
    assert default_device().type == ("cuda" if torch.cuda.is_available() else "cpu")
