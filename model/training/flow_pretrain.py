"""Pre-train the learnable FNet on the simulator's exact flow (``task: flow``).

The simulator knows the scene is a plane and knows every pose, so the flow between the
central stack's end time and each side stack's end time is exact
(:func:`esim_lite.geometry.motion.planar_flow`). The loss is the end-point error (EPE, pixels);
validation reports it beside two baselines: zero flow and OpenCV's DIS on the stacks.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader
from tqdm import tqdm

from esim_lite.core.atomic import write_text
from esim_lite.core.dataconf import to_yaml
from model import checkpoint
from model.archs.flow import FlowNet
from model.config import TrainConfig
from model.data.classical_flow import stack_flows
from model.data.dataset import ShardSamples
from model.training.setup import build_data, epoch_batches


def epe(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean end-point error (pixels) of ``(..., 2, H, W)`` flows."""
    return torch.linalg.vector_norm(pred - target, dim=-3).mean()


def _side_pairs(batch: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(central, side, exact flow) for every side stack of the batch, stacked on dim 0."""
    stacks, flows = batch["stacks"], batch["flows"]
    mid = stacks.shape[1] // 2
    sides = [j for j in range(stacks.shape[1]) if j != mid]
    central = stacks[:, mid:mid + 1].expand(-1, len(sides), -1, -1, -1)
    return (central.flatten(0, 1), stacks[:, sides].flatten(0, 1), flows[:, sides].flatten(0, 1))


@torch.inference_mode()
def validate(net: FlowNet, data: ShardSamples, limit: int = 64) -> dict[str, float]:
    """EPE of the net, of zero flow and of DIS on up to ``limit`` held-out samples."""
    net.eval()
    sums, count = {"learned": 0.0, "zero": 0.0, "dis": 0.0}, 0
    for i in range(min(limit, len(data))):
        sample = data[i]
        central, side, exact = _side_pairs({k: v[None] for k, v in sample.items()})
        sums["learned"] += float(epe(net(central, side), exact))
        sums["zero"] += float(epe(torch.zeros_like(exact), exact))
        raw = np.round(sample["stacks"].numpy() * 127.5 + 127.5).astype(np.uint8)
        dis = torch.from_numpy(stack_flows(raw, "dis"))
        mid = raw.shape[0] // 2
        sums["dis"] += float(epe(dis[[j for j in range(raw.shape[0]) if j != mid]], exact))
        count += 1
    net.train()
    return {k: v / max(count, 1) for k, v in sums.items()}


def pretrain_flow(config: TrainConfig, data: str | Path, out: str | Path,
                  show_progress: bool = True) -> dict:
    """Train :class:`FlowNet` on exact flow; writes ``out/flow_last.pt`` and ``result.json``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    run, optim = config.run, config.optim
    data_cfg = dataclasses.replace(config.data, flow="exact")
    torch.manual_seed(run.seed)
    samples = build_data(config, data, data_config=data_cfg, use_cache=False, spread_val=False)
    train_set, val_set, steps_per_epoch = (samples.train_set, samples.val_set,
                                           samples.steps_per_epoch)
    net = FlowNet(config.model.stack_channels)
    opt = torch.optim.Adam(net.parameters(), lr=optim.lr)
    total = optim.epochs * steps_per_epoch if run.max_steps is None else run.max_steps
    before = validate(net, val_set) if len(val_set) else {}
    step, epoch, start, losses = 0, 0, time.perf_counter(), []
    bar = tqdm(total=total, disable=not show_progress, unit="step", desc="flow")
    while step < total:
        train_set.set_epoch(epoch)
        batches = epoch_batches(len(train_set), optim.batch_size, run.seed, epoch)
        for batch in DataLoader(train_set, batch_sampler=batches, num_workers=run.workers):
            central, side, exact = _side_pairs(batch)
            loss = epe(net(central, side), exact)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
            step += 1
            bar.update(1)
            bar.set_postfix(epe=f"{losses[-1]:.3f}")
            if step >= total or (run.max_minutes and
                                 time.perf_counter() - start > 60 * run.max_minutes):
                total = step
                break
        epoch += 1
    bar.close()
    checkpoint.save(out / "flow_last.pt", flow_net=net.state_dict(), step=step,
                    config=to_yaml(config))
    result = {"step": step, "train_epe_first": losses[0], "train_epe_last": losses[-1],
              "val_before": before, "val": validate(net, val_set) if len(val_set) else {},
              "seconds": time.perf_counter() - start}
    write_text(out / "result.json", json.dumps(result, indent=2))
    return result
