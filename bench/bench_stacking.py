"""SBN stacking: the compiled implementation against the numpy one it replaced (issue 25).

Run: .venv/bin/python bench/bench_stacking.py [--events 2000000] [--repeats 21]
     [--sizes 128x128,240x180,346x260]
(smoke run: --events 100000 --repeats 3 --sizes 128x128)
Per sensor size, a synthetic stream of ``--events`` events (pixels drawn from a heavy-tailed
per-pixel rate map, so some pixels fire often, as edges do in real recordings) and the
events per stack `reconstruct` uses with the shipped models (9,000 at 128x128 scaled by
area: 23,730 at 240x180, 49,416 at 346x260; 3 channels, overwrite cap 50). Two call
patterns, each at ``--repeats`` random anchors:
- stack: one ``sbn_stack(events, end=anchor)`` on the whole stream (as
  ``model/data/input_cache.py`` calls it on a whole sequence);
- frame: ``stack_sequence`` of 3 stacks on `reconstruct`'s window of 3 stacks of events
  around the anchor (``Reconstructor.stacks_at``, without the window's slicing).
Old and new run interleaved in one process (order alternating per repeat, both warmed up
first), so a busy machine slows both alike; the table gives the median ms of each and the
median of the per-repeat ratios, and checks the outputs are identical. The old
implementation is the oracle of ``tests/esim_lite/test_stacking_fast.py``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from esim_lite.core.events import Events
from esim_lite.core.stacking import StackConfig, sbn_stack, stack_sequence

ROOT = Path(__file__).resolve().parents[1]
PER_STACK_128 = 9000  # the shipped models' events per stack at 128x128
N_STACKS = 3


def synthetic(n: int, hw: tuple[int, int], seed: int) -> Events:
    """``n`` events at ~1 M events/s with pixels drawn from a lognormal rate map."""
    rng = np.random.default_rng(seed)
    h, w = hw
    rate = rng.lognormal(0.0, 1.5, h * w)
    pix = rng.choice(h * w, n, p=rate / rate.sum())
    t = np.sort(rng.integers(0, n * 1000, n)).astype(np.int64)
    return Events((pix % w).astype(np.int16), (pix // w).astype(np.int16), t,
                  rng.choice(np.array([-1, 1], np.int8), n), hw)


def same(new, old) -> bool:
    image, start, end, bounds = old
    return (np.array_equal(new.image, image) and (new.start, new.end) == (start, end)
            and np.array_equal(new.bounds, bounds))


def interleaved(calls: dict, anchors: np.ndarray) -> tuple[dict, float, bool]:
    """(median seconds per name, median old/new ratio, outputs identical) of ``calls``
    ``{"old": f, "new": g}`` (``f(anchor)``), alternating which runs first."""
    seconds = {"old": [], "new": []}
    identical = True
    for k, anchor in enumerate(anchors):
        out = {}
        for name in ("old", "new") if k % 2 == 0 else ("new", "old"):
            start = time.perf_counter()
            out[name] = calls[name](int(anchor))
            seconds[name].append(time.perf_counter() - start)
        identical &= all(same(a, b) for a, b in zip(out["new"], out["old"]))
    ratio = float(np.median(np.array(seconds["old"]) / np.array(seconds["new"])))
    return {k: float(np.median(v)) for k, v in seconds.items()}, ratio, identical


def row(hw: tuple[int, int], n_events: int, repeats: int, oracle) -> str:
    reference_sbn_stack, reference_stack_sequence = oracle
    per_channel = StackConfig.events_per_channel_for(hw, PER_STACK_128 * 240 * 180 / 128**2)
    cfg = StackConfig(channels=3, events_per_channel=per_channel, overwrite_cap=50)
    per = cfg.events_per_stack
    events = synthetic(n_events, hw, seed=hw[0])
    anchors = np.random.default_rng(1).integers(2 * per, n_events - per, repeats + 1)
    half = N_STACKS // 2

    def frame(seq):
        def call(anchor):
            window = events.slice(anchor - (half + 1) * per, anchor + half * per)
            return seq(window, cfg, (half + 1) * per, N_STACKS)
        return call

    stack_calls = {"old": lambda a: [reference_sbn_stack(events, cfg, end=a)],
                   "new": lambda a: [sbn_stack(events, cfg, end=a)]}
    frame_calls = {"old": frame(reference_stack_sequence), "new": frame(stack_sequence)}
    interleaved(stack_calls, anchors[:1])  # warm-up (numba compiles or loads its cache)
    interleaved(frame_calls, anchors[:1])
    s, s_ratio, s_same = interleaved(stack_calls, anchors[1:])
    f, f_ratio, f_same = interleaved(frame_calls, anchors[1:])
    return (f"| {hw[1]}x{hw[0]} | {per:,} | {n_events:,} | {1e3 * s['old']:.2f} | "
            f"{1e3 * s['new']:.3f} | {s_ratio:.0f}x | {1e3 * f['old']:.2f} | "
            f"{1e3 * f['new']:.3f} | {f_ratio:.0f}x | {'yes' if s_same and f_same else 'NO'} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--events", type=int, default=2_000_000)
    parser.add_argument("--repeats", type=int, default=21)
    parser.add_argument("--sizes", default="128x128,240x180,346x260", help="WxH,...")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))  # the oracle lives in the tests
    from tests.esim_lite.test_stacking_fast import (
        reference_sbn_stack,
        reference_stack_sequence,
    )

    print(f"# {' '.join(['python'] + sys.argv)}; numpy {np.__version__}")
    print("| sensor | events per stack | stream events | stack old ms | stack new ms | "
          "stack speed-up | frame old ms | frame new ms | frame speed-up | identical |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for size in args.sizes.split(","):
        w, h = (int(v) for v in size.split("x"))
        print(row((h, w), args.events, args.repeats,
                  (reference_sbn_stack, reference_stack_sequence)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
