"""Sensor noise of a DVS pixel array: shot noise, hot pixels and leak events.

All three are off by default. Shot noise and hot pixels are independent Poisson processes
added to the signal events (they do not move a pixel's reference level). Shot noise may
depend on the light, as v2e models it: the rate falls linearly from ``shot_rate_hz`` in
the dark to ``shot_bright_factor`` times it at full brightness (v2e: 0.25), pixel by pixel,
from the intensity of each step's new sample. Leak is the slow
drift of each pixel's reference that makes real DVS pixels fire ON events without any
change of light (v2e's model): it is applied as a per-pixel linear drift of the compared
signal, ``L_eff(t) = L(t) + rate_p * C+_p * t``, so about ``rate_p`` ON events per second;
each pixel starts a random share of the way to its next leak event (a real sensor has been
leaking long before a recording starts), so leak events come at their rate from the first
second instead of after ``1 / rate_p``. Noise events obey the refractory period as signal
events do (:func:`refractory_noise`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
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
            self.leak_phase = rng.random(hw)
        else:
            self.leak_rate = None
            self.leak_phase = None

    def leak_offset(self, c_pos: np.ndarray, t_s: float) -> np.ndarray | None:
        """float32[H, W] drift to add to the log image at time ``t_s`` (None if no leak)."""
        if self.leak_rate is None:
            return None
        c = np.broadcast_to(np.asarray(c_pos, np.float64), self.hw)
        return _leak_offset(self.leak_rate, c, float(t_s))

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
            # thinning: candidates at the dark rate (the largest), each kept with its own
            # pixel's share of it; the same Poisson process as one draw per pixel, at the
            # cost of the few candidates instead of H x W draws per step
            n = self.rng.poisson(cfg.shot_rate_hz * dt_s * h * w)
            cand = self.rng.integers(0, h * w, n)
            light = np.clip(np.asarray(intensity, np.float64).ravel()[cand], 0.0, 1.0)
            kept = cand[self.rng.random(n) < 1.0 + (cfg.shot_bright_factor - 1.0) * light]
            pix.append(kept)
            pol.append(self.rng.choice(np.array([-1, 1], np.int8), len(kept)))
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


@numba.njit(cache=True, nogil=True)
def _leak_offset(rate, c_pos, t_s):
    """float32 ``rate * c_pos * t_s`` per pixel, in numpy's order, in one pass."""
    h, w = rate.shape
    out = np.empty((h, w), np.float32)
    for y in range(h):
        for x in range(w):
            out[y, x] = np.float32(rate[y, x] * c_pos[y, x] * t_s)
    return out


@numba.njit(cache=True)
def _refractory_keep(pix, t, is_noise, prev_last, refractory_ns, keep, last_t_flat):
    n = len(pix)
    next_signal = np.empty(n, np.int64)
    upcoming = np.iinfo(np.int64).max
    for i in range(n - 1, -1, -1):  # the next signal event of the same pixel
        if i == n - 1 or pix[i + 1] != pix[i]:
            upcoming = np.iinfo(np.int64).max
        next_signal[i] = upcoming
        if not is_noise[i]:
            upcoming = t[i]
    prev = 0
    for i in range(n):
        if i == 0 or pix[i - 1] != pix[i]:
            prev = prev_last[pix[i]]
        if is_noise[i]:
            ok = (t[i] - prev >= refractory_ns) and (next_signal[i] - t[i] >= refractory_ns)
            keep[i] = ok
            if ok:
                prev = t[i]
                if t[i] > last_t_flat[pix[i]]:
                    last_t_flat[pix[i]] = t[i]
        else:
            keep[i] = True
            prev = t[i]


def refractory_noise(signal: tuple[np.ndarray, ...], noise: tuple[np.ndarray, ...],
                     prev_last: np.ndarray, last_t: np.ndarray, refractory_ns: int
                     ) -> np.ndarray:
    """Which noise events (bool[N]) a refractory pixel lets through.

    A noise event is dropped when it comes less than ``refractory_ns`` after the pixel's
    previous event (signal, kept noise, or ``prev_last``: the last before this step) or
    before its next signal event in this step; the step's signal events are kept (an
    approximation: a real pixel would instead hold back the signal event after a noise
    event). Kept noise events advance ``last_t`` (int64[H, W], updated in place), so the
    next step's signal respects them.
    """
    sx, sy, st = signal[:3]
    nx, ny, nt = noise[:3]
    w = prev_last.shape[1]
    pix = np.concatenate([sy.astype(np.int64) * w + sx, ny.astype(np.int64) * w + nx])
    t = np.concatenate([st, nt]).astype(np.int64)
    is_noise = np.concatenate([np.zeros(len(st), np.bool_), np.ones(len(nt), np.bool_)])
    order = np.lexsort((~is_noise, t, pix))  # a tie: the signal event first
    keep = np.empty(len(order), np.bool_)
    _refractory_keep(pix[order], t[order], is_noise[order], prev_last.ravel(),
                     np.int64(refractory_ns), keep, last_t.reshape(-1))
    out = np.empty(len(order), np.bool_)
    out[order] = keep
    return out[len(st):]
