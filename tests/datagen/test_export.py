"""``datagen export``: each layout checked field by field against its format's published
description, and read back (our readers) to the same events and frames."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from datagen.cli import main
from datagen.config import DatagenConfig
from datagen.export import export, to_uint8
from datagen.generate import generate
from datagen.shard import ShardReader
from esim_lite.core.dataconf import load_config
from esim_lite.core.outputs import MANIFEST

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def shard(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export_src")
    generate(load_config(DatagenConfig, ROOT / "configs" / "datagen_tiny.yaml"), out, n_seq=2,
             seed=3, show_progress=False)
    return out / "shard_00000.h5"


@pytest.fixture(scope="module")
def record(shard):
    with ShardReader(shard) as r:
        return r.read("seq_000000")


def assert_reads_back(rec, record) -> None:
    """``rec`` (an exported file opened by our readers) holds ``record``'s events exactly
    and its LR frames to within 8-bit rounding."""
    back = rec.read_all()
    for field in ("x", "y", "t_ns", "p"):
        np.testing.assert_array_equal(getattr(back, field), getattr(record.events, field))
    lr = record.frames["lr"]
    np.testing.assert_array_equal(rec.frames.t_ns, lr.t_ns)
    assert np.abs(rec.frames.intensity - lr.intensity).max() <= 0.5 / 255 + 1e-6


def test_event_utils_layout_is_the_packagers(shard, record, tmp_path):
    (path,) = export([shard], "event_utils", tmp_path, "seq_000000")
    assert path.name == "shard_00000_seq_000000.h5"
    ev, ts = record.events, record.events.t_ns * 1e-9
    with h5py.File(path, "r") as f:
        assert f["events/xs"].dtype == np.int16 and f["events/ys"].dtype == np.int16
        assert f["events/ts"].dtype == np.float64 and f["events/ps"].dtype == np.bool_
        np.testing.assert_array_equal(f["events/xs"][:], ev.x)
        np.testing.assert_array_equal(f["events/ps"][:], ev.p > 0)
        a = f.attrs
        assert list(a["sensor_resolution"]) == list(ev.sensor_hw)
        assert a["num_events"] == len(ev) and a["num_pos"] + a["num_neg"] == len(ev)
        assert a["t0"] == ts[0] and a["tk"] == ts[-1] and a["duration"] == ts[-1] - ts[0]
        lr = record.frames["lr"]
        assert a["num_imgs"] == len(lr.t_ns) == len(f["images"]) and a["num_flow"] == 0
        for k, t_ns in enumerate(lr.t_ns):
            ds = f[f"images/image{k:09d}"]
            assert ds.dtype == np.uint8 and ds.shape == lr.intensity.shape[1:]
            assert ds.attrs["type"] == "greyscale" and tuple(ds.attrs["size"]) == ds.shape
            assert ds.attrs["timestamp"] == t_ns * 1e-9
            # the packager's rule: max(0, searchsorted(ts, t) - 1)
            assert ds.attrs["event_idx"] == max(0, np.searchsorted(ts, t_ns * 1e-9) - 1)
        assert f["hr_x2/image000000000"].shape == record.frames["hr_x2"].intensity.shape[1:]
        np.testing.assert_array_equal(f["poses"][:], record.frame_poses)
        assert a["contrast_threshold_pos"] == pytest.approx(record.thresholds.pos)


def test_event_utils_export_reads_back_as_the_same_sequence(shard, record, tmp_path):
    from datagen.recording import open_recording

    (path,) = export([shard], "event_utils", tmp_path, "seq_000000")
    assert_reads_back(open_recording(path), record)


def test_evreal_folder_has_its_files_dtypes_and_index_rule(shard, record, tmp_path):
    (folder,) = export([shard], "evreal", tmp_path, "seq_000000")
    ev, lr = record.events, record.frames["lr"]
    load = {n: np.load(folder / f"{n}.npy") for n in ("events_ts", "events_xy", "events_p",
                                                      "images", "images_ts",
                                                      "image_event_indices")}
    assert load["events_ts"].dtype == np.float64 and load["events_ts"].shape == (len(ev),)
    assert load["events_xy"].dtype == np.int16 and load["events_xy"].shape == (len(ev), 2)
    np.testing.assert_array_equal(load["events_xy"][:, 0], ev.x)
    np.testing.assert_array_equal(load["events_xy"][:, 1], ev.y)
    assert set(np.unique(load["events_p"])) <= {0, 1}
    np.testing.assert_array_equal(load["events_p"], (ev.p > 0).astype(np.uint8))
    t, h, w = lr.intensity.shape
    assert load["images"].dtype == np.uint8 and load["images"].shape == (t, h, w, 1)
    np.testing.assert_array_equal(load["images"][..., 0], to_uint8(lr.intensity))
    assert load["images_ts"].shape == (t, 1) and load["image_event_indices"].shape == (t, 1)
    np.testing.assert_array_equal(load["images_ts"][:, 0], lr.t_ns * 1e-9)
    assert load["image_event_indices"].dtype == np.int64
    meta = json.loads((folder / "metadata.json").read_text())
    assert meta["sensor_resolution"] == [h, w]
    assert np.load(folder / "images_hr_x2.npy").shape == (t, 2 * h, 2 * w, 1)


def test_evreal_event_indices_pass_evreals_loader_and_match_its_converters(shard, record,
                                                                          tmp_path):
    """EVREAL's MemMapDataset (dataset.py, 'between_frames') cuts the events at
    image_event_indices and refuses any index outside [0, N - 1] ("Event indices -1,2999 out
    of bounds"); its converters (tools/bag_to_npy.py) write, for each frame, the last event
    at or before the frame, clipped: clip(searchsorted(ts, t, 'right') - 1, 0, N - 1)."""
    (folder,) = export([shard], "evreal", tmp_path, "seq_000000")
    ts = np.load(folder / "events_ts.npy")
    img_ts = np.load(folder / "images_ts.npy")[:, 0]
    idx = np.load(folder / "image_event_indices.npy")[:, 0]
    n = len(ts)
    assert img_ts[0] < ts[0], "the fixture must have a frame before the first event"
    assert idx.min() >= 0 and idx.max() <= n - 1
    assert np.all(np.diff(idx) >= 0)
    for k, t in enumerate(img_ts):
        at_or_before = np.flatnonzero(ts <= t)
        assert idx[k] == (at_or_before[-1] if len(at_or_before) else 0), k
    # the loader's own check, on the [start, end) pairs it builds from the indices
    start = 0
    for end in idx:
        assert start >= 0 and end <= n, (start, end)
        start = end


def test_ecd_text_folder_reads_back_and_has_calib_and_groundtruth(shard, record, tmp_path):
    from datagen.recording import open_recording

    (folder,) = export([shard], "txt", tmp_path, "seq_000000")
    assert_reads_back(open_recording(folder), record)
    lr = record.frames["lr"]
    calib = [float(v) for v in (folder / "calib.txt").read_text().split()]
    c = record.cameras["lr"]
    assert calib == [c.fx, c.fy, c.cx, c.cy, 0, 0, 0, 0, 0]
    gt = np.loadtxt(folder / "groundtruth.txt")
    assert gt.shape == (len(lr.t_ns), 8)
    np.testing.assert_allclose(gt, record.frame_poses, rtol=0, atol=1e-9)
    assert len((folder / "images_hr_x2.txt").read_text().splitlines()) == len(lr.t_ns)


def test_export_cli_writes_every_sequence_and_names_a_missing_one(shard, tmp_path, capsys):
    assert main(["export", str(shard), "--format", "evreal", "--out", str(tmp_path)]) == 0
    written = sorted(p.name for p in tmp_path.iterdir() if p.name != MANIFEST)
    assert written == ["shard_00000_seq_000000", "shard_00000_seq_000001"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [MANIFEST, *written]
    assert main(["export", str(shard), "--format", "txt", "--out", str(tmp_path / "t"),
                 "--sequence", "seq_9"]) == 2
    assert "no sequence 'seq_9'" in capsys.readouterr().err
    assert not (tmp_path / "t").exists() or not any((tmp_path / "t").iterdir())


def test_evreal_folders_open_as_recordings(shard, record, tmp_path):
    from datagen.recording import open_recording

    (folder,) = export([shard], "evreal", tmp_path, "seq_000000")
    rec = open_recording(folder)
    assert rec.kind == "evreal" and rec.sensor_hw == record.events.sensor_hw
    assert_reads_back(rec, record)


def test_a_broken_evreal_folder_is_named_with_its_problem(shard, tmp_path):
    from datagen.recording import open_recording

    (folder,) = export([shard], "evreal", tmp_path, "seq_000000")
    np.save(folder / "events_p.npy", np.load(folder / "events_p.npy")[:-5])
    with pytest.raises(ValueError, match="do not describe the same") as err:
        open_recording(folder)
    assert str(folder) in str(err.value)
