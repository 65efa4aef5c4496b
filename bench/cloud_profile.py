"""The cloud profile: how a model's output level changes with distance from where events fired.

Run: .venv/bin/python bench/cloud_profile.py --model NAME=CKPT [--model NAME=CKPT ...]
         [--folder DIR] [--every K]

Under a static camera the background never fires. A model that fills it with the level
the nearby edges imply and a constant prior beyond paints a cloud around each moving
object: dark near it, light far from it, although the truth there is one road. This
script measures that on the real DAVIS346 recordings with APS frames
(``--folder``/``davis346/*.aedat4``): every scored frame's output is brought to the sensor
size and fitted to the APS frame (the affine fit of docs/evaluation.md), and the pixels are
banded by their distance from the observed region (``support_mask`` of the events behind
the output, docs/evaluation.md). Per band it prints the APS mean and, per model, the fitted
output's mean and mean absolute error; then the gap, the far band's mean (48 px and beyond)
minus the near band's (within 16 px), beside the APS frames' own gap. A cloud shows as an
output gap far from the APS gap. Without the folder it says so and exits 0.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np

REAL_EVENTS = Path(__file__).resolve().parents[2] / "shared" / "real_events"
BANDS = ((0, 1), (1, 8), (8, 16), (16, 32), (32, 48), (48, 96), (96, 10_000))
NEAR, FAR = 16, 48  # the gap: mean beyond FAR px minus mean within NEAR px of the support


def distance_from(support: np.ndarray) -> np.ndarray:
    """Each pixel's distance (px) from the nearest pixel of ``support`` (0 inside it)."""
    import cv2

    outside = (~support.astype(bool)).astype(np.uint8)
    return cv2.distanceTransform(outside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def profile(fitted: list[np.ndarray], targets: list[np.ndarray], supports: list[np.ndarray]
            ) -> dict:
    """Band means of the fitted outputs and the targets, the outputs' mean absolute error
    per band, and both gaps, over all frames' pixels."""
    d = np.concatenate([distance_from(s).ravel() for s in supports])
    p = np.concatenate([f.ravel() for f in fitted])
    g = np.concatenate([t.ravel() for t in targets])
    rows = []
    for lo, hi in BANDS:
        k = (d >= lo) & (d < hi)
        rows.append((lo, hi, int(k.sum()), float(g[k].mean()) if k.any() else np.nan,
                     float(p[k].mean()) if k.any() else np.nan,
                     float(np.abs(p[k] - g[k]).mean()) if k.any() else np.nan))
    near, far = d < NEAR, d >= FAR
    gap = float(p[far].mean() - p[near].mean()) if far.any() and near.any() else np.nan
    aps_gap = float(g[far].mean() - g[near].mean()) if far.any() and near.any() else np.nan
    return {"bands": rows, "gap": gap, "aps_gap": aps_gap}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", action="append", required=True, metavar="NAME=CKPT",
                   help="a model to profile (repeat to compare)")
    p.add_argument("--folder", default=str(REAL_EVENTS),
                   help="real recordings (default: ../shared/real_events beside the repo)")
    p.add_argument("--every", type=int, default=1, help="every k-th APS frame")
    args = p.parse_args(argv)
    command = " ".join([".venv/bin/python bench/cloud_profile.py",
                        shlex.join(sys.argv[1:] if argv is None else argv)]).strip()
    print(f"# {command}")
    models = []
    for spec in args.model:
        name, sep, ckpt = spec.partition("=")
        if not sep or not name or not ckpt:
            print(f"cloud_profile: --model {spec!r}: expected NAME=CKPT", file=sys.stderr)
            return 2
        if not Path(ckpt).is_file():
            print(f"cloud_profile: {ckpt}: no such checkpoint", file=sys.stderr)
            return 2
        models.append((name, ckpt))
    folder = Path(args.folder)
    if not folder.is_dir():
        print(f"cloud_profile: skipped: {folder} is not there (the real recordings live in "
              f"../shared/real_events beside the repository; see --folder)")
        return 0
    from datagen.recording import open_recording
    from model.inference.evaluate import (
        EvalOptions,
        ModelPool,
        _down,
        normalized,
        recording_outputs,
    )
    from model.inference.real_benchmark import find_recordings

    start = time.perf_counter()
    options = EvalOptions(every=args.every, exposure_average=True)
    recordings = [open_recording(path, None) for path in find_recordings(folder).scored]
    results: dict[str, dict[str, dict]] = {}
    for name, ckpt in models:
        pool = ModelPool(ckpt, options, engine="torch")
        scale = pool.config.model.scale
        for rec in recordings:
            seq = recording_outputs(rec, pool.for_recording(rec), options, rec.path.stem)
            fitted = [normalized(_down(o, scale), g, "affine")[0]
                      for o, g in zip(seq.images["ours"], seq.lr_targets)]
            results.setdefault(seq.name, {})[name] = profile(fitted, seq.lr_targets, seq.support)
    for rec_name, by_model in results.items():
        first = next(iter(by_model.values()))
        print(f"\n## {rec_name}: fitted output by distance from the observed region\n")
        print("| band (px) | pixels | APS mean | "
              + " | ".join(f"{m} mean | {m} MAE" for m in by_model) + " |")
        print("|---|---|---|" + "---|---|" * len(by_model))
        for i, (lo, hi, n, g, _, _) in enumerate(first["bands"]):
            cells = " | ".join(f"{r['bands'][i][4]:.3f} | {r['bands'][i][5]:.3f}"
                               for r in by_model.values())
            band = f"{lo}-{hi}" if hi < 10_000 else f">= {lo}"
            print(f"| {band} | {n} | {g:.3f} | {cells} |")
        gaps = ", ".join(f"{m} {r['gap']:+.3f}" for m, r in by_model.items())
        print(f"\ngap (mean beyond {FAR} px minus within {NEAR} px): APS {first['aps_gap']:+.3f}; "
              f"{gaps}")
    print(f"\n{time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
