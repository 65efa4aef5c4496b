"""Dataset generation throughput, scaling, storage and memory at the default config.

Run: .venv/bin/python bench/bench_datagen.py [--quick]
     .venv/bin/python bench/bench_datagen.py --compare-code DIR  (Mitsuba only: this
     checkout against another one, e.g. a git worktree of an older commit, same runs
     interleaved: before/after a change)
Each case runs ``datagen generate`` as a child process into a fresh temporary folder and
reports sequences/min, events/s (simulated events per wall second), the peak RSS of the
largest process of the run (``getrusage(RUSAGE_CHILDREN)``: with workers, a worker or the
parent, whichever is larger) and stored MB per sequence by dataset.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py

from datagen.shard import ShardReader


def stored_mb(folder: Path) -> dict[str, float]:
    sizes: dict[str, float] = {}
    for path in folder.glob("shard_*.h5"):
        with h5py.File(path, "r") as f:
            for seq in f:
                if not seq.startswith("seq_"):
                    continue
                g = f[seq]
                for k in ("xs", "ys", "ts", "ps"):
                    sizes["events"] = sizes.get("events", 0) + g["events"][k].id.get_storage_size()
                for cam in g["frames"]:
                    ds = g["frames"][cam]
                    if ds.ndim == 3:
                        sizes[cam] = sizes.get(cam, 0) + ds.id.get_storage_size()
    return {k: v / 1e6 for k, v in sizes.items()}


def run_case(n_seq: int, workers: int, sets: list[str], scale: str = "2",
             code: Path | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "shards"
        cmd = [sys.executable, "-m", "datagen.cli", "generate", "--n-seq", str(n_seq),
               "--out", str(out), "--workers", str(workers), "--scale", scale, "--no-progress"]
        for s in sets:
            cmd += ["--set", s]
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        start = time.perf_counter()
        env = dict(os.environ)
        if code is not None:  # another checkout's datagen, same interpreter and packages
            env["PYTHONPATH"] = str(code)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=env,
                       cwd=code or Path(__file__).resolve().parents[1])
        seconds = time.perf_counter() - start
        peak_mb = max(before, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss) / 1024
        events = frames = 0
        for path in out.glob("shard_*.h5"):
            with ShardReader(path) as r:
                for name in r.sequences():
                    events += r.num_events(name)
                    frames += len(r.frame_event_idx(name))
        sizes = stored_mb(out)
    return {"seconds": seconds, "events": events, "frames": frames, "peak_mb": peak_mb,
            "mb_per_seq": {k: v / n_seq for k, v in sizes.items()}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="fewer sequences per case")
    parser.add_argument("--compare-code", type=Path, metavar="DIR",
                        help="Mitsuba rows only, for this checkout and the one in DIR")
    args = parser.parse_args(argv)
    if args.compare_code:
        return compare(args.compare_code, 2 if args.quick else 4)
    n_h, n_m = (8, 2) if args.quick else (16, 4)
    homography = ["simulation.render.backend=homography"]
    mitsuba = ["simulation.render.backend=mitsuba", "sequences_per_shard=2"]
    print(f"# {' '.join(['python'] + sys.argv)}")
    print("| backend | workers | sequences | seconds | sequences/min | events/s | frames "
          "| peak RSS MB |")
    print("|---|---|---|---|---|---|---|---|")
    runs = {}
    for backend, sets, n in (("homography", homography, n_h), ("mitsuba", mitsuba, n_m)):
        for workers in (1, 2):
            r = run_case(n, workers, sets)
            runs[(backend, workers)] = r
            print(f"| {backend} | {workers} | {n} | {r['seconds']:.1f} | "
                  f"{n / r['seconds'] * 60:.1f} | {r['events'] / r['seconds'] / 1e3:.0f}k | "
                  f"{r['frames']} | {r['peak_mb']:.0f} |", flush=True)
    rate = n_h / runs[("homography", 2)]["seconds"] * 60
    print(f"\n1,000 x2 sequences with homography, 2 workers: {1000 / rate:.1f} min (projected)")
    print("\n| scales | MB/seq events | MB/seq lr | MB/seq hr_x2 | MB/seq hr_x4 | MB/seq total |")
    print("|---|---|---|---|---|---|")
    for scale in ("2", "4", "2,4"):
        mb = run_case(4 if not args.quick else 2, 2, homography, scale)["mb_per_seq"]
        print(f"| {scale} | {mb.get('events', 0):.2f} | {mb.get('lr', 0):.2f} | "
              f"{mb.get('hr_x2', 0):.2f} | {mb.get('hr_x4', 0):.2f} | {sum(mb.values()):.2f} |",
              flush=True)
    return 0


def compare(other: Path, n: int) -> int:
    """Mitsuba sequences/min of this checkout and ``other``, runs interleaved."""
    mitsuba = ["simulation.render.backend=mitsuba", "sequences_per_shard=2"]
    here = Path(__file__).resolve().parents[1]
    print(f"# {' '.join(['python'] + sys.argv)}")
    print("| code | workers | sequences | seconds | sequences/min | events |")
    print("|---|---|---|---|---|---|")
    for workers in (1, 2):
        for label, code in ((f"{other}", other), ("this checkout", here)):
            r = run_case(n, workers, mitsuba, code=code)
            print(f"| {label} | {workers} | {n} | {r['seconds']:.1f} | "
                  f"{n / r['seconds'] * 60:.1f} | {r['events']:,} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
