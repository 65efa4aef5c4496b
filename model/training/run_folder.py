"""One run per folder, and one writer per run.

``train --out DIR`` claims ``DIR`` for the whole of its run with :class:`RunFolder`:

- a folder that already holds a run (its checkpoint, validation history, TensorBoard logs,
  ...) is refused unless the run continues it (``--resume``) or the user asks to start
  afresh in it (``--overwrite``, which removes the old run's files first), so forgetting
  ``--resume`` never overwrites hours of training;
- an exclusive ``flock`` on ``DIR/.train.lock`` is held while the run lives, so a second
  ``train`` on the same folder is refused with the live process named
  (``DIR/.train.owner.json``: pid, host, seed, start time). The kernel releases an
  ``flock`` when its process dies, however it dies, so a killed run never leaves the folder
  stuck and can be resumed at once.

Under torchrun only rank 0 writes the folder, so only rank 0 claims it (the launcher stops
the other ranks when rank 0 exits with an error).
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import socket
import time
from pathlib import Path

from datagen.lock import FolderBusyError, alive

LOCK = ".train.lock"
OWNER = ".train.owner.json"

#: What a run writes into its folder (model/training/train.py, flow_pretrain.py, curves.py).
RUN_FILES = ("last.pt", "flow_last.pt", "config.yaml", "val_history.csv", "val_curve.png",
             "val_examples.png", "result.json")
RUN_DIRS = ("tb",)
RUN_GLOBS = ("nan_step*.pt",)


def run_files(folder: Path) -> list[Path]:
    """The files and folders of a run found in ``folder`` (empty: none)."""
    found = [folder / n for n in RUN_FILES if (folder / n).is_file()]
    found += [folder / n for n in RUN_DIRS if (folder / n).is_dir()]
    for pattern in RUN_GLOBS:
        found += sorted(folder.glob(pattern))
    return found


def describe_run(folder: Path, found: list[Path]) -> str:
    """``last.pt at step 1,234, val_history.csv (12 validations), tb/``: what is there."""
    parts = []
    for p in found:
        text = p.name + ("/" if p.is_dir() else "")
        if p.name in ("last.pt", "flow_last.pt"):
            step = _checkpoint_step(p)
            text += f" at step {step:,}" if step is not None else " (unreadable)"
        elif p.name == "val_history.csv":
            rows = max(0, len(p.read_text(errors="replace").splitlines()) - 1)
            text += f" ({rows} validation{'s' if rows != 1 else ''})"
        parts.append(text)
    return ", ".join(parts)


def _checkpoint_step(path: Path) -> int | None:
    from model import checkpoint  # torch only when a checkpoint is there to describe

    try:
        return int(checkpoint.load_any(path).get("step", 0))
    except (ValueError, OSError):
        return None


def _owner_text(folder: Path) -> str:
    try:
        info = json.loads((folder / OWNER).read_text())
    except (OSError, json.JSONDecodeError):
        return "another process"
    if not alive(int(info.get("pid", -1))):
        return "another process"
    return (f"pid {info['pid']} on {info.get('host', '?')} (seed {info.get('seed')}, since "
            f"{info.get('started')})")


class RunFolder:
    """``with RunFolder(out, seed, resume=..., overwrite=...):`` train into ``out``.

    Raises:
        FolderBusyError: a live ``train`` holds the folder (named in the message).
        ValueError: the folder holds a run and neither ``resume`` nor ``overwrite`` is set,
            both are set, or ``out`` is not a folder.
    """

    def __init__(self, folder: str | Path, seed: int, resume: bool = False,
                 overwrite: bool = False) -> None:
        if resume and overwrite:
            raise ValueError("--resume continues the run in --out, --overwrite starts afresh "
                             "there: give one of them")
        self.folder, self.seed = Path(folder), seed
        self.resume, self.overwrite = resume, overwrite
        self._lock = None

    def __enter__(self) -> RunFolder:
        if self.folder.exists() and not self.folder.is_dir():
            raise ValueError(f"{self.folder}: exists and is not a folder (--out names the "
                             "folder the run writes)")
        self.folder.mkdir(parents=True, exist_ok=True)
        f = open(self.folder / LOCK, "a+")  # noqa: SIM115 (held until release)
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.close()
            raise FolderBusyError(f"{self.folder}: another train is writing to this folder: "
                                  f"{_owner_text(self.folder)}; wait for it or use another "
                                  "--out") from None
        self._lock = f
        try:
            self._claim()
        except BaseException:
            self.release()
            raise
        return self

    def _claim(self) -> None:
        found = run_files(self.folder)
        if found and not self.resume:
            if not self.overwrite:
                raise ValueError(f"{self.folder}: holds a run ({describe_run(self.folder, found)}"
                                 "); give --resume to continue it, --overwrite to start afresh "
                                 "in its place, or another --out")
            for p in found:
                shutil.rmtree(p) if p.is_dir() else p.unlink()
        tmp = self.folder / f"{OWNER}.tmp-{os.getpid()}"
        tmp.write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                                   "seed": self.seed,
                                   "started": time.strftime("%Y-%m-%d %H:%M:%S")}))
        os.replace(tmp, self.folder / OWNER)

    def release(self) -> None:
        if self._lock is not None:
            (self.folder / OWNER).unlink(missing_ok=True)
            self._lock.close()
            self._lock = None

    def __exit__(self, *exc) -> None:
        self.release()
