"""EVREAL's dataset folders (the events-to-video benchmark's ``.npy`` layout): ``events_ts``
(float64 seconds), ``events_xy`` ([N, 2] int16, x then y), ``events_p`` (0/1),
``images`` (uint8 [T, H, W, 1] or [T, H, W]), ``images_ts`` ([T, 1] seconds) and
``metadata.json`` with ``sensor_resolution`` [H, W]. Events are memory-mapped, so a
recording of any length streams in chunks."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from datagen.formats.base import (
    Recording,
    check_field_dtype,
    checked_events,
    gray_image,
    sorted_frames,
)
from esim_lite.core.events import Events

FILES = ("events_ts.npy", "events_xy.npy", "events_p.npy")


def is_evreal(folder: Path) -> bool:
    return folder.is_dir() and all((folder / f).is_file() for f in FILES)


def _sensor(folder: Path) -> tuple[int, int] | None:
    meta = folder / "metadata.json"
    if not meta.is_file():
        return None
    try:
        res = json.loads(meta.read_text()).get("sensor_resolution")
    except (json.JSONDecodeError, AttributeError) as exc:
        raise ValueError(f"{meta}: not a JSON object ({exc})") from exc
    if res is None:
        return None
    if len(res) < 2:
        raise ValueError(f"{meta}: sensor_resolution {res} is not [H, W]")
    return int(res[0]), int(res[1])


def open_evreal(folder: Path, sensor_hw: tuple[int, int] | None) -> Recording:
    try:
        ts = np.load(folder / "events_ts.npy", mmap_mode="r")
        xy = np.load(folder / "events_xy.npy", mmap_mode="r")
        p = np.load(folder / "events_p.npy", mmap_mode="r")
    except ValueError as exc:
        raise ValueError(f"{folder}: unreadable EVREAL event arrays ({exc})") from exc
    n = ts.shape[0]
    if xy.ndim != 2 or xy.shape != (n, 2) or p.reshape(-1).shape[0] != n:
        raise ValueError(f"{folder}: events_ts {ts.shape}, events_xy {xy.shape} and events_p "
                         f"{p.shape} do not describe the same {n} events ([N], [N, 2], [N])")
    for name, arr, role in (("events_ts.npy", ts, "t"), ("events_xy.npy", xy, "x"),
                            ("events_p.npy", p, "p")):
        check_field_dtype(folder, name, arr.dtype, role)
    frames = None
    if (folder / "images.npy").is_file() and (folder / "images_ts.npy").is_file():
        images = np.load(folder / "images.npy")
        times = np.load(folder / "images_ts.npy").reshape(-1)
        if len(images) != len(times):
            raise ValueError(f"{folder}: {len(images)} images but {len(times)} images_ts")
        frames = sorted_frames([gray_image(im) for im in images],
                               [int(round(float(t) * 1e9)) for t in times], folder)
    hw = sensor_hw or _sensor(folder) or (frames.hw if frames is not None else None)
    if hw is None:
        raise ValueError(f"{folder}: no metadata.json sensor_resolution and no images; "
                         "give the sensor size")

    def chunks(size: int) -> Iterator[Events]:
        for start in range(0, n, size):
            sl = slice(start, min(start + size, n))
            yield checked_events(xy[sl, 0], xy[sl, 1], np.round(ts[sl] * 1e9),
                                 p.reshape(-1)[sl], hw, folder, start)

    return Recording(folder, "evreal", hw, frames, chunks)
