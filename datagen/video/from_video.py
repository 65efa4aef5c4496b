"""``datagen from-video``: videos in, super-resolution training shards out.

Each input clip (see :mod:`datagen.video.source`) is cut into sequences of
``video.frames_per_sequence`` frames; the sequences of all clips are numbered in input
order and written ``sequences_per_shard`` to a shard, exactly like ``datagen generate``'s:

- a sequence's frames are its video frames, as the paired cameras see them
  (:mod:`datagen.video.optics`: HR by area resizing, LR the block mean of HR), at the
  video's own times (the first frame at t = 0);
- its events come from the same sensor model and per-sequence draws as ``generate``'s
  (:func:`datagen.sampling.sequence_streams` of ``(seed, index)``: sensor ranges, then
  thresholds, then the noise stream), simulated on LR intensity sampled between the frames
  by the configured interpolator (:mod:`datagen.video.interpolate`): at least
  ``max_motion_px`` apart in motion and ``max_step_s`` in time, and each accepted step
  changes no pixel's log intensity by more than ``contrast_fraction`` of its threshold
  (outside occlusions), a longer one being retried shorter, down to ``min_step_s``; at a
  scene cut the sensor restarts at the new frame (no burst);
- deterministic (the bytes depend only on the inputs' content, the config and the seed,
  whatever ``--workers`` or job split), atomic and resumable (a shard is renamed into
  place when complete; a re-run skips complete shards of the same inputs, config and
  seed), one writer per folder (:class:`datagen.lock.FolderLock`), streaming (two frames
  in memory at a time, whatever the video's length).

The shard's stored config is the resolved config followed by ``sources``: each clip's
name, SHA-256 and frame count, so other inputs make another dataset (refused in the same
folder) and a renamed or moved copy of the same inputs resumes.
"""

from __future__ import annotations

import concurrent.futures as futures
import errno
import logging
import math
import multiprocessing as mp
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from tqdm import tqdm

from datagen.generate import DiskFullError, GenerateSummary, ShardResult
from datagen.lock import FolderLock, clear_leftovers
from datagen.sampling import sequence_streams
from datagen.shard import ShardReader, ShardWriter, VideoProvenance
from datagen.video.config import FromVideoConfig
from datagen.video.interpolate import Between, Interpolator
from datagen.video.optics import CameraImages, camera_images, check_frame_size
from datagen.video.source import Source, read_frames, scan_inputs
from esim_lite.core.atomic import atomic_path
from esim_lite.core.dataconf import to_yaml
from esim_lite.core.outputs import writable_folder
from esim_lite.events.sampling import SAFETY
from esim_lite.events.simulator import log_intensity
from esim_lite.events.thresholds import ContrastThresholds, sample_thresholds
from esim_lite.sequence import EventCamera, event_camera

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class SequencePlan:
    """Sequence ``index`` of the dataset: frames ``start .. stop - 1`` of ``source``."""

    index: int
    source: Source
    start: int
    stop: int


@dataclass(frozen=True, eq=False)
class VideoShardPlan:
    """Shard ``index`` holds ``sequences`` and lives at ``path``."""

    index: int
    sequences: tuple[SequencePlan, ...]
    path: Path

    @property
    def indices(self) -> list[int]:
        return [s.index for s in self.sequences]


def plan_sequences(sources: list[Source], config: FromVideoConfig) -> list[SequencePlan]:
    """Every sequence of the dataset, numbered in input order.

    Raises:
        ValueError: a clip shorter than one sequence, or too small for the HR frames.
    """
    cam, video = config.simulation.camera, config.video
    sensor_hw, finest = (cam.height, cam.width), max(cam.scales)
    plans: list[SequencePlan] = []
    for src in sources:
        check_frame_size(src.frame_hw, sensor_hw, finest, str(src.path))
        n = video.sequences_in(src.n_frames)
        if n == 0:
            raise ValueError(f"{src.path}: {src.n_frames} frame(s), fewer than one sequence "
                             f"of video.frames_per_sequence = {video.frames_per_sequence}; "
                             f"leave it out or set a shorter sequence (--set "
                             f"video.frames_per_sequence=N)")
        for j in range(n):
            start = j * video.stride
            plans.append(SequencePlan(len(plans), src, start,
                                      start + video.frames_per_sequence))
    return plans


