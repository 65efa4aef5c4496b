"""A tiny simulated dataset shared by the model tests (made once per test session)."""

from __future__ import annotations

from pathlib import Path

import pytest

from datagen.cli import load_config as load_datagen_config
from datagen.generate import generate
from model.cli import load_config

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def tiny_shards(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("tiny_shards")
    cfg = load_datagen_config(str(ROOT / "configs" / "datagen_tiny.yaml"), [])
    generate(cfg, out, n_seq=4, seed=11, show_progress=False)
    return out


def tiny_config(*overrides: str):
    return load_config(str(ROOT / "configs" / "train_tiny.yaml"), list(overrides))


@pytest.fixture(scope="session")
def tiny_checkpoint(tiny_shards, tmp_path_factory) -> Path:
    """A tiny model trained for a few steps (for pipelines, not quality)."""
    from model.training.train import train

    out = tmp_path_factory.mktemp("tiny_run")
    train(tiny_config("run.max_steps=3"), tiny_shards, out, show_progress=False)
    return out / "last.pt"
