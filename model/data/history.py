"""The event history input: how long ago, in events, each pixel last fired.

One output's SBN stacks hold the last few thousand events; a pixel that is silent in them
may be the event-free interior of an object whose edges swept it a moment ago, or a static
background that has not fired for the whole recording. The two need opposite fills (the
object's level carried inward; the background left alone) and a single output's stacks
cannot tell them apart. The history can: for every pixel, the number of events the whole
sensor produced since that pixel's latest event, counted over everything before the
output (not only the stacks), in units of the output's events per stack.

The network reads it as ``exp(-age / tau)`` for each time constant ``tau`` (in stacks) of
``NetConfig.history``: 1 for a pixel firing in the central stack, falling towards 0 for one
silent for many stacks, exactly 0 for a pixel that never fired. Counting events instead of
seconds makes it follow the SBN stacks: the same scene at a different speed or sensor size
gives the same history. It is exact and causal (a running per-pixel maximum), costs one
``H x W`` integer map, and needs no recurrent state to learn: an alternative to carrying a
learned state from one output to the next as recurrent events-to-video networks do.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from esim_lite.core.events import Events

NEVER = -1
"""The latest-event index of a pixel that has not fired."""


def latest_index(events: Events, first: int, latest: np.ndarray | None = None) -> np.ndarray:
    """int64[H * W]: for every pixel, the global index of its latest event among ``events``
    (whose first event has global index ``first``), starting from ``latest`` (copied, not
    changed; None: no pixel has fired). Events must come in order after ``latest``'s."""
    h, w = events.sensor_hw
    out = np.full(h * w, NEVER, np.int64) if latest is None else latest.copy()
    if len(events):
        pixel = events.y.astype(np.int64) * w + events.x.astype(np.int64)
        np.maximum.at(out, pixel, np.arange(first, first + len(events), dtype=np.int64))
    return out


def event_age(latest: np.ndarray, anchor: int, hw: tuple[int, int]) -> np.ndarray:
    """float32[H, W]: events since each pixel's latest event before global index ``anchor``
    (0 for a pixel that fired last, inf for one that never fired)."""
    age = (anchor - 1 - latest).astype(np.float32)
    age[latest == NEVER] = np.inf
    if np.any(age < 0):
        raise ValueError("the event history holds events at or after the output's anchor")
    return age.reshape(hw)


def history_input(age: np.ndarray, events_per_stack: int, taus: Sequence[float]) -> np.ndarray:
    """float32[len(taus), H, W]: ``exp(-age / (tau * events_per_stack))`` for each time
    constant ``tau`` in stacks (0 where a pixel never fired). ``age`` may be cropped or
    flipped first: the map is per pixel."""
    if events_per_stack < 1:
        raise ValueError(f"events per stack must be >= 1, got {events_per_stack}")
    age = np.asarray(age, np.float32)
    return np.stack([np.exp(-age / np.float32(tau * events_per_stack)) for tau in taus]
                    ).astype(np.float32)


class EventAge:
    """A running latest-event map for a stream read in order: :meth:`advance` takes the
    events a window is about to drop; :meth:`age_at` answers for any later anchor from the
    events still held, without moving (so outputs may be asked for out of order, as long
    as none lies before what was advanced)."""

    def __init__(self, hw: tuple[int, int]) -> None:
        self.hw = hw
        self.latest = np.full(hw[0] * hw[1], NEVER, np.int64)
        self.upto = 0  # events before this global index are folded into ``latest``

    def advance(self, events: Events, first: int, index: int) -> None:
        """Fold in the events with global indices ``[upto, index)`` from ``events`` (which
        start at global index ``first`` and must reach back to ``upto``)."""
        if index <= self.upto:
            return
        if first > self.upto or first + len(events) < index:
            raise ValueError(f"the event history needs events {self.upto:,}-{index:,}, the "
                             f"window holds {first:,}-{first + len(events):,}")
        part = events.slice(self.upto - first, index - first)
        np.copyto(self.latest, latest_index(part, self.upto, self.latest))
        self.upto = index

    def age_at(self, events: Events, first: int, anchor: int) -> np.ndarray:
        """float32[H, W]: :func:`event_age` at ``anchor`` (``>= upto``), with the events
        ``[upto, anchor)`` taken from ``events`` (starting at global index ``first``)."""
        if anchor < self.upto:
            raise ValueError(f"the event history has moved past event {anchor:,} (it is at "
                             f"{self.upto:,})")
        if first > self.upto or first + len(events) < anchor:
            raise ValueError(f"the event history needs events {self.upto:,}-{anchor:,}, the "
                             f"window holds {first:,}-{first + len(events):,}")
        part = events.slice(self.upto - first, anchor - first)
        return event_age(latest_index(part, self.upto, self.latest), anchor, self.hw)
