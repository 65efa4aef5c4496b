"""Scoring against APS frames with an exposure: the average over the window, the outputs it
takes, and evaluation's streamed result against a direct in-memory computation."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from datagen.formats.base import Recording
from esim_lite.core.frames import Frames
from model.inference.exposure import boundary_times, exposure_average, exposure_stats
from model.inference.reconstruct import EventWindow
from tests.datagen.test_recording import events


def test_the_average_is_the_mean_of_the_outputs_inside_the_window():
    rng = np.random.default_rng(0)
    images = [rng.random((4, 5)).astype(np.float32) for _ in range(6)]
    times = [10, 20, 30, 40, 50, 60]
    mean, n = exposure_average(times, images, (20, 45))  # 20, 30, 40: ends included
    assert n == 3
    np.testing.assert_allclose(mean, (images[1] + images[2] + images[3]) / 3, rtol=1e-6)
    before, n = exposure_average(times, images, (0, 5))  # none inside: the nearest
    assert n == 1 and np.array_equal(before, images[0])
    between, n = exposure_average(times, images, (52, 57))  # 50 is 2 ns off, 60 is 3
    assert n == 1 and np.array_equal(between, images[4])
    with pytest.raises(ValueError, match="one image per time"):
        exposure_average([1, 2], images[:1], (0, 3))


def test_boundary_times_are_those_of_every_nth_event_inside_the_window():
    ev = events(n=5000, hw=(30, 40))
    window = EventWindow(iter([ev.slice(0, 2000), ev.slice(2000, 5000)]), ev.sensor_hw)
    start, end = int(ev.t_ns[1000]), int(ev.t_ns[2600])
    every = 300
    expected = sorted({int(ev.t_ns[k * every - 1]) for k in range(1, 5000 // every + 1)
                       if start <= ev.t_ns[k * every - 1] <= end})
    assert boundary_times(window, every, start, end) == expected
    assert len(expected) >= 5


def centred_recording(n_frames=3, exposure_ms=130.0, hw=(48, 64)) -> Recording:
    """Random events over 1-3 s; frames every 40 ms from 1.5 s with exposures centred on
    them and longer than the frame interval (each window holds the previous frame's time)."""
    ev = events(n=20000, hw=hw, seed=5)
    rng = np.random.default_rng(6)
    t = (1.5e9 + 40e6 * np.arange(n_frames)).astype(np.int64)
    half = int(exposure_ms * 1e6 / 2)
    frames = Frames(rng.random((n_frames,) + hw).astype(np.float32), t)

    def chunks(size):
        for k in range(0, len(ev), 1500):
            yield ev.slice(k, min(k + 1500, len(ev)))

    return Recording(Path("centred"), "aedat4", hw, frames, chunks,
                     np.stack([t - half, t + half], 1))


def test_evaluation_averages_our_outputs_over_each_exposure(tiny_checkpoint):
    """The streamed, forgetting evaluation equals the mean of outputs computed directly on
    all events in memory at the stack boundaries inside the window and at the frame."""
    from model.inference.evaluate import EvalOptions, ModelPool, recording_outputs

    rec = centred_recording()
    stats = exposure_stats(rec)
    assert stats.exposure_ms == (130.0, 130.0, 130.0) and stats.stamp_position == 0.5
    options = EvalOptions(baselines=(), temporal=False, exposure_average=True,
                          stack_rule="area")
    model = ModelPool(tiny_checkpoint, options).for_recording(rec)
    seq = recording_outputs(rec, model, options, "centred")
    all_events = rec.read_all()
    per = model.stacks.events_per_stack
    boundaries = all_events.t_ns[per - 1::per]
    for pos, k in enumerate(range(1, len(rec.frames))):
        start, end = rec.exposures_ns[k]
        times = sorted({int(u) for u in boundaries if start <= u <= end}
                       | {int(rec.frames.t_ns[k])})
        outs = []
        for u in times:
            whole = EventWindow(iter([all_events]), rec.sensor_hw)
            outs.append(model.run(model.stacks_at(whole, u).stacks, None)[0])
        assert seq.averaged[pos] == len(times) >= 4
        np.testing.assert_allclose(seq.images["ours"][pos], np.mean(outs, axis=0), atol=1e-6)
    plain = recording_outputs(rec, model, EvalOptions(baselines=(), temporal=False,
                                                      max_frames=1), "plain")
    assert not plain.averaged
    assert not np.allclose(plain.images["ours"][0], seq.images["ours"][0])


def test_evaluation_averages_the_baselines_over_each_exposure_like_ours(tiny_checkpoint):
    """HF and direct integration are sampled at our times inside the window (those a filter
    can still reach: from the previous frame on) and averaged; each sample equals a fresh
    filter fed every event up to it."""
    from model.inference.baselines import EventFilter
    from model.inference.evaluate import EvalOptions, ModelPool, recording_outputs

    rec = centred_recording()
    options = EvalOptions(baselines=("hf", "direct"), temporal=False, exposure_average=True,
                          stack_rule="area")
    model = ModelPool(tiny_checkpoint, options).for_recording(rec)
    seq = recording_outputs(rec, model, options, "centred")
    plain = recording_outputs(rec, model, replace(options, exposure_average=False), "plain")
    all_events = rec.read_all()
    per = model.stacks.events_per_stack
    boundaries = all_events.t_ns[per - 1::per]
    for pos, k in enumerate(range(1, len(rec.frames))):
        start, end = rec.exposures_ns[k]
        t, before = int(rec.frames.t_ns[k]), int(rec.frames.t_ns[k - 1])
        times = sorted({int(u) for u in boundaries if start <= u <= end} | {t})
        samples = [u for u in times if u >= before]
        assert len(samples) >= 3 and any(u > t for u in samples)
        for method in ("hf", "direct"):
            expected = []
            for u in samples:
                f = EventFilter(method, rec.sensor_hw, options.filters)
                f.add_events(all_events.slice(0, int(np.searchsorted(all_events.t_ns, u, "right"))))
                expected.append(f.image(u))
            np.testing.assert_allclose(seq.images[method][pos], np.mean(expected, axis=0),
                                       atol=1e-6)
            # without averaging: the image at the frame's time (with it, the later frames'
            # samples above show that the samples taken past a frame left the filters alone)
            fresh = EventFilter(method, rec.sensor_hw, options.filters)
            fresh.add_events(all_events.slice(0, int(np.searchsorted(all_events.t_ns, t, "right"))))
            np.testing.assert_allclose(plain.images[method][pos], fresh.image(t), atol=1e-6)
