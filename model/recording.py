"""Event recordings in: every supported file format as one streaming, validated interface.

``open_recording(path)`` recognises:
- e2sr shards (``shard_*.h5``; a ``sequence`` picks one, default the first);
- event_utils / E2VID-style HDF5 (``events/xs, ys, ts, ps``; ``images/*`` with a
  ``timestamp`` attribute; ``sensor_resolution`` attribute);
- the Event Camera Dataset's text format (``events.txt``: ``t x y p`` in seconds and 0/1,
  with ``images.txt`` + ``images/`` when present), a file or its folder;
- AEDAT4 from iniVation cameras (events and APS frames) and Prophesee EVT2/EVT3 ``.raw``,
  both decoded by the maintained ``faery`` package.

Events come in chunks (:meth:`Recording.events`), so a file of any length is read with
bounded memory; every chunk is checked (time order across chunks, coordinates inside the
sensor, polarity) and a bad file fails with its path and the problem. APS frames, small by
nature, are loaded whole as linear intensity in [0, 1].
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import h5py
import numba
import numpy as np

from esim_lite.events import Events
from esim_lite.frames import Frames

log = logging.getLogger(__name__)
CHUNK = 1_000_000


@dataclass(frozen=True, eq=False)
class Recording:
    """An opened event file.

    Attributes:
        path: the file.
        kind: ``shard``, ``hdf5``, ``text``, ``aedat4`` or ``raw``.
        sensor_hw: (H, W) of the event sensor.
        frames: APS frames (linear intensity in [0, 1], sorted by time), or None.
    """

    path: Path
    kind: str
    sensor_hw: tuple[int, int]
    frames: Frames | None
    _chunks: Callable[[int], Iterator[Events]]

    def events(self, chunk: int = CHUNK) -> Iterator[Events]:
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


def open_recording(path: str | Path, sensor_hw: tuple[int, int] | None = None,
                   sequence: str | None = None) -> Recording:
    """Open ``path`` (format from its content/name); ``sensor_hw`` overrides the file's."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    if path.is_dir() or path.suffix == ".txt":
        return _open_text(path, sensor_hw)
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5", ".hdf"):
        try:
            with h5py.File(path, "r") as f:
                is_shard = "schema_version" in f.attrs
        except OSError as exc:
            raise ValueError(f"{path}: not a readable HDF5 file ({exc})") from exc
        return _open_shard(path, sequence) if is_shard else _open_hdf5(path, sensor_hw)
    if suffix == ".aedat4":
        return _open_aedat4(path, sensor_hw)
    if suffix == ".raw":
        return _open_raw(path, sensor_hw)
    raise ValueError(f"{path}: unknown event file type {suffix!r} (expected .h5, .txt, "
                     f".aedat4, .raw or an ECD folder)")


def _events(x, y, t_ns, p, hw, source: Path, offset: int = 0) -> Events:
    """Events from a decoder's arrays (``offset``: global index of the first), checked
    before any cast could hide a problem; errors name ``source`` and the event:
    non-finite timestamps, non-integer coordinates or ones int16 cannot hold (the cast
    would truncate or wrap them onto the sensor), polarities other than 0/1 or -1/1."""
    x, y, t_ns, p = (np.asarray(v) for v in (x, y, t_ns, p))
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


def _gray(pixels: np.ndarray) -> np.ndarray:
    """float32 [0, 1] gray image from uint8/uint16 gray or RGB(A) pixels."""
    img = pixels
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_RGB2GRAY)
    scale = 65535.0 if img.dtype == np.uint16 else 255.0 if img.dtype == np.uint8 else 1.0
    return (img.astype(np.float32) / scale).clip(0, 1)


def _frames(images: list[np.ndarray], t_ns: list[int], path: Path) -> Frames | None:
    if not images:
        return None
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise ValueError(f"{path}: APS frames of different sizes {sorted(shapes)}")
    order = np.argsort(np.asarray(t_ns, np.int64), kind="stable")
    return Frames(np.stack([images[i] for i in order]), np.asarray(t_ns, np.int64)[order])


