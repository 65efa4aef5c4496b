"""Inference engines: every installed engine gives torch's output (within 1/255, far
tighter in practice) at any sensor size, the exported file is cached per weights and engine
version, and a missing engine is a one-line error."""

from __future__ import annotations

import importlib.util
import re

import numpy as np
import pytest
import torch

from esim_lite.core.stacking import StackConfig, stack_to_input
from model import checkpoint
from model.archs.e2sri_arch import E2SRI, NetConfig
from model.cli import reconstruct_main
from model.inference import engines
from model.inference.engines import EngineMissing, load_engine
from model.inference.pretrained import shipped_checkpoint
from model.inference.reconstruct import Reconstructor
from tests.datagen.test_recording import events, write_hdf5

CPU = torch.device("cpu")
TOLERANCE = 1 / 255  # the bound on fp32 outputs against torch
COMPILED = [pytest.param(e, marks=pytest.mark.skipif(not engines.installed(e),
                                                      reason=f"{e} not installed"))
            for e in ("onnxruntime", "openvino")]


def inputs(config: NetConfig, hw: tuple[int, int], seed: int = 0):
    """Network inputs as ``Reconstructor.run`` makes them: uint8 stacks mapped to [-1, 1],
    the central stack, flows of a few pixels."""
    rng = np.random.default_rng(seed)
    n, c = config.n_stacks, config.stack_channels
    stacks = rng.integers(0, 256, (n, c, *hw)).astype(np.uint8)
    x = torch.from_numpy(stack_to_input(stacks))[None]
    flows = torch.from_numpy(rng.normal(0, 2, (1, n, 2, *hw)).astype(np.float32))
    central = x[:, n // 2] if config.central == "stack" else \
        torch.from_numpy(rng.random((1, 1, *hw), np.float32))
    return x, central, flows


def max_difference(engine, net: E2SRI, hw: tuple[int, int], seed: int = 0) -> float:
    args = inputs(net.config, hw, seed)
    with torch.inference_mode():
        want = net(*args).clamp(0, 1)
        got = engine(*args).clamp(0, 1)
    assert got.shape == want.shape == (1, 1, hw[0] * net.config.scale, hw[1] * net.config.scale)
    return float((got - want).abs().max())


@pytest.mark.parametrize("engine", COMPILED)
@pytest.mark.parametrize("scale", [2, 4])
def test_shipped_models_match_torch(engine, scale, tmp_path, record_property):
    net = checkpoint.load_model(shipped_checkpoint(scale))
    runner = load_engine(engine, net, CPU, (40, 48), cache=tmp_path)
    assert runner.name == engine
    diff = max_difference(runner, net, (40, 48))
    record_property("max_difference", diff)
    print(f"{engine} x{scale} 40x48: max |engine - torch| = {diff:.2e}")
    assert diff <= TOLERANCE
    assert diff < 1e-4  # what fp32 engines actually give; 1/255 would hide a real bug
    # another size than the one compiled at load, and not a multiple of anything
    assert max_difference(runner, net, (37, 29), seed=1) < 1e-4


TINY = dict(base_channels=8, hr_channels=4, c_blocks=1, blocks=1)


@pytest.mark.parametrize("engine", COMPILED)
@pytest.mark.parametrize("variant", [
    dict(),  # the paper's layout: HR state, transposed convolutions
    dict(state="lr"),  # the CPU variant: LR state, one sub-pixel lift
    dict(scale=4, state="lr"),
    dict(state="lr", lift="smooth"),  # the anti-grid filter: replicate pad + depthwise conv
    dict(scale=4, state="lr", lift="smooth"),
    dict(central="aps"),
    dict(flow="learned"),  # no flows input used
    dict(flow="none"),
    dict(state="lr", context=4),  # pooled cells (partial at odd sizes), bilinear back
    dict(scale=4, state="lr", lift="smooth", context=4),  # the shipped layout
])
def test_any_network_at_odd_sizes_matches_torch(engine, variant, tmp_path):
    torch.manual_seed(0)
    net = E2SRI(NetConfig(**{**TINY, **variant})).eval()
    if net.config.context:  # its residual starts at zero: give it weight to compare
        torch.nn.init.normal_(net.context.out.weight, std=0.3)
    runner = load_engine(engine, net, CPU, (21, 27), cache=tmp_path)
    for k, hw in enumerate([(21, 27), (16, 16), (9, 31)]):
        assert max_difference(runner, net, hw, seed=k) < 1e-4


@pytest.mark.parametrize("engine", COMPILED)
def test_duo_pass_runs_both_networks_on_the_engine(engine, tmp_path):
    torch.manual_seed(1)
    first = E2SRI(NetConfig(**TINY)).eval()
    duo = E2SRI(NetConfig(central="first_pass", **TINY)).eval()
    cfg = StackConfig(events_per_channel=50)
    hw = (19, 26)
    reference = Reconstructor(duo, first, cfg, CPU)
    fast = Reconstructor(duo, load_engine(engine, first, CPU, hw, tmp_path), cfg, CPU,
                         load_engine(engine, duo, CPU, hw, tmp_path))
    assert fast.engine_name == engine and reference.engine_name == "torch"
    stacks = np.random.default_rng(2).integers(0, 256, (3, 3, *hw)).astype(np.uint8)
    want, _ = reference.run(stacks, None)
    got, timing = fast.run(stacks, None)
    assert set(timing) == {"flow", "network"}
    assert np.abs(got - want).max() < 1e-4


def files(folder):
    return sorted((folder / "engines").iterdir())


@pytest.mark.parametrize("engine", COMPILED)
def test_the_export_is_cached_and_follows_the_weights(engine, tmp_path, monkeypatch):
    torch.manual_seed(2)
    net = E2SRI(NetConfig(**TINY)).eval()
    load_engine(engine, net, CPU, (16, 20), tmp_path)
    [path] = files(tmp_path)
    assert engine in path.name and engines.version(engine) in path.name
    before = path.stat()

    def no_export(*_):
        raise AssertionError("exported again")

    suffix, export = engines._EXPORTS[engine]
    monkeypatch.setitem(engines._EXPORTS, engine, (suffix, no_export))
    again = load_engine(engine, net, CPU, (16, 20), tmp_path)  # reused, not re-exported
    after = path.stat()
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)
    assert files(tmp_path) == [path]
    assert max_difference(again, net, (16, 20)) < 1e-4
    monkeypatch.setitem(engines._EXPORTS, engine, (suffix, export))
    with torch.no_grad():  # new weights: a new file, and the engine follows them
        net.efr0[0][0].weight.add_(0.05)
    changed = load_engine(engine, net, CPU, (16, 20), tmp_path)
    assert len(files(tmp_path)) == 2 and path.stat().st_mtime_ns == before.st_mtime_ns
    assert max_difference(changed, net, (16, 20)) < 1e-4
    # a damaged cache entry is exported again rather than failing
    for p in files(tmp_path):
        p.write_bytes(b"not a network")
    assert max_difference(load_engine(engine, net, CPU, (16, 20), tmp_path), net,
                          (16, 20)) < 1e-4


