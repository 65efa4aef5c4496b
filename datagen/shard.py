"""The HDF5 shard schema: one writer and one reader that everything else uses.

A shard holds several sequences, one group each, named ``seq_{index:06d}``. Inside a group
the event datasets are named as in event_utils / E2VID HDF5 (``datagen export`` writes the
files those tools' loaders open as they are):

```
seq_000012/                      attrs: sensor_resolution [H, W], num_events, num_pos,
                                        num_neg, duration, t0, index, seed, log_eps,
                                        contrast_threshold_pos, contrast_threshold_neg,
                                        renderer, texture, frame_dtype; with moving
                                        objects in the config also num_objects,
                                        static_camera; with sensor_ranges on also the
                                        sequence's sensor (SENSOR_ATTRS: refractory_ns,
                                        mismatch_std, shot_rate_hz, ..., flicker_hz
                                        (0 = no lamp), flicker_depth, flicker_area);
                                        made from a video (datagen from-video) also its
                                        provenance (VIDEO_ATTRS: source_path,
                                        source_sha256, source_kind, source_frame_start,
                                        source_frame_stop, source_t0_s, interpolator,
                                        scene_cuts), renderer video:<interpolator> and
                                        texture the source's name
  events/xs, ys      int16[N]    column, row
  events/ts          float64[N]  seconds (exact to the nanosecond for t < 10^6 s)
  events/ps          uint8[N]    1 = ON (brighter), 0 = OFF
  frames/lr          [T,h,w]     linear intensity, float16 or float32 (see frame_dtype)
  frames/hr_x2, hr_x4 [T,sh,sw]  the HR cameras present in the rig
  frames/ts          float64[T]  seconds
  frames/event_idx   int64[T]    index of the first event after each frame
  frames/poses       float64[T,8] t, tx, ty, tz, qx, qy, qz, qw at each frame
  frames/flow_<cam>  float32[T,2,h,w] ground truth (only the kinds frames.ground_truth
                                  lists, for every camera): instantaneous optical flow of
                                  the visible surface, px/s, channel 0 = x
  frames/depth_<cam> float32[T,h,w] metres along the optical axis
  frames/ids_<cam>   uint8[T,h,w] visible surface: 0 background, k + 1 object k
  poses              float64[S,8] the same at every render sample (adaptive time grid)
  cameras/<name>     attrs fx, fy, cx, cy, width, height (lr, hr_x2, ...)
  scene              attrs width_m, height_m, texture_hw; plane z = 0, normal +z
  trajectory/        positions [K,3], rotations [K,3,3], attr knot_spacing_s, duration_s
                     (a from-video sequence has no scene and no trajectory; its frame and
                     sample poses are NaN beside their times, its cameras' intrinsics
                     nominal)
  objects/obj_000/   one group per object (obj_k has surface id k + 1): positions [K,3],
                     rotations [K,3,3] (object-to-world B-spline), alpha uint8[h,w]
                     (round(255 a), exact for 0/1 masks); attrs knot_spacing_s, duration_s,
                     width_m, height_m, texture (provenance), texture_hw
  thresholds/        pos_map, neg_map float32[H,W] (only when per-pixel mismatch is on)
/ (file)             attrs: schema_version, config (resolved YAML), complete, versions (JSON:
                     the library versions that shape the bytes, see library_versions; absent
                     in shards written before they were recorded); from datagen also seed
                     and sequences (the indices the shard is to hold)
```

Frames are stored as float16 when its rounding (relative 2^-12) changes ``log(eps + I)`` by
at most 1% of the sequence's smallest contrast threshold, otherwise as float32. Ground truth
is stored as the simulator computed it (no rounding), gzip-compressed like the frames.
A configuration without objects, ground truth or sensor ranges writes none of the optional
attributes, groups or datasets, so its shards are what they were before these existed.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

import h5py
import numpy as np
import yaml

from esim_lite.config import FrameConfig
from esim_lite.core.dataconf import from_mapping
from esim_lite.core.events import Events
from esim_lite.core.frames import Frames
from esim_lite.events.simulator import EventConfig
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.objects import DynamicScene
from esim_lite.geometry.trajectory import BSplineTrajectory

if TYPE_CHECKING:
    from datagen.sampling import SequenceSpec
    from esim_lite.geometry.visibility import SurfaceTruth

SCHEMA_VERSION = 1
FLOAT16_LOG_ERROR = 2.0**-12  # max |log(eps + I16) - log(eps + I)| for normal float16
EVENT_CHUNK = 1 << 16
_COMPRESSION = {"compression": "gzip", "compression_opts": 1, "shuffle": True}
#: Per-pixel ground truth a shard can hold (``frames.ground_truth``), in storage order.
GROUND_TRUTH_KINDS = ("flow", "depth", "ids")
_GROUND_TRUTH_DTYPE = {"flow": np.dtype(np.float32), "depth": np.dtype(np.float32),
                       "ids": np.dtype(np.uint8)}
#: Sequence attributes recording a drawn sensor (``sensor_ranges``), in storage order.
SENSOR_ATTRS = ("refractory_ns", "mismatch_std", "mismatch_relative", "shot_rate_hz",
                "shot_bright_factor", "leak_rate_hz", "hot_pixel_fraction", "hot_pixel_rate_hz",
                "cutoff_hz", "flicker_hz", "flicker_depth", "flicker_area")


#: Sequence attributes of a from-video sequence's provenance (``datagen from-video``).
VIDEO_ATTRS = ("source_path", "source_sha256", "source_kind", "source_frame_start",
               "source_frame_stop", "source_t0_s", "interpolator", "scene_cuts")


@dataclass(frozen=True)
class VideoProvenance:
    """Where a from-video sequence came from (stored as :data:`VIDEO_ATTRS`).

    Attributes:
        path: the video file or frame folder (as given, resolved).
        sha256: its digest (see ``datagen.video.source.Source``).
        kind: ``video`` or ``frames``.
        frame_start, frame_stop: the source's frames ``start .. stop - 1`` made it.
        t0_s: the source's time of frame ``frame_start`` (the sequence's time 0).
        interpolator: ``flow`` or ``linear``.
        scene_cuts: how many scene cuts the sensor restarted at.
    """

    path: Path
    sha256: str
    kind: str
    frame_start: int
    frame_stop: int
    t0_s: float
    interpolator: str
    scene_cuts: int = 0

    def attrs(self) -> dict[str, object]:
        return {"source_path": str(self.path), "source_sha256": self.sha256,
                "source_kind": self.kind, "source_frame_start": self.frame_start,
                "source_frame_stop": self.frame_stop, "source_t0_s": self.t0_s,
                "interpolator": self.interpolator, "scene_cuts": self.scene_cuts}


def frame_dtype(min_threshold: float) -> np.dtype:
    """float16 if its log-intensity rounding is <= 1% of ``min_threshold``, else float32."""
    return np.dtype(np.float16 if FLOAT16_LOG_ERROR <= 0.01 * min_threshold else np.float32)


def sensor_attrs(events: EventConfig) -> dict[str, float]:
    """The :data:`SENSOR_ATTRS` of one sequence's sensor (``refractory_ns`` an int, the
    rest floats; ``flicker_hz`` 0 when it has no lamp)."""
    noise, flicker = events.noise, events.flicker
    values = {"refractory_ns": int(events.refractory_ns),
              "mismatch_std": events.thresholds.mismatch_std,
              "mismatch_relative": events.thresholds.mismatch_relative,
              "shot_rate_hz": noise.shot_rate_hz,
              "shot_bright_factor": noise.shot_bright_factor,
              "leak_rate_hz": noise.leak_rate_hz,
              "hot_pixel_fraction": noise.hot_pixel_fraction,
              "hot_pixel_rate_hz": noise.hot_pixel_rate_hz,
              "cutoff_hz": events.bandwidth.cutoff_hz,
              "flicker_hz": flicker.frequency_hz if flicker.enabled else 0.0,
              "flicker_depth": flicker.depth, "flicker_area": flicker.area_fraction}
    return {k: values[k] if k == "refractory_ns" else float(values[k]) for k in SENSOR_ATTRS}


def sequence_name(index: int) -> str:
    return f"seq_{index:06d}"


def ground_truth_name(kind: str, camera: str) -> str:
    """Name of one camera's ground truth dataset under ``frames/``, e.g. ``flow_lr``."""
    return f"{kind}_{camera}"


