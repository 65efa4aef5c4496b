"""Classical event-to-image baselines, so every number has a reference.

All three are the per-pixel log-intensity filter of Scheerlinck, Barnes and Mahony
(ACCV 2018), ``dL/dt = c E(t) - alpha (L - L_F)`` with ``E`` the events (+-1 impulses) and
``L_F`` the latest APS frame's log intensity:
- ``hf`` (high-pass filter, no frames, ``L_F = 0``): per event at pixel x,
  ``L(x) <- exp(-alpha (t - t_x)) L(x) + c sigma``; the decay is applied to all pixels at
  output time;
- ``direct``: ``alpha = 0``, plain event integration (the naive floor);
- ``complementary``: with APS frames, events fill in between frames while ``L`` relaxes to
  the latest frame (complementary filter).
Outputs are at the sensor's size; :func:`upsample` brings them to HR (bicubic).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numba
import numpy as np

from esim_lite.core.events import Events

Method = Literal["hf", "direct", "complementary"]


@dataclass(frozen=True)
class FilterConfig:
    """``contrast``: log-intensity step per event (c); ``cutoff_hz``: alpha / 2 pi."""

    contrast: float = 0.15
    cutoff_hz: float = 5.0
    log_eps: float = 1e-3


@numba.njit(cache=True, nogil=True)
def _integrate(x, y, t, p, state, t_last, frame_log, alpha, c):
    for i in range(len(t)):
        xi, yi = x[i], y[i]
        if alpha > 0:
            decay = np.exp(-alpha * (t[i] - t_last[yi, xi]) * 1e-9)
            state[yi, xi] = frame_log[yi, xi] + (state[yi, xi] - frame_log[yi, xi]) * decay
        state[yi, xi] += c * p[i]
        t_last[yi, xi] = t[i]


class EventFilter:
    """Streams events (and APS frames for ``complementary``) into a log-intensity image."""

    def __init__(self, method: Method, hw: tuple[int, int], config: FilterConfig | None = None
                 ) -> None:
        self.method, self.config = method, config or FilterConfig()
        self.alpha = 0.0 if method == "direct" else 2 * np.pi * self.config.cutoff_hz
        self.state = np.zeros(hw, np.float64)
        self.t_last = np.zeros(hw, np.int64)
        self.frame_log = np.zeros(hw, np.float64)
        self.has_frame = False

    def add_events(self, events: Events) -> None:
        if self.method == "complementary" and not self.has_frame:
            return  # nothing to complement before the first frame
        _integrate(events.x, events.y, events.t_ns, events.p, self.state, self.t_last,
                   self.frame_log, self.alpha, self.config.contrast)

    def add_frame(self, intensity: np.ndarray, t_ns: int) -> None:
        """A new APS frame at ``t_ns`` (only used by ``complementary``)."""
        if self.method != "complementary":
            return
        log_frame = np.log(self.config.log_eps + intensity.astype(np.float64))
        if not self.has_frame:
            self.state[:] = log_frame
            self.t_last[:] = t_ns
        else:  # relax every pixel to t_ns towards the old frame, then switch frames
            self._bring_to(t_ns)
        self.frame_log, self.has_frame = log_frame, True

    def _bring_to(self, t_ns: int) -> None:
        if self.alpha > 0:
            decay = np.exp(-self.alpha * (t_ns - self.t_last) * 1e-9)
            self.state = self.frame_log + (self.state - self.frame_log) * decay
        self.t_last[:] = t_ns

    def log_image(self, t_ns: int) -> np.ndarray:
        """float64[H, W] log-intensity estimate at ``t_ns`` (the state is not changed)."""
        if self.alpha == 0:
            return self.state.copy()
        decay = np.exp(-self.alpha * np.maximum(t_ns - self.t_last, 0) * 1e-9)
        return self.frame_log + (self.state - self.frame_log) * decay

    def image(self, t_ns: int) -> np.ndarray:
        """float32[H, W] intensity at ``t_ns``: absolute for ``complementary``, else up to
        an unknown scale (shown stretched to [0, 1] by its 1st..99th percentiles)."""
        img = np.exp(self.log_image(t_ns))
        if self.method == "complementary" and self.has_frame:
            return (img - self.config.log_eps).clip(0, 1).astype(np.float32)
        lo, hi = np.percentile(img, (1, 99))
        return ((img - lo) / max(hi - lo, 1e-9)).clip(0, 1).astype(np.float32)


def upsample(img: np.ndarray, scale: int) -> np.ndarray:
    """Bicubic upsampling by ``scale`` (clipped to [0, 1])."""
    h, w = img.shape
    return cv2.resize(img, (w * scale, h * scale), interpolation=cv2.INTER_CUBIC).clip(0, 1)
