"""Atomic file writes: the one helper every stage uses (temporary name, then rename).

``with atomic_path(target) as tmp:`` hands out a temporary path in the target's folder;
when the block ends without an exception the file is renamed over ``target`` in one step
(readers see the old file or the new one, never half of one), with the permissions a new
file would get (``0666`` minus the umask, not ``mkstemp``'s ``0600``); on an exception the
temporary file is removed and ``target`` is untouched.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


def _default_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextmanager
def atomic_path(target: str | Path, suffix: str = ".tmp", *,
                unique: bool = True) -> Iterator[Path]:
    """A temporary path beside ``target``, renamed over it when the block succeeds.

    ``unique=False``: the temporary is exactly ``target.name + suffix`` and is not created
    beforehand; for writers that put their pid in ``suffix`` (``.tmp-<pid>``) so that a later
    run can tell a dead writer's leftover from a live writer's file.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    if unique:
        fd, tmp = tempfile.mkstemp(prefix=target.name + ".", suffix=suffix, dir=target.parent)
        os.close(fd)
    else:
        tmp = str(target.with_name(target.name + suffix))
    try:
        yield Path(tmp)
        os.chmod(tmp, _default_mode())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_bytes(target: str | Path, data: bytes) -> Path:
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)
    return Path(target)


def write_text(target: str | Path, text: str) -> Path:
    return write_bytes(target, text.encode())


@contextmanager
def atomic_folder(target: str | Path) -> Iterator[Path]:
    """``with atomic_folder(target) as tmp:`` fills a temporary folder beside ``target``;
    when the block ends it replaces ``target`` by a rename (an existing ``target`` is removed
    first); on an exception the temporary folder is removed and ``target`` is untouched."""
    import shutil

    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=target.name + ".", suffix=".tmp", dir=target.parent))
    try:
        yield tmp
        if target.exists():
            shutil.rmtree(target)
        tmp.rename(target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
