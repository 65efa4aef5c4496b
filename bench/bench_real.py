"""The real-data benchmark: E2SRI and the classical baselines on every real recording.

Run: .venv/bin/python bench/bench_real.py [--folder DIR] [--out DIR] [--checkpoint CKPT]
         [--engine auto|torch|onnxruntime|openvino] [--fill none|harmonic|flat]

``--folder`` (default ``../shared/real_events`` beside the repository), searched at any
depth: ``*.aedat4`` files and folders with ``events.txt`` + ``images.txt`` (+
``exposures.txt``) are scored against their APS frames, every method's outputs averaged over
each frame's exposure window; each by the verdict measured from its events (a scene moving
across most of the frame: whole-frame PSNR/SSIM/LPIPS under EVREAL's protocol and the
affine fit; a static camera: the observed region with ``invented``, whole-frame PSNR/SSIM
for reference, no whole-frame LPIPS). Folders with ``events.txt`` alone (the 240x180 ECD
snippets, no frames) appear in the figure only. One table (``real_benchmark.md``, ``.csv``)
and one figure (``real_benchmark.png``) in ``--out``; the logic is
:mod:`model.inference.real_benchmark` and :mod:`model.inference.scene_motion`, the protocol
docs/evaluation.md. Without the folder it says so and exits 0.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

REAL_EVENTS = Path(__file__).resolve().parents[2] / "shared" / "real_events"


def main(argv: list[str] | None = None) -> int:
    from model.cli import fill_arguments, fill_config

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--folder", default=str(REAL_EVENTS),
                   help="real recordings (default: ../shared/real_events beside the repo)")
    p.add_argument("--out", default="out/bench_real", help="folder for the table and figure")
    p.add_argument("--checkpoint", help="a trained model (default: the shipped one of "
                   "--scale), e.g. to compare two models")
    p.add_argument("--scale", type=int, default=2, help="shipped model without --checkpoint")
    p.add_argument("--engine", choices=["auto", "torch", "onnxruntime", "openvino",
                                        "openvino-int8"],
                   default="auto", help="what runs the network (as evaluate --engine)")
    p.add_argument("--events-per-stack", type=int, help="default: chosen per recording")
    p.add_argument("--stack-rule", choices=["auto", "active", "area"], default="auto",
                   help="as evaluate --stack-rule (default auto: active pixels)")
    p.add_argument("--no-exposure-average", action="store_true",
                   help="score every method at each frame's timestamp only")
    fill_arguments(p)
    p.add_argument("--every", type=int, default=1, help="every k-th APS frame")
    p.add_argument("--max-frames", type=int, help="per recording")
    p.add_argument("--model-only", action="store_true",
                   help="score the model alone: no classical baselines, floors or ceilings "
                        "(they do not depend on the model; most of the run's time on a "
                        "loaded machine), e.g. to compare checkpoints")
    args = p.parse_args(argv)
    command = " ".join([".venv/bin/python bench/bench_real.py",
                        shlex.join(sys.argv[1:] if argv is None else argv)]).strip()
    print(f"# {command}")
    folder = Path(args.folder)
    if not folder.is_dir():
        print(f"bench_real: skipped: {folder} is not there (the real recordings live in "
              f"../shared/real_events beside the repository; see --folder)")
        return 0
    from model.calibration import simulated_inputs
    from model.inference.evaluate import EvalOptions
    from model.inference.pretrained import resolve
    from model.inference.real_benchmark import run_benchmark

    options = EvalOptions(every=args.every, max_frames=args.max_frames,
                          stack_rule=args.stack_rule, events_per_stack=args.events_per_stack,
                          exposure_average=not args.no_exposure_average,
                          fill=fill_config(args),
                          **({"baselines": (), "temporal": False} if args.model_only else {}))
    start = time.perf_counter()
    try:
        result = run_benchmark(resolve(args.checkpoint, args.scale), folder, args.out,
                               options, args.engine, command, simulated_inputs,
                               model_only=args.model_only)
    except (FileNotFoundError, ValueError) as exc:
        print(f"bench_real: error: {exc}", file=sys.stderr)
        return 2
    print(result.table.read_text())
    print(f"table {result.table}, {result.csv}; figure {result.figure}; "
          f"{time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
