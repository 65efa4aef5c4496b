"""Dataset generation throughput, scaling, storage and memory at the default config.

Run: .venv/bin/python bench/bench_datagen.py [--quick]
     .venv/bin/python bench/bench_datagen.py --ratio [--n-seq N] [--repeats R]
     .venv/bin/python bench/bench_datagen.py --ratio --compare-code DIR
     .venv/bin/python bench/bench_datagen.py --dynamic configs/datagen_dynamic.yaml [--n-seq N]
     .venv/bin/python bench/bench_datagen.py --recipe configs/datagen_realistic.yaml [--n-seq N]
     .venv/bin/python bench/bench_datagen.py --recipes [--n-seq N] [--compare-code DIR]
``--ratio``: the same N default sequences generated with each backend, runs interleaved
(homography, Mitsuba, homography, ...; this VM drifts), per worker count: median seconds
and Mitsuba / homography. With ``--compare-code DIR`` it also runs another checkout (e.g. a
git worktree of an older commit) in the same rotation: before/after a change.
``--dynamic CONFIG``: N sequences of today's single-plane homography dataset against N of
CONFIG (moving objects, Mitsuba) with and without its ground truth and with the compiled
exact renderer instead of Mitsuba, interleaved, one worker: the cost of dynamic scenes per
sequence, per event and per render sample. ``--recipe CONFIG``: the same table for today's
training config (configs/datagen_train.yaml's simulation) against CONFIG, with its own
renderer and with the compiled exact one.
``--recipes``: the clean plane (configs/datagen_train.yaml's simulation, built-in
textures), the dynamic (configs/datagen_dynamic.yaml) and the realistic
(configs/datagen_realistic.yaml) recipes, 1 and 2 workers, in one run (with
``--compare-code DIR`` also that checkout's): seconds per sequence and per frame written,
and each recipe per frame against the clean plane of the same code and worker count, in
wall seconds and in CPU seconds of the run's processes (``RUSAGE_CHILDREN``: what a shared
machine's load does not inflate).
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
                    if ds.ndim >= 3:  # images, and ground truth (flow [T,2,H,W])
                        sizes[cam] = sizes.get(cam, 0) + ds.id.get_storage_size()
    return {k: v / 1e6 for k, v in sizes.items()}


def run_case(n_seq: int, workers: int, sets: list[str], scale: str = "2",
             code: Path | None = None, config: str | None = None, seed: int = 0) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "shards"
        cmd = [sys.executable, "-m", "datagen.cli", "generate", "--n-seq", str(n_seq),
               "--out", str(out), "--workers", str(workers), "--scale", scale, "--no-progress"]
        if config:
            cmd += ["--config", config]
        if seed:
            cmd += ["--seed", str(seed)]
        for s in sets:
            cmd += ["--set", s]
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        before, cpu = usage.ru_maxrss, usage.ru_utime + usage.ru_stime
        start = time.perf_counter()
        env = dict(os.environ)
        if code is not None:  # another checkout's datagen, same interpreter and packages
            env["PYTHONPATH"] = str(code)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=env,
                       cwd=code or Path(__file__).resolve().parents[1])
        seconds = time.perf_counter() - start
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        peak_mb = max(before, usage.ru_maxrss) / 1024
        cpu = usage.ru_utime + usage.ru_stime - cpu
        events = frames = samples = 0
        for path in out.glob("shard_*.h5"):
            with ShardReader(path) as r:
                for name in r.sequences():
                    events += r.num_events(name)
                    frames += len(r.frame_event_idx(name))
                    samples += r.num_samples(name)
        sizes = stored_mb(out)
    return {"seconds": seconds, "cpu_s": cpu, "events": events, "frames": frames,
            "samples": samples, "peak_mb": peak_mb,
            "mb_per_seq": {k: v / n_seq for k, v in sizes.items()}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="fewer sequences per case")
    parser.add_argument("--ratio", action="store_true",
                        help="Mitsuba / homography on the same sequences, interleaved")
    parser.add_argument("--n-seq", type=int, default=8, help="sequences per --ratio run")
    parser.add_argument("--repeats", type=int, default=3, help="runs per --ratio case")
    parser.add_argument("--workers", default="1,2", help="worker counts for --ratio")
    parser.add_argument("--compare-code", type=Path, metavar="DIR",
                        help="with --ratio: also the checkout in DIR, same rotation")
    parser.add_argument("--dynamic", metavar="CONFIG",
                        help="homography plane datasets against CONFIG's (Mitsuba, objects)")
    parser.add_argument("--recipe", metavar="CONFIG",
                        help="today's training set against CONFIG (e.g. the realistic recipe)")
    parser.add_argument("--seed", type=int, default=0,
                        help="dataset seed for --dynamic and --recipe")
    parser.add_argument("--recipes", action="store_true",
                        help="clean plane, dynamic and realistic recipes, 1 and 2 workers")
    args = parser.parse_args(argv)
    if args.recipes:
        return recipes(args.n_seq, args.repeats, [int(w) for w in args.workers.split(",")],
                       args.seed, args.compare_code)
    if args.dynamic:
        return dynamic(args.dynamic, args.n_seq, args.repeats, args.seed)
    if args.recipe:
        return recipe(args.recipe, args.n_seq, args.repeats, args.seed)
    if args.ratio or args.compare_code:
        return ratio(args.n_seq, args.repeats, [int(w) for w in args.workers.split(",")],
                     args.compare_code)
    n_h, n_m = (8, 2) if args.quick else (16, 4)
    homography = ["simulation.render.backend=homography"]
    mitsuba = ["simulation.render.backend=mitsuba", "sequences_per_shard=2"]
    print(f"# {' '.join(['python'] + sys.argv)}")
    print(f"# {machine()}")
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


def machine() -> str:
    """The CPU count and the Mitsuba variant the mitsuba rows run on (CUDA where drjit
    sees a GPU), for the table's header."""
    from esim_lite.render.mitsuba import resolve_variant

    return f"{os.cpu_count()} CPUs; mitsuba variant {resolve_variant()}"


