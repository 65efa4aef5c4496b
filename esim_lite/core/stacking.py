"""Event stacks for the network: stacking by number of events (SBN) or by time (SBT).

SBN (Mostafavi et al. 2019; E2SRI section 3.1 and supplement): a stack has ``c`` channels;
each channel is a canvas initialised to 128 on which every event writes 255 (ON) or 0 (OFF),
the newest event at a pixel winning. A channel takes ``Ne`` consecutive events, but is
closed early when one pixel would be written more than ``cap`` times (the supplement's 50),
so fast-firing pixels cannot wipe a channel; the next channel starts where it stopped.

Stacks are built either forward from a start index or backward to an end index (a sample's
central stack ends at a frame). Consecutive stacks may overlap by ``L`` events.
Two compiled (numba) passes over the stack's own events: one counts writes per pixel to find
where each channel closes, one paints the channels in time order (so the newest event
wins without a sort). The rest of the stream is never read, so a stack costs the same
however long the recording is.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numba
import numpy as np

from esim_lite.core.events import Events

BACKGROUND, ON, OFF = 128, 255, 0


@dataclass(frozen=True)
class StackConfig:
    """How events become network input.

    Attributes:
        method: ``sbn`` (by number of events) or ``sbt`` (by time).
        channels: channels per stack (the paper: 3).
        events_per_channel: SBN's Ne. Default 1,000, i.e. 3,000 events per stack: the
            paper's stated choice for its 128x128 synthetic camera (its ~5,000 per stack at
            240x180 is for real recordings; :meth:`events_per_channel_for` scales by area).
        overwrite_cap: SBN closes a channel before a pixel's (cap+1)-th write (paper: 50).
        overlap: events shared by consecutive stacks (L).
        channel_ms: SBT's time per channel.
    """

    method: Literal["sbn", "sbt"] = "sbn"
    channels: int = 3
    events_per_channel: int = 1000
    overwrite_cap: int = 50
    overlap: int = 0
    channel_ms: float = 5.0

    def __post_init__(self) -> None:
        if self.channels < 1 or self.events_per_channel < 1 or self.overwrite_cap < 1:
            raise ValueError("channels, events_per_channel and overwrite_cap must be >= 1")
        if not 0 <= self.overlap < self.channels * self.events_per_channel:
            raise ValueError("overlap must be in [0, events per stack)")
        if self.channel_ms <= 0:
            raise ValueError("channel_ms must be > 0")

    @property
    def events_per_stack(self) -> int:
        return self.channels * self.events_per_channel

    @staticmethod
    def events_per_channel_for(sensor_hw: tuple[int, int], per_stack_240x180: int = 5000,
                               channels: int = 3) -> int:
        """Ne giving the same event density per pixel as ``per_stack_240x180`` at 240x180."""
        return max(1, round(per_stack_240x180 * sensor_hw[0] * sensor_hw[1] / (240 * 180)
                            / channels))


@numba.njit(cache=True, nogil=True)
def _pixel(x, y, i, h, w):
    """Flat index of event ``i``; raises for an event outside the sensor (a wrong
    ``sensor_hw`` would otherwise write outside the canvas)."""
    if x[i] < 0 or x[i] >= w or y[i] < 0 or y[i] >= h:
        raise ValueError("event coordinates outside sensor_hw")
    return np.int64(y[i]) * w + x[i]


@numba.njit(cache=True, nogil=True)
def _capped_walk(x, y, h, w, first, step, count, cap, writes):
    """How many of the ``count`` events from index ``first`` in steps of ``step`` (+1
    forward, -1 backward) come before a pixel's (cap+1)-th write. ``writes`` int32[H*W] is
    zero on entry and on return (only the pixels touched are reset)."""
    taken = 0
    while taken < count:
        q = _pixel(x, y, first + step * taken, h, w)
        if writes[q] == cap:
            break
        writes[q] += 1
        taken += 1
    for k in range(taken):
        writes[_pixel(x, y, first + step * k, h, w)] = 0
    return taken


@numba.njit(cache=True, nogil=True)
def _sbn_bounds(x, y, h, w, pos, forward, ne, cap, channels):
    """int64[channels, 2] event ranges of the channels of an SBN stack starting (forward)
    or ending (backward) at ``pos`` (already clipped to ``[0, N]``), oldest first."""
    n = len(x)
    writes = np.zeros(h * w, np.int32)
    bounds = np.empty((channels, 2), np.int64)
    for k in range(channels):
        if forward:
            taken = _capped_walk(x, y, h, w, pos, 1, min(ne, n - pos), cap, writes)
            bounds[k, 0], bounds[k, 1] = pos, pos + taken
            pos += taken
        else:
            taken = _capped_walk(x, y, h, w, pos - 1, -1, min(ne, pos), cap, writes)
            bounds[channels - 1 - k, 0], bounds[channels - 1 - k, 1] = pos - taken, pos
            pos -= taken
    return bounds


@numba.njit(cache=True, nogil=True)
def _paint(x, y, p, h, w, bounds, image):
    """Paints channel ``k`` of ``image`` uint8[c, H*W] (all 128 on entry) with events
    ``bounds[k]`` in time order, so each pixel keeps its newest event."""
    for k in range(bounds.shape[0]):
        for i in range(bounds[k, 0], bounds[k, 1]):
            image[k, _pixel(x, y, i, h, w)] = ON if p[i] > 0 else OFF


def _painted(events: Events, bounds: np.ndarray) -> np.ndarray:
    """uint8[c, H, W]: channel ``k`` painted with events ``bounds[k]`` (int64[c, 2])."""
    h, w = events.sensor_hw
    image = np.full((len(bounds), h * w), BACKGROUND, np.uint8)
    _paint(events.x, events.y, events.p, h, w, bounds, image)
    return image.reshape(len(bounds), h, w)


def paint_channel(x: np.ndarray, y: np.ndarray, p: np.ndarray, hw: tuple[int, int]
                  ) -> np.ndarray:
    """uint8[H, W] canvas of 128 with each pixel's newest event: 255 ON, 0 OFF."""
    h, w = hw
    image = np.full((1, h * w), BACKGROUND, np.uint8)
    _paint(x, y, p, h, w, np.array([[0, len(x)]], np.int64), image)
    return image.reshape(h, w)


