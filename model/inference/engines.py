"""Engines for the network's forward pass: eager PyTorch, ONNX Runtime, OpenVINO.

Only the forward pass moves to an engine; stacking and flow stay in NumPy/OpenCV. Every
engine is called like the network itself, ``engine(stacks, central, flows)`` with torch
tensors ``(B, n, c, H, W)``, ``(B, c_central, H, W)``, ``(B, n, 2, H, W)``, and returns
``(B, 1, scale H, scale W)`` (not clamped) on the inputs' device.

- ``torch``: the network in eager PyTorch, on any device: the reference and the fallback.
- ``onnxruntime``: the ONNX export (:mod:`model.inference.graph_export`) on ONNX
  Runtime's CPU provider.
- ``openvino``: OpenVINO's IR on its CPU plugin, compiled for the sensor size at load
  (static shapes run faster than dynamic ones) and for any other size on first use;
  precision pinned to float32: the same outputs as torch to about 1e-6.
- ``openvino-bf16``: the same graph computed in bfloat16 (float32 accumulation), on CPUs
  with bf16 units (AMX or AVX512-BF16; elsewhere an error). With AMX, OpenVINO's own
  default precision, and 3-4x float32's speed on the 2-core CPU of ``docs/benchmarks.md``.
- ``openvino-int8``: the graph quantised to int8 by NNCF (:mod:`model.inference.quantize`,
  calibrated on the inputs of the caller's ``calibrate``: the CLI's are simulated). Faster
  than float32 where there is no AMX, but 30-33 dB from float32 (docs/benchmarks.md): by
  name only.
- ``auto``: ``torch`` on a GPU. On a CPU, ``openvino-bf16`` where bfloat16 is OpenVINO's
  native precision on this CPU (:func:`native_precision`: AMX) and the network passed its
  quality check in bf16 (:mod:`model.inference.quality`: at least 35 dB PSNR against
  float32 on every one of a few held-out simulated inputs made by the caller's
  ``calibrate``; run once per export and recorded beside it); otherwise the first
  installed of :data:`PREFERENCE` in float32 (OpenVINO was the fastest float32 engine,
  ONNX Runtime second). When an engine fails to export or compile, a warning and the next
  choice (bf16 -> float32 -> ``torch``). Every engine carries ``why``: a line saying why
  it runs (``auto``'s reason, or ``asked for``).

The exported file is made once per network and engine version and kept in the user's cache
(:mod:`model.inference.graph_cache`). The CPU engines use as many threads as torch
(``torch.get_num_threads()``, e.g. ``OMP_NUM_THREADS``). Their packages come with the
``fast`` extra: ``pip install -e ".[fast]"``.
"""

from __future__ import annotations

import functools
import importlib.util
import logging
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from importlib.metadata import version
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from model import checkpoint
from model.archs.e2sri_arch import E2SRI
from model.inference import graph_export, quality, quantize
from model.inference.graph_cache import CacheKey, cached_file, weights_digest

log = logging.getLogger(__name__)

Forward = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]
"""The network's forward pass: ``(stacks, central, flows) -> image``."""

ENGINES = ("torch", "onnxruntime", "openvino", "openvino-bf16", "openvino-int8")
PREFERENCE = ("openvino", "onnxruntime", "torch")
EXTRA = "fast"
PACKAGES = {"torch": (), "onnxruntime": ("onnxruntime", "onnx"), "openvino": ("openvino",),
            "openvino-bf16": ("openvino",), "openvino-int8": ("openvino", "nncf")}
"""The Python packages each engine needs (``onnx``: torch's ONNX exporter; ``nncf``: the
quantiser)."""


class EngineMissing(ValueError):
    """An engine was asked for whose package is not installed."""


def native_precision() -> str:
    """OpenVINO's own default inference precision on this CPU: ``bf16`` where it has AMX
    (where OpenVINO computes in bfloat16 unless told otherwise), ``f32`` elsewhere."""
    import openvino as ov

    return "bf16" if ov.Core().get_property("CPU", "INFERENCE_PRECISION_HINT") == ov.Type.bf16 \
        else "f32"


