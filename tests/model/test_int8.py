"""``--engine openvino-int8``: the network quantised by NNCF on simulated calibration inputs.

Properties: the graph really runs convolutions in int8 (quantisers in front of them) except
the ones kept in float32; its output stays close to float32 on realistic inputs it was not
calibrated on; the export is cached and reused without simulating again; ``auto``'s float32
choice is never it (auto's int8: test_auto_engine.py); a missing ``nncf`` is a one-line
error, and so is a missing calibration source."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from model import checkpoint
from model.calibration import simulated_inputs
from model.inference import engines, graph_export, quantize
from model.inference.engines import EngineMissing, load_engine
from model.inference.pretrained import shipped_checkpoint
from tests.model.test_engines import hide

CPU = torch.device("cpu")
pytestmark = pytest.mark.skipif(not engines.installed("openvino-int8"),
                                reason="openvino or nncf not installed")
SMALL = quantize.Calibration(sequences=1, frames=10, samples=8, seed=5)


@pytest.fixture(scope="module")
def shipped_x2():
    return checkpoint.load_model(shipped_checkpoint(2))


@pytest.fixture(scope="module", autouse=True)
def small_calibration():
    """Every export in this module calibrates on :data:`SMALL` (seconds, not a minute)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(quantize, "DEFAULT_CALIBRATION", SMALL)
        yield


@pytest.fixture(scope="module")
def int8_folder(shipped_x2, tmp_path_factory):
    """The shipped x2 model exported once to int8."""
    folder = tmp_path_factory.mktemp("int8")
    load_engine("openvino-int8", shipped_x2, CPU, (48, 64), folder, calibrate=simulated_inputs)
    return folder


def test_first_and_last_convolutions_stay_float(shipped_x2, tmp_path):
    graph_export.export_openvino(shipped_x2, tmp_path / "n.npz")
    kept = quantize.kept_in_float(graph_export.read_openvino(tmp_path / "n.npz"))
    modules = {name.split("/")[0].removeprefix("__module.") for name in kept}
    # efr0's and efr's first convolutions read the inputs (efr's runs once per side stack);
    # mix.4 makes the image (mix.1, the lift before it, is quantised)
    assert modules == {"efr0.0.0", "efr.0.0", "mix.4.0"}
    assert len(kept) == 4


def test_the_graph_is_quantised_except_the_kept_convolutions(shipped_x2, int8_folder):
    [path] = sorted((int8_folder / "engines").iterdir())
    assert "openvino-int8" in path.name and SMALL.tag in path.name
    model = graph_export.read_openvino(path)
    ops = list(model.get_ordered_ops())
    convs = [op for op in ops if op.get_type_name() == "Convolution"]
    kept = set(quantize.kept_in_float(model))

    def quantised(node) -> bool:  # a FakeQuantize, possibly through Converts and Concats
        while node.get_type_name() == "Convert":
            node = node.input_value(0).get_node()
        if node.get_type_name() == "Concat":
            return all(quantised(v.get_node()) for v in node.input_values())
        return node.get_type_name() == "FakeQuantize"

    def quantised_input(op) -> bool:
        return quantised(op.input_value(0).get_node())

    # every Conv2d of the network is in the graph: the recurrence (efr, rnet_*) once per side
    # stack, everything else (efr0, mix, the context branch) once
    sides = shipped_x2.config.n_stacks - 1
    want = sum(sides if name.startswith(("efr.", "rnet_")) else 1
               for name, m in shipped_x2.named_modules() if isinstance(m, torch.nn.Conv2d))
    assert len(convs) == want
    for op in convs:
        assert quantised_input(op) == (op.get_friendly_name() not in kept), \
            op.get_friendly_name()


def test_int8_stays_close_to_float32_on_inputs_it_was_not_calibrated_on(shipped_x2,
                                                                         int8_folder):
    engine = load_engine("openvino-int8", shipped_x2, CPU, (64, 64), int8_folder,
                         calibrate=simulated_inputs)
    assert engine.name == "openvino-int8"
    held_out = simulated_inputs(
        shipped_x2, quantize.Calibration(sequences=1, frames=10, samples=3, seed=99))
    for d in held_out:
        x = [torch.from_numpy(d[k]) for k in graph_export.INPUT_NAMES]
        with torch.inference_mode():
            want = shipped_x2(*x).clamp(0, 1)
            got = engine(*x).clamp(0, 1)
        assert got.shape == want.shape == (1, 1, 256, 256)
        diff = (got - want).abs()
        # int8 moves outputs by a few grey levels, not more; an unquantised graph would
        # give ~1e-6 (checked below), a broken one tenths
        assert float(diff.mean()) < 0.03
        assert 1e-4 < float(diff.max()) < 0.5
        psnr = -10 * np.log10(float((diff ** 2).mean()))
        assert psnr > 30


