"""AEDAT4 (iniVation: events and APS frames) and Prophesee EVT2/EVT3 ``.raw``, decoded by
the maintained ``faery`` package."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from datagen.formats.base import (
    Recording,
    checked_events,
    gray_image,
    sorted_exposures,
    sorted_frames,
)
from esim_lite.core.events import Events


def _faery(path: Path):
    try:
        import faery
    except ImportError as exc:  # pragma: no cover - faery is a dependency
        raise ValueError(f"{path}: reading this format needs the 'faery' package") from exc
    return faery


def open_aedat4(path: Path, sensor_hw: tuple[int, int] | None) -> Recording:
    """Events and APS frames; each frame's exposure window (its ``exposure_start_t`` and
    ``exposure_end_t``) is kept in ``Recording.exposures_ns`` (None when a frame lacks it)."""
    faery = _faery(path)
    try:
        with faery.aedat.Decoder(path) as dec:
            tracks = dec.tracks()
            ev_tracks = [t for t in tracks if t.data_type == "events"]
            if not ev_tracks:
                raise ValueError(f"{path}: no event track")
            w, h = ev_tracks[0].dimensions
            images, times, starts, ends = [], [], [], []
            if any(t.data_type == "frame" for t in tracks):
                for track, packet in dec:
                    if track.data_type == "frame":
                        images.append(gray_image(packet.pixels))
                        times.append(int(packet.t) * 1000)
                        starts.append(packet.exposure_start_t)
                        ends.append(packet.exposure_end_t)
    except (OSError, RuntimeError) as exc:
        raise ValueError(f"{path}: not a readable AEDAT4 file ({exc})") from exc
    hw = sensor_hw or (h, w)
    ev_id = ev_tracks[0].id

    def chunks(size: int) -> Iterator[Events]:
        with faery.aedat.Decoder(path) as dec:
            for track, packet in dec:
                if track.id == ev_id and len(packet):
                    yield checked_events(packet["x"], packet["y"],
                                         packet["t"].astype(np.int64) * 1000, packet["on"], hw,
                                         path)

    exposures = None
    if all(v is not None for v in starts + ends):
        exposures = sorted_exposures(times, [int(v) * 1000 for v in starts],
                                     [int(v) * 1000 for v in ends], path)
    return Recording(path, "aedat4", hw, sorted_frames(images, times, path), chunks, exposures)


def open_raw(path: Path, sensor_hw: tuple[int, int] | None) -> Recording:
    faery = _faery(path)
    fallback = (sensor_hw[1], sensor_hw[0]) if sensor_hw else None
    try:
        with faery.evt.Decoder(path, fallback, None) as dec:
            w, h = dec.dimensions
    except (OSError, RuntimeError) as exc:
        raise ValueError(f"{path}: not a readable Prophesee EVT2/EVT3 file ({exc})") from exc
    hw = sensor_hw or (h, w)

    def chunks(size: int) -> Iterator[Events]:
        with faery.evt.Decoder(path, fallback, None) as dec:
            for packet in dec:
                ev = packet.get("events")
                if ev is not None and len(ev):
                    yield checked_events(ev["x"], ev["y"], ev["t"].astype(np.int64) * 1000,
                                         ev["on"], hw, path)

    return Recording(path, "raw", hw, None, chunks)
