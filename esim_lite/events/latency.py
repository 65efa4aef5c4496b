"""Readout latency and timestamp jitter of a DVS pixel array.

A real DVS pixel's event is timestamped when the arbiter reads it out, some time after its
comparator fired: a roughly constant delay (``latency_us``) plus a random part (``jitter_us``,
Gaussian here), both off by default. Each event's delay is ``latency + jitter * N(0, 1)``
clipped at 0 and rounded to the nanosecond. A pixel cannot fire again before its previous
event is read out, so a pixel's events keep their order: its event's timestamp is
``max(t + delay, previous timestamp of that pixel + 1 ns)``.

Delays reorder events across pixels, so :class:`ReadoutDelay` keeps a reorder buffer. The
simulator hands it each step's events, whose undelayed times lie in ``(t_prev, t_step]``;
every later event has an undelayed time ``> t_step`` and a delay ``>= 0``, so delayed events
at or before ``t_step`` are final and come out sorted by (time, row, column), the rest
wait. At the end of a sequence the recording stops at the last sample time: events still
waiting are later than it and are dropped (:meth:`ReadoutDelay.finish`), so a sequence
with latency loses about ``latency_us`` of its last events.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from esim_lite.core.events import Events
from esim_lite.core.streams import derived_rng

#: the ``spawn_key`` entry of the delay's random stream below a sequence's noise stream
#: (far above any child index ``SeedSequence.spawn`` would hand out).
LATENCY_STREAM_KEY = 0x1A7E

_NO_EVENT = np.iinfo(np.int64).min // 4


@dataclass(frozen=True)
class LatencyConfig:
    """Readout delay of every event (off by default: events keep their comparator times).

    Attributes:
        latency_us: constant delay (microseconds) added to every event.
        jitter_us: std (microseconds) of a Gaussian per-event delay around ``latency_us``;
            the total delay is clipped at 0.
    """

    latency_us: float = 0.0
    jitter_us: float = 0.0

    def __post_init__(self) -> None:
        for name in ("latency_us", "jitter_us"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"latency.{name} must be >= 0 (0 = off), got {value}")

    @property
    def enabled(self) -> bool:
        return self.latency_us > 0 or self.jitter_us > 0


def readout_rng(rng: np.random.Generator) -> np.random.Generator:
    """The delay's own generator, derived from a sequence's ``rng`` (its noise stream)
    without drawing from it or changing it: the same ``rng`` gives the same delays, and
    every draw of ``rng`` stays what it was without latency.

    Raises:
        ValueError: ``rng`` was not seeded through a ``SeedSequence``.
    """
    return derived_rng(rng, LATENCY_STREAM_KEY, "latency")


class ReadoutDelay:
    """One sequence's readout: the per-pixel last timestamps and the reorder buffer.

    Args:
        config: the latency (must be enabled).
        hw: (H, W) of the sensor.
        rng: draws the jitter (one normal per event, in input order); may be None when
            ``jitter_us`` is 0, and nothing is drawn then.
    """

    def __init__(self, config: LatencyConfig, hw: tuple[int, int],
                 rng: np.random.Generator | None = None) -> None:
        if not config.enabled:
            raise ValueError("ReadoutDelay needs latency.latency_us or latency.jitter_us > 0")
        if config.jitter_us > 0 and rng is None:
            raise ValueError("latency.jitter_us > 0 needs a random generator")
        self.config = config
        self.hw = (int(hw[0]), int(hw[1]))
        self.rng = rng
        self.last_t = np.full(self.hw[0] * self.hw[1], _NO_EVENT, np.int64)
        self.released_t = _NO_EVENT
        self.dropped = 0
        empty = Events.empty(self.hw)
        self._pending = (empty.x, empty.y, empty.t_ns, empty.p)

    def delays_ns(self, n: int) -> np.ndarray:
        """int64[n] readout delays (ns) before the per-pixel order rule."""
        cfg = self.config
        d = np.full(n, cfg.latency_us * 1e3)
        if cfg.jitter_us > 0:
            d += cfg.jitter_us * 1e3 * self.rng.standard_normal(n)
        return np.rint(np.maximum(d, 0.0)).astype(np.int64)

    def step(self, events: Events, t_ns: int) -> Events:
        """Delay one step's ``events`` (sorted by time, all ``<= t_ns``) and release every
        waiting event timestamped ``<= t_ns``, sorted by (time, row, column)."""
        t_ns = int(t_ns)
        if t_ns < self.released_t:
            raise ValueError(f"readout steps must move forward in time: {t_ns} < "
                             f"{self.released_t}")
        if len(events) and events.t_ns[-1] > t_ns:
            raise ValueError(f"events at {events.t_ns[-1]} ns after the step end {t_ns} ns")
        if len(events):
            t = _delay(events.x, events.y, events.t_ns, self.delays_ns(len(events)),
                       self.last_t, self.hw[1])
            px, py, pt, pp = self._pending
            self._pending = (np.concatenate([px, events.x]), np.concatenate([py, events.y]),
                             np.concatenate([pt, t]), np.concatenate([pp, events.p]))
        return self._release(t_ns)

    def finish(self, t_ns: int) -> Events:
        """The end of the recording at ``t_ns``: the waiting events up to it (none when
        ``t_ns`` is the last step's end); later ones are dropped and counted in
        :attr:`dropped`."""
        out = self._release(int(t_ns))
        self.dropped += len(self._pending[2])
        empty = Events.empty(self.hw)
        self._pending = (empty.x, empty.y, empty.t_ns, empty.p)
        return out

    def _release(self, t_ns: int) -> Events:
        x, y, t, p = self._pending
        order = np.lexsort((x, y, t))  # stable; a pixel's own times are strictly increasing
        x, y, t, p = x[order], y[order], t[order], p[order]
        n = int(np.searchsorted(t, t_ns, side="right"))
        self._pending = (x[n:], y[n:], t[n:], p[n:])
        self.released_t = max(self.released_t, t_ns)
        return Events(x[:n], y[:n], t[:n], p[:n], self.hw)


@numba.njit(cache=True, nogil=True)
def _delay(x, y, t, delay, last_t, w):
    """int64[N] readout times of events ``(x, y, t)`` (int16, int16, int64) in emission
    order: ``max(t + delay, the pixel's previous readout time + 1)``; updates ``last_t``
    (int64[H * W]) in place."""
    out = np.empty(len(t), np.int64)
    for i in range(len(t)):
        pix = np.int64(y[i]) * w + np.int64(x[i])
        ti = max(t[i] + delay[i], last_t[pix] + 1)
        last_t[pix] = ti
        out[i] = ti
    return out