# --- e2sr shards ------------------------------------------------------------------------

def _open_shard(path: Path, sequence: str | None) -> Recording:
    from datagen.shard import ShardReader

    with ShardReader(path) as reader:
        names = reader.sequences()
        name = sequence or names[0]
        if name not in names:
            raise ValueError(f"{path}: no sequence {name!r} (it has {', '.join(names)})")
        hw = tuple(int(v) for v in reader.group(name).attrs["sensor_resolution"])
        lr = reader.group(name)["frames/lr"][:].astype(np.float32)
        frames = Frames(lr, reader.frame_times_ns(name))
        total = reader.num_events(name)

    def chunks(size: int) -> Iterator[Events]:
        with ShardReader(path) as r:
            for start in range(0, total, size):
                yield r.events(name, start, min(start + size, total))

    return Recording(path, "shard", hw, frames, chunks)


# --- event_utils / E2VID HDF5 -----------------------------------------------------------

def _open_hdf5(path: Path, sensor_hw: tuple[int, int] | None) -> Recording:
    with h5py.File(path, "r") as f:
        if not all(f"events/{k}" in f for k in ("xs", "ys", "ts", "ps")):
            raise ValueError(f"{path}: no events/xs, ys, ts, ps datasets (not an event "
                             f"HDF5 file)")
        n = f["events/ts"].shape[0]
        if any(f[f"events/{k}"].shape[0] != n for k in ("xs", "ys", "ps")):
            raise ValueError(f"{path}: events/xs, ys, ts, ps have different lengths "
                             f"(truncated file?)")
        hw = sensor_hw or _hdf5_sensor(f, path)
        images, times = [], []
        if "images" in f:
            for name in sorted(f["images"]):
                ds = f["images"][name]
                if "timestamp" not in ds.attrs:
                    raise ValueError(f"{path}: images/{name} has no timestamp attribute")
                images.append(_gray(ds[:]))
                times.append(int(round(float(ds.attrs["timestamp"]) * 1e9)))
    frames = _frames(images, times, path)

    def chunks(size: int) -> Iterator[Events]:
        with h5py.File(path, "r") as f:
            ev = f["events"]
            for start in range(0, n, size):
                sl = slice(start, min(start + size, n))
                yield _events(ev["xs"][sl], ev["ys"][sl], np.round(ev["ts"][sl] * 1e9),
                              ev["ps"][sl], hw, path, start)

    return Recording(path, "hdf5", hw, frames, chunks)


def _hdf5_sensor(f: h5py.File, path: Path) -> tuple[int, int]:
    if "sensor_resolution" in f.attrs:
        h, w = (int(v) for v in f.attrs["sensor_resolution"])
        return h, w
    if "images" in f and len(f["images"]):
        return tuple(f["images"][sorted(f["images"])[0]].shape[:2])
    raise ValueError(f"{path}: no sensor_resolution attribute; give the sensor size")


