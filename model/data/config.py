"""How training samples are cut from the shards: the ``data:`` section of a training config.

Kept apart from the dataset itself so that a checkpoint's config can be rebuilt (by
training and by inference alike) without the data pipeline.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from esim_lite.core.stacking import StackConfig


@dataclass(frozen=True)
class DataConfig:
    """How samples are cut from the shards.

    Attributes:
        stacks: SBN settings (events per channel, channels, cap, overlap).
        crop: LR crop side for training (the paper's 64); None trains on whole frames.
        val_fraction: share of sequences held out (by a hash of shard and sequence name).
        flow: classical flow computed here (``dis``, ``farneback``), ``exact`` (the
            simulator's analytic flow between the stacks' end times: training targets for
            the learned FNet), or ``none``.
        flips: random horizontal/vertical flips in training.
        cache: precompute SBN stacks, flow and frames once into ``<data>/cache/`` and train
            from memory maps (model/data/input_cache.py); flow is then computed on whole frames.
        stack_rule: SBN events per stack per sequence. ``fixed`` (the paper, and the first
            shipped models): ``stacks.events_per_stack`` everywhere.
            ``active``: the number reconstruction's active-pixel rule gives a recording of
            the sequence's activity (model/stack_size.py: ``stacks`` per fully
            active sensor, times the share of pixels firing >= 2 events in the first
            second), so a static camera watching small objects trains on the short, sparse
            stacks a real one is given, not on stacks that span seconds of sensor noise.
    """

    stacks: StackConfig = field(default_factory=StackConfig)
    crop: int | None = 64
    val_fraction: float = 0.1
    flow: Literal["dis", "farneback", "exact", "none"] = "dis"
    flips: bool = True
    cache: bool = False
    stack_rule: Literal["fixed", "active"] = "fixed"

    def __post_init__(self) -> None:
        if self.stack_rule not in ("fixed", "active"):
            raise ValueError(f"data.stack_rule must be fixed or active, got {self.stack_rule!r}")
        if self.stack_rule == "active" and (self.stacks.method != "sbn" or self.stacks.overlap):
            raise ValueError("data.stack_rule: active needs SBN stacks without overlap")
        if self.crop is not None and self.crop < 16:
            raise ValueError("crop must be >= 16 (or null for whole frames)")
        if not 0 <= self.val_fraction < 1:
            raise ValueError("val_fraction must be in [0, 1)")
