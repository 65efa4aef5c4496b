"""Evaluation: the temporal metrics against constructed cases, and the whole protocol."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest

from model.cli import evaluate_main
from model.inference.evaluate import normalized, temporally_consistent, warp_error
from tests.datagen.test_recording import events


def moving_scene(n=6, shift=2):
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.random((96, 96)).astype(np.float32), (0, 0), 3)
    base = (base - base.min()) / (base.max() - base.min())
    return [np.roll(base, shift * k, axis=1)[:, 16:80].copy() for k in range(n)]


def test_warp_error_is_zero_for_outputs_that_move_with_the_scene():
    frames = moving_scene()
    assert warp_error(frames, frames) < 0.05  # only interpolation at the flow's subpixels
    rng = np.random.default_rng(1)
    flicker = [f + 0.1 * rng.standard_normal(f.shape).astype(np.float32) for f in frames]
    assert warp_error(flicker, frames) > 10


def test_temporal_post_process_lowers_the_warp_error():
    frames = moving_scene(n=8)
    rng = np.random.default_rng(2)
    noisy = [f + 0.05 * rng.standard_normal(f.shape).astype(np.float32) for f in frames]
    before = warp_error(noisy, frames)
    after = warp_error(temporally_consistent(noisy, 0.6), frames)
    assert after < 0.7 * before


def test_affine_normalisation_removes_scale_and_offset():
    gt = moving_scene(1)[0]
    pred, _ = normalized(0.3 * gt + 0.2, gt, "affine")
    np.testing.assert_allclose(pred, gt, atol=1e-5)


def test_evaluate_on_held_out_shards_and_a_recording(tiny_shards, tiny_checkpoint, tmp_path,
                                                    capsys):
    from tests.datagen.test_recording import write_hdf5

    rec = tmp_path / "with_aps.h5"
    write_hdf5(rec, events(n=8000, hw=(48, 64)), with_frames=True)
    # frames() gives 3 APS frames at 1.5, 1.9, 2.3 s (30x40): regenerate at 48x64
    import h5py

    rng = np.random.default_rng(3)
    with h5py.File(rec, "a") as f:
        del f["images"]
        for k, t in enumerate((1.5, 1.9, 2.3)):
            ds = f.create_dataset(f"images/image{k:09d}", data=(rng.random((48, 64)) * 255)
                                  .astype(np.uint8))
            ds.attrs["timestamp"] = t
    out = tmp_path / "eval"
    assert evaluate_main(["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_shards),
                          "--recording", str(rec), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    for method in ("ours", "hf", "direct", "complementary", "ours+tc"):
        assert method in text
    table = (out / "metrics.md").read_text()
    assert "HR output vs HR ground truth" in table and "APS/LR frame" in table
    # the engine of ours and why, per sensor size (auto: int8 or float32 by its check)
    engine_lines = table.split("Network engine (ours):\n\n")[1].split("\n\n")[0]
    assert re.fullmatch(r"- 64x48: engine (openvino-bf16|openvino|onnxruntime|torch) "
                        r"\(auto: .+\)", engine_lines.splitlines()[-1])
    assert f"{rec.parent.name}/{rec.name}" in table and "| average |" in table
    rows = (out / "metrics.csv").read_text().splitlines()
    assert rows[0].startswith("sequence,protocol,method") and len(rows) > 10
    assert cv2.imread(str(out / "figure.png")).shape[0] > 100
    assert evaluate_main(["--checkpoint", str(tiny_checkpoint), "--out", str(out)]) == 2
    assert "nothing to evaluate" in capsys.readouterr().err


def test_evreal_protocol_compares_absolute_methods_as_they_are():
    gt = moving_scene(1)[0]
    pred = 1.3 * gt - 0.1  # out of [0, 1] at both ends
    ours, target = normalized(pred, gt, "evreal", absolute=True)
    np.testing.assert_array_equal(ours, pred.clip(0, 1).astype(np.float32))
    assert target is gt
    hf, target = normalized(0.01 * gt + 5, gt, "evreal", absolute=False)  # no absolute scale
    assert target is gt and hf.min() == 0.0 and hf.max() == 1.0
    np.testing.assert_allclose(hf, normalized(gt, gt, "minmax")[0], atol=1e-4)


def test_split_all_scores_every_sequence_and_frameless_recordings_go_to_the_figure(
        tiny_shards, tiny_checkpoint, tmp_path):
    from model.inference.evaluate import EvalOptions, evaluate
    from tests.datagen.test_recording import write_text

    opts = EvalOptions(baselines=("hf",), temporal=False)
    val = evaluate(tiny_checkpoint, tmp_path / "v", tiny_shards, options=opts)
    every = evaluate(tiny_checkpoint, tmp_path / "a", tiny_shards, options=opts, split="all")
    seqs = {r["sequence"] for r in every if r["sequence"] != "average"}
    assert len(seqs) == 4 > len({r["sequence"] for r in val if r["sequence"] != "average"})
    folder = tmp_path / "no_frames"
    write_text(folder, events(n=6000, hw=(48, 64)), with_frames=False)
    rows = evaluate(tiny_checkpoint, tmp_path / "f", recordings=[str(folder)], options=opts,
                    sensor_hw=(48, 64))
    assert rows == []  # nothing to score against ...
    figure = cv2.imread(str(tmp_path / "f" / "figure.png"))
    assert figure is not None and figure.shape[0] > 100  # ... but shown: events | HF | ours


def test_without_baselines_the_figure_has_no_hf_panels(tiny_shards, tiny_checkpoint, tmp_path):
    """--no-baselines once crashed in the figure (after the tables were written), looking
    up HF's middle frame in a one-element stand-in list."""
    from model.inference.evaluate import EvalOptions, evaluate

    with_hf = evaluate(tiny_checkpoint, tmp_path / "b", tiny_shards, split="all",
                       options=EvalOptions(baselines=("hf",), temporal=False))
    alone = evaluate(tiny_checkpoint, tmp_path / "n", tiny_shards, split="all",
                     options=EvalOptions(baselines=(), temporal=False))
    assert {r["method"] for r in alone} == {"ours"}
    assert [r for r in with_hf if r["method"] == "ours"] == alone  # the same scores
    a = cv2.imread(str(tmp_path / "b" / "figure.png"))
    b = cv2.imread(str(tmp_path / "n" / "figure.png"))
    assert b is not None and b.shape[0] == a.shape[0] and b.shape[1] < a.shape[1]  # 2 fewer


