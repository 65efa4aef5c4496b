"""Time of the fill of what no event saw (model/inference/fill.py), per output frame.

Run: .venv/bin/python bench/bench_fill.py [--repeats 5]

For each sensor size (the 128x128 training sensor, the DAVIS240C, the DAVIS346) at x2 and
for a dense and a sparse event support (30% and 1% of the pixels fired, in small clusters as
edges fire), the median wall time of ``fill_unobserved`` per frame for each mode, and of
the harmonic solve's parts. One thread per process is not forced: numpy and scipy use what
they find. Printed as a markdown table with the command that made it.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time

import numpy as np

SIZES = {"128x128": (128, 128), "DAVIS240C 240x180": (180, 240), "DAVIS346 346x260": (260, 346)}
DENSITIES = (0.30, 0.01)


def stacks_with(hw: tuple[int, int], density: float, rng: np.random.Generator) -> np.ndarray:
    """uint8 stacks ``[3, 3, H, W]`` whose fired pixels are 2x2 clusters covering about
    ``density`` of the sensor."""
    stacks = np.full((3, 3) + hw, 128, np.uint8)
    h, w = hw
    n = int(density * h * w / 4)
    ys, xs = rng.integers(0, h - 1, n), rng.integers(0, w - 1, n)
    for dy in (0, 1):
        for dx in (0, 1):
            stacks[1, 0, ys + dy, xs + dx] = 200
    return stacks


def main(argv: list[str] | None = None) -> int:
    from model.inference.fill import FillConfig, fill_unobserved

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--scale", type=int, default=2)
    args = p.parse_args(argv)
    print(f"# .venv/bin/python bench/bench_fill.py "
          f"{shlex.join(sys.argv[1:] if argv is None else argv)}".rstrip())
    rng = np.random.default_rng(0)
    print("\n| sensor | fired | harmonic ms | flat ms |\n|---|---|---|---|")
    for name, hw in SIZES.items():
        for density in DENSITIES:
            stacks = stacks_with(hw, density, rng)
            image = rng.random((hw[0] * args.scale, hw[1] * args.scale)).astype(np.float32)
            cells = []
            for mode in ("harmonic", "flat"):
                config = FillConfig(mode)
                times = []
                for _ in range(args.repeats):
                    start = time.perf_counter()
                    fill_unobserved(image, stacks, config)
                    times.append(time.perf_counter() - start)
                cells.append(f"{1e3 * float(np.median(times)):.1f}")
            print(f"| {name} | {density:.0%} | {' | '.join(cells)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
