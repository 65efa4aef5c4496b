"""Events per stack on recordings the model was not trained on: the active-pixel rule against
constructed recordings whose active pixels are known, the area rule, the override."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from datagen.formats.base import Recording
from esim_lite.core.events import Events
from model.stack_size import (
    MIN_ACTIVE_FRACTION,
    activity_of,
    choose_stack,
    measure_activity,
    resolve_rule,
)

SHIPPED = (3000, 3, (128, 128))  # the shipped models: 3 x 3,000 events per stack at 128x128


def firing(hw, active_cols: int, per_pixel: int = 3, seconds: float = 0.9, seed: int = 0
           ) -> Events:
    """Each pixel of the first ``active_cols`` columns fires ``per_pixel`` events at random
    times in ``[0, seconds)``; the other pixels never fire."""
    rng = np.random.default_rng(seed)
    h = hw[0]
    ys, xs = np.meshgrid(np.arange(h), np.arange(active_cols), indexing="ij")
    x = np.repeat(xs.ravel(), per_pixel)
    y = np.repeat(ys.ravel(), per_pixel)
    t = rng.integers(0, int(seconds * 1e9), len(x))
    order = np.argsort(t, kind="stable")
    return Events(x[order].astype(np.int16), y[order].astype(np.int16),
                  t[order].astype(np.int64) + 10**9, rng.choice(np.array([-1, 1], np.int8),
                                                                len(x)), hw)


def test_every_pixel_active_at_128x128_gives_the_trained_stacks():
    act = activity_of(firing((128, 128), 128))
    assert act.fraction == 1.0
    choice = choose_stack(*SHIPPED, (128, 128), activity=act)
    assert (choice.rule, choice.events_per_channel, choice.events_per_stack) == \
        ("active", 3000, 9000)


@pytest.mark.parametrize("hw, cols", [((128, 128), 32), ((128, 128), 64), ((260, 346), 173),
                                      ((180, 240), 24)])
def test_stacks_scale_with_the_active_pixels_not_the_area(hw, cols):
    act = activity_of(firing(hw, cols))
    assert act.active_pixels == hw[0] * cols
    choice = choose_stack(*SHIPPED, hw, activity=act)
    # the same events per active pixel per stack as training's 9,000 per 128x128 pixels
    expected = 3000 * hw[0] * cols / (128 * 128)
    assert choice.events_per_channel == round(expected)
    area = choose_stack(*SHIPPED, hw)
    assert area.rule == "area" and area.events_per_channel == round(3000 * hw[0] * hw[1]
                                                                    / 128**2)
    assert choice.events_per_stack < area.events_per_stack


def test_a_pixel_needs_two_events_inside_the_first_second():
    hw = (8, 8)
    # pixel 0: 2 events early (active); pixel 1: 1 event (noise); pixel 2: 2 events but
    # the second after the first second (not active in the window)
    x = np.array([0, 1, 0, 2, 2], np.int16)
    t = np.array([0, 0.2, 0.5, 0.6, 1.5]) * 1e9 + 10**9
    ev = Events(x, np.zeros(5, np.int16), t.astype(np.int64), np.ones(5, np.int8), hw)
    act = activity_of(ev)
    assert act.active_pixels == 1 and act.events == 4 and act.seconds == pytest.approx(0.6)
    assert activity_of(ev, window_s=2.0).active_pixels == 2


def test_the_active_fraction_is_clamped_below():
    hw = (260, 346)
    act = activity_of(firing(hw, 1))  # one column: 0.3% of the pixels
    choice = choose_stack(*SHIPPED, hw, activity=act)
    assert act.fraction < MIN_ACTIVE_FRACTION
    assert choice.events_per_channel == round(3000 * MIN_ACTIVE_FRACTION * hw[0] * hw[1]
                                              / 128**2)
    assert "clamped" in choice.describe()


def test_an_explicit_number_wins_and_the_rule_follows_the_recording_kind():
    act = activity_of(firing((128, 128), 16))
    given = choose_stack(*SHIPPED, (128, 128), given=6000, activity=act)
    assert (given.rule, given.events_per_stack) == ("given", 6000)
    assert resolve_rule("auto", "shard") == "area"
    assert resolve_rule("auto", "aedat4") == resolve_rule("auto", "text") == "active"
    assert resolve_rule("area", "aedat4") == "area"
    with pytest.raises(ValueError, match="unknown stack rule"):
        resolve_rule("volume", "text")


def test_measure_activity_reads_only_the_first_second():
    hw = (16, 16)
    ev = firing(hw, 16, seconds=0.9)

    def chunks(size):
        yield ev
        later = Events(ev.x, ev.y, ev.t_ns + 2 * 10**9, ev.p, hw)
        yield later  # past the window: read once to see that, then no more
        raise AssertionError("read past the first second")

    rec = Recording(Path("synthetic"), "text", hw, None, chunks)
    act = measure_activity(rec)
    assert act.fraction == 1.0 and act.events == len(ev)


def test_the_shipped_model_gets_its_trained_stacks_on_a_fully_active_128x128_sensor():
    from model.inference.pretrained import shipped_checkpoint
    from model.inference.reconstruct import Reconstructor

    act = activity_of(firing((128, 128), 128))
    model = Reconstructor.load(shipped_checkpoint(2), (128, 128), device="cpu", activity=act)
    assert model.stacks.events_per_stack == 9000 and model.stacks.channels == 3
    half = activity_of(firing((128, 128), 64))
    assert model.with_stacks(activity=half).stacks.events_per_stack == 4500
    assert model.with_stacks(given=3000).stacks.events_per_stack == 3000
