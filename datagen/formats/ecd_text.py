"""The Event Camera Dataset's text layout: ``events.txt`` (``t x y p``, seconds and 0/1),
``images.txt`` + ``images/`` when present; a file or its folder. A numba parser reads
it in blocks (bounded memory, exact nanoseconds from the decimal text).

Beside ``images.txt`` an ``exposures.txt`` may give each frame's exposure window, one line
``index source_frame start end`` (``index``: the frame's line among ``images.txt``'s frames,
from 0; ``source_frame``: its number in the source, kept for provenance; ``start``/``end``
in seconds, the same clock as the events), into ``Recording.exposures_ns``: the layout of
the eSL-Net / EDI examples in ``../shared/real_events`` (there a window is the exposure
itself, or the span around it that holds it)."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import numba
import numpy as np

from datagen.formats.base import (
    READ_CHUNK_EVENTS,
    FrameBudget,
    Recording,
    checked_events,
    gray_image,
    seconds_to_ns,
    sorted_exposures,
    sorted_frames,
)
from esim_lite.core.events import Events
from esim_lite.core.images import read_image

log = logging.getLogger(__name__)


@numba.njit(cache=True)
def _parse_time(buf, i, size):
    """A time ``digits [. digits] [e|E [+|-] digits]`` at ``buf[i]``, kept as mantissa ``m``
    and decimal exponent so that ``t = m 10^(exp - fdigits)`` s converts to ns exactly:
    (index after it, m, fdigits, exp, ok)."""
    m, fdigits, exp, ok = 0, 0, 0, False
    while i < size and 48 <= buf[i] <= 57:
        m = m * 10 + (buf[i] - 48)
        i += 1
        ok = True
    if i < size and buf[i] == 46:
        i += 1
        while i < size and 48 <= buf[i] <= 57:
            if fdigits < 12:  # beyond a picosecond nothing survives the rounding
                m = m * 10 + (buf[i] - 48)
                fdigits += 1
            i += 1
            ok = True
    if ok and i < size and (buf[i] == 101 or buf[i] == 69):  # e/E: scientific notation
        i += 1
        eneg = False
        if i < size and (buf[i] == 45 or buf[i] == 43):
            eneg = buf[i] == 45
            i += 1
        got = False
        while i < size and 48 <= buf[i] <= 57:
            exp = exp * 10 + (buf[i] - 48)
            i += 1
            got = True
        ok = ok and got and exp <= 18
        if eneg:
            exp = -exp
    return i, m, fdigits, exp, ok


@numba.njit(cache=True)
def _parse_int(buf, i, size):
    """An integer, optionally negative, after the separators (space, tab, comma) at
    ``buf[i]``: (index after it, value, ok)."""
    while i < size and (buf[i] == 32 or buf[i] == 9 or buf[i] == 44):
        i += 1
    neg = False
    if i < size and buf[i] == 45:
        neg = True
        i += 1
    got, v = False, 0
    while i < size and 48 <= buf[i] <= 57:
        v = v * 10 + (buf[i] - 48)
        i += 1
        got = True
    return i, -v if neg else v, got


@numba.njit(cache=True)
def _nanoseconds(m, fdigits, exp):
    """``m 10^(exp - fdigits)`` seconds in integer nanoseconds, rounded to the nearest."""
    p10 = exp - fdigits + 9
    if p10 >= 0:
        t = m
        for _ in range(p10):
            t *= 10
        return t
    q = 1
    for _ in range(-p10):
        q *= 10
    return (m + q // 2) // q


@numba.njit(cache=True)
def _skip_line(buf, i, size):
    """Index after the line break ending the line at ``buf[i]``."""
    while i < size and buf[i] != 10:
        i += 1
    return i + 1


@numba.njit(cache=True)
def _parse_text(buf, t_ns, xs, ys, ps):
    """Parse lines ``t x y p`` from uint8 ``buf`` (complete lines). Times in seconds (plain
    or scientific notation) are turned into integer nanoseconds digit by digit: exact for up
    to 9 decimals, rounded to the nearest nanosecond beyond. Returns
    (events parsed, index of the first bad line or -1, lines seen); ``#`` lines and blank
    lines are skipped."""
    n, i, size, line = 0, 0, len(buf), 0
    while i < size:
        while i < size and (buf[i] == 32 or buf[i] == 9 or buf[i] == 13):
            i += 1
        if i < size and (buf[i] == 10 or buf[i] == 35):  # a blank line, or '#': a comment
            i = _skip_line(buf, i, size)
            line += 1
            continue
        if i >= size:
            break
        i, m, fdigits, exp, ok = _parse_time(buf, i, size)
        i, x, got_x = _parse_int(buf, i, size)
        i, y, got_y = _parse_int(buf, i, size)
        i, p, got_p = _parse_int(buf, i, size)
        ok = ok and got_x and got_y and got_p
        while i < size and (buf[i] == 32 or buf[i] == 9 or buf[i] == 13):
            i += 1
        if not ok or (i < size and buf[i] != 10):
            return n, line, line
        t_ns[n] = _nanoseconds(m, fdigits, exp)
        xs[n], ys[n], ps[n] = x, y, p
        n += 1
        line += 1
        i += 1
    return n, -1, line


def _text_chunks(path: Path, size: int) -> Iterator[tuple]:
    """Raw parsed arrays (t_ns, x, y, p) of ``path`` in blocks of about ``size`` lines."""
    block = max(size, 1) * 32  # bytes: ~32 per ECD line
    first_line = 0
    with open(path, "rb") as f:
        rest = b""
        while True:
            data = f.read(block)
            buf = rest + data
            if not buf:
                return
            cut = buf.rfind(b"\n") + 1 if data else len(buf)
            if cut == 0:
                rest = buf
                continue
            body, rest = buf[:cut], buf[cut:]
            arr = np.frombuffer(body, np.uint8)
            cap = body.count(b"\n") + 1
            t = np.empty(cap, np.int64)
            x, y, p = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
            n, bad, lines = _parse_text(arr, t, x, y, p)
            if bad >= 0:
                text = body.split(b"\n")[bad].decode(errors="replace").strip()
                raise ValueError(f"{path}: line {first_line + bad + 1} is not 't x y p': "
                                 f"{text[:60]!r} (truncated or not an event file?)")
            first_line += lines
            yield t[:n], x[:n], y[:n], p[:n]
            if not data:
                return


def open_text(path: Path, sensor_hw: tuple[int, int] | None) -> Recording:
    folder = path if path.is_dir() else path.parent
    events_file = folder / "events.txt" if path.is_dir() else path
    if not events_file.is_file():
        raise FileNotFoundError(f"{folder}: no events.txt")
    index = folder / "images.txt"
    frames, exposures = None, None
    if index.is_file():
        images, times = _frames(folder, index)
        frames = sorted_frames(images, times, index)
        exposures = _exposures(folder / "exposures.txt", times)
    hw = sensor_hw or (frames.hw if frames is not None else _text_extent(events_file))

    def chunks(size: int) -> Iterator[Events]:
        done = 0
        for t, x, y, p in _text_chunks(events_file, size):
            yield checked_events(x, y, t, p, hw, events_file, done)
            done += len(t)

    return Recording(events_file, "text", hw, frames, chunks, exposures)


def _frames(folder: Path, index: Path) -> tuple[list[np.ndarray], list[int]]:
    """(images, t_ns) of the APS frames ``images.txt`` lists (``t path`` a line), in its
    order, bounded by a :class:`FrameBudget` read from each image's header before it is
    decoded."""
    images, times, budget = [], [], FrameBudget(index)
    with open(index, "rb") as f:
        for k, raw in enumerate(f):
            line = raw.decode(errors="replace")
            if not line.strip() or line.startswith("#"):
                continue
            parts = line.split()
            if len(parts) != 2:
                raise ValueError(f"{index}: line {k + 1} is not 't path'")
            where = f"{index}: line {k + 1}"
            t_ns = seconds_to_ns(parts[0], where)
            img = read_image(folder / parts[1])
            if img is None:
                raise ValueError(f"{where}: cannot read image {parts[1]}")
            budget.take(img.shape, parts[1])
            images.append(gray_image(img, "bgr"))  # OpenCV decodes colour as BGR
            times.append(t_ns)
    return images, times


def _exposures(path: Path, times: list[int]) -> np.ndarray | None:
    """int64[T, 2] exposure windows from ``path`` (module doc) for the frames stamped
    ``times`` (``images.txt``'s order), in the order of the sorted frames; None when there
    is no such file or no frame.

    Raises:
        ValueError: naming ``path`` and the line: not four fields, an index outside the
            frames or given twice, a frame without a window, a window ending before it
            starts or not holding its frame's timestamp.
    """
    if not path.is_file() or not times:
        return None
    windows: dict[int, tuple[int, int]] = {}
    with open(path, "rb") as f:
        for k, raw in enumerate(f):
            line = raw.decode(errors="replace")
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            where = f"{path}: line {k + 1}"
            parts = line.split()
            if len(parts) != 4 or not parts[0].isdigit():
                raise ValueError(f"{where} is not 'index source_frame start end'")
            i = int(parts[0])
            if i >= len(times) or i in windows:
                raise ValueError(f"{where}: frame index {i} "
                                 + ("given twice" if i in windows else
                                    f"outside images.txt's {len(times)} frames"))
            start, end = seconds_to_ns(parts[2], where), seconds_to_ns(parts[3], where)
            if not start <= times[i] <= end:
                raise ValueError(f"{where}: frame {i}'s window {parts[2]}..{parts[3]} s does "
                                 f"not hold its timestamp {times[i] * 1e-9:.9f} s")
            windows[i] = (start, end)
    missing = sorted(set(range(len(times))) - set(windows))
    if missing:
        raise ValueError(f"{path}: no window for frame(s) {missing[:5]} of images.txt's "
                         f"{len(times)}")
    return sorted_exposures(times, [windows[i][0] for i in range(len(times))],
                            [windows[i][1] for i in range(len(times))], path)


def _text_extent(path: Path) -> tuple[int, int]:
    """(H, W) from the largest coordinates (no frames, no sensor size given)."""
    mx = my = -1
    for _, x, y, _ in _text_chunks(path, READ_CHUNK_EVENTS):
        if len(x):
            mx, my = max(mx, int(x.max())), max(my, int(y.max()))
    if mx < 0:
        raise ValueError(f"{path}: the recording holds no events")
    log.warning("%s: no frames or sensor size; using %dx%d from the largest coordinates",
                path, mx + 1, my + 1)
    return my + 1, mx + 1
