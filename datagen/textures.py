"""Textures for the simulated planes: built-in photographs, procedural patterns, user images.

Intensity convention (ESIM's planar renderer): an 8-bit image value ``v`` is taken as linear
intensity ``v / 255``; ``gamma`` can decode a display gamma first. Every texture is then
mapped affinely to a random ``[low, high]`` range, so sequences see varied contrast and
brightness and never exact black (where ``log(eps + I)`` would be dominated by ``eps``).
"""

from __future__ import annotations

import fnmatch
import logging
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from esim_lite.core.images import decode_image
from esim_lite.core.limits import MAX_IMAGE_BYTES

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".tga", ".webp")
ARCHIVE_SUFFIXES = (".zip", ".pk3")
#: Photographs and material textures that ship inside scikit-image (no download).
#: (Flat images such as color.png, cell.png or retina.jpg are left out: they make few events
#: and teach super-resolution nothing.)
BUILTIN_FILES = ("astronaut.png", "brick.png", "camera.png", "chelsea.png", "coffee.png",
                 "coins.png", "grass.png", "gravel.png", "hubble_deep_field.jpg", "ihc.png",
                 "moon.png", "page.png", "rocket.jpg", "text.png", "motorcycle_left.png")
PROCEDURAL = ("noise", "shapes", "grating", "checker")
"""The procedural patterns drawn by default (``procedural_kinds``)."""
PROCEDURAL_KINDS = PROCEDURAL + ("poster",)
"""Every procedural pattern: ``poster`` (a flat ground with a few large flat shapes, the
scene of the Event Camera Dataset's ``shapes``) is drawn only when configured."""
#: Material packs ship auxiliary maps beside each texture (ufoai: ``_nm`` normal maps, ``_sm``
#: specular and ``_gm`` gloss maps); they are not pictures of anything and are left out.
MATERIAL_MAPS = ("*_nm.*", "*_sm.*", "*_gm.*")


@dataclass(frozen=True)
class TextureConfig:
    """Where textures come from and how they are varied.

    Attributes:
        source: ``builtin``, a folder (searched recursively) or a zip/pk3 of images, or a
            list of these (each sequence first draws a source, then an image in it).
        source_weights: relative probability of each source (default: equal).
        split: ``all`` images, or only the ``train`` or ``test`` part of each source. An
            image's part depends only on its name inside its source (file name, or member
            path in an archive), so a test set never sees a training image.
        test_fraction: share of each source's images in the ``test`` part.
        exclude: ``fnmatch`` patterns of file names to leave out (default: the normal,
            specular and gloss maps of material packs).
        procedural_fraction: share of sequences using a procedural pattern instead.
        procedural_kinds: the patterns drawn, each equally likely (default: noise, shapes,
            grating, checker; ``poster`` adds large flat regions bounded by edges of either
            polarity, which busy photographs rarely have; docs/notes/halos.md).
        crop_fraction: (min, max) side of the random crop relative to the image.
        low_range, high_range: ranges of the darkest / brightest linear intensity.
        gamma: decode ``(v/255) ** gamma`` (1.0 = ESIM's convention, 2.2 = sRGB-like).
        max_texels: cap on the texture's longest side.
        min_detail: photo crops whose mean absolute gradient (intensity normalised to [0, 1],
            crop seen 256 texels wide) is below this are redrawn; 0 keeps everything.
    """

    source: str | tuple[str, ...] = "builtin"
    source_weights: tuple[float, ...] | None = None
    split: Literal["all", "train", "test"] = "all"
    test_fraction: float = 0.1
    exclude: tuple[str, ...] = MATERIAL_MAPS
    procedural_fraction: float = 0.25
    procedural_kinds: tuple[str, ...] = PROCEDURAL
    crop_fraction: tuple[float, float] = (0.6, 1.0)
    low_range: tuple[float, float] = (0.02, 0.2)
    high_range: tuple[float, float] = (0.6, 1.0)
    gamma: float = 1.0
    max_texels: int = 4096
    min_detail: float = 0.03

    def __post_init__(self) -> None:
        if not self.sources:
            raise ValueError("source must name at least one texture source")
        if self.source_weights is not None and (
                len(self.source_weights) != len(self.sources)
                or min(self.source_weights) < 0 or sum(self.source_weights) <= 0):
            raise ValueError(f"source_weights must be {len(self.sources)} non-negative "
                             f"numbers, not all 0 (one per source)")
        if not 0 < self.test_fraction < 1:
            raise ValueError("test_fraction must be in (0, 1)")
        if not 0 <= self.procedural_fraction <= 1:
            raise ValueError("procedural_fraction must be in [0, 1]")
        unknown = sorted(set(self.procedural_kinds) - set(PROCEDURAL_KINDS))
        if not self.procedural_kinds or unknown:
            raise ValueError(f"procedural_kinds must name some of {', '.join(PROCEDURAL_KINDS)}"
                             f"{'; unknown: ' + ', '.join(unknown) if unknown else ''}")
        lo, hi = self.crop_fraction
        if not 0 < lo <= hi <= 1:
            raise ValueError("crop_fraction must satisfy 0 < min <= max <= 1")
        if not 0 < self.low_range[0] <= self.low_range[1] < self.high_range[0] \
                <= self.high_range[1]:
            raise ValueError("need 0 < low_range <= ... < high_range")
        if self.gamma <= 0 or self.max_texels < 16:
            raise ValueError("gamma must be > 0 and max_texels >= 16")

    @property
    def sources(self) -> tuple[str, ...]:
        return (self.source,) if isinstance(self.source, str) else tuple(self.source)


