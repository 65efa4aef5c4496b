"""How much a model with memory across outputs (``model.memory``) uses it on real recordings.

Run: .venv/bin/python bench/memory_use.py [LABEL=]CKPT ... [--outputs 40]
         [--recordings DIR ...] [--only NAME ...] [--figure PNG]

For every real recording (the DAVIS346 files and the ECD snippets of ../shared/real_events
by default) the model runs once a stack, in time order, as ``reconstruct`` does; at each
output it also runs on the same stacks with an empty memory (the state is put back
afterwards, so the chain is the model's own). Printed per recording: outputs made, the mean
absolute difference between the two outputs at the first output (0: no memory yet) and
over the last ten, and the share of HR pixels that differ by more than 0.02 over the last
ten; and the carried state's mean magnitude at outputs 1, 4, 10, 20 and the last, which
shows whether the memory settles or keeps growing past the clips it was trained on.
``--figure`` writes one row per model and recording: the outputs at those counts.
``--only`` keeps the recordings whose name contains one of the given strings.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "real_events"
MARKS = (1, 4, 10, 20)  # outputs whose state size and image are reported (and the last)


def memory_use(ckpt: str, path: Path, outputs: int) -> dict:
    from datagen.recording import open_recording
    from model.inference.real_benchmark import ECD_SENSOR_HW, recording_name
    from model.inference.reconstruct import Reconstructor, output_times, plan_outputs
    from model.inference.stack_size import activity_of

    # an AEDAT4 file says its sensor size; an ECD snippet (its folder or events.txt) not
    rec = open_recording(path, None if path.suffix == ".aedat4" else ECD_SENSOR_HW)
    events = rec.read_all()
    model = Reconstructor.load(ckpt, rec.sensor_hw, device="cpu",
                               activity=activity_of(events))
    if not model.net.config.memory:
        raise ValueError(f"{ckpt}: the network carries no memory across outputs")
    window = model.event_window(iter([events]), rec.sensor_hw, len(events) + 1)
    plan = plan_outputs(rec, model.stacks, "events")
    diffs, sizes, shown = [], [], []
    model.reset()
    for t, _ in output_times(plan, rec, window):
        given = model.stacks_at(window, t)
        kept, _ = model.run(given.stacks, None, given.history)
        state = model.memory.state
        model.memory.state = None
        fresh, _ = model.run(given.stacks, None, given.history)
        model.memory.state = state
        diffs.append(np.abs(kept - fresh))
        sizes.append(float(state.abs().mean()))
        if len(diffs) in MARKS:
            shown.append((kept, f"output {len(diffs)}"))
        if len(diffs) >= outputs:
            break
    if len(diffs) not in MARKS:
        shown.append((kept, f"output {len(diffs)}"))
    last = np.stack(diffs[-10:])
    return {"recording": recording_name(path), "outputs": len(diffs),
            "per_stack": model.stacks.events_per_stack, "first": float(diffs[0].mean()),
            "last10": float(last.mean()), "share": float((last > 0.02).mean()),
            "state": [sizes[k - 1] for k in MARKS if k <= len(sizes)] +
            ([sizes[-1]] if len(sizes) not in MARKS else []), "shown": shown}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("checkpoints", nargs="+", metavar="[LABEL=]CKPT")
    p.add_argument("--outputs", type=int, default=40, help="outputs per recording (at most)")
    p.add_argument("--recordings", type=Path, nargs="*", default=[REAL],
                   help="folders laid out as ../shared/real_events")
    p.add_argument("--figure", type=Path, help="PNG of the outputs at 1, 4, 10, 20, last")
    p.add_argument("--only", nargs="*", default=[], help="recording names to keep (substrings)")
    args = p.parse_args(argv)
    from model.inference.real_benchmark import find_recordings, recording_name

    found = []
    for folder in args.recordings:
        try:
            real = find_recordings(folder)
        except FileNotFoundError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        found += [f for f in real.scored + real.shown
                  if not args.only or any(o in recording_name(f) for o in args.only)]
    if not found:
        print(f"no recordings named {', '.join(args.only)}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    print("```\n" + shlex.join([".venv/bin/python", "bench/memory_use.py",
                                 *(argv if argv is not None else sys.argv[1:])]) + "\n```\n")
    print("| model | recording | outputs | events per stack | mean diff, first "
          "| mean diff, last 10 | share > 0.02, last 10 | state size at 1 / 4 / 10 / 20 / last |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for item in args.checkpoints:
        label, _, ckpt = item.rpartition("=")
        label = label or ckpt
        for path in found:
            try:
                r = memory_use(ckpt, path, args.outputs)
            except (ValueError, FileNotFoundError) as exc:
                print(f"error: {exc}", file=sys.stderr)
                return 2
            rows.append([(img, f"{label}, {r['recording']}: {text}")
                         for img, text in r["shown"]])
            print(f"| {label} | {r['recording']} | {r['outputs']} | {r['per_stack']:,} "
                  f"| {r['first']:.4f} | {r['last10']:.4f} | {r['share']:.3f} | "
                  f"{' / '.join(f'{v:.3f}' for v in r['state'])} |")
    if args.figure:
        from esim_lite.core.figures import contact_sheet, gray_to_rgb, write_png

        sheet = contact_sheet([[(gray_to_rgb(img), label) for img, label in row]
                               for row in rows], "memory across outputs: outputs along the "
                              "chain, the memory carried from the first", height=180)
        print(f"figure {write_png(args.figure, sheet)}")
    print(f"\n{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
