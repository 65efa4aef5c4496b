"""Generate a dataset: plan shards, simulate their sequences in worker processes, write HDF5.

Guarantees:
- deterministic: sequence ``i`` depends only on (seed, i, config), and shard ``k`` always
  holds sequences ``k*S .. k*S+S-1``, so any ``--workers`` or job split gives the same files;
- atomic and resumable: a shard is written as ``shard_XXXXX.h5.tmp-<pid>`` and renamed when
  complete (its ``complete`` attribute is set last); a re-run skips complete shards written
  with the same config and seed and redoes everything else;
- bounded memory: events and frames are appended to the file chunk by chunk.
"""

from __future__ import annotations

import concurrent.futures as futures
import dataclasses
import errno
import logging
import multiprocessing as mp
import os
import queue
import threading
import time
from dataclasses import dataclass
from multiprocessing.managers import SyncManager
from pathlib import Path

import numpy as np
from tqdm import tqdm

from datagen.config import DatagenConfig
from datagen.lock import FolderLock, clear_leftovers
from datagen.sampling import sample_sequence
from datagen.sensor_ranges import SensorRanges
from datagen.shard import ShardReader, ShardWriter
from datagen.textures import TextureSampler
from esim_lite.core.atomic import atomic_path
from esim_lite.core.dataconf import to_yaml
from esim_lite.core.outputs import writable_folder
from esim_lite.render.renderer import make_renderer
from esim_lite.sequence import sample_footprints, simulate

log = logging.getLogger(__name__)


class DiskFullError(OSError):
    """Writing a shard failed because the disk is full."""


@dataclass(frozen=True)
class ShardPlan:
    """Shard ``index`` holds sequences ``first .. first + count - 1`` and lives at ``path``."""

    index: int
    first: int
    count: int
    path: Path

    @property
    def sequences(self) -> range:
        return range(self.first, self.first + self.count)


@dataclass(frozen=True)
class ShardResult:
    index: int
    sequences: int
    events: int
    frames: int
    bytes: int
    seconds: float


def plan_shards(out: Path, n_seq: int, per_shard: int, shard_index: int = 0,
                num_shards: int = 1) -> list[ShardPlan]:
    """The shards job ``shard_index`` of ``num_shards`` is responsible for."""
    if n_seq < 1:
        raise ValueError(f"--n-seq must be >= 1, got {n_seq}")
    if not 0 <= shard_index < num_shards:
        raise ValueError(f"--shard-index must be in [0, {num_shards}), got {shard_index}")
    total = (n_seq + per_shard - 1) // per_shard
    return [ShardPlan(k, k * per_shard, min(per_shard, n_seq - k * per_shard),
                      out / f"shard_{k:05d}.h5")
            for k in range(total) if k % num_shards == shard_index]


def shard_state(plan: ShardPlan, config_yaml: str, seed: int) -> str:
    """``done``, ``foreign`` or ``todo`` for one planned shard (see ShardReader.state)."""
    return ShardReader.state(plan.path, config_yaml, seed, plan.sequences)


def _resolve_variant(config: DatagenConfig) -> DatagenConfig:
    """Pin the Mitsuba variant 'auto' picks here: it changes the data (LLVM and scalar
    renders differ in the last bits), so it belongs to the dataset's stored config."""
    render = config.simulation.render
    if render.backend != "mitsuba":
        return config
    from esim_lite.render.mitsuba import resolve_variant

    render = dataclasses.replace(render, mitsuba_variant=resolve_variant(render.mitsuba_variant))
    return dataclasses.replace(config, simulation=dataclasses.replace(config.simulation,
                                                                      render=render))


def _with_threads(config: DatagenConfig, threads: int | None) -> DatagenConfig:
    """``config`` rendering with ``threads`` threads (does not change the data)."""
    if threads is None or config.simulation.render.threads is not None:
        return config
    render = dataclasses.replace(config.simulation.render, threads=threads)
    return dataclasses.replace(config, simulation=dataclasses.replace(config.simulation,
                                                                      render=render))


