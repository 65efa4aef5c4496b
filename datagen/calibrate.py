"""``datagen calibrate``: a sensor preset measured from a real (or simulated) recording.

Reads any recording :func:`datagen.recording.open_recording` reads, runs the estimators
of :mod:`datagen.sensor_stats` and writes a partial datagen config (``simulation.events``
keys only, the existing ones) that ``datagen generate --config BASE --config PRESET``
loads on top of a dataset config. Ranges are centred on each estimate; comments give the
measured value, its uncertainty and how it was measured. What the recording cannot tell
(thresholds without frames, flicker in a recording without a line) is left to the base
config, and the preset says so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from datagen.sensor_stats import (
    HOT_RATIO,
    BackgroundActivity,
    Estimate,
    EventStats,
    Flicker,
    HotPixels,
    Thresholds,
    background_activity,
    event_stats,
    flicker,
    hot_pixels,
    refractory_period,
    thresholds,
)
from esim_lite.core.events import Events
from esim_lite.core.frames import Frames

#: The shortest recording calibrated: events, and seconds.
MIN_EVENTS = 1000
MIN_DURATION_S = 0.005
#: Frame intervals needed for thresholds.
MIN_FRAME_INTERVALS = 4
#: A flicker line also needs this share of pixels locked to it.
MIN_FLICKER_AREA = 1e-3
#: Thresholds assumed for flicker depth when the recording has no frames to measure them:
#: the middle of the E2VID/E2SRI training range (Rebecq et al., 2019).
DEFAULT_THRESHOLD = 0.18
#: Half-width of a threshold range around its estimate: this share of it, or two standard
#: uncertainties when larger.
RANGE_HALF_WIDTH = 0.15


@dataclass(frozen=True)
class Calibration:
    """What one recording says about its sensor.

    Attributes:
        source: the recording's path (and sequence); kind: its format; sensor_hw: (H, W).
        stats: rates, ON share, inter-event intervals; hot: hot pixels; background:
            background activity away from them; refractory: seconds (an upper bound unless
            bursts reach it); flicker: the 100/120 Hz line.
        thresholds: from frames, or None (``notes`` says why).
        notes: what could not be measured and why.
    """

    source: str
    kind: str
    sensor_hw: tuple[int, int]
    stats: EventStats
    hot: HotPixels
    background: BackgroundActivity
    refractory: Estimate
    flicker: Flicker
    thresholds: Thresholds | None
    notes: tuple[str, ...] = field(default=())

    @property
    def flicker_found(self) -> bool:
        return self.flicker.detected and self.flicker.area_fraction >= MIN_FLICKER_AREA


def calibrate_events(events: Events, frames: Frames | None, source: str = "<events>",
                     kind: str = "events") -> Calibration:
    """Measure a sensor from its ``events`` (and ``frames``, for the thresholds).

    Raises:
        ValueError: naming ``source``: fewer than ``MIN_EVENTS`` events or shorter than
            ``MIN_DURATION_S``.
    """
    if len(events) < MIN_EVENTS:
        raise ValueError(f"{source}: {len(events)} events; calibration needs at least "
                         f"{MIN_EVENTS}")
    span = (int(events.t_ns[-1]) - int(events.t_ns[0])) * 1e-9
    if span < MIN_DURATION_S:
        raise ValueError(f"{source}: the events span {span * 1e3:.2f} ms; calibration needs "
                         f"at least {MIN_DURATION_S * 1e3:.0f} ms")
    notes = []
    stats = event_stats(events)
    hot = hot_pixels(events)
    background = background_activity(events, hot.mask)
    if not math.isfinite(background.rate_hz.value):
        notes.append("background activity: no quiet space-time found (the scene fires "
                     "everywhere); kept from the base config")
    refractory = refractory_period(events, hot.mask)
    if not math.isfinite(refractory.value):
        notes.append("refractory period: fewer than 100 same-pixel intervals; kept from the "
                     "base config")
    lamp = flicker(events, hot.mask)
    measured = None
    if frames is None or len(frames) < 2:
        notes.append("thresholds need APS frames, and the recording has none: kept from "
                     "the base config")
    elif len(frames) - 1 < MIN_FRAME_INTERVALS:
        notes.append(f"thresholds: {len(frames) - 1} frame interval(s), fewer than "
                     f"{MIN_FRAME_INTERVALS}; kept from the base config")
    else:
        try:
            measured = thresholds(events, frames, exclude=hot.mask, background=background)
        except ValueError as exc:
            notes.append(f"thresholds: {exc}; kept from the base config")
    if measured is not None and not (measured.pos.value > 0 and measured.neg.value > 0):
        notes.append(f"thresholds: the fit gave C+ {measured.pos.value:.3g}, C- "
                     f"{measured.neg.value:.3g}, not both positive; kept from the base config")
        measured = None
    return Calibration(source, kind, events.sensor_hw, stats, hot, background, refractory,
                       lamp, measured, tuple(notes))


PRESET_HEADER = "# Sensor preset measured from"
"""The first words of every preset :func:`preset_yaml` writes (how ``calibrate --out``
knows a file it may replace)."""


def is_preset(path: Path) -> bool:
    """Whether ``path`` is a preset this command wrote (its first line says so)."""
    try:
        with open(path, "rb") as f:
            return f.read(len(PRESET_HEADER)) == PRESET_HEADER.encode()
    except OSError:
        return False


def calibrate_recording(path: str | Path, sensor_hw: tuple[int, int] | None = None,
                        sequence: str | None = None) -> Calibration:
    """Open ``path`` (any format ``reconstruct`` reads) and calibrate it.

    Raises:
        FileNotFoundError, ValueError: naming the file: missing, unreadable, empty or too
            short.
    """
    from datagen.recording import open_recording  # the readers, only when calibrating

    rec = open_recording(path, sensor_hw, sequence)
    events = rec.read_all()
    source = str(path) if sequence is None else f"{path} ({sequence})"
    frames = rec.frames
    if frames is not None and frames.hw != events.sensor_hw:
        frames = None
    return calibrate_events(events, frames, source, rec.kind)


def _rng(est: Estimate) -> list[float]:
    half = max(RANGE_HALF_WIDTH * est.value, 2 * est.std if math.isfinite(est.std) else 0.0)
    return [round(max(est.value - half, 0.01), 4), round(est.value + half, 4)]


def _g(value: float, digits: int = 3) -> float:
    """``value`` rounded to ``digits`` significant digits (a plain float for YAML)."""
    if value == 0 or not math.isfinite(value):
        return float(value)
    return float(f"{value:.{digits}g}")


def _name(cal: Calibration) -> str:
    return Path(cal.source.split(" (")[0]).name or cal.source


def _pick(cals: Sequence[Calibration], value) -> Calibration | None:
    """The calibration with the smallest finite ``value(cal)`` (each one an upper bound)."""
    finite = [c for c in cals if math.isfinite(value(c))]
    return min(finite, key=value) if finite else None


def preset_yaml(cals: Calibration | Sequence[Calibration], command: str = "") -> str:
    """The preset: a partial datagen config with a comment on every measured value.

    From several recordings of one sensor, each value comes from where it is measured
    best, and the comment names that recording: thresholds are the inverse-variance mean
    over the recordings with frames; the refractory period, the background activity and
    the hot-pixel share are each the smallest over the recordings (each recording only
    bounds them from above: a slow scene hides the refractory wall, signal leaks into
    quiet cells, flickering spots look hot); a lamp's flicker is the light, not the sensor,
    so it is kept only when every recording has it.
    """
    cals = [cals] if isinstance(cals, Calibration) else list(cals)
    if not cals:
        raise ValueError("a preset needs at least one calibrated recording")
    hws = {c.sensor_hw for c in cals}
    if len(hws) > 1:
        raise ValueError(f"the recordings come from sensors of different sizes: "
                         f"{sorted(hws)}; calibrate one sensor at a time")
    lines = _header_lines(cals, command)
    lines += ["simulation:", "  events:",
              "    random_start: true   # a running sensor's pixels stand anywhere between "
              "their levels"]
    with_thr = [c for c in cals if c.thresholds is not None]
    if with_thr:
        lines += ["    thresholds:"] + _threshold_lines(with_thr)
    else:
        on = sum(c.stats.on_fraction * c.stats.events for c in cals) / sum(
            c.stats.events for c in cals)
        lines += ["    # thresholds: none of the recordings has frames; the base config's stay.",
                  f"    # The ON share {on:.3f} implies C+/C- = {(1 - on) / on:.2f} where the "
                  "light ends where it began",
                  "    # (C+ N_on = C- N_off; leak and noise events aside)"]
    lines += _refractory_lines(cals)
    lines += ["    noise:"] + _noise_lines(cals)
    lines += ["    flicker:"] + _flicker_lines(cals, with_thr)
    return "\n".join(lines) + "\n"


def _header_lines(cals: Sequence[Calibration], command: str) -> list[str]:
    """The comments on top: the sensor, how to load the preset, and each recording's stats."""
    h, w = cals[0].sensor_hw
    lines = [f"{PRESET_HEADER} {len(cals)} recording(s) of one {w}x{h} sensor.",
             *([f"# Made by: {command}"] if command else []),
             "# Loads on top of a dataset config: datagen generate --config BASE.yaml "
             "--config THIS.yaml ...",
             "# Estimators and their assumptions: datagen/sensor_stats.py; how the presets "
             "were made: docs/sensors.md."]
    for cal in cals:
        st = cal.stats
        lines += [f"# {_name(cal)} ({cal.kind}): {st.events:,} events in "
                  f"{st.duration_s:.3f} s, {st.rate_hz:.3g} events/pixel/s, ON share "
                  f"{st.on_fraction:.3f}, {st.active_fraction:.1%} of pixels active; "
                  "inter-event intervals p1/p10/p50/p90/p99 (ms) "
                  + "/".join(f"{v:.3g}" for v in st.iei_ms)]
        lines += [f"#   not measured: {n}." for n in cal.notes]
    return lines


