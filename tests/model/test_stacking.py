"""SBN/SBT stacks against a per-event reference and their defining properties."""

from __future__ import annotations

import numpy as np
import pytest

from esim_lite.core.events import Events
from esim_lite.core.stacking import StackConfig, sbn_stack, sbt_stack, stack_sequence


def random_events(n, hw=(20, 30), seed=0, hot=None):
    rng = np.random.default_rng(seed)
    x = rng.integers(0, hw[1], n).astype(np.int16)
    y = rng.integers(0, hw[0], n).astype(np.int16)
    if hot is not None:  # one pixel firing very often
        sel = rng.random(n) < hot
        x[sel], y[sel] = 3, 4
    t = np.sort(rng.integers(0, 10**9, n)).astype(np.int64)
    p = rng.choice(np.array([-1, 1], np.int8), n)
    return Events(x, y, t, p, hw)


def reference_channel(ev: Events, a: int, b: int) -> np.ndarray:
    """The definition, event by event: start at 128, each event overwrites its pixel."""
    img = np.full(ev.sensor_hw, 128, np.uint8)
    for i in range(a, b):
        img[ev.y[i], ev.x[i]] = 255 if ev.p[i] > 0 else 0
    return img


@pytest.mark.parametrize("direction", ["start", "end"])
@pytest.mark.parametrize("hot", [None, 0.3])
def test_sbn_matches_the_per_event_definition(direction, hot):
    ev = random_events(5000, hot=hot)
    cfg = StackConfig(channels=3, events_per_channel=400, overwrite_cap=20)
    stack = sbn_stack(ev, cfg, **{direction: 1000 if direction == "start" else 4000})
    assert stack.image.shape == (3, 20, 30) and stack.image.dtype == np.uint8
    assert set(np.unique(stack.image)) <= {0, 128, 255}
    for k, (a, b) in enumerate(stack.bounds):
        np.testing.assert_array_equal(stack.image[k], reference_channel(ev, a, b))
        pix = ev.y[a:b].astype(int) * 30 + ev.x[a:b]
        assert np.bincount(pix).max() <= cfg.overwrite_cap  # the cap holds
        if hot is None:
            assert b - a == 400  # no pixel reaches the cap: exactly Ne events
        else:
            assert b - a < 400  # closed early
            # ... exactly before the event that would exceed the cap
            nxt = b if direction == "start" else a - 1
            extended = np.r_[pix, ev.y[nxt] * 30 + ev.x[nxt]]
            assert np.bincount(extended).max() == cfg.overwrite_cap + 1
    assert np.all(stack.bounds[1:, 0] == stack.bounds[:-1, 1])  # channels are contiguous


def test_sequence_of_stacks_ends_at_the_anchor_with_the_requested_overlap():
    ev = random_events(20000, seed=1)
    cfg = StackConfig(channels=3, events_per_channel=500, overlap=300)
    stacks = stack_sequence(ev, cfg, anchor=10000, n_stacks=7)
    assert len(stacks) == 7
    assert stacks[3].end == 10000 and stacks[3].end - stacks[3].start == 1500
    for a, b in zip(stacks[:-1], stacks[1:]):
        assert a.end - b.start == 300  # overlap L between consecutive stacks
    no_overlap = stack_sequence(ev, StackConfig(channels=3, events_per_channel=500), 10000, 3)
    assert no_overlap[0].end == no_overlap[1].start and no_overlap[1].end == no_overlap[2].start


def test_stacks_near_the_stream_ends_are_partly_empty():
    ev = random_events(700)
    stack = sbn_stack(ev, StackConfig(channels=3, events_per_channel=500), start=0)
    assert stack.bounds.tolist() == [[0, 500], [500, 700], [700, 700]]
    assert np.all(stack.image[2] == 128)


def test_sbt_windows():
    ev = random_events(3000)
    cfg = StackConfig(method="sbt", channels=3, channel_ms=100.0)
    stack = sbt_stack(ev, cfg, t_end_ns=600_000_000)
    for k, (a, b) in enumerate(stack.bounds):
        lo, hi = 300_000_000 + k * 100_000_000, 400_000_000 + k * 100_000_000
        inside = np.flatnonzero((ev.t_ns > lo) & (ev.t_ns <= hi))
        assert (a, b) == (inside[0], inside[-1] + 1)
        np.testing.assert_array_equal(stack.image[k], reference_channel(ev, a, b))


def test_events_per_channel_scales_with_area():
    assert StackConfig.events_per_channel_for((180, 240)) == 1667
    assert StackConfig.events_per_channel_for((128, 128)) == 632


def test_sbt_sequence_is_adjacent_in_time():
    from esim_lite.core.stacking import stack_sequence_by_time

    ev = random_events(5000)
    cfg = StackConfig(method="sbt", channels=3, channel_ms=20.0)
    stacks = stack_sequence_by_time(ev, cfg, t_anchor_ns=500_000_000, n_stacks=3)
    assert [s.end for s in stacks[:-1]] == [s.start for s in stacks[1:]]
    assert np.searchsorted(ev.t_ns, 500_000_000, "right") == stacks[1].end
    assert np.searchsorted(ev.t_ns, 440_000_000, "right") == stacks[1].start
