"""The quality check of a reduced-precision engine: does it reproduce the float32 network
closely enough for ``--engine auto`` to use it?

The check runs the candidate engine (``openvino-bf16``; the function takes any) and the
float32 network (eager torch, the reference) on held-out simulated inputs and scores the
candidate's output against float32's by PSNR (dB, both clamped to [0, 1], one value per
input); it passes when the *minimum* over the inputs is at least
:attr:`QualityCheck.threshold_db` (35 dB: issue 50's bar for ``auto``'s outputs against
torch's). The inputs follow the int8 calibration recipe
(:class:`model.inference.quantize.Calibration`: a few short sequences of the default
dataset recipe on training textures) with another seed; they are made by the caller's
:data:`~model.inference.quantize.CalibrationSource` (running a model never simulates).

The result is written as JSON beside the cached export the engine runs
(:func:`record_path`, named by the engine), once per export, engine and check recipe,
atomically; a later ``auto`` reads it instead of checking again.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from esim_lite.core.atomic import write_text
from model.inference import graph_export, quantize

log = logging.getLogger(__name__)

CHECK_VERSION = 2
"""Raised when what the check measures changes (it is part of the record's name).
2: the record names the engine checked."""


@dataclass(frozen=True)
class QualityCheck:
    """What a reduced-precision engine is checked on and the bar it must clear.

    Attributes:
        inputs: the held-out inputs' recipe (a seed other than the calibration's).
        threshold_db: the least PSNR (dB) of any input, the candidate against float32.
    """

    inputs: quantize.Calibration = quantize.Calibration(sequences=2, frames=24, samples=16,
                                                        seed=20_251_207)
    threshold_db: float = 35.0

    def for_stack_rule(self, stack_rule: str) -> QualityCheck:
        """The same check on stacks sized as the model was trained (``data.stack_rule``)."""
        return replace(self, inputs=replace(self.inputs, stack_rule=stack_rule))

    @property
    def tag(self) -> str:
        """What a record's file name carries of this check."""
        return f"check{CHECK_VERSION}_{self.inputs.tag}_{self.threshold_db:g}dB"


DEFAULT_CHECK = QualityCheck()
"""The check an engine gets before ``auto`` may use it (tests swap in a smaller one)."""


@dataclass(frozen=True)
class CheckResult:
    """One check's outcome: per-input PSNR (dB) of the candidate against float32, its minimum and
    mean, the threshold, whether the minimum cleared it, and the inputs' recipe tag."""

    passed: bool
    min_db: float
    mean_db: float
    psnr_db: tuple[float, ...]
    threshold_db: float
    recipe: str

    def describe(self) -> str:
        """``min 41.2 dB >= 35 dB vs float32 on 16 simulated inputs`` (or ``<``)."""
        sign = ">=" if self.passed else "<"
        return (f"min {self.min_db:.1f} dB {sign} {self.threshold_db:g} dB vs float32 on "
                f"{len(self.psnr_db)} simulated inputs, mean {self.mean_db:.1f} dB")


def psnr_db(got: torch.Tensor, want: torch.Tensor) -> float:
    """PSNR (dB, peak 1) of ``got`` against ``want``, both clamped to [0, 1]; identical
    images give 100 dB (a finite number for the JSON record)."""
    mse = float(((got.clamp(0, 1) - want.clamp(0, 1)).double() ** 2).mean())
    return 100.0 if mse <= 1e-10 else -10.0 * math.log10(mse)


def run_check(candidate, reference, inputs: quantize.Inputs, check: QualityCheck
              ) -> CheckResult:
    """Score ``candidate``'s outputs against ``reference``'s (both called as the network:
    ``(stacks, central, flows) -> (1, 1, sH, sW)``) on ``inputs`` (network inputs, batch 1)."""
    if not inputs:
        raise ValueError("the quality check got no inputs")
    scores = []
    with torch.inference_mode():
        for d in inputs:
            x = [torch.from_numpy(np.ascontiguousarray(d[k])) for k in graph_export.INPUT_NAMES]
            scores.append(round(psnr_db(candidate(*x), reference(*x)), 3))
    low = min(scores)
    return CheckResult(low >= check.threshold_db, low, round(float(np.mean(scores)), 3),
                       tuple(scores), check.threshold_db, check.inputs.tag)


def record_path(export: Path, engine: str, check: QualityCheck) -> Path:
    """Where the check of ``engine`` running the cached export ``export`` is recorded:
    beside it."""
    return export.with_name(f"{export.name}.{engine}.{check.tag}.json")


def read_record(path: Path) -> CheckResult | None:
    """The result recorded at ``path``; None when there is none (or it cannot be read)."""
    try:
        data = json.loads(path.read_text())
        return CheckResult(**{**data, "psnr_db": tuple(data["psnr_db"])})
    except FileNotFoundError:
        return None
    except (ValueError, TypeError, KeyError) as exc:
        log.warning("%s: unreadable quality check record (%s); checking again", path, exc)
        return None


def checked(export: Path, engine: str, make_candidate, reference, make_inputs,
            check: QualityCheck) -> CheckResult:
    """The check of ``engine`` running the cached export ``export``: read from its record,
    else run (``make_candidate()`` against ``reference`` on ``make_inputs()``, both called
    only then) and recorded atomically."""
    path = record_path(export, engine, check)
    result = read_record(path)
    if result is None:
        log.info("checking %s against float32 (%s)", engine, check.tag)
        inputs = list(make_inputs())
        result = run_check(make_candidate(), reference, inputs, check)
        write_text(path, json.dumps(asdict(result), indent=1) + "\n")
    return result
