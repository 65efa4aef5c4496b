"""``--engine auto`` on a CPU: int8 where the int8 graph of these weights passed its quality
check against float32, float32 otherwise, and a line saying which and why.

Properties: the check's PSNR is the analytic one on known differences; a real check on the
shipped x2 model is run once, recorded beside the export and reused without calling the
source again (a record lost is checked once more); a recorded pass gives int8, a recorded
fail or an unreachable threshold float32; without a calibration source, nncf, or a working
int8 export, float32 with the reason; on a GPU torch."""

from __future__ import annotations

import json
import re
from dataclasses import asdict

import numpy as np
import pytest
import torch

from esim_lite.core.atomic import write_text
from model import checkpoint
from model.calibration import simulated_inputs
from model.inference import engines, quality, quantize
from model.inference.engines import load_engine
from model.inference.pretrained import shipped_checkpoint
from tests.model.conftest import SMALL_CALIBRATION, SMALL_CHECK_INPUTS
from tests.model.test_engines import hide

CPU = torch.device("cpu")
pytestmark = pytest.mark.skipif(not engines.installed("openvino-int8"),
                                reason="openvino or nncf not installed")
FLOAT32 = "openvino"  # auto's float32 choice wherever int8 (openvino + nncf) is installed


def no_source(*_):
    raise AssertionError("simulated again")


class Counting:
    """A calibration source that records the recipes it was called with."""

    def __init__(self):
        self.recipes = []

    def __call__(self, net, recipe):
        self.recipes.append(recipe)
        return simulated_inputs(net, recipe)


@pytest.fixture(scope="module")
def shipped_x2():
    return checkpoint.load_model(shipped_checkpoint(2))


@pytest.fixture(scope="module")
def checked_folder(shipped_x2, tmp_path_factory):
    """The shipped x2 model through ``auto`` once: int8 exported and checked (small
    recipes, tests/model/conftest.py); the calibration source's calls."""
    folder = tmp_path_factory.mktemp("auto")
    source = Counting()
    engine = load_engine("auto", shipped_x2, CPU, (48, 64), folder, calibrate=source)
    return folder, source.recipes, engine


def export_and_record(folder):
    [export] = sorted((folder / "engines").glob("*openvino-int8*.npz"))
    return export, quality.record_path(export, quality.DEFAULT_CHECK)


def test_the_psnr_is_the_analytic_one_per_input_and_the_minimum_decides():
    inputs = [{"stacks": np.zeros((1, 3, 3, 4, 4), np.float32),
               "central": np.full((1, 3, 4, 4), k, np.float32),
               "flows": np.zeros((1, 3, 2, 4, 4), np.float32)} for k in (0.01, 0.001)]

    def reference(stacks, central, flows):  # mid-grey: the offsets below stay unclamped
        return torch.full((1, 1, 8, 8), 0.5)

    def off_by_central(stacks, central, flows):  # 0.01 -> 40 dB, 0.001 -> 60 dB
        return reference(stacks, central, flows) + central[0, 0, 0, 0]

    check = quality.QualityCheck(threshold_db=40.0)
    result = quality.run_check(off_by_central, reference, inputs, check)
    assert result.psnr_db == pytest.approx((40.0, 60.0), abs=1e-3)
    assert result.min_db == pytest.approx(40.0, abs=1e-3)
    assert result.mean_db == pytest.approx(50.0, abs=1e-3)
    assert result.passed  # at the threshold passes: min >= threshold
    assert not quality.run_check(off_by_central, reference, inputs,
                                 quality.QualityCheck(threshold_db=40.1)).passed
    assert quality.run_check(reference, reference, inputs, check).min_db == 100.0
    # the clamp: values beyond [0, 1] on both sides are the same image
    assert quality.psnr_db(torch.full((2, 2), 1.7), torch.ones(2, 2)) == 100.0
    with pytest.raises(ValueError, match="no inputs"):
        quality.run_check(reference, reference, [], check)


def test_a_real_check_is_run_once_and_recorded_beside_the_export(shipped_x2, checked_folder):
    folder, recipes, engine = checked_folder
    # the source made the calibration inputs, then the check's held-out ones (another seed)
    assert recipes == [quantize.Calibration(**SMALL_CALIBRATION),
                       quantize.Calibration(**SMALL_CHECK_INPUTS)]
    export, record = export_and_record(folder)
    assert record.parent == export.parent and record.name.startswith(export.name)
    data = json.loads(record.read_text())
    assert len(data["psnr_db"]) == SMALL_CHECK_INPUTS["samples"]
    assert data["min_db"] == min(data["psnr_db"]) <= data["mean_db"]
    assert data["threshold_db"] == 35.0 and data["recipe"] == recipes[1].tag
    assert data["passed"] == (data["min_db"] >= 35.0)
    print(f"shipped x2, small check: min {data['min_db']} dB, mean {data['mean_db']} dB")
    # int8 moves the output (on sparse simulated stacks its level by up to ~0.15), yet
    # stays an image of the same scene; identical outputs would give 100 dB
    assert 10 < data["min_db"] < 100
    want = "openvino-int8" if data["passed"] else FLOAT32
    assert engine.name == want
    assert engine.why.startswith(f"auto: int8 {'passed' if data['passed'] else 'failed'} "
                                 f"its quality check, min {data['min_db']:.1f} dB")
    # a later auto reads the record: nothing is simulated, quantised or checked again
    before = (export.stat().st_mtime_ns, record.stat().st_mtime_ns)
    again = load_engine("auto", shipped_x2, CPU, (20, 24), folder, calibrate=no_source)
    assert again.name == want and again.why == engine.why
    assert (export.stat().st_mtime_ns, record.stat().st_mtime_ns) == before