def _refractory_lines(cals: Sequence[Calibration]) -> list[str]:
    """``refractory_ns`` from the recording that bounds it lowest (none if none does)."""
    ref = _pick(cals, lambda c: c.refractory.value)
    if ref is None:
        return []
    r = ref.refractory
    return [f"    # {r.value * 1e3:.3g} +- {r.std * 1e3:.2g} ms, the 0.1% quantile of "
            f"a pixel's inter-event intervals in {_name(ref)} (the smallest over the "
            "recordings; an upper bound when no scene makes a pixel burst)",
            f"    refractory_ns: {int(round(r.value * 1e9, -3))}"]


def _noise_lines(cals: Sequence[Calibration]) -> list[str]:
    """The ``noise`` section: background activity from the quietest recording, hot pixels
    from the one with the fewest."""
    lines = []
    quiet = _pick(cals, lambda c: c.background.rate_hz.value)
    if quiet is not None:
        bg = quiet.background
        lines += [f"      # background activity {bg.rate_hz} Hz per pixel, ON share "
                  f"{bg.on_fraction}, in {_name(quiet)} ({bg.events} events in quiet "
                  f"{bg.bin_s * 1e3:.3g} ms cells, {bg.quiet_fraction:.0%} of the "
                  "pixel-time); leak fires ON only, shot noise either way",
                  f"      shot_rate_hz: {_g(bg.shot_hz)}",
                  f"      leak_rate_hz: {_g(bg.leak_hz)}"]
    hot_cal = min(cals, key=lambda c: c.hot.fraction)
    hot = hot_cal.hot
    lines += [f"      # hot pixels (>= {HOT_RATIO:g}x the busiest neighbour): "
              + ", ".join(f"{int(c.hot.mask.sum())} in {_name(c)}" for c in cals)
              + (f"; median {hot.rate_hz:.3g} Hz" if hot.mask.any() else ""),
              f"      hot_pixel_fraction: {_g(hot.fraction)}",
              f"      hot_pixel_rate_hz: {_g(hot.rate_hz) if hot.mask.any() else 0.0}"]
    return lines


