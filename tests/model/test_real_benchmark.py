"""The real-data benchmark (bench/bench_real.py over model/inference/real_benchmark.py) on a
tiny folder laid out like ../shared/real_events, made here."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest

from esim_lite.core.events import Events
from model.inference.real_benchmark import find_recordings
from tests.datagen.test_exposure_windows import write_aedat4_exposed
from tests.datagen.test_recording import events, write_text
from tests.model.conftest import bench_module
from tests.model.test_scene_motion import (
    moving_texture,
    static_scene_with_a_small_object,
    with_noise_and_hot_pixels,
)


def bench_real():
    return bench_module("bench_real")


def shifted(ev: Events, seconds: float) -> Events:
    return Events(ev.x, ev.y, ev.t_ns + int(seconds * 1e9), ev.p, ev.sensor_hw)


def write_text_with_exposures(folder, ev, frame_s, half_window_s):
    """An EDI/eSL-style folder: events.txt, images/ + images.txt and exposures.txt (windows
    of +-``half_window_s`` around each frame)."""
    write_text(folder, ev, with_frames=False)
    (folder / "images").mkdir()
    rng = np.random.default_rng(3)
    index, windows = [], ["# index source_frame start end"]
    for k, t in enumerate(frame_s):
        img = (rng.random(ev.sensor_hw) * 255).astype(np.uint8)
        cv2.imwrite(str(folder / "images" / f"frame_{k:08d}.png"), img)
        index.append(f"{t:.9f} images/frame_{k:08d}.png")
        windows.append(f"{k} {100 + k:04d} {t - half_window_s:.9f} {t + half_window_s:.9f}")
    (folder / "images.txt").write_text("\n".join(index) + "\n")
    (folder / "exposures.txt").write_text("\n".join(windows) + "\n")


@pytest.fixture()
def real_folder(tmp_path):
    """davis346/tiny.aedat4 (60x80, a static scene with a small moving square, noise and hot
    pixels; 3 APS frames with 20 ms exposures), edi/shake/ (60x80, a texture moving across
    the frame; 3 frames with 100 ms windows in exposures.txt) and one 240x180 ECD-style
    snippet of 250 events."""
    folder = tmp_path / "real_events"
    (folder / "davis346").mkdir(parents=True)
    rng = np.random.default_rng(0)
    static = shifted(with_noise_and_hot_pixels(static_scene_with_a_small_object(rng), rng), 1)
    write_aedat4_exposed(folder / "davis346" / "tiny.aedat4", static,
                         [1_290_000, 1_590_000, 1_890_000], [20_000] * 3)
    (folder / "edi").mkdir()
    write_text_with_exposures(folder / "edi" / "shake", shifted(moving_texture(rng), 1),
                              [1.3, 1.6, 1.9], 0.05)
    (folder / "ecd_snippets").mkdir()
    write_text(folder / "ecd_snippets" / "snip", events(n=250, hw=(180, 240), seed=4),
               with_frames=False)
    return folder


def test_the_benchmark_finds_recordings_at_any_depth(real_folder):
    found = find_recordings(real_folder)
    assert [p.relative_to(real_folder).as_posix() for p in found.scored] == [
        "davis346/tiny.aedat4", "edi/shake"]
    assert [p.relative_to(real_folder).as_posix() for p in found.shown] == [
        "ecd_snippets/snip/events.txt"]


def test_the_benchmark_scores_each_recording_by_its_verdict(real_folder, tiny_checkpoint,
                                                             tmp_path, capsys):
    out = tmp_path / "bench"
    assert bench_real().main(["--folder", str(real_folder), "--out", str(out),
                              "--checkpoint", str(tiny_checkpoint), "--engine", "torch"]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("# .venv/bin/python bench/bench_real.py --folder")
    table = (out / "real_benchmark.md").read_text()
    assert "exposure averaging: on" in table
    recordings = {line.split(" | ")[0][2:]: line.split(" | ") for line in table.splitlines()
                  if line.startswith("| ") and "(active:" in line}
    assert set(recordings) == {"davis346/tiny", "edi/shake", "ecd/snip"}
    assert recordings["davis346/tiny"][2] == "static camera: observed region"
    assert recordings["edi/shake"][2] == "moving: whole frame"
    assert recordings["ecd/snip"][1:3] == ["-", "figure only"]
    shares = {n: float(r[1].rstrip("%")) for n, r in recordings.items() if r[1] != "-"}
    assert shares["davis346/tiny"] < 50 <= shares["edi/shake"]
    # the exposures.txt windows (100 ms) are read and our outputs averaged over them
    assert "APS: 3 frames every 400.0 ms, exposure 20.000 ms" not in table
    assert "3 frames every 300.0 ms, exposure 100.000 ms" in recordings["edi/shake"][4]
    averaged = recordings["edi/shake"][5].split("-")
    assert int(averaged[0]) >= 2
    assert "### Moving: whole frame" in table and "### Static camera: observed region" in table

    rows = list(csv.DictReader((out / "real_benchmark.csv").open()))
    methods = ("ours", "hf", "direct", "complementary", "ours+tc", "flat", "salt")
    by = {(r["sequence"], r["normalize"], r["method"]): r for r in rows}
    # moving: whole frames, with LPIPS, and nothing under observed
    for norm in ("evreal", "affine"):
        for method in methods:
            row = by["edi/shake", norm, method]
            assert row["verdict"] == "moving: whole frame" and row["frames"] == "2"
            assert np.isfinite(float(row["lpips"])) and np.isfinite(float(row["psnr"]))
    assert not any(r["normalize"] == "observed" for r in rows if r["sequence"] == "edi/shake")
    # static: whole-frame PSNR and SSIM for reference, no whole-frame LPIPS; the observed
    # region's rows with LPIPS and invented
    static = [r for r in rows if r["sequence"] == "davis346/tiny"]
    assert {r["verdict"] for r in static} == {"static camera: observed region"}
    assert {r["normalize"] for r in static} == {"evreal", "affine", "observed"}
    for r in static:
        if r["normalize"] == "observed":
            assert 0 < float(r["coverage"]) < 1 and r["ewarp"] == "" and r["lpips"] != ""
        else:
            assert r["lpips"] == "" and np.isfinite(float(r["ssim"])) and r["coverage"] == ""
    for method in methods:
        assert by["davis346/tiny", "observed", method]["frames"] == "2"
    assert float(by["davis346/tiny", "observed", "flat"]["invented"]) == 0.0
    for ceiling in ("seen+flat", "seen+harmonic", "seen+salt"):
        rows_of = [r for r in static if r["method"] == ceiling]
        assert {r["normalize"] for r in rows_of} == {"evreal", "affine"}  # whole frames only
    # the flat floor is what the affine fit makes of a featureless image: the same scores
    for key in ("psnr", "ssim"):
        assert float(by["edi/shake", "affine", "flat"][key]) == pytest.approx(
            float(by["edi/shake", "evreal", "flat"][key]), abs=1e-4)
    # the ceiling is the target where events fired and the best grey elsewhere: never
    # further from the target than the flat floor
    for norm in ("evreal", "affine"):
        assert float(by["davis346/tiny", norm, "seen+flat"]["mse"]) < float(
            by["davis346/tiny", norm, "flat"]["mse"])
    figure = cv2.imread(str(out / "real_benchmark.png"))
    assert figure is not None and figure.shape[0] > 300  # three rows


def test_the_benchmark_skips_cleanly_without_the_folder(tmp_path, capsys):
    missing = tmp_path / "nowhere"
    assert bench_real().main(["--folder", str(missing), "--out", str(tmp_path / "o")]) == 0
    assert f"skipped: {missing} is not there" in capsys.readouterr().out
    assert not (tmp_path / "o").exists()
    with pytest.raises(FileNotFoundError, match="no such folder of real recordings"):
        find_recordings(missing)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no \\*.aedat4 file and no events.txt"):
        find_recordings(tmp_path / "empty")


def test_model_only_scores_the_model_alone(real_folder, tiny_checkpoint, tmp_path):
    out = tmp_path / "bench"
    assert bench_real().main(["--folder", str(real_folder), "--out", str(out), "--model-only",
                              "--checkpoint", str(tiny_checkpoint), "--engine", "torch"]) == 0
    rows = list(csv.DictReader((out / "real_benchmark.csv").open()))
    assert {(r["normalize"], r["method"]) for r in rows} == {
        ("evreal", "ours"), ("affine", "ours"), ("observed", "ours")}
    assert cv2.imread(str(out / "real_benchmark.png")) is not None