def plan_shards(out: Path, sequences: list[SequencePlan], per_shard: int,
                shard_index: int = 0, num_shards: int = 1) -> list[VideoShardPlan]:
    """The shards job ``shard_index`` of ``num_shards`` writes (shard ``k`` holds
    sequences ``k * per_shard ..``, whichever job writes it)."""
    if not 0 <= shard_index < num_shards:
        raise ValueError(f"--shard-index must be in [0, {num_shards}), got {shard_index}")
    total = (len(sequences) + per_shard - 1) // per_shard
    return [VideoShardPlan(k, tuple(sequences[k * per_shard:(k + 1) * per_shard]),
                           out / f"shard_{k:05d}.h5")
            for k in range(total) if k % num_shards == shard_index]


def dataset_yaml(config: FromVideoConfig, sources: list[Source]) -> str:
    """The text stored as every shard's ``config``: the resolved config, then the clips
    by name, digest and frame count (their content, not where they lie)."""
    clips = [{"name": s.path.name, "kind": s.kind, "sha256": s.sha256, "frames": s.n_frames}
             for s in sources]
    return to_yaml(config) + yaml.safe_dump({"sources": clips}, sort_keys=False)


# ----------------------------------------------------------------------------- one sequence


@dataclass(frozen=True)
class _Budget:
    """The review's rule: the largest weighed log change of an accepted step."""

    limit: float
    weight: np.ndarray | None

    @classmethod
    def of(cls, fraction: float, thresholds: ContrastThresholds) -> _Budget:
        """``fraction`` of the smaller nominal threshold, each pixel weighed by the share
        its own threshold is of it (as :class:`esim_lite.events.sampling.AdaptiveSampler`
        does)."""
        nominal = min(thresholds.pos, thresholds.neg)
        pixel = np.minimum(thresholds.pos_map, thresholds.neg_map)
        weight = (nominal / pixel).astype(np.float32) if pixel.max() > pixel.min() else None
        return cls(fraction * nominal, weight)

    def change(self, before: np.ndarray, after: np.ndarray, skip: np.ndarray | None) -> float:
        diff = np.abs(after - before)
        if self.weight is not None:
            diff = diff * self.weight
        if skip is not None:
            diff = np.where(skip, 0.0, diff)
        return float(diff.max())


