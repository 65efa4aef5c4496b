"""Training throughput on this machine: the model's consumption and the data pipeline's supply.

Run: .venv/bin/python bench/bench_train.py [--data SHARDS] [--quick]
     .venv/bin/python bench/bench_train.py --options [--data SHARDS] [--steps N]
--options: end-to-end samples/s of real training steps fed by the real data pipeline, for
each throughput option in turn (today's path; the input cache instead of data workers;
channels_last; bfloat16 autocast; torch.compile; the CPU variant), at 2 threads and 1.
Model: samples/s of a full training step (forward, L1 + 0.01 LPIPS, backward, Adam) at each
config's crop, on inputs of the right shape (compute does not depend on the values); batch 8
for the small config, batch 1 for the full-size ones (x4 with 7 stacks adds 4.8 GB per
sample, so batch 8 would need ~39 GB, more than this machine has). "RSS growth" is the
memory the steps added (activations, gradients, Adam state). Data: samples/s that a
2-worker DataLoader delivers from real shards (read events, build SBN stacks, DIS flow,
crop, flip). Peak RSS is this process's (model side) and the
largest worker's (data side). Without --data, a small x2 dataset is simulated first
(homography backend).
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from datagen.shard import find_shards
from esim_lite.core.dataconf import load_yaml
from model.archs.e2sri_arch import E2SRI, count_parameters
from model.config import TrainConfig
from model.data.dataset import ShardSamples, index_samples
from model.losses.similarity import SimilarityLoss

ROOT = Path(__file__).resolve().parents[1]


def model_rate(cfg: TrainConfig, steps: int, batch: int) -> tuple[float, float, float]:
    """(samples/s, parameters in millions, peak RSS growth in MB) of training steps."""
    torch.manual_seed(0)
    net = E2SRI(cfg.model)
    loss_fn = SimilarityLoss(cfg.loss.lpips_weight)
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    b, n, c, s = batch, cfg.model.n_stacks, cfg.data.crop or 64, cfg.model.scale
    rss0 = _rss_mb()
    stacks = torch.randint(-1, 2, (b, n, 3, c, c)).float()
    flows, hr = torch.randn(b, n, 2, c, c), torch.rand(b, 1, s * c, s * c)
    times = []
    for i in range(steps + 1):
        start = time.perf_counter()
        loss, _ = loss_fn(net(stacks, stacks[:, n // 2], flows), hr)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if i:  # the first step warms up allocators and kernels
            times.append(time.perf_counter() - start)
    return b / statistics.median(times), count_parameters(net) / 1e6, _rss_mb() - rss0


def _rss_mb() -> float:
    """Current resident memory of this process (MB), from /proc."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def data_rate(cfg: TrainConfig, shards: Path, batches: int) -> float:
    refs, _ = index_samples(find_shards(shards), cfg.data, cfg.model.n_stacks, cfg.model.scale)
    ds = ShardSamples(refs, cfg.data, cfg.model.n_stacks, cfg.model.scale, True)
    loader = DataLoader(ds, batch_size=cfg.optim.batch_size, shuffle=True, num_workers=2,
                        persistent_workers=False)
    n, start = 0, None
    while True:  # epochs until enough batches; worker start-up of the first is not timed
        for batch in loader:
            if start is None:
                start = time.perf_counter()
                continue
            n += len(batch["hr"])
            if n >= batches * cfg.optim.batch_size:
                return n / (time.perf_counter() - start)