def in_split(key: str, split: str, test_fraction: float) -> bool:
    """Whether the image named ``key`` belongs to ``split`` (``all``, ``train``, ``test``):
    a fixed hash of the name, so the split never depends on what else is in the source."""
    if split == "all":
        return True
    is_test = zlib.crc32(key.lower().encode()) % 100_000 < test_fraction * 100_000
    return is_test == (split == "test")


def _decode(data: bytes, source: str) -> np.ndarray | None:
    """Gray image in [0, 1] (float32) from encoded bytes, or None if unreadable.

    Raises:
        ValueError: naming ``source``: its header states more than ``MAX_IMAGE_PIXELS``.
    """
    arr = decode_image(data, source)
    if arr is None or arr.ndim not in (2, 3):
        return None
    if arr.ndim == 3:
        if arr.shape[2] == 4:
            arr = arr[..., :3]
        arr = cv2.cvtColor(arr, cv2.COLOR_BGR2GRAY) if arr.shape[2] == 3 else arr[..., 0]
    scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(arr.dtype)
    if scale is None:
        arr = arr.astype(np.float32)
        span = float(arr.max() - arr.min())
        return None if span <= 0 else (arr - arr.min()) / span
    return arr.astype(np.float32) / scale


class ImageLibrary:
    """A list of image files (in folders or archives) read on demand.

    Unreadable entries are skipped with a warning and counted in ``skipped``. ``exclude``
    drops file names matching any of its patterns; ``split`` keeps one part of the images
    (see :func:`in_split`).
    """

    def __init__(self, source: str | Path, exclude: tuple[str, ...] = MATERIAL_MAPS,
                 split: Literal["all", "train", "test"] = "all", test_fraction: float = 0.1
                 ) -> None:
        self.source = str(source)
        self.skipped = 0
        self._entries: list[tuple[str, str]] = []  # (container, member) pairs
        if self.source == "builtin":
            import skimage.data

            folder = Path(skimage.data.__file__).parent
            self._entries = [(str(folder / f), "") for f in BUILTIN_FILES
                             if (folder / f).is_file()]
        else:
            self._scan(Path(self.source))
        found = len(self._entries)
        self._entries = [e for e in self._entries
                         if not any(fnmatch.fnmatch(_base(e).lower(), p) for p in exclude)
                         and in_split(_key(e), split, test_fraction)]
        if not self._entries:
            part = f" in its {split!r} part ({found} before the split/exclusion)" \
                if split != "all" or found else ""
            raise FileNotFoundError(f"{self.source}: no readable images found{part} "
                                    f"({', '.join(IMAGE_SUFFIXES + ARCHIVE_SUFFIXES)})")

    def _scan(self, path: Path) -> None:
        if not path.exists():
            raise FileNotFoundError(f"{path}: texture path does not exist")
        files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
        for f in files:
            suffix = f.suffix.lower()
            if suffix in IMAGE_SUFFIXES:
                self._entries.append((str(f), ""))
            elif suffix in ARCHIVE_SUFFIXES:
                try:
                    with zipfile.ZipFile(f) as zf:
                        self._entries += [(str(f), n) for n in sorted(zf.namelist())
                                          if n.lower().endswith(IMAGE_SUFFIXES)]
                except (zipfile.BadZipFile, OSError) as exc:
                    self.skipped += 1
                    log.warning("%s: skipped, not a readable zip archive (%s)", f, exc)

    def __len__(self) -> int:
        return len(self._entries)

    def keys(self) -> list[str]:
        """The split key of every image (its name inside the source)."""
        return [_key(e) for e in self._entries]

    def name(self, i: int) -> str:
        container, member = self._entries[i]
        if self.source == "builtin":
            return f"builtin:{Path(container).name}"
        return f"{container}:{member}" if member else container

    def read(self, i: int) -> np.ndarray | None:
        """float32 gray image in [0, 1], or None (warned and counted) if unreadable."""
        container, member = self._entries[i]
        try:
            if member:
                with zipfile.ZipFile(container) as zf:
                    size = zf.getinfo(member).file_size
                    data = b"" if size > MAX_IMAGE_BYTES else zf.read(member)
            else:
                size = Path(container).stat().st_size
                data = b"" if size > MAX_IMAGE_BYTES else Path(container).read_bytes()
            if size > MAX_IMAGE_BYTES:
                raise ValueError(f"{size:,} bytes, more than {MAX_IMAGE_BYTES:,}")
            img = _decode(data, self.name(i))
            problem = "not a decodable image" if img is None else "smaller than 8 pixels"
        except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
            img, problem = None, str(exc)
        if img is None or min(img.shape) < 8:
            self.skipped += 1
            log.warning("%s: skipped texture (%s)", self.name(i), problem)
            return None
        return img


