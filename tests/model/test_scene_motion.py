"""The swept share and its verdict (model/inference/scene_motion.py) on synthetic event
cameras with known answers: a texture moving across the frame, a static scene with a small
moving object under noise and hot pixels, a static scene under a flickering lamp."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from datagen.formats.base import Recording
from esim_lite.core.events import Events
from model.inference.scene_motion import (
    MOVING,
    MOVING_SHARE,
    STATIC,
    SwingMap,
    measure_scene_motion,
    scene_motion_of,
)

HW = (60, 80)
C = 0.2  # contrast threshold (log intensity)


def texture(rng, hw, blur=3.0, contrast=1.5) -> np.ndarray:
    """Smooth random log intensity spanning about ``contrast``."""
    img = cv2.GaussianBlur(rng.standard_normal(hw).astype(np.float32), (0, 0), blur)
    return contrast * (img - img.mean()) / (img.std() * 4)


def events_of(log_frames: np.ndarray, t_ns: np.ndarray, rng) -> Events:
    """A reference-based event camera: a pixel fires each time its log intensity leaves its
    reference level by ``C`` (reference moved by ``C``); references start at the first
    frame shifted by up to +-C/2."""
    hw = log_frames.shape[1:]
    ref = log_frames[0] + rng.uniform(-C / 2, C / 2, hw)
    xs, ys, ts, ps = [], [], [], []
    for frame, t in zip(log_frames[1:], t_ns[1:]):
        n = np.trunc((frame - ref) / C).astype(np.int64)
        ref += n * C
        for sign in (1, -1):
            k = np.clip(sign * n, 0, None)
            y, x = np.nonzero(k)
            reps = k[y, x]
            xs.append(np.repeat(x, reps))
            ys.append(np.repeat(y, reps))
            ps.append(np.full(int(reps.sum()), sign))
            ts.append(np.full(int(reps.sum()), t))
    order = np.argsort(np.concatenate(ts), kind="stable")
    return Events(np.concatenate(xs)[order].astype(np.int16),
                  np.concatenate(ys)[order].astype(np.int16),
                  np.concatenate(ts)[order].astype(np.int64),
                  np.concatenate(ps)[order].astype(np.int8), hw)


def times(n: int, seconds: float) -> np.ndarray:
    return (np.linspace(0, seconds, n) * 1e9).astype(np.int64)


def fired_twice_share(ev: Events) -> float:
    """The count-based measure the swing replaces: pixels with at least 2 events."""
    h, w = ev.sensor_hw
    counts = np.bincount(ev.y.astype(np.int64) * w + ev.x, minlength=h * w)
    return float(np.mean(counts >= 2))


def moving_texture(rng) -> Events:
    """A texture moving one frame width across the frame in a second."""
    wide = texture(rng, (HW[0], 3 * HW[1]))
    t = times(200, 1.0)
    shift = np.linspace(0, HW[1], len(t)).astype(int)
    return events_of(np.stack([wide[:, s:s + HW[1]] for s in shift]), t, rng)


def test_a_texture_moving_across_the_frame_is_moving():
    motion = scene_motion_of(moving_texture(np.random.default_rng(0)))
    assert motion.swept_share > 0.8 and motion.moving and motion.verdict == MOVING
    assert "moving: whole frame" in motion.describe() and "(moving from 50%)" in motion.describe()


def static_scene_with_a_small_object(rng) -> Events:
    """A static textured scene; a 10x10 dark square crossing a third of the width."""
    scene = texture(rng, HW)
    t = times(150, 1.0)
    frames = np.repeat(scene[None], len(t), 0)
    for k, x0 in enumerate(np.linspace(5, 5 + HW[1] // 3, len(t)).astype(int)):
        frames[k, 25:35, x0:x0 + 10] = -1.0
    return events_of(frames, t, rng)


def with_noise_and_hot_pixels(ev: Events, rng, per_pixel: float = 1.0) -> Events:
    """``ev`` plus uniform background noise (``per_pixel`` events on average, ON or OFF)
    and 20 hot pixels firing 300 ON events each, over the same second."""
    h, w = ev.sensor_hw
    n = int(per_pixel * h * w)
    hot = rng.integers(0, [w, h], (20, 2))
    x = np.concatenate([ev.x, rng.integers(0, w, n), np.repeat(hot[:, 0], 300)])
    y = np.concatenate([ev.y, rng.integers(0, h, n), np.repeat(hot[:, 1], 300)])
    t = np.concatenate([ev.t_ns, rng.integers(0, 10**9, n + 20 * 300)])
    p = np.concatenate([ev.p, rng.choice([-1, 1], n), np.ones(20 * 300)])
    order = np.argsort(t, kind="stable")
    return Events(x[order].astype(np.int16), y[order].astype(np.int16), t[order].astype(np.int64),
                  p[order].astype(np.int8), ev.sensor_hw)


def test_a_static_scene_with_a_small_object_noise_and_hot_pixels_is_static():
    rng = np.random.default_rng(1)
    clean = static_scene_with_a_small_object(rng)
    assert 0.02 < scene_motion_of(clean).swept_share < 0.3  # the object's track
    noisy = with_noise_and_hot_pixels(clean, rng)
    assert fired_twice_share(noisy) > fired_twice_share(clean) + 0.2  # noise fires widely
    motion = scene_motion_of(noisy)
    assert motion.swept_share < 0.3 and not motion.moving and motion.verdict == STATIC
    # the hot pixels alone sweep nothing: they have no neighbours
    hot_only = with_noise_and_hot_pixels(clean.slice(0, 0), rng, per_pixel=0.0)
    assert scene_motion_of(hot_only).swept_share == 0.0


def test_a_flickering_lamp_over_a_static_scene_is_static():
    """Most pixels fire ON, OFF, ON, ... (a count measure would call it moving); the
    running sum never spans two thresholds."""
    rng = np.random.default_rng(2)
    scene = texture(rng, HW)
    t = times(1000, 0.5)
    ripple = 0.8 * C * np.sin(2 * np.pi * 100 * t * 1e-9)  # 100 Hz, 1.6 C peak to peak
    ev = events_of(scene[None] + ripple[:, None, None], t, rng)
    assert fired_twice_share(ev) > MOVING_SHARE
    motion = scene_motion_of(ev)
    assert motion.swept_share < 0.05 and motion.verdict == STATIC


def test_streaming_a_recording_in_chunks_gives_the_in_memory_measure():
    rng = np.random.default_rng(3)
    ev = with_noise_and_hot_pixels(static_scene_with_a_small_object(rng), rng)

    def chunks(size):
        for k in range(0, len(ev), size):
            yield ev.slice(k, min(k + size, len(ev)))

    rec = Recording(Path("synthetic"), "text", HW, None, chunks)
    streamed = measure_scene_motion(rec, chunk=777)
    assert streamed == scene_motion_of(ev)
    assert streamed.events == len(ev) and streamed.seconds == pytest.approx(
        (ev.t_ns[-1] - ev.t_ns[0]) * 1e-9)


def test_the_swing_is_the_span_of_the_running_polarity_sum():
    # one pixel: +1 +1 -1 -1 -1 -> sums 1 2 1 0 -1: span from -1 to 2 is 3;
    # another: +1 -1 +1 -1 -> span 1 (0 included)
    x = np.array([0, 0, 0, 0, 0, 1, 1, 1, 1], np.int16)
    p = np.array([1, 1, -1, -1, -1, 1, -1, 1, -1], np.int8)
    ev = Events(x, np.zeros(9, np.int16), np.arange(9, dtype=np.int64), p, (1, 3))
    swings = SwingMap((1, 3))
    swings.add(ev)
    np.testing.assert_array_equal(swings.swing(), [[3, 1, 0]])
    with pytest.raises(ValueError, match="sensor"):
        swings.add(Events(x, np.zeros(9, np.int16), np.arange(9, dtype=np.int64), p, (2, 3)))
