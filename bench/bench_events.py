"""Event generation throughput: compiled kernel vs per-frame numpy vs a per-pixel Python loop.

Run: .venv/bin/python bench/bench_events.py [--frames N] [--repeats R]
Frames are rendered first (homography, 128x128, photo texture, a default-speed trajectory
sampled at a fixed step chosen so that about 0.02 events fire per pixel per step) and kept
in memory as float32 log images; only event generation is timed. Two figures per
implementation: the bare kernel (state update + crossings) and the full
``EventSimulator.step_log`` (kernel + time sort + Events record), one core. The Python
loop runs on the first 30 frames only (it is ~10^3 times slower).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import cv2
import numpy as np
from skimage import data

from esim_lite.camera import Intrinsics
from esim_lite.event_kernel import NEVER, TIE_TOL
from esim_lite.event_reference import numpy_step, python_step
from esim_lite.renderer import RenderConfig, make_renderer
from esim_lite.scene import PlanarScene
from esim_lite.simulator import EventSimulator, _NumbaKernel, log_intensity
from esim_lite.thresholds import ContrastThresholds
from esim_lite.trajectory import TrajectoryConfig, plane_extent_covering, sample_trajectory

THRESHOLD = 0.2


def make_frames(n: int, step_s: float) -> np.ndarray:
    cam = Intrinsics.from_fov(128, 128, 60.0)
    traj = sample_trajectory(TrajectoryConfig(), 2.0, cam, np.random.default_rng(1))
    tex = cv2.resize(data.camera().astype(np.float32) / 255, (1024, 1024)).clip(0.01, 1)
    traj, w, h = plane_extent_covering(traj, cam, 1.0)
    r = make_renderer(PlanarScene(cv2.GaussianBlur(tex, (0, 0), 1.0), w, h), {"lr": cam},
                      RenderConfig(backend="homography"))
    times = np.minimum(np.arange(n + 1) * step_s, traj.duration_s)
    return np.stack([log_intensity(r.render("lr", traj.pose(t)), 1e-3) for t in times])


def time_kernel(kernel, frames: np.ndarray, repeats: int) -> tuple[float, int]:
    """Median seconds for all steps of the bare kernel, and the number of events."""
    th = ContrastThresholds.uniform(THRESHOLD, THRESHOLD, frames.shape[1:])
    runs, n_events = [], 0
    for _ in range(repeats):
        ref = frames[0].astype(np.float64)
        last = np.full(frames.shape[1:], NEVER, np.int64)
        n_events = 0
        start = time.perf_counter()
        for k in range(1, len(frames)):
            out = kernel(frames[k - 1], frames[k], ref, last, th.pos_map, th.neg_map,
                         (k - 1) * 1000, k * 1000, 0, TIE_TOL)
            n_events += len(out[0])
        runs.append(time.perf_counter() - start)
    return statistics.median(runs), n_events


def time_simulator(kind: str, frames: np.ndarray, repeats: int) -> float:
    th = ContrastThresholds.uniform(THRESHOLD, THRESHOLD, frames.shape[1:])
    runs = []
    for _ in range(repeats):
        sim = EventSimulator(np.ones(frames.shape[1:], np.float32), 0, th, kernel=kind)
        sim.log_prev = frames[0].copy()
        sim.ref[:] = frames[0]
        start = time.perf_counter()
        for k in range(1, len(frames)):
            sim.step_log(frames[k], k * 1000)
        runs.append(time.perf_counter() - start)
    return statistics.median(runs)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--step-ms", type=float, default=0.8,
                        help="time between rendered frames (sets events per pixel per step)")
    args = parser.parse_args(argv)
    frames = make_frames(args.frames, args.step_ms * 1e-3)
    numba_kernel = _NumbaKernel()
    time_kernel(numba_kernel, frames[:3], 1)  # compile
    px = frames.shape[1] * frames.shape[2]
    print(f"# {' '.join(['python'] + sys.argv)}")
    rows = []
    for name, kernel, kind, n in (("numba (compiled)", numba_kernel, "numba", len(frames)),
                                  ("numpy per frame", numpy_step, "numpy", len(frames)),
                                  ("python per-pixel loop", python_step, "python", 31)):
        reps = args.repeats if kind != "python" else 1
        sec, n_ev = time_kernel(kernel, frames[:n], reps)
        full = time_simulator(kind, frames[:n], reps)
        updates = px * (n - 1)
        rows.append((name, updates / sec, n_ev / sec, updates / full, n_ev / updates))
    print(f"# 128x128, {args.frames} steps of {args.step_ms} ms, C = {THRESHOLD}, "
          f"{rows[0][4]:.4f} events per pixel per step, one core")
    print("| implementation | kernel Mpx-updates/s | kernel Mevents/s | full step Mpx-updates/s |"
          " speedup vs python |")
    print("|---|---|---|---|---|")
    for name, ups, eps, full, _ in rows:
        print(f"| {name} | {ups / 1e6:.1f} | {eps / 1e6:.2f} | {full / 1e6:.1f} | "
              f"{ups / rows[-1][1]:.0f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
