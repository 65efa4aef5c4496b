"""Image files in, with bounded memory: the size is read from the header before anything
is decoded, so a few kilobytes that claim a huge image are refused instead of decoded."""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import cv2
import numpy as np

from esim_lite.core.limits import MAX_IMAGE_BYTES, MAX_IMAGE_PIXELS, check_image_pixels


def image_hw(data: bytes) -> tuple[int, int] | None:
    """(H, W) an encoded image's header states, or None when it is no image Pillow knows."""
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Pillow's own bomb warning: we refuse below
            with Image.open(io.BytesIO(data)) as img:
                w, h = img.size
    except Image.DecompressionBombError:
        return (MAX_IMAGE_PIXELS + 1, 1)  # past Pillow's own (higher) limit
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        return None
    return int(h), int(w)


def decode_image(data: bytes, source: str | Path,
                 flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray | None:
    """OpenCV's decoding of ``data`` (BGR channel order), or None when it is no decodable
    image (empty, not an image, corrupt).

    Raises:
        ValueError: naming ``source``: the header states more than
            :data:`esim_lite.core.limits.MAX_IMAGE_PIXELS` pixels.
    """
    hw = image_hw(data) if data else None
    if hw is None:
        return None
    check_image_pixels(hw, source)
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    except cv2.error:
        return None
    return None if img is None or img.size == 0 else img


def read_image(path: str | Path, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray | None:
    """:func:`decode_image` of the file at ``path`` (None when it cannot be read)."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_IMAGE_BYTES:
            raise ValueError(f"{path}: {path.stat().st_size:,} bytes, more than e2sr reads "
                             f"as one image ({MAX_IMAGE_BYTES:,})")
        data = path.read_bytes()
    except OSError:
        return None
    return decode_image(data, path, flags)
