"""Whether a recording's scene moves across most of the frame, measured from its events.

Under a static camera the background never fires, so a whole-frame score measures what a
method draws where no event saw anything (:mod:`model.inference.observed`); where the scene
moves across most of the frame, the whole frame is what the events saw. The real-data
benchmark (:mod:`model.inference.real_benchmark`) scores each recording by this verdict.

The measure is the **swept share**: the share of the sensor's pixels that saw the scene
change, over the whole recording. A pixel saw it when the running sum of its polarities
(+1 ON, -1 OFF, from 0 at the recording's start) spans at least :data:`SWING_EVENTS`
(its maximum minus its minimum, 0 included): its log intensity moved by at least that many
contrast thresholds in one direction at some time. And only pixels with at least
:data:`~model.inference.observed.MIN_NEIGHBOURS` such neighbours among their 8 count (the
observed region's spatial rule, without its dilation). Each part keeps a static scene
static:

- **flicker**: a lamp's ripple makes a pixel fire ON, OFF, ON, OFF: its sum swings by one,
  however many events it fires (the DAVIS346 robot_arm clip, mostly flicker: 12.8% of the
  pixels fire twice with support, 4.1% swing by two);
- **hot pixels**: they fire all the time, but alone: no neighbour support;
- **background noise**: events at random pixels, half ON, half OFF; a pixel needs two net
  noise events in one direction and two neighbours that did the same.

The verdict is ``moving`` when the swept share is at least :data:`MOVING_SHARE`, one half:
then most of a whole-frame score is of pixels the events saw change, and below it most is
of pixels they never saw. Its limit: noise accumulates over the recording, so a long, noisy
recording of a static scene ends up swept: uniform noise of 2 events per pixel (half ON)
gives a swept share of 36%, 3 events 60% (240x180 random events); at the 0.0023 Hz per
pixel of the DAVIS346 street clip's background that is 14-22 minutes, at 0.1 Hz 20-30
s. The benchmark's recordings last seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from datagen.formats.base import READ_CHUNK_EVENTS
from datagen.recording import Recording
from esim_lite.core.events import Events
from model.inference.observed import MIN_NEIGHBOURS, region_of

#: The span of a pixel's running polarity sum (in events) that counts as the scene changing.
SWING_EVENTS = 2
#: The swept share at and above which the scene moves across most of the frame.
MOVING_SHARE = 0.5
MOVING = "moving: whole frame"
STATIC = "static camera: observed region"


@numba.njit(cache=True, nogil=True)
def _accumulate(x, y, p, w, total, high, low):
    for i in range(len(x)):
        k = y[i] * w + x[i]
        total[k] += p[i]
        if total[k] > high[k]:
            high[k] = total[k]
        elif total[k] < low[k]:
            low[k] = total[k]


class SwingMap:
    """Per pixel, the span of its running polarity sum, fed events in time order
    (module doc). ``swing()``: int64[H, W]."""

    def __init__(self, sensor_hw: tuple[int, int]) -> None:
        h, w = sensor_hw
        self.sensor_hw = (int(h), int(w))
        self._total = np.zeros(h * w, np.int64)
        self._high = np.zeros(h * w, np.int64)
        self._low = np.zeros(h * w, np.int64)
        self.events = 0

    def add(self, events: Events) -> None:
        if tuple(events.sensor_hw) != self.sensor_hw:
            raise ValueError(f"events of a {events.sensor_hw} sensor fed to a swing map of "
                             f"{self.sensor_hw}")
        _accumulate(events.x.astype(np.int64), events.y.astype(np.int64),
                    events.p.astype(np.int64), self.sensor_hw[1], self._total, self._high,
                    self._low)
        self.events += len(events)

    def swing(self) -> np.ndarray:
        return (self._high - self._low).reshape(self.sensor_hw)


def swept_region(swing: np.ndarray, swing_events: int = SWING_EVENTS) -> np.ndarray:
    """bool[H, W]: the pixels whose ``swing`` (int[H, W]) reaches ``swing_events`` with at
    least :data:`~model.inference.observed.MIN_NEIGHBOURS` neighbours that do too."""
    return region_of(swing >= swing_events, 0, MIN_NEIGHBOURS)


@dataclass(frozen=True)
class SceneMotion:
    """A recording's swept share (module doc) over its ``events`` spanning ``seconds``, and
    the verdict it gives."""

    swept_share: float
    events: int
    seconds: float
    threshold: float = MOVING_SHARE

    @property
    def moving(self) -> bool:
        return self.swept_share >= self.threshold

    @property
    def verdict(self) -> str:
        """:data:`MOVING` or :data:`STATIC`."""
        return MOVING if self.moving else STATIC

    def describe(self) -> str:
        return (f"swept share {100 * self.swept_share:.1f}% (moving from "
                f"{100 * self.threshold:.0f}%): {self.verdict}")


def scene_motion_of(events: Events) -> SceneMotion:
    """:class:`SceneMotion` of ``events`` (time-sorted) held in memory."""
    swings = SwingMap(events.sensor_hw)
    swings.add(events)
    seconds = (int(events.t_ns[-1]) - int(events.t_ns[0])) * 1e-9 if len(events) else 0.0
    return SceneMotion(float(swept_region(swings.swing()).mean()), len(events), seconds)


def measure_scene_motion(recording: Recording, chunk: int = READ_CHUNK_EVENTS
                         ) -> SceneMotion:
    """:class:`SceneMotion` of every event of ``recording``, read one chunk at a time."""
    swings = SwingMap(recording.sensor_hw)
    first = last = None
    for ev in recording.events(chunk):
        swings.add(ev)
        first = int(ev.t_ns[0]) if first is None else first
        last = int(ev.t_ns[-1])
    return SceneMotion(float(swept_region(swings.swing()).mean()), swings.events,
                       (last - first) * 1e-9)
