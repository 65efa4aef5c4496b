"""The real-data benchmark (bench/bench_real.py over model/inference/real_benchmark.py) on a
tiny folder laid out like ../shared/real_events, made here."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest

from model.inference.real_benchmark import find_recordings
from tests.datagen.test_exposure_windows import write_aedat4_exposed
from tests.datagen.test_recording import events, write_text
from tests.model.conftest import bench_module


def bench_real():
    return bench_module("bench_real")


@pytest.fixture()
def real_folder(tmp_path):
    """davis346/tiny.aedat4 (48x64, 3 APS frames with 20 ms exposures) and one 240x180
    ECD-style snippet of 250 events."""
    folder = tmp_path / "real_events"
    (folder / "davis346").mkdir(parents=True)
    write_aedat4_exposed(folder / "davis346" / "tiny.aedat4", events(n=8000, hw=(48, 64)),
                         [1_490_000, 1_890_000, 2_290_000], [20_000] * 3)
    (folder / "ecd_snippets").mkdir()
    write_text(folder / "ecd_snippets" / "snip", events(n=250, hw=(180, 240), seed=4),
               with_frames=False)
    return folder


def test_the_benchmark_writes_one_table_and_one_figure(real_folder, tiny_checkpoint, tmp_path,
                                                       capsys):
    found = find_recordings(real_folder)
    assert [p.name for p in found.scored] == ["tiny.aedat4"] and len(found.shown) == 1
    out = tmp_path / "bench"
    assert bench_real().main(["--folder", str(real_folder), "--out", str(out),
                              "--checkpoint", str(tiny_checkpoint), "--engine", "torch"]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("# .venv/bin/python bench/bench_real.py --folder")
    table = (out / "real_benchmark.md").read_text()
    assert "exposure averaging of ours: on" in table
    assert "davis346/tiny (scored): events per stack" in table and "(active:" in table
    assert "APS: 3 frames every 400.0 ms, exposure 20.000 ms" in table
    assert "ecd/snip (figure only)" in table
    methods = ("ours", "hf", "direct", "complementary", "ours+tc", "flat", "salt")
    for norm in ("evreal", "affine", "observed"):
        for method in methods:
            assert f"| davis346/tiny | {norm} | {method} | 2 |" in table
    rows = list(csv.DictReader((out / "real_benchmark.csv").open()))
    assert {r["normalize"] for r in rows} == {"evreal", "affine", "observed"}
    for ceiling in ("seen+flat", "seen+harmonic", "seen+salt"):
        rows_of = [r for r in rows if r["method"] == ceiling]
        assert {r["normalize"] for r in rows_of} == {"evreal", "affine"}  # whole frames only
    assert len(rows) == 3 * len(methods) + 2 * 3
    assert all(np.isfinite(float(r["psnr"])) for r in rows)
    observed = [r for r in rows if r["normalize"] == "observed"]
    assert all(0 < float(r["coverage"]) <= 1 and r["ewarp"] == "" for r in observed)
    assert all(r["coverage"] == "" for r in rows if r["normalize"] != "observed")
    # the flat floor is what the affine fit makes of a featureless image: the same scores
    by = {(r["normalize"], r["method"]): r for r in rows}
    for key in ("psnr", "ssim"):
        assert float(by["affine", "flat"][key]) == pytest.approx(
            float(by["evreal", "flat"][key]), abs=1e-4)
    # the ceiling is the target where events fired and the best grey elsewhere: never
    # further from the target than the flat floor
    for norm in ("evreal", "affine"):
        assert float(by[norm, "seen+flat"]["mse"]) < float(by[norm, "flat"]["mse"])
    figure = cv2.imread(str(out / "real_benchmark.png"))
    assert figure is not None and figure.shape[0] > 200  # two rows: the AEDAT4, the snippet


def test_the_benchmark_skips_cleanly_without_the_folder(tmp_path, capsys):
    missing = tmp_path / "nowhere"
    assert bench_real().main(["--folder", str(missing), "--out", str(tmp_path / "o")]) == 0
    assert f"skipped: {missing} is not there" in capsys.readouterr().out
    assert not (tmp_path / "o").exists()
    with pytest.raises(FileNotFoundError, match="no such folder of real recordings"):
        find_recordings(missing)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="neither davis346"):
        find_recordings(tmp_path / "empty")


def test_model_only_scores_the_model_alone(real_folder, tiny_checkpoint, tmp_path):
    out = tmp_path / "bench"
    assert bench_real().main(["--folder", str(real_folder), "--out", str(out), "--model-only",
                              "--checkpoint", str(tiny_checkpoint), "--engine", "torch"]) == 0
    rows = list(csv.DictReader((out / "real_benchmark.csv").open()))
    assert {(r["normalize"], r["method"]) for r in rows} == {
        ("evreal", "ours"), ("affine", "ours"), ("observed", "ours")}
    assert cv2.imread(str(out / "real_benchmark.png")) is not None
