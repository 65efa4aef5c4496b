"""Event recordings in: every supported file format as one streaming, validated interface.

``open_recording(path)`` recognises:
- e2sr shards (``shard_*.h5``; a ``sequence`` picks one, default the first);
- event_utils / E2VID-style HDF5 (``events/xs, ys, ts, ps``; ``images/*`` with a
  ``timestamp`` attribute; ``sensor_resolution`` attribute);
- EVREAL's dataset folders (``events_ts.npy``, ``events_xy.npy``, ``events_p.npy``,
  ``images.npy``, ``images_ts.npy``, ``metadata.json``);
- the Event Camera Dataset's text format (``events.txt``: ``t x y p`` in seconds and 0/1,
  with ``images.txt`` + ``images/`` when present), a file or its folder;
- AEDAT4 from iniVation cameras (events and APS frames) and Prophesee EVT2/EVT3 ``.raw``,
  both decoded by the maintained ``faery`` package.

Events come in chunks (:meth:`Recording.events`), so a file of any length is read with
bounded memory; every chunk is checked (time order across chunks, coordinates inside the
sensor, polarity) and a bad file fails with its path and the problem. APS frames, small by
nature, are loaded whole as linear intensity in [0, 1]. Each format is one module of
:mod:`datagen.formats`; this one only picks.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from datagen.formats.base import Recording
from datagen.formats.ecd_text import open_text
from datagen.formats.event_utils import open_event_hdf5
from datagen.formats.evreal import is_evreal, open_evreal
from datagen.formats.faery_formats import open_aedat4, open_raw
from datagen.formats.shard import open_shard

__all__ = ["Recording", "open_recording", "tonic_events"]


def open_recording(path: str | Path, sensor_hw: tuple[int, int] | None = None,
                   sequence: str | None = None) -> Recording:
    """Open ``path`` (format from its content/name); ``sensor_hw`` overrides the file's."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    if is_evreal(path):
        return open_evreal(path, sensor_hw)
    if path.is_dir() or path.suffix == ".txt":
        return open_text(path, sensor_hw)
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5", ".hdf"):
        try:
            with h5py.File(path, "r") as f:
                is_shard = "schema_version" in f.attrs
        except OSError as exc:
            raise ValueError(f"{path}: not a readable HDF5 file ({exc})") from exc
        if is_shard:
            return open_shard(path, sequence, sensor_hw)
        return open_event_hdf5(path, sensor_hw)
    if suffix == ".aedat4":
        return open_aedat4(path, sensor_hw)
    if suffix == ".raw":
        return open_raw(path, sensor_hw)
    raise ValueError(f"{path}: unknown event file type {suffix!r} (expected .h5, .txt, "
                     f".aedat4, .raw or an ECD folder)")


def tonic_events(path: str | Path, sensor_hw: tuple[int, int] | None = None,
                 sequence: str | None = None) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Every event of any recording ``open_recording`` reads (a shard's ``sequence``
    included) as tonic's structured array and ``sensor_size`` (see ``Events.to_tonic``)."""
    return open_recording(path, sensor_hw, sequence).read_all().to_tonic()