def bf16_units() -> bool:
    """This CPU has bfloat16 units OpenVINO can use (AMX or AVX512-BF16)."""
    import openvino as ov

    return "BF16" in ov.Core().get_property("CPU", "OPTIMIZATION_CAPABILITIES")


def missing_packages(engine: str) -> list[str]:
    return [p for p in PACKAGES[engine] if importlib.util.find_spec(p) is None]


def installed(engine: str) -> bool:
    return not missing_packages(engine)


def choose(engine: str, device: torch.device) -> str:
    """The engine to use for ``engine`` (``auto`` or one of :data:`ENGINES`); for ``auto``
    the float32 choice (:func:`load_engine` may put the checked bf16 engine in its place).

    Raises:
        ValueError: an unknown name.
        EngineMissing: the engine's package is not installed (the message names it and the
            extra that brings it).
    """
    if engine == "auto":
        return "torch" if device.type != "cpu" else next(e for e in PREFERENCE if installed(e))
    if engine not in ENGINES:
        raise ValueError(f"unknown engine {engine!r}: choose auto, {', '.join(ENGINES)}")
    missing = missing_packages(engine)
    if missing:
        raise EngineMissing(f"engine {engine!r} needs {' and '.join(missing)}, which "
                            f"{'is' if len(missing) == 1 else 'are'} not installed: pip "
                            f"install 'e2sr[{EXTRA}]' (or pip install {' '.join(missing)})")
    return engine


def _arrays(tensors: tuple[torch.Tensor, ...]) -> dict[str, np.ndarray]:
    return {name: np.ascontiguousarray(t.detach().to("cpu", torch.float32).numpy())
            for name, t in zip(graph_export.INPUT_NAMES, tensors)}


@dataclass(frozen=True, eq=False)
class TorchEngine:
    """The network itself (eager PyTorch)."""

    net: E2SRI
    why: str = "asked for"
    name: ClassVar[str] = "torch"

    def __call__(self, stacks: torch.Tensor, central: torch.Tensor,
                 flows: torch.Tensor) -> torch.Tensor:
        return self.net(stacks, central, flows)


@dataclass(frozen=True, eq=False)
class OnnxRuntimeEngine:
    """An ONNX file on ONNX Runtime's CPU execution provider."""

    path: Path
    threads: int
    why: str = "asked for"
    name: ClassVar[str] = "onnxruntime"
    session: Any = field(init=False, repr=False)
    inputs: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = self.threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3  # errors only
        session = ort.InferenceSession(str(self.path), options,
                                       providers=["CPUExecutionProvider"])
        object.__setattr__(self, "session", session)
        object.__setattr__(self, "inputs", tuple(i.name for i in session.get_inputs()))

    def __call__(self, stacks: torch.Tensor, central: torch.Tensor,
                 flows: torch.Tensor) -> torch.Tensor:
        arrays = _arrays((stacks, central, flows))
        out = self.session.run(None, {k: arrays[k] for k in self.inputs})[0]
        return torch.from_numpy(out).to(stacks.device)


