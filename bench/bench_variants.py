"""Choosing the CPU variant of E2SRI: cost and quality of candidate configs side by side.

Run: .venv/bin/python bench/bench_variants.py CONFIG[:RUN_DIR] ... [--latency]
For each config: parameters, MFLOPs per output frame (one 128x128 event frame to its HR
image; multiply-adds of every convolution, counted by hooks, x2), training samples/s (full
steps: forward, L1 + LPIPS, backward, Adam; batch and crop of the config, channels_last,
float32, this process's threads), and, when RUN_DIR is given, the validation metrics that
run (``train --config CONFIG --out RUN_DIR``) reached, read from its val_history.csv, with
its steps and wall minutes. ``--latency`` adds the CPU time of one output frame at 240x180
-> x scale (the DAVIS240's sensor) in inference mode.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import time
from pathlib import Path

import torch

from esim_lite.core.dataconf import load_yaml
from model.archs.e2sri_arch import E2SRI, count_parameters
from model.config import TrainConfig
from model.losses.similarity import SimilarityLoss


def example(cfg, b: int, h: int, w: int):
    g = torch.Generator().manual_seed(0)
    n = cfg.model.n_stacks
    stacks = torch.randint(-1, 2, (b, n, 3, h, w), generator=g).float()
    return stacks, stacks[:, n // 2], torch.randn(b, n, 2, h, w, generator=g)


def mflops(net: E2SRI, cfg, h: int = 128, w: int = 128) -> float:
    """Forward MFLOPs (2 x multiply-adds of the convolutions) for one output frame."""
    total = [0]

    def hook(mod, inp, out):
        if isinstance(mod, torch.nn.ConvTranspose2d):  # every input pixel spreads a kernel
            pixels = inp[0].shape[-2] * inp[0].shape[-1]
        else:
            pixels = out.shape[-2] * out.shape[-1]
        total[0] += pixels * mod.weight.numel() * inp[0].shape[0]

    handles = [m.register_forward_hook(hook) for m in net.modules()
               if isinstance(m, (torch.nn.Conv2d, torch.nn.ConvTranspose2d))]
    with torch.no_grad():
        net(*example(cfg, 1, h, w))
    for hd in handles:
        hd.remove()
    return 2 * total[0] / 1e6


def train_rate(net: E2SRI, cfg, steps: int = 6) -> float:
    loss_fn = SimilarityLoss(cfg.loss.lpips_weight)
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    net = net.to(memory_format=torch.channels_last)
    b, c, s = cfg.optim.batch_size, cfg.data.crop or 64, cfg.model.scale
    stacks, central, flows = example(cfg, b, c, c)
    hr = torch.rand(b, 1, s * c, s * c)
    times = []
    for i in range(steps + 1):
        start = time.perf_counter()
        loss, _ = loss_fn(net(stacks, central, flows), hr)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if i:
            times.append(time.perf_counter() - start)
    return b / statistics.median(times)


def latency_ms(net: E2SRI, cfg, repeats: int = 5) -> float:
    net = net.eval().to(memory_format=torch.channels_last)
    x = example(cfg, 1, 180, 240)
    times = []
    with torch.inference_mode():
        for i in range(repeats + 1):
            start = time.perf_counter()
            net(*x)
            if i:
                times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def run_facts(run: Path) -> dict:
    facts = {}
    hist = run / "val_history.csv"
    if hist.is_file():
        with open(hist) as f:
            rows = list(csv.DictReader(f))
        if rows:
            facts.update({k: float(v) for k, v in rows[-1].items() if v})
    result = run / "result.json"
    if result.is_file():
        facts["minutes"] = json.loads(result.read_text()).get("train_hours", 0) * 60
    return facts


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("items", nargs="+", metavar="CONFIG[:RUN_DIR]")
    p.add_argument("--latency", action="store_true")
    args = p.parse_args(argv)
    print(f"# {' '.join(['python'] + sys.argv)}; torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads")
    head = "| config | params | MFLOPs/frame | train samples/s |"
    if args.latency:
        head += " ms/frame 240x180 |"
    head += " steps | minutes | val PSNR | val SSIM | val LPIPS |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for item in args.items:
        path, _, run = item.partition(":")
        cfg = load_yaml(TrainConfig, path)
        torch.manual_seed(0)
        net = E2SRI(cfg.model)
        cells = [Path(path).stem, f"{count_parameters(net) / 1e6:.3f}M",
                 f"{mflops(net, cfg):.0f}", f"{train_rate(net, cfg):.1f}"]
        if args.latency:
            cells.append(f"{latency_ms(E2SRI(cfg.model), cfg):.0f}")
        f = run_facts(Path(run)) if run else {}
        cells += [f"{int(f['step'])}" if "step" in f else "-",
                  f"{f['minutes']:.1f}" if "minutes" in f else "-"]
        cells += [f"{f[k]:.{d}f}" if k in f else "-"
                  for k, d in (("psnr", 2), ("ssim", 3), ("lpips", 3))]
        print("| " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
