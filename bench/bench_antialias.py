"""How many events come from texture aliasing, by event-camera supersampling.

Run: .venv/bin/python bench/bench_antialias.py [--config PATH] [--n-seq N]
The first 0.5 s of sequences 0..N-1 of the default dataset (128x128, photo textures,
homography renderer), rendered with s x s samples per pixel; 8x8 stands in for the exact
pixel integral. With a config with moving objects (configs/datagen_dynamic.yaml) the
sequences are rendered by Mitsuba, and the objects' alpha-tested edges alias too. "gauss" is
the rejected alternative: 2x2 samples of a texture blurred by a Gaussian of 0.5 sqrt(m^2 -
1) texels (m = median texels per sample), the classic band-limit for point sampling, which
removes real detail and with it real events.
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
from esim_lite.core.dataconf import load_config
from esim_lite.geometry.scene import PlanarScene
from esim_lite.render.antialias import texels_per_sample
from esim_lite.render.homography import HomographyRenderer
from esim_lite.render.renderer import make_renderer
from esim_lite.sequence import sample_footprints, simulate


def events(config: DatagenConfig, index: int, supersample: int, gauss: bool = False) -> int:
    if config.simulation.objects.enabled:
        return dynamic_events(config, index, supersample)
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


def dynamic_events(config: DatagenConfig, index: int, supersample: int) -> int:
    """Events of the first 0.5 s of a sequence with moving objects, Mitsuba at ``s x s``."""
    render = dataclasses.replace(config.simulation.render, backend="mitsuba",
                                 supersample_lr=supersample)
    sim = dataclasses.replace(config.simulation, render=render, duration_s=0.5,
                              frames=dataclasses.replace(config.simulation.frames, count=None,
                                                         ground_truth=()))
    spec = sample_sequence(sim, TextureSampler(config.textures), 0, index)
    rig = sim.camera.rig()
    cams = {"lr": rig.event}
    renderer = make_renderer(spec.scene, cams, render,
                             {"lr": sample_footprints(spec.scene, spec.trajectory, rig,
                                                      render)["lr"]})
    try:
        return sum(len(c.events) for c in simulate(spec.scene, spec.trajectory,
                                                   spec.thresholds, sim, spec.noise_rng,
                                                   renderer=renderer))
    finally:
        renderer.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--config", help="datagen YAML (default: the built-in defaults)")
    parser.add_argument("--n-seq", type=int, default=4)
    args = parser.parse_args(argv)
    config = load_config(DatagenConfig, args.config)
    dynamic = config.simulation.objects.enabled
    print(f"# {' '.join(['python'] + sys.argv)}")
    print("| seq | 8x8 (exact) | 2x2 | 3x3 (default) | 4x4 |" +
          ("" if dynamic else " 2x2 + gauss |"))
    print("|---|---|---|---|---|" + ("" if dynamic else "---|"))
    for i in range(args.n_seq):
        exact = events(config, i, 8)
        cells = [f"{exact:,}"]
        cases = ((2, False), (3, False), (4, False)) + (() if dynamic else ((2, True),))
        for ss, g in cases:
            n = events(config, i, ss, g)
            cells.append(f"{(n - exact) / exact:+.1%}")
        print(f"| {i} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