def ratio(n: int, repeats: int, workers: list[int], other: Path | None) -> int:
    """Both backends on the same ``n`` sequences, interleaved; medians and their ratio."""
    import statistics

    backends = {"homography": ["simulation.render.backend=homography"],
                "mitsuba": ["simulation.render.backend=mitsuba"]}
    codes = [("this checkout", None)] + ([(f"{other}", other)] if other else [])
    print(f"# {' '.join(['python'] + sys.argv)}")
    print(f"# {machine()}")
    print("| code | workers | backend | sequences | seconds (median) | runs | sequences/min "
          "| events | mitsuba / homography |")
    print("|---|---|---|---|---|---|---|---|---|")
    for w in workers:
        times, last = interleaved({b: (None, sets) for b, sets in backends.items()}, codes, n,
                                  w, repeats)
        events = {key: r["events"] for key, r in last.items()}
        for label, _ in codes:
            med = {b: statistics.median(times[(label, b)]) for b in backends}
            for backend in backends:
                runs = ", ".join(f"{t:.1f}" for t in times[(label, backend)])
                tail = f"**{med['mitsuba'] / med['homography']:.2f}x**" \
                    if backend == "mitsuba" else ""
                print(f"| {label} | {w} | {backend} | {n} | {med[backend]:.1f} | {runs} | "
                      f"{n / med[backend] * 60:.1f} | {events[(label, backend)]:,} | {tail} |",
                      flush=True)
    return 0


def interleaved(cases: dict[str, tuple[str | None, list[str]]],
                codes: list[tuple[str, Path | None]], n: int, workers: int, repeats: int,
                seed: int = 0) -> tuple[dict[tuple[str, str], list[float]],
                                        dict[tuple[str, str], dict]]:
    """Every (code, case) run ``repeats`` times in rotation (this VM drifts): the seconds of
    each run and the last run's :func:`run_case` result, by ``(code label, case)``. A case's
    config is taken from each code's own ``configs/``."""
    times: dict[tuple[str, str], list[float]] = {}
    last: dict[tuple[str, str], dict] = {}
    for _ in range(repeats):
        for label, code in codes:
            for name, (config, sets) in cases.items():
                if code is not None and config is not None:
                    config = str(Path(code) / "configs" / Path(config).name)
                r = run_case(n, workers, sets, code=code, config=config, seed=seed)
                times.setdefault((label, name), []).append(r["seconds"])
                last[(label, name)] = r
    return times, last


def dynamic(config: str, n: int, repeats: int, seed: int) -> int:
    """Today's plane dataset (homography) against ``config`` with and without ground truth,
    runs interleaved, one worker; medians and ratios to the plane dataset."""
    cases = {BASE: (None, ["simulation.render.backend=homography"]),
             f"{config}": (config, []),
             f"{config}, no ground truth": (config, ["simulation.frames.ground_truth=[]"]),
             f"{config}, no ground truth, reference renderer": (
                 config, ["simulation.frames.ground_truth=[]",
                          "simulation.render.backend=reference"])}
    return compare(cases, n, repeats, seed)


