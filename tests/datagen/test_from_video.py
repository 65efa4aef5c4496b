"""datagen from-video: the optics rule, closed forms (a static video, a log-brightness ramp,
a scene cut), bad inputs, determinism, resumption, and shards the trainer loads."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from datagen.cli import main
from datagen.shard import ShardReader, find_shards
from datagen.video.config import FromVideoConfig
from datagen.video.from_video import from_video
from datagen.video.optics import (
    block_mean,
    camera_images,
    crop_box,
    linear_luminance,
    srgb_to_linear,
)
from datagen.video.source import read_frames, scan_frames
from esim_lite.core.dataconf import load_config
from tests.datagen.video_oracle import texture, write_png_video

C = 0.25
SENSOR = (24, 32)  # (H, W)


def config(*sets: str, interpolator: str = "linear", frames: int = 6) -> FromVideoConfig:
    return load_config(FromVideoConfig, None, [
        f"simulation.camera.width={SENSOR[1]}", f"simulation.camera.height={SENSOR[0]}",
        "simulation.camera.scales=[2]", f"simulation.events.thresholds.pos_range=[{C},{C}]",
        f"simulation.events.thresholds.neg_range=[{C},{C}]",
        f"video.frames_per_sequence={frames}", f"video.interpolator={interpolator}", *sets])


def hr_texture(seed: int, hw=(SENSOR[0] * 2, SENSOR[1] * 2)) -> np.ndarray:
    return texture(seed, hw, 1.5)


def read_sequences(folder: Path) -> dict[str, dict[str, np.ndarray]]:
    out = {}
    for path in find_shards(folder):
        with ShardReader(path) as r:
            for name in r.sequences():
                rec = r.read(name)
                out[name] = {"x": rec.events.x, "y": rec.events.y, "t": rec.events.t_ns,
                             "p": rec.events.p, "event_idx": rec.frame_event_idx,
                             "poses": rec.sample_poses,
                             **{f"frame_{k}": v.intensity for k, v in rec.frames.items()},
                             "source": np.array(str(r.video_source(name)))}
    return out


# ------------------------------------------------------------------------------ optics


def test_the_crop_is_the_largest_centred_window_of_the_sensor_aspect():
    assert crop_box((1080, 1920), (128, 128)) == (0, 420, 1080, 1080)
    assert crop_box((1080, 1920), (260, 346)) == (0, 241, 1080, 1437)  # w 1080*346/260
    assert crop_box((1000, 500), (100, 200)) == (375, 0, 250, 500)


def test_colour_is_luminance_of_linearised_srgb():
    assert srgb_to_linear(np.array([0.0, 0.04045, 0.5, 1.0])) == pytest.approx(
        [0.0, 0.04045 / 12.92, 0.21404, 1.0], abs=1e-5)
    bgr = np.zeros((1, 3, 3), np.uint8)
    bgr[0, 0, 2] = bgr[0, 1, 1] = bgr[0, 2, 0] = 255  # pure red, green, blue
    assert linear_luminance(bgr, "srgb")[0] == pytest.approx([0.2126, 0.7152, 0.0722], 1e-6)
    assert linear_luminance(np.array([[0, 32768, 65535]], np.uint16), "linear")[0] == \
        pytest.approx([0.0, 0.5, 1.0], abs=1e-4)


def test_lr_and_every_hr_are_block_means_of_the_finest():
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (100, 140, 3), np.uint8)  # cropped to 100x133, resized
    cams = camera_images(frame, (12, 16), (2, 4), 2, "srgb")
    assert cams.images["hr_x4"].shape == (48, 64) and cams.images["hr_x2"].shape == (24, 32)
    np.testing.assert_allclose(cams.images["hr_x2"], block_mean(cams.images["hr_x4"], 2),
                               rtol=1e-6)
    np.testing.assert_allclose(cams.images["lr"], block_mean(cams.images["hr_x4"], 4),
                               rtol=1e-5)
    np.testing.assert_allclose(cams.work, cams.images["hr_x2"], rtol=1e-6)


# ------------------------------------------------------------------------ closed forms


@pytest.mark.parametrize("interpolator", ["linear", "flow"])
def test_a_static_video_gives_no_events_and_its_frames(tmp_path, interpolator):
    hr = hr_texture(1)
    t_ns = np.arange(6) * 40_000_000
    folder = write_png_video(np.repeat(hr[None], 6, 0), t_ns, tmp_path / "still")
    out = tmp_path / "out"
    from_video([folder], out, config(interpolator=interpolator), show_progress=False)
    (seq,) = read_sequences(out).values()
    assert len(seq["t"]) == 0
    np.testing.assert_array_equal(seq["event_idx"], 0)
    np.testing.assert_allclose(seq["frame_hr_x2"][0], hr, atol=2e-3, rtol=2e-3)  # float16
    np.testing.assert_allclose(seq["frame_lr"][0], block_mean(hr, 2), atol=2e-3, rtol=2e-3)


@pytest.mark.parametrize("interpolator", ["linear", "flow"])
def test_a_log_brightness_ramp_gives_floor_dl_over_c_events_at_the_video_times(
        tmp_path, interpolator):
    # variable frame rate: the frames' own times, not a rate, must be used
    t_ns = np.array([0, 30, 45, 90, 100, 160]) * 1_000_000
    base = 0.05 + 0.3 * np.linspace(0, 1, SENSOR[1] * 2)[None, :] * np.ones((SENSOR[0] * 2, 1))
    gains = np.exp(np.array([0.0, 0.21, 0.35, 0.52, 0.66, 0.87]))  # 3.48 C in all
    folder = write_png_video(base[None] * gains[:, None, None], t_ns, tmp_path / "ramp")
    out = tmp_path / "out"
    from_video([folder], out, config(interpolator=interpolator), show_progress=False)
    (seq,) = read_sequences(out).values()
    with ShardReader(find_shards(out)[0]) as r:
        np.testing.assert_array_equal(r.frame_times_ns("seq_000000"), t_ns)
    # the oracle: the LR frames as the rule makes them from the decoded files
    src = scan_frames(folder, None)
    lr = [camera_images(f, SENSOR, (2,), 2, "srgb").images["lr"]
          for f in read_frames(src, 0, src.n_frames)]
    dl = np.log(1e-3 + lr[-1].astype(np.float64)) - np.log(1e-3 + lr[0].astype(np.float64))
    expected = np.floor(dl / C).astype(int)
    assert expected.min() == expected.max() == 3  # every pixel 3, none near a boundary
    counts = np.zeros(SENSOR, int)
    np.add.at(counts, (seq["y"], seq["x"]), 1)
    np.testing.assert_array_equal(counts, expected)
    assert (seq["p"] == 1).all()
    if interpolator == "linear":  # log-linear between frames: the k-th event where L0 + k C
        logs = np.log(1e-3 + np.stack(lr).astype(np.float64))  # is crossed
        y, x = 5, 7
        path = logs[:, y, x]
        want = np.interp(path[0] + C * np.arange(1, 4), path, t_ns)
        got = seq["t"][(seq["y"] == y) & (seq["x"] == x)]
        np.testing.assert_allclose(got, want, atol=1_000)  # ns


@pytest.mark.parametrize("interpolator", ["linear", "flow"])
def test_a_scene_cut_restarts_the_sensor_instead_of_bursting(tmp_path, interpolator):
    a, b = hr_texture(2), 1.0 - 0.9 * hr_texture(3)
    frames = np.stack([a] * 3 + [b] * 3)
    folder = write_png_video(frames, np.arange(6) * 33_000_000, tmp_path / "cut")
    out = tmp_path / "out"
    from_video([folder], out, config(interpolator=interpolator), show_progress=False)
    (seq,) = read_sequences(out).values()
    assert len(seq["t"]) == 0
    with ShardReader(find_shards(out)[0]) as r:
        assert r.video_source("seq_000000")["scene_cuts"] == 1
    burst = tmp_path / "burst"
    from_video([folder], burst, config("video.scene_cut_fraction=null",
                                       interpolator=interpolator), show_progress=False)
    (seq,) = read_sequences(burst).values()
    assert len(seq["t"]) > SENSOR[0] * SENSOR[1] // 2  # without the rule: the jump fires
    assert ((seq["t"] > 66_000_000) & (seq["t"] <= 99_000_000)).all()


# --------------------------------------------------------------------------- bad inputs


def moving_video(path: Path, n: int, hw=(SENSOR[0] * 2, SENSOR[1] * 2), fps: float = 25.0,
                 seed: int = 4) -> Path:
    """An FFV1 video of a texture sliding 1.5 px a frame."""
    tex = texture(seed, (hw[0], hw[1] + 4 * n), 1.5)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), fps, hw[::-1])
    assert writer.isOpened()
    for k in range(n):
        x = int(round(1.5 * k))
        img = (np.clip(tex[:, x:x + hw[1]], 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)
        writer.write(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    writer.release()
    return path


def _bad_folder(tmp_path: Path, problem: str) -> Path:
    hr = hr_texture(5)
    folder = write_png_video(np.repeat(hr[None], 7, 0), np.arange(7) * 10_000_000,
                             tmp_path / problem)
    if problem == "sizes":
        cv2.imwrite(str(folder / "00003.png"), np.zeros((10, 12), np.uint16))
    elif problem == "backwards":
        (folder / "timestamps.txt").write_text("0\n0.01\n0.02\n0.015\n0.04\n0.05\n0.06\n")
    elif problem == "count":
        (folder / "timestamps.txt").write_text("0\n0.01\n")
    elif problem == "no-times":
        (folder / "timestamps.txt").unlink()
    return folder


BAD = {
    "unreadable": (lambda p: _write(p / "clip.mp4", b"not a video at all" * 100),
                   "cannot read this file as a video"),
    "empty": (lambda p: _write(p / "empty.mkv", b""), "cannot read"),
    "short": (lambda p: moving_video(p / "short.mkv", 3), "fewer than one sequence"),
    "small": (lambda p: moving_video(p / "small.mkv", 8, hw=(30, 40)), "never upscaled"),
    "sizes": (lambda p: _bad_folder(p, "sizes"), "frames must have one size"),
    "backwards": (lambda p: _bad_folder(p, "backwards"), "go backwards"),
    "count": (lambda p: _bad_folder(p, "count"), "2 times for 7 frames"),
    "no-times": (lambda p: _bad_folder(p, "no-times"), "no timestamps.txt"),
    "image": (lambda p: Path(cv2.imwrite(str(p / "one.png"), np.zeros((48, 64), np.uint8))
                             and p / "one.png"), "one image is not a video"),
    "missing": (lambda p: p / "nowhere.mp4", "no such video file"),
}


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("problem", sorted(BAD))
def test_bad_inputs_are_refused_by_name_with_nothing_written(tmp_path, capsys, problem):
    make, words = BAD[problem]
    given = make(tmp_path)
    out = tmp_path / "out"
    rc = main(["from-video", str(given), "--out", str(out), "--sensor-size",
               f"{SENSOR[1]}x{SENSOR[0]}", "--scale", "2", "--set",
               "video.frames_per_sequence=6", "--workers", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2
    assert words in err and given.name in err and "Traceback" not in err
    assert not out.exists()


# ------------------------------------------------- determinism, resumption, one dataset


def test_same_inputs_and_seed_give_the_same_shards_with_any_workers_and_resume(tmp_path):
    videos = tmp_path / "videos"
    videos.mkdir()
    moving_video(videos / "a.mkv", 12, seed=6)
    moving_video(videos / "b.avi", 7, seed=7)  # a folder of videos: sorted, one dataset
    cfg = config("sequences_per_shard=1", interpolator="flow")
    one, two = tmp_path / "one", tmp_path / "two"
    s1 = from_video([videos], one, cfg, seed=3, workers=1, show_progress=False)
    from_video([videos], two, cfg, seed=3, workers=2, show_progress=False)
    assert (s1.shards_written, s1.sequences) == (3, 3)  # 12 frames: 2 sequences, 7: 1
    a, b = read_sequences(one), read_sequences(two)
    assert a.keys() == b.keys() == {"seq_000000", "seq_000001", "seq_000002"}
    for name in a:
        for key in a[name]:
            np.testing.assert_array_equal(a[name][key], b[name][key], err_msg=f"{name}/{key}")
    assert sum(len(s["t"]) for s in a.values()) > 1000
    with ShardReader(one / "shard_00002.h5") as r:
        src = r.video_source("seq_000002")
        assert (Path(src["source_path"]).name, src["source_frame_start"],
                src["source_frame_stop"], src["interpolator"]) == ("b.avi", 0, 6, "flow")
    (one / "shard_00001.h5").unlink()
    again = from_video([videos], one, cfg, seed=3, show_progress=False)
    assert (again.shards_written, again.shards_skipped) == (1, 2)
    c = read_sequences(one)
    for key in a["seq_000001"]:
        np.testing.assert_array_equal(a["seq_000001"][key], c["seq_000001"][key])
    other = tmp_path / "other"  # other content under the same names: another dataset
    other.mkdir()
    moving_video(other / "a.mkv", 12, seed=8)
    moving_video(other / "b.avi", 7, seed=7)
    with pytest.raises(ValueError, match="different config or seed"):
        from_video([other], one, cfg, seed=3, show_progress=False)


def test_the_shards_load_as_training_samples(tmp_path):
    from model.config import TrainConfig
    from model.data.dataset import ShardSamples, index_samples

    root = Path(__file__).resolve().parents[2]
    train = load_config(TrainConfig, root / "configs" / "train_tiny.yaml")
    video = moving_video(tmp_path / "clip.mkv", 24, hw=(96, 128))
    out = tmp_path / "shards"
    rc = main(["from-video", str(video), "--out", str(out), "--sensor-size", "64x48",
               "--scale", "2", "--set", "video.frames_per_sequence=12", "--workers", "1",
               "--no-progress"])
    assert rc == 0
    refs, val = index_samples(find_shards(out), train.data, train.model.n_stacks, 2)
    assert len(refs) + len(val) > 0
    sample = ShardSamples(refs or val, train.data, train.model.n_stacks, 2, True)[0]
    crop = train.data.crop
    assert tuple(sample["lr"].shape) == (1, crop, crop)
    assert tuple(sample["hr"].shape) == (1, 2 * crop, 2 * crop)
    assert sample["stacks"].abs().sum() > 0


def test_the_config_files_load_and_the_default_one_is_the_builtin_defaults():
    root = Path(__file__).resolve().parents[2] / "configs"
    assert load_config(FromVideoConfig, root / "from_video.yaml") == FromVideoConfig()
    real = load_config(FromVideoConfig, [root / "from_video.yaml",
                                         root / "from_video_realistic.yaml"])
    assert real.sensor_ranges.enabled and real.simulation.events.random_start
    preset = load_config(FromVideoConfig, [root / "from_video.yaml",
                                           root / "sensors" / "davis346.yaml"])
    assert preset.simulation.events.refractory_ns == 282000  # a sensor preset layers on


def test_a_realistic_sensor_runs_and_records_its_draw(tmp_path):
    root = Path(__file__).resolve().parents[2] / "configs"
    video = moving_video(tmp_path / "clip.mkv", 6)
    cfg = load_config(FromVideoConfig, [root / "from_video_realistic.yaml"], [
        f"simulation.camera.width={SENSOR[1]}", f"simulation.camera.height={SENSOR[0]}",
        "video.frames_per_sequence=6", "sensor_ranges.flicker_share=1.0"])
    from_video([video], tmp_path / "out", cfg, seed=5, show_progress=False)
    with ShardReader(find_shards(tmp_path / "out")[0]) as r:
        sensor = r.sensor("seq_000000")
        assert sensor is not None and sensor["flicker_hz"] in (100.0, 120.0)
        assert r.num_events("seq_000000") > 0
