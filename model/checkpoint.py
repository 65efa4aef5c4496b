"""Checkpoints that rebuild themselves, for training and inference alike: model, optimiser,
scheduler, progress, RNG states and the resolved config, written atomically (temporary name,
then rename)."""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import torch

from esim_lite.core.atomic import atomic_path
from esim_lite.core.dataconf import from_mapping, load_yaml_text, to_mapping
from model.archs.e2sri_arch import E2SRI, NetConfig
from model.config import TrainConfig

TRAINED_SENSOR_HW = (128, 128)
"""(H, W) of the paper's simulated event camera: what a checkpoint that does not record its
training sensor was trained on."""


def rng_state() -> dict[str, Any]:
    """Global RNG states (e2sr itself draws from explicit generators; this covers torch's
    default generator and anything else a user plugs in)."""
    state = {"torch": torch.get_rng_state(), "python": random.getstate()}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    random.setstate(state["python"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def save(path: str | Path, **payload: Any) -> Path:
    """``torch.save(payload)`` to ``path`` atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def load_any(path: str | Path) -> dict[str, Any]:
    """Any e2sr checkpoint (network or flow pre-training) as a dict."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # truncated or foreign file
        raise ValueError(f"{path}: not a readable checkpoint ({exc})") from exc
    if not isinstance(ckpt, dict) or "config" not in ckpt:
        raise ValueError(f"{path}: not an e2sr checkpoint (no config)")
    return ckpt


def load(path: str | Path) -> dict[str, Any]:
    """A network training checkpoint (model, optimiser, ... see model.training.train)."""
    ckpt = load_any(path)
    if "model" not in ckpt:
        raise ValueError(f"{path}: not a network checkpoint (no model)")
    return ckpt


def config_of(ckpt: dict[str, Any], source: str = "checkpoint") -> TrainConfig:
    return load_yaml_text(TrainConfig, ckpt["config"], source=source)


def model_from(ckpt: dict[str, Any], device: str | torch.device = "cpu",
               source: str = "checkpoint") -> E2SRI:
    """The network stored in a loaded checkpoint, in eval mode."""
    net = E2SRI(from_mapping(NetConfig, ckpt["net"], source=source))
    net.load_state_dict(ckpt["model"])
    return net.to(device).eval()


def load_model(path: str | Path, device: str | torch.device = "cpu") -> E2SRI:
    """The network stored in a checkpoint file, in eval mode."""
    return model_from(load(path), device, str(path))


def net_args(net: E2SRI) -> dict[str, Any]:
    return to_mapping(net.config)
