"""Where exported networks are kept: one file per (weights, engine, versions), outside the
package, written once and reused by every later run.

The folder: ``$E2SR_CACHE_DIR`` when set, else ``$XDG_CACHE_HOME/e2sr``, else
``~/.cache/e2sr``; engine files go into its ``engines/`` subfolder. A file's name carries
everything its content depends on: the SHA-256 of the network's weights and constructor
arguments (:func:`weights_digest`), the engine and its version, the exporter's (torch)
version and :data:`FORMAT` (raised when the export code changes). Changed weights or an
upgraded engine therefore get a new file, and a file is never replaced by different
content. Files are written atomically (temporary name in the same folder, then rename): two
processes exporting the same network at once both write whole files and the last rename
wins; no process ever opens half a file. Deleting the folder is always safe.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from esim_lite.core.atomic import atomic_path

log = logging.getLogger(__name__)

CACHE_ENV = "E2SR_CACHE_DIR"
FORMAT = 1
"""Version of the export code: raising it makes every run export afresh."""


def cache_root() -> Path:
    """The e2sr cache folder (see the module doc); not created here."""
    given = os.environ.get(CACHE_ENV)
    if given:
        return Path(given).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "e2sr"


def weights_digest(net: nn.Module, config: dict[str, Any]) -> str:
    """SHA-256 (hex) of the constructor arguments ``config`` and every tensor of ``net``'s
    state dict (name, dtype, shape and bytes, in the state dict's order)."""
    h = hashlib.sha256(json.dumps(config, sort_keys=True).encode())
    for name, tensor in net.state_dict().items():
        t = tensor.detach().to("cpu").contiguous()
        h.update(f"{name}:{t.dtype}:{tuple(t.shape)};".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.+_]", "_", text)


@dataclass(frozen=True)
class CacheKey:
    """What an exported file depends on; ``suffix`` is its extension (``.onnx``)."""

    weights_sha256: str
    engine: str
    engine_version: str
    suffix: str
    exporter_version: str = torch.__version__

    @property
    def file_name(self) -> str:
        return (f"e2sri-{self.weights_sha256}-{self.engine}-{_safe(self.engine_version)}"
                f"-torch-{_safe(self.exporter_version)}-f{FORMAT}{self.suffix}")


def cached_file(key: CacheKey, build: Callable[[Path], None], root: Path | None = None,
                rebuild: bool = False) -> Path:
    """The cached file for ``key``: reused when present (unless ``rebuild``), else made by
    ``build(temporary_path)`` and renamed into place."""
    path = (root or cache_root()) / "engines" / key.file_name
    if path.is_file() and not rebuild:
        return path
    log.info("exporting the network for %s into %s", key.engine, path)
    with atomic_path(path, ".tmp") as tmp:
        build(tmp)
    return path
