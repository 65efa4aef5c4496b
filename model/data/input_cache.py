"""Precomputed network inputs: SBN stacks, classical flow and frames, once per training set.

Building a sample from a shard (read and decompress events, paint SBN stacks, run DIS twice
or more, read and decompress the frames) costs CPU time per sample that data workers would
take from the network on a machine with few cores (bench/bench_train.py measures it). The cache does
that work once, in parallel, and stores whole-frame arrays that training reads through
memory maps and only crops and flips.

Layout (one folder per shard, written under a temporary name and renamed when complete,
so an interrupted build leaves nothing that looks finished and resumes shard by shard)::

    <shard folder>/cache/<settings hash>/<shard stem>-<shard content hash>/
    (or ...-<shard content hash>-<samples hash>/: a second dataset over the same shard
    whose samples the first folder lacks gets its own, never a replacement of the first,
    which a run may be reading)
        stacks.npy  uint8[U, c, H, W]       distinct stacks (neighbouring samples share them)
        flows.npy   float16[F, 2, H, W]     DIS flow from a sample's central stack to a side
        lr.npy, hr.npy [R, 1, H, W], [R, 1, sH, sW]   the sample's frames (the shard's dtype)
        rows.npy    int32[R, 2n]            per sample: n stack rows, then n flow rows (-1:
                                            the central stack, whose flow is zero)
        keys.json   ["seq_000012/17", ...]  sequence/frame of each sample row

The two hashes cover everything the arrays depend on (stack settings, flow method, number
of stacks, scale; the shard's config, seed, sequences and size), so a changed setting or a
regenerated shard builds a new cache instead of reading a stale one. Flow is computed on
whole frames, as at reconstruction, then cropped with the sample (the uncached path runs
DIS on the crop).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from datagen.shard import ShardReader
from esim_lite.core.scales import hr_camera
from esim_lite.core.stacking import StackConfig, stacks_around
from model.data.classical_flow import classical_flow, stack_to_gray

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CacheSpec:
    """What the cached arrays depend on besides the shards themselves."""

    stacks: StackConfig
    flow: str  # dis, farneback or none
    n_stacks: int
    scale: int
    stack_rule: str = "fixed"  # data.stack_rule: the samples carry their stack sizes

    def __post_init__(self) -> None:
        if self.stacks.method != "sbn":
            raise ValueError("data.cache needs SBN stacks (data.stacks.method: sbn)")
        if self.flow not in ("dis", "farneback", "none"):
            raise ValueError(f"data.cache supports classical flow or none, not {self.flow!r}")


def shard_identity(path: Path) -> str:
    """Content identity of a complete shard: its config, seed, sequences and size."""
    with ShardReader(path) as reader:
        parts = [reader.config_yaml, str(reader.seed), str(reader.planned_sequences),
                 ",".join(reader.sequences())]
    return hashlib.sha256("\n".join(parts + [str(path.stat().st_size)]).encode()).hexdigest()


def cache_folder(spec: CacheSpec, shard: Path) -> Path:
    """Where one shard's cache lives: beside the shard (links resolved, so a folder of links
    to a subset shares the cache of the whole set), under the settings' hash, named by the
    shard's content identity."""
    real = Path(shard).resolve()
    text = repr(spec)
    if spec.stack_rule == "fixed":  # caches built before the rule existed keep their key
        text = text.replace(", stack_rule='fixed'", "")
    key = hashlib.sha256(text.encode()).hexdigest()[:12]
    return real.parent / "cache" / key / f"{real.stem}-{shard_identity(real)[:12]}"


def _shard_arrays(path: Path, refs: list, spec: CacheSpec) -> dict[str, np.ndarray | list]:
    """All cached arrays of one shard's samples ``refs`` (model.data.dataset.SampleRef)."""
    mid = spec.n_stacks // 2
    stacks, stack_rows = [], {}
    flows, lr, hr, rows, keys = [], [], [], [], []
    hr_name = hr_camera(spec.scale)
    with ShardReader(path) as reader:
        by_seq: dict[str, list] = {}
        for r in refs:
            by_seq.setdefault(r.sequence, []).append(r)
        for seq, seq_refs in sorted(by_seq.items()):
            events = reader.events(seq)
            for r in sorted(seq_refs, key=lambda r: r.anchor):
                built = stacks_around(events, r.stacks(spec.stacks), spec.n_stacks, r.anchor,
                                      r.t_ns)
                idx = []
                for st in built:
                    key = (seq, st.bounds.tobytes())
                    if key not in stack_rows:
                        stack_rows[key] = len(stacks)
                        stacks.append(st.image)
                    idx.append(stack_rows[key])
                centre = stack_to_gray(built[mid].image)
                flow_idx = []
                for j, st in enumerate(built):
                    if j == mid or spec.flow == "none":
                        flow_idx.append(-1)
                        continue
                    f = classical_flow(centre, stack_to_gray(st.image), spec.flow)
                    flow_idx.append(len(flows))
                    flows.append(f.transpose(2, 0, 1).astype(np.float16))
                rows.append(idx + flow_idx)
                lr.append(reader.frame(seq, "lr", r.frame, as_stored=True)[None])
                hr.append(reader.frame(seq, hr_name, r.frame, as_stored=True)[None])
                keys.append(f"{seq}/{r.frame}")
    h, w = events.sensor_hw
    return {"stacks": np.stack(stacks), "rows": np.asarray(rows, np.int32),
            "flows": np.stack(flows) if flows else np.zeros((0, 2, h, w), np.float16),
            "lr": np.stack(lr), "hr": np.stack(hr), "keys": keys}


ARRAYS = ("stacks", "flows", "lr", "hr", "rows")
"""The arrays of a cache folder, one ``.npy`` file each."""


