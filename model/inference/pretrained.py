"""The models shipped inside the package: the default of ``reconstruct`` and ``evaluate``.

``model/weights/`` holds one file per scale, ``e2sr_x{scale}.pt``: a network checkpoint
reduced to what inference needs (half-precision weights, the network's constructor args, the
resolved training config, the sensor size) and ``manifest.json`` with each file's SHA-256,
size and provenance (training data, steps, CPU hours). :func:`shipped_checkpoint` checks the
digest before anything is unpickled, so a truncated or altered file is refused, not loaded.

:func:`export` turns a training checkpoint (``last.pt``) into a shipped file.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import torch

from esim_lite.core.atomic import atomic_path, write_text
from model import checkpoint

WEIGHTS = Path(__file__).resolve().parents[1] / "weights"
MANIFEST = "manifest.json"


def file_name(scale: int) -> str:
    return f"e2sr_x{scale}.pt"


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def manifest(folder: Path = WEIGHTS) -> dict[str, Any]:
    path = folder / MANIFEST
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc


def available_scales(folder: Path = WEIGHTS) -> list[int]:
    return sorted(int(v["scale"]) for v in manifest(folder).values())


def shipped_checkpoint(scale: int = 2, folder: Path = WEIGHTS) -> Path:
    """Path of the shipped model for ``scale``, after checking its SHA-256.

    Raises:
        FileNotFoundError: no model of that scale is shipped (the message lists those that
            are), or its file is missing.
        ValueError: the file's digest differs from the manifest's (damaged or replaced).
    """
    entry = manifest(folder).get(file_name(scale))
    if entry is None:
        have = ", ".join(f"x{s}" for s in available_scales(folder)) or "none"
        raise FileNotFoundError(f"{folder}: no shipped x{scale} model (shipped: {have}); "
                                f"pass --checkpoint")
    path = folder / file_name(scale)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: shipped model listed in {MANIFEST} but missing")
    digest = sha256(path)
    if digest != entry["sha256"]:
        raise ValueError(f"{path}: SHA-256 {digest[:16]}... differs from {MANIFEST}'s "
                         f"{entry['sha256'][:16]}...: the file is damaged or was replaced")
    return path


def resolve(ckpt: str | Path | None, scale: int = 2) -> Path:
    """``ckpt`` itself, or the shipped model of ``scale`` when ``ckpt`` is None."""
    return Path(ckpt) if ckpt else shipped_checkpoint(scale)


def export(source: str | Path, scale: int | None = None, folder: Path = WEIGHTS,
           info: dict[str, Any] | None = None) -> Path:
    """Write ``source`` (a training checkpoint) as the shipped model of its scale.

    Weights are stored in float16 (the network computes in float32 after loading); the
    optimiser state is dropped. ``info`` (training data, steps, hours, metrics) goes into
    the manifest beside the digest. Both files are written atomically.
    """
    state = checkpoint.load(source)
    net = checkpoint.model_from(state, "cpu", str(source))
    s = net.config.scale
    if scale is not None and scale != s:
        raise ValueError(f"{source}: an x{s} model, not x{scale}")
    slim = {"model": {k: (v.half() if v.is_floating_point() else v)
                      for k, v in net.state_dict().items()},
            "config": state["config"], "net": state["net"], "sensor_hw": state["sensor_hw"],
            "step": state.get("step"), "train_seconds": state.get("train_seconds")}
    target = folder / file_name(s)
    with atomic_path(target) as tmp:
        torch.save(slim, tmp)
    entries = manifest(folder)
    entries[target.name] = {"scale": s, "sha256": sha256(target),
                            "bytes": target.stat().st_size, **(info or {})}
    write_text(folder / MANIFEST, json.dumps(entries, indent=2, sort_keys=True) + "\n")
    return target