@dataclass(frozen=True, eq=False)
class Stack:
    """One stack: ``image`` uint8[c, H, W] (channels oldest first) built from events
    ``[start, end)``; ``bounds`` int64[c, 2] gives each channel's event range."""

    image: np.ndarray
    start: int
    end: int
    bounds: np.ndarray


def sbn_stack(events: Events, config: StackConfig, *, start: int | None = None,
              end: int | None = None) -> Stack:
    """SBN stack built forward from event ``start`` or backward to event ``end`` (exclusive).

    Near the ends of the stream channels get fewer events (or none: an all-128 channel).
    """
    if (start is None) == (end is None):
        raise ValueError("give exactly one of start= or end=")
    h, w = events.sensor_hw
    pos = min(max(start if start is not None else end, 0), len(events))
    bounds = _sbn_bounds(events.x, events.y, h, w, pos, start is not None,
                         config.events_per_channel, config.overwrite_cap, config.channels)
    return Stack(_painted(events, bounds), int(bounds[0, 0]), int(bounds[-1, 1]), bounds)


def sbt_stack(events: Events, config: StackConfig, *, t_end_ns: int) -> Stack:
    """SBT stack of ``channels`` windows of ``channel_ms`` ending at ``t_end_ns``."""
    width = int(round(config.channel_ms * 1e6))
    edges = t_end_ns - width * np.arange(config.channels, -1, -1)
    idx = np.searchsorted(events.t_ns, edges, side="right")
    bounds = np.stack([idx[:-1], idx[1:]], axis=1).astype(np.int64)
    return Stack(_painted(events, bounds), int(idx[0]), int(idx[-1]), bounds)


def stack_sequence(events: Events, config: StackConfig, anchor: int, n_stacks: int
                   ) -> list[Stack]:
    """``n_stacks`` SBN stacks whose central one ends at event ``anchor``; stacks before it
    end ``overlap`` events after their successor starts, stacks after it start ``overlap``
    events before their predecessor ends. Returned in time order."""
    if n_stacks < 1 or n_stacks % 2 == 0:
        raise ValueError(f"n_stacks must be odd and >= 1, got {n_stacks}")
    centre = sbn_stack(events, config, end=anchor)
    before, after = [], []
    nxt = centre
    for _ in range(n_stacks // 2):
        nxt = sbn_stack(events, config, end=nxt.start + config.overlap)
        before.append(nxt)
    prev = centre
    for _ in range(n_stacks // 2):
        prev = sbn_stack(events, config, start=prev.end - config.overlap)
        after.append(prev)
    return before[::-1] + [centre] + after


def stack_sequence_by_time(events: Events, config: StackConfig, t_anchor_ns: int,
                           n_stacks: int) -> list[Stack]:
    """``n_stacks`` SBT stacks of ``channels x channel_ms``, the central one ending at
    ``t_anchor_ns``, the others adjacent in time. Returned in time order."""
    if n_stacks < 1 or n_stacks % 2 == 0:
        raise ValueError(f"n_stacks must be odd and >= 1, got {n_stacks}")
    span = stack_span_ns(config)
    half = n_stacks // 2
    return [sbt_stack(events, config, t_end_ns=t_anchor_ns + k * span)
            for k in range(-half, half + 1)]


def stacks_around(events: Events, config: StackConfig, n_stacks: int, anchor: int,
                  t_anchor_ns: int) -> list[Stack]:
    """``n_stacks`` stacks by ``config.method``, in time order: SBN's central stack ends at
    event ``anchor`` (exclusive), SBT's at time ``t_anchor_ns``."""
    if config.method == "sbt":
        return stack_sequence_by_time(events, config, t_anchor_ns, n_stacks)
    return stack_sequence(events, config, anchor, n_stacks)


def stack_span_ns(config: StackConfig) -> int:
    """Duration of one SBT stack in nanoseconds."""
    return int(round(config.channels * config.channel_ms * 1e6))


def stack_to_input(stacks: np.ndarray) -> np.ndarray:
    """float32 in [-1, 1] from uint8 SBN values: 0 -> -1 (OFF), 128 -> 0, 255 -> +1 (ON)."""
    out = (stacks.astype(np.float32) - 127.5) / 127.5
    out[stacks == 128] = 0.0
    return out


def stack_fit_warnings(every_events: int, tail_events: int, events_per_stack: int,
                       n_stacks: int, overlap: int = 0) -> list[str]:
    """Why frames laid out by datagen (one every ``every_events`` events, ``tail_events``
    after the last) fit the training stacks badly: empty when they agree.

    A sample needs ``events_per_stack + half * step`` events before its frame and
    ``half * step`` after it (``step = events_per_stack - overlap``, ``half = n_stacks // 2``).
    """
    half, step = n_stacks // 2, events_per_stack - overlap
    out = []
    if tail_events < half * step:
        out.append(f"{tail_events:,} events after the last frame, but {n_stacks} stacks of "
                   f"{events_per_stack:,} need {half * step:,}: the last frames go unused")
    if every_events > events_per_stack:
        out.append(f"frames every {every_events:,} events but stacks of {events_per_stack:,}: "
                   "events between stacks are never seen by the network")
    return out