def recipe(config: str, n: int, repeats: int, seed: int) -> int:
    """Today's training set (configs/datagen_train.yaml's simulation, built-in textures so
    that nothing needs installing) against the recipe ``config`` with its own renderer and
    with the compiled reference renderer, interleaved, one worker."""
    train = str(Path(__file__).resolve().parents[1] / "configs" / "datagen_train.yaml")
    cases = {BASE: (train, ["textures.source=builtin", "textures.source_weights=null"]),
             f"{config}": (config, []),
             f"{config}, reference renderer": (config, ["simulation.render.backend=reference"])}
    return compare(cases, n, repeats, seed)


def recipes(n: int, repeats: int, workers: list[int], seed: int, other: Path | None) -> int:
    """The three recipes' ``n`` sequences per worker count (and code), runs interleaved;
    medians of seconds per sequence and per frame, and per frame against the clean plane."""
    import statistics

    cfg = Path(__file__).resolve().parents[1] / "configs"
    cases = {"clean plane": (str(cfg / "datagen_train.yaml"),
                             ["textures.source=builtin", "textures.source_weights=null"]),
             "dynamic": (str(cfg / "datagen_dynamic.yaml"), []),
             "realistic": (str(cfg / "datagen_realistic.yaml"), [])}
    codes = [("this checkout", None)] + ([(f"{other}", other)] if other else [])
    print(f"# {' '.join(['python'] + sys.argv)}")
    print(f"# {machine()}; {n} sequences per run, seed {seed}, {repeats} runs, "
          f"load average {os.getloadavg()[0]:.1f} at the start")
    print("| code | workers | recipe | seconds (median) | runs | s per sequence | frames "
          "| s per frame | x clean per frame | CPU s per frame | x clean (CPU) | events |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for w in workers:
        times, last = interleaved(cases, codes, n, w, repeats, seed)
        for label, _ in codes:
            base = last[(label, "clean plane")]
            clean = statistics.median(times[(label, "clean plane")]) / max(base["frames"], 1)
            clean_cpu = base["cpu_s"] / max(base["frames"], 1)
            for name in cases:
                med = statistics.median(times[(label, name)])
                r = last[(label, name)]
                per_frame = med / max(r["frames"], 1)
                cpu = r["cpu_s"] / max(r["frames"], 1)  # the last run's: load-proof
                runs = ", ".join(f"{t:.1f}" for t in times[(label, name)])
                print(f"| {label} | {w} | {name} | {med:.1f} | {runs} | {med / n:.2f} | "
                      f"{r['frames']} | {per_frame:.3f} | {per_frame / clean:.1f}x | "
                      f"{cpu:.3f} | **{cpu / clean_cpu:.1f}x** | {r['events']:,} |",
                      flush=True)
    return 0


#: The first case of :func:`compare`, the one the others are divided by.
BASE = "plane, homography (today)"


def compare(cases: dict[str, tuple[str | None, list[str]]], n: int, repeats: int,
            seed: int) -> int:
    """Each case's ``n`` sequences, runs interleaved, one worker; medians and ratios to the
    :data:`BASE` case per sequence, per event and per render sample."""
    import statistics

    print(f"# {' '.join(['python'] + sys.argv)}")
    print(f"# {machine()}; {n} sequences per run, seed {seed}, 1 worker, {repeats} runs")
    times: dict[str, list[float]] = {}
    last: dict[str, dict] = {}
    for _ in range(repeats):
        for label, (cfg, sets) in cases.items():
            r = run_case(n, 1, sets, config=cfg, seed=seed)
            times.setdefault(label, []).append(r["seconds"])
            last[label] = r
    base = statistics.median(times[BASE])
    base_ev = last[BASE]
    per_event = base / max(base_ev["events"], 1)
    per_sample = base / max(base_ev["samples"], 1)
    print("| dataset | seconds (median) | runs | s per sequence | x plane homography | events "
          "| x per event | render samples | x per sample | frames | MB/seq |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for label in cases:
        med = statistics.median(times[label])
        r = last[label]
        runs = ", ".join(f"{t:.1f}" for t in times[label])
        print(f"| {label} | {med:.1f} | {runs} | {med / n:.1f} | {med / base:.2f} | "
              f"{r['events']:,} | {med / max(r['events'], 1) / per_event:.2f} | "
              f"{r['samples']:,} | {med / max(r['samples'], 1) / per_sample:.2f} | "
              f"{r['frames']} | {sum(r['mb_per_seq'].values()):.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