@dataclass(frozen=True, eq=False)
class OpenVinoEngine:
    """OpenVINO IR on the CPU plugin in ``precision`` (``f32`` or ``bf16``); one compiled
    graph per input shape, made on first use (``sensor_hw``'s at load)."""

    path: Path
    threads: int
    sensor_hw: tuple[int, int] | None = None
    name: str = "openvino"
    why: str = "asked for"
    precision: str = "f32"
    core: Any = field(init=False, repr=False)
    model: Any = field(init=False, repr=False)
    inputs: tuple[str, ...] = field(init=False)
    requests: dict = field(init=False, repr=False, default_factory=dict)

    def __post_init__(self) -> None:
        import openvino as ov

        core = ov.Core()
        model = graph_export.read_openvino(self.path, core)
        object.__setattr__(self, "core", core)
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "inputs", tuple(  # a port has several names; ours is one
            next(n for n in graph_export.INPUT_NAMES if n in p.get_names())
            for p in model.inputs))
        if self.sensor_hw is not None:
            self._request(self._shapes_at(self.sensor_hw))

    def _shapes_at(self, hw: tuple[int, int]) -> tuple[tuple[int, ...], ...]:
        """The graph's input shapes for batch 1 at sensor size ``hw``."""
        shapes = []
        for port in self.model.inputs:
            dims = [d.get_length() if d.is_static else 1 for d in port.get_partial_shape()]
            shapes.append(tuple(dims[:-2]) + tuple(hw))
        return tuple(shapes)

    def _request(self, shapes: tuple[tuple[int, ...], ...]):
        if shapes not in self.requests:
            import openvino as ov

            model = self.model.clone()
            model.reshape({p: ov.PartialShape(list(s)) for p, s in zip(model.inputs, shapes)})
            config = {"INFERENCE_NUM_THREADS": self.threads,
                      "INFERENCE_PRECISION_HINT": self.precision,
                      "PERFORMANCE_HINT": "LATENCY", "NUM_STREAMS": 1}
            compiled = self.core.compile_model(model, "CPU", config)
            self.requests[shapes] = compiled.create_infer_request()
        return self.requests[shapes]

    def __call__(self, stacks: torch.Tensor, central: torch.Tensor,
                 flows: torch.Tensor) -> torch.Tensor:
        arrays = _arrays((stacks, central, flows))
        feed = [arrays[k] for k in self.inputs]
        request = self._request(tuple(a.shape for a in feed))
        out = request.infer(feed)[0]
        return torch.from_numpy(np.array(out, copy=True)).to(stacks.device)


def load_engine(engine: str, net: E2SRI, device: torch.device,
                sensor_hw: tuple[int, int] | None = None, cache: Path | None = None,
                stack_rule: str = "fixed", calibrate: quantize.CalibrationSource | None = None
                ) -> TorchEngine | OnnxRuntimeEngine | OpenVinoEngine:
    """``net``'s forward pass on ``engine`` (``auto`` or one of :data:`ENGINES`), exported
    into (or reused from) the cache folder ``cache`` (default: :func:`cache_root`).
    ``stack_rule``: the stack rule ``net`` was trained with (``data.stack_rule``), which
    the int8 calibration and the quality check's inputs follow; ``calibrate``: what makes
    those inputs (``openvino-int8`` needs it, ``auto`` uses bf16 only with it; called only
    when the int8 graph is exported or an engine is first checked). The engine's ``why``
    says why it was chosen.

    Raises:
        ValueError: ``openvino-bf16`` asked for on a CPU without bf16 units.
    """
    chosen = choose(engine, device)
    if engine != "auto":
        if chosen == "openvino-bf16" and not bf16_units():
            raise ValueError("engine openvino-bf16: this CPU has no bfloat16 units (AMX or "
                             "AVX512-BF16); use openvino")
        return TorchEngine(net) if chosen == "torch" else \
            _compiled(chosen, net, sensor_hw, cache, stack_rule, calibrate)
    if device.type != "cpu":
        return TorchEngine(net, "auto: eager torch on a GPU")
    fast, why = _checked_bf16(net, sensor_hw, cache, stack_rule, calibrate)
    if fast is not None:
        return fast
    if chosen == "torch":
        return TorchEngine(net, why + "; no float32 engine is installed")
    try:
        return _compiled(chosen, net, sensor_hw, cache, stack_rule, why=why)
    except Exception as exc:
        log.warning("engine %s failed (%s: %s); using torch", chosen, type(exc).__name__, exc)
        return TorchEngine(net, f"{why}; {chosen} failed ({type(exc).__name__}: {exc})")