def write_shard(plan: ShardPlan, config: DatagenConfig, seed: int, progress=None,
                render_threads: int | None = None,
                textures: TextureSampler | None = None) -> ShardResult:
    """Simulate and write one shard atomically; ``progress(n_events)`` after each chunk and
    ``progress(None)`` after each sequence. ``textures``: a sampler over
    ``config.textures`` already scanned (a large folder is scanned once, not per shard)."""
    start = time.perf_counter()
    config_yaml = to_yaml(config)
    sim = _with_threads(config, render_threads).simulation
    textures = textures or TextureSampler(config.textures)
    n_events = n_frames = 0
    try:  # the temporary name carries our pid: see datagen.lock.stale_temporary
        with atomic_path(plan.path, f".tmp-{os.getpid()}", unique=False) as tmp:
            writer = ShardWriter(tmp, config_yaml, seed, list(plan.sequences))
            try:
                for index in plan.sequences:
                    e, f = _write_sequence(writer, sim, config.sensor_ranges, textures,
                                           seed, index, progress)
                    n_events, n_frames = n_events + e, n_frames + f
                    if progress:
                        progress(None)
                writer.finish()
            except BaseException:
                writer.close()  # before atomic_path removes the file
                raise
    except OSError as exc:
        if exc.errno == errno.ENOSPC or "No space left" in str(exc) or "errno = 28" in str(exc):
            raise DiskFullError(errno.ENOSPC, f"{plan.path}: disk full while writing "
                                f"the shard (partial file removed)") from exc
        raise
    return ShardResult(plan.index, plan.count, n_events, n_frames, plan.path.stat().st_size,
                       time.perf_counter() - start)


def _write_sequence(writer: ShardWriter, sim, sensor: SensorRanges, textures: TextureSampler,
                    seed: int, index: int, progress) -> tuple[int, int]:
    spec = sample_sequence(sim, textures, seed, index, sensor)
    sim = dataclasses.replace(sim, events=spec.events)  # the sequence's own sensor
    rig = sim.camera.rig()
    renderer = make_renderer(spec.scene, rig.cameras(), sim.render,
                             sample_footprints(spec.scene, spec.trajectory, rig, sim.render))
    name = renderer.name + (f":{renderer.variant}" if hasattr(renderer, "variant") else "")
    writer.begin_sequence(spec, rig.cameras(), sim.events.log_eps, name,
                          sim.frames.ground_truth)
    n_events = n_frames = 0
    try:
        for chunk in simulate(spec.scene, spec.trajectory, spec.thresholds, sim,
                              spec.noise_rng, renderer=renderer):
            ev, done = chunk.events, 0
            for frame in chunk.frames:  # events up to each frame's time precede it
                cut = int(np.searchsorted(ev.t_ns, frame.t_ns, side="right"))
                writer.append_events(ev.slice(done, cut))
                done = cut
                writer.append_frame(frame.t_ns, np.concatenate(
                    [[frame.t_ns * 1e-9], frame.pose.to_tq()]), frame.images, frame.truth)
            writer.append_events(ev.slice(done, len(ev)))
            writer.append_poses(chunk.sample_poses)
            n_events += len(ev)
            n_frames += len(chunk.frames)
            if progress:
                progress(len(ev))
    finally:
        renderer.close()
    writer.end_sequence()
    return n_events, n_frames


_QUEUE = None
_TEXTURES: TextureSampler | None = None  # one scan of the texture source per worker


def _init_worker(q, texture_config, parent: int | None = None) -> None:
    global _QUEUE, _TEXTURES
    _QUEUE = q
    _TEXTURES = TextureSampler(texture_config)
    import cv2

    cv2.setNumThreads(1)
    if parent is not None:
        _watch_parent(parent)


def _watch_parent(parent: int) -> None:
    threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()


def _exit_with_parent(parent: int, period_s: float = 1.0) -> None:
    """A worker whose ``datagen`` was killed (SIGTERM, SIGKILL: no cleanup runs there)
    would go on rendering its shard for minutes into a temporary file nobody renames:
    once its parent is gone (it is re-parented), it exits at once."""
    while os.getppid() == parent:
        time.sleep(period_s)
    os._exit(1)


def _worker(plan: ShardPlan, config: DatagenConfig, seed: int) -> ShardResult:
    return write_shard(plan, config, seed, progress=_QUEUE.put, render_threads=1,
                       textures=_TEXTURES)


