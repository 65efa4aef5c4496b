"""The model tests' tiny checkpoint (made once per test session) and config; the tiny
simulated dataset (``tiny_shards``) comes from tests/conftest.py."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from esim_lite.core.dataconf import load_config
from model.config import TrainConfig

ROOT = Path(__file__).resolve().parents[2]


def bench_module(name: str):
    """The script ``bench/<name>.py`` imported as a module (bench/ is not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "bench" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session", autouse=True)
def engine_cache(tmp_path_factory) -> Iterator[Path]:
    """Networks exported for ONNX Runtime / OpenVINO (``reconstruct --engine auto``) go to a
    temporary cache, never the user's ~/.cache/e2sr."""
    from model.inference.graph_cache import CACHE_ENV

    path = tmp_path_factory.mktemp("e2sr_cache")
    before = os.environ.get(CACHE_ENV)
    os.environ[CACHE_ENV] = str(path)
    yield path
    if before is None:
        os.environ.pop(CACHE_ENV, None)
    else:
        os.environ[CACHE_ENV] = before


SMALL_CALIBRATION = dict(sequences=1, frames=10, samples=8, seed=5)
"""The int8 calibration every test export uses (test_int8.py's ``SMALL``): seconds, not a
minute."""
SMALL_CHECK_INPUTS = dict(sequences=1, frames=10, samples=4, seed=6)
"""The int8 quality check's held-out inputs in tests (another seed than the calibration)."""


@pytest.fixture(scope="session", autouse=True)
def small_int8_recipes() -> Iterator[None]:
    """``reconstruct``/``evaluate`` default to ``--engine auto``, which on a CPU exports,
    calibrates and checks int8: in tests on :data:`SMALL_CALIBRATION` and
    :data:`SMALL_CHECK_INPUTS` (the real recipes cost a minute per model)."""
    from model.inference import quality, quantize

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(quantize, "DEFAULT_CALIBRATION", quantize.Calibration(**SMALL_CALIBRATION))
        mp.setattr(quality, "DEFAULT_CHECK", quality.QualityCheck(
            quantize.Calibration(**SMALL_CHECK_INPUTS)))
        yield


def tiny_config(*overrides: str):
    return load_config(TrainConfig, ROOT / "configs" / "train_tiny.yaml", overrides)


@pytest.fixture(scope="session")
def tiny_checkpoint(tiny_shards, tmp_path_factory) -> Path:
    """A tiny model trained for a few steps (for pipelines, not quality)."""
    from model.training.train import train

    out = tmp_path_factory.mktemp("tiny_run")
    train(tiny_config("run.max_steps=3"), tiny_shards, out, show_progress=False)
    return out / "last.pt"