def test_observed_scores_equal_the_affine_ones_when_every_pixel_is_observed(
        tiny_shards, tiny_checkpoint, tmp_path, monkeypatch, capsys):
    """Wiring of the ``observed`` normalisation (model/inference/observed.py): with a region
    covering the whole frame its fit and metrics are the affine protocol's, at HR and LR."""
    from model.inference import evaluate as ev

    opts = dict(baselines=("hf",), temporal=False, max_frames=2)
    real = ev.evaluate(tiny_checkpoint, tmp_path / "o", tiny_shards, split="all",
                       options=ev.EvalOptions(normalize="observed", **opts))
    assert {r["protocol"] for r in real} == {"hr", "lr"}
    assert all("ewarp" not in r for r in real)
    assert all(0 < r["coverage"] <= 1 for r in real if r["frames"])
    # the tables carry the region and the invented share (written files read back)
    import csv
    written = list(csv.DictReader((tmp_path / "o" / "metrics.csv").open()))
    assert len(written) == len(real)
    for r, w in zip(real, written):
        assert float(w["coverage"]) == pytest.approx(r["coverage"])
        assert (w["invented"] == "") == ("invented" not in r)
    assert "| region | invented |" in (tmp_path / "o" / "metrics.md").read_text()
    # and from the command line, which prints the averages (no E_warp under observed)
    assert evaluate_main(["--checkpoint", str(tiny_checkpoint), "--data", str(tiny_shards),
                          "--split", "all", "--normalize", "observed", "--no-temporal",
                          "--max-frames", "2", "--out", str(tmp_path / "cli")]) == 0
    printed = capsys.readouterr().out
    assert "invented" in printed and "E_warp" not in printed
    monkeypatch.setattr(ev, "support_mask",
                        lambda events: np.ones(events.sensor_hw, bool))
    everywhere = ev.evaluate(tiny_checkpoint, tmp_path / "w", tiny_shards, split="all",
                             options=ev.EvalOptions(normalize="observed", **opts))
    affine = ev.evaluate(tiny_checkpoint, tmp_path / "a", tiny_shards, split="all",
                         options=ev.EvalOptions(normalize="affine", **opts))
    assert len(everywhere) == len(affine)
    for w, a in zip(everywhere, affine):
        assert (w["sequence"], w["protocol"], w["method"], w["frames"]) == \
            (a["sequence"], a["protocol"], a["method"], a["frames"])
        assert w["coverage"] == 1.0
        assert w["psnr"] == pytest.approx(a["psnr"], abs=1e-3)
        assert w["ssim"] == pytest.approx(a["ssim"], abs=1e-5)
        assert w["lpips"] == pytest.approx(a["lpips"], rel=0.03)
