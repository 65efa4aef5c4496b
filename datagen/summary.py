"""``datagen inspect``: what a shard holds, in numbers."""

from __future__ import annotations

from pathlib import Path

import h5py

from datagen.shard import ShardReader


def _stored_bytes(group: h5py.Group) -> int:
    total = 0

    def visit(_, obj) -> None:
        nonlocal total
        if isinstance(obj, h5py.Dataset):
            total += obj.id.get_storage_size()

    group.visititems(visit)
    return total


def describe_shard(path: str | Path) -> str:
    """A human-readable summary of one shard: per sequence and totals."""
    lines, totals = [], {"events": 0, "frames": 0}
    with ShardReader(path) as reader:
        names = reader.sequences()
        size = Path(path).stat().st_size
        lines.append(f"{path}: {len(names)} sequence(s), {size / 1e6:.1f} MB, schema "
                     f"{reader.file.attrs['schema_version']}, seed "
                     f"{reader.file.attrs.get('seed', '?')}")
        for name in names:
            g = reader.group(name)
            a = g.attrs
            fr = g["frames"]
            names_fr = reader.frame_names(name)
            cams = ", ".join(f"{c} {fr[c].shape[2]}x{fr[c].shape[1]}" for c in names_fr)
            per_cam = ", ".join(f"{c} {fr[c].id.get_storage_size() / 1e6:.1f}"
                                for c in names_fr)
            lines.append(
                f"  {name}: {int(a['num_events']):,} events ({int(a['num_pos']):,} ON / "
                f"{int(a['num_neg']):,} OFF) over {float(a['duration']):.3f} s; "
                f"{fr['ts'].shape[0]} frames ({cams}, {a['frame_dtype']}); "
                f"C+ {a['contrast_threshold_pos']:.3f} C- {a['contrast_threshold_neg']:.3f}"
                f"{' + per-pixel maps' if 'thresholds' in g else ''}; texture {a['texture']}; "
                f"renderer {a['renderer']}\n"
                f"    stored MB: events {_stored_bytes(g['events']) / 1e6:.1f}, frames {per_cam}")
            totals["events"] += int(a["num_events"])
            totals["frames"] += fr["ts"].shape[0]
    lines.append(f"  total: {totals['events']:,} events, {totals['frames']} frames")
    return "\n".join(lines)
