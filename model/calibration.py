"""Int8 calibration inputs made by the simulator, for the quantiser of
:mod:`model.inference.quantize`.

This module stands above ``inference/``: it runs datagen's generator, which running a model
never does, and hands its inputs to the quantiser as a
:data:`~model.inference.quantize.CalibrationSource` (the CLI passes
:func:`simulated_inputs` as ``calibrate``). The recipe and why it is what it is:
:mod:`model.inference.quantize`.
"""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from model.archs.e2sri_arch import E2SRI, central_input
from model.inference import quantize


def simulated_inputs(net: E2SRI, calibration: quantize.Calibration | None = None
                     ) -> list[dict[str, np.ndarray]]:
    """Network inputs ``{"stacks", "central", "flows"}`` (batch 1, float32) for ``net``:
    a few short sequences of the default dataset recipe on the training textures, rendered
    by the homography renderer and turned into inputs as training does
    (``calibration``: default :data:`~model.inference.quantize.DEFAULT_CALIBRATION`)."""
    calibration = calibration or quantize.DEFAULT_CALIBRATION
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
