"""The same sequences simulated with both render backends: events, samples and time.

Run: .venv/bin/python bench/compare_backends.py [--n-seq N] [--seed S]
Sequence i of dataset seed S (default config: 128x128, x2, built-in textures) is simulated
once with the exact homography renderer and once with Mitsuba; the table shows how close
the event streams are (counts, and frames compared by PSNR) and what each costs.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from datagen.config import DatagenConfig
from datagen.sampling import sample_sequence
from datagen.textures import TextureSampler
from esim_lite.sequence import simulate_sequence


def run(config: DatagenConfig, backend: str, seed: int, index: int):
    render = dataclasses.replace(config.simulation.render, backend=backend)
    sim = dataclasses.replace(config.simulation, render=render)
    spec = sample_sequence(sim, TextureSampler(config.textures), seed, index)
    start = time.perf_counter()
    seq = simulate_sequence(spec.scene, spec.trajectory, spec.thresholds, sim, spec.noise_rng)
    return seq, time.perf_counter() - start, spec.texture_name


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n-seq", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    config = DatagenConfig()
    print(f"# {' '.join(['python'] + sys.argv)}")
    print("| seq | texture | events homography | events mitsuba | difference | HR frame PSNR |"
          " samples | s homography | s mitsuba |")
    print("|---|---|---|---|---|---|---|---|---|")
    for i in range(args.n_seq):
        a, ta, name = run(config, "homography", args.seed, i)
        b, tb, _ = run(config, "mitsuba", args.seed, i)
        n = min(len(a.frames["hr_x2"]), len(b.frames["hr_x2"]))
        mse = np.mean((a.frames["hr_x2"].intensity[:n] - b.frames["hr_x2"].intensity[:n]) ** 2)
        psnr = 10 * np.log10(1.0 / mse) if mse > 0 else float("inf")
        diff = (len(b.events) - len(a.events)) / len(a.events)
        print(f"| {i} | {name} | {len(a.events):,} | {len(b.events):,} | {diff:+.3%} | "
              f"{psnr:.1f} dB | {len(a.sample_poses):,} | {ta:.1f} | {tb:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