def object_name(k: int) -> str:
    """Name of object ``k``'s group under ``objects/`` (its surface id is ``k + 1``)."""
    return f"obj_{k:03d}"


def find_shards(target: str | Path) -> list[Path]:
    """``target`` itself if it is a file, else every ``shard_*.h5`` in the folder, sorted.

    Raises:
        FileNotFoundError: ``target`` does not exist, or is a folder without shards.
    """
    path = Path(target)
    if path.is_dir():
        found = sorted(path.glob("shard_*.h5"))
        if not found:
            raise FileNotFoundError(f"{path}: no shard_*.h5 files in this folder (make them "
                                    f"with datagen generate)")
        return found
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder, so no shard_*.h5 files to "
                                f"read (make them with datagen generate)")
    return [path]


def library_versions() -> dict[str, str]:
    """Versions of the libraries whose arithmetic shapes a shard's bytes (a dataset is
    bit-identical only per stack: e.g. OpenCV's warpPerspective rounds differently across
    versions); ``not installed`` for a missing one. Read from package metadata, so nothing
    heavy is imported and Mitsuba's variant is left alone; OpenCV's is the loaded module's,
    whichever of its wheels provides it."""
    import cv2  # imported by the renderers anyway

    def installed(dist: str) -> str:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return "not installed"

    return {"numpy": np.__version__, "opencv": cv2.__version__,
            "mitsuba": installed("mitsuba"), "drjit": installed("drjit"),
            "numba": installed("numba"), "h5py": h5py.__version__,
            "hdf5": h5py.version.hdf5_version, "e2sr": installed("e2sr")}


MAX_INTENSITY = 4.0
"""The largest linear intensity a shard's frame may hold (the simulator's are in [0, 1])."""


