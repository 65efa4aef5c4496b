"""Pictures every stage draws: event images, grey panels, labelled contact sheets, PNGs.

The bottom floor's drawing kit: datagen's previews, training's validation sheets and
evaluate's figures all use these, so an event looks the same in every picture.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from PIL import Image, ImageDraw, ImageFont

from esim_lite.core.atomic import atomic_path
from esim_lite.core.events import Events

ON_COLOR = np.array([220, 40, 40], np.uint8)  # red: brighter
OFF_COLOR = np.array([40, 70, 230], np.uint8)  # blue: darker


def gray_to_rgb(img: np.ndarray, lo: float = 0.0, hi: float = 1.0) -> np.ndarray:
    """uint8[H, W, 3] of a float image shown from ``lo`` (black) to ``hi`` (white)."""
    g = np.clip((img - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    return np.repeat((g * 255 + 0.5).astype(np.uint8)[..., None], 3, axis=2)


def event_image(events: Events, t0_ns: int | None = None, t1_ns: int | None = None
                ) -> np.ndarray:
    """uint8[H, W, 3]: events in ``[t0, t1)`` on white, red for net ON, blue for net OFF,
    saturation by the number of events at the pixel."""
    h, w = events.sensor_hw
    lo = 0 if t0_ns is None else int(np.searchsorted(events.t_ns, t0_ns, "left"))
    hi = len(events) if t1_ns is None else int(np.searchsorted(events.t_ns, t1_ns, "left"))
    counts = events.slice(lo, hi).count_image().astype(np.float32)
    net = counts[0] - counts[1]
    strength = np.clip(np.abs(net) / 3.0, 0.0, 1.0)[..., None]
    color = np.where((net > 0)[..., None], ON_COLOR, OFF_COLOR).astype(np.float32)
    img = 255.0 * (1 - strength) + color * strength
    return img.astype(np.uint8).reshape(h, w, 3)


def fit(img: np.ndarray, height: int) -> np.ndarray:
    """Resize an RGB panel to ``height`` (nearest when enlarging: pixels stay visible)."""
    h, w = img.shape[:2]
    width = max(1, round(w * height / h))
    interp = cv2.INTER_NEAREST if height >= h else cv2.INTER_AREA
    return cv2.resize(img, (width, height), interpolation=interp)


def contact_sheet(rows: list[list[tuple[np.ndarray, str]]], title: str, height: int = 256,
                  pad: int = 6) -> np.ndarray:
    """uint8[H, W, 3] grid of labelled RGB panels (each row a list of (panel, label))."""
    font = ImageFont.load_default()
    label_h, title_h = 16, 22 + 14 * title.count("\n")
    rendered = [[(fit(p, height), label) for p, label in row] for row in rows]
    width = max(sum(p.shape[1] + pad for p, _ in row) + pad for row in rendered)
    total_h = title_h + len(rendered) * (height + label_h + pad) + pad
    canvas = Image.new("RGB", (width, total_h), (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    draw.multiline_text((pad, 4), title, fill=(0, 0, 0), font=font)
    y = title_h
    for row in rendered:
        x = pad
        for panel, label in row:
            draw.text((x, y), label, fill=(0, 0, 0), font=font)
            canvas.paste(Image.fromarray(panel), (x, y + label_h))
            x += panel.shape[1] + pad
        y += height + label_h + pad
    return np.asarray(canvas)


def write_png(path: str | Path, rgb: np.ndarray) -> Path:
    """Write uint8 RGB ``rgb`` to ``path`` atomically (temporary name, then rename)."""
    path = Path(path)
    with atomic_path(path, ".tmp.png") as tmp:
        Image.fromarray(rgb).save(tmp, format="PNG")
    return path


def stack_panel(stack: np.ndarray) -> np.ndarray:
    """uint8[H, c*W + gaps, 3]: an SBN stack's channels side by side, oldest first."""
    c, h, w = stack.shape
    gap = np.full((h, 2), 255, np.uint8)
    parts = []
    for k in range(c):
        parts += [stack[k], gap] if k < c - 1 else [stack[k]]
    return np.repeat(np.concatenate(parts, axis=1)[..., None], 3, axis=2)
