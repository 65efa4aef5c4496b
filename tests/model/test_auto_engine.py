"""``--engine auto`` on a CPU: OpenVINO in bfloat16 where bf16 is OpenVINO's native
precision on this CPU and the network passed its quality check in it, float32 otherwise,
and a line saying which and why.

Properties: the check's PSNR is the analytic one on known differences; a real check of the
shipped x2 model in bf16 is run once, recorded beside the float32 export and reused without
calling the source again (a record lost is checked once more); bf16 really computes in
bf16 (its outputs differ from float32's) yet stays within the 35 dB bar; a recorded pass
gives bf16, a recorded fail or an unreachable threshold float32; where float32 is the
native precision nothing is simulated or checked; without a source or a working compile,
float32 with the reason; on a GPU torch. Tests that compile bf16 skip on CPUs without
bf16 units; the rest pretend the native precision either way."""

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
from tests.model.conftest import SMALL_CHECK_INPUTS
from tests.model.test_engines import hide

CPU = torch.device("cpu")
pytestmark = pytest.mark.skipif(not engines.installed("openvino"),
                                reason="openvino not installed")
FLOAT32 = "openvino"  # auto's float32 choice wherever openvino is installed
BF16 = "openvino-bf16"
needs_bf16 = pytest.mark.skipif(not (engines.installed("openvino") and engines.bf16_units()),
                                reason="this CPU has no bfloat16 units")


def no_source(*_):
    raise AssertionError("simulated again")


class Counting:
    """A source of inputs that records the recipes it was called with."""

    def __init__(self):
        self.recipes = []

    def __call__(self, net, recipe):
        self.recipes.append(recipe)
        return simulated_inputs(net, recipe)


@pytest.fixture
def native_bf16(monkeypatch):
    monkeypatch.setattr(engines, "native_precision", lambda: "bf16")


@pytest.fixture(scope="module")
def shipped_x2():
    return checkpoint.load_model(shipped_checkpoint(2))


@pytest.fixture(scope="module")
def checked_folder(shipped_x2, tmp_path_factory):
    """The shipped x2 model through ``auto`` once with bf16 native (small check recipe,
    tests/model/conftest.py); the source's calls."""
    if not engines.bf16_units():
        pytest.skip("this CPU has no bfloat16 units")
    folder = tmp_path_factory.mktemp("auto")
    source = Counting()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(engines, "native_precision", lambda: "bf16")
        engine = load_engine("auto", shipped_x2, CPU, (48, 64), folder, calibrate=source)
    return folder, source.recipes, engine


def export_and_record(folder, check=None):
    [export] = sorted((folder / "engines").glob("*-openvino-*.npz"))
    return export, quality.record_path(export, BF16, check or quality.DEFAULT_CHECK)


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


def test_a_real_check_is_run_once_and_recorded_beside_the_export(shipped_x2, checked_folder,
                                                                native_bf16):
    folder, recipes, engine = checked_folder
    assert recipes == [quantize.Calibration(**SMALL_CHECK_INPUTS)]  # bf16 needs no calibration
    export, record = export_and_record(folder)
    assert record.parent == export.parent and record.name.startswith(export.name)
    data = json.loads(record.read_text())
    assert len(data["psnr_db"]) == SMALL_CHECK_INPUTS["samples"]
    assert data["min_db"] == min(data["psnr_db"]) <= data["mean_db"]
    assert data["threshold_db"] == 35.0 and data["recipe"] == recipes[0].tag
    print(f"shipped x2 in bf16, small check: min {data['min_db']} dB, mean {data['mean_db']} dB")
    # bf16 keeps 8 bits of mantissa: the output moves (float32 engines match torch to
    # ~1e-6, which scores 100 dB here) but by far less than the bar
    assert 35 <= data["min_db"] < 80 and data["passed"]
    assert engine.name == BF16 and engine.precision == "bf16"
    assert engine.why.startswith(f"auto: bf16 (this CPU's native precision) passed its "
                                 f"quality check, min {data['min_db']:.1f} dB >= 35 dB")
    # a later auto reads the record: nothing is simulated, exported or checked again
    before = (export.stat().st_mtime_ns, record.stat().st_mtime_ns)
    again = load_engine("auto", shipped_x2, CPU, (20, 24), folder, calibrate=no_source)
    assert again.name == BF16 and again.why == engine.why
    assert (export.stat().st_mtime_ns, record.stat().st_mtime_ns) == before