class ShardWriter:
    """Writes sequences into one open HDF5 file; events and frames are appended in chunks.

    Use :meth:`begin_sequence`, then any number of :meth:`append_events` /
    :meth:`append_frame`, then :meth:`end_sequence`. :meth:`finish` marks the file complete.
    """

    def __init__(self, path: str | Path, config_yaml: str, seed: int | None = None,
                 sequences: list[int] | None = None) -> None:
        self.path = Path(path)
        self.file = h5py.File(self.path, "w")
        self.file.attrs["schema_version"] = SCHEMA_VERSION
        self.file.attrs["config"] = config_yaml
        self.file.attrs["complete"] = False
        self.file.attrs["versions"] = json.dumps(library_versions())
        if seed is not None:  # a dataset's shard: which seed and sequences it is to hold
            self.file.attrs["seed"] = seed
            self.file.attrs["sequences"] = list(sequences or [])
        self._group: h5py.Group | None = None

    def begin_sequence(self, spec: SequenceSpec, cameras: dict[str, Intrinsics],
                       log_eps: float, renderer: str,
                       ground_truth: tuple[str, ...] = ()) -> None:
        """Start the group of sequence ``spec.index`` (its scene, objects, trajectory,
        thresholds, seed and drawn sensor come from the spec; ``renderer`` names the
        backend that made its frames; ``ground_truth``: the kinds of
        :data:`GROUND_TRUTH_KINDS` every frame carries, for every camera).

        Raises:
            ValueError: an unknown ground truth kind.
        """
        unknown = [k for k in ground_truth if k not in GROUND_TRUTH_KINDS]
        if unknown:
            raise ValueError(f"unknown ground truth kind(s) {unknown} (expected any of "
                             f"{', '.join(GROUND_TRUTH_KINDS)})")
        g = self._open_sequence(spec.index, spec.seed, spec.thresholds, cameras, log_eps,
                                renderer, spec.texture_name, ground_truth)
        self._write_scene_and_trajectory(g, spec)
        if isinstance(spec.scene, DynamicScene):  # a configuration with moving objects
            self._write_objects(g, spec)
        if spec.sensor_drawn:  # a configuration with sensor ranges
            g.attrs.update(sensor_attrs(spec.events))
        self._write_thresholds(g, spec.thresholds)

    def begin_video_sequence(self, index: int, seed: int, thresholds: ContrastThresholds,
                             cameras: dict[str, Intrinsics], log_eps: float,
                             source: VideoProvenance, events: EventConfig | None = None
                             ) -> None:
        """Start the group of sequence ``index`` made from a video by ``datagen
        from-video``: no scene, trajectory or poses (a video has none; its frame and
        sample poses are stored as NaN beside their times), the video's provenance
        (:data:`VIDEO_ATTRS`) instead; ``renderer`` is ``video:<interpolator>`` and
        ``texture`` the source's file name. ``events``: the sequence's drawn sensor (None:
        the config's, nothing drawn)."""
        g = self._open_sequence(index, seed, thresholds, cameras, log_eps,
                                f"video:{source.interpolator}", source.path.name, ())
        g.attrs.update(source.attrs())
        if events is not None:
            g.attrs.update(sensor_attrs(events))
        self._write_thresholds(g, thresholds)

    def _open_sequence(self, index: int, seed: int, thresholds: ContrastThresholds,
                       cameras: dict[str, Intrinsics], log_eps: float, renderer: str,
                       texture: str, ground_truth: tuple[str, ...]) -> h5py.Group:
        """The sequence's group with its common attributes and its empty events, frames
        and sample poses."""
        g = self.file.create_group(sequence_name(index))
        self._group, lr = g, cameras["lr"]
        self._dtype = frame_dtype(thresholds.min_threshold)
        g.attrs.update({"sensor_resolution": [lr.height, lr.width], "index": index,
                        "seed": seed, "log_eps": log_eps, "renderer": renderer,
                        "texture": texture, "frame_dtype": self._dtype.name,
                        "contrast_threshold_pos": thresholds.pos,
                        "contrast_threshold_neg": thresholds.neg})
        ev = g.create_group("events")
        for name, dtype in (("xs", np.int16), ("ys", np.int16), ("ts", np.float64),
                            ("ps", np.uint8)):
            ev.create_dataset(name, (0,), dtype, maxshape=(None,), chunks=(EVENT_CHUNK,),
                              **_COMPRESSION)
        self._truth = tuple(k for k in GROUND_TRUTH_KINDS if k in ground_truth)
        self._create_frames(g, cameras)
        g.create_dataset("poses", (0, 8), np.float64, maxshape=(None, 8), chunks=(1024, 8))
        return g

    def _write_thresholds(self, g: h5py.Group, thresholds: ContrastThresholds) -> None:
        """The per-pixel maps (only with mismatch); then the event counters start."""
        if thresholds.has_mismatch:
            th = g.create_group("thresholds")
            th.create_dataset("pos_map", data=thresholds.pos_map.astype(np.float32))
            th.create_dataset("neg_map", data=thresholds.neg_map.astype(np.float32))
        self._n_events = self._n_pos = self._n_pending = 0
        self._pending: list[Events] = []

    def _create_frames(self, g: h5py.Group, cameras: dict[str, Intrinsics]) -> None:
        """The empty ``frames`` group (each camera's frames, then its ground truth of the
        kinds in ``self._truth``, then times, event indices and poses) and ``cameras``."""
        fr = g.create_group("frames")
        for name, cam in cameras.items():
            fr.create_dataset(name, (0, cam.height, cam.width), self._dtype,
                              maxshape=(None, cam.height, cam.width),
                              chunks=(1, cam.height, cam.width), **_COMPRESSION)
            c = g.create_group(f"cameras/{name}")
            c.attrs.update({k: getattr(cam, k) for k in ("fx", "fy", "cx", "cy", "width",
                                                         "height")})
        for name, cam in cameras.items():
            for kind in self._truth:
                shape = (2, cam.height, cam.width) if kind == "flow" else (cam.height, cam.width)
                fr.create_dataset(ground_truth_name(kind, name), (0, *shape),
                                  _GROUND_TRUTH_DTYPE[kind], maxshape=(None, *shape),
                                  chunks=(1, *shape), **_COMPRESSION)
        fr.create_dataset("ts", (0,), np.float64, maxshape=(None,))
        fr.create_dataset("event_idx", (0,), np.int64, maxshape=(None,))
        fr.create_dataset("poses", (0, 8), np.float64, maxshape=(None, 8))

    @staticmethod
    def _write_scene_and_trajectory(g: h5py.Group, spec: SequenceSpec) -> None:
        """The background plane's size (``scene``) and the camera's ``trajectory``."""
        background, trajectory = spec.background, spec.trajectory
        sc = g.create_group("scene")
        sc.attrs.update({"width_m": background.width_m, "height_m": background.height_m,
                         "texture_hw": list(background.texture_hw)})
        tr = g.create_group("trajectory")
        tr.create_dataset("positions", data=trajectory.positions)
        tr.create_dataset("rotations", data=trajectory.rotations)
        tr.attrs.update({"knot_spacing_s": trajectory.knot_spacing_s,
                         "duration_s": trajectory.duration_s})

    @staticmethod
    def _write_objects(g: h5py.Group, spec: SequenceSpec) -> None:
        """``num_objects``, ``static_camera`` and one ``objects/obj_XXX`` group per object:
        its trajectory, size, alpha shape and texture provenance."""
        g.attrs.update({"num_objects": len(spec.objects),
                        "static_camera": bool(spec.static_camera)})
        for k, obj in enumerate(spec.objects):
            o = g.create_group(f"objects/{object_name(k)}")
            tr = obj.trajectory
            o.create_dataset("positions", data=tr.positions)
            o.create_dataset("rotations", data=tr.rotations)
            alpha = np.round(np.clip(obj.alpha, 0.0, 1.0) * 255.0).astype(np.uint8)
            o.create_dataset("alpha", data=alpha, chunks=alpha.shape, **_COMPRESSION)
            o.attrs.update({"knot_spacing_s": tr.knot_spacing_s, "duration_s": tr.duration_s,
                            "width_m": obj.surface.width_m, "height_m": obj.surface.height_m,
                            "texture": obj.name,
                            "texture_hw": list(obj.surface.texture.shape)})

    @staticmethod
    def _append(ds: h5py.Dataset, values: np.ndarray) -> None:
        n = ds.shape[0]
        ds.resize(n + len(values), axis=0)
        ds[n:] = values

    def append_events(self, events: Events) -> None:
        """Queue events; they reach the file in whole HDF5 chunks, so no compressed chunk is
        ever rewritten (appending a few thousand events at a time otherwise re-compresses
        the same 65,536-event chunk dozens of times)."""
        if not len(events):
            return
        self._pending.append(events)
        self._n_pending += len(events)
        self._n_events += len(events)
        self._n_pos += int((events.p > 0).sum())
        if self._n_pending >= EVENT_CHUNK:
            self._flush_events(whole_chunks=True)

    def _flush_events(self, whole_chunks: bool) -> None:
        if not self._pending:
            return
        batch = Events.concatenate(self._pending)
        n = len(batch) - len(batch) % EVENT_CHUNK if whole_chunks else len(batch)
        rest = batch.slice(n, len(batch))
        self._pending, self._n_pending = ([rest] if len(rest) else []), len(rest)
        if n == 0:
            return
        batch = batch.slice(0, n)
        ev = self._group["events"]
        self._append(ev["xs"], batch.x)
        self._append(ev["ys"], batch.y)
        self._append(ev["ts"], batch.t_ns * 1e-9)
        self._append(ev["ps"], (batch.p > 0).astype(np.uint8))

    def append_frame(self, t_ns: int, pose_row: np.ndarray, images: dict[str, np.ndarray],
                     truth: dict[str, SurfaceTruth] | None = None) -> None:
        """Add one frame; call after appending every event up to ``t_ns``. ``truth``: each
        camera's ground truth at the frame, required when the sequence stores some (the
        kinds it was begun with; the others are not written).

        Raises:
            ValueError: the sequence stores ground truth and ``truth`` lacks a camera.
        """
        fr = self._group["frames"]
        for name, img in images.items():
            self._append(fr[name], img[None].astype(self._dtype))
        if self._truth:
            missing = [n for n in images if truth is None or n not in truth]
            if missing:
                raise ValueError(f"frame at {t_ns} ns: no ground truth for camera(s) "
                                 f"{', '.join(missing)}, which this sequence stores "
                                 f"({', '.join(self._truth)})")
            for name in images:
                for kind in self._truth:
                    value = getattr(truth[name], kind)
                    self._append(fr[ground_truth_name(kind, name)],
                                 np.asarray(value, _GROUND_TRUTH_DTYPE[kind])[None])
        self._append(fr["ts"], np.array([t_ns * 1e-9]))
        self._append(fr["event_idx"], np.array([self._n_events], np.int64))
        self._append(fr["poses"], pose_row[None])

    def append_poses(self, rows: np.ndarray) -> None:
        if len(rows):
            self._append(self._group["poses"], rows)

    def end_sequence(self, scene_cuts: int | None = None) -> None:
        """Close the sequence; ``scene_cuts``: a from-video sequence's count, known only
        now."""
        self._flush_events(whole_chunks=False)
        g = self._group
        if scene_cuts is not None:
            g.attrs["scene_cuts"] = int(scene_cuts)
        ts = g["events/ts"]
        g.attrs.update({"num_events": self._n_events, "num_pos": self._n_pos,
                        "num_neg": self._n_events - self._n_pos,
                        "t0": float(ts[0]) if len(ts) else 0.0,
                        "duration": float(ts[-1] - ts[0]) if len(ts) else 0.0})
        self._group = None

    def finish(self) -> None:
        """Mark the shard complete and close it (the caller then renames it into place)."""
        self.file.attrs["complete"] = True
        self.file.flush()
        self.file.close()

    def close(self) -> None:
        if self.file.id.valid:
            self.file.close()