def _threshold_lines(cals: Sequence[Calibration]) -> list[str]:
    def mean(get) -> Estimate:
        est = [get(c.thresholds) for c in cals]
        ok = [e for e in est if math.isfinite(e.value)]
        if not ok:
            return Estimate(math.nan, math.nan)
        weights = [1 / max(e.std, 1e-6) ** 2 if math.isfinite(e.std) else 1.0 for e in ok]
        value = sum(wt * e.value for wt, e in zip(weights, ok)) / sum(weights)
        return Estimate(value, 1 / math.sqrt(sum(weights)) if len(ok) > 1 else ok[0].std)

    pos, neg = mean(lambda t: t.pos), mean(lambda t: t.neg)
    spread = mean(lambda t: t.mismatch)
    where = ", ".join(f"{_name(c)} ({c.thresholds.intervals} frame intervals)" for c in cals)
    lines = [f"      # C+ {pos}, C- {neg} from {where}: an ideal pixel replayed on the log "
             "frames fires as many ON and OFF events as the sensor (uncertainty: bootstrap "
             "over pixels)",
             f"      pos_range: {_rng(pos)}",
             f"      neg_range: {_rng(neg)}"]
    if math.isfinite(spread.value):
        mismatch = spread.value * (pos.value + neg.value) / 2
        lines += [f"      # pixel-to-pixel spread {spread} of the mean threshold (per-pixel "
                  "gains of the first and second half of the frames)",
                  f"      mismatch_std: {_g(mismatch)}"]
    return lines


