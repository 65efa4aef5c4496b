"""How many events come from texture aliasing, by event-camera supersampling.

Run: .venv/bin/python bench/bench_antialias.py [--n-seq N]
The first 0.5 s of sequences 0..N-1 of the default dataset (128x128, photo textures,
homography renderer), rendered with s x s samples per pixel; 8x8 stands in for the exact
pixel integral. "gauss" is the rejected alternative: 2x2 samples of a texture blurred by a
Gaussian of 0.5 sqrt(m^2 - 1) texels (m = median texels per sample), the classic band-limit
for point sampling, which removes real detail and with it real events.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import cv2
import numpy as np

from datagen.config import DatagenConfig
from datagen.sampling import sample_sequence
from datagen.textures import TextureSampler
from esim_lite.geometry.scene import PlanarScene
from esim_lite.render.antialias import texels_per_sample
from esim_lite.render.homography import HomographyRenderer
from esim_lite.sequence import simulate


def events(config: DatagenConfig, index: int, supersample: int, gauss: bool = False) -> int:
    render = dataclasses.replace(config.simulation.render, backend="homography")
    sim = dataclasses.replace(config.simulation, render=render, duration_s=0.5,
                              frames=dataclasses.replace(config.simulation.frames, count=None))
    spec = sample_sequence(sim, TextureSampler(config.textures), 0, index)
    cam = sim.camera.rig().event
    scene = spec.scene
    if gauss:
        poses = [spec.trajectory.pose(t) for t in spec.trajectory.sample_times(0.02)]
        m = float(np.median([texels_per_sample(scene, cam, supersample, [p]) for p in poses]))
        sigma = 0.5 * np.sqrt(max(m * m - 1, 0.0))
        if sigma > 0:
            scene = PlanarScene(cv2.GaussianBlur(scene.texture, (0, 0), sigma),
                                scene.width_m, scene.height_m)
    renderer = HomographyRenderer({"lr": scene}, {"lr": cam}, {"lr": supersample})
    return sum(len(c.events) for c in simulate(spec.scene, spec.trajectory, spec.thresholds,
                                               sim, spec.noise_rng, renderer=renderer))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n-seq", type=int, default=4)
    args = parser.parse_args(argv)
    config = DatagenConfig()
    print(f"# {' '.join(['python'] + sys.argv)}")
    print("| seq | 8x8 (exact) | 2x2 | 3x3 (default) | 4x4 | 2x2 + gauss |")
    print("|---|---|---|---|---|---|")
    for i in range(args.n_seq):
        exact = events(config, i, 8)
        cells = [f"{exact:,}"]
        for ss, g in ((2, False), (3, False), (4, False), (2, True)):
            n = events(config, i, ss, g)
            cells.append(f"{(n - exact) / exact:+.1%}")
        print(f"| {i} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
