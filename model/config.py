"""The training configuration record (one YAML file per experiment in configs/)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

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
        fill_unseen: score L1 and LPIPS against a target whose pixels outside the fired
            region are a smooth fill of those inside it (model/losses/unseen.py; False =
            the true image everywhere, the paper's loss).
        fill_dilate: LR pixels the fired region is widened by before the fill.
    """

    lpips_weight: float = 0.01
    unfired_tv: float = 0.0
    unfired_dilate: int = 1
    fill_unseen: bool = False
    fill_dilate: int = 2

    def __post_init__(self) -> None:
        if self.lpips_weight < 0 or self.unfired_tv < 0 or self.unfired_dilate < 0 \
                or self.fill_dilate < 0:
            raise ValueError("loss weights, loss.unfired_dilate and loss.fill_dilate must be "
                             ">= 0")


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
        if self.model.memory != (self.data.clip > 1):
            raise ValueError(f"model.memory ({self.model.memory}) and data.clip "
                             f"({self.data.clip}) go together: a network that carries its "
                             f"state across outputs trains on clips of 2 or more consecutive "
                             f"outputs, and only such a network needs them")
