"""Checkpoints that rebuild themselves, for training and inference alike: model, optimiser,
scheduler, progress, RNG states and the resolved config, written atomically (temporary name,
then rename).

A checkpoint is data, not code. Every read goes through :func:`load_any`, which unpickles with
``torch.load(..., weights_only=True)``: tensors, numbers, strings, None and plain containers
(dict, list, tuple, OrderedDict) are rebuilt, and any other global a pickle names is refused
before it is called, so a file from a download link or an email cannot run code when it is
loaded. Everything e2sr writes fits that: configs are YAML text, the network's constructor
arguments a plain mapping, RNG states a tensor and Python's state tuple of ints.
:func:`convert_trusted` rewrites an older or foreign file that needs more, once, for a user who
trusts where it came from (``convert-checkpoint SRC OUT --trust``); nothing else ever loads a
checkpoint the unsafe way.
"""

from __future__ import annotations

import random
import re
from collections import OrderedDict
from pathlib import Path
from typing import Any

import torch
import yaml

from esim_lite.core.atomic import atomic_path
from esim_lite.core.dataconf import from_mapping, load_yaml_text, to_mapping
from model.archs.e2sri_arch import E2SRI, NetConfig
from model.config import TrainConfig, without_retired

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


class UnsafeCheckpointError(ValueError):
    """A checkpoint whose pickle asks for more than tensors and plain containers."""


def convert_command(path: str | Path) -> str:
    return f"convert-checkpoint {path} CONVERTED.pt --trust"


def _refusal(path: Path, exc: Exception) -> UnsafeCheckpointError | None:
    """The refusal of a weights-only load that met a global it does not rebuild (None for
    any other failure: a damaged or foreign file)."""
    named = re.search(r"GLOBAL ([\w.]+)", str(exc))
    if named is None:
        return None
    return UnsafeCheckpointError(
        f"{path}: refused: its pickle calls {named.group(1)}, which loading a checkpoint never "
        f"runs (it could execute code). If you trust where this file came from, convert it "
        f"once with `{convert_command(path)}` and load the converted file (docs/training.md, "
        f"'Checkpoints')")


def _reason(exc: Exception) -> str:
    """The line of torch's message that says what was wrong, without its advice."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    useful = [ln for ln in lines if not ln.startswith(("Weights only load failed", "Check the "
                                                       "documentation", "Please file"))]
    return (useful or lines or [type(exc).__name__])[0]


def _read(path: Path, trusted: bool = False) -> Any:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint")
    try:
        return torch.load(path, map_location="cpu", weights_only=not trusted)
    except Exception as exc:  # a refused global, or a truncated or foreign file
        refusal = None if trusted else _refusal(path, exc)
        if refusal is not None:
            raise refusal from None
        raise ValueError(f"{path}: not a readable checkpoint ({_reason(exc)})") from None


def load_any(path: str | Path) -> dict[str, Any]:
    """Any e2sr checkpoint (network or flow pre-training) as a dict, read as data only.

    Raises:
        FileNotFoundError: no such file.
        UnsafeCheckpointError: its pickle names a global beyond tensors and plain containers
            (nothing of it is run; the message gives the conversion command).
        ValueError: not a readable checkpoint, or not one of e2sr's.
    """
    path = Path(path)
    ckpt = _read(path)
    if not isinstance(ckpt, dict) or "config" not in ckpt:
        raise ValueError(f"{path}: not an e2sr checkpoint (no config)")
    return ckpt


def _plain(value: Any) -> Any:
    """``value`` with numpy arrays and scalars, paths and attribute bags (argparse's
    Namespace) made tensors and plain Python values: what a weights-only load rebuilds."""
    import numpy as np

    if isinstance(value, np.generic):  # before float: numpy's float64 is one
        return value.item()
    if value is None or isinstance(value, (torch.Tensor, bool, int, float, str, bytes)):
        return value
    if isinstance(value, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(value))
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, dict):
        kind = OrderedDict if isinstance(value, OrderedDict) else dict
        return kind((k, _plain(v)) for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return (tuple if isinstance(value, tuple) else list)(_plain(v) for v in value)
    if hasattr(value, "__dict__") and not callable(value):
        return {k: _plain(v) for k, v in vars(value).items()}
    raise ValueError(f"a {type(value).__module__}.{type(value).__qualname__} has no plain "
                     f"form")


def convert_trusted(source: str | Path, target: str | Path) -> Path:
    """Rewrite ``source``, a checkpoint the user trusts, so that a weights-only load reads it.

    This is the one place that unpickles without ``weights_only``: it runs whatever the file's
    pickle names, so it is only ever called on the user's explicit request. Numpy arrays and
    scalars become tensors and numbers, paths strings; the result is checked to load as data
    before it is renamed into place.

    Raises:
        FileExistsError: ``target`` exists (it is never overwritten).
        ValueError: ``source`` is unreadable, not an e2sr checkpoint, or holds objects that
            have no plain form.
    """
    source, target = Path(source), Path(target)
    if target.exists() or target.resolve() == source.resolve():
        raise FileExistsError(f"{target}: exists; give a new file name for the converted "
                              f"checkpoint")
    ckpt = _read(source, trusted=True)
    if not isinstance(ckpt, dict) or "config" not in ckpt:
        raise ValueError(f"{source}: not an e2sr checkpoint (no config)")
    try:
        plain = _plain(ckpt)
    except ValueError as exc:
        raise ValueError(f"{source}: cannot convert: {exc}") from None
    with atomic_path(target) as tmp:
        torch.save(plain, tmp)
        _read(Path(tmp))  # reads back as data, or the temporary file is dropped
    return target


def load(path: str | Path) -> dict[str, Any]:
    """A network training checkpoint (model, optimiser, ... see model.training.train)."""
    ckpt = load_any(path)
    if "model" not in ckpt:
        raise ValueError(f"{path}: not a network checkpoint (no model)")
    return ckpt


def config_of(ckpt: dict[str, Any], source: str = "checkpoint") -> TrainConfig:
    """The resolved training config a checkpoint stores (settings of removed experiments
    at their neutral values dropped: :func:`model.config.without_retired`)."""
    text = ckpt["config"]
    try:
        data = yaml.safe_load(text) if isinstance(text, str) else None
    except yaml.YAMLError:
        data = None
    if not isinstance(data, dict):
        return load_yaml_text(TrainConfig, text, source=source)  # its own clear error
    return from_mapping(TrainConfig, without_retired(data, source), source=source)


def net_config(ckpt: dict[str, Any], source: str = "checkpoint") -> NetConfig:
    """The network's constructor arguments a checkpoint stores."""
    net = ckpt.get("net")
    if not isinstance(net, dict):
        raise ValueError(f"{source}: not a network checkpoint (no network arguments)")
    return from_mapping(NetConfig, without_retired(net, source, "model."), source=source)


def model_from(ckpt: dict[str, Any], device: str | torch.device = "cpu",
               source: str = "checkpoint") -> E2SRI:
    """The network stored in a loaded checkpoint, in eval mode."""
    net = E2SRI(net_config(ckpt, source))
    try:
        net.load_state_dict(ckpt["model"])
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise ValueError(f"{source}: its weights do not fit the network it describes "
                         f"({str(exc).splitlines()[0]})") from None
    return net.to(device).eval()


def load_model(path: str | Path, device: str | torch.device = "cpu") -> E2SRI:
    """The network stored in a checkpoint file, in eval mode."""
    return model_from(load(path), device, str(path))


def net_args(net: E2SRI) -> dict[str, Any]:
    return to_mapping(net.config)
