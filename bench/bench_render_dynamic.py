"""Milliseconds per frame of dynamic scenes (K moving objects over the background plane):
the Mitsuba backend, the compiled exact reference renderer and its numpy oracle.

Run: .venv/bin/python bench/bench_render_dynamic.py [--frames N] [--reference-frames M]
A 2048x2048 photo background seen from 1 m and K objects (random smooth textures, soft
ellipse alphas, 0.2-0.5 m, some tilted, at 0.15-0.75 m) that move every frame; each renderer
draws warm-up frames (Mitsuba records its frozen kernels there, numba compiles), then N
(Mitsuba, reference) or M (numpy oracle) frames, R times; the table reports the median over
runs of each run's median time per frame. Sizes: 128x128 with 3x3 samples/pixel (the event
camera), 512x512 with 2x2 (the x4 HR camera).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

import cv2
import numpy as np
from skimage import data

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.objects import DynamicScene, ObjectPatch
from esim_lite.geometry.pose import Pose, so3_exp
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import LOOK_DOWN, BSplineTrajectory
from esim_lite.render.mitsuba import MitsubaRenderer
from esim_lite.render.reference import ReferenceRenderer


def random_object(rng: np.random.Generator) -> ObjectPatch:
    h, w = (int(v) for v in rng.integers(64, 256, 2))
    tex = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 2.0)
    tex = ((tex - tex.min()) / (tex.max() - tex.min()) * 0.9 + 0.05).astype(np.float32)
    alpha = np.zeros((h, w), np.float32)
    cv2.ellipse(alpha, (w // 2, h // 2), (w * 2 // 5, h * 2 // 5), float(rng.uniform(0, 180)),
                0, 360, 1.0, -1)
    alpha = np.clip(cv2.GaussianBlur(alpha, (0, 0), 1.0), 0, 1).astype(np.float32)
    size = rng.uniform(0.2, 0.5, 2)
    fixed = np.repeat(np.eye(3)[None], 4, 0)
    return ObjectPatch(PlanarScene(tex, float(size[0]), float(size[1])), alpha,
                       BSplineTrajectory(np.zeros((4, 3)), fixed, 1.0, 1.0))


def object_poses(rng: np.random.Generator, count: int, frames: int) -> list[list[Pose]]:
    """Per frame, the poses of ``count`` objects drifting and spinning a little per frame."""
    start = [(rng.normal(0, 0.4, 3), np.array([*rng.uniform(-0.35, 0.35, 2),
                                               rng.uniform(0.15, 0.75)])) for _ in range(count)]
    return [[Pose(so3_exp(w + 0.01 * f), t + 0.002 * f) for w, t in start]
            for f in range(frames)]


def run(renderer, poses: list[list[Pose]], warmup: int, repeats: int) -> float:
    camera = Pose(so3_exp(np.array([0.08, -0.06, 0.0])) @ LOOK_DOWN, np.array([0.03, -0.02, 1.0]))
    for frame in poses[:warmup]:
        renderer.render("lr", camera, frame)
    runs = []
    for _ in range(repeats):
        times = []
        for frame in poses[warmup:]:
            start = time.perf_counter()
            renderer.render("lr", camera, frame)
            times.append(time.perf_counter() - start)
        runs.append(statistics.median(times))
    return statistics.median(runs)


class _NumpyOracle:
    """The reference renderer's numpy path behind the ``render`` name :func:`run` calls."""

    def __init__(self, reference: ReferenceRenderer) -> None:
        self.render = reference.render_numpy


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=50)
    parser.add_argument("--reference-frames", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    print(f"# {' '.join(['python'] + sys.argv)}")
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cpus")
    photo = cv2.resize(data.camera().astype(np.float32) / 255, (2048, 2048),
                       interpolation=cv2.INTER_CUBIC).clip(0.01, 1)
    background = PlanarScene(photo, 3.0, 3.0)
    print("| size | samples/px | objects | mitsuba variant | mitsuba ms/frame "
          "| reference (compiled) ms/frame | numpy oracle ms/frame | reference / mitsuba |")
    print("|---|---|---|---|---|---|---|---|")
    for size, s in ((128, 3), (512, 2)):
        cam = Intrinsics.from_fov(size, size, 60.0)
        for count in (0, 4, 8):
            rng = np.random.default_rng(count)
            scene = DynamicScene(background, tuple(random_object(rng) for _ in range(count)))
            poses = object_poses(rng, count, 3 + args.frames)
            mitsuba = MitsubaRenderer({"lr": scene}, {"lr": cam}, {"lr": s})
            fast = run(mitsuba, poses, 3, args.repeats)
            variant = mitsuba.variant
            mitsuba.close()
            reference = ReferenceRenderer({"lr": scene}, {"lr": cam}, {"lr": s})
            compiled = run(reference, poses, 3, args.repeats)
            oracle = _NumpyOracle(reference)
            slow = run(oracle, poses[:1 + args.reference_frames], 1, args.repeats)
            print(f"| {size}x{size} | {s * s} | {count} | {variant} | {fast * 1e3:.2f} "
                  f"| {compiled * 1e3:.2f} | {slow * 1e3:.1f} | {compiled / fast:.2f} |",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