def recording(tmp_path):
    path = tmp_path / "e.h5"
    write_hdf5(path, events(n=6000, hw=(30, 40)), with_frames=False)
    return path


def hide(monkeypatch, *packages: str) -> None:
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in packages else real(name, *a))


@pytest.mark.parametrize("engine", ["onnxruntime", "openvino"])
def test_a_missing_engine_is_a_one_line_error(engine, tmp_path, monkeypatch, capsys):
    hide(monkeypatch, engine)
    with pytest.raises(EngineMissing, match=rf"needs {engine}.*e2sr\[fast\]"):
        engines.choose(engine, CPU)
    rc = reconstruct_main([str(recording(tmp_path)), "--out", str(tmp_path / "o"),
                           "--engine", engine, "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert err.strip().splitlines() == [
        f"reconstruct: error: engine {engine!r} needs {engine}, which is not installed: "
        f"pip install 'e2sr[fast]' (or pip install {engine})"]
    assert not (tmp_path / "o").exists()


def test_auto_prefers_the_fastest_installed_engine_and_falls_back_to_torch(monkeypatch):
    assert engines.choose("auto", torch.device("cuda")) == "torch"  # GPUs: eager torch
    hide(monkeypatch, "openvino")
    assert engines.choose("auto", CPU) == ("onnxruntime" if engines.installed("onnxruntime")
                                           else "torch")
    hide(monkeypatch, "openvino", "onnxruntime")
    assert engines.choose("auto", CPU) == "torch"
    with pytest.raises(ValueError, match="unknown engine 'tensorrt'"):
        engines.choose("tensorrt", CPU)


def test_auto_falls_back_to_torch_when_the_export_fails(monkeypatch, tmp_path, caplog):
    chosen = engines.choose("auto", CPU)
    if chosen == "torch":
        pytest.skip("no compiled engine installed")

    def broken(*_):
        raise RuntimeError("unsupported operator")

    monkeypatch.setitem(engines._EXPORTS, chosen, (".x", broken))
    net = E2SRI(NetConfig(**TINY)).eval()
    assert load_engine("auto", net, CPU, (8, 8), tmp_path).name == "torch"
    assert "unsupported operator" in caplog.text
    with pytest.raises(RuntimeError, match="unsupported operator"):
        load_engine(chosen, net, CPU, (8, 8), tmp_path)


def test_reconstruct_names_its_engine_and_why_and_matches_torch(tmp_path, capsys):
    import cv2

    path = recording(tmp_path)
    outs, names = {}, {}
    for engine in ("torch", "auto"):
        assert reconstruct_main([str(path), "--out", str(tmp_path / engine), "--engine",
                                 engine, "--limit", "2", "--no-progress"]) == 0
        lines = [line for line in capsys.readouterr().out.splitlines()  # not nncf's bars
                 if line.startswith(("engine ", "wrote "))]
        names[engine], why = re.fullmatch(r"engine (\S+) \((.+)\)", lines[0]).groups()
        assert why == "asked for" if engine == "torch" else why.startswith("auto: ")
        assert f"engine {names[engine]}); ms per frame: stacking" in lines[1]
        outs[engine] = [cv2.imread(str(p), 0).astype(int)
                        for p in sorted((tmp_path / engine).glob("frame_*.png"))]
    assert names["torch"] == "torch"
    assert len(outs["torch"]) == len(outs["auto"]) == 2
    for a, b in zip(outs["torch"], outs["auto"]):
        if names["auto"] == "openvino-bf16":  # passed its check: the 35 dB bar
            assert 10 * np.log10(255 ** 2 / max(np.mean((a - b) ** 2), 1e-10)) >= 35
        else:  # float32
            assert np.abs(a - b).max() <= 1  # a rounding step at most