def _checked_bf16(net: E2SRI, sensor_hw: tuple[int, int] | None, cache: Path | None,
                  stack_rule: str, calibrate: quantize.CalibrationSource | None
                  ) -> tuple[OpenVinoEngine | None, str]:
    """``auto``'s bf16 engine when bf16 is OpenVINO's native precision here and the network
    passed its quality check in it (else None), and why."""
    if not installed("openvino"):
        return None, "auto: OpenVINO is not installed"
    if native_precision() != "bf16":
        return None, "auto: float32 (bfloat16 is not OpenVINO's native precision on this CPU)"
    if calibrate is None:
        return None, "auto: no source of inputs to check bf16 with; float32"
    check = quality.DEFAULT_CHECK.for_stack_rule(stack_rule)
    threads = torch.get_num_threads()
    try:
        path = _export("openvino", net, cache, stack_rule, calibrate)
        result = quality.checked(
            path, "openvino-bf16",
            lambda: OpenVinoEngine(path, threads, name="openvino-bf16", precision="bf16"),
            net, functools.partial(calibrate, net, check.inputs), check)
        if not result.passed:
            return None, f"auto: bf16 failed its quality check, {result.describe()}; float32"
        return _compiled("openvino-bf16", net, sensor_hw, cache, stack_rule, calibrate,
                         f"auto: bf16 (this CPU's native precision) passed its quality "
                         f"check, {result.describe()}"), ""
    except Exception as exc:
        log.warning("engine openvino-bf16 failed (%s: %s); using float32",
                    type(exc).__name__, exc)
        return None, f"auto: bf16 failed to compile or check ({type(exc).__name__}: {exc})"


def _export(engine: str, net: E2SRI, cache: Path | None, stack_rule: str,
            calibrate: quantize.CalibrationSource | None, rebuild: bool = False) -> Path:
    """The cached file of ``net`` for ``engine``, exported when absent (or ``rebuild``);
    ``openvino-bf16`` runs ``openvino``'s float32 file."""
    engine = "openvino" if engine == "openvino-bf16" else engine
    suffix, export = _EXPORTS[engine]
    calibration = replace(quantize.DEFAULT_CALIBRATION, stack_rule=stack_rule)
    key = CacheKey(weights_digest(net, checkpoint.net_args(net)), engine,
                   _engine_version(engine, calibration), suffix)
    if engine == "openvino-int8":
        if calibrate is None:
            raise ValueError("engine openvino-int8 needs calibration inputs: pass calibrate "
                             "(e.g. model.calibration.simulated_inputs)")
        build = functools.partial(export, net,
                                  inputs=functools.partial(calibrate, net, calibration))
    else:
        build = functools.partial(export, net)
    return cached_file(key, build, cache, rebuild)


def _compiled(engine: str, net: E2SRI, sensor_hw: tuple[int, int] | None,
              cache: Path | None, stack_rule: str = "fixed",
              calibrate: quantize.CalibrationSource | None = None, why: str = "asked for"
              ) -> OnnxRuntimeEngine | OpenVinoEngine:
    threads = torch.get_num_threads()

    def make(path: Path) -> OnnxRuntimeEngine | OpenVinoEngine:
        if engine == "onnxruntime":
            return OnnxRuntimeEngine(path, threads, why)
        return OpenVinoEngine(path, threads, sensor_hw, engine, why,
                              "bf16" if engine == "openvino-bf16" else "f32")

    path = _export(engine, net, cache, stack_rule, calibrate)
    try:
        return make(path)
    except Exception as exc:  # an unreadable cache entry: export once more, then give up
        log.warning("%s: cannot be loaded (%s); exporting again", path, exc)
        return make(_export(engine, net, cache, stack_rule, calibrate, rebuild=True))


def _engine_version(engine: str, calibration: quantize.Calibration) -> str:
    """What the cached file of ``engine`` depends on besides the weights: the versions of
    its packages (and, for int8, the calibration recipe)."""
    graph = f"g{graph_export.GRAPH_VERSION}"
    if engine == "openvino-int8":
        return f"{version('openvino')}+nncf{version('nncf')}+{calibration.tag}+{graph}"
    return f"{version(engine)}+{graph}"


_EXPORTS = {"onnxruntime": (".onnx", graph_export.export_onnx),
            "openvino": (".npz", graph_export.export_openvino),
            "openvino-int8": (".npz", quantize.export_openvino_int8)}
"""Each compiled engine's cache file suffix and exporter."""
