"""The network as a graph file for an inference engine, traced from the PyTorch module.

Two formats: ONNX (for ONNX Runtime; through torch's TorchScript exporter, which needs the
``onnx`` package) and OpenVINO's IR (converted by OpenVINO's own PyTorch front end, whose
graph fuses better in OpenVINO than the ONNX one; the ``.xml`` and ``.bin`` it writes are
packed into one ``.npz`` so a cache entry is a single file, written in one rename). Batch,
height and width stay dynamic in both, so one file serves every sensor size: the network's
padding to a multiple of ``fold`` and the crop back are traced as shape arithmetic, and
sizes that are not multiples of it give the same result as PyTorch (tested).

Graph inputs, named as :meth:`model.archs.e2sri_arch.E2SRI.forward`'s arguments:
``stacks (B, n, c, H, W)``, ``central (B, c_central, H, W)``, ``flows (B, n, 2, H, W)``;
output ``(B, 1, scale H, scale W)``, not clamped. A network that does not use ``flows``
(flow ``learned`` or ``none``) may have that input dropped by the exporter; engines feed
only the inputs a graph has.
"""

from __future__ import annotations

import copy
import tempfile
import warnings
from pathlib import Path

import numpy as np
import torch

from model.archs.e2sri_arch import E2SRI

INPUT_NAMES = ("stacks", "central", "flows")
OUTPUT_NAME = "image"
ONNX_OPSET = 17
GRAPH_VERSION = 2
"""Raised when the exported graph of the same weights changes (it is part of every cached
export's key). 2: the context branch's cell means divide by a pooling of ``x * 0 + 1``
(:func:`model.archs.blocks.cell_means`), which OpenVINO compiles in bfloat16."""
_EXAMPLE_HW = (24, 32)


def example_inputs(net: E2SRI, hw: tuple[int, int] = _EXAMPLE_HW
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Zero inputs of the shapes ``net`` takes at sensor size ``hw`` (batch 1, CPU)."""
    cfg = net.config
    n, c = cfg.n_stacks, cfg.stack_channels
    return (torch.zeros(1, n, c, *hw), torch.zeros(1, cfg.central_channels, *hw),
            torch.zeros(1, n, 2, *hw))


def _cpu_copy(net: E2SRI) -> E2SRI:
    """``net`` itself when it is on the CPU, else a CPU copy (the caller's stays put)."""
    on_cpu = all(p.device.type == "cpu" for p in net.parameters())
    return (net if on_cpu else copy.deepcopy(net).to("cpu")).eval()


def export_onnx(net: E2SRI, path: Path) -> None:
    """Write ``net`` as an ONNX file at ``path`` (dynamic batch, height and width)."""
    import onnx  # noqa: F401  (torch's exporter needs it; fail here with its name)

    dynamic = {"stacks": {0: "batch", 3: "height", 4: "width"},
               "central": {0: "batch", 2: "height", 3: "width"},
               "flows": {0: "batch", 3: "height", 4: "width"},
               OUTPUT_NAME: {0: "batch", 2: "out_height", 3: "out_width"}}
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # tracer and deprecation notes, not problems
        torch.onnx.export(_cpu_copy(net), example_inputs(net), str(path), dynamo=False,
                          opset_version=ONNX_OPSET, input_names=list(INPUT_NAMES),
                          output_names=[OUTPUT_NAME], dynamic_axes=dynamic)


def export_openvino(net: E2SRI, path: Path) -> None:
    """Write ``net`` as OpenVINO IR packed in one ``.npz`` (arrays ``xml``, ``bin``) at
    ``path``; weights stay float32 (OpenVINO would store float16 by default)."""
    import openvino as ov

    cfg = net.config
    n, c = cfg.n_stacks, cfg.stack_channels
    shapes = [ov.PartialShape([-1, n, c, -1, -1]),
              ov.PartialShape([-1, cfg.central_channels, -1, -1]),
              ov.PartialShape([-1, n, 2, -1, -1])]
    shapes = list(zip(INPUT_NAMES, shapes))
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        graph = ov.convert_model(_cpu_copy(net), example_input=example_inputs(net),
                                 input=shapes)
    save_openvino(graph, path)


def save_openvino(graph, path: Path) -> None:
    """Write an ``openvino.Model`` as IR packed in one ``.npz`` (arrays ``xml``, ``bin``);
    weights stay as they are (OpenVINO would compress float32 ones to float16)."""
    import openvino as ov

    with tempfile.TemporaryDirectory() as tmp:
        xml = Path(tmp) / "net.xml"
        ov.save_model(graph, str(xml), compress_to_fp16=False)
        parts = {"xml": np.frombuffer(xml.read_bytes(), np.uint8),
                 "bin": np.frombuffer(xml.with_suffix(".bin").read_bytes(), np.uint8)}
    with open(path, "wb") as f:
        np.savez(f, **parts)


def read_openvino(path: Path, core=None):
    """The ``openvino.Model`` packed by :func:`export_openvino` (read by ``core``, an
    ``openvino.Core``, or a new one)."""
    import openvino as ov

    with np.load(path) as parts:
        xml, weights = parts["xml"].tobytes(), parts["bin"].tobytes()
    return (core or ov.Core()).read_model(model=xml, weights=weights)