def _flicker_lines(cals: Sequence[Calibration], with_thr: Sequence[Calibration]
                   ) -> list[str]:
    seen = "; ".join(
        f"{_name(c)}: " + (f"{c.flicker.frequency_hz:.0f} Hz line {c.flicker.line_ratio:.3g}x "
                           f"the spectrum nearby, {c.flicker.area_fraction:.2%} of pixels "
                           f"locked" if math.isfinite(c.flicker.line_ratio) else "too short")
        for c in cals)
    if not all(c.flicker_found for c in cals):
        return [f"      # no flicker kept ({seen}): a lamp is the light, not the sensor",
                "      frequency_hz: 0.0"]
    lamp = max(cals, key=lambda c: c.flicker.area_fraction).flicker
    c_pos = with_thr[0].thresholds.pos.value if with_thr else DEFAULT_THRESHOLD
    c_neg = with_thr[0].thresholds.neg.value if with_thr else DEFAULT_THRESHOLD
    depth = min(lamp.depth(c_pos, c_neg), 0.95)
    return [f"      # {seen}; {lamp.events_per_cycle:.3g} events per cycle at the locked "
            "pixels"
            + ("" if with_thr else f" (depth for thresholds {DEFAULT_THRESHOLD}: no frames)"),
            f"      frequency_hz: {lamp.frequency_hz:.1f}",
            f"      depth: {_g(depth)}",
            f"      area_fraction: {_g(max(lamp.area_fraction, 1e-3))}"]


def summary_table(cal: Calibration) -> str:
    """A text table of the measured values, for the terminal."""
    st, bg, thr = cal.stats, cal.background, cal.thresholds
    rows = [("events", f"{st.events:,} in {st.duration_s:.3f} s"),
            ("events / pixel / s", f"{st.rate_hz:.4g}"),
            ("ON share", f"{st.on_fraction:.3f}"),
            ("inter-event interval p1/p10/p50 (ms)",
             "/".join(f"{v:.3g}" for v in st.iei_ms[:3])),
            ("background activity (Hz / pixel)", str(bg.rate_hz)),
            ("background ON share", str(bg.on_fraction)),
            ("hot pixels", f"{int(cal.hot.mask.sum())} ({cal.hot.fraction:.2e})"),
            ("refractory (ms, upper bound)",
             f"{cal.refractory.value * 1e3:.3g} +- {cal.refractory.std * 1e3:.2g}"),
            ("flicker", f"{cal.flicker.frequency_hz:.0f} Hz x{cal.flicker.line_ratio:.3g}, "
                        f"{cal.flicker.area_fraction:.2%} of pixels"
             if math.isfinite(cal.flicker.line_ratio) else "n/a"),
            ("C+", str(thr.pos) if thr else "needs frames"),
            ("C-", str(thr.neg) if thr else "needs frames"),
            ("threshold spread (relative)", str(thr.mismatch) if thr else "needs frames")]
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)
