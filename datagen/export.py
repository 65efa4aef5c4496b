"""``datagen export``: one sequence of a shard in a format other tools read as it is.

- ``event_utils``: ``<shard>_<seq>.h5`` as event_utils' hdf5 packager lays it out (the
  layout E2VID+'s training loader reads): ``events/xs, ys`` int16, ``events/ts`` float64
  seconds, ``events/ps`` bool; ``images/image%09d`` uint8 [H, W] with ``size``,
  ``timestamp``, ``type = greyscale`` and ``event_idx`` (``max(0, searchsorted(ts, t) - 1)``,
  the packager's rule); root attributes ``sensor_resolution`` [H, W], ``num_events``,
  ``num_pos``, ``num_neg``, ``duration``, ``t0``, ``tk``, ``num_imgs``, ``num_flow``. The HR
  frames go beside ``images/`` under their camera's name (``hr_x2/image%09d``, same
  attributes); thresholds, intrinsics and frame poses go in root attributes and ``poses``.
  A shard with flow ground truth adds the packager's ``flow/flow%09d``: float32 [2, H, W]
  of the event camera at each frame (px/s, channel 0 = x) with ``size``, ``timestamp``
  and ``event_idx`` (the images' rule), the group attribute ``num_images`` and the root
  ``num_flow`` (0 without flow); the HR flow beside it as ``flow_hr_x2/flow%09d``.
- ``evreal``: a ``<shard>_<seq>/`` folder of EVREAL's ``.npy`` files: ``events_ts`` float64
  seconds, ``events_xy`` int16 [N, 2], ``events_p`` uint8 0/1, ``images`` uint8
  [T, H, W, 1], ``images_ts`` float64 [T, 1], ``image_event_indices`` int64 [T, 1]
  (``clip(searchsorted(events_ts, images_ts, 'right') - 1, 0, N - 1)``, EVREAL's converters'
  rule) and ``metadata.json`` with
  ``sensor_resolution`` [H, W]; HR frames as ``images_hr_x2.npy``; thresholds, intrinsics and
  poses in ``metadata.json``.
- ``txt``: a ``<shard>_<seq>/`` folder in the Event Camera Dataset's layout: ``events.txt``
  (``t x y p``, seconds, 0/1), ``images.txt`` (``t images/frame_%08d.png``), ``images/``,
  ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 k3``, no distortion) and ``groundtruth.txt``
  (``t px py pz qx qy qz qw`` at every frame); HR frames in ``images_hr_x2/`` with
  ``images_hr_x2.txt``.

Frames are written as 8-bit, ``round(255 * I)`` of the linear intensity in [0, 1]. Every
output is written under a temporary name and renamed into place.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import cv2
import h5py
import numpy as np

from datagen.shard import SequenceRecord, ShardReader
from esim_lite.core.atomic import atomic_folder, atomic_path
from esim_lite.core.outputs import OutputFolder, claim

FORMATS = ("event_utils", "evreal", "txt")


def to_uint8(intensity: np.ndarray) -> np.ndarray:
    """uint8 frames from linear intensity in [0, 1] (clipped, rounded)."""
    return np.clip(np.round(np.asarray(intensity, np.float64) * 255.0), 0, 255).astype(np.uint8)


def evreal_event_indices(events_ts: np.ndarray, images_ts: np.ndarray) -> np.ndarray:
    """int64[T]: for each frame time, the index of the last event at or before it, clipped
    to [0, N - 1] as EVREAL's converters (tools/bag_to_npy.py) clip it: its loader refuses
    a folder with any index outside that range, e.g. -1 for a frame before the first event.
    Both times in seconds, ``events_ts`` sorted (no events: all 0)."""
    idx = np.searchsorted(events_ts, images_ts, "right") - 1
    return np.clip(idx, 0, max(len(events_ts) - 1, 0)).astype(np.int64)


def _metadata(rec: SequenceRecord) -> dict:
    th = rec.thresholds
    cams = {n: {k: getattr(c, k) for k in ("fx", "fy", "cx", "cy", "width", "height")}
            for n, c in rec.cameras.items()}
    return {"sensor_resolution": list(rec.events.sensor_hw),
            "contrast_threshold_pos": float(th.pos), "contrast_threshold_neg": float(th.neg),
            "cameras": cams, "source_sequence": rec.name,
            "renderer": str(rec.attrs.get("renderer", "")),
            "texture": str(rec.attrs.get("texture", ""))}


def _write_event_utils(rec: SequenceRecord, target: Path) -> Path:
    ev, ts = rec.events, rec.events.t_ns * 1e-9
    with atomic_path(target, ".tmp.h5") as tmp, h5py.File(tmp, "w") as f:
        f.create_dataset("events/xs", data=ev.x.astype(np.int16))
        f.create_dataset("events/ys", data=ev.y.astype(np.int16))
        f.create_dataset("events/ts", data=ts.astype(np.float64))
        f.create_dataset("events/ps", data=ev.p > 0)
        for camera, group in (("lr", "images"), *((c, c) for c in rec.frames if c != "lr")):
            frames = rec.frames[camera]
            for k, (img, t_ns) in enumerate(zip(to_uint8(frames.intensity), frames.t_ns)):
                t = t_ns * 1e-9
                ds = f.create_dataset(f"{group}/image{k:09d}", data=img)
                ds.attrs.update({"size": img.shape, "timestamp": t, "type": "greyscale",
                                 "event_idx": max(0, int(np.searchsorted(ts, t)) - 1)})
        n_flow = _write_event_utils_flow(f, rec, ts)
        n_pos = int((ev.p > 0).sum())
        meta = _metadata(rec)
        f.attrs.update({"sensor_resolution": list(ev.sensor_hw), "num_events": len(ev),
                        "num_pos": n_pos, "num_neg": len(ev) - n_pos,
                        "t0": float(ts[0]) if len(ts) else 0.0,
                        "tk": float(ts[-1]) if len(ts) else 0.0,
                        "duration": float(ts[-1] - ts[0]) if len(ts) else 0.0,
                        "num_imgs": len(rec.frames["lr"].t_ns), "num_flow": n_flow,
                        "contrast_threshold_pos": meta["contrast_threshold_pos"],
                        "contrast_threshold_neg": meta["contrast_threshold_neg"],
                        "cameras": json.dumps(meta["cameras"])})
        f.create_dataset("poses", data=rec.frame_poses)  # t, tx, ty, tz, qx, qy, qz, qw
    return target


def _write_event_utils_flow(f: h5py.File, rec: SequenceRecord, ts: np.ndarray) -> int:
    """Each camera's stored flow at each frame as event_utils' packager writes flow
    (``package_flow``, ``set_data_available``, ``add_event_indices``): ``flow/`` for the
    event camera, ``flow_<camera>/`` for the HR ones. Returns the LR flow count."""
    for camera, truth in rec.ground_truth.items():
        if "flow" not in truth:
            continue
        group = f.create_group("flow" if camera == "lr" else f"flow_{camera}")
        group.attrs["num_images"] = len(truth["flow"])
        for k, (flow, t_ns) in enumerate(zip(truth["flow"], rec.frames[camera].t_ns)):
            t = t_ns * 1e-9
            ds = group.create_dataset(f"flow{k:09d}", data=np.asarray(flow, np.float32))
            ds.attrs.update({"size": flow.shape, "timestamp": t,
                             "event_idx": max(0, int(np.searchsorted(ts, t)) - 1)})
    lr = rec.ground_truth.get("lr", {})
    return len(lr["flow"]) if "flow" in lr else 0


def _folder(target: Path, fill: Callable[[Path], None]) -> Path:
    with atomic_folder(target) as tmp:
        fill(tmp)
    return target


def _write_evreal(rec: SequenceRecord, target: Path) -> Path:
    def fill(d: Path) -> None:
        ev = rec.events
        ts = ev.t_ns * 1e-9
        np.save(d / "events_ts.npy", ts.astype(np.float64))
        np.save(d / "events_xy.npy", np.stack([ev.x, ev.y], axis=1).astype(np.int16))
        np.save(d / "events_p.npy", (ev.p > 0).astype(np.uint8))
        lr = rec.frames["lr"]
        img_ts = lr.t_ns * 1e-9
        np.save(d / "images.npy", to_uint8(lr.intensity)[..., None])
        np.save(d / "images_ts.npy", img_ts[:, None].astype(np.float64))
        np.save(d / "image_event_indices.npy", evreal_event_indices(ts, img_ts)[:, None])
        for camera, frames in rec.frames.items():
            if camera != "lr":
                np.save(d / f"images_{camera}.npy", to_uint8(frames.intensity)[..., None])
        meta = _metadata(rec) | {"poses": "frame_poses.npy (t, tx, ty, tz, qx, qy, qz, qw)"}
        np.save(d / "frame_poses.npy", rec.frame_poses)
        (d / "metadata.json").write_text(json.dumps(meta, indent=2))

    return _folder(target, fill)


def _write_txt(rec: SequenceRecord, target: Path) -> Path:
    def fill(d: Path) -> None:
        ev = rec.events
        with open(d / "events.txt", "w") as f:
            for t, x, y, p in zip(ev.t_ns, ev.x, ev.y, ev.p):
                f.write(f"{t // 10**9}.{t % 10**9:09d} {x} {y} {int(p > 0)}\n")
        for camera, frames in rec.frames.items():
            sub = "images" if camera == "lr" else f"images_{camera}"
            (d / sub).mkdir()
            rows = []
            for k, (img, t) in enumerate(zip(to_uint8(frames.intensity), frames.t_ns)):
                name = f"{sub}/frame_{k:08d}.png"
                cv2.imwrite(str(d / name), img)
                rows.append(f"{t // 10**9}.{t % 10**9:09d} {name}")
            (d / f"{sub}.txt").write_text("\n".join(rows) + "\n")
        c = rec.cameras["lr"]
        (d / "calib.txt").write_text(f"{c.fx!r} {c.fy!r} {c.cx!r} {c.cy!r} 0 0 0 0 0\n")
        rows = [" ".join([f"{r[0]:.9f}"] + [repr(float(v)) for v in r[1:]])
                for r in rec.frame_poses]
        (d / "groundtruth.txt").write_text("\n".join(rows) + "\n")

    return _folder(target, fill)


_WRITERS = {"event_utils": (_write_event_utils, ".h5"), "evreal": (_write_evreal, ""),
            "txt": (_write_txt, "")}


def export_names(shards: list[Path], fmt: str) -> list[str]:
    """The ``fnmatch`` patterns of what :func:`export` writes for ``shards`` in ``fmt``."""
    suffix = _WRITERS[fmt][1] if fmt in _WRITERS else ""
    return [f"{path.stem}_seq_*{suffix}" for path in shards]


def export(shards: list[Path], fmt: str, out: str | Path | OutputFolder,
           sequence: str | None = None) -> list[Path]:
    """Write every sequence of ``shards`` (or only ``sequence``) in format ``fmt`` into
    ``out``; return what was written.

    Raises:
        ValueError: an unknown format, or ``sequence`` in none of the shards.
    """
    if fmt not in _WRITERS:
        raise ValueError(f"unknown export format {fmt!r} (expected {', '.join(FORMATS)})")
    write, suffix = _WRITERS[fmt]
    written = []
    for path in shards:
        with ShardReader(path) as reader:
            for name in reader.sequences():
                if sequence is not None and name != sequence:
                    continue
                target = claim(out) / f"{path.stem}_{name}{suffix}"
                written.append(write(reader.read(name), target))
    if sequence is not None and not written:
        raise ValueError(f"no sequence {sequence!r} in {', '.join(str(p) for p in shards)}")
    return written
