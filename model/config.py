"""The training configuration record (one YAML file per experiment in configs/)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from model.archs.e2sri_arch import NetConfig
from model.data.config import DataConfig


@dataclass(frozen=True)
class LossConfig:
    """The training loss: L1 + ``lpips_weight`` LPIPS + ``unfired_tv`` TV(unfired).

    Attributes:
        lpips_weight: lambda of L1 + lambda * LPIPS (the paper: 0.01; 0 = L1 only).
        unfired_tv: weight of the output's total variation where no event fired
            (model/losses/unfired.py; 0 = off, the paper's loss): each event-free region
            may take one level, and levels change only where events fired.
        unfired_dilate: LR pixels the fired region is widened by before that term.
    """

    lpips_weight: float = 0.01
    unfired_tv: float = 0.0
    unfired_dilate: int = 1

    def __post_init__(self) -> None:
        if self.lpips_weight < 0 or self.unfired_tv < 0 or self.unfired_dilate < 0:
            raise ValueError("loss weights and loss.unfired_dilate must be >= 0")


@dataclass(frozen=True)
class OptimConfig:
    """Adam and the learning-rate schedule.

    Attributes:
        schedule: ``paper`` (decay x10 at every half of the remaining epochs: E/2, 3E/4,
            7E/8, ...), ``released`` (x10 at 50% and 75% of the epochs, the authors' code),
            or ``constant``.
        lr: initial learning rate (paper 0.01, released code 1e-4).
    """

    lr: float = 1e-4
    schedule: Literal["paper", "released", "constant"] = "released"
    epochs: int = 100
    batch_size: int = 8
    betas: tuple[float, float] = (0.9, 0.999)
    weight_decay: float = 0.0
    grad_clip: float | None = None

    def __post_init__(self) -> None:
        if self.lr <= 0 or self.epochs < 1 or self.batch_size < 1:
            raise ValueError("lr must be > 0, epochs and batch_size >= 1")


@dataclass(frozen=True)
class RunConfig:
    """Everything about running rather than learning.

    Attributes:
        seed: data order, augmentation and initial weights.
        workers: DataLoader worker processes per training process.
        max_steps, max_minutes: stop early (the first that is reached).
        log_every, val_every, checkpoint_every: in optimiser steps (0 = only at the end).
        val_batches: validation batches per evaluation (None = the whole held-out split);
            the frames are spread evenly over all held-out sequences.
        amp: mixed precision on GPUs (bfloat16 where supported, else float16 with a scaler).
        cpu_amp: bfloat16 autocast on the CPU. Off by default: on CPUs without AMX it can
            make E2SRI's training steps slower, not faster (bench/bench_train.py measures
            it on yours).
        channels_last: NHWC memory format (GPUs and CPUs; faster for these convs on both).
        threads: intra-op CPU threads (None: torch's default, one per core).
        first_pass: a trained main-model checkpoint producing the central input when
            ``model.central == first_pass`` (Duo-Pass).
        flow_init: a ``task: flow`` checkpoint initialising the learned FNet
            (``model.flow == learned``).
        init_from: a network checkpoint or shipped model whose weights start this run (its
            network may differ only in the scale; model/training/warm_start.py). A resumed
            run takes its weights from its own checkpoint instead.
    """

    seed: int = 0
    workers: int = 2
    max_steps: int | None = None
    max_minutes: float | None = None
    log_every: int = 20
    val_every: int = 500
    checkpoint_every: int = 500
    val_batches: int | None = None
    amp: bool = True
    cpu_amp: bool = False
    channels_last: bool = True
    threads: int | None = None
    first_pass: str | None = None
    flow_init: str | None = None
    init_from: str | None = None


@dataclass(frozen=True)
class TrainConfig:
    """``task``: ``e2sri`` trains the network; ``flow`` pre-trains the learnable FNet on the
    simulator's exact flow (model/training/flow_pretrain.py)."""

    task: Literal["e2sri", "flow"] = "e2sri"
    model: NetConfig = field(default_factory=NetConfig)
    data: DataConfig = field(default_factory=DataConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    run: RunConfig = field(default_factory=RunConfig)

    def __post_init__(self) -> None:
        # the network's input width is the stacks' channel count: a mismatch would
        # otherwise surface only as a shape error in the first forward pass
        if self.model.stack_channels != self.data.stacks.channels:
            raise ValueError(f"model.stack_channels ({self.model.stack_channels}) must equal "
                             f"data.stacks.channels ({self.data.stacks.channels}): the "
                             f"network takes the stacks' channels as its input")


RETIRED_AT = "9e72ba2"
"""The last commit holding the experiments' switches below (docs/notes/experiments.md)."""

ANY = object()
RETIRED: dict[str, Any] = {
    "model.fold": 1, "model.context_far": "cells", "model.context_global": False,
    "model.context_support": False, "model.context_gate": 0.0, "model.history": [],
    "model.memory": False, "data.clip": 1, "data.clip_stride": 1, "loss.fill_unseen": False,
    "loss.fill_dilate": ANY}
"""Settings of experiments that did not ship, with the value at which each did nothing.
Checkpoints written before they were removed store them; a stored value that did nothing is
dropped when the checkpoint is read, any other refused (that network or loss is gone)."""


def _neutral(value: Any, neutral: Any) -> bool:
    if neutral is ANY:
        return True
    if isinstance(neutral, list):
        return isinstance(value, (list, tuple)) and list(value) == neutral
    return value == neutral


def without_retired(data: Mapping[str, Any], source: str, prefix: str = "") -> dict[str, Any]:
    """``data`` (a training config mapping, or with ``prefix`` one of its sections, e.g.
    ``"model."`` for a checkpoint's network arguments) without the :data:`RETIRED` settings.

    Raises:
        ValueError: a retired setting holds a value other than the one at which it did
            nothing (the message names it and the commit that still has its code).
    """
    out: dict[str, Any] = {}
    for key, value in data.items():
        dotted = prefix + str(key)
        if isinstance(value, Mapping) and not prefix:
            out[key] = without_retired(value, source, dotted + ".")
        elif dotted not in RETIRED:
            out[key] = value
        elif not _neutral(value, RETIRED[dotted]):
            raise ValueError(f"{source}: {dotted} = {value!r}: an experiment's setting that "
                             f"e2sr no longer has (docs/notes/experiments.md; its code is at "
                             f"commit {RETIRED_AT})")
    return out
