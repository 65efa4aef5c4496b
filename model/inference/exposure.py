"""APS frames integrate light over an exposure window; our outputs are instants.

An AEDAT4 frame carries its exposure, a text folder's ``exposures.txt`` a window holding it
(``Recording.exposures_ns``: start and end). To score
an output against such a frame fairly, the outputs whose timestamps fall inside the window
are averaged (the nearest one when none does), the discrete version of the frame's time
integral. The outputs considered are the ones the model makes anyway: one at every stack
boundary (every ``events_per_stack``-th event counted from the recording's first, where
``reconstruct --at events`` puts them) inside the window, plus the one at the frame's own
timestamp that ``evaluate`` scores without averaging. The baselines (event filters) are
sampled at the same times, from the previous frame's time on, and averaged the same way
(:func:`model.inference.evaluate.run_sequence`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from datagen.recording import Recording
from model.inference.reconstruct import EventWindow


def exposure_average(times_ns: Sequence[int], images: Sequence[np.ndarray],
                     window_ns: tuple[int, int]) -> tuple[np.ndarray, int]:
    """(float32 mean of the ``images`` whose time lies in ``[start, end]`` of
    ``window_ns``, how many were averaged); the one nearest to the window (1) when none
    lies inside. ``images`` are float32[H, W], one per time in ``times_ns``."""
    if len(times_ns) != len(images) or not len(images):
        raise ValueError(f"need one image per time and at least one, got {len(images)} "
                         f"image(s) for {len(times_ns)} time(s)")
    start, end = int(window_ns[0]), int(window_ns[1])
    times = np.asarray(times_ns, np.int64)
    inside = np.flatnonzero((times >= start) & (times <= end))
    if not len(inside):
        gap = np.maximum(start - times, times - end)
        inside = np.array([int(np.argmin(gap))])
    mean = np.mean(np.stack([images[i] for i in inside]).astype(np.float64), axis=0)
    return mean.astype(np.float32), len(inside)


def boundary_times(window: EventWindow, every_events: int, start_ns: int, end_ns: int
                   ) -> list[int]:
    """Distinct times in ``[start_ns, end_ns]`` of the outputs made every ``every_events``
    events (at the ``every_events``-th event, the 2x..., counted from the first)."""
    if every_events < 1:
        raise ValueError(f"every_events must be >= 1, got {every_events}")
    lo = window.index_after(start_ns - 1)  # first event at or after the start
    hi = window.index_after(end_ns)  # first event after the end
    first_k = -(-(lo + 1) // every_events)  # boundary event k * every - 1 >= lo
    times = (window.time_of(k * every_events - 1) for k in range(first_k, hi // every_events + 1))
    return sorted({t for t in times if t is not None})


@dataclass(frozen=True)
class ExposureStats:
    """A recording's APS exposures: ``frames``, exposure durations in ms (min, median,
    max), where the frame's timestamp sits in its window (median fraction: 0 start,
    0.5 middle, 1 end) and the median frame interval in ms."""

    frames: int
    exposure_ms: tuple[float, float, float]
    stamp_position: float
    interval_ms: float

    def describe(self) -> str:
        lo, med, hi = self.exposure_ms
        spread = f"{med:.3f} ms" if lo == hi else f"{med:.3f} ms (median; {lo:.3f}-{hi:.3f})"
        return (f"{self.frames} frames every {self.interval_ms:.1f} ms, exposure {spread}, "
                f"frame timestamp at {100 * self.stamp_position:.0f}% of the window")


def exposure_stats(recording: Recording) -> ExposureStats | None:
    """:class:`ExposureStats` of a recording's frames; None without exposure windows."""
    if recording.exposures_ns is None or recording.frames is None:
        return None
    win = recording.exposures_ns
    dur = (win[:, 1] - win[:, 0]) * 1e-6
    pos = (recording.frames.t_ns - win[:, 0]) / np.maximum(win[:, 1] - win[:, 0], 1)
    gaps = np.diff(recording.frames.t_ns) * 1e-6
    return ExposureStats(len(win), (float(dur.min()), float(np.median(dur)), float(dur.max())),
                         float(np.median(pos)), float(np.median(gaps)) if len(gaps) else 0.0)