def _key(entry: tuple[str, str]) -> str:
    """An image's name inside its source: the archive member's path, else the file name."""
    container, member = entry
    return member if member else Path(container).name


def _base(entry: tuple[str, str]) -> str:
    return Path(_key(entry)).name


def procedural(kind: str, size: int, rng: np.random.Generator) -> np.ndarray:
    """float32[size, size] pattern in [0, 1]: smooth noise, shapes, gratings, checkers or a
    poster (:data:`PROCEDURAL_KINDS`)."""
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    if kind == "noise":  # fractal value noise: random grids of doubling resolution, smoothly
        img = np.zeros((size, size), np.float32)  # upsampled, amplitudes falling by 0.6
        for octave in range(5):
            cells = 4 * 2**octave + 1
            layer = cv2.resize(rng.standard_normal((cells, cells)).astype(np.float32),
                               (size, size), interpolation=cv2.INTER_CUBIC)
            img += layer * 0.6**octave
    elif kind == "shapes":
        img = np.full((size, size), rng.uniform(0, 1), np.float32)
        for _ in range(int(rng.integers(15, 60))):
            c = (int(rng.integers(0, size)), int(rng.integers(0, size)))
            r = int(rng.integers(size // 40, size // 6))
            color = float(rng.uniform(0, 1))
            if rng.random() < 0.5:
                cv2.ellipse(img, c, (r, int(r * rng.uniform(0.3, 1))), float(rng.uniform(0, 180)),
                            0, 360, color, -1, cv2.LINE_AA)
            else:
                pts = np.array(c) + rng.integers(-r, r + 1, (int(rng.integers(3, 7)), 2))
                cv2.fillPoly(img, [pts.astype(np.int32)], color, cv2.LINE_AA)
    elif kind == "poster":  # a flat ground, a few flat shapes far apart, any levels
        img = np.full((size, size), rng.uniform(0, 1), np.float32)
        for _ in range(int(rng.integers(6, 20))):
            c = (int(rng.integers(0, size)), int(rng.integers(0, size)))
            r = int(rng.integers(size // 40, size // 12))
            color = float(rng.uniform(0, 1))
            if rng.random() < 0.5:
                cv2.ellipse(img, c, (r, int(r * rng.uniform(0.4, 1))),
                            float(rng.uniform(0, 180)), 0, 360, color, -1, cv2.LINE_AA)
            else:  # a star or convex-ish polygon around the centre
                n = int(rng.integers(3, 8))
                angles = np.sort(rng.uniform(0, 2 * np.pi, n))
                radii = r * rng.uniform(0.4, 1.0, n)
                pts = np.array(c) + np.stack([radii * np.cos(angles), radii * np.sin(angles)], 1)
                cv2.fillPoly(img, [pts.round().astype(np.int32)], color, cv2.LINE_AA)
    elif kind in ("grating", "checker"):
        theta = rng.uniform(0, np.pi)
        period = size / rng.uniform(6, 30)
        u = (xx * np.cos(theta) + yy * np.sin(theta)) / period
        if kind == "grating":
            img = 0.5 + 0.5 * np.sin(2 * np.pi * u)
        else:
            v = (-xx * np.sin(theta) + yy * np.cos(theta)) / period
            img = ((np.floor(u) + np.floor(v)) % 2).astype(np.float32)
            img = cv2.GaussianBlur(img, (0, 0), 0.7)
    else:
        raise ValueError(f"unknown procedural texture {kind!r}; choose from "
                         f"{PROCEDURAL_KINDS}")
    img = img.astype(np.float32)
    return (img - img.min()) / max(float(img.max() - img.min()), 1e-9)


def flat_background(shape: tuple[int, int], rng: np.random.Generator,
                    level_range: tuple[float, float] = (0.05, 0.9)) -> np.ndarray:
    """float32[h, w] linear intensity: one level under a gentle illumination field.

    The level is drawn log-uniformly in ``level_range``; on it lie a linear gradient of up
    to +-20% across the plane and one broad Gaussian bump of up to +-15% (a lamp's fall-off,
    a shadow), so the field is smooth but not a constant. Used for the background of
    static-camera sequences (``objects.flat_background_share``).
    """
    h, w = shape
    lo, hi = level_range
    if not 0 < lo <= hi:
        raise ValueError(f"level_range must satisfy 0 < min <= max, got {level_range}")
    level = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = xx / max(w - 1, 1) - 0.5, yy / max(h - 1, 1) - 0.5
    theta = rng.uniform(0, 2 * np.pi)
    field = 1.0 + rng.uniform(0, 0.4) * (np.cos(theta) * u + np.sin(theta) * v)
    cx, cy = rng.uniform(-0.5, 0.5, 2)
    sigma = rng.uniform(0.2, 0.5)
    field += rng.uniform(-0.15, 0.15) * np.exp(-((u - cx) ** 2 + (v - cy) ** 2)
                                                / (2 * sigma**2))
    return np.clip(level * field, 1e-3, 1.0).astype(np.float32)


def normalised(img: np.ndarray) -> np.ndarray:
    """``img`` stretched so its 1st..99th percentiles span [0, 1] (clipped)."""
    lo, hi = np.percentile(img, (1, 99))
    return np.clip((img - lo) / max(float(hi - lo), 1e-6), 0.0, 1.0).astype(np.float32)


def detail(img: np.ndarray) -> float:
    """Mean absolute x+y gradient of ``img`` (values in [0, 1]) seen 256 texels wide."""
    h, w = img.shape
    small = cv2.resize(img, (256, max(2, round(256 * h / w))), interpolation=cv2.INTER_AREA)
    return float(np.abs(np.diff(small, axis=1)).mean() + np.abs(np.diff(small, axis=0)).mean())


class TextureSampler:
    """Draws a varied texture of a requested shape for each sequence."""

    def __init__(self, config: TextureConfig) -> None:
        self.config = config
        self.libraries = [ImageLibrary(src, config.exclude, config.split, config.test_fraction)
                          for src in config.sources]
        weights = np.asarray(config.source_weights or [1.0] * len(self.libraries), float)
        self._cum = np.cumsum(weights / weights.sum())
        self.flat = 0  # photo crops redrawn for lack of detail

    @property
    def skipped(self) -> int:
        return sum(lib.skipped for lib in self.libraries)

    def shape(self, aspect: float, width: int) -> tuple[int, int]:
        """(h, w) of the texture :meth:`sample` draws for a plane of ``aspect`` and
        ``width`` texels across (capped at ``max_texels`` on the longest side)."""
        scale = min(1.0, self.config.max_texels / max(width, width / aspect))
        w = max(16, int(round(width * scale)))
        return max(16, int(round(w / aspect))), w

    def sample(self, rng: np.random.Generator, aspect: float, width: int) -> tuple[np.ndarray,
                                                                                   str]:
        """(float32[h, w] linear texture with ``w/h ~= aspect``, its name).

        Args:
            aspect: width / height of the plane.
            width: texels across (capped at ``max_texels`` on the longest side).
        """
        cfg = self.config
        h, w = self.shape(aspect, width)
        for _ in range(50):
            if rng.random() < cfg.procedural_fraction:
                kinds = cfg.procedural_kinds
                kind = kinds[int(rng.integers(len(kinds)))]
                img = normalised(self._crop(procedural(kind, 1024, rng), aspect, rng))
                name = f"procedural:{kind}"
                break
            base, name = self._photo(rng)
            img = normalised(self._crop(base, aspect, rng))
            if detail(img) >= cfg.min_detail:
                break
            self.flat += 1
        else:
            raise ValueError(f"{cfg.source}: 50 texture crops in a row were flatter than "
                             f"min_detail={cfg.min_detail}")
        interp = cv2.INTER_AREA if w < img.shape[1] else cv2.INTER_CUBIC
        img = np.clip(cv2.resize(img, (w, h), interpolation=interp), 0.0, 1.0)
        img = img ** cfg.gamma if cfg.gamma != 1.0 else img
        low, high = rng.uniform(*cfg.low_range), rng.uniform(*cfg.high_range)
        return (low + (high - low) * img).astype(np.float32), name

    def _photo(self, rng: np.random.Generator) -> tuple[np.ndarray, str]:
        for _ in range(20):
            # a source drawn by weight (no draw with a single source)
            lib = self.libraries[0] if len(self.libraries) == 1 else \
                self.libraries[min(int(np.searchsorted(self._cum, rng.random(), "right")),
                                   len(self.libraries) - 1)]
            i = int(rng.integers(len(lib)))
            img = lib.read(i)
            if img is not None:
                return img, lib.name(i)
        raise ValueError(f"{self.config.source}: 20 consecutive textures were unreadable")

    def _crop(self, img: np.ndarray, aspect: float, rng: np.random.Generator) -> np.ndarray:
        img = np.rot90(img, int(rng.integers(4)))
        if rng.random() < 0.5:
            img = img[:, ::-1]
        ih, iw = img.shape
        frac = rng.uniform(*self.config.crop_fraction)
        w = min(iw, ih * aspect) * frac
        h = w / aspect
        x0 = rng.uniform(0, iw - w)
        y0 = rng.uniform(0, ih - h)
        crop = img[int(y0):int(y0 + h) + 1, int(x0):int(x0 + w) + 1]
        return np.ascontiguousarray(crop, np.float32)
