"""Intensity frames with their timestamps."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Frames:
    """A sequence of linear intensity images.

    Attributes:
        intensity: float32[T, H, W] linear intensity (the texture's units, nominally [0, 1]).
        t_ns: int64[T] timestamps in nanoseconds, increasing.
    """

    intensity: np.ndarray
    t_ns: np.ndarray

    def __post_init__(self) -> None:
        if self.intensity.ndim != 3 or self.intensity.dtype != np.float32:
            raise ValueError(f"Frames.intensity must be float32[T,H,W], got "
                             f"{self.intensity.dtype}{list(self.intensity.shape)}")
        if self.t_ns.dtype != np.int64 or self.t_ns.shape != (self.intensity.shape[0],):
            raise ValueError("Frames.t_ns must be int64[T] matching intensity")

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def hw(self) -> tuple[int, int]:
        return int(self.intensity.shape[1]), int(self.intensity.shape[2])
