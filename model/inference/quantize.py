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
trained with, and DIS flow).

INT8 changes the outputs (unlike the float32 engines, which match torch within 1e-6): it is
never chosen by ``--engine auto``, only when asked for. Its quality against float32 on the
simulated test split is measured in docs/benchmarks.md.
"""

from __future__ import annotations

import logging
import tempfile
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from model.archs.e2sri_arch import E2SRI, central_input
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


def calibration_inputs(net: E2SRI, calibration: Calibration | None = None
                       ) -> list[dict[str, np.ndarray]]:
    """Network inputs ``{"stacks", "central", "flows"}`` (batch 1, float32) for ``net``,
    simulated as the module doc says (``calibration``: default :data:`DEFAULT_CALIBRATION`)."""
    calibration = calibration or DEFAULT_CALIBRATION
    from datagen.config import DatagenConfig
    from datagen.generate import plan_shards, write_shard
    from esim_lite.core.dataconf import load_config
    from model.data.config import DataConfig
    from model.data.dataset import ShardSamples, index_samples

    cfg = net.config
    per_stack = 3000  # the training datasets' frame spacing: one stack per frame
    config = load_config(DatagenConfig, None, values={
        "simulation.camera.scales": [cfg.scale],
        "simulation.render.backend": "homography",
        "simulation.frames.count": calibration.frames,
        "simulation.frames.every_events": per_stack,
        "simulation.frames.tail_events": per_stack * (cfg.n_stacks // 2 + 1),
        "textures.split": "train",
        "sequences_per_shard": calibration.sequences})
    data = DataConfig(crop=None, val_fraction=0.0, flow="dis",
                      stack_rule=calibration.stack_rule)
    with tempfile.TemporaryDirectory(prefix="e2sr-calibration-") as tmp:
        plan = plan_shards(Path(tmp), calibration.sequences, calibration.sequences)[0]
        write_shard(plan, config, calibration.seed, render_threads=1)
        refs, _ = index_samples([plan.path], data, cfg.n_stacks, cfg.scale)
        if not refs:
            raise RuntimeError("the calibration sequences gave no samples")
        pick = np.unique(np.linspace(0, len(refs) - 1, min(calibration.samples, len(refs)))
                         .round().astype(int))
        dataset = ShardSamples([refs[i] for i in pick], data, cfg.n_stacks, cfg.scale,
                               train=False)
        items = [dataset[i] for i in range(len(dataset))]
    # a Duo-Pass model is calibrated on the LR frame in its first pass's place (same range)
    as_net = cfg if cfg.central != "first_pass" else replace(cfg, central="aps")
    out = []
    for item in items:
        batch = {k: v[None] for k, v in item.items()}
        central = central_input(as_net, batch["stacks"], batch["flows"], batch["lr"], None)
        out.append({"stacks": batch["stacks"].numpy(),
                    "central": np.ascontiguousarray(central.numpy()),
                    "flows": batch["flows"].numpy()})
    return out


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


def quantize_openvino(net: E2SRI, calibration: Calibration | None = None):
    """``net`` as an int8 OpenVINO model (``openvino.Model``), calibrated as above."""
    import nncf
    import openvino as ov

    with tempfile.TemporaryDirectory() as tmp:
        fp32 = Path(tmp) / "fp32.npz"
        graph_export.export_openvino(net, fp32)
        model = graph_export.read_openvino(fp32, ov.Core())
    inputs = calibration_inputs(net, calibration)
    names = [next(n for n in graph_export.INPUT_NAMES if n in p.get_names())
             for p in model.inputs]
    dataset = nncf.Dataset(inputs, lambda d: [d[n] for n in names])
    log.info("quantising the network to int8 on %d simulated inputs", len(inputs))
    nncf.set_log_level(logging.ERROR)  # its per-layer notes and progress bars
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return nncf.quantize(model, dataset, subset_size=len(inputs),
                             preset=nncf.QuantizationPreset.MIXED,
                             ignored_scope=nncf.IgnoredScope(names=kept_in_float(model),
                                                             validate=False))


def export_openvino_int8(net: E2SRI, path: Path, calibration: Calibration | None = None
                         ) -> None:
    """Write the int8 model packed as :func:`graph_export.export_openvino` packs (``.npz``)."""
    graph_export.save_openvino(quantize_openvino(net, calibration), path)
