"""Export throughput and size per format for default sequences.

Run: .venv/bin/python bench/bench_export.py [--n-seq 2] [--repeat 3]
Simulates ``--n-seq`` sequences with the default datagen config (Mitsuba, 128x128 events,
256x256 HR frames) into a temporary folder, then times ``datagen export`` of every format
(in this process, median of ``--repeat``) and reports events/s and the bytes written per
sequence beside the shard's own.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from datagen.config import DatagenConfig
from datagen.export import FORMATS, export
from datagen.generate import generate
from datagen.shard import ShardReader


def size_of(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n-seq", type=int, default=2)
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "shards"
        generate(DatagenConfig(), src, n_seq=args.n_seq, seed=0, show_progress=False)
        shards = sorted(src.glob("shard_*.h5"))
        with ShardReader(shards[0]) as r:
            events = sum(r.num_events(n) for n in r.sequences())
        shard_mb = sum(s.stat().st_size for s in shards) / 1e6 / args.n_seq
        print(f"# python bench/bench_export.py --n-seq {args.n_seq} --repeat {args.repeat}")
        print(f"{args.n_seq} default sequences, {events:,} events; shard: {shard_mb:.1f} MB "
              "per sequence\n")
        print("| format | seconds per sequence | events/s | MB per sequence |")
        print("|---|---|---|---|")
        for fmt in FORMATS:
            times, written = [], []
            for k in range(args.repeat):
                start = time.perf_counter()
                written = export(shards, fmt, Path(tmp) / f"{fmt}_{k}")
                times.append(time.perf_counter() - start)
            t = statistics.median(times)
            mb = sum(size_of(w) for w in written) / 1e6 / args.n_seq
            print(f"| {fmt} | {t / args.n_seq:.2f} | {events / t:,.0f} | {mb:.1f} |")


if __name__ == "__main__":
    main()
