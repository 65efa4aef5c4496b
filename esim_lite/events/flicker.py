"""Flicker of the light on part of the scene: mains-powered lamps modulate their light at
twice the mains frequency (100 Hz on 50 Hz grids, 120 Hz on 60 Hz), and an event camera
sees it as bursts of ON and OFF events wherever that lamp lights the scene.

The lamp lights a random axis-aligned rectangle of the event camera's view (``area_fraction``
of it, drawn per sequence), multiplying its light by ``1 + m sin(2 pi f t + phase)``. Only
the event camera's samples are modulated: the frames stay the scene's steady light (the
targets a reconstruction aims at). The log change rate of the modulation,
``2 pi f m cos / (1 + m sin)``, is at most ``2 pi f m / sqrt(1 - m^2)`` (where
``sin = -m``), which bounds the sampler's steps (:meth:`Flicker.max_step`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FlickerConfig:
    """A flickering lamp (off by default).

    Attributes:
        frequency_hz: the light's modulation frequency; 0 = off (100 on 50 Hz mains, 120 on
            60 Hz).
        depth: modulation depth ``m`` in [0, 1): the light is ``I (1 + m sin(...))``.
        area_fraction: share of the view the lamp lights (a random rectangle; 1 = all).
    """

    frequency_hz: float = 0.0
    depth: float = 0.3
    area_fraction: float = 0.3

    def __post_init__(self) -> None:
        if self.frequency_hz < 0 or not math.isfinite(self.frequency_hz):
            raise ValueError(f"flicker.frequency_hz must be >= 0 (0 = off), got "
                             f"{self.frequency_hz}")
        if not 0 <= self.depth < 1:
            raise ValueError(f"flicker.depth must be in [0, 1), got {self.depth}")
        if not 0 < self.area_fraction <= 1:
            raise ValueError(f"flicker.area_fraction must be in (0, 1], got "
                             f"{self.area_fraction}")

    @property
    def enabled(self) -> bool:
        return self.frequency_hz > 0 and self.depth > 0


class Flicker:
    """One sequence's lamp: its lit rectangle and phase, drawn once from ``rng``."""

    def __init__(self, config: FlickerConfig, hw: tuple[int, int], rng: np.random.Generator):
        if not config.enabled:
            raise ValueError("Flicker needs flicker.frequency_hz > 0 and depth > 0")
        self.config = config
        h, w = hw
        aspect = rng.uniform(0.5, 2.0)
        area = config.area_fraction * h * w
        rw = int(np.clip(round(math.sqrt(area * aspect)), 1, w))
        rh = int(np.clip(round(area / rw), 1, h))
        x0, y0 = int(rng.integers(0, w - rw + 1)), int(rng.integers(0, h - rh + 1))
        self.mask = np.zeros(hw, bool)
        self.mask[y0:y0 + rh, x0:x0 + rw] = True
        self.phase = float(rng.uniform(0, 2 * math.pi))

    def gain(self, t_ns: int) -> float:
        """The lamp's light factor at ``t_ns``."""
        cfg = self.config
        return 1.0 + cfg.depth * math.sin(2 * math.pi * cfg.frequency_hz * t_ns * 1e-9
                                          + self.phase)

    def apply(self, image: np.ndarray, t_ns: int) -> np.ndarray:
        """float32 ``image`` with the lamp's light modulated at ``t_ns`` (a new array)."""
        out = np.array(image, np.float32, copy=True)
        out[self.mask] *= np.float32(self.gain(t_ns))
        return out

    def max_step(self, budget: float) -> float:
        """The longest step (s) over which the modulation changes ``log I`` by at most
        ``budget``: its largest rate is ``2 pi f m / sqrt(1 - m^2)``."""
        cfg = self.config
        return budget * math.sqrt(1 - cfg.depth**2) / (2 * math.pi * cfg.frequency_hz
                                                        * cfg.depth)
