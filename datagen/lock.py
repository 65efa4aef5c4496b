"""One writer per dataset folder, and one dataset per folder.

``datagen generate`` holds a :class:`FolderLock` on its ``--out`` folder while it writes;
its bookkeeping lives in ``<out>/.datagen/``:

- ``.datagen.lock``: an ``flock`` taken exclusively by a plain run and shared by the jobs of
  a job array (``--shard-index i --num-shards n``), so array jobs may share the folder with
  each other but not with a plain run; ``.datagen.job-i-of-n.lock``, exclusive, so two
  processes never write the same job's shards. The kernel releases an ``flock`` when its
  process dies, however it dies, so a killed run never leaves the folder stuck.
- ``.datagen.owner-<pid>.json``: who holds the lock (pid, host, seed, job, start time), for
  the message a refused writer prints; removed on exit, ignored when its pid is gone.
- ``dataset.json``: the dataset's identity (seed and a digest of the resolved config),
  written by the folder's first writer (and by any writer while the folder has no shard
  yet). Once shards exist, a writer of another seed or config is refused, so two datasets
  are never mixed in one folder, concurrently or one after the other.

Temporary shard files carry their writer's pid (``shard_XXXXX.h5.tmp-<pid>``): only those
of processes that no longer exist are removed (:func:`stale_temporary`).
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import socket
import time
from pathlib import Path

STATE = ".datagen"
LOCK = ".datagen.lock"
IDENTITY = "dataset.json"


class FolderBusyError(ValueError):
    """Another live process writes to the folder (the message names it)."""


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def stale_temporary(path: Path) -> bool:
    """Whether ``path`` (``*.tmp-<pid>``) was left by a process that no longer exists."""
    try:
        pid = int(path.name.rsplit("-", 1)[1])
    except (IndexError, ValueError):
        return False
    return pid != os.getpid() and not alive(pid)


def clear_leftovers(shards: list[Path], unfinished: set[Path]) -> None:
    """Before writing ``shards``: remove the temporary files of interrupted runs beside each
    (never a live process's: :func:`stale_temporary`) and the shards in ``unfinished``
    (incomplete ones, which are written again)."""
    for path in shards:
        for stale in path.parent.glob(path.name + ".tmp-*"):
            if stale_temporary(stale):
                stale.unlink(missing_ok=True)
        if path in unfinished:
            path.unlink(missing_ok=True)


def _owners(state: Path) -> list[dict]:
    out = []
    for f in sorted(state.glob(".datagen.owner-*.json")):
        try:
            info = json.loads(f.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if alive(int(info.get("pid", -1))):
            out.append(info)
    return out


def _describe(owners: list[dict]) -> str:
    if not owners:
        return "another process"
    return "; ".join(f"pid {o['pid']} on {o.get('host', '?')} (seed {o.get('seed')}, job "
                     f"{o.get('job')}, since {o.get('started')})" for o in owners)


def config_digest(config_yaml: str) -> str:
    return hashlib.sha256(config_yaml.encode()).hexdigest()[:16]


class FolderLock:
    """``with FolderLock(out, seed, config_yaml, shard_index, num_shards):`` write shards.

    Raises:
        FolderBusyError: a live writer holds a conflicting lock (named in the message).
        ValueError: the folder holds a dataset of another seed or config.
    """

    def __init__(self, folder: str | Path, seed: int, config_yaml: str, shard_index: int = 0,
                 num_shards: int = 1) -> None:
        self.folder, self.seed = Path(folder), seed
        self.state = self.folder / STATE
        self.digest = config_digest(config_yaml)
        self.job = f"{shard_index}-of-{num_shards}"
        self.array = num_shards > 1
        self._files: list = []
        self._owner: Path | None = None

    def _flock(self, name: str, exclusive: bool) -> None:
        f = open(self.state / name, "a+")  # noqa: SIM115 (held until release)
        try:
            fcntl.flock(f, (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB)
        except BlockingIOError:
            f.close()
            raise FolderBusyError(f"{self.folder}: another datagen is writing to this folder: "
                                  f"{_describe(_owners(self.state))}; wait for it or use "
                                  f"another --out") from None
        self._files.append(f)

    def __enter__(self) -> FolderLock:
        self.state.mkdir(parents=True, exist_ok=True)
        try:
            self._flock(LOCK, exclusive=not self.array)
            self._flock(f".datagen.job-{self.job}.lock", exclusive=True)
            # identity check and registration as one step among concurrent array jobs
            with open(self.state / ".datagen.identity.lock", "a+") as guard:
                fcntl.flock(guard, fcntl.LOCK_EX)
                self._check_identity()
                self._owner = self.state / f".datagen.owner-{os.getpid()}.json"
                self._owner.write_text(json.dumps({
                    "pid": os.getpid(), "host": socket.gethostname(), "seed": self.seed,
                    "job": self.job, "config": self.digest,
                    "started": time.strftime("%Y-%m-%d %H:%M:%S")}))
        except BaseException:
            self.release()
            raise
        return self

    def _check_identity(self) -> None:
        path = self.state / IDENTITY
        mine = {"seed": self.seed, "config": self.digest}
        # the recorded dataset binds this run once shards exist or another writer is live
        has_shards = any(self.folder.glob("shard_*.h5")) or any(
            o["pid"] != os.getpid() for o in _owners(self.state))
        if path.is_file() and has_shards:
            try:
                theirs = json.loads(path.read_text())
            except json.JSONDecodeError as exc:
                raise ValueError(f"{path}: not valid JSON ({exc})") from exc
            if {k: theirs.get(k) for k in mine} != mine:
                raise ValueError(f"{self.folder}: holds the dataset of seed "
                                 f"{theirs.get('seed')} (config {theirs.get('config')}); "
                                 f"this run has a different config or seed (seed "
                                 f"{self.seed}, config {self.digest}): write it to another "
                                 f"--out folder")
            return
        if has_shards:
            return  # made before datasets recorded their identity: the shard checks decide
        # no shard yet (a new folder, or one whose first writer died before finishing any):
        # this run's dataset is the folder's
        tmp = path.with_name(f"{IDENTITY}.tmp-{os.getpid()}")
        tmp.write_text(json.dumps(mine) + "\n")
        os.replace(tmp, path)

    def release(self) -> None:
        if self._owner is not None:
            self._owner.unlink(missing_ok=True)
            self._owner = None
        for f in reversed(self._files):
            f.close()
        self._files = []

    def __exit__(self, *exc) -> None:
        self.release()
