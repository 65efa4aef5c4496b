"""Pictures of simulated data: event images and labelled contact sheets, written as PNG."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from datagen.shard import ShardReader
from esim_lite.core.figures import (
    contact_sheet,
    event_image,
    flow_scale,
    flow_to_rgb,
    gray_to_rgb,
    ids_to_rgb,
    stack_panel,
    write_png,
)
from esim_lite.core.outputs import OutputFolder, claim
from esim_lite.core.stacking import StackConfig, sbn_stack


def sequence_preview(reader: ShardReader, name: str, stacks: StackConfig, rows: int = 2
                     ) -> np.ndarray:
    """Contact sheet of one stored sequence: for a few frames, the LR frame, each HR frame,
    the events since the previous frame, the SBN stack ending at the frame and, when the
    shard holds them, the LR flow (colour wheel, one scale for the whole sheet) and
    surface ids."""
    info = reader.summary(name)
    event_idx = reader.frame_event_idx(name)
    t_ns = reader.frame_times_ns(name)
    cams = [c for c in reader.frame_names(name)]
    # frames after the first (each has events since the one before); a sequence whose
    # events filled less than one frame interval has only frame 0 (a static camera
    # watching little motion), shown with the events up to it
    picks = np.unique(np.linspace(1, len(t_ns) - 1, rows + 2).round().astype(int)[1:-1]) \
        if len(t_ns) > 2 else np.arange(1, len(t_ns)) if len(t_ns) == 2 else np.arange(len(t_ns))
    truth = reader.ground_truth_kinds(name)
    scale = flow_scale(np.stack([reader.flow(name, "lr", int(k)) for k in picks])) \
        if "flow" in truth and len(picks) else 1.0
    panels = []
    for k in picks:
        row = [(gray_to_rgb(reader.frame(name, c, int(k))),
                f"{c} {info.frame_hw[c][1]}x{info.frame_hw[c][0]}  frame {k}") for c in cams]
        if k:
            between = reader.events(name, int(event_idx[k - 1]), int(event_idx[k]))
            row.append((event_image(between), f"events since frame {k - 1}: {len(between)}"))
        else:
            between = reader.events(name, 0, int(event_idx[0]))
            row.append((event_image(between), f"events before frame 0: {len(between)}"))
        lo = max(0, int(event_idx[k]) - 2 * stacks.events_per_stack)
        window = reader.events(name, lo, int(event_idx[k]))
        stack = sbn_stack(window, stacks, end=len(window))
        row.append((stack_panel(stack.image), f"SBN stack ending at frame {k} "
                    f"({stack.end - stack.start} events)"))
        if "flow" in truth:
            row.append((flow_to_rgb(reader.flow(name, "lr", int(k)), scale),
                        f"lr flow frame {k} (white 0, full colour {scale:.0f} px/s)"))
        if "ids" in truth:
            ids = reader.ids(name, "lr", int(k))
            seen = int(np.count_nonzero(np.unique(ids)))
            row.append((ids_to_rgb(ids), f"lr surface ids frame {k} ({seen} object(s))"))
        panels.append(row)
    title = (f"{reader.path.name}/{name}  texture {info.texture}  renderer "
             f"{info.renderer}\nC+ = {info.threshold_pos:.3f}, "
             f"C- = {info.threshold_neg:.3f}, {info.num_events:,} events "
             f"over {info.duration_s:.2f} s, {len(t_ns)} frames"
             + (f", {info.num_objects} object(s)" if info.num_objects is not None else "")
             + (", static camera" if info.static_camera else ""))
    return contact_sheet(panels, title)


def preview_names(paths: list[Path]) -> list[str]:
    """The ``fnmatch`` patterns of what :func:`preview_shards` writes for ``paths``."""
    return [f"{path.stem}_seq_*.png" for path in paths]


def preview_shards(paths: list[Path], out_dir: str | Path | OutputFolder, stacks: StackConfig
                   ) -> list[Path]:
    """Write one PNG per sequence of each shard into ``out_dir``; return their paths."""
    written = []
    for path in paths:
        with ShardReader(path) as reader:
            for name in reader.sequences():
                sheet = sequence_preview(reader, name, stacks)
                written.append(write_png(claim(out_dir) / f"{path.stem}_{name}.png", sheet))
    return written
