"""INT8 post-training quantisation of the network for OpenVINO (``--engine openvino-int8``).

The float32 OpenVINO graph (:func:`model.inference.graph_export.export_openvino`) is
quantised by NNCF: its convolutions' weights per output channel, their inputs per tensor,
with ranges measured on calibration inputs. What stays float32, because it costs little
and carries most of the rounding error (measured on held-out training samples, see
docs/benchmarks.md):
- the first convolution on each input (stacks and flows are narrow, signed and
  heavy-tailed: 8 bits over the flow range would be coarse), and
- the last convolution (the image itself: its rounding lands directly on the output; at
  the output resolution, narrow, so it costs little). The sub-pixel lift before it is
  quantised: it is 2 (x2) to 8 (x4) times an LR convolution's work, and keeping it in
  float32 cost x4 more time than it saved in quality (docs/benchmarks.md).

Calibration inputs come from the simulator, not from the data the user reconstructs, so one
quantised graph serves every recording and is exported once per weights (the cache:
:mod:`model.inference.graph_cache`): a few short sequences of the default dataset recipe on
the *training* half of its textures (the held-out test textures are never seen), rendered
by the homography renderer, turned into network inputs exactly as training does
(:class:`model.data.dataset.ShardSamples`: SBN stacks sized by the stack rule the model was
trained with, and DIS flow). Running a model never simulates, so this module only names the
recipe (:class:`Calibration`); the inputs are made above ``inference/``
(:func:`model.calibration.simulated_inputs`) and handed in as a :data:`CalibrationSource`,
called only when an export is made.

INT8 changes the outputs (unlike the float32 engines, which match torch within 1e-6):
``--engine auto`` uses it only when it passed its quality check against float32
(:mod:`model.inference.quality`). Its quality against float32 on the simulated test split is
measured in docs/benchmarks.md.
"""

from __future__ import annotations

import logging
import tempfile
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model.archs.e2sri_arch import E2SRI
from model.inference import graph_export

log = logging.getLogger(__name__)

CALIBRATION_VERSION = 3
"""Raised when the calibration recipe or what stays float32 changes (it is part of the cache
key). 2: the lift is quantised too. 3: the calibration stacks follow the model's training
stack rule (``Calibration.stack_rule``)."""


@dataclass(frozen=True)
class Calibration:
    """How many calibration inputs, from how many simulated sequences.

    Attributes:
        sequences: simulated sequences (default recipe, training textures).
        frames: frames per sequence (one sample per frame whose stacks fit).
        samples: calibration inputs used, spread evenly over all the samples.
        seed: the simulation seed.
        stack_rule: how the calibration inputs' SBN stacks are sized, as the model was
            trained (``data.stack_rule``: ``fixed`` or ``active``). A model trained on
            active-pixel stacks calibrated on fixed ones lost 0.2 dB (docs/benchmarks.md).
    """

    sequences: int = 4
    frames: int = 24
    samples: int = 64
    seed: int = 20_251_203
    stack_rule: str = "fixed"

    def __post_init__(self) -> None:
        if min(self.sequences, self.frames, self.samples) < 1:
            raise ValueError("calibration needs at least one sequence, frame and sample")
        if self.stack_rule not in ("fixed", "active"):
            raise ValueError(f"calibration stack_rule must be fixed or active, got "
                             f"{self.stack_rule!r}")

    @property
    def tag(self) -> str:
        """What the cache key carries of this recipe."""
        return (f"cal{CALIBRATION_VERSION}_{self.sequences}x{self.frames}_{self.samples}"
                f"_{self.seed}_{self.stack_rule}")


DEFAULT_CALIBRATION = Calibration()
"""The recipe every int8 export uses (tests swap in a smaller one)."""

Inputs = Sequence[dict[str, np.ndarray]]
"""Calibration inputs: network inputs ``{"stacks", "central", "flows"}`` (batch 1, float32)."""

CalibrationSource = Callable[[E2SRI, Calibration], Inputs]
"""Makes a network's calibration inputs by a recipe: :func:`model.calibration.simulated_inputs`
(which simulates, so it lives above ``inference/``)."""


def kept_in_float(model) -> list[str]:
    """Names of the convolutions of an OpenVINO graph left in float32: every convolution
    with no convolution upstream (the first on each input) and the last in topological
    order (the image)."""
    convs = {"Convolution", "GroupConvolution", "ConvolutionBackpropData"}
    after_conv: dict[str, bool] = {}  # op name -> a convolution lies on some path into it
    ordered = []
    for op in model.get_ordered_ops():
        ups = [v.get_node() for v in op.input_values()]
        seen = any(after_conv.get(u.get_friendly_name(), False) or u.get_type_name() in convs
                   for u in ups)
        after_conv[op.get_friendly_name()] = seen
        if op.get_type_name() in convs:
            ordered.append((op.get_friendly_name(), seen))
    first = [name for name, seen in ordered if not seen]
    last = [name for name, _ in ordered[-1:]]
    return list(dict.fromkeys(first + last))


def quantize_openvino(net: E2SRI, inputs: Callable[[], Inputs]):
    """``net`` as an int8 OpenVINO model (``openvino.Model``), calibrated on ``inputs()``
    (called once, after the float32 export)."""
    import nncf
    import openvino as ov

    with tempfile.TemporaryDirectory() as tmp:
        fp32 = Path(tmp) / "fp32.npz"
        graph_export.export_openvino(net, fp32)
        model = graph_export.read_openvino(fp32, ov.Core())
    calibration = list(inputs())
    names = [next(n for n in graph_export.INPUT_NAMES if n in p.get_names())
             for p in model.inputs]
    dataset = nncf.Dataset(calibration, lambda d: [d[n] for n in names])
    log.info("quantising the network to int8 on %d calibration inputs", len(calibration))
    nncf.set_log_level(logging.ERROR)  # its per-layer notes and progress bars
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return nncf.quantize(model, dataset, subset_size=len(calibration),
                             preset=nncf.QuantizationPreset.MIXED,
                             ignored_scope=nncf.IgnoredScope(names=kept_in_float(model),
                                                             validate=False))


def export_openvino_int8(net: E2SRI, path: Path, inputs: Callable[[], Inputs]) -> None:
    """Write the int8 model, calibrated on ``inputs()``, packed as
    :func:`graph_export.export_openvino` packs (``.npz``)."""
    graph_export.save_openvino(quantize_openvino(net, inputs), path)
