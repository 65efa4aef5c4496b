"""Both shipped models give the same output bytes as before the experiments' switches left
the network, on every engine.

The digests were taken at commit 9e72ba2 (the last one holding the switches) by the code
below, and again after their removal: equal on this CPU and software stack. Engines compile
differently on other CPUs, so a digest is compared only where the reference stack is.

The int8 digests were taken again when the exported graph's cell means changed to divide by
a pooling of ``x * 0 + 1`` (graph version 2, so that OpenVINO compiles it in bfloat16): the
float32 engines' bytes stayed equal; int8's moved (NNCF quantises a different graph), with
its largest difference from torch on this input 0.045 -> 0.045 (x2) and 0.089 -> 0.085
(x4), and its quality check unchanged (min 30.0 / mean 33.1 dB). ``openvino-bf16`` has no
digest: its bytes depend on the CPU's bfloat16 units (AMX or AVX512-BF16); its bar is the
quality check (tests/model/test_auto_engine.py)."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import torch

from model import checkpoint
from model.calibration import simulated_inputs
from model.inference import engines, quantize
from model.inference.engines import load_engine
from model.inference.pretrained import shipped_checkpoint

BEFORE = {
    "x2/torch": "a53fe1a15e59240571b9a38f1643c0f702c27c47879643d6f3664d24f075d446",
    "x2/onnxruntime": "d71dffd99c6b67143d3658f4ad2f3ae79d78777c9f9b2f3d00743d2b7faf561f",
    "x2/openvino": "f27c6790d5e37d74dc3a0ebfaeedfd0f2a7156e8d61c9545b7bcf19b00ba131e",
    "x2/openvino-int8": "558542b06275880f02130ae379d8739262ff734f366a350e5911e78c5c14fd7a",
    "x4/torch": "700612d98a2d93f56cdf2f82d33609963f2426b8491b1a94fe71c602661f6c31",
    "x4/onnxruntime": "43b6bbea9719e61135fa65b1fd3ee61142b55a3f212d4c3ef473130b41b1a40c",
    "x4/openvino": "253d530fd45d653ce3ef512822e5160473cf60f15c379dc8da11908218f90cfb",
    "x4/openvino-int8": "557c2bca44b01e9af41adca08df5963aded257608693d941866a48725c74561b",
}
SMALL = quantize.Calibration(sequences=1, frames=10, samples=8, seed=5)
REFERENCE_STACK = {"torch": "2.13.0", "cpu": "AVX512"}  # digests taken on AVX512 CPUs: on
# an AVX2 one (AMD EPYC, 2026-12-07) torch, ONNX Runtime and int8 give other bytes


def fixed_input(n: int, c: int, hw=(24, 32)):
    """Sparse stacks in [-1, 1] (70% of the values zero), their central one, random flows."""
    g = torch.Generator().manual_seed(7)
    stacks = (torch.rand(1, n, c, *hw, generator=g) * 2 - 1) \
        * (torch.rand(1, n, c, *hw, generator=g) < 0.3)
    return stacks, stacks[:, n // 2].clone(), torch.randn(1, n, 2, *hw, generator=g)


@pytest.mark.skipif(torch.__version__.split("+")[0] != REFERENCE_STACK["torch"]
                    or not torch.backends.cpu.get_cpu_capability().startswith(
                        REFERENCE_STACK["cpu"]),
                    reason="digests recorded with torch 2.13.0 on an AVX512 CPU")
@pytest.mark.parametrize("engine", [pytest.param(
    e, marks=pytest.mark.skipif(not engines.installed(e), reason=f"{e} not installed"))
    for e in engines.ENGINES if e != "openvino-bf16"])
@pytest.mark.parametrize("scale", [2, 4])
def test_shipped_outputs_are_unchanged(scale, engine, tmp_path, monkeypatch):
    monkeypatch.setattr(quantize, "DEFAULT_CALIBRATION", SMALL)  # int8: seconds, not a minute
    net = checkpoint.load_model(shipped_checkpoint(scale))
    runner = load_engine(engine, net, torch.device("cpu"), (24, 32), tmp_path,
                         calibrate=simulated_inputs)
    with torch.inference_mode():
        out = runner(*fixed_input(net.config.n_stacks, net.config.stack_channels))
    digest = hashlib.sha256(np.ascontiguousarray(out.float().numpy()).tobytes()).hexdigest()
    assert digest == BEFORE[f"x{scale}/{engine}"]
