"""Event stacks for the network: stacking by number of events (SBN) or by time (SBT).

SBN (Mostafavi et al. 2019; E2SRI section 3.1 and supplement): a stack has ``c`` channels;
each channel is a canvas initialised to 128 on which every event writes 255 (ON) or 0 (OFF),
the newest event at a pixel winning. A channel takes ``Ne`` consecutive events, but is
closed early when one pixel would be written more than ``cap`` times (the supplement's 50),
so fast-firing pixels cannot wipe a channel; the next channel starts where it stopped.

Stacks are built either forward from a start index or backward to an end index (a sample's
central stack ends at a frame). Consecutive stacks may overlap by ``L`` events.
No per-event Python loop: each channel is a handful of numpy calls over its events.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

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


def _capped_length(pix: np.ndarray, cap: int) -> int:
    """Largest n such that no value occurs more than ``cap`` times in ``pix[:n]``."""
    if len(pix) <= cap:
        return len(pix)
    order = np.argsort(pix, kind="stable")
    sorted_pix = pix[order]
    starts = np.flatnonzero(np.r_[True, sorted_pix[1:] != sorted_pix[:-1]])
    group = np.cumsum(np.r_[False, sorted_pix[1:] != sorted_pix[:-1]])
    occurrence = np.empty(len(pix), np.int64)
    occurrence[order] = np.arange(len(pix)) - starts[group]
    over = np.flatnonzero(occurrence >= cap)
    return int(over[0]) if len(over) else len(pix)


def paint_channel(x: np.ndarray, y: np.ndarray, p: np.ndarray, hw: tuple[int, int]
                  ) -> np.ndarray:
    """uint8[H, W] canvas of 128 with each pixel's newest event: 255 ON, 0 OFF."""
    h, w = hw
    canvas = np.full(h * w, BACKGROUND, np.uint8)
    if len(x):
        pix = y.astype(np.int64) * w + x
        last = len(pix) - 1 - np.unique(pix[::-1], return_index=True)[1]
        canvas[pix[last]] = np.where(p[last] > 0, ON, OFF)
    return canvas.reshape(h, w)


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
    pix = events.y.astype(np.int64) * events.sensor_hw[1] + events.x
    ne, cap, n = config.events_per_channel, config.overwrite_cap, len(events)
    bounds = []
    if start is not None:
        s = min(max(start, 0), n)
        for _ in range(config.channels):
            e = s + _capped_length(pix[s:min(s + ne, n)], cap)
            bounds.append((s, e))
            s = e
    else:
        e = min(max(end, 0), n)
        for _ in range(config.channels):
            s = e - _capped_length(pix[max(e - ne, 0):e][::-1], cap)
            bounds.append((s, e))
            e = s
        bounds.reverse()
    image = np.stack([paint_channel(events.x[a:b], events.y[a:b], events.p[a:b],
                                    events.sensor_hw) for a, b in bounds])
    return Stack(image, bounds[0][0], bounds[-1][1], np.array(bounds, np.int64))


def sbt_stack(events: Events, config: StackConfig, *, t_end_ns: int) -> Stack:
    """SBT stack of ``channels`` windows of ``channel_ms`` ending at ``t_end_ns``."""
    width = int(round(config.channel_ms * 1e6))
    edges = t_end_ns - width * np.arange(config.channels, -1, -1)
    idx = np.searchsorted(events.t_ns, edges, side="right")
    bounds = np.stack([idx[:-1], idx[1:]], axis=1)
    image = np.stack([paint_channel(events.x[a:b], events.y[a:b], events.p[a:b],
                                    events.sensor_hw) for a, b in bounds])
    return Stack(image, int(idx[0]), int(idx[-1]), bounds.astype(np.int64))


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