def _ref_key(ref) -> str:
    return f"{ref.sequence}/{ref.frame}"


def covers(folder: Path, refs: list) -> bool:
    """Whether the complete cache folder ``folder`` holds every sample of ``refs``. The
    samples a run asks for depend on the whole dataset (validation keeps frames spread
    over all held-out sequences), so a shard cached for one folder of links may lack
    samples another folder over the same shard needs."""
    if not (folder / "keys.json").is_file():
        return False
    keys = set(json.loads((folder / "keys.json").read_text()))
    return all(_ref_key(r) in keys for r in refs)


def _variant(folder: Path, refs: list) -> Path:
    """The cache folder of exactly ``refs``'s samples beside ``folder`` (named by them)."""
    keys = "\n".join(sorted(_ref_key(r) for r in refs))
    return folder.with_name(f"{folder.name}-{hashlib.sha256(keys.encode()).hexdigest()[:12]}")


def build_shard(folder: Path, path: Path, refs: list, spec: CacheSpec) -> Path:
    """The cache folder holding every sample of ``refs``, written atomically when there is
    none: ``folder`` itself when it holds them or is free; when ``folder`` holds another
    dataset's samples (a run over another folder of links to the same shard may be reading
    it), a folder of its own beside it (:func:`_variant`), never a replacement. Returns the
    folder used."""
    if covers(folder, refs):
        return folder
    if (folder / "keys.json").is_file():
        folder = _variant(folder, refs)
        if covers(folder, refs):
            return folder
    tmp = folder.with_name(f"{folder.name}.tmp-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        arrays = _shard_arrays(path, refs, spec)
        for name in ARRAYS:
            np.save(tmp / f"{name}.npy", arrays[name])
        (tmp / "keys.json").write_text(json.dumps(arrays["keys"]))
        old = folder.with_name(f"{folder.name}.old-{os.getpid()}")
        if folder.is_dir() and not (folder / "keys.json").is_file():  # never completed
            os.rename(folder, old)
        try:
            os.rename(tmp, folder)
        except OSError:  # another process finished this folder first
            if not covers(folder, refs):
                folder = _variant(folder, refs)
                if not covers(folder, refs):
                    os.rename(tmp, folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.rmtree(folder.with_name(f"{folder.name}.old-{os.getpid()}"), ignore_errors=True)
    return folder


def _build_job(job: tuple[Path, Path, list, CacheSpec]) -> tuple[str, Path]:
    return str(job[1]), build_shard(*job)


class InputCache:
    """Cached inputs of a set of samples: ``cache.sample(ref)`` -> (stacks uint8[n, c, H, W],
    flows float32[n, 2, H, W], lr float32[H, W], hr float32[sH, sW]).

    Memory maps are opened lazily, once per process (DataLoader workers included).
    """

    def __init__(self, folders: dict[str, Path]) -> None:
        self.folders = folders  # shard path -> its cache folder
        self._maps: dict[str, dict] = {}
        self._pid: int | None = None

    @classmethod
    def build(cls, shards: Sequence[Path], refs: list, spec: CacheSpec, workers: int = 1
              ) -> InputCache:
        """Build (or reuse) the cache of ``refs`` beside their shards."""
        by_shard: dict[str, list] = {str(p): [] for p in shards}
        for r in refs:
            by_shard[r.path].append(r)
        folders = {p: cache_folder(spec, Path(p)) for p, rs in by_shard.items() if rs}
        for p in folders:  # another dataset's cache of the shard may hold ours already
            if not covers(folders[p], by_shard[p]) and \
                    covers(_variant(folders[p], by_shard[p]), by_shard[p]):
                folders[p] = _variant(folders[p], by_shard[p])
        jobs = [(folders[p], Path(p), by_shard[p], spec) for p in folders
                if not covers(folders[p], by_shard[p])]
        if jobs:
            root = jobs[0][0].parent
            log.info("caching inputs of %d shard(s) in %s", len(jobs), root)
            try:
                root.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise ValueError(f"{root}: cannot create the input cache ({exc})") from exc
            if workers > 1 and len(jobs) > 1:
                with get_context("spawn").Pool(min(workers, len(jobs))) as pool:
                    folders.update(pool.imap_unordered(_build_job, jobs))
            else:
                folders.update(_build_job(job) for job in jobs)
        return cls(folders)

    def _map(self, path: str) -> dict:
        if self._pid != os.getpid():
            self._maps, self._pid = {}, os.getpid()
        if path not in self._maps:
            folder = self.folders[path]
            m = {n: np.load(folder / f"{n}.npy", mmap_mode="r") for n in ARRAYS}
            keys = json.loads((folder / "keys.json").read_text())
            m["index"] = {k: i for i, k in enumerate(keys)}
            self._maps[path] = m
        return self._maps[path]

    def _row(self, ref) -> tuple[dict, int]:
        m = self._map(ref.path)
        try:
            return m, m["index"][f"{ref.sequence}/{ref.frame}"]
        except KeyError as exc:
            raise ValueError(f"{self.folders[ref.path]}: no cached sample for "
                             f"{ref.sequence} frame {ref.frame}") from exc

    def sample(self, ref) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        m, row = self._row(ref)
        ids = m["rows"][row]
        n = len(ids) // 2
        stacks = m["stacks"][ids[:n]]
        _, _, h, w = stacks.shape
        flows = np.zeros((n, 2, h, w), np.float32)
        for j, f in enumerate(ids[n:]):
            if f >= 0:
                flows[j] = m["flows"][f]
        return (stacks, flows, m["lr"][row, 0].astype(np.float32),
                m["hr"][row, 0].astype(np.float32))
