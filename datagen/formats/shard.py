"""e2sr's own shards (``shard_*.h5``), read through :class:`datagen.shard.ShardReader`."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

from datagen.formats.base import FrameBudget, Recording, check_field_dtype
from datagen.formats.event_utils import FIELDS
from datagen.shard import ShardReader
from esim_lite.core.events import Events


def open_shard(path: Path, sequence: str | None, sensor_hw: tuple[int, int] | None = None
               ) -> Recording:
    """One sequence of a shard (default the first); ``sensor_hw`` overrides the stored size."""
    with ShardReader(path) as reader:
        names = reader.sequences()
        name = sequence or names[0]
        if name not in names:
            raise ValueError(f"{path}: no sequence {name!r} (it has {', '.join(names)})")
        for k, dtype in reader.event_dtypes(name).items():
            check_field_dtype(path, f"{name}/events/{k}", dtype, FIELDS[k])
        hw = sensor_hw or reader.sensor_hw(name)
        stored = reader.frame_shape(name, "lr")
        FrameBudget(path).take(stored[1:], f"{name}/frames/lr", stored[0])
        frames = reader.frames(name, "lr")
        total = reader.num_events(name)

    def chunks(size: int) -> Iterator[Events]:
        with ShardReader(path) as r:
            for start in range(0, total, size):
                ev = r.events(name, start, min(start + size, total))
                yield ev if ev.sensor_hw == hw else replace(ev, sensor_hw=hw)

    return Recording(path, "shard", hw, frames, chunks)