@dataclass(frozen=True)
class GenerateSummary:
    shards_written: int
    shards_skipped: int
    sequences: int
    events: int
    frames: int
    bytes: int
    seconds: float

    def line(self) -> str:
        rate = self.sequences / self.seconds * 60 if self.seconds > 0 else 0.0
        return (f"wrote {self.shards_written} shard(s) ({self.sequences} sequences, "
                f"{self.events:,} events, {self.frames:,} frames, {self.bytes / 1e6:.1f} MB) in "
                f"{self.seconds:.1f} s ({rate:.1f} sequences/min); skipped "
                f"{self.shards_skipped} complete shard(s)")


def generate(config: DatagenConfig, out: str | Path, n_seq: int, seed: int = 0,
             workers: int = 1, shard_index: int = 0, num_shards: int = 1,
             show_progress: bool = True) -> GenerateSummary:
    """Write (or complete) a dataset of ``n_seq`` sequences under ``out``."""
    out = Path(out)
    plans = plan_shards(out, n_seq, config.sequences_per_shard, shard_index, num_shards)
    writable_folder(out)
    textures = TextureSampler(config.textures)  # fails here on a bad texture path
    config = _resolve_variant(config)
    config_yaml = to_yaml(config)
    with FolderLock(out, seed, config_yaml, shard_index, num_shards):
        return _generate_locked(out, plans, config, config_yaml, seed, workers, textures,
                                show_progress)


def _generate_locked(out: Path, plans: list[ShardPlan], config: DatagenConfig,
                     config_yaml: str, seed: int, workers: int, textures: TextureSampler,
                     show_progress: bool) -> GenerateSummary:
    """The body of :func:`generate`, run while this process holds the folder's lock."""
    states = {p.index: shard_state(p, config_yaml, seed) for p in plans}
    strangers = [p.path for p in plans if states[p.index] == "stranger"]
    if strangers:
        raise ValueError(f"{strangers[0]}: is in the way of a shard and is not one datagen "
                         f"wrote (not an e2sr shard); it is left as it is: move it or write "
                         f"this dataset to another --out folder")
    foreign = [p.path for p in plans if states[p.index] == "foreign"]
    if foreign:
        raise ValueError(f"{foreign[0]}: a complete shard made with a different config or "
                         f"seed is in the way; write this dataset to another --out folder")
    todo = [p for p in plans if states[p.index] == "todo"]
    clear_leftovers([p.path for p in plans], {p.path for p in todo})
    start = time.perf_counter()
    bar = tqdm(total=sum(p.count for p in todo), unit="seq", disable=not show_progress,
               desc="datagen")
    stats = {"events": 0}

    def progress(n_events) -> None:
        if n_events is None:
            bar.update(1)
        else:
            stats["events"] += n_events
        elapsed = time.perf_counter() - start
        bar.set_postfix_str(f"{stats['events'] / max(elapsed, 1e-9) / 1e3:.0f}k events/s",
                            refresh=False)

    results = _run(todo, config, seed, workers, progress, textures)
    bar.close()
    return GenerateSummary(len(results), len(plans) - len(todo),
                           sum(r.sequences for r in results), sum(r.events for r in results),
                           sum(r.frames for r in results), sum(r.bytes for r in results),
                           time.perf_counter() - start)


def _run(todo: list[ShardPlan], config: DatagenConfig, seed: int, workers: int,
         progress, textures: TextureSampler) -> list[ShardResult]:
    if workers <= 1 or len(todo) <= 1:
        return [write_shard(p, config, seed, progress, textures=textures) for p in todo]
    ctx = mp.get_context("spawn")  # drjit/numba threads do not survive fork
    manager = SyncManager(ctx=ctx)
    manager.start(_watch_parent, (os.getpid(),))  # the queue's server dies with us too
    with manager:
        return _run_pool(todo, config, seed, workers, progress, ctx, manager.Queue())


def _run_pool(todo, config, seed, workers, progress, ctx, q) -> list[ShardResult]:
    stop = threading.Event()

    def pump() -> None:
        while not stop.is_set():
            try:
                progress(q.get(timeout=0.2))
            except queue.Empty:
                continue

    thread = threading.Thread(target=pump, daemon=True)
    thread.start()
    results = []
    try:
        with futures.ProcessPoolExecutor(min(workers, len(todo)), mp_context=ctx,
                                         initializer=_init_worker,
                                         initargs=(q, config.textures, os.getpid())) as pool:
            jobs = [pool.submit(_worker, p, config, seed) for p in todo]
            for job in futures.as_completed(jobs):
                results.append(job.result())
    finally:
        stop.set()
        thread.join()
    return results
