"""The compiled SBN/SBT stacking against the numpy implementation it replaced (issue 25).

``reference_*`` below is that implementation, copied verbatim as the oracle (and timed
against the compiled one by ``bench/bench_stacking.py``): images, starts, ends and bounds
must be bit-identical on random streams with many repeated pixels, caps hit, streams
shorter than a stack, positions at and beyond the stream's edges, and empty input.
"""

from __future__ import annotations

import numpy as np
import pytest

from esim_lite.core.events import Events
from esim_lite.core.stacking import (
    StackConfig,
    paint_channel,
    sbn_stack,
    sbt_stack,
    stack_sequence,
)

BACKGROUND, ON, OFF = 128, 255, 0


def reference_capped_length(pix: np.ndarray, cap: int) -> int:
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


def reference_paint_channel(x: np.ndarray, y: np.ndarray, p: np.ndarray,
                            hw: tuple[int, int]) -> np.ndarray:
    """uint8[H, W] canvas of 128 with each pixel's newest event: 255 ON, 0 OFF."""
    h, w = hw
    canvas = np.full(h * w, BACKGROUND, np.uint8)
    if len(x):
        pix = y.astype(np.int64) * w + x
        last = len(pix) - 1 - np.unique(pix[::-1], return_index=True)[1]
        canvas[pix[last]] = np.where(p[last] > 0, ON, OFF)
    return canvas.reshape(h, w)


def reference_sbn_stack(events: Events, config: StackConfig, *, start: int | None = None,
                        end: int | None = None) -> tuple[np.ndarray, int, int, np.ndarray]:
    """(image, start, end, bounds) of the SBN stack, as the numpy implementation built it."""
    if (start is None) == (end is None):
        raise ValueError("give exactly one of start= or end=")
    pix = events.y.astype(np.int64) * events.sensor_hw[1] + events.x
    ne, cap, n = config.events_per_channel, config.overwrite_cap, len(events)
    bounds = []
    if start is not None:
        s = min(max(start, 0), n)
        for _ in range(config.channels):
            e = s + reference_capped_length(pix[s:min(s + ne, n)], cap)
            bounds.append((s, e))
            s = e
    else:
        e = min(max(end, 0), n)
        for _ in range(config.channels):
            s = e - reference_capped_length(pix[max(e - ne, 0):e][::-1], cap)
            bounds.append((s, e))
            e = s
        bounds.reverse()
    image = np.stack([reference_paint_channel(events.x[a:b], events.y[a:b], events.p[a:b],
                                              events.sensor_hw) for a, b in bounds])
    return image, bounds[0][0], bounds[-1][1], np.array(bounds, np.int64)


