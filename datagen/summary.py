"""``datagen inspect``: what a shard holds, in numbers."""

from __future__ import annotations

from pathlib import Path

from datagen.shard import SequenceSummary, ShardReader


def _dynamics(s: SequenceSummary) -> str:
    """``; 3 objects, static camera; ground truth flow, depth, ids`` (empty for a sequence
    of a configuration with neither, so its line reads as before)."""
    text = ""
    if s.num_objects is not None:
        text += f"; {s.num_objects} object(s), {'static' if s.static_camera else 'moving'} camera"
    if s.ground_truth:
        text += f"; ground truth {', '.join(s.ground_truth)} (every camera)"
    return text


def _sensor(s: SequenceSummary) -> str:
    """A third line with the sequence's drawn sensor (empty without sensor ranges)."""
    v = s.sensor
    if v is None:
        return ""
    lamp = (f"{v['flicker_hz']:g} Hz depth {v['flicker_depth']:.2f} area "
            f"{v['flicker_area']:.2f}") if v["flicker_hz"] > 0 else "none"
    return (f"\n    sensor: refractory {v['refractory_ns'] / 1e3:g} us, mismatch "
            f"{v['mismatch_std']:.3f} + {v.get('mismatch_relative', 0.0):.1%} of C, shot "
            f"{v['shot_rate_hz']:.3g} Hz (bright x"
            f"{v['shot_bright_factor']:.2f}), leak {v['leak_rate_hz']:.3g} Hz, hot pixels "
            f"{v['hot_pixel_fraction']:.2%} at {v['hot_pixel_rate_hz']:.3g} Hz, cutoff "
            f"{v['cutoff_hz']:.3g} Hz" + (" (ideal)" if v["cutoff_hz"] == 0 else "")
            + f", lamp {lamp}")


def describe_shard(path: str | Path) -> str:
    """A human-readable summary of one shard: per sequence and totals."""
    lines, totals = [], {"events": 0, "frames": 0}
    with ShardReader(path) as reader:
        names = reader.sequences()
        size = Path(path).stat().st_size
        seed = "?" if reader.seed is None else reader.seed
        lines.append(f"{path}: {len(names)} sequence(s), {size / 1e6:.1f} MB, schema "
                     f"{reader.schema_version}, seed {seed}")
        versions = reader.versions
        lines.append("  versions: " + (", ".join(f"{k} {v}" for k, v in versions.items())
                                       if versions is not None else "not recorded"))
        for name in names:
            s = reader.summary(name)
            cams = ", ".join(f"{c} {w}x{h}" for c, (h, w) in s.frame_hw.items())
            per_cam = ", ".join(f"{c} {s.stored_bytes[c] / 1e6:.1f}" for c in s.frame_hw)
            lines.append(
                f"  {name}: {s.num_events:,} events ({s.num_pos:,} ON / "
                f"{s.num_neg:,} OFF) over {s.duration_s:.3f} s; "
                f"{s.num_frames} frames ({cams}, {s.frame_dtype}); "
                f"C+ {s.threshold_pos:.3f} C- {s.threshold_neg:.3f}"
                f"{' + per-pixel maps' if s.per_pixel_thresholds else ''}; texture {s.texture}; "
                f"renderer {s.renderer}{_dynamics(s)}\n"
                f"    stored MB: events {s.stored_bytes['events'] / 1e6:.1f}, frames {per_cam}"
                + "".join(f", {k} {s.stored_bytes[k] / 1e6:.1f}" for k in s.ground_truth)
                + _sensor(s))
            totals["events"] += s.num_events
            totals["frames"] += s.num_frames
    lines.append(f"  total: {totals['events']:,} events, {totals['frames']} frames")
    return "\n".join(lines)
