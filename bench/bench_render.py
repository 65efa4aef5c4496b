"""Frames per second of each render backend at the event (128x128) and HR (512x512) sizes.

Run: .venv/bin/python bench/bench_render.py [--frames N]
Each backend renders N frames along a random trajectory over a 2048x2048 photo texture
(after warm-up frames that compile Mitsuba's kernel), R times; the table reports the
median over runs of each run's median time per frame (this VM's timings vary run to run).
Default supersampling: 3x3 samples/pixel for 128x128 (the event camera), 2x2 for 512x512
(the x4 HR camera, rendered only at frame times); cheaper settings shown for comparison.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time

import cv2
import numpy as np
from skimage import data

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import TrajectoryConfig, plane_extent_covering, sample_trajectory
from esim_lite.render.renderer import RenderConfig, make_renderer


def run(backend: str, size: int, supersample: int, frames: int, repeats: int,
        variant: str = "auto"):
    cam = Intrinsics.from_fov(size, size, 60.0)
    rng = np.random.default_rng(0)
    traj = sample_trajectory(TrajectoryConfig(), 1.0, cam, rng)
    tex = cv2.resize(data.camera().astype(np.float32) / 255, (2048, 2048),
                     interpolation=cv2.INTER_CUBIC).clip(0.01, 1)
    traj, w, h = plane_extent_covering(traj, cam, 1.0)
    cfg = RenderConfig(backend=backend, supersample_lr=supersample, mitsuba_variant=variant)
    renderer = make_renderer(PlanarScene(tex, w, h), {"lr": cam}, cfg)
    poses = [traj.pose(t) for t in np.linspace(0, 1, frames + 1)]
    for pose in poses[:3]:
        renderer.render("lr", pose)
    runs = []
    for _ in range(repeats):
        times = []
        for pose in poses[1:]:
            start = time.perf_counter()
            renderer.render("lr", pose)
            times.append(time.perf_counter() - start)
        runs.append(statistics.median(times))
    name = getattr(renderer, "variant", "")
    renderer.close()
    return statistics.median(runs), name


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--scalar", action="store_true", help="also time Mitsuba scalar_rgb")
    args = parser.parse_args(argv)
    print(f"# {' '.join(['python'] + sys.argv)}")
    print(f"# {platform.processor() or platform.machine()}, {__import__('os').cpu_count()} cpus")
    print("| backend | variant | size | samples/px | ms/frame | frames/s |")
    print("|---|---|---|---|---|---|")
    cases = [(b, size, ss) for b in ("homography", "mitsuba")
             for size, ss in ((128, 3), (128, 2), (128, 1), (512, 2), (512, 1))]
    if args.scalar:
        cases += [("mitsuba-scalar", 128, 3), ("mitsuba-scalar", 512, 2)]
    for backend, size, ss in cases:
        variant = "scalar_rgb" if backend.endswith("scalar") else "auto"
        sec, name = run(backend.split("-")[0], size, ss, args.frames, args.repeats, variant)
        print(f"| {backend.split('-')[0]} | {name or '-'} | {size}x{size} | {ss * ss} | "
              f"{sec * 1e3:.2f} | {1 / sec:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