def reference_stack_sequence(events: Events, config: StackConfig, anchor: int,
                             n_stacks: int) -> list[tuple]:
    """The oracle's stacks around ``anchor``, as :func:`stack_sequence` chains them."""
    centre = reference_sbn_stack(events, config, end=anchor)
    before, after = [], []
    nxt = centre
    for _ in range(n_stacks // 2):
        nxt = reference_sbn_stack(events, config, end=nxt[1] + config.overlap)
        before.append(nxt)
    prev = centre
    for _ in range(n_stacks // 2):
        prev = reference_sbn_stack(events, config, start=prev[2] - config.overlap)
        after.append(prev)
    return before[::-1] + [centre] + after


def clustered_events(n: int, hw: tuple[int, int], seed: int, n_hot: int) -> Events:
    """``n`` events whose pixels are drawn mostly from ``n_hot`` hot pixels (so caps are
    hit and pixels repeat often), with some uniform ones."""
    rng = np.random.default_rng(seed)
    h, w = hw
    hot = rng.integers(0, h * w, max(n_hot, 1))
    pix = np.where(rng.random(n) < 0.7, hot[rng.integers(0, len(hot), n)],
                   rng.integers(0, h * w, n))
    t = np.sort(rng.integers(0, 10**9, n)).astype(np.int64)
    p = rng.choice(np.array([-1, 1], np.int8), n)
    return Events((pix % w).astype(np.int16), (pix // w).astype(np.int16), t, p, hw)


def assert_same(stack, want) -> None:
    image, start, end, bounds = want
    assert stack.image.dtype == np.uint8 and stack.image.shape == image.shape
    np.testing.assert_array_equal(stack.image, image)
    assert (stack.start, stack.end) == (start, end)
    assert type(stack.start) is int and type(stack.end) is int
    assert stack.bounds.dtype == np.int64
    np.testing.assert_array_equal(stack.bounds, bounds)


def positions(n: int, rng: np.random.Generator) -> list[int]:
    """Start/end positions at, near and beyond the stream's edges, plus random ones."""
    return sorted({-5, 0, 1, n // 2, max(n - 1, 0), n, n + 7,
                   *rng.integers(0, n + 1, 4).tolist()})


@pytest.mark.parametrize("seed", range(12))
def test_sbn_stack_is_bit_identical_to_the_numpy_oracle(seed):
    rng = np.random.default_rng(100 + seed)
    hw = (int(rng.integers(1, 12)), int(rng.integers(1, 15)))
    n = int(rng.choice([0, 1, 7, 60, 400, 2500]))
    ev = clustered_events(n, hw, seed, n_hot=int(rng.integers(1, 6)))
    for _ in range(4):
        cfg = StackConfig(channels=int(rng.integers(1, 5)),
                          events_per_channel=int(rng.integers(1, 300)),
                          overwrite_cap=int(rng.choice([1, 2, 5, 50, 10**6])))
        for pos in positions(n, rng):
            assert_same(sbn_stack(ev, cfg, start=pos), reference_sbn_stack(ev, cfg, start=pos))
            assert_same(sbn_stack(ev, cfg, end=pos), reference_sbn_stack(ev, cfg, end=pos))


@pytest.mark.parametrize("hw", [(128, 128), (180, 240), (260, 346)])
def test_sensor_sized_stacks_match_the_oracle(hw):
    ev = clustered_events(40_000, hw, seed=hw[0], n_hot=40)
    cfg = StackConfig(channels=3, events_per_channel=5000, overwrite_cap=50)
    for pos in (0, 1234, 20_000, 39_999, 40_000):
        assert_same(sbn_stack(ev, cfg, start=pos), reference_sbn_stack(ev, cfg, start=pos))
        assert_same(sbn_stack(ev, cfg, end=pos), reference_sbn_stack(ev, cfg, end=pos))


@pytest.mark.parametrize("overlap", [0, 1, 250])
@pytest.mark.parametrize("n_stacks", [1, 3, 7])
def test_stack_sequence_matches_the_oracle(overlap, n_stacks):
    ev = clustered_events(6000, (9, 13), seed=n_stacks + overlap, n_hot=3)
    cfg = StackConfig(channels=3, events_per_channel=300, overwrite_cap=20, overlap=overlap)
    for anchor in (0, 100, 3000, 6000):
        got = stack_sequence(ev, cfg, anchor, n_stacks)
        want = reference_stack_sequence(ev, cfg, anchor, n_stacks)
        assert len(got) == len(want)
        for stack, ref in zip(got, want):
            assert_same(stack, ref)


def test_empty_stream_gives_background_channels():
    ev = Events.empty((4, 5))
    cfg = StackConfig(channels=3, events_per_channel=10)
    for kw in ({"start": 0}, {"end": 0}, {"start": 3}, {"end": -2}):
        stack = sbn_stack(ev, cfg, **kw)
        assert_same(stack, reference_sbn_stack(ev, cfg, **kw))
        assert np.all(stack.image == 128) and stack.bounds.tolist() == [[0, 0]] * 3


@pytest.mark.parametrize("seed", range(6))
def test_paint_channel_matches_the_oracle(seed):
    ev = clustered_events(int(np.random.default_rng(seed).integers(0, 3000)), (7, 11),
                          seed, n_hot=2)
    np.testing.assert_array_equal(paint_channel(ev.x, ev.y, ev.p, ev.sensor_hw),
                                  reference_paint_channel(ev.x, ev.y, ev.p, ev.sensor_hw))


def test_sbt_stack_matches_the_oracle_painter():
    ev = clustered_events(3000, (10, 12), seed=3, n_hot=4)
    cfg = StackConfig(method="sbt", channels=4, channel_ms=150.0)
    for t_end in (0, 300_000_000, 700_000_000, 2_000_000_000):
        stack = sbt_stack(ev, cfg, t_end_ns=t_end)
        want = np.stack([reference_paint_channel(ev.x[a:b], ev.y[a:b], ev.p[a:b], (10, 12))
                         for a, b in stack.bounds])
        np.testing.assert_array_equal(stack.image, want)
        assert stack.bounds.dtype == np.int64


def test_stack_reads_only_its_own_events():
    """Events outside the stack's window may hold anything: they are never read."""
    ev = clustered_events(5000, (6, 8), seed=5, n_hot=2)
    bad = Events(ev.x.copy(), ev.y.copy(), ev.t_ns, ev.p, ev.sensor_hw)
    bad.x[:1000], bad.x[4000:] = 30_000, -30_000  # far outside the sensor
    cfg = StackConfig(channels=3, events_per_channel=300, overwrite_cap=10)
    assert_same(sbn_stack(bad, cfg, start=1000), reference_sbn_stack(ev, cfg, start=1000))
    assert_same(sbn_stack(bad, cfg, end=4000), reference_sbn_stack(ev, cfg, end=4000))


def test_events_outside_the_sensor_raise():
    ev = clustered_events(100, (6, 8), seed=1, n_hot=2)
    bad = Events(ev.x.copy(), ev.y, ev.t_ns, ev.p, ev.sensor_hw)
    bad.x[50] = 8
    with pytest.raises(ValueError, match="outside sensor_hw"):
        sbn_stack(bad, StackConfig(channels=1, events_per_channel=100), start=0)
    with pytest.raises(ValueError, match="outside sensor_hw"):
        paint_channel(bad.x, bad.y, bad.p, bad.sensor_hw)
