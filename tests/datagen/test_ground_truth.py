"""Ground truth and moving objects in shards: written as the simulator made them, read
back, absent when not asked for, exported (event_utils flow) and previewed (colour wheel,
surface ids)."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
from PIL import Image

from datagen.cli import main
from datagen.config import DatagenConfig
from datagen.export import export
from datagen.generate import generate
from datagen.preview import preview_shards
from datagen.sampling import sample_sequence
from datagen.shard import ShardReader, ShardWriter
from datagen.textures import TextureSampler
from esim_lite.core.dataconf import load_config
from esim_lite.core.figures import BACKGROUND_COLOR, flow_scale, flow_to_rgb, ids_to_rgb
from esim_lite.core.stacking import StackConfig
from esim_lite.sequence import simulate

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "configs" / "datagen_tiny.yaml"
SEED, SEQ = 5, "seq_000000"
# A tiny dynamic scene (exact reference renderer, 32x32 event camera, 1-2 objects).
DYNAMIC = {"simulation.render.backend": "reference", "simulation.objects.count": "[1, 2]",
           "simulation.duration_s": 0.2, "simulation.frames.count": 3,
           "simulation.frames.every_events": 200, "simulation.frames.tail_events": 200,
           "simulation.camera.width": 32, "simulation.camera.height": 32,
           "simulation.frames.ground_truth": "[flow, depth, ids]"}


def config(**overrides) -> DatagenConfig:
    values = DYNAMIC | overrides
    return load_config(DatagenConfig, TINY, [f"{k}={v}" for k, v in values.items()])


def make(folder: Path, cfg: DatagenConfig) -> Path:
    generate(cfg, folder, n_seq=1, seed=SEED, show_progress=False)
    return folder / "shard_00000.h5"


@pytest.fixture(scope="module")
def shard(tmp_path_factory) -> Path:
    return make(tmp_path_factory.mktemp("gt"), config())


@pytest.fixture(scope="module")
def plain_shard(tmp_path_factory) -> Path:
    """The same sequence without ground truth."""
    return make(tmp_path_factory.mktemp("no_gt"), config(**{
        "simulation.frames.ground_truth": "[]"}))


def test_ground_truth_round_trip_equals_the_simulation(shard):
    cfg = config()
    spec = sample_sequence(cfg.simulation, TextureSampler(cfg.textures), SEED, 0)
    assert spec.objects
    samples = [f for chunk in simulate(spec.scene, spec.trajectory, spec.thresholds,
                                       cfg.simulation, spec.noise_rng) for f in chunk.frames]
    with ShardReader(shard) as r:
        assert r.frame_names(SEQ) == ["lr", "hr_x2"]  # ground truth is no camera
        assert r.ground_truth_kinds(SEQ) == ("flow", "depth", "ids")
        np.testing.assert_array_equal(r.frame_times_ns(SEQ), [f.t_ns for f in samples])
        for cam, (h, w) in (("lr", (32, 32)), ("hr_x2", (64, 64))):
            gt = r.ground_truth(SEQ, cam)
            assert gt["flow"].shape == (3, 2, h, w) and gt["flow"].dtype == np.float32
            assert gt["depth"].shape == (3, h, w) and gt["depth"].dtype == np.float32
            assert gt["ids"].shape == (3, h, w) and gt["ids"].dtype == np.uint8
            for k, f in enumerate(samples):  # stored exactly as simulated
                np.testing.assert_array_equal(gt["flow"][k], f.truth[cam].flow)
                np.testing.assert_array_equal(gt["depth"][k], f.truth[cam].depth)
                np.testing.assert_array_equal(gt["ids"][k], f.truth[cam].ids)
            np.testing.assert_array_equal(r.flow(SEQ, cam, 1), gt["flow"][1])
            np.testing.assert_array_equal(r.depth(SEQ, cam), gt["depth"])
            np.testing.assert_array_equal(r.ids(SEQ, cam), gt["ids"])
        ids = r.ids(SEQ, "lr")
        assert set(np.unique(ids)) - {0} and set(np.unique(ids)) <= set(
            range(len(spec.objects) + 1))
        assert np.all(r.depth(SEQ, "lr") > 0)
        rec = r.read(SEQ)
        assert set(rec.ground_truth) == {"lr", "hr_x2"}
        np.testing.assert_array_equal(rec.ground_truth["lr"]["flow"], r.flow(SEQ))


def test_objects_read_back_as_drawn(shard):
    cfg = config()
    spec = sample_sequence(cfg.simulation, TextureSampler(cfg.textures), SEED, 0)
    with ShardReader(shard) as r:
        assert r.num_objects(SEQ) == len(spec.objects)
        assert r.static_camera(SEQ) is spec.static_camera
        stored = r.objects(SEQ)
        assert len(stored) == len(r.object_trajectories(SEQ)) == len(spec.objects)
        for obj, drawn in zip(stored, spec.objects):
            for t in (0.0, 0.07, 0.2):
                got, want = obj.trajectory.pose(t), drawn.pose(t)
                np.testing.assert_array_equal(got.r_wc, want.r_wc)
                np.testing.assert_array_equal(got.t_wc, want.t_wc)
            np.testing.assert_array_equal(obj.alpha, drawn.alpha)  # 0/1 masks: exact
            assert obj.texture == drawn.name and obj.texture_hw == drawn.surface.texture.shape
            assert (obj.width_m, obj.height_m) == (drawn.surface.width_m,
                                                   drawn.surface.height_m)
        s = r.summary(SEQ)
        assert s.num_objects == len(spec.objects) and s.ground_truth == ("flow", "depth", "ids")
        assert all(s.stored_bytes[k] > 0 for k in s.ground_truth)


def test_inspect_names_objects_and_ground_truth(shard, plain_shard, capsys):
    assert main(["inspect", str(shard)]) == 0
    out = capsys.readouterr().out
    assert "object(s), moving camera" in out and "ground truth flow, depth, ids" in out
    assert "flow 0." in out  # its stored MB
    assert main(["inspect", str(plain_shard)]) == 0
    out = capsys.readouterr().out
    assert "object(s)" in out and "ground truth" not in out


def test_no_ground_truth_unless_asked(plain_shard, tmp_path):
    with ShardReader(plain_shard) as r:
        assert r.ground_truth_kinds(SEQ) == () and r.ground_truth(SEQ, "lr") == {}
        assert r.num_objects(SEQ) >= 1  # the objects are still recorded
        with pytest.raises(KeyError, match="no flow ground truth.*frames.ground_truth"):
            r.flow(SEQ)
    with h5py.File(plain_shard, "r") as f:
        assert set(f[SEQ]["frames"]) == {"lr", "hr_x2", "ts", "event_idx", "poses"}
    only_ids = make(tmp_path / "ids", config(**{"simulation.frames.ground_truth": "[ids]"}))
    with ShardReader(only_ids) as r:
        assert r.ground_truth_kinds(SEQ) == ("ids",)
        assert set(r.ground_truth(SEQ, "hr_x2")) == {"ids"}


def test_a_plane_without_ground_truth_writes_the_old_layout(tmp_path):
    """No objects, no ground truth: exactly the groups, datasets and attributes of before."""
    path = make(tmp_path, load_config(DatagenConfig, TINY))
    with h5py.File(path, "r") as f:
        g = f[SEQ]
        assert set(g) == {"events", "frames", "poses", "cameras", "scene", "trajectory"}
        assert set(g["frames"]) == {"lr", "hr_x2", "ts", "event_idx", "poses"}
        assert set(g.attrs) == {
            "sensor_resolution", "index", "seed", "log_eps", "renderer", "texture",
            "frame_dtype", "contrast_threshold_pos", "contrast_threshold_neg", "num_events",
            "num_pos", "num_neg", "t0", "duration"}
    with ShardReader(path) as r:
        assert r.num_objects(SEQ) is None and r.objects(SEQ) == () and not r.static_camera(SEQ)
        assert r.summary(SEQ).ground_truth == ()


def test_writer_needs_the_truth_it_was_asked_for(tmp_path):
    cfg = config()
    sim = cfg.simulation
    spec = sample_sequence(sim, TextureSampler(cfg.textures), SEED, 0)
    cams = sim.camera.rig().cameras()
    writer = ShardWriter(tmp_path / "s.h5", "x: 1")
    try:
        with pytest.raises(ValueError, match="unknown ground truth kind"):
            writer.begin_sequence(spec, cams, 1e-3, "reference", ("normals",))
        writer.begin_sequence(spec, cams, 1e-3, "reference", ("flow",))
        images = {n: np.zeros((c.height, c.width), np.float32) for n, c in cams.items()}
        with pytest.raises(ValueError, match="no ground truth for camera"):
            writer.append_frame(0, np.zeros(8), images)
    finally:
        writer.close()


def test_event_utils_export_carries_the_flow(shard, plain_shard, tmp_path):
    (path,) = export([shard], "event_utils", tmp_path, SEQ)
    with ShardReader(shard) as r, h5py.File(path, "r") as f:
        t = r.frame_times_ns(SEQ) * 1e-9
        ts = f["events/ts"][:]
        assert f.attrs["num_flow"] == len(t) == len(f["flow"]) == f["flow"].attrs["num_images"]
        for k in range(len(t)):
            ds = f[f"flow/flow{k:09d}"]
            assert ds.dtype == np.float32 and ds.shape == (2, 32, 32)
            assert tuple(ds.attrs["size"]) == ds.shape and ds.attrs["timestamp"] == t[k]
            assert ds.attrs["event_idx"] == max(0, np.searchsorted(ts, t[k]) - 1)
            np.testing.assert_array_equal(ds[:], r.flow(SEQ, "lr", k))
            np.testing.assert_array_equal(f[f"flow_hr_x2/flow{k:09d}"][:],
                                          r.flow(SEQ, "hr_x2", k))
    (path,) = export([plain_shard], "event_utils", tmp_path / "plain", SEQ)
    with h5py.File(path, "r") as f:
        assert f.attrs["num_flow"] == 0 and "flow" not in f


def test_preview_adds_flow_and_id_panels(shard, plain_shard, tmp_path):
    (with_gt,) = preview_shards([shard], tmp_path / "gt", StackConfig())
    (without,) = preview_shards([plain_shard], tmp_path / "plain", StackConfig())
    wide, narrow = Image.open(with_gt), Image.open(without)
    assert wide.height == narrow.height and wide.width > narrow.width + 2 * 200


def test_flow_colour_wheel():
    flow = np.zeros((2, 1, 5))
    flow[:, 0, 1] = (4.0, 0.0)  # +x
    flow[:, 0, 2] = (-4.0, 0.0)  # -x
    flow[:, 0, 3] = (0.0, 4.0)  # +y (down)
    flow[:, 0, 4] = (0.0, 2.0)  # half as fast
    rgb = flow_to_rgb(flow, scale=4.0).astype(int)[0]
    assert rgb.shape == (5, 3) and tuple(rgb[0]) == (255, 255, 255)  # zero flow is white
    assert tuple(rgb[1]) == (255, 0, 0) and tuple(rgb[2]) == (0, 255, 255)  # opposite hues
    assert len({tuple(c) for c in rgb[1:4]}) == 3  # each direction its own hue
    saturation = 1 - rgb.min(axis=1) / rgb.max(axis=1)
    np.testing.assert_allclose(saturation[1:4], 1.0)  # same magnitude, same saturation
    assert saturation[4] == pytest.approx(0.5, abs=0.01)
    assert np.array_equal(flow_to_rgb(flow * 10, scale=4.0)[0, 1:4], rgb[1:4])  # clipped
    nan = np.full((2, 2, 2), np.nan, np.float32)
    assert not flow_to_rgb(nan, 1.0).any()  # non-finite: black
    assert flow_scale(np.zeros((2, 3, 3))) == 1.0
    assert flow_scale(flow) == pytest.approx(np.percentile([0, 4, 4, 4, 2], 99))
    with pytest.raises(ValueError, match=r"\[2, H, W\]"):
        flow_to_rgb(np.zeros((3, 2, 2)))


def test_ids_get_distinct_colours():
    ids = np.arange(256, dtype=np.uint8).reshape(16, 16)
    rgb = ids_to_rgb(ids)
    assert rgb.shape == (16, 16, 3) and rgb.dtype == np.uint8
    assert len({tuple(c) for c in rgb.reshape(-1, 3)}) == 256
    assert tuple(rgb[0, 0]) == tuple(BACKGROUND_COLOR)
    assert np.array_equal(ids_to_rgb(np.array([[3]]))[0, 0], rgb.reshape(-1, 3)[3])  # stable
    with pytest.raises(ValueError, match="integers"):
        ids_to_rgb(np.zeros((2, 2), np.float32))