def test_the_int8_export_is_reused(shipped_x2, int8_folder, monkeypatch):
    [path] = sorted((int8_folder / "engines").iterdir())
    before = path.stat().st_mtime_ns

    def no_export(*_, **__):
        raise AssertionError("quantised again")

    def no_simulation(*_):
        raise AssertionError("simulated again")

    # a cached int8 graph is reused as it is: nothing is simulated for it
    load_engine("openvino-int8", shipped_x2, CPU, (20, 24), int8_folder,
                calibrate=no_simulation)
    monkeypatch.setitem(engines._EXPORTS, "openvino-int8", (".npz", no_export))
    load_engine("openvino-int8", shipped_x2, CPU, (20, 24), int8_folder,
                calibrate=simulated_inputs)
    assert path.stat().st_mtime_ns == before
    # another calibration recipe is another file, not this one
    monkeypatch.setattr(quantize, "DEFAULT_CALIBRATION", quantize.Calibration(samples=9))
    with pytest.raises(AssertionError, match="quantised again"):
        load_engine("openvino-int8", shipped_x2, CPU, (20, 24), int8_folder,
                    calibrate=simulated_inputs)
    # a model trained on active-pixel stacks is calibrated on them: another file too
    monkeypatch.setattr(quantize, "DEFAULT_CALIBRATION", SMALL)
    with pytest.raises(AssertionError, match="quantised again"):
        load_engine("openvino-int8", shipped_x2, CPU, (20, 24), int8_folder,
                    stack_rule="active", calibrate=simulated_inputs)


def test_the_calibration_source_is_called_once_per_export_with_the_recipe(shipped_x2,
                                                                          tmp_path):
    calls = []

    def source(net, calibration):
        calls.append((net, calibration))
        return simulated_inputs(net, calibration)

    load_engine("openvino-int8", shipped_x2, CPU, (20, 24), tmp_path, stack_rule="active",
                calibrate=source)
    load_engine("openvino-int8", shipped_x2, CPU, (20, 24), tmp_path, stack_rule="active",
                calibrate=source)
    assert calls == [(shipped_x2, quantize.Calibration(sequences=1, frames=10, samples=8,
                                                       seed=5, stack_rule="active"))]


def test_int8_without_a_calibration_source_is_named(shipped_x2, tmp_path):
    with pytest.raises(ValueError, match="openvino-int8 needs calibration inputs"):
        load_engine("openvino-int8", shipped_x2, CPU, (20, 24), tmp_path)


def test_the_calibration_stacks_follow_the_training_stack_rule(shipped_x2):
    # the active rule sizes each stack by the pixels that fire, at most the fixed rule's
    # count: on a sequence where about half the frame fires, about half the events
    def events(rule):
        inputs = simulated_inputs(shipped_x2, quantize.Calibration(
            sequences=1, frames=10, samples=3, seed=99, stack_rule=rule))
        return np.array([np.abs(x["stacks"]).sum() for x in inputs])

    fixed, active = events("fixed"), events("active")
    assert len(fixed) == len(active) == 3
    assert np.all(active < 0.8 * fixed)
    with pytest.raises(ValueError, match="stack_rule"):
        quantize.Calibration(stack_rule="area")


def test_auto_float32_choice_is_never_int8_and_a_missing_nncf_is_named(monkeypatch):
    assert engines.choose("auto", CPU) != "openvino-int8"  # int8 only through its check
    hide(monkeypatch, "nncf")
    with pytest.raises(EngineMissing, match=r"needs nncf, which is not installed.*e2sr\[fast\]"):
        engines.choose("openvino-int8", CPU)


def test_a_calibration_needs_something_to_calibrate_on():
    with pytest.raises(ValueError, match="at least one"):
        quantize.Calibration(samples=0)
