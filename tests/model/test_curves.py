"""The validation curve survives resumption and is drawn."""

from __future__ import annotations

import cv2

from model.training.curves import ValHistory


def test_history_round_trips_and_a_resumed_run_replaces_what_it_repeats(tmp_path):
    path = tmp_path / "val_history.csv"
    h = ValHistory(path)
    for step, p in ((100, 14.0), (200, 15.0), (300, 15.5)):
        h.add(step, step / 1000, {"psnr": p, "ssim": 0.5, "mse": 0.03, "lpips": 0.4,
                                  "other": 1.0})
    h.save()
    back = ValHistory(path)
    assert [int(r["step"]) for r in back.rows] == [100, 200, 300]
    assert back.rows[1]["psnr"] == 15.0 and "other" not in back.rows[1]
    # a run killed after step 300's validation but resumed from the step-200 checkpoint
    # validates at 300 again: one row per step, the new one
    back.add(300, 0.31, {"psnr": 15.7})
    assert [r.get("psnr") for r in back.rows] == [14.0, 15.0, 15.7]
    png = back.plot(tmp_path / "curve.png", "test")
    img = cv2.imread(str(png))
    assert img is not None and img.shape[1] > img.shape[0] > 100