def test_a_cached_export_without_a_record_is_checked_once(shipped_x2, tmp_path):
    load_engine("openvino-int8", shipped_x2, CPU, (20, 24), tmp_path,
                calibrate=simulated_inputs)  # asked for: exported, not checked
    export, record = export_and_record(tmp_path)
    assert not record.exists()
    source = Counting()
    load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path, calibrate=source)
    assert source.recipes == [quantize.Calibration(**SMALL_CHECK_INPUTS)]  # no re-export
    assert record.exists()
    load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path, calibrate=no_source)


@pytest.mark.parametrize("passed", [True, False])
def test_auto_follows_the_recorded_result(shipped_x2, checked_folder, passed, tmp_path):
    folder, _, _ = checked_folder
    export, record = export_and_record(folder)
    (tmp_path / "engines").mkdir()
    (tmp_path / "engines" / export.name).write_bytes(export.read_bytes())
    fake = quality.CheckResult(passed, 41.25 if passed else 12.5, 44.0, (41.25, 46.75),
                               35.0, "recipe")
    write_text(tmp_path / "engines" / record.name, json.dumps(asdict(fake)))
    engine = load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path, calibrate=no_source)
    if passed:
        assert engine.name == "openvino-int8"
        assert engine.why == ("auto: int8 passed its quality check, min 41.2 dB >= 35 dB vs "
                              "float32 on 2 simulated inputs, mean 44.0 dB")
    else:
        assert engine.name == FLOAT32
        assert engine.why == ("auto: int8 failed its quality check, min 12.5 dB < 35 dB vs "
                              "float32 on 2 simulated inputs, mean 44.0 dB; float32")


def test_an_unreachable_threshold_gives_float32(shipped_x2, checked_folder, monkeypatch):
    folder, _, _ = checked_folder
    strict = quality.QualityCheck(quantize.Calibration(**SMALL_CHECK_INPUTS), 99.0)
    monkeypatch.setattr(quality, "DEFAULT_CHECK", strict)
    source = Counting()
    engine = load_engine("auto", shipped_x2, CPU, (20, 24), folder, calibrate=source)
    assert source.recipes == [strict.inputs]  # another check on the same export
    assert engine.name == FLOAT32
    assert re.fullmatch(r"auto: int8 failed its quality check, min \d+\.\d dB < 99 dB vs "
                        r"float32 on 4 simulated inputs, mean \d+\.\d dB; float32", engine.why)
    export, _ = export_and_record(folder)
    assert not json.loads(quality.record_path(export, strict).read_text())["passed"]


def test_without_a_source_nncf_or_a_working_export_auto_keeps_float32(
        shipped_x2, tmp_path, monkeypatch):
    plain = load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path)
    assert plain.name == FLOAT32
    assert plain.why == ("auto: no calibration source given to build and check int8 with; "
                         "float32")

    def broken(*_, **__):
        raise RuntimeError("quantiser broke")

    warned = []  # the warning itself (caplog misses it after some other tests in a worker)
    monkeypatch.setattr(engines.log, "warning", lambda msg, *args: warned.append(msg % args))
    monkeypatch.setitem(engines._EXPORTS, "openvino-int8", (".npz", broken))
    engine = load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path,
                         calibrate=simulated_inputs)
    assert engine.name == FLOAT32
    assert warned == ["engine openvino-int8 failed (RuntimeError: quantiser broke); using "
                      "float32"]
    assert engine.why == "auto: int8 failed to build or check (RuntimeError: quantiser broke)"
    hide(monkeypatch, "nncf")
    engine = load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path, calibrate=no_source)
    assert engine.name == FLOAT32
    assert engine.why == "auto: int8 needs nncf (not installed); float32"
    gpu = load_engine("auto", shipped_x2, torch.device("cuda"), calibrate=no_source)
    assert (gpu.name, gpu.why) == ("torch", "auto: eager torch on a GPU")
    asked = load_engine("torch", shipped_x2, CPU, calibrate=no_source)
    assert (asked.name, asked.why) == ("torch", "asked for")