def _union(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    return b if a is None else a if b is None else a | b


def pair_samples(between: Between, camera: EventCamera, t0: int, t1: int,
                 lr1: np.ndarray, log0: np.ndarray, config: FromVideoConfig,
                 budget: _Budget) -> Iterator[tuple[int, np.ndarray]]:
    """``(t_ns, log image)`` of the samples after ``t0`` up to and including ``t1`` (the
    second frame ``lr1`` itself), given the first's log image ``log0`` (see the module
    doc for the rules)."""
    sc, eps = config.simulation.sampling, config.simulation.events.log_eps
    span = t1 - t0
    n = max(1, math.ceil(span * 1e-9 / sc.max_step_s - 1e-9))
    if between.motion_px > 0:
        n = max(n, math.ceil(between.motion_px / config.video.flow.max_motion_px))
    grid = span / n
    min_ns = max(1, int(round(sc.min_step_s * 1e9)))
    t, last, log_prev, skip_prev = t0, grid, log0, None
    while t < t1:
        still = camera.sim.max_step(sc.contrast_fraction)
        if camera.flicker is not None:
            still = min(still, camera.flicker.max_step(budget.limit))
        proposal = min(grid, 2 * last if sc.adaptive else grid, still * 1e9)
        while True:
            t_new = min(t + max(1, int(round(proposal))), t1)
            image, skip = (lr1, None) if t_new == t1 else between.at((t_new - t0) / span)
            log_new = log_intensity(camera.light(image, t_new), eps)
            if not sc.adaptive or t_new - t <= min_ns:
                break
            change = budget.change(log_prev, log_new, _union(skip_prev, skip))
            if change <= budget.limit:
                break
            proposal = max(min_ns, (t_new - t) * SAFETY * budget.limit / change)
        yield t_new, log_new
        last, t, log_prev, skip_prev = t_new - t, t_new, log_new, skip


@dataclass(frozen=True)
class SequenceResult:
    events: int
    frames: int
    samples: int
    scene_cuts: int


def _pose_rows(times_ns: list[int]) -> np.ndarray:
    """float64[S, 8]: time (s) and NaN pose (a video has no camera pose)."""
    rows = np.full((len(times_ns), 8), np.nan)
    rows[:, 0] = np.asarray(times_ns, np.float64) * 1e-9
    return rows


def write_sequence(writer: ShardWriter, plan: SequencePlan, config: FromVideoConfig,
                   seed: int, interpolator: Interpolator) -> SequenceResult:
    """Simulate sequence ``plan`` and append it to ``writer`` (frames streamed)."""
    sim_cfg, src = config.simulation, plan.source
    rng = sequence_streams(seed, plan.index)
    events_cfg, drawn = sim_cfg.events, config.sensor_ranges.enabled
    if drawn:
        events_cfg = config.sensor_ranges.draw(events_cfg, rng["sensor"])
    cam = sim_cfg.camera
    sensor_hw, scales = (cam.height, cam.width), tuple(cam.scales)
    thresholds = sample_thresholds(events_cfg.thresholds, sensor_hw, rng["thresholds"])
    times = src.t_ns[plan.start:plan.stop] - src.t_ns[plan.start]
    provenance = VideoProvenance(src.path.resolve(), src.sha256, src.kind, plan.start,
                                 plan.stop, float(src.t_ns[plan.start] * 1e-9),
                                 interpolator.name)
    writer.begin_video_sequence(plan.index, seed, thresholds, cam.rig().cameras(),
                                events_cfg.log_eps, provenance, events_cfg if drawn else None)
    frames = read_frames(src, plan.start, plan.stop)

    def images(frame: np.ndarray) -> CameraImages:
        return camera_images(frame, sensor_hw, scales, config.video.work_scale,
                             config.video.colour)

    budget = _Budget.of(sim_cfg.sampling.contrast_fraction, thresholds)
    prev = images(next(frames))
    camera = event_camera(events_cfg, thresholds, rng["noise"], prev.images["lr"], 0)
    writer.append_frame(0, _pose_rows([0])[0], prev.images)
    log_prev = log_intensity(camera.light(prev.images["lr"], 0), events_cfg.log_eps)
    n_events = n_samples = cuts = 0
    for k, frame in enumerate(frames, 1):
        cur = images(frame)
        t0, t1 = int(times[k - 1]), int(times[k])
        between = interpolator.between(prev, cur)
        if between.cut:
            cuts += 1
            camera.sim.restart(camera.light(cur.images["lr"], t1), t1)
            log_prev, sample_times = log_intensity(camera.light(cur.images["lr"], t1),
                                                   events_cfg.log_eps), [t1]
        else:
            sample_times = []
            for t, log_img in pair_samples(between, camera, t0, t1, cur.images["lr"],
                                           log_prev, config, budget):
                batch = camera.sim.step_log(log_img, t)
                writer.append_events(batch)
                n_events += len(batch)
                sample_times.append(t)
                log_prev = log_img
        writer.append_poses(_pose_rows(sample_times))
        n_samples += len(sample_times)
        writer.append_frame(t1, _pose_rows([t1])[0], cur.images)
        prev = cur
    tail = camera.sim.finish()
    writer.append_events(tail)
    writer.end_sequence(scene_cuts=cuts)
    return SequenceResult(n_events + len(tail), len(times), n_samples, cuts)


# ------------------------------------------------------------------------------- shards


def write_shard(plan: VideoShardPlan, config: FromVideoConfig, config_yaml: str,
                seed: int) -> ShardResult:
    """Simulate and write one shard atomically."""
    start = time.perf_counter()
    interpolator = Interpolator(config.video, config.simulation.events.log_eps)
    n_events = n_frames = 0
    try:  # the temporary name carries our pid: see datagen.lock.stale_temporary
        with atomic_path(plan.path, f".tmp-{os.getpid()}", unique=False) as tmp:
            writer = ShardWriter(tmp, config_yaml, seed, plan.indices)
            try:
                for seq in plan.sequences:
                    r = write_sequence(writer, seq, config, seed, interpolator)
                    n_events, n_frames = n_events + r.events, n_frames + r.frames
                writer.finish()
            except BaseException:
                writer.close()  # before atomic_path removes the file
                raise
    except OSError as exc:
        if exc.errno == errno.ENOSPC or "No space left" in str(exc):
            raise DiskFullError(errno.ENOSPC, f"{plan.path}: disk full while writing "
                                f"the shard (partial file removed)") from exc
        raise
    return ShardResult(plan.index, len(plan.sequences), n_events, n_frames,
                       plan.path.stat().st_size, time.perf_counter() - start)


def _init_worker(parent: int) -> None:
    import threading

    import cv2

    cv2.setNumThreads(1)

    def exit_with_parent() -> None:  # a killed parent leaves no worker writing on
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=exit_with_parent, daemon=True).start()


