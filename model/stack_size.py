"""How many events make one SBN stack on a recording the model was not trained on.

The network learned what a stack looks like from ``E`` events per stack (3 x 3,000 for the
shipped models) on a 128x128 camera moving over a textured plane: most pixels see texture
pass (by :func:`activity_of`'s measure, 53-98% of the pixels, mean 79%, over the first
second of eight sequences of the default dataset: ``datagen generate --n-seq 8 --seed 1``,
homography renderer, builtin textures). Three rules, in order:

- ``given``: an explicit number (``--events-per-stack``);
- ``active`` (the default for real recordings): the same number of events per *active*
  pixel per stack as in training, taking every training pixel as active. A pixel is active
  when it fires at least ``min_events`` (2) events in the recording's first ``window_s``
  (1 s; the whole recording when shorter): two, so a lone background-activity event does not
  count, and one second, so a moving object has time to show the area it sweeps. Then
  ``E' = E * active_pixels / trained_pixels``, with the active fraction clamped to
  ``[MIN_ACTIVE_FRACTION, 1]`` so that a recording where almost nothing moves (hot pixels,
  noise) still gets stacks of hundreds of events. A static camera watching cars (a few
  percent of the pixels active) thus gets stacks that cover the cars' edges as densely as
  training stacks covered the plane, instead of stacks that span a second and smear them;
- ``area`` (the paper's rule, kept for simulated shards): ``E' = E * area / trained_area``,
  i.e. every pixel active.

A model trained with ``data.stack_rule: active`` (model/data/config.py) saw the active rule
on every training sequence, so ``auto`` gives it the active rule on simulated shards too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from datagen.formats.base import READ_CHUNK_EVENTS
from datagen.recording import Recording
from esim_lite.core.events import Events

Rule = Literal["auto", "active", "area"]
ACTIVE_MIN_EVENTS = 2
ACTIVE_WINDOW_S = 1.0
MIN_ACTIVE_FRACTION = 1 / 64


@dataclass(frozen=True)
class Activity:
    """How much of a sensor a recording uses: ``active_pixels`` fired at least
    ``min_events`` events among the ``events`` of its first ``seconds`` (the window asked
    for, or less when the recording is shorter)."""

    active_pixels: int
    sensor_hw: tuple[int, int]
    seconds: float
    events: int
    min_events: int

    @property
    def fraction(self) -> float:
        return self.active_pixels / (self.sensor_hw[0] * self.sensor_hw[1])


def activity_of(events: Events, window_s: float = ACTIVE_WINDOW_S,
                min_events: int = ACTIVE_MIN_EVENTS) -> Activity:
    """:class:`Activity` of ``events`` (time-sorted) over their first ``window_s`` seconds."""
    if window_s <= 0 or min_events < 1:
        raise ValueError(f"window_s must be > 0 and min_events >= 1, got {window_s}, "
                         f"{min_events}")
    h, w = events.sensor_hw
    if not len(events):
        return Activity(0, (h, w), 0.0, 0, min_events)
    end = int(np.searchsorted(events.t_ns, events.t_ns[0] + round(window_s * 1e9)))
    counts = np.bincount(events.y[:end].astype(np.int64) * w + events.x[:end], minlength=h * w)
    span = (int(events.t_ns[end - 1]) - int(events.t_ns[0])) * 1e-9
    return Activity(int(np.count_nonzero(counts >= min_events)), (h, w), span, end, min_events)


def measure_activity(recording: Recording, window_s: float = ACTIVE_WINDOW_S,
                     min_events: int = ACTIVE_MIN_EVENTS,
                     chunk: int = READ_CHUNK_EVENTS) -> Activity:
    """:func:`activity_of` the recording's first ``window_s`` seconds, reading only those
    and holding one chunk at a time (per-pixel counts accumulate chunk by chunk, so a
    second of a billion events takes no more memory than a second of a thousand)."""
    if window_s <= 0 or min_events < 1:
        raise ValueError(f"window_s must be > 0 and min_events >= 1, got {window_s}, "
                         f"{min_events}")
    h, w = recording.sensor_hw
    counts = np.zeros(h * w, np.int64)
    t0 = last = None
    n = 0
    for ev in recording.events(chunk):
        t0 = int(ev.t_ns[0]) if t0 is None else t0
        end = int(np.searchsorted(ev.t_ns, t0 + round(window_s * 1e9)))
        counts += np.bincount(ev.y[:end].astype(np.int64) * w + ev.x[:end], minlength=h * w)
        n += end
        last = int(ev.t_ns[end - 1]) if end else last
        if end < len(ev):
            break
    if not n:
        return Activity(0, (h, w), 0.0, 0, min_events)
    return Activity(int(np.count_nonzero(counts >= min_events)), (h, w), (last - t0) * 1e-9, n,
                    min_events)


@dataclass(frozen=True)
class StackChoice:
    """The events per SBN stack used on one recording and why: ``rule`` is ``given``,
    ``area`` or ``active`` (with the ``activity`` it was measured from); ``trained`` is the
    model's own events per channel at ``trained_hw``."""

    events_per_channel: int
    channels: int
    rule: Literal["given", "area", "active"]
    trained: int
    trained_hw: tuple[int, int]
    sensor_hw: tuple[int, int]
    activity: Activity | None = None

    @property
    def events_per_stack(self) -> int:
        return self.events_per_channel * self.channels

    def describe(self) -> str:
        """One line: the number and the rule that chose it, e.g. for a report."""
        n, trained = f"{self.events_per_stack:,}", f"{self.trained * self.channels:,}"
        th, tw = self.trained_hw
        if self.rule == "given":
            return f"{n} (given)"
        if self.rule == "area":
            h, w = self.sensor_hw
            return f"{n} (area: {trained} at {tw}x{th} x {w}x{h} / {tw}x{th})"
        a = self.activity
        f = min(max(a.fraction, MIN_ACTIVE_FRACTION), 1.0)
        clamp = "" if f == a.fraction else f", clamped to {100 * f:.1f}%"
        return (f"{n} (active: {a.active_pixels:,} pixels = {100 * a.fraction:.1f}% fired "
                f">= {a.min_events} events in the first {a.seconds:.2f} s{clamp}; "
                f"{trained} per {tw}x{th} active pixels)")


