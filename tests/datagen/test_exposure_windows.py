"""APS exposure windows: AEDAT4 carries each frame's exposure into ``Recording``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from datagen.formats.base import Recording, sorted_exposures
from datagen.recording import open_recording
from tests.conftest import REAL_EVENTS
from tests.datagen.test_recording import aedat4_writer, events

DAVIS = REAL_EVENTS / "davis346"


def write_aedat4_exposed(path, ev, frame_us, exposure_us):
    """AEDAT4 with frames at ``frame_us`` (their exposure start, as dv-processing stores a
    frame's timestamp) lasting ``exposure_us`` each."""
    import dv_processing as dv

    writer = aedat4_writer(path, ev)
    rng = np.random.default_rng(2)
    for t, e in zip(frame_us, exposure_us):
        img = (rng.random(ev.sensor_hw) * 255).astype(np.uint8)
        writer.writeFrame(dv.Frame(int(t), int(e), 0, 0, img, dv.FrameSource.SENSOR))
    del writer


def test_aedat4_exposures_come_back_per_frame(tmp_path):
    path = tmp_path / "e.aedat4"
    starts, lengths = [1_500_000, 1_900_000, 2_300_000], [500, 4_773, 20_000]
    write_aedat4_exposed(path, events(), starts, lengths)
    rec = open_recording(path)
    assert rec.exposures_ns.dtype == np.int64 and rec.exposures_ns.shape == (3, 2)
    np.testing.assert_array_equal(rec.exposures_ns[:, 0], np.array(starts) * 1000)
    np.testing.assert_array_equal(rec.exposures_ns[:, 1] - rec.exposures_ns[:, 0],
                                  np.array(lengths) * 1000)
    np.testing.assert_array_equal(rec.frames.t_ns, np.array(starts) * 1000)


def test_exposures_follow_the_frames_order_and_are_checked():
    windows = sorted_exposures([30, 10, 20], [29, 9, 19], [31, 11, 21], Path("f"))
    np.testing.assert_array_equal(windows, [[9, 11], [19, 21], [29, 31]])
    with pytest.raises(ValueError, match="f: APS frame 1 has an exposure ending before"):
        sorted_exposures([1, 2], [0, 5], [2, 3], Path("f"))
    with pytest.raises(ValueError, match="one per frame"):
        Recording(Path("g"), "aedat4", (2, 2), None, lambda n: iter(()),
                  np.zeros((1, 2), np.int64))


@pytest.mark.skipif(not DAVIS.is_dir(), reason="real recordings not present")
def test_the_real_davis346_files_store_short_centred_exposures():
    for name, frames, exposure_ns in (("street", 59, 500_000), ("robot_arm", 3, 4_773_000)):
        rec = open_recording(DAVIS / f"{name}.aedat4")
        win = rec.exposures_ns
        assert len(win) == len(rec.frames) == frames
        np.testing.assert_array_equal(win[:, 1] - win[:, 0], exposure_ns)
        # the frame's timestamp is the middle of its exposure (to the microsecond)
        assert np.abs(rec.frames.t_ns - (win[:, 0] + win[:, 1]) / 2).max() <= 1000
