"""Pictures every stage draws: event images, grey panels, flow and surface-id colourings,
labelled contact sheets, PNGs.

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


#: Colour of the background (surface id 0) in :func:`ids_to_rgb`: dark grey.
BACKGROUND_COLOR = np.array([64, 64, 64], np.uint8)
_GOLDEN = 0.6180339887498949  # hue step between consecutive ids: never repeats


def hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """uint8[..., 3] from hue in [0, 1) (0 red, 1/3 green, 2/3 blue), saturation and value
    in [0, 1] (arrays of one shape)."""
    h6 = (np.asarray(h, np.float64) % 1.0) * 6.0
    s, v = np.asarray(s, np.float64), np.asarray(v, np.float64)
    sector = np.floor(h6).astype(np.int64) % 6
    f = h6 - np.floor(h6)
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    r = np.choose(sector, [v, q, p, p, t, v])
    g = np.choose(sector, [t, v, v, q, p, p])
    b = np.choose(sector, [p, p, t, v, v, q])
    return np.clip(np.round(np.stack([r, g, b], axis=-1) * 255.0), 0, 255).astype(np.uint8)


def flow_scale(flow: np.ndarray, percentile: float = 99.0) -> float:
    """A robust largest flow magnitude (the ``percentile`` of the finite magnitudes of
    ``flow`` [2, H, W] or [T, 2, H, W]) for :func:`flow_to_rgb`; 1 for all-zero flow."""
    flow = np.asarray(flow, np.float64)
    mag = np.hypot(flow[..., 0, :, :], flow[..., 1, :, :])
    mag = mag[np.isfinite(mag)]
    scale = float(np.percentile(mag, percentile)) if mag.size else 0.0
    return scale if scale > 0 else 1.0


def flow_to_rgb(flow: np.ndarray, scale: float | None = None) -> np.ndarray:
    """uint8[H, W, 3] colour wheel of ``flow`` [2, H, W] (channel 0 = x, image axes: +y
    down), Middlebury style: hue is the direction (+x red, +y yellow-green, -x cyan, -y
    violet: hue = atan2(y, x) / 2 pi), saturation the magnitude over ``scale`` (clipped
    at 1), value 1, so zero flow is white; non-finite flow is black. ``scale`` defaults to
    :func:`flow_scale` of ``flow``; say it in the picture's label."""
    flow = np.asarray(flow, np.float64)
    if flow.ndim != 3 or flow.shape[0] != 2:
        raise ValueError(f"flow must be [2, H, W], got shape {flow.shape}")
    scale = flow_scale(flow) if scale is None else float(scale)
    if not scale > 0:
        raise ValueError(f"flow scale must be positive, got {scale}")
    u, v = flow
    finite = np.isfinite(u) & np.isfinite(v)
    u, v = np.where(finite, u, 0.0), np.where(finite, v, 0.0)
    hue = (np.arctan2(v, u) / (2 * np.pi)) % 1.0
    rgb = hsv_to_rgb(hue, np.clip(np.hypot(u, v) / scale, 0.0, 1.0), np.ones_like(u))
    rgb[~finite] = 0
    return rgb


def ids_to_rgb(ids: np.ndarray) -> np.ndarray:
    """uint8[H, W, 3] of surface ids: 0 (background) dark grey, every other id its own
    bright colour (hues a golden-ratio step apart, value alternating 1 / 0.8), the same
    id the same colour in every picture."""
    ids = np.asarray(ids)
    if not np.issubdtype(ids.dtype, np.integer):
        raise ValueError(f"ids must be integers, got {ids.dtype}")
    if ids.size and ids.min() < 0:
        raise ValueError(f"ids must be non-negative, got {ids.min()}")
    k = np.arange(int(ids.max(initial=0)) + 1)
    palette = hsv_to_rgb(k * _GOLDEN, np.full(k.shape, 0.85), np.where(k % 2, 1.0, 0.8))
    palette[0] = BACKGROUND_COLOR
    return palette[ids]