def resolve_rule(rule: Rule, kind: str, trained: str = "fixed") -> Literal["active", "area"]:
    """``auto``: ``active`` on real recordings; on our simulated shards (recorded at the
    training camera) the rule the model was trained with (``trained``, its
    ``data.stack_rule``): ``area`` for ``fixed``, ``active`` for ``active``."""
    if rule not in ("auto", "active", "area"):
        raise ValueError(f"unknown stack rule {rule!r} (expected auto, active or area)")
    if rule == "auto":
        return "active" if kind != "shard" or trained == "active" else "area"
    return rule


def activity_for_rule(recording: Recording, rule: Rule, trained: str = "fixed",
                      given: int | None = None) -> Activity | None:
    """The recording's :func:`measure_activity` when its stacks follow the active rule
    (:func:`resolve_rule` of ``rule`` for this recording and a model trained with
    ``trained``; never with a ``given`` size), else None (the area rule)."""
    if given is not None or resolve_rule(rule, recording.kind, trained) != "active":
        return None
    return measure_activity(recording)


def choose_stack(trained_per_channel: int, channels: int, trained_hw: tuple[int, int],
                 sensor_hw: tuple[int, int], given: int | None = None,
                 activity: Activity | None = None) -> StackChoice:
    """Events per stack for a ``sensor_hw`` recording (see the module doc): ``given`` if
    set, else the active-pixel rule if an ``activity`` is given, else the area rule."""
    trained_area = trained_hw[0] * trained_hw[1]
    if given is not None:
        if given < 1:
            raise ValueError(f"events per stack must be >= 1, got {given}")
        return StackChoice(max(1, given // channels), channels, "given", trained_per_channel,
                           trained_hw, sensor_hw)
    if activity is None:
        ratio, rule = sensor_hw[0] * sensor_hw[1] / trained_area, "area"
    else:
        if activity.sensor_hw != tuple(sensor_hw):
            raise ValueError(f"activity measured on a {activity.sensor_hw} sensor, stacks "
                             f"asked for {sensor_hw}")
        fraction = min(max(activity.fraction, MIN_ACTIVE_FRACTION), 1.0)
        ratio, rule = fraction * sensor_hw[0] * sensor_hw[1] / trained_area, "active"
    return StackChoice(max(1, round(trained_per_channel * ratio)), channels, rule,
                       trained_per_channel, trained_hw, sensor_hw, activity)
