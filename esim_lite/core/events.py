"""The event stream record passed between every stage of e2sr."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Events:
    """A time-sorted batch of events from one sensor (struct of arrays).

    Attributes:
        x: int16[N] column, 0 <= x < W.
        y: int16[N] row, 0 <= y < H.
        t_ns: int64[N] timestamps in nanoseconds, non-decreasing.
        p: int8[N] polarity, +1 (brighter) or -1 (darker).
        sensor_hw: (H, W) of the sensor the coordinates refer to.
    """

    x: np.ndarray
    y: np.ndarray
    t_ns: np.ndarray
    p: np.ndarray
    sensor_hw: tuple[int, int]

    def __post_init__(self) -> None:
        n = len(self.t_ns)
        for name, dtype in (("x", np.int16), ("y", np.int16), ("t_ns", np.int64),
                            ("p", np.int8)):
            arr = getattr(self, name)
            if not isinstance(arr, np.ndarray) or arr.ndim != 1:
                raise ValueError(f"Events.{name} must be a 1-D numpy array")
            if arr.dtype != dtype:
                raise ValueError(f"Events.{name} must be {np.dtype(dtype)}, got {arr.dtype}")
            if len(arr) != n:
                raise ValueError(f"Events.{name} has {len(arr)} entries, t_ns has {n}")
        h, w = self.sensor_hw
        object.__setattr__(self, "sensor_hw", (int(h), int(w)))

    @classmethod
    def trusted(cls, x: np.ndarray, y: np.ndarray, t_ns: np.ndarray, p: np.ndarray,
                sensor_hw: tuple[int, int]) -> Events:
        """The record without the field checks, for a producer that made the arrays itself
        with these dtypes and equal lengths (the simulator's kernel, once per render
        sample); everything else goes through the checked constructor."""
        events = object.__new__(cls)
        for name, value in (("x", x), ("y", y), ("t_ns", t_ns), ("p", p),
                            ("sensor_hw", sensor_hw)):
            object.__setattr__(events, name, value)
        return events

    def __len__(self) -> int:
        return len(self.t_ns)

    @classmethod
    def empty(cls, sensor_hw: tuple[int, int]) -> Events:
        return cls(np.empty(0, np.int16), np.empty(0, np.int16), np.empty(0, np.int64),
                   np.empty(0, np.int8), sensor_hw)

    @classmethod
    def concatenate(cls, parts: list[Events], sensor_hw: tuple[int, int] | None = None
                    ) -> Events:
        """Join batches that are already in time order (the result stays sorted)."""
        if not parts:
            if sensor_hw is None:
                raise ValueError("Events.concatenate needs sensor_hw when given no parts")
            return cls.empty(sensor_hw)
        hw = parts[0].sensor_hw if sensor_hw is None else tuple(sensor_hw)
        if any(part.sensor_hw != hw for part in parts):
            raise ValueError("Events.concatenate: batches come from different sensor sizes")
        return cls(np.concatenate([e.x for e in parts]), np.concatenate([e.y for e in parts]),
                   np.concatenate([e.t_ns for e in parts]),
                   np.concatenate([e.p for e in parts]), hw)

    def slice(self, start: int, stop: int) -> Events:
        return Events(self.x[start:stop], self.y[start:stop], self.t_ns[start:stop],
                      self.p[start:stop], self.sensor_hw)

    def is_sorted(self) -> bool:
        return bool(np.all(np.diff(self.t_ns) >= 0))

    def validate(self, source: str = "events") -> None:
        """Raise ValueError naming ``source`` if coordinates, polarity or order are invalid."""
        h, w = self.sensor_hw
        if len(self) == 0:
            return
        if self.x.min() < 0 or self.x.max() >= w or self.y.min() < 0 or self.y.max() >= h:
            raise ValueError(f"{source}: event coordinates outside the {w}x{h} sensor")
        if not np.all(np.abs(self.p) == 1):
            raise ValueError(f"{source}: polarity must be +1 or -1")
        if not self.is_sorted():
            raise ValueError(f"{source}: timestamps are not sorted")

    def count_image(self) -> np.ndarray:
        """int32[2, H, W]: number of positive (0) and negative (1) events per pixel."""
        h, w = self.sensor_hw
        out = np.zeros((2, h * w), np.int32)
        flat = self.y.astype(np.int64) * w + self.x
        np.add.at(out[0], flat[self.p > 0], 1)
        np.add.at(out[1], flat[self.p < 0], 1)
        return out.reshape(2, h, w)

    def to_tonic(self) -> tuple[np.ndarray, tuple[int, int, int]]:
        """``(events, sensor_size)`` as tonic takes them: a structured array with fields
        ``x``, ``y`` (int16), ``t`` (int64 microseconds, floor of ``t_ns / 1000``) and ``p``
        (bool, True = ON), and ``sensor_size = (W, H, 2)``. tonic's transforms read ``t`` in
        the unit of their time arguments; microseconds are what its datasets use."""
        out = np.empty(len(self), TONIC_DTYPE)
        out["x"], out["y"] = self.x, self.y
        out["t"] = self.t_ns // 1000
        out["p"] = self.p > 0
        h, w = self.sensor_hw
        return out, (w, h, 2)


TONIC_DTYPE = np.dtype([("x", np.int16), ("y", np.int16), ("t", np.int64), ("p", np.bool_)])
