"""Reconstruction latency per output frame at 240x180, per engine and sensor size with the
shipped models, and memory on long recordings.

Run: .venv/bin/python bench/bench_reconstruct.py [--skip-latency] [--skip-engines]
     [--skip-memory] [--frames 5] [--rounds 3] [--sizes 128x128,240x180,346x260]
     [--real RECORDING ...] [--limit N]
(smoke run: --skip-latency --skip-memory --sizes 128x128 --frames 1 --rounds 1)
Latency: full-size E2SRI (random weights; compute does not depend on them) for 3 and 7
stacks at x2 and x4 on a 240x180 stream of synthetic events, ~7,900 events per stack (the
paper's density). Reported per output frame and split into stacking (SBN from the event
window), flow (OpenCV DIS between the central and each side stack) and network (forward
pass); the paper's Titan Xp figures are network-only (18.5, 19.4, 250.8, 450.9 ms).
Engines: the shipped x2 and x4 models (`reconstruct`'s default) through
`Reconstructor.from_state` with each installed engine (`model/inference/engines.py`), at
128x128, 240x180 and 346x260 with the model's events per stack scaled by sensor area (as
`reconstruct` does), on synthetic events: median ms per frame over `--frames` frames (after
one warm-up frame, in each of `--rounds` rounds over the engines) for stacking
(`stacks_at`), flow and network, and the largest difference of the output image in [0, 1]
from torch's on the same stacks. Exports land in the user's cache (see docs/evaluation.md),
made before timing.
Auto on real recordings (`--real PATH`, repeatable; skipped without): the issue 50 check of
`reconstruct` as a user runs it: the CLI as a child process with no `--engine` (auto) and
with `--engine torch`, back to back, `--rounds` times (default 3; `--limit` frames each);
per recording the engine auto chose and why, the median network ms per frame of each,
their ratio, and the PSNR (min and mean over frames) of auto's PNGs against torch's.
Memory: `reconstruct` as a child process on an event_utils HDF5 file of 1 million and of
100 million events (written here in chunks), 5 outputs spread over each file with the small
config; peak RSS from getrusage of the child.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import torch

from esim_lite.core.events import Events
from esim_lite.core.stacking import StackConfig, stack_sequence
from model import checkpoint
from model.archs.e2sri_arch import E2SRI, NetConfig
from model.inference.reconstruct import EventWindow, Reconstructor

HW = (180, 240)
PER_CHANNEL = 2637  # 3 x 2637 = 7,911 events per stack: 3,000 at 128x128 scaled by area


def synthetic(n: int, seed: int, t0: int = 0, hw: tuple[int, int] = HW) -> Events:
    rng = np.random.default_rng(seed)
    t = t0 + np.sort(rng.integers(0, n * 10_000, n))  # ~100k events/s
    return Events(rng.integers(0, hw[1], n).astype(np.int16),
                  rng.integers(0, hw[0], n).astype(np.int16), t.astype(np.int64),
                  rng.choice(np.array([-1, 1], np.int8), n), hw)


def latency(scale: int, n_stacks: int) -> dict[str, float]:
    torch.manual_seed(0)
    net = E2SRI(NetConfig(scale=scale, n_stacks=n_stacks)).eval()
    stacks_cfg = StackConfig(events_per_channel=PER_CHANNEL)
    model = Reconstructor(net, None, stacks_cfg, torch.device("cpu"))
    per, half = stacks_cfg.events_per_stack, n_stacks // 2
    events = synthetic((n_stacks + 2) * per, 1)
    anchor = (half + 1) * per
    with torch.inference_mode():  # warm-up at a small size (allocator, kernels)
        net(torch.zeros(1, n_stacks, 3, 32, 32), torch.zeros(1, 3, 32, 32),
            torch.zeros(1, n_stacks, 2, 32, 32))
    start = time.perf_counter()
    window = EventWindow(iter([events]), HW)
    ev, first = window.slice(anchor - (half + 1) * per, anchor + half * per)
    stacks = np.stack([s.image for s in stack_sequence(ev, stacks_cfg, anchor - first,
                                                       n_stacks)])
    stacking = time.perf_counter() - start
    _, timing = model.run(stacks, None)
    return {"stacking": stacking, **timing}


def engine_frames(models: list[Reconstructor], events: Events, frames: int, rounds: int
                  ) -> list[tuple[dict[str, float], list[np.ndarray]]]:
    """Per model: (median seconds per frame of stacking, flow and network, the output
    images of the first round) over ``rounds`` rounds. In a round each model in turn makes
    one warm-up output and then ``frames`` outputs at the ends of consecutive stacks, as a
    user's run would; the rounds spread a drift in the machine's speed (a shared VM's varies
    by tens of percent within minutes) over every engine alike. Taking turns frame by frame
    instead slowed whichever engine came next (the other engines' thread pools spin for a
    while after a call, and caches go cold)."""
    per, half = models[0].stacks.events_per_stack, models[0].net.config.n_stacks // 2
    times = [{"stacking": [], "flow": [], "network": []} for _ in models]
    images: list[list[np.ndarray]] = [[] for _ in models]
    for r in range(rounds):
        for model, spent, out in zip(models, times, images):
            window = EventWindow(iter([events]), events.sensor_hw)
            for k in range(frames + 1):
                t = int(events.t_ns[(half + 1 + k) * per - 1])
                start = time.perf_counter()
                given = model.stacks_at(window, t)
                stacking = time.perf_counter() - start
                image, timing = model.run(given.stacks, None)
                if k:  # the first output warms up caches and allocators
                    for key, v in {"stacking": stacking, **timing}.items():
                        spent[key].append(v)
                    if not r:
                        out.append(image)
    return [({k: float(np.median(v)) for k, v in spent.items()}, out)
            for spent, out in zip(times, images)]


def engine_rows(sizes: list[tuple[int, int]], frames: int, rounds: int) -> None:
    from model.calibration import simulated_inputs
    from model.inference.engines import ENGINES, bf16_units, installed
    from model.inference.pretrained import shipped_checkpoint

    available = [e for e in ENGINES if installed(e)
                 and (e != "openvino-bf16" or bf16_units())]
    print("| sensor | scale | engine | events per stack | stacking ms | flow ms | network ms "
          "| total ms | network vs torch | frame vs torch | max abs diff vs torch |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for hw in sizes:
        for scale in (2, 4):
            ckpt = shipped_checkpoint(scale)
            state = checkpoint.load(ckpt)
            models = [Reconstructor.from_state(state, str(ckpt), hw, device="cpu",
                                               engine=engine, calibrate=simulated_inputs)
                      for engine in available]
            per = models[0].stacks.events_per_stack
            events = synthetic((models[0].net.config.n_stacks + frames + 2) * per, 1, hw=hw)
            rows = engine_frames(models, events, frames, rounds)
            reference_t, reference = rows[0]  # torch comes first in ENGINES
            for model, (t, images) in zip(models, rows):
                diff = max(float(np.abs(a - b).max()) for a, b in zip(images, reference))
                print(f"| {hw[1]}x{hw[0]} | x{scale} | {model.engine_name} | {per:,} | "
                      f"{1e3 * t['stacking']:.1f} | {1e3 * t['flow']:.1f} | "
                      f"{1e3 * t['network']:.1f} | {1e3 * sum(t.values()):.1f} | "
                      f"{reference_t['network'] / t['network']:.2f}x | "
                      f"{sum(reference_t.values()) / sum(t.values()):.2f}x | {diff:.1e} |",
                      flush=True)


def cli_run(recording: str, out: Path, engine: str | None, limit: int | None
            ) -> tuple[str, float]:
    """``reconstruct`` as a child process: (its engine line, network ms per frame)."""
    argv = [recording, "--out", str(out), "--no-progress"] + (
        ["--engine", engine] if engine else []) + (["--limit", str(limit)] if limit else [])
    code = ("import sys; from model.cli import reconstruct_main; "
            f"sys.exit(reconstruct_main({argv!r}))")
    proc = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                          text=True)
    lines = proc.stdout.splitlines()
    engine_line = next(line for line in lines if line.startswith("engine "))
    network = next(line for line in lines if line.startswith("wrote ")).split(" network ")[1]
    return engine_line, float(network.split(",")[0])


def png_psnr(a: Path, b: Path) -> float:
    import cv2

    x, y = (cv2.imread(str(p), cv2.IMREAD_GRAYSCALE).astype(np.float64) for p in (a, b))
    mse = float(np.mean((x - y) ** 2))
    return 10 * np.log10(255 ** 2 / mse) if mse else float("inf")


def real_rows(recordings: list[str], rounds: int, limit: int | None) -> None:
    print("| recording | auto's engine (why) | torch network ms | auto network ms | "
          "network vs torch | PSNR auto vs torch, min / mean dB | frames |")
    print("|---|---|---|---|---|---|---|")
    for recording in recordings:
        with tempfile.TemporaryDirectory() as tmp:
            ms: dict[str, list[float]] = {"torch": [], "auto": []}
            for r in range(rounds):
                for engine in ("torch", "auto"):
                    line, network = cli_run(recording, Path(tmp) / f"{engine}{r}",
                                            engine if engine == "torch" else None, limit)
                    ms[engine].append(network)
                    if engine == "auto":
                        auto_line = line
            pngs = sorted((Path(tmp) / "auto0").glob("frame_*.png"))
            psnr = [png_psnr(p, Path(tmp) / "torch0" / p.name) for p in pngs]
        torch_ms, auto_ms = float(np.median(ms["torch"])), float(np.median(ms["auto"]))
        differ = [v for v in psnr if np.isfinite(v)]  # identical PNGs have no PSNR
        quality = (f"{min(differ):.1f} / {np.mean(differ):.1f}" if differ else "identical") \
            + (f" ({len(psnr) - len(differ)} identical)" if differ and len(differ) < len(psnr)
               else "")
        print(f"| {Path(recording).name} | {auto_line.removeprefix('engine ')} | "
              f"{torch_ms:.0f} | {auto_ms:.0f} | {torch_ms / auto_ms:.2f}x | {quality} | "
              f"{len(pngs)} |", flush=True)


def write_h5(path: Path, n: int, chunk: int = 5_000_000) -> None:
    with h5py.File(path, "w") as f:
        f.attrs["sensor_resolution"] = list(HW)
        ds = {k: f.create_dataset(f"events/{k}", (0,), dt, maxshape=(None,), chunks=(1 << 16,))
              for k, dt in (("xs", np.int16), ("ys", np.int16), ("ts", np.float64),
                            ("ps", np.uint8))}
        for start in range(0, n, chunk):
            ev = synthetic(min(chunk, n - start), start, t0=start * 10_000)
            for k, values in (("xs", ev.x), ("ys", ev.y), ("ts", ev.t_ns * 1e-9),
                              ("ps", (ev.p > 0).astype(np.uint8))):
                d = ds[k]
                d.resize(d.shape[0] + len(values), axis=0)
                d[-len(values):] = values


def small_checkpoint(path: Path) -> Path:
    from esim_lite.core.dataconf import load_yaml, to_yaml
    from model.config import TrainConfig

    cfg = load_yaml(TrainConfig, Path(__file__).resolve().parents[1] / "configs" /
                    "train_small.yaml")
    net = E2SRI(cfg.model)
    return checkpoint.save(path, model=net.state_dict(), config=to_yaml(cfg),
                           net=checkpoint.net_args(net), sensor_hw=(128, 128))


def peak_rss(h5: Path, ckpt: Path, out: Path, rate_hz: float) -> tuple[float, float, float]:
    """(peak RSS MB of the child itself, seconds, time of the last output in s)."""
    code = ("import resource, sys; from model.cli import reconstruct_main; "
            f"rc = reconstruct_main([{str(h5)!r}, '--checkpoint', {str(ckpt)!r}, '--out', "
            f"{str(out)!r}, '--at', 'rate', '--rate', {str(rate_hz)!r}, '--limit', '5', "
            "'--no-progress']); "
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); "
            "sys.exit(rc)")
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                          text=True)
    seconds = time.perf_counter() - start
    rss_kb = int(proc.stderr.strip().splitlines()[-1])
    last = float((out / "timestamps.txt").read_text().split()[-1])
    return rss_kb / 1024, seconds, last


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--skip-latency", action="store_true")
    parser.add_argument("--skip-engines", action="store_true")
    parser.add_argument("--skip-memory", action="store_true")
    parser.add_argument("--frames", type=int, default=5,
                        help="timed frames per engine row and round")
    parser.add_argument("--rounds", type=int, default=3,
                        help="rounds over the engines (a median over all of them)")
    parser.add_argument("--sizes", default="128x128,240x180,346x260",
                        help="sensor sizes (WxH) of the engine rows")
    parser.add_argument("--real", action="append", default=[],
                        help="a real recording for the auto-vs-torch rows (repeatable)")
    parser.add_argument("--limit", type=int, help="frames per --real run (default: all)")
    args = parser.parse_args(argv)
    torch.set_num_threads(2)
    print(f"# {' '.join(['python'] + sys.argv)}; torch {torch.__version__}, CPU, 2 threads")
    if not args.skip_latency:
        print("| stacks | scale | stacking ms | flow ms | network ms | total ms | paper (Titan Xp,"
              " network) ms |")
        print("|---|---|---|---|---|---|---|")
        paper = {(3, 2): 18.5, (3, 4): 19.4, (7, 2): 250.8, (7, 4): 450.9}
        for n in (3, 7):
            for s in (2, 4):
                t = latency(s, n)
                print(f"| {n} | x{s} | {1e3 * t['stacking']:.0f} | {1e3 * t['flow']:.0f} | "
                      f"{1e3 * t['network']:.0f} | {1e3 * sum(t.values()):.0f} | "
                      f"{paper[(n, s)]} |", flush=True)
    if not args.skip_engines:
        print()
        sizes = [tuple(int(v) for v in size.split("x"))[::-1] for size in args.sizes.split(",")]
        engine_rows(sizes, args.frames, args.rounds)
    if args.real:
        print()
        real_rows(args.real, args.rounds, args.limit)
    if not args.skip_memory:
        print("\n| events in file | file MB | recording s | last output at s | peak RSS MB | "
              "seconds |")
        print("|---|---|---|---|---|---|")
        with tempfile.TemporaryDirectory() as tmp:
            ckpt = small_checkpoint(Path(tmp) / "small.pt")
            for n in (1_000_000, 100_000_000):
                h5 = Path(tmp) / f"e{n}.h5"
                write_h5(h5, n)
                duration_s = n * 10_000 * 1e-9
                rss, sec, last = peak_rss(h5, ckpt, Path(tmp) / f"out{n}", 4.5 / duration_s)
                print(f"| {n:,} | {h5.stat().st_size / 1e6:.0f} | {duration_s:.0f} | "
                      f"{last:.0f} | {rss:.0f} | {sec:.0f} |", flush=True)
                h5.unlink()
    return 0


if __name__ == "__main__":
    sys.exit(main())
