"""Finite photoreceptor bandwidth: a first-order low-pass of the log intensity whose cutoff
grows with the light, as v2e models it (Hu, Liu and Delbruck, CVPRW 2021).

A DVS pixel's photoreceptor follows a change of light with a time constant that is short
in bright light and long in the dark, so dark regions leave longer trails. The pixel
compares the filtered signal ``y``:

    dy/dt = (L(t) - y) / tau(I),   tau = 1 / (2 pi f(I)),   f(I) = f_c (I + o) / (1 + o)

with ``L = log(eps + I)``, ``f_c`` the cutoff at full brightness (``I = 1``) and ``o`` the
dark offset (v2e's ``(luma + 20) / 275`` for 8-bit luma: ``o = 20 / 255``). Between two
samples the simulator takes ``L`` as linear in time (the event kernel does the same), so
each step applies the exact solution for a linear input (first-order hold):

    y1 = L1 - s tau + (y0 - L0 + s tau) a,   s = (L1 - L0) / dt,   a = exp(-dt / tau)

with ``tau`` from the new sample's intensity. A step of light therefore gives the
exponential approach ``y(t) = L1 + (y0 - L1) exp(-t / tau)`` whatever the sample times
(tested against that closed form). After a fast change the filtered signal keeps moving
while the image stands still; :meth:`PhotoreceptorLowPass.max_step` bounds the next step
so that it moves by at most the sampler's budget: each pixel's own share of its threshold
in the direction it relaxes (:meth:`EventSimulator.max_step`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

#: v2e's dark offset: its cutoff scales with (luma + 20) / 275 for 8-bit luma.
V2E_DARK_OFFSET = 20.0 / 255.0


@dataclass(frozen=True)
class BandwidthConfig:
    """Photoreceptor bandwidth (off by default: an infinitely fast photoreceptor).

    Attributes:
        cutoff_hz: 3 dB cutoff frequency at full brightness (linear intensity 1); 0 = off.
            Real DAVIS pixels: a few hundred Hz in bright light (v2e's default 300).
        dark_offset: ``o`` in ``f(I) = cutoff_hz (I + o) / (1 + o)``: the cutoff at
            ``I = 0`` is ``o / (1 + o)`` of the bright one (v2e: 20/255, about 7%).
    """

    cutoff_hz: float = 0.0
    dark_offset: float = V2E_DARK_OFFSET

    def __post_init__(self) -> None:
        if self.cutoff_hz < 0 or not math.isfinite(self.cutoff_hz):
            raise ValueError(f"bandwidth.cutoff_hz must be >= 0 (0 = off), got "
                             f"{self.cutoff_hz}")
        if not self.dark_offset > 0:
            raise ValueError(f"bandwidth.dark_offset must be > 0, got {self.dark_offset}")

    @property
    def enabled(self) -> bool:
        return self.cutoff_hz > 0

    def time_constant(self, intensity: np.ndarray) -> np.ndarray:
        """float64 ``tau`` (s) at each linear ``intensity`` (clipped at 0)."""
        i = np.maximum(np.asarray(intensity, np.float64), 0.0)
        f = self.cutoff_hz * (i + self.dark_offset) / (1.0 + self.dark_offset)
        return 1.0 / (2.0 * math.pi * f)


class PhotoreceptorLowPass:
    """The filter's per-pixel state for one sequence.

    Args:
        config: the bandwidth (must be enabled).
        first_log: float32[H, W] log intensity at the first sample; the filter starts
            settled there.
        log_eps: the ``eps`` of ``L = log(eps + I)`` (to recover ``I`` for the cutoff).
    """

    def __init__(self, config: BandwidthConfig, first_log: np.ndarray, log_eps: float):
        if not config.enabled:
            raise ValueError("PhotoreceptorLowPass needs bandwidth.cutoff_hz > 0")
        self.config = config
        self.log_eps = float(log_eps)
        self.input = np.asarray(first_log, np.float64).copy()
        self.state = self.input.copy()
        self._tau = config.time_constant(np.exp(self.input) - self.log_eps)

    def step(self, log_img: np.ndarray, dt_s: float) -> np.ndarray:
        """float32[H, W] filtered log intensity ``dt_s`` after the previous sample, the
        input rising linearly from the previous sample's ``L`` to ``log_img``."""
        if not dt_s > 0:
            raise ValueError(f"low-pass steps must move forward in time, got dt {dt_s}")
        cfg = self.config
        return _step(self.state, self.input, self._tau,
                     np.ascontiguousarray(log_img, np.float32), float(dt_s), cfg.cutoff_hz,
                     cfg.dark_offset, self.log_eps)

    def max_step(self, budget: float | np.ndarray,
                 fall_budget: float | np.ndarray | None = None) -> float:
        """The longest next step (s) over which the filtered signal, relaxing towards the
        current input with the current time constants, moves by at most ``budget`` at
        every pixel (inf when it is within ``budget`` of the input everywhere).

        ``budget`` may be per pixel (float[H, W]); with ``fall_budget``, ``budget`` holds
        the pixels that rise towards their input and ``fall_budget`` those that fall (a
        relaxation is monotonic, so it can only cross the levels of its own direction)."""
        shape = self.state.shape

        def per_pixel(b: float | np.ndarray) -> np.ndarray:
            return b if isinstance(b, np.ndarray) and b.shape == shape else \
                np.broadcast_to(np.asarray(b), shape)

        rise = per_pixel(budget)
        fall = rise if fall_budget is None else per_pixel(fall_budget)
        return _max_step(self.state, self.input, self._tau, rise, fall)


@numba.njit(cache=True, nogil=True)
def _max_step(state, inp, tau, rise, fall):
    """:meth:`PhotoreceptorLowPass.max_step` in one compiled pass: the smallest
    ``-tau log(1 - allowed / gap)`` over the pixels whose gap to their input exceeds their
    allowance (inf where none does)."""
    h, w = state.shape
    best = math.inf
    for y in range(h):
        for x in range(w):
            diff = inp[y, x] - state[y, x]
            gap = abs(diff)
            allowed = np.float64(rise[y, x] if diff > 0 else fall[y, x])
            if gap > allowed:
                best = min(best, -tau[y, x] * math.log1p(-allowed / gap))
    return best


@numba.njit(cache=True, nogil=True)
def _step(state, inp, tau, log_img, dt, cutoff_hz, offset, log_eps):
    """One filter step in place (``state``, ``inp``, ``tau``: float64[H, W]); returns the
    new state as float32. The arithmetic of :meth:`BandwidthConfig.time_constant` and the
    first-order-hold update, per pixel."""
    h, w = log_img.shape
    out = np.empty((h, w), np.float32)
    scale = cutoff_hz / (1.0 + offset) * 2.0 * np.pi
    for y in range(h):
        for x in range(w):
            l1 = np.float64(log_img[y, x])
            t = 1.0 / (scale * (max(np.exp(l1) - log_eps, 0.0) + offset))
            a = np.exp(-dt / t)
            slope_tau = (l1 - inp[y, x]) / dt * t
            v = l1 - slope_tau + (state[y, x] - inp[y, x] + slope_tau) * a
            state[y, x] = v
            inp[y, x] = l1
            tau[y, x] = t
            out[y, x] = v
    return out
