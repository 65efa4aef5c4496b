"""The Triton event kernel against the compiled kernel's simulator, bit for bit.

Without a GPU the kernel runs in Triton's interpreter, which must be switched on before
triton is imported, so the comparison runs in a child process with ``TRITON_INTERPRET=1``.
On a machine where torch sees CUDA the same comparison also runs compiled, in this process.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

pytestmark = pytest.mark.skipif(importlib.util.find_spec("triton") is None,
                                reason="triton is not installed")

ROOT = Path(__file__).resolve().parents[2]


def compare(device: str) -> list[str]:
    """Runs every case on ``device``; returns one line per case (raises on a mismatch)."""
    from esim_lite.events import torch_kernel as event_torch
    from esim_lite.events.torch_kernel import TorchEventCamera
    from tests.esim_lite.test_event_torch import numba_stream, random_video

    lines = []
    for refractory_ns, sigma, cells in [(0, 0.05, None), (0, 0.4, None), (150_000, 0.4, None),
                                        (0, 0.4, 5 * 23 * 37)]:  # 5 samples per launch
        logs, times, th = random_video(11, 30, 23, 37, sigma)
        want, sim = numba_stream(logs, times, th, refractory_ns)
        saved = event_torch._TRITON_CELLS
        if cells:
            event_torch._TRITON_CELLS = cells
        try:
            cam = TorchEventCamera(th, refractory_ns=refractory_ns, device=device,
                                   backend="triton")
            got = [cam.simulate(logs[a:b], times[a:b]) for a, b in ((0, 1), (1, 12), (12, 30))]
        finally:
            event_torch._TRITON_CELLS = saved
        for name, w in zip(("x", "y", "t_ns", "p"), want):
            np.testing.assert_array_equal(np.concatenate([getattr(e, name) for e in got]), w)
        np.testing.assert_array_equal(cam.ref.cpu().numpy(), sim.ref)
        np.testing.assert_array_equal(cam.last_t.cpu().numpy(), sim.last_t)
        assert len(want[0]) > 500
        lines.append(f"ok {refractory_ns} {sigma} {cells} {len(want[0])}")
    return lines


def test_interpreted_kernel_gives_the_simulators_events_bit_for_bit():
    code = ("from tests.esim_lite.test_event_triton import compare\n"
            "print('\\n'.join(compare('cpu')))")
    env = {**os.environ, "TRITON_INTERPRET": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.count("ok ") == 4, out.stdout


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_compiled_kernel_gives_the_simulators_events_bit_for_bit():
    assert len(compare("cuda")) == 4


@pytest.mark.parametrize("write", [False, True])
def test_cuda_build_keeps_every_float64_rounding(write):
    """Compiled ahead of time for an sm_90 GPU (Triton bundles ptxas; no GPU needed): with
    the kernel's options the PTX has IEEE float64 division and no fused multiply-add (the
    compiled kernel's separate roundings); with fusion on (Triton 3.9's default) it would
    fuse four."""
    import triton
    from triton.backends.compiler import GPUTarget
    from triton.compiler import ASTSource

    from esim_lite.events.triton_kernel import (
        BLOCK,
        COMPILE_OPTIONS,
        SIGNATURE,
        _sweep,
        interpreting,
    )

    if interpreting():
        pytest.skip("this process interprets Triton")

    def ptx(options):
        src = ASTSource(fn=triton.jit(_sweep), signature=SIGNATURE,
                        constexprs={"WRITE": write, "BLOCK": BLOCK})
        return triton.compile(src, target=GPUTarget("cuda", 90, 32), options=options).asm["ptx"]

    ours = ptx(COMPILE_OPTIONS)
    assert "fma.rn.f64" not in ours and ".approx" not in ours
    assert ours.count("div.rn.f64") == 2 and "mul.rn.f64" in ours
    assert ptx({"enable_fp_fusion": True}).count("fma.rn.f64") > 0  # what the option prevents


def test_cpu_tensors_outside_the_interpreter_are_refused():
    from esim_lite.events.triton_kernel import interpreting, sweep

    if interpreting():
        pytest.skip("this process interprets Triton")

    z = torch.zeros(2, 3, 3)
    with pytest.raises(ValueError, match="TRITON_INTERPRET"):
        sweep(z, torch.tensor([0, 1]), z[0].double(), z[0].long(), z[0].double() + .2,
              z[0].double() + .2, 0, 1e-6)


def test_auto_backend_picks_triton_only_on_cuda():
    from esim_lite.events.torch_kernel import resolve_backend

    assert resolve_backend("auto", torch.device("cpu")) == "torch"
    assert resolve_backend("auto", torch.device("cuda")) == "triton"
    assert resolve_backend("torch", torch.device("cuda")) == "torch"
    with pytest.raises(ValueError, match="unknown event backend"):
        resolve_backend("cuda", torch.device("cpu"))
