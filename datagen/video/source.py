"""Frame sources: video files and folders of frames, scanned once, then streamed.

An input is a video file (anything OpenCV's FFmpeg backend reads), a folder of frames
(image files sorted by name, with ``timestamps.txt``: one time in seconds a line, ``#``
comments allowed; or a frame rate given by ``--fps``), or a folder of videos (every file
with a video extension, sorted by name). A video's frame times are its own presentation
times (OpenCV's ``CAP_PROP_POS_MSEC`` after each frame), so a variable frame rate is kept.

:func:`scan_inputs` reads every input once (frame count, times, frame size, a SHA-256 of
the bytes) and refuses a bad one before anything is written; :func:`read_frames` then
streams the frames of one range, one at a time (a video is never held in memory).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from esim_lite.core.images import image_hw, read_image
from esim_lite.core.limits import MAX_IMAGE_BYTES, check_image_pixels

VIDEO_EXTENSIONS = (".mp4", ".m4v", ".mov", ".mkv", ".avi", ".webm", ".mpg", ".mpeg",
                    ".wmv", ".flv", ".y4m", ".ts", ".mts", ".ogv", ".3gp", ".mxf")
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp", ".ppm",
                    ".pgm", ".exr")
TIMESTAMPS = "timestamps.txt"
_HASH_BLOCK = 1 << 22


@dataclass(frozen=True, eq=False)
class Source:
    """One clip: a video file or a folder of frames.

    Attributes:
        path: the file or folder.
        kind: ``video`` or ``frames``.
        t_ns: int64[N] every frame's time (ns from the clip's own origin), increasing.
        frame_hw: (H, W) of its frames.
        sha256: digest of its bytes (a folder: of each frame file's name and bytes, in
            order, then of its ``timestamps.txt`` when it has one).
        files: a folder's frame file names, in order (empty for a video).
        origin_ns: a video's first frame time as its decoder reports it (``t_ns`` counts
            from there).
    """

    path: Path
    kind: str
    t_ns: np.ndarray
    frame_hw: tuple[int, int]
    sha256: str
    files: tuple[str, ...] = ()
    origin_ns: int = 0

    @property
    def n_frames(self) -> int:
        return len(self.t_ns)


def _sha256_file(path: Path, digest=None):
    digest = digest or hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(_HASH_BLOCK):
            digest.update(block)
    return digest


def expand_inputs(inputs: list[str | Path]) -> list[tuple[Path, str]]:
    """``(path, kind)`` of every clip the inputs name, in order (a folder of videos gives
    its videos sorted by name).

    Raises:
        FileNotFoundError: an input does not exist.
        ValueError: an input is a single image, or a folder with neither frames nor videos.
    """
    out = []
    for given in inputs:
        path = Path(given)
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such video file or folder of frames")
        if path.is_file():
            if path.suffix.lower() in IMAGE_EXTENSIONS:
                raise ValueError(f"{path}: one image is not a video; give the folder of "
                                 f"frames it belongs to (with {TIMESTAMPS} or --fps)")
            out.append((path, "video"))
            continue
        entries = sorted(p for p in path.iterdir() if p.is_file())
        if (path / TIMESTAMPS).is_file() or any(p.suffix.lower() in IMAGE_EXTENSIONS
                                               for p in entries):
            out.append((path, "frames"))
            continue
        videos = [p for p in entries if p.suffix.lower() in VIDEO_EXTENSIONS]
        if not videos:
            raise ValueError(f"{path}: a folder with neither image frames "
                             f"({', '.join(IMAGE_EXTENSIONS[:4])}, ...) nor videos "
                             f"({', '.join(VIDEO_EXTENSIONS[:4])}, ...)")
        out.extend((v, "video") for v in videos)
    if not out:
        raise ValueError("no input given (a video file, a folder of frames or of videos)")
    return out


def open_video(path: Path) -> cv2.VideoCapture:
    """An opened capture of ``path`` through FFmpeg.

    Raises:
        ValueError: OpenCV cannot open it as a video.
    """
    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    if not cap.isOpened():
        cap.release()
        raise ValueError(f"{path}: OpenCV (FFmpeg) cannot read this file as a video")
    return cap


def _video_time_ns(cap: cv2.VideoCapture) -> int:
    return int(round(cap.get(cv2.CAP_PROP_POS_MSEC) * 1e6))


def _check_times(t_ns: np.ndarray, where: str) -> None:
    if len(t_ns) > 1:
        bad = np.flatnonzero(np.diff(t_ns) <= 0)
        if len(bad):
            k = int(bad[0])
            raise ValueError(f"{where}: frame times go backwards or repeat at frame {k + 1} "
                             f"({t_ns[k] * 1e-9:.6f} s, then {t_ns[k + 1] * 1e-9:.6f} s); "
                             f"frame times must increase")


def scan_video(path: Path) -> Source:
    """Decode ``path`` once: its frame times, frame size and SHA-256.

    Raises:
        ValueError: unreadable, no frames, or times that do not increase.
    """
    cap = open_video(path)
    try:
        times, hw = [], None
        while cap.grab():
            times.append(_video_time_ns(cap))
            if hw is None:
                ok, frame = cap.retrieve()
                if not ok or frame is None or frame.size == 0:
                    raise ValueError(f"{path}: OpenCV cannot decode its first frame")
                hw = (int(frame.shape[0]), int(frame.shape[1]))
                check_image_pixels(hw, path)
    finally:
        cap.release()
    if not times:
        raise ValueError(f"{path}: the video has no frames OpenCV can decode (empty or "
                         f"unreadable)")
    t_ns = np.asarray(times, np.int64)
    _check_times(t_ns, str(path))
    return Source(path, "video", t_ns - t_ns[0], hw, _sha256_file(path).hexdigest(),
                  origin_ns=int(t_ns[0]))


def _read_timestamps(path: Path) -> np.ndarray:
    values = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        try:
            value = float(text.split()[-1])  # "t" or "index t"
        except ValueError:
            raise ValueError(f"{path}: line {number} is not a time in seconds: "
                             f"{line.strip()!r}") from None
        if not math.isfinite(value):
            raise ValueError(f"{path}: line {number}: {value} is not a finite time")
        values.append(value)
    return np.round(np.asarray(values, np.float64) * 1e9).astype(np.int64)


def scan_frames(folder: Path, fps: float | None) -> Source:
    """A folder of frames: names, times (``timestamps.txt``, else ``fps``), size, digest.

    Raises:
        ValueError: no frames, frames of different sizes or not images, no times, a count
            of times other than of frames, or times that do not increase.
    """
    files = sorted(p for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
    if not files:
        raise ValueError(f"{folder}: no image frames ({', '.join(IMAGE_EXTENSIONS)})")
    stamps = folder / TIMESTAMPS
    if stamps.is_file():
        t_ns = _read_timestamps(stamps)
        if len(t_ns) != len(files):
            raise ValueError(f"{stamps}: {len(t_ns)} times for {len(files)} frames; one "
                             f"time (seconds) a line, one line per frame in name order")
        _check_times(t_ns, str(stamps))
    elif fps is not None:
        t_ns = np.round(np.arange(len(files)) * (1e9 / fps)).astype(np.int64)
    else:
        raise ValueError(f"{folder}: no {TIMESTAMPS} (one time in seconds a line) and no "
                         f"--fps: the frames' times are unknown")
    digest, hw = hashlib.sha256(), None
    for f in files:
        if f.stat().st_size > MAX_IMAGE_BYTES:
            raise ValueError(f"{f}: {f.stat().st_size:,} bytes, more than e2sr reads as one "
                             f"image ({MAX_IMAGE_BYTES:,})")
        data = f.read_bytes()
        size = image_hw(data)
        if size is None:
            raise ValueError(f"{f}: not an image this reader decodes")
        check_image_pixels(size, f)
        if hw is None:
            hw = size
        elif size != hw:
            raise ValueError(f"{f}: a {size[1]}x{size[0]} frame among {hw[1]}x{hw[0]} "
                             f"ones (from {files[0].name}); a clip's frames must have one "
                             f"size")
        digest.update(f.name.encode() + b"\0")
        digest.update(data)
    if stamps.is_file():
        _sha256_file(stamps, digest)
    return Source(folder, "frames", t_ns - t_ns[0], hw, digest.hexdigest(),
                  tuple(f.name for f in files))


def scan_inputs(inputs: list[str | Path], fps: float | None = None) -> list[Source]:
    """Every clip of ``inputs``, scanned (see :func:`expand_inputs`)."""
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"--fps must be a positive frame rate, got {fps}")
    return [scan_video(p) if kind == "video" else scan_frames(p, fps)
            for p, kind in expand_inputs(inputs)]


def read_frames(source: Source, start: int, stop: int) -> Iterator[np.ndarray]:
    """The decoded frames ``start .. stop - 1`` of ``source``, one at a time (BGR uint8
    for a video; a frame file's own dtype and channels for a folder).

    Raises:
        ValueError: a frame cannot be decoded, has another size than the scan found, or
            (a video) is not where the scan found it (the file changed).
    """
    if source.kind == "frames":
        for k in range(start, stop):
            path = source.path / source.files[k]
            frame = read_image(path, cv2.IMREAD_UNCHANGED)
            if frame is None:
                raise ValueError(f"{path}: cannot decode this frame")
            _check_size(frame, source, path)
            yield frame
        return
    yield from _read_video(source, start, stop)


def _check_size(frame: np.ndarray, source: Source, where) -> None:
    hw = (int(frame.shape[0]), int(frame.shape[1]))
    if hw != source.frame_hw:
        raise ValueError(f"{where}: a {hw[1]}x{hw[0]} frame among {source.frame_hw[1]}x"
                         f"{source.frame_hw[0]} ones; a clip's frames must have one size")


def _read_video(source: Source, start: int, stop: int) -> Iterator[np.ndarray]:
    """Seek to ``start`` when the decoder lands on the scanned frame there (its time tells),
    else decode from the first frame; every frame's time is checked against the scan."""
    cap = open_video(source.path)
    try:
        if start > 0:
            cap.set(cv2.CAP_PROP_POS_FRAMES, start)
            if not cap.grab() or _video_time_ns(cap) != source.origin_ns + source.t_ns[start]:
                cap.release()
                cap = open_video(source.path)
                for _ in range(start + 1):
                    if not cap.grab():
                        raise ValueError(f"{source.path}: ends before frame {start} (the "
                                         f"file changed since it was scanned?)")
        elif not cap.grab():
            raise ValueError(f"{source.path}: cannot decode frame 0")
        for k in range(start, stop):
            if k > start and not cap.grab():
                raise ValueError(f"{source.path}: ends at frame {k}, the scan found "
                                 f"{source.n_frames} (the file changed since it was scanned?)")
            t = _video_time_ns(cap) - source.origin_ns
            ok, frame = cap.retrieve()
            if not ok or frame is None or t != source.t_ns[k]:
                raise ValueError(f"{source.path}: frame {k} is not the frame the scan found "
                                 f"at {source.t_ns[k] * 1e-9:.6f} s (the file changed since "
                                 f"it was scanned?)")
            _check_size(frame, source, f"{source.path} frame {k}")
            yield frame
    finally:
        cap.release()
