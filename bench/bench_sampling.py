"""Adaptive sampling against fixed steps: events found, samples used, largest step change.

Run: .venv/bin/python bench/bench_sampling.py
A hand-shake-speed trajectory (2-3 m/s, 300-400 deg/s) over thin bright lines, 64x48
sensor, C = 0.2, 0.25 s, homography renderer. The 20 us grid is the reference.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from esim_lite.config import CameraConfig, FrameConfig, SimulationConfig
from esim_lite.events.sampling import SamplingConfig
from esim_lite.events.simulator import EventSimulator
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import TrajectoryConfig, plane_extent_covering, sample_trajectory
from esim_lite.render.renderer import RenderConfig
from esim_lite.sequence import simulate

FAST = TrajectoryConfig(speed_m_s=(2.0, 3.0), angular_speed_deg_s=(300, 400))


def stripes() -> np.ndarray:
    tex = np.full((1024, 1024), 0.05, np.float32)
    for k in range(0, 1024, 37):
        tex[:, k:k + 6] = 0.9
        tex[k:k + 6, :] = 0.9
    return tex


def run(sampling: SamplingConfig, seed: int = 4):
    cfg = SimulationConfig(duration_s=0.25, sampling=sampling, trajectory=FAST,
                           camera=CameraConfig(width=64, height=48, scales=(2,)),
                           frames=FrameConfig(mode="rate", rate_hz=50.0),
                           render=RenderConfig(backend="homography"))
    rig = cfg.camera.rig()
    traj = sample_trajectory(FAST, cfg.duration_s, rig.event, np.random.default_rng(seed))
    traj, w, h = plane_extent_covering(traj, rig.event, 1.0)
    th = ContrastThresholds.uniform(0.2, 0.2, rig.event.hw)
    changes = []
    original = EventSimulator.step_log

    def recording(sim, log_img, t_ns):
        changes.append(float(np.abs(log_img - sim.log_prev).max()))
        return original(sim, log_img, t_ns)

    EventSimulator.step_log = recording
    start = time.perf_counter()
    try:
        n = sum(len(c.events) for c in simulate(PlanarScene(stripes(), w, h), traj, th, cfg,
                                                np.random.default_rng(0)))
    finally:
        EventSimulator.step_log = original
    return n, len(changes), max(changes), time.perf_counter() - start


def main() -> int:
    print(f"# {' '.join(['python'] + sys.argv)}")
    print("| sampling | events | vs reference | samples | largest step change / (lambda C) |"
          " seconds |")
    print("|---|---|---|---|---|---|")
    cases = [("fixed 20 us (reference)", SamplingConfig(adaptive=False, max_step_s=2e-5)),
             ("adaptive, lambda = 0.5", SamplingConfig()),
             ("fixed 5 ms", SamplingConfig(adaptive=False, max_step_s=5e-3)),
             ("fixed 20 ms (50 Hz frames)", SamplingConfig(adaptive=False, max_step_s=2e-2))]
    ref = None
    for name, cfg in cases:
        n, samples, change, sec = run(cfg)
        ref = ref or n
        print(f"| {name} | {n:,} | {(n - ref) / ref:+.2%} | {samples:,} | {change / 0.1:.2f} |"
              f" {sec:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
