"""Side by side: the "ours" columns of several real-benchmark figures (bench/bench_real.py).

Run: .venv/bin/python bench/side_by_side.py --out FIG.png [--scale 0.5] LABEL=DIR [LABEL=DIR ...]

Each ``DIR`` holds a ``real_benchmark.png``; the figure has one column pair per ``LABEL``
(our output and its 4x zoom, for every recording), then the first figure's APS columns
(ground truth and its zoom, where a recording has frames), each headed by its label.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

#: The real-benchmark figure's column pairs, as fractions of its width: ours, ground truth.
OURS, TRUTH = (4 / 8, 6 / 8), (6 / 8, 8 / 8)
HEAD = 40


def columns(figure: np.ndarray, span: tuple[float, float]) -> np.ndarray:
    w = figure.shape[1]
    return figure[:, int(round(span[0] * w)):int(round(span[1] * w))]


def headed(block: np.ndarray, label: str) -> np.ndarray:
    head = np.full((HEAD, block.shape[1], 3), 255, np.uint8)
    cv2.putText(head, label, (8, HEAD - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (0, 0, 0), 2,
                cv2.LINE_AA)
    return np.vstack([head, block])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="the PNG to write")
    p.add_argument("--scale", type=float, default=1.0, help="resize the result (default 1)")
    p.add_argument("runs", nargs="+", help="LABEL=DIR, DIR holding real_benchmark.png")
    args = p.parse_args(argv)
    blocks, first = [], None
    for item in args.runs:
        label, sep, folder = item.partition("=")
        path = Path(folder) / "real_benchmark.png"
        figure = cv2.imread(str(path), cv2.IMREAD_COLOR) if sep else None
        if figure is None:
            print(f"side_by_side: error: {item}: expected LABEL=DIR with DIR/real_benchmark.png",
                  file=sys.stderr)
            return 2
        if first is not None and figure.shape != first.shape:
            print(f"side_by_side: error: {path}: {figure.shape[1]}x{figure.shape[0]}, not the "
                  f"first figure's {first.shape[1]}x{first.shape[0]}", file=sys.stderr)
            return 2
        first = figure if first is None else first
        blocks.append(headed(columns(figure, OURS), label))
    blocks.append(headed(columns(first, TRUTH), "APS frame"))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp.png")
    sheet = np.hstack(blocks)
    if args.scale != 1.0:
        sheet = cv2.resize(sheet, None, fx=args.scale, fy=args.scale, interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(tmp), sheet)
    tmp.replace(out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