# --- Event Camera Dataset text ----------------------------------------------------------

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
        if i < size and buf[i] == 10:
            i += 1
            line += 1
            continue
        if i < size and buf[i] == 35:  # '#': comment line
            while i < size and buf[i] != 10:
                i += 1
            i += 1
            line += 1
            continue
        if i >= size:
            break
        # time: digits [. digits] [e|E [+|-] digits], kept as mantissa m and decimal
        # exponent so that t = m 10^(exp - frac_digits) s is turned into ns exactly
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
        vals = np.zeros(3, np.int64)
        for k in range(3):
            while i < size and (buf[i] == 32 or buf[i] == 9 or buf[i] == 44):
                i += 1
            neg = False
            if i < size and buf[i] == 45:
                neg = True
                i += 1
            got = False
            v = 0
            while i < size and 48 <= buf[i] <= 57:
                v = v * 10 + (buf[i] - 48)
                i += 1
                got = True
            ok = ok and got
            vals[k] = -v if neg else v
        while i < size and (buf[i] == 32 or buf[i] == 9 or buf[i] == 13):
            i += 1
        if not ok or (i < size and buf[i] != 10):
            return n, line, line
        p10 = exp - fdigits + 9
        if p10 >= 0:
            t = m
            for _ in range(p10):
                t *= 10
        else:  # round to the nearest nanosecond
            q = 1
            for _ in range(-p10):
                q *= 10
            t = (m + q // 2) // q
        t_ns[n] = t
        xs[n], ys[n], ps[n] = vals[0], vals[1], vals[2]
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


def _open_text(path: Path, sensor_hw: tuple[int, int] | None) -> Recording:
    folder = path if path.is_dir() else path.parent
    events_file = folder / "events.txt" if path.is_dir() else path
    if not events_file.is_file():
        raise FileNotFoundError(f"{folder}: no events.txt")
    images, times = [], []
    index = folder / "images.txt"
    if index.is_file():
        for k, line in enumerate(index.read_text().splitlines()):
            if not line.strip() or line.startswith("#"):
                continue
            parts = line.split()
            if len(parts) != 2:
                raise ValueError(f"{index}: line {k + 1} is not 't path'")
            img = cv2.imread(str(folder / parts[1]), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise ValueError(f"{index}: line {k + 1}: cannot read image {parts[1]}")
            images.append(_gray(img))
            times.append(int(round(float(parts[0]) * 1e9)))
    frames = _frames(images, times, index)
    hw = sensor_hw or (frames.hw if frames is not None else _text_extent(events_file))

    def chunks(size: int) -> Iterator[Events]:
        done = 0
        for t, x, y, p in _text_chunks(events_file, size):
            yield _events(x, y, t, p, hw, events_file, done)
            done += len(t)

    return Recording(events_file, "text", hw, frames, chunks)


def _text_extent(path: Path) -> tuple[int, int]:
    """(H, W) from the largest coordinates (no frames, no sensor size given)."""
    mx = my = -1
    for _, x, y, _ in _text_chunks(path, CHUNK):
        if len(x):
            mx, my = max(mx, int(x.max())), max(my, int(y.max()))
    if mx < 0:
        raise ValueError(f"{path}: the recording holds no events")
    log.warning("%s: no frames or sensor size; using %dx%d from the largest coordinates",
                path, mx + 1, my + 1)
    return my + 1, mx + 1


# --- AEDAT4 and Prophesee raw (faery) ----------------------------------------------------

def _faery(path: Path):
    try:
        import faery
    except ImportError as exc:  # pragma: no cover - faery is a dependency
        raise ValueError(f"{path}: reading this format needs the 'faery' package") from exc
    return faery


def _open_aedat4(path: Path, sensor_hw: tuple[int, int] | None) -> Recording:
    faery = _faery(path)
    try:
        with faery.aedat.Decoder(path) as dec:
            tracks = dec.tracks()
            ev_tracks = [t for t in tracks if t.data_type == "events"]
            if not ev_tracks:
                raise ValueError(f"{path}: no event track")
            w, h = ev_tracks[0].dimensions
            images, times = [], []
            if any(t.data_type == "frame" for t in tracks):
                for track, packet in dec:
                    if track.data_type == "frame":
                        images.append(_gray(packet.pixels))
                        times.append(int(packet.t) * 1000)
    except (OSError, RuntimeError) as exc:
        raise ValueError(f"{path}: not a readable AEDAT4 file ({exc})") from exc
    hw = sensor_hw or (h, w)
    ev_id = ev_tracks[0].id

    def chunks(size: int) -> Iterator[Events]:
        with faery.aedat.Decoder(path) as dec:
            for track, packet in dec:
                if track.id == ev_id and len(packet):
                    yield _events(packet["x"], packet["y"], packet["t"].astype(np.int64) * 1000,
                                  packet["on"], hw, path)

    return Recording(path, "aedat4", hw, _frames(images, times, path), chunks)


def _open_raw(path: Path, sensor_hw: tuple[int, int] | None) -> Recording:
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
                    yield _events(ev["x"], ev["y"], ev["t"].astype(np.int64) * 1000, ev["on"],
                                  hw, path)

    return Recording(path, "raw", hw, None, chunks)
