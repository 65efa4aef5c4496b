"""Building what training needs before its first step: processes, samples, batches.

Shared by network training (:mod:`model.training.train`) and flow pre-training
(:mod:`model.training.flow_pretrain`), so both read the same samples in the same order.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.distributed as dist

from datagen.shard import find_shards
from model.config import TrainConfig
from model.data.config import DataConfig
from model.data.dataset import ShardSamples, index_samples
from model.data.input_cache import CacheSpec, InputCache


@dataclass(frozen=True)
class Distributed:
    rank: int = 0
    world: int = 1
    device: torch.device = torch.device("cpu")

    @property
    def main(self) -> bool:
        return self.rank == 0


def init_distributed() -> Distributed:
    """One process, or the one torchrun started us as (``WORLD_SIZE`` > 1)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    cuda = torch.cuda.is_available()
    if world == 1:
        return Distributed(device=torch.device("cuda" if cuda else "cpu"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if cuda:
        torch.cuda.set_device(local)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    return Distributed(dist.get_rank(), world,
                       torch.device(f"cuda:{local}" if cuda else "cpu"))


def epoch_batches(n: int, batch: int, seed: int, epoch: int, rank: int = 0, world: int = 1
                  ) -> list[list[int]]:
    """This rank's batches of epoch ``epoch``: a permutation seeded by (seed, epoch), cut to
    whole batches for every rank (all ranks must take the same number of steps, or DDP
    waits forever), dealt round-robin to ranks."""
    g = torch.Generator().manual_seed(seed * 1_000_003 + epoch)
    usable = n // (batch * world) * batch * world
    order = torch.randperm(n, generator=g)[:usable][rank::world].tolist()
    return [order[i:i + batch] for i in range(0, len(order), batch)]


@dataclass(frozen=True)
class TrainData:
    """The samples of one run: training and held-out, with the facts the loop needs."""

    shards: list[Path]
    train_set: ShardSamples
    val_set: ShardSamples
    sensor_hw: tuple[int, int]
    steps_per_epoch: int


def build_data(config: TrainConfig, data: str | Path, env: Distributed = Distributed(), *,
               data_config: DataConfig | None = None, use_cache: bool = True,
               spread_val: bool = True) -> TrainData:
    """Index the shards in ``data`` into training and held-out samples.

    ``data_config`` replaces ``config.data`` (flow pre-training asks for exact flow);
    ``use_cache`` builds or opens the precomputed inputs when ``data.cache`` is on;
    ``spread_val`` keeps ``run.val_batches`` batches spread over every held-out sequence.

    Raises:
        ValueError: fewer training samples than one batch per process.
    """
    cfg, run = config, config.run
    data_cfg = data_config or cfg.data
    shards = find_shards(data)
    train_refs, val_refs = index_samples(shards, data_cfg, cfg.model.n_stacks, cfg.model.scale)
    if spread_val and run.val_batches is not None:
        val_refs = spread(val_refs, run.val_batches * cfg.optim.batch_size)
    cache = None
    if use_cache and data_cfg.cache:
        spec = CacheSpec(data_cfg.stacks, data_cfg.flow, cfg.model.n_stacks, cfg.model.scale,
                         data_cfg.stack_rule)
        cache = InputCache.build(shards, train_refs + val_refs, spec,
                                 workers=max(1, os.cpu_count() or 1) if env.main else 1)
    train_set = ShardSamples(train_refs, data_cfg, cfg.model.n_stacks, cfg.model.scale, True,
                             run.seed, cache)
    val_set = ShardSamples(val_refs, data_cfg, cfg.model.n_stacks, cfg.model.scale, False,
                           cache=cache)
    steps = len(epoch_batches(len(train_set), cfg.optim.batch_size, run.seed, 0, env.rank,
                              env.world))
    if steps == 0:
        raise ValueError(f"{data}: {len(train_set)} training samples, fewer than the batch "
                         f"size {cfg.optim.batch_size} x {env.world} process(es)")
    return TrainData(shards, train_set, val_set, sensor_of(shards[0]), steps)


def spread(items: list, n: int) -> list:
    """``n`` items evenly spaced over ``items`` (all of them if there are no more than n)."""
    if len(items) <= n:
        return items
    return [items[int(i * len(items) / n)] for i in range(n)]


def sensor_of(shard: Path) -> tuple[int, int]:
    """(H, W) of the event sensor the training data was simulated with."""
    from datagen.shard import ShardReader

    with ShardReader(shard) as reader:
        return reader.sensor_hw(reader.sequences()[0])
