"""APS exposure windows: AEDAT4 and the text layout's ``exposures.txt`` carry each frame's
exposure into ``Recording``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from datagen.formats.base import Recording, sorted_exposures
from datagen.recording import open_recording
from tests.conftest import REAL_EVENTS
from tests.datagen.test_recording import aedat4_writer, events, write_text
from tests.datagen.test_recording import frames as random_frames

DAVIS = REAL_EVENTS / "davis346"
TEXT_WITH_EXPOSURES = (REAL_EVENTS / "davis240c_edi" / "camerashake",
                       REAL_EVENTS / "davis346_esl" / "checkerboard")


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


def write_exposures(folder, lines):
    (folder / "exposures.txt").write_text(
        "# index source_frame start end\n" + "\n".join(lines) + "\n")


def test_text_exposures_come_back_per_frame_in_the_frames_order(tmp_path):
    """Windows given out of order (and around frames stamped 1.5, 1.9, 2.3 s) come back in
    exact nanoseconds, one per frame, in the frames' order."""
    folder = tmp_path / "rec"
    write_text(folder, events())
    stamps = random_frames()[1]
    assert stamps == [1_500_000_000, 1_900_000_000, 2_300_000_000]
    write_exposures(folder, ["2 0042 2.250000001 2.350000000", "0 0040 1.450000000 1.550000000",
                             "1 0041 1.899999999 1.900000000"])
    rec = open_recording(folder)
    assert rec.exposures_ns.dtype == np.int64
    np.testing.assert_array_equal(rec.exposures_ns, [[1_450_000_000, 1_550_000_000],
                                                     [1_899_999_999, 1_900_000_000],
                                                     [2_250_000_001, 2_350_000_000]])
    (folder / "exposures.txt").unlink()
    assert open_recording(folder).exposures_ns is None


@pytest.mark.parametrize("lines,problem", [
    (["0 1 1.4 1.6", "1 2 1.8 2.0"], r"no window for frame\(s\) \[2\]"),
    (["0 1 1.4 1.6", "0 1 1.4 1.6", "2 3 2.2 2.4"], "line 3: frame index 0 given twice"),
    (["0 1 1.4 1.6", "1 2 1.8 2.0", "3 4 2.2 2.4"], "frame index 3 outside images.txt's 3"),
    (["0 1 1.4 1.6", "1 2 1.95 2.0", "2 3 2.2 2.4"], "line 3: frame 1's window 1.95..2.0 s"),
    (["0 1 1.4", "1 2 1.8 2.0", "2 3 2.2 2.4"], "line 2 is not 'index source_frame start"),
    (["0 1 1.4 x", "1 2 1.8 2.0", "2 3 2.2 2.4"], "timestamp 'x' is not a number"),
])
def test_bad_exposure_files_are_named_with_their_problem(tmp_path, lines, problem):
    folder = tmp_path / "rec"
    write_text(folder, events())
    write_exposures(folder, lines)
    with pytest.raises(ValueError, match=problem) as err:
        open_recording(folder)
    assert "exposures.txt" in str(err.value)


@pytest.mark.skipif(not all(p.is_dir() for p in TEXT_WITH_EXPOSURES),
                    reason="real recordings not present")
def test_the_real_text_recordings_store_a_window_around_each_frame():
    for folder, n in zip(TEXT_WITH_EXPOSURES, (30, 7)):
        rec = open_recording(folder)
        win = rec.exposures_ns
        assert len(win) == len(rec.frames) == n and rec.frames.hw == rec.sensor_hw
        # images.txt stamps each frame at the middle of its window (to the microsecond)
        assert np.abs(rec.frames.t_ns - (win[:, 0] + win[:, 1]) / 2).max() <= 1000