def from_video(inputs: list[str | Path], out: str | Path, config: FromVideoConfig,
               seed: int = 0, workers: int = 1, fps: float | None = None,
               shard_index: int = 0, num_shards: int = 1,
               show_progress: bool = True) -> GenerateSummary:
    """Write (or complete) the dataset of ``inputs`` under ``out``.

    Every input is scanned and checked before the folder is touched, so a bad input is
    refused with nothing written.

    Raises:
        FileNotFoundError, ValueError: a bad input (named), a folder of another dataset.
    """
    out = Path(out)
    sources = scan_inputs(inputs, fps)
    sequences = plan_sequences(sources, config)
    plans = plan_shards(out, sequences, config.sequences_per_shard, shard_index, num_shards)
    config_yaml = dataset_yaml(config, sources)
    writable_folder(out)
    with FolderLock(out, seed, config_yaml, shard_index, num_shards):
        todo, skipped = _todo(plans, config_yaml, seed)
        start = time.perf_counter()
        results = _run(todo, config, config_yaml, seed, workers, show_progress)
    return GenerateSummary(len(results), skipped, sum(r.sequences for r in results),
                           sum(r.events for r in results), sum(r.frames for r in results),
                           sum(r.bytes for r in results), time.perf_counter() - start)


def _todo(plans: list[VideoShardPlan], config_yaml: str, seed: int
          ) -> tuple[list[VideoShardPlan], int]:
    """The shards still to write (their leftovers removed) and how many are complete."""
    states = {p.index: ShardReader.state(p.path, config_yaml, seed, p.indices) for p in plans}
    for kind, why in (("stranger", "is not a shard datagen wrote; it is left as it is: move "
                                   "it or write this dataset to another --out folder"),
                      ("foreign", "is a complete shard of other inputs, config or seed; "
                                  "write this dataset to another --out folder")):
        bad = [p.path for p in plans if states[p.index] == kind]
        if bad:
            raise ValueError(f"{bad[0]}: in the way of a shard of this dataset: it {why}")
    todo = [p for p in plans if states[p.index] == "todo"]
    clear_leftovers([p.path for p in plans], {p.path for p in todo})
    return todo, len(plans) - len(todo)


def _run(todo: list[VideoShardPlan], config: FromVideoConfig, config_yaml: str, seed: int,
         workers: int, show_progress: bool) -> list[ShardResult]:
    bar = tqdm(total=sum(len(p.sequences) for p in todo), unit="seq",
               disable=not show_progress, desc="from-video")
    results = []
    try:
        if workers <= 1 or len(todo) <= 1:
            for p in todo:
                results.append(write_shard(p, config, config_yaml, seed))
                bar.update(len(p.sequences))
            return results
        ctx = mp.get_context("spawn")  # numba and OpenCV threads do not survive fork
        with futures.ProcessPoolExecutor(min(workers, len(todo)), mp_context=ctx,
                                         initializer=_init_worker,
                                         initargs=(os.getpid(),)) as pool:
            jobs = {pool.submit(write_shard, p, config, config_yaml, seed): p for p in todo}
            for job in futures.as_completed(jobs):
                results.append(job.result())
                bar.update(len(jobs[job].sequences))
        return results
    finally:
        bar.close()

