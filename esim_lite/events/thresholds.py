"""Contrast thresholds: drawn per sequence, optionally mismatched per pixel."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Smallest threshold any pixel may get after mismatch (log units).
MIN_THRESHOLD = 0.01


@dataclass(frozen=True)
class ThresholdConfig:
    """Ranges the per-sequence thresholds are drawn from (uniformly, independently).

    The defaults span E2VID's N(0.18, 0.03) to +-2 sigma, the recipe the E2SRI paper follows
    so that the network cannot adapt to one camera's thresholds.

    Attributes:
        pos_range: (min, max) ON threshold C+ in log-intensity units.
        neg_range: (min, max) OFF threshold C- in log-intensity units.
        mismatch_std: std of the per-pixel Gaussian deviation around each threshold, drawn
            once per pixel (0 disables); results are clamped to >= 0.01.
        mismatch_relative: a further std in proportion to the sequence's threshold (0.1:
            10% of C+ for the ON map, of C- for the OFF one), added to ``mismatch_std``;
            keeps low thresholds from being pushed to the clamp when thresholds are
            drawn over a wide range.
    """

    pos_range: tuple[float, float] = (0.12, 0.24)
    neg_range: tuple[float, float] = (0.12, 0.24)
    mismatch_std: float = 0.0
    mismatch_relative: float = 0.0

    def __post_init__(self) -> None:
        for name in ("pos_range", "neg_range"):
            lo, hi = getattr(self, name)
            if not MIN_THRESHOLD <= lo <= hi:
                raise ValueError(f"{name} must satisfy {MIN_THRESHOLD} <= min <= max, "
                                 f"got {(lo, hi)}")
        if self.mismatch_std < 0 or self.mismatch_relative < 0:
            raise ValueError("mismatch_std and mismatch_relative must be >= 0")


@dataclass(frozen=True, eq=False)
class ContrastThresholds:
    """The thresholds of one simulated sensor.

    Attributes:
        pos, neg: the sequence's nominal ON/OFF thresholds (log units).
        pos_map, neg_map: float64[H, W] per-pixel thresholds actually used.
    """

    pos: float
    neg: float
    pos_map: np.ndarray
    neg_map: np.ndarray

    def __post_init__(self) -> None:
        if self.pos_map.shape != self.neg_map.shape or self.pos_map.ndim != 2:
            raise ValueError("threshold maps must be two equal 2-D arrays")
        if min(self.pos_map.min(), self.neg_map.min()) < MIN_THRESHOLD:
            raise ValueError(f"thresholds must be >= {MIN_THRESHOLD}")

    @classmethod
    def uniform(cls, pos: float, neg: float, hw: tuple[int, int]) -> ContrastThresholds:
        """The same thresholds at every pixel (no mismatch)."""
        return cls(float(pos), float(neg), np.full(hw, float(pos)), np.full(hw, float(neg)))

    @property
    def has_mismatch(self) -> bool:
        return bool(np.any(self.pos_map != self.pos) or np.any(self.neg_map != self.neg))

    @property
    def min_threshold(self) -> float:
        return float(min(self.pos_map.min(), self.neg_map.min()))


def sample_thresholds(config: ThresholdConfig, hw: tuple[int, int],
                      rng: np.random.Generator) -> ContrastThresholds:
    """Draw C+ and C- for one sequence, then the per-pixel mismatch maps if enabled."""
    pos = float(rng.uniform(*config.pos_range))
    neg = float(rng.uniform(*config.neg_range))
    if config.mismatch_std == 0 and config.mismatch_relative == 0:
        return ContrastThresholds.uniform(pos, neg, hw)
    std_pos = config.mismatch_std + config.mismatch_relative * pos
    std_neg = config.mismatch_std + config.mismatch_relative * neg
    pos_map = np.maximum(pos + std_pos * rng.standard_normal(hw), MIN_THRESHOLD)
    neg_map = np.maximum(neg + std_neg * rng.standard_normal(hw), MIN_THRESHOLD)
    return ContrastThresholds(pos, neg, pos_map, neg_map)