@dataclass(frozen=True)
class SequenceSummary:
    """What one stored sequence is, in numbers (``datagen inspect``, previews, checks).

    ``frame_hw`` and ``stored_bytes`` are keyed by camera (``lr`` first, then HR by scale);
    ``stored_bytes`` also has ``events`` and each stored ground truth kind (all cameras
    together): compressed bytes on disk. ``num_objects`` is None for a sequence of a
    configuration without moving objects; ``ground_truth`` lists the kinds stored;
    ``sensor`` is the drawn sensor (:data:`SENSOR_ATTRS`), None without sensor ranges.
    """

    name: str
    index: int
    seed: int
    sensor_hw: tuple[int, int]
    num_events: int
    num_pos: int
    num_neg: int
    t0_s: float
    duration_s: float
    num_frames: int
    frame_hw: dict[str, tuple[int, int]]
    frame_dtype: str
    threshold_pos: float
    threshold_neg: float
    per_pixel_thresholds: bool
    renderer: str
    texture: str
    stored_bytes: dict[str, int]
    num_objects: int | None = None
    static_camera: bool = False
    ground_truth: tuple[str, ...] = ()
    sensor: dict[str, float] | None = None


def _stored_bytes(node: h5py.Group | h5py.Dataset) -> int:
    if isinstance(node, h5py.Dataset):
        return node.id.get_storage_size()
    total = 0

    def visit(_, obj) -> None:
        nonlocal total
        if isinstance(obj, h5py.Dataset):
            total += obj.id.get_storage_size()

    node.visititems(visit)
    return total


