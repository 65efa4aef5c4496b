"""event_utils / E2VID-style HDF5: ``events/xs, ys, ts, ps``, ``images/*`` with a
``timestamp`` attribute, a ``sensor_resolution`` attribute."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np

from datagen.formats.base import (
    FrameBudget,
    Recording,
    check_field_dtype,
    checked_events,
    gray_image,
    seconds_to_ns,
    sorted_frames,
)
from esim_lite.core.events import Events

# event_utils' dataset names and the event field each holds
FIELDS = {"xs": "x", "ys": "y", "ts": "t", "ps": "p"}


def open_event_hdf5(path: Path, sensor_hw: tuple[int, int] | None) -> Recording:
    with h5py.File(path, "r") as f:
        if not all(f"events/{k}" in f for k in ("xs", "ys", "ts", "ps")):
            raise ValueError(f"{path}: no events/xs, ys, ts, ps datasets (not an event "
                             f"HDF5 file)")
        n = f["events/ts"].shape[0]
        if any(f[f"events/{k}"].shape[0] != n for k in ("xs", "ys", "ps")):
            raise ValueError(f"{path}: events/xs, ys, ts, ps have different lengths "
                             f"(truncated file?)")
        for name, role in FIELDS.items():
            check_field_dtype(path, f"events/{name}", f[f"events/{name}"].dtype, role)
        hw = sensor_hw or _sensor_of(f, path)
        images, times = _images(f, path)
    frames = sorted_frames(images, times, path)

    def chunks(size: int) -> Iterator[Events]:
        with h5py.File(path, "r") as f:
            ev = f["events"]
            for start in range(0, n, size):
                sl = slice(start, min(start + size, n))
                yield checked_events(ev["xs"][sl], ev["ys"][sl], np.round(ev["ts"][sl] * 1e9),
                                     ev["ps"][sl], hw, path, start)

    return Recording(path, "hdf5", hw, frames, chunks)


def _images(f: h5py.File, path: Path) -> tuple[list[np.ndarray], list[int]]:
    """The ``images/*`` datasets as gray frames and their times (ns), each dataset's shape
    checked against a :class:`FrameBudget` before it is read."""
    images, times, budget = [], [], FrameBudget(path)
    for name in sorted(f["images"]) if "images" in f else []:
        ds = f["images"][name]
        if not isinstance(ds, h5py.Dataset) or ds.ndim not in (2, 3):
            raise ValueError(f"{path}: images/{name} is not an image dataset")
        if "timestamp" not in ds.attrs:
            raise ValueError(f"{path}: images/{name} has no timestamp attribute")
        times.append(seconds_to_ns(ds.attrs["timestamp"], f"{path}: images/{name}"))
        budget.take(ds.shape, f"images/{name}")
        kind = ds.attrs.get("type", "")
        kind = kind.decode() if isinstance(kind, bytes) else str(kind)
        images.append(gray_image(ds[:], "bgr" if kind == "color_bgr" else "rgb"))
    return images, times


def _sensor_of(f: h5py.File, path: Path) -> tuple[int, int]:
    if "sensor_resolution" in f.attrs:
        try:
            res = [int(v) for v in np.ravel(f.attrs["sensor_resolution"])]
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{path}: sensor_resolution {f.attrs['sensor_resolution']!r} is "
                             f"not a list of whole numbers") from None
        # event_utils' converter stores a colour camera's image shape, (H, W, 3)
        if len(res) == 2 or (len(res) == 3 and res[2] in (1, 3, 4)):
            return res[0], res[1]
        raise ValueError(f"{path}: sensor_resolution {res} is not (H, W) or (H, W, channels)")
    if "images" in f and len(f["images"]):
        return tuple(f["images"][sorted(f["images"])[0]].shape[:2])
    raise ValueError(f"{path}: no sensor_resolution attribute; give the sensor size")
