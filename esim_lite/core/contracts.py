"""Agreements between stages, each written once.

The simulator names its HR cameras, datagen offers scales and lays frames between events,
the network knows projection kernels for some scales, and reconstruction reads recordings
in chunks: where two stages must agree, the value lives here and a check says when they
do not.
"""

from __future__ import annotations

from collections.abc import Iterable

SCALES = (2, 4, 8)
"""Super-resolution factors: the HR cameras datagen renders, the factors the network has
projection kernels for, and the ``--scale`` choices of every CLI."""

TRAINED_SENSOR_HW = (128, 128)
"""(H, W) of the paper's simulated event camera: what a checkpoint that does not record its
training sensor was trained on."""

READ_CHUNK_EVENTS = 1_000_000
"""Events read at a time when streaming a recording (bounded memory at any length)."""


def hr_camera(scale: int) -> str:
    """Name of the HR intensity camera ``scale`` times the event camera's resolution."""
    return f"hr_x{scale}"


def check_scales(scales: Iterable[int], what: str = "scale") -> tuple[int, ...]:
    """``scales`` as a tuple if every one is in :data:`SCALES`, else a ValueError."""
    out = tuple(scales)
    if not out or any(s not in SCALES for s in out):
        raise ValueError(f"{what} must be {', '.join(map(str, SCALES[:-1]))} or {SCALES[-1]} "
                         f"(or several of them); got {', '.join(map(str, out)) or 'none'}")
    return out


def stack_fit_warnings(every_events: int, tail_events: int, events_per_stack: int,
                       n_stacks: int, overlap: int = 0) -> list[str]:
    """Why frames laid out by datagen (one every ``every_events`` events, ``tail_events``
    after the last) fit the training stacks badly: empty when they agree.

    A sample needs ``events_per_stack + half * step`` events before its frame and
    ``half * step`` after it (``step = events_per_stack - overlap``, ``half = n_stacks // 2``).
    """
    half, step = n_stacks // 2, events_per_stack - overlap
    out = []
    if tail_events < half * step:
        out.append(f"{tail_events:,} events after the last frame, but {n_stacks} stacks of "
                   f"{events_per_stack:,} need {half * step:,}: the last frames go unused")
    if every_events > events_per_stack:
        out.append(f"frames every {every_events:,} events but stacks of {events_per_stack:,}: "
                   "events between stacks are never seen by the network")
    return out