@dataclass(frozen=True, eq=False)
class StoredObject:
    """One moving object of a stored sequence: enough to rebuild its shape and motion (the
    texture itself is not stored, only where it came from).

    Attributes:
        trajectory: object-to-world poses over the sequence.
        width_m, height_m: the patch's size.
        alpha: float32[h, w] in [0, 1] on the texture's grid (stored as 8 bits).
        texture: the texture's provenance.
        texture_hw: the texture's size in texels.
    """

    trajectory: BSplineTrajectory
    width_m: float
    height_m: float
    alpha: np.ndarray
    texture: str
    texture_hw: tuple[int, int]


@dataclass(frozen=True, eq=False)
class SequenceRecord:
    """One sequence read back from a shard (see the module doc for the fields);
    ``ground_truth[camera][kind]`` holds every frame's stored ground truth."""

    name: str
    events: Events
    frames: dict[str, Frames]
    frame_poses: np.ndarray
    frame_event_idx: np.ndarray
    sample_poses: np.ndarray
    cameras: dict[str, Intrinsics]
    thresholds: ContrastThresholds
    attrs: dict
    ground_truth: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


class ShardReader:
    """Read access to a complete shard; the only code that knows the layout for reading.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: not an e2sr shard, an unknown schema version, or an incomplete shard;
            the message names the file.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"{self.path}: no such shard")
        try:
            self.file = h5py.File(self.path, "r")
        except OSError as exc:
            raise ValueError(f"{self.path}: not a readable HDF5 file ({exc})") from exc
        version = self.file.attrs.get("schema_version")
        if version is None:
            self.close()
            raise ValueError(f"{self.path}: not an e2sr shard (no schema_version)")
        if int(version) != SCHEMA_VERSION:
            self.close()
            raise ValueError(f"{self.path}: schema version {version}, this reader knows "
                             f"{SCHEMA_VERSION}")
        if not bool(self.file.attrs.get("complete", False)):
            self.close()
            raise ValueError(f"{self.path}: incomplete shard (generation was interrupted)")

    def __enter__(self) -> ShardReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if getattr(self, "file", None) is not None and self.file.id.valid:
            self.file.close()

    @property
    def config_yaml(self) -> str:
        return str(self.file.attrs["config"])

    def frame_layout(self) -> FrameConfig | None:
        """When the shard's frames were taken (``simulation.frames`` of its stored config);
        None for a shard whose config this version cannot read."""
        try:
            frames = (yaml.safe_load(self.config_yaml) or {}).get("simulation", {}).get("frames")
            if frames is None:  # e.g. from-video: a sequence's frames are its video's
                return None
            return from_mapping(FrameConfig, frames)
        except (yaml.YAMLError, AttributeError, ValueError, TypeError):
            return None

    def sequences(self) -> list[str]:
        return sorted(k for k in self.file if k.startswith("seq_"))

    @property
    def schema_version(self) -> int:
        return int(self.file.attrs["schema_version"])

    @property
    def versions(self) -> dict[str, str] | None:
        """The library versions the shard was written with (see :func:`library_versions`);
        None for a shard written before they were recorded."""
        text = self.file.attrs.get("versions")
        if text is None:
            return None
        try:
            return dict(json.loads(text))
        except (TypeError, ValueError) as exc:  # JSONDecodeError is a ValueError
            raise ValueError(f"{self.path}: the versions attribute is not a JSON object "
                             f"({exc})") from exc

    @property
    def seed(self) -> int | None:
        """The dataset's master seed (None for a shard not written by ``datagen``)."""
        seed = self.file.attrs.get("seed")
        return None if seed is None else int(seed)

    @property
    def planned_sequences(self) -> list[int]:
        """The sequence indices the shard was to hold (empty outside a dataset)."""
        return [int(v) for v in self.file.attrs.get("sequences", [])]

    @staticmethod
    def state(path: str | Path, config_yaml: str, seed: int, sequences: list[int]) -> str:
        """``done`` (a complete shard of this config, seed and sequences), ``foreign`` (a
        complete shard of another config, seed or schema), ``todo`` (missing, or an e2sr
        shard that is interrupted or holds other sequences of this dataset: ours to
        replace) or ``stranger`` (anything else: not HDF5, or HDF5 without the shard
        schema's attributes; never ours to remove)."""
        path = Path(path)
        if not path.exists() and not path.is_symlink():
            return "todo"
        try:
            with h5py.File(path, "r") as f:
                a = f.attrs
                if "schema_version" not in a or "config" not in a or "complete" not in a:
                    return "stranger"
                if not bool(a["complete"]):
                    return "todo"
                if a.get("config") != config_yaml or int(a.get("seed", -1)) != seed \
                        or a.get("schema_version") != SCHEMA_VERSION:
                    return "foreign"
                return "done" if list(a.get("sequences", [])) == list(sequences) else "todo"
        except (OSError, ValueError, TypeError):
            return "stranger"

    def _group(self, name: str) -> h5py.Group:
        if name not in self.file:
            raise KeyError(f"{self.path}: no sequence {name!r}")
        return self.file[name]

    def sensor_hw(self, name: str) -> tuple[int, int]:
        """(H, W) of the event sensor of sequence ``name``."""
        h, w = (int(v) for v in self._group(name).attrs["sensor_resolution"])
        return h, w

    def frame_hw(self, name: str, camera: str) -> tuple[int, int]:
        """(H, W) of one camera's frames."""
        _, h, w = self._group(name)["frames"][camera].shape
        return int(h), int(w)

    def last_event_ns(self, name: str) -> int:
        """Time of the last event (0 for a sequence without events)."""
        ts = self._group(name)["events/ts"]
        return int(round(ts[ts.shape[0] - 1] * 1e9)) if ts.shape[0] else 0

    def event_dtypes(self, name: str) -> dict[str, np.dtype]:
        """Stored dtype of each event dataset of sequence ``name`` (``xs``, ``ys``, ``ts``,
        ``ps``), for readers that check a file before doing arithmetic on it."""
        ev = self._group(name)["events"]
        return {k: ev[k].dtype for k in ("xs", "ys", "ts", "ps")}

    def summary(self, name: str) -> SequenceSummary:
        g = self._group(name)
        a, fr = g.attrs, g["frames"]
        cams = self.frame_names(name)
        stored = {"events": _stored_bytes(g["events"])}
        stored.update({c: _stored_bytes(fr[c]) for c in cams})
        kinds = self.ground_truth_kinds(name)
        stored.update({k: sum(_stored_bytes(fr[ground_truth_name(k, c)]) for c in cams
                              if ground_truth_name(k, c) in fr) for k in kinds})
        return SequenceSummary(
            name, int(a["index"]), int(a["seed"]), self.sensor_hw(name), int(a["num_events"]),
            int(a["num_pos"]), int(a["num_neg"]), float(a["t0"]), float(a["duration"]),
            int(fr["ts"].shape[0]), {c: self.frame_hw(name, c) for c in cams},
            str(a["frame_dtype"]), float(a["contrast_threshold_pos"]),
            float(a["contrast_threshold_neg"]), "thresholds" in g, str(a["renderer"]),
            str(a["texture"]), stored, self.num_objects(name), self.static_camera(name),
            kinds, self.sensor(name))

    def cameras(self, name: str) -> dict[str, Intrinsics]:
        g = self._group(name)["cameras"]
        return {n: Intrinsics(**{k: (int if k in ("width", "height") else float)(v)
                                 for k, v in g[n].attrs.items()}) for n in g}

    def events(self, name: str, start: int = 0, stop: int | None = None) -> Events:
        """Events ``[start, stop)`` of a sequence (reads only that slice)."""
        g = self._group(name)
        ev = g["events"]
        sl = slice(start, stop)
        return Events(ev["xs"][sl], ev["ys"][sl], np.round(ev["ts"][sl] * 1e9).astype(np.int64),
                      np.where(ev["ps"][sl] > 0, 1, -1).astype(np.int8), self.sensor_hw(name))

    def event_index_at(self, name: str, t_ns: int) -> int:
        """Index of the first event later than ``t_ns`` (bisection: ~log2(N) reads)."""
        ts = self._group(name)["events/ts"]
        lo, hi, t = 0, ts.shape[0], t_ns * 1e-9
        while lo < hi:
            mid = (lo + hi) // 2
            if ts[mid] <= t:
                lo = mid + 1
            else:
                hi = mid
        return lo

    def num_events(self, name: str) -> int:
        return int(self._group(name)["events/ts"].shape[0])

    def num_samples(self, name: str) -> int:
        """How many render samples (rows of ``poses``) the sequence took."""
        return int(self._group(name)["poses"].shape[0])

    def frame_names(self, name: str) -> list[str]:
        """Cameras with frames: ``lr`` first, then the HR ones by scale."""
        g = self._group(name)
        fr, cams = g["frames"], g["cameras"]
        names = [n for n in fr if n in cams and isinstance(fr[n], h5py.Dataset)
                 and fr[n].ndim == 3]
        return sorted(names, key=lambda n: (n != "lr", fr[n].shape[1]))

    def ground_truth_kinds(self, name: str, camera: str = "lr") -> tuple[str, ...]:
        """The ground truth kinds stored for ``camera`` (in :data:`GROUND_TRUTH_KINDS`
        order; empty for a shard generated without ``frames.ground_truth``)."""
        fr = self._group(name)["frames"]
        return tuple(k for k in GROUND_TRUTH_KINDS if ground_truth_name(k, camera) in fr)

    def ground_truth(self, name: str, camera: str, k: int | None = None
                     ) -> dict[str, np.ndarray]:
        """Every stored kind of ``camera``'s ground truth: ``flow`` float32[T, 2, H, W]
        (px/s, channel 0 = x), ``depth`` float32[T, H, W] (m), ``ids`` uint8[T, H, W]; for
        frame ``k`` only without the leading T. Empty when none is stored."""
        fr = self._group(name)["frames"]
        sl = slice(None) if k is None else k
        return {kind: fr[ground_truth_name(kind, camera)][sl]
                for kind in self.ground_truth_kinds(name, camera)}

    def _truth(self, name: str, kind: str, camera: str, k: int | None) -> np.ndarray:
        fr = self._group(name)["frames"]
        ds_name = ground_truth_name(kind, camera)
        if ds_name not in fr:
            stored = ", ".join(self.ground_truth_kinds(name, camera)) or "none"
            raise KeyError(f"{self.path}/{name}: no {kind} ground truth for camera "
                           f"{camera!r} (stored: {stored}); generate with "
                           f"simulation.frames.ground_truth listing {kind}")
        return fr[ds_name][slice(None) if k is None else k]

    def flow(self, name: str, camera: str = "lr", k: int | None = None) -> np.ndarray:
        """float32[T, 2, H, W] optical flow in px/s (channel 0 = x) of ``camera``, or
        [2, H, W] of frame ``k``.

        Raises:
            KeyError: the shard holds no flow for that camera.
        """
        return self._truth(name, "flow", camera, k)

    def depth(self, name: str, camera: str = "lr", k: int | None = None) -> np.ndarray:
        """float32[T, H, W] depth along the optical axis in metres (see :meth:`flow`)."""
        return self._truth(name, "depth", camera, k)

    def ids(self, name: str, camera: str = "lr", k: int | None = None) -> np.ndarray:
        """uint8[T, H, W] visible surface, 0 = background, k + 1 = object k (see
        :meth:`flow`)."""
        return self._truth(name, "ids", camera, k)

    def num_objects(self, name: str) -> int | None:
        """How many objects move in the sequence (None: its configuration had none)."""
        n = self._group(name).attrs.get("num_objects")
        return None if n is None else int(n)

    def sensor(self, name: str) -> dict[str, float] | None:
        """The sequence's drawn sensor (:data:`SENSOR_ATTRS` to values; ``refractory_ns``
        an int); None when its configuration drew none (the stored config's
        ``simulation.events`` is then every sequence's sensor)."""
        a = self._group(name).attrs
        if SENSOR_ATTRS[0] not in a:
            return None
        return {k: int(a[k]) if k == "refractory_ns" else float(a[k]) for k in SENSOR_ATTRS}

    def static_camera(self, name: str) -> bool:
        """Whether the camera stands still (only the objects move)."""
        return bool(self._group(name).attrs.get("static_camera", False))

    def objects(self, name: str) -> tuple[StoredObject, ...]:
        """The sequence's moving objects in id order (object ``k`` has surface id
        ``k + 1``); empty without objects."""
        g = self._group(name)
        if "objects" not in g:
            return ()
        out = []
        for k in range(len(g["objects"])):
            o = g["objects"][object_name(k)]
            a = o.attrs
            trajectory = BSplineTrajectory(o["positions"][:], o["rotations"][:],
                                           float(a["knot_spacing_s"]), float(a["duration_s"]))
            h, w = (int(v) for v in a["texture_hw"])
            out.append(StoredObject(trajectory, float(a["width_m"]), float(a["height_m"]),
                                    o["alpha"][:].astype(np.float32) / np.float32(255.0),
                                    str(a["texture"]), (h, w)))
        return tuple(out)

    def object_trajectories(self, name: str) -> list[BSplineTrajectory]:
        """Object-to-world trajectories of the sequence's objects, in id order."""
        return [o.trajectory for o in self.objects(name)]

    def frame(self, name: str, camera: str, k: int, as_stored: bool = False) -> np.ndarray:
        """float32[H, W] frame ``k`` of ``camera`` (``as_stored``: in the file's dtype)."""
        img = self._group(name)["frames"][camera][k]
        return img if as_stored else img.astype(np.float32)

    def check_frames(self, name: str, camera: str) -> None:
        """Refuse frames that are no linear intensity: stored as other than float16/32, or
        (in the first and last frame) not finite or outside ``[0, MAX_INTENSITY]``.

        Raises:
            ValueError: naming the file, the dataset and the values found.
        """
        ds = self._group(name)["frames"][camera]
        where = f"{self.path}: {name}/frames/{camera}"
        if ds.dtype not in (np.float16, np.float32) or ds.ndim != 3:
            raise ValueError(f"{where}: {ds.dtype}{list(ds.shape)}, expected float16 or "
                             f"float32 [T, H, W] linear intensity")
        for k in sorted({0, len(ds) - 1}) if len(ds) else []:
            frame = ds[k].astype(np.float32)
            if not np.isfinite(frame).all() or frame.min() < 0 or frame.max() > MAX_INTENSITY:
                raise ValueError(f"{where}: frame {k} holds values {frame.min():.4g}.."
                                 f"{frame.max():.4g}, not linear intensity in [0, "
                                 f"{MAX_INTENSITY}] (the simulator writes [0, 1])")

    def frame_shape(self, name: str, camera: str) -> tuple[int, ...]:
        """(T, H, W) of ``camera``'s frames as stored (nothing read)."""
        return tuple(int(v) for v in self._group(name)["frames"][camera].shape)

    def frames(self, name: str, camera: str) -> Frames:
        """All frames of one camera, float32 linear intensity, with their times."""
        return Frames(self._group(name)["frames"][camera][:].astype(np.float32),
                      self.frame_times_ns(name))

    def frame_times_ns(self, name: str) -> np.ndarray:
        return np.round(self._group(name)["frames/ts"][:] * 1e9).astype(np.int64)

    def frame_event_idx(self, name: str) -> np.ndarray:
        return self._group(name)["frames/event_idx"][:]

    def video_source(self, name: str) -> dict[str, object] | None:
        """A from-video sequence's provenance (:data:`VIDEO_ATTRS` to values); None for a
        simulated scene."""
        a = self._group(name).attrs
        if VIDEO_ATTRS[0] not in a:
            return None
        return {k: a[k].item() if hasattr(a[k], "item") else a[k] for k in VIDEO_ATTRS}

    def trajectory(self, name: str) -> BSplineTrajectory:
        """The camera trajectory the sequence was simulated with (exact poses at any time).

        Raises:
            ValueError: the sequence has none (made from a video).
        """
        g = self._group(name)
        if "trajectory" not in g:
            raise ValueError(f"{self.path}/{name}: no camera trajectory (made from a video "
                             f"by datagen from-video), so no exact flow: train with "
                             f"data.flow dis, farneback or none")
        tr = g["trajectory"]
        return BSplineTrajectory(tr["positions"][:], tr["rotations"][:],
                                 float(tr.attrs["knot_spacing_s"]),
                                 float(tr.attrs["duration_s"]))

    def thresholds(self, name: str) -> ContrastThresholds:
        g = self._group(name)
        hw = self.sensor_hw(name)
        pos = float(g.attrs["contrast_threshold_pos"])
        neg = float(g.attrs["contrast_threshold_neg"])
        if "thresholds" in g:
            return ContrastThresholds(pos, neg, g["thresholds/pos_map"][:].astype(np.float64),
                                      g["thresholds/neg_map"][:].astype(np.float64))
        return ContrastThresholds.uniform(pos, neg, hw)

    def read(self, name: str) -> SequenceRecord:
        """The whole sequence in memory."""
        g = self._group(name)
        cams = self.frame_names(name)
        frames = {c: self.frames(name, c) for c in cams}
        truth = {c: gt for c in cams if (gt := self.ground_truth(name, c))}
        return SequenceRecord(name, self.events(name), frames, g["frames/poses"][:],
                              g["frames/event_idx"][:], g["poses"][:], self.cameras(name),
                              self.thresholds(name), dict(g.attrs), truth)
