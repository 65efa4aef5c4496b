"""Sensor noise of a DVS pixel array: shot noise, hot pixels and leak events.

All three are off by default. Shot noise and hot pixels are independent Poisson processes
added to the signal events (they do not move a pixel's reference level). Shot noise may
depend on the light, as v2e models it: the rate falls linearly from ``shot_rate_hz`` in
the dark to ``shot_bright_factor`` times it at full brightness (v2e: 0.25), pixel by pixel,
from the intensity of each step's new sample. Leak is the slow
drift of each pixel's reference that makes real DVS pixels fire ON events without any
change of light (v2e's model): it is applied as a per-pixel linear drift of the compared
signal, ``L_eff(t) = L(t) + rate_p * C+_p * t``, so about ``rate_p`` ON events per second.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NoiseConfig:
    """Noise rates (all per pixel).

    Attributes:
        shot_rate_hz: Poisson rate of random-polarity events at every pixel (in the dark).
        shot_bright_factor: the shot rate at full brightness (linear intensity 1) as a
            fraction of ``shot_rate_hz``, linear in between (1: the same everywhere, the
            original model; v2e uses 0.25).
        hot_pixel_fraction: fraction of pixels that are hot (chosen once per sequence).
        hot_pixel_rate_hz: Poisson rate of a hot pixel; each hot pixel has one polarity.
        leak_rate_hz: mean rate of leak ON events.
        leak_rate_jitter: relative std of the per-pixel leak rate.
    """

    shot_rate_hz: float = 0.0
    shot_bright_factor: float = 1.0
    hot_pixel_fraction: float = 0.0
    hot_pixel_rate_hz: float = 0.0
    leak_rate_hz: float = 0.0
    leak_rate_jitter: float = 0.1

    def __post_init__(self) -> None:
        if min(self.shot_rate_hz, self.hot_pixel_rate_hz, self.leak_rate_hz,
               self.leak_rate_jitter) < 0:
            raise ValueError("noise rates must be >= 0")
        if not 0 <= self.hot_pixel_fraction <= 1:
            raise ValueError("hot_pixel_fraction must be in [0, 1]")
        if not 0 <= self.shot_bright_factor <= 1:
            raise ValueError(f"shot_bright_factor must be in [0, 1], got "
                             f"{self.shot_bright_factor}")

    @property
    def enabled(self) -> bool:
        return (self.shot_rate_hz > 0 or self.leak_rate_hz > 0
                or (self.hot_pixel_fraction > 0 and self.hot_pixel_rate_hz > 0))


class NoiseModel:
    """Per-sequence noise state: hot-pixel set and leak rates drawn once from ``rng``."""

    def __init__(self, config: NoiseConfig, hw: tuple[int, int], rng: np.random.Generator):
        self.config = config
        self.hw = hw
        self.rng = rng
        n = hw[0] * hw[1]
        n_hot = int(round(config.hot_pixel_fraction * n)) if config.hot_pixel_rate_hz else 0
        self.hot_pixels = rng.choice(n, size=n_hot, replace=False) if n_hot else \
            np.empty(0, np.int64)
        self.hot_polarity = rng.choice(np.array([-1, 1], np.int8), size=n_hot)
        if config.leak_rate_hz > 0:
            jitter = 1 + config.leak_rate_jitter * rng.standard_normal(hw)
            self.leak_rate = np.maximum(config.leak_rate_hz * jitter, 0.0)
        else:
            self.leak_rate = None

    def leak_offset(self, c_pos: np.ndarray, t_s: float) -> np.ndarray | None:
        """float32[H, W] drift to add to the log image at time ``t_s`` (None if no leak)."""
        if self.leak_rate is None:
            return None
        return (self.leak_rate * c_pos * t_s).astype(np.float32)

    def events(self, t0_ns: int, t1_ns: int, intensity: np.ndarray | None = None
               ) -> tuple[np.ndarray, ...]:
        """Shot-noise and hot-pixel events in ``(t0, t1]`` as unsorted ``(x, y, t, p)``.

        Args:
            intensity: float[H, W] linear intensity of the step's new sample; needed when
                shot noise depends on the light (``shot_bright_factor < 1``).
        """
        cfg, (h, w) = self.config, self.hw
        dt_s = (t1_ns - t0_ns) * 1e-9
        pix, pol = [], []
        if cfg.shot_rate_hz > 0 and cfg.shot_bright_factor == 1:
            n = self.rng.poisson(cfg.shot_rate_hz * dt_s * h * w)
            pix.append(self.rng.integers(0, h * w, n))
            pol.append(self.rng.choice(np.array([-1, 1], np.int8), n))
        elif cfg.shot_rate_hz > 0:
            if intensity is None:
                raise ValueError("shot noise that depends on the light needs the intensity")
            light = np.clip(np.asarray(intensity, np.float64).ravel(), 0.0, 1.0)
            rate = cfg.shot_rate_hz * (1.0 + (cfg.shot_bright_factor - 1.0) * light)
            counts = self.rng.poisson(rate * dt_s)
            pix.append(np.repeat(np.arange(h * w), counts))
            pol.append(self.rng.choice(np.array([-1, 1], np.int8), int(counts.sum())))
        if len(self.hot_pixels):
            counts = self.rng.poisson(cfg.hot_pixel_rate_hz * dt_s, len(self.hot_pixels))
            pix.append(np.repeat(self.hot_pixels, counts))
            pol.append(np.repeat(self.hot_polarity, counts))
        if not pix:
            return (np.empty(0, np.int16), np.empty(0, np.int16), np.empty(0, np.int64),
                    np.empty(0, np.int8))
        flat = np.concatenate(pix)
        t = t0_ns + 1 + self.rng.integers(0, max(t1_ns - t0_ns, 1), len(flat))
        return ((flat % w).astype(np.int16), (flat // w).astype(np.int16), t.astype(np.int64),
                np.concatenate(pol).astype(np.int8))
