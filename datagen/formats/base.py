"""What every event-file reader shares: the :class:`Recording` it returns and the checks
that turn a decoder's arrays into :class:`Events` without hiding a bad value."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from esim_lite.core.events import Events
from esim_lite.core.frames import Frames

READ_CHUNK_EVENTS = 1_000_000
"""Events read at a time when streaming a recording (bounded memory at any length)."""


@dataclass(frozen=True, eq=False)
class Recording:
    """An opened event file.

    Attributes:
        path: the file.
        kind: ``shard``, ``hdf5``, ``evreal``, ``text``, ``aedat4`` or ``raw``.
        sensor_hw: (H, W) of the event sensor.
        frames: APS frames (linear intensity in [0, 1], sorted by time), or None.
        exposures_ns: int64[T, 2] each frame's exposure window (start, end) in ns, in the
            order of ``frames``, when the file stores it (AEDAT4), else None.
    """

    path: Path
    kind: str
    sensor_hw: tuple[int, int]
    frames: Frames | None
    _chunks: Callable[[int], Iterator[Events]]
    exposures_ns: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.exposures_ns is None:
            return
        n = 0 if self.frames is None else len(self.frames)
        if self.exposures_ns.dtype != np.int64 or self.exposures_ns.shape != (n, 2):
            raise ValueError(f"{self.path}: exposure windows must be int64[{n}, 2] (one per "
                             f"frame), got {self.exposures_ns.dtype}"
                             f"{list(self.exposures_ns.shape)}")

    def events(self, chunk: int = READ_CHUNK_EVENTS) -> Iterator[Events]:
        """Validated chunks of about ``chunk`` events, in time order.

        Raises:
            ValueError: naming the file: no events, timestamps going back, coordinates
                outside the sensor, or a polarity other than ON/OFF.
        """
        last, total = None, 0
        for ev in self._chunks(chunk):
            if not len(ev):
                continue
            where = f"{self.path}: events {total}..{total + len(ev) - 1}"
            h, w = self.sensor_hw
            if ev.x.min() < 0 or ev.x.max() >= w or ev.y.min() < 0 or ev.y.max() >= h:
                raise ValueError(f"{where}: coordinates outside the {w}x{h} sensor "
                                 f"(x {ev.x.min()}..{ev.x.max()}, y {ev.y.min()}..{ev.y.max()})"
                                 f"; give the sensor size if the file's is wrong")
            dt = np.diff(ev.t_ns)
            if (last is not None and ev.t_ns[0] < last) or (len(dt) and dt.min() < 0):
                bad = total + (int(np.argmax(dt < 0)) + 1 if len(dt) and dt.min() < 0 else 0)
                raise ValueError(f"{self.path}: timestamps go back in time at event {bad}")
            last, total = int(ev.t_ns[-1]), total + len(ev)
            yield ev
        if total == 0:
            raise ValueError(f"{self.path}: the recording holds no events")

    def read_all(self) -> Events:
        """Every event in memory (for short recordings)."""
        return Events.concatenate(list(self.events()), self.sensor_hw)


# numpy dtype kinds an event field may be stored as: timestamps and coordinates integer or
# float (float coordinates must hold whole numbers: checked per value), polarity also bool
FIELD_KINDS = {"t": "iuf", "x": "iuf", "y": "iuf", "p": "biuf"}
_KIND_WORDS = {"S": "byte strings", "U": "unicode strings", "b": "booleans",
               "O": "Python objects, e.g. variable-length strings", "c": "complex numbers",
               "M": "dates", "m": "time deltas", "V": "records or raw bytes"}


def check_field_dtype(source: Path, field: str, dtype: np.dtype, role: str) -> None:
    """Refuse a stored event field whose dtype cannot hold its ``role`` (``t``, ``x``, ``y``
    or ``p``; see ``FIELD_KINDS``) before arithmetic on it fails with a numpy error.

    Raises:
        ValueError: naming ``source`` and ``field`` (as the file names it, e.g.
            ``events/ts``), e.g. "events/ts holds byte strings (dtype |S8), expected
            numbers (integer or float)".
    """
    dtype = np.dtype(dtype)
    if dtype.kind not in FIELD_KINDS[role]:
        expected = "numbers or booleans" if role == "p" else "numbers (integer or float)"
        raise ValueError(f"{source}: {field} holds "
                         f"{_KIND_WORDS.get(dtype.kind, 'non-numbers')} (dtype {dtype}), "
                         f"expected {expected}")


def checked_events(x, y, t_ns, p, hw, source: Path, offset: int = 0) -> Events:
    """Events from a decoder's arrays (``offset``: global index of the first), checked
    before any cast could hide a problem; errors name ``source`` and the event:
    arrays of a non-numeric dtype, non-finite timestamps, non-integer coordinates or ones
    int16 cannot hold (the cast would truncate or wrap them onto the sensor), polarities
    other than 0/1 or -1/1."""
    x, y, t_ns, p = (np.asarray(v) for v in (x, y, t_ns, p))
    for role, v in (("x", x), ("y", y), ("t", t_ns), ("p", p)):
        check_field_dtype(source, f"event field {role}", v.dtype, role)
    if t_ns.dtype.kind == "f":
        bad = np.flatnonzero(~np.isfinite(t_ns))
        if len(bad):
            raise ValueError(f"{source}: event {offset + bad[0]} has timestamp "
                             f"{t_ns[bad[0]] * 1e-9} (not a finite number)")
    for name, v in (("x", x), ("y", y)):
        if v.dtype.kind == "f":
            bad = np.flatnonzero(v != np.round(v))
            if len(bad):
                raise ValueError(f"{source}: event {offset + bad[0]} has {name} = "
                                 f"{v[bad[0]]} (pixel coordinates must be whole numbers)")
        if len(v) and (v.min() < -2**15 or v.max() >= 2**15):
            raise ValueError(f"{source}: coordinates outside the {hw[1]}x{hw[0]} sensor "
                             f"({name} {v.min()}..{v.max()})")
    if p.dtype != np.bool_:
        bad = np.flatnonzero((p != 0) & (p != 1) & (p != -1))
        if len(bad):
            raise ValueError(f"{source}: event {offset + bad[0]} has polarity "
                             f"{p[bad[0]]}: polarity must be 0/1 (or -1/1)")
    return Events(x.astype(np.int16), y.astype(np.int16), t_ns.astype(np.int64),
                  np.where(p > 0, 1, -1).astype(np.int8), hw)


def gray_image(pixels: np.ndarray, order: str = "rgb") -> np.ndarray:
    """float32 [0, 1] gray image from uint8/uint16 gray, or colour pixels whose channels are
    in ``order`` (``rgb``, or ``bgr`` as OpenCV decodes and event_utils stores them)."""
    img = pixels
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim == 3:
        code = cv2.COLOR_BGR2GRAY if order == "bgr" else cv2.COLOR_RGB2GRAY
        img = cv2.cvtColor(np.ascontiguousarray(img[..., :3]), code)
    scale = 65535.0 if img.dtype == np.uint16 else 255.0 if img.dtype == np.uint8 else 1.0
    return (img.astype(np.float32) / scale).clip(0, 1)


def sorted_frames(images: list[np.ndarray], t_ns: list[int], path: Path) -> Frames | None:
    if not images:
        return None
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise ValueError(f"{path}: APS frames of different sizes {sorted(shapes)}")
    order = np.argsort(np.asarray(t_ns, np.int64), kind="stable")
    return Frames(np.stack([images[i] for i in order]), np.asarray(t_ns, np.int64)[order])


def sorted_exposures(t_ns: list[int], start_ns: list[int], end_ns: list[int], path: Path
                     ) -> np.ndarray | None:
    """int64[T, 2] exposure windows (start, end) of frames stamped ``t_ns``, in the order
    :func:`sorted_frames` puts those frames; None without frames.

    Raises:
        ValueError: naming ``path`` and the frame, when an exposure ends before it starts.
    """
    if not t_ns:
        return None
    order = np.argsort(np.asarray(t_ns, np.int64), kind="stable")
    windows = np.stack([np.asarray(start_ns, np.int64), np.asarray(end_ns, np.int64)], 1)
    bad = np.flatnonzero(windows[:, 1] < windows[:, 0])
    if len(bad):
        raise ValueError(f"{path}: APS frame {bad[0]} has an exposure ending before it starts "
                         f"({windows[bad[0], 0]} > {windows[bad[0], 1]} ns)")
    return windows[order]