@needs_bf16
def test_a_cached_export_without_a_record_is_checked_once(shipped_x2, tmp_path, native_bf16):
    load_engine("openvino", shipped_x2, CPU, (20, 24), tmp_path)  # asked for: not checked
    export, record = export_and_record(tmp_path)
    assert not record.exists()
    source = Counting()
    load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path, calibrate=source)
    assert source.recipes == [quantize.Calibration(**SMALL_CHECK_INPUTS)]
    assert record.exists() and export_and_record(tmp_path)[0] == export  # no re-export
    load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path, calibrate=no_source)


@pytest.mark.parametrize("passed", [pytest.param(True, marks=needs_bf16), False])
def test_auto_follows_the_recorded_result(shipped_x2, passed, tmp_path, native_bf16):
    load_engine("openvino", shipped_x2, CPU, (20, 24), tmp_path)
    export, record = export_and_record(tmp_path)
    fake = quality.CheckResult(passed, 41.25 if passed else 12.5, 44.0, (41.25, 46.75),
                               35.0, "recipe")
    write_text(record, json.dumps(asdict(fake)))
    engine = load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path, calibrate=no_source)
    if passed:
        assert engine.name == BF16
        assert engine.why == ("auto: bf16 (this CPU's native precision) passed its quality "
                              "check, min 41.2 dB >= 35 dB vs float32 on 2 simulated inputs, "
                              "mean 44.0 dB")
    else:
        assert engine.name == FLOAT32 and engine.precision == "f32"
        assert engine.why == ("auto: bf16 failed its quality check, min 12.5 dB < 35 dB vs "
                              "float32 on 2 simulated inputs, mean 44.0 dB; float32")


def test_an_unreachable_threshold_gives_float32(shipped_x2, checked_folder, monkeypatch,
                                                native_bf16):
    folder, _, _ = checked_folder
    strict = quality.QualityCheck(quantize.Calibration(**SMALL_CHECK_INPUTS), 99.0)
    monkeypatch.setattr(quality, "DEFAULT_CHECK", strict)
    source = Counting()
    engine = load_engine("auto", shipped_x2, CPU, (20, 24), folder, calibrate=source)
    assert source.recipes == [strict.inputs]  # another check on the same export
    assert engine.name == FLOAT32
    assert re.fullmatch(r"auto: bf16 failed its quality check, min \d+\.\d dB < 99 dB vs "
                        r"float32 on 4 simulated inputs, mean \d+\.\d dB; float32", engine.why)
    _, record = export_and_record(folder, strict)
    assert not json.loads(record.read_text())["passed"]


def test_where_float32_is_native_nothing_is_checked(shipped_x2, tmp_path, monkeypatch):
    monkeypatch.setattr(engines, "native_precision", lambda: "f32")
    engine = load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path, calibrate=no_source)
    assert (engine.name, engine.precision) == (FLOAT32, "f32")
    assert engine.why == ("auto: float32 (bfloat16 is not OpenVINO's native precision on "
                          "this CPU)")
    assert not list((tmp_path / "engines").glob("*.json"))


def test_without_a_source_or_a_working_engine_auto_keeps_float32(
        shipped_x2, tmp_path, monkeypatch, native_bf16):
    plain = load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path)
    assert plain.name == FLOAT32
    assert plain.why == "auto: no source of inputs to check bf16 with; float32"

    def broken(*_, **__):
        raise RuntimeError("check broke")

    warned = []  # the warning itself (caplog misses it after some other tests in a worker)
    monkeypatch.setattr(engines.log, "warning", lambda msg, *args: warned.append(msg % args))
    monkeypatch.setattr(quality, "run_check", broken)
    engine = load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path / "b",
                         calibrate=simulated_inputs)
    assert engine.name == FLOAT32
    assert warned == ["engine openvino-bf16 failed (RuntimeError: check broke); using "
                      "float32"]
    assert engine.why == "auto: bf16 failed to compile or check (RuntimeError: check broke)"
    hide(monkeypatch, "openvino")
    engine = load_engine("auto", shipped_x2, CPU, (20, 24), tmp_path, calibrate=no_source)
    assert engine.name in ("onnxruntime", "torch")
    assert engine.why.startswith("auto: OpenVINO is not installed")
    gpu = load_engine("auto", shipped_x2, torch.device("cuda"), calibrate=no_source)
    assert (gpu.name, gpu.why) == ("torch", "auto: eager torch on a GPU")
    asked = load_engine("torch", shipped_x2, CPU, calibrate=no_source)
    assert (asked.name, asked.why) == ("torch", "asked for")


def test_bf16_by_name_needs_bf16_units(shipped_x2, tmp_path, monkeypatch):
    monkeypatch.setattr(engines, "bf16_units", lambda: False)
    with pytest.raises(ValueError, match="openvino-bf16: this CPU has no bfloat16 units"):
        load_engine("openvino-bf16", shipped_x2, CPU, (20, 24), tmp_path)