def pipeline_rate(cfg: TrainConfig, shards: Path, steps: int, *, cache: bool, workers: int,
                  channels_last: bool, bf16: bool, compile_: bool = False) -> float:
    """Samples/s of whole training steps fed by the real data pipeline (DataLoader over
    shards, or over the input cache), the way train() runs them."""
    from model.data.input_cache import CacheSpec, InputCache

    refs, _ = index_samples(find_shards(shards), cfg.data, cfg.model.n_stacks, cfg.model.scale)
    store = InputCache.build(find_shards(shards), refs, CacheSpec(
        cfg.data.stacks, cfg.data.flow, cfg.model.n_stacks, cfg.model.scale), 2) \
        if cache else None
    ds = ShardSamples(refs, cfg.data, cfg.model.n_stacks, cfg.model.scale, True, 0, store)
    loader = DataLoader(ds, batch_size=cfg.optim.batch_size, shuffle=True,
                        num_workers=workers, persistent_workers=workers > 0)
    torch.manual_seed(0)
    net = E2SRI(cfg.model)
    if channels_last:
        net = net.to(memory_format=torch.channels_last)
    model = torch.compile(net) if compile_ else net
    loss_fn = SimilarityLoss(cfg.loss.lpips_weight)
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    done, start, warm = 0, None, 3  # the first steps warm up workers, allocators, compiler
    while True:
        for batch in loader:
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                out = model(batch["stacks"], batch["stacks"][:, cfg.model.n_stacks // 2],
                            batch["flows"])
            loss, _ = loss_fn(out.float(), batch["hr"])
            opt.zero_grad()
            loss.backward()
            opt.step()
            warm -= 1
            if warm == 0:
                start = time.perf_counter()
            elif warm < 0:
                done += len(batch["hr"])
                if done >= steps * cfg.optim.batch_size:
                    return done / (time.perf_counter() - start)


OPTIONS = [  # (label, config, cache, workers, channels_last, bf16, compile)
    ("small config (train_small), 2 data workers, NCHW float32", "train_small",
     False, 2, False, False, False),
    ("+ input cache (no data workers)", "train_small", True, 0, False, False, False),
    ("+ channels_last", "train_small", True, 0, True, False, False),
    ("+ bfloat16 autocast", "train_small", True, 0, True, True, False),
    ("+ torch.compile (float32)", "train_small", True, 0, True, False, True),
    ("CPU variant (train_x2_cpu): cache, channels_last, float32", "train_x2_cpu", True, 0,
     True, False, False),
    ("CPU variant + bfloat16 autocast", "train_x2_cpu", True, 0, True, True, False),
]


def options_table(shards: Path, steps: int, threads: int) -> None:
    torch.set_num_threads(threads)
    print(f"\nEnd-to-end training throughput, {threads} thread(s) ({steps} steps each):\n")
    print("| option | config | samples/s | vs today |")
    print("|---|---|---|---|")
    base = None
    for label, name, cache, workers, cl, bf16, comp in OPTIONS:
        cfg = load_yaml(TrainConfig, ROOT / "configs" / f"{name}.yaml")
        try:
            rate = pipeline_rate(cfg, shards, steps, cache=cache, workers=workers,
                                 channels_last=cl, bf16=bf16, compile_=comp)
        except Exception as exc:  # e.g. torch.compile without a working compiler
            print(f"| {label} | {name} | failed: {type(exc).__name__} | - |", flush=True)
            continue
        base = base or rate
        print(f"| {label} | {name} | {rate:.1f} | {rate / base:.2f}x |", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data", help="shards to read (default: simulate a small x2 set)")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--options", action="store_true",
                        help="only the end-to-end table of throughput options")
    parser.add_argument("--steps", type=int, default=30)
    args = parser.parse_args(argv)
    torch.set_num_threads(2)
    print(f"# {' '.join(['python'] + sys.argv)}; torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")
    with tempfile.TemporaryDirectory() as tmp:
        shards = Path(args.data) if args.data else Path(tmp) / "shards"
        if not args.data:
            subprocess.run([sys.executable, "-m", "datagen.cli", "generate", "--n-seq", "4",
                            "--out", str(shards), "--no-progress", "--set",
                            "simulation.render.backend=homography"], check=True,
                           stdout=subprocess.DEVNULL)
        if args.options:
            for threads in (2, 1):
                options_table(shards, args.steps, threads)
            return 0
        print("| config | params | batch x crop | model samples/s | RSS growth MB | "
              "data samples/s (2 workers) |")
        print("|---|---|---|---|---|---|")
        names = ["train_small", "train_x2_3s", "train_x2_7s", "train_x4_3s", "train_x4_7s"]
        for name in names[:2] if args.quick else names:
            cfg = load_yaml(TrainConfig, ROOT / "configs" / f"{name}.yaml")
            small = name == "train_small"
            batch = cfg.optim.batch_size if small else 1  # batch 8 of x4 7S: ~39 GB
            rate, params, grown = model_rate(cfg, 5 if small else 2, batch)
            if cfg.model.scale == 2:
                supply = f"{data_rate(cfg, shards, 10 if args.quick else 30):.0f}"
            else:
                supply = "(x4 data not simulated)"
            print(f"| {name} | {params:.2f}M | {batch} x {cfg.data.crop} | {rate:.2f} | "
                  f"{grown:.0f} | {supply} |", flush=True)
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    workers = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"\npeak RSS: training process {own:.0f} MB, largest data worker or child "
          f"{workers:.0f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
