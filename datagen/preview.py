"""Pictures of simulated data: event images and labelled contact sheets, written as PNG."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from PIL import Image, ImageDraw, ImageFont

from datagen.shard import ShardReader
from esim_lite.atomic import atomic_path
from esim_lite.events import Events
from model.stacking import StackConfig, sbn_stack

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


def sequence_preview(reader: ShardReader, name: str, stacks: StackConfig, rows: int = 2
                     ) -> np.ndarray:
    """Contact sheet of one stored sequence: for a few frames, the LR frame, each HR frame,
    the events since the previous frame and the SBN stack ending at the frame."""
    attrs = reader.group(name).attrs
    event_idx = reader.frame_event_idx(name)
    t_ns = reader.frame_times_ns(name)
    cams = [c for c in reader.frame_names(name)]
    picks = np.unique(np.linspace(1, len(t_ns) - 1, rows + 2).round().astype(int)[1:-1]) \
        if len(t_ns) > 2 else np.arange(1, len(t_ns))
    panels = []
    for k in picks:
        row = [(gray_to_rgb(reader.frame(name, c, int(k))),
                f"{c} {reader.group(name)['frames'][c].shape[2]}x"
                f"{reader.group(name)['frames'][c].shape[1]}  frame {k}") for c in cams]
        between = reader.events(name, int(event_idx[k - 1]), int(event_idx[k]))
        row.append((event_image(between), f"events since frame {k - 1}: {len(between)}"))
        lo = max(0, int(event_idx[k]) - 2 * stacks.events_per_stack)
        window = reader.events(name, lo, int(event_idx[k]))
        stack = sbn_stack(window, stacks, end=len(window))
        row.append((stack_panel(stack.image), f"SBN stack ending at frame {k} "
                    f"({stack.end - stack.start} events)"))
        panels.append(row)
    title = (f"{reader.path.name}/{name}  texture {attrs['texture']}  renderer "
             f"{attrs['renderer']}\nC+ = {attrs['contrast_threshold_pos']:.3f}, "
             f"C- = {attrs['contrast_threshold_neg']:.3f}, {int(attrs['num_events']):,} events "
             f"over {float(attrs['duration']):.2f} s, {len(t_ns)} frames")
    return contact_sheet(panels, title)


def preview_shards(paths: list[Path], out_dir: str | Path, stacks: StackConfig
                   ) -> list[Path]:
    """Write one PNG per sequence of each shard into ``out_dir``; return their paths."""
    written = []
    for path in paths:
        with ShardReader(path) as reader:
            for name in reader.sequences():
                sheet = sequence_preview(reader, name, stacks)
                written.append(write_png(Path(out_dir) / f"{path.stem}_{name}.png", sheet))
    return written
