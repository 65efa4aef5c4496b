"""Domain randomisation of the simulated sensor: one event camera drawn per sequence.

A dataset's :class:`~esim_lite.events.simulator.EventConfig` is one fixed sensor apart from
the contrast thresholds. E2VID+ and V2V train on sensors spread over the range real cameras
span, which transfers better than matching one camera; :class:`SensorRanges` says which
of the sensor's other settings are drawn per sequence, and from where. Everything is off by
default: the config's fixed values are kept and nothing is drawn.

Each drawn value comes from its own uniform of a fixed-length vector drawn from the
sequence's ``sensor`` stream (see :func:`datagen.sampling.sequence_streams`), mapped
through its range (``lo + u (hi - lo)``, or the same in ``log`` for the names in
``log_uniform``). Turning one range on or off therefore leaves every other draw as it was.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from esim_lite.events.simulator import EventConfig

Range = tuple[float, float]

#: The fields holding a ``[min, max]`` range, each with its (lower, upper) limits.
RANGE_LIMITS: dict[str, tuple[float, float]] = {
    "mismatch_std": (0.0, math.inf),
    "refractory_us": (0.0, math.inf),
    "shot_rate_hz": (0.0, math.inf),
    "shot_bright_factor": (0.0, 1.0),
    "leak_rate_hz": (0.0, math.inf),
    "hot_pixel_fraction": (0.0, 1.0),
    "hot_pixel_rate_hz": (0.0, math.inf),
    "cutoff_hz": (0.0, math.inf),
    "flicker_depth": (0.0, 1.0),  # FlickerConfig.depth < 1, checked below
    "flicker_area": (0.0, 1.0),  # FlickerConfig.area_fraction > 0, checked below
    "mismatch_relative": (0.0, math.inf),
}
#: Rates and the cutoff span decades across real sensors: drawn uniformly in ``log``.
DEFAULT_LOG_UNIFORM = ("shot_rate_hz", "leak_rate_hz", "hot_pixel_rate_hz", "cutoff_hz")
#: Position of each uniform in the vector drawn per sequence (fixed; append only).
_SLOTS = (*RANGE_LIMITS, "bandwidth", "flicker", "flicker_frequency")
_NOISE_FIELDS = ("shot_rate_hz", "shot_bright_factor", "leak_rate_hz", "hot_pixel_fraction",
                 "hot_pixel_rate_hz")


@dataclass(frozen=True)
class SensorRanges:
    """Which sensor settings are drawn per sequence (all off: the config's sensor as is).

    Every range is ``[min, max]`` or None (keep ``simulation.events``' fixed value);
    ``min == max`` pins a value. Drawn uniformly, or log-uniformly for the names in
    ``log_uniform`` (their ranges need ``min > 0``).

    Attributes:
        mismatch_std: ``thresholds.mismatch_std`` (per-pixel threshold mismatch, log units).
        mismatch_relative: ``thresholds.mismatch_relative`` (mismatch as a share of the
            sequence's thresholds).
        refractory_us: ``refractory_ns`` in microseconds (rounded to the nanosecond).
        shot_rate_hz, shot_bright_factor, leak_rate_hz, hot_pixel_fraction,
            hot_pixel_rate_hz: the ``noise`` settings of the same names.
        cutoff_hz: ``bandwidth.cutoff_hz`` (photoreceptor low-pass at full brightness).
        bandwidth_share: probability that a sequence has the low-pass at all (its cutoff,
            drawn or fixed, is otherwise 0); 1 keeps it on every sequence that has one.
        flicker_share: probability that a sequence has a flickering lamp, at a frequency
            drawn from ``flicker_frequencies_hz`` (otherwise ``frequency_hz`` 0); None keeps
            the config's lamp (usually none).
        flicker_frequencies_hz: the lamp frequencies to choose from, equally likely (100 on
            50 Hz mains, 120 on 60 Hz).
        flicker_depth, flicker_area: the lamp's ``depth`` (max < 1) and ``area_fraction``
            (min > 0); used only by sequences that have a lamp.
        log_uniform: the range names drawn uniformly in ``log``.
    """

    mismatch_std: Range | None = None
    mismatch_relative: Range | None = None
    refractory_us: Range | None = None
    shot_rate_hz: Range | None = None
    shot_bright_factor: Range | None = None
    leak_rate_hz: Range | None = None
    hot_pixel_fraction: Range | None = None
    hot_pixel_rate_hz: Range | None = None
    cutoff_hz: Range | None = None
    bandwidth_share: float = 1.0
    flicker_share: float | None = None
    flicker_frequencies_hz: tuple[float, ...] = (100.0, 120.0)
    flicker_depth: Range | None = None
    flicker_area: Range | None = None
    log_uniform: tuple[str, ...] = DEFAULT_LOG_UNIFORM

    def __post_init__(self) -> None:
        for name, (low, high) in RANGE_LIMITS.items():
            value = getattr(self, name)
            if value is None:
                continue
            if len(value) != 2:
                raise ValueError(f"{name}: expected [min, max], got {value!r}")
            lo, hi = value
            if not low <= lo <= hi <= high:
                limits = f"{low} <= min <= max" + ("" if high == math.inf else f" <= {high}")
                raise ValueError(f"{name}: must satisfy {limits}, got {[lo, hi]}")
        if self.flicker_depth is not None and self.flicker_depth[1] >= 1:
            raise ValueError(f"flicker_depth: max must be < 1, got {self.flicker_depth[1]}")
        if self.flicker_area is not None and self.flicker_area[0] <= 0:
            raise ValueError(f"flicker_area: min must be > 0, got {self.flicker_area[0]}")
        unknown = [n for n in self.log_uniform if n not in RANGE_LIMITS]
        if unknown:
            raise ValueError(f"log_uniform: unknown name(s) {unknown} (valid: "
                             f"{', '.join(RANGE_LIMITS)})")
        for name in self.log_uniform:
            value = getattr(self, name)
            if value is not None and value[0] <= 0:
                raise ValueError(f"{name}: drawn log-uniformly, so min must be > 0, got "
                                 f"{list(value)} (or remove {name} from log_uniform)")
        for name in ("bandwidth_share", "flicker_share"):
            p = getattr(self, name)
            if p is not None and not 0 <= p <= 1:
                raise ValueError(f"{name}: a probability in [0, 1], got {p}")
        if not self.flicker_frequencies_hz or min(self.flicker_frequencies_hz) <= 0:
            raise ValueError(f"flicker_frequencies_hz: one or more frequencies > 0, got "
                             f"{list(self.flicker_frequencies_hz)}")

    @property
    def enabled(self) -> bool:
        """Whether anything is drawn (else every sequence has the config's sensor)."""
        return (any(getattr(self, n) is not None for n in RANGE_LIMITS)
                or self.bandwidth_share < 1 or self.flicker_share is not None)

    def _value(self, name: str, u: float) -> float | None:
        """Range ``name`` at quantile ``u`` in [0, 1) (None when the range is off)."""
        rng = getattr(self, name)
        if rng is None:
            return None
        lo, hi = rng
        if name in self.log_uniform:
            return float(math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))))
        return float(lo + u * (hi - lo))

    def draw(self, events: EventConfig, rng: np.random.Generator) -> EventConfig:
        """One sequence's sensor: ``events`` with the drawn values in place of its own.

        Always takes ``len(_SLOTS)`` uniforms from ``rng``, whichever ranges are on.
        """
        u = dict(zip(_SLOTS, rng.random(len(_SLOTS)).tolist()))
        v = {n: x for n in RANGE_LIMITS if (x := self._value(n, u[n])) is not None}
        thresholds = events.thresholds
        thresholds = dataclasses.replace(
            thresholds, **{n: v[n] for n in ("mismatch_std", "mismatch_relative") if n in v})
        noise = dataclasses.replace(events.noise,
                                    **{n: v[n] for n in _NOISE_FIELDS if n in v})
        cutoff = v.get("cutoff_hz", events.bandwidth.cutoff_hz)
        bandwidth = dataclasses.replace(
            events.bandwidth, cutoff_hz=cutoff if u["bandwidth"] < self.bandwidth_share else 0.0)
        flicker = events.flicker
        frequency = flicker.frequency_hz
        if self.flicker_share is not None:
            choices = self.flicker_frequencies_hz
            pick = choices[min(int(u["flicker_frequency"] * len(choices)), len(choices) - 1)]
            frequency = float(pick) if u["flicker"] < self.flicker_share else 0.0
        flicker = dataclasses.replace(flicker, frequency_hz=frequency,
                                      depth=v.get("flicker_depth", flicker.depth),
                                      area_fraction=v.get("flicker_area", flicker.area_fraction))
        refractory_ns = events.refractory_ns if "refractory_us" not in v else \
            int(round(v["refractory_us"] * 1e3))
        return dataclasses.replace(events, thresholds=thresholds, refractory_ns=refractory_ns,
                                   noise=noise, bandwidth=bandwidth, flicker=flicker)
