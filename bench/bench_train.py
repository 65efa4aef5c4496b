"""Training throughput on this machine: the model's consumption and the data pipeline's supply.

Run: .venv/bin/python bench/bench_train.py [--data SHARDS] [--quick]
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

from esim_lite.dataconf import load_yaml
from model.config import TrainConfig
from model.dataset import ShardSamples, find_shards, index_samples
from model.e2sri_arch import E2SRI, count_parameters
from model.losses import SimilarityLoss

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data", help="shards to read (default: simulate a small x2 set)")
    parser.add_argument("--quick", action="store_true")
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
