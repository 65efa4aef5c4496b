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
from esim_lite.core.limits import (
    MAX_EVENTS_HELD,
    MAX_FRAME_PIXELS,
    check_image_pixels,
    check_sensor_hw,
)

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
        check_sensor_hw(self.sensor_hw, self.path)
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
        for ev in self._decoded(chunk):
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

    def check_frames_match(self) -> None:
        """Refuse APS frames of another size than the event sensor (a command that compares
        or fuses the two).

        Raises:
            ValueError: naming the file and both sizes.
        """
        if self.frames is not None and self.frames.hw != tuple(self.sensor_hw):
            (fh, fw), (h, w) = self.frames.hw, self.sensor_hw
            raise ValueError(f"{self.path}: APS frames are {fw}x{fh}, the event sensor is "
                             f"{w}x{h}; give the sensor size if the file's is wrong")

    def _decoded(self, chunk: int) -> Iterator[Events]:
        """The decoder's chunks, its failures past the header (a corrupt payload, an
        unreadable HDF5 chunk) turned into a ValueError naming the file."""
        chunks, total = self._chunks(chunk), 0
        while True:
            try:
                ev = next(chunks)
            except StopIteration:
                return
            except (RuntimeError, OSError, KeyError, TypeError, IndexError) as exc:
                raise ValueError(f"{self.path}: cannot be read after event {total:,} "
                                 f"(corrupt or not this format: {exc})") from exc
            total += len(ev)
            yield ev

    def read_all(self, max_events: int = MAX_EVENTS_HELD) -> Events:
        """Every event in memory (for short recordings).

        Raises:
            ValueError: naming the file, when it holds more than ``max_events`` events.
        """
        parts, total = [], 0
        for ev in self.events():
            total += len(ev)
            if total > max_events:
                raise ValueError(f"{self.path}: more than {max_events:,} events, the most "
                                 f"this command holds in memory at once; cut the recording "
                                 f"into parts")
            parts.append(ev)
        return Events.concatenate(parts, self.sensor_hw)


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
        bad = np.flatnonzero(~(np.abs(t_ns) < _NS_LIMIT))
        if len(bad):
            value = t_ns[bad[0]] * 1e-9
            raise ValueError(f"{source}: event {offset + bad[0]} has timestamp {value} "
                             + ("(not a finite number)" if not np.isfinite(value) else
                                f"s (beyond {_NS_LIMIT * 1e-9:.3g} s)"))
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


_NS_LIMIT = 2.0 ** 63 * 0.999  # int64 nanoseconds (about 292 years)


def seconds_to_ns(seconds: object, source: str | Path) -> int:
    """Integer nanoseconds of a timestamp in seconds (a number or its text).

    Raises:
        ValueError: naming ``source``: not a number, or not finite or beyond int64 ns.
    """
    try:
        value = float(seconds) * 1e9
    except (TypeError, ValueError):
        raise ValueError(f"{source}: timestamp {seconds!r} is not a number") from None
    if not abs(value) < _NS_LIMIT:
        raise ValueError(f"{source}: timestamp {seconds!r} s is not a finite time (at most "
                         f"{_NS_LIMIT * 1e-9:.3g} s)")
    return int(round(value))


class FrameBudget:
    """Counts the pixels of the APS frames a reader loads; refuses an image above
    ``MAX_IMAGE_PIXELS`` or frames past ``MAX_FRAME_PIXELS`` together, before loading it."""

    def __init__(self, source: str | Path) -> None:
        self.source, self.pixels = source, 0

    def take(self, hw: tuple[int, ...], what: str, count: int = 1) -> None:
        """Account for ``count`` more frames of shape ``hw`` (a header's or dataset's)."""
        check_image_pixels(hw, f"{self.source}: {what}")
        self.pixels += int(hw[0]) * int(hw[1]) * int(count)
        if self.pixels > MAX_FRAME_PIXELS:
            raise ValueError(f"{self.source}: APS frames of more than {MAX_FRAME_PIXELS:,} "
                             f"pixels together, more than e2sr holds at once")


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
