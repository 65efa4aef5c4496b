"""Where commands write: the checks every output path passes before any work is done.

A command never deletes or overwrites a file it did not write. Folder outputs (frames,
previews, exports, metrics) go through :class:`OutputFolder`: the folder keeps a list of
the names its commands wrote (``.e2sr-outputs``, one ``fnmatch`` pattern a line, claimed
before the first write), and an existing file under one of this run's names is replaced
only when that list holds it; any other is a refusal that names it. A single output file
proves itself by its content (e.g. a preset's first line: :func:`check_output_file`). The
folder (or the file's folder) is created and proven writable first, so a read-only disk is
a clear error before any work, never a traceback halfway.
"""

from __future__ import annotations

import fnmatch
import os
import shutil
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Literal

from esim_lite.core.atomic import write_text

MANIFEST = ".e2sr-outputs"


def writable_folder(folder: str | Path, flag: str = "--out", keep: bool = True) -> Path:
    """``folder``, created if needed and proven writable (a probe file is written and
    removed); ``keep=False``: the folders created for the probe are removed again (a check
    before any work leaves nothing behind).

    Raises:
        ValueError: naming ``folder`` and why: a file is in the way, or it cannot be
            created or written (read-only disk, permissions, disk full).
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder}: exists and is not a folder ({flag} names a folder)")
    missing = [p for p in (folder, *folder.parents) if not p.exists()]
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
        for made in [] if keep else missing:
            made.rmdir()
    except OSError as exc:
        raise ValueError(f"{folder}: output folder is not writable "
                         f"({exc.strerror or exc})") from exc
    return folder


def _same(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and a.samefile(b))
    except OSError:
        return False


def refuse_inputs(target: Path, inputs: Iterable[str | Path], flag: str = "--out") -> None:
    """Refuse ``target`` when it is one of the command's ``inputs`` (empty ones skipped).

    Raises:
        ValueError: naming the input that ``target`` would overwrite.
    """
    for given in inputs:
        source = Path(given)
        if str(given) and _same(target, source):
            raise ValueError(f"{target}: is an input of this command ({source}); {flag} "
                             f"must name another path")


def check_output_file(target: str | Path, inputs: Iterable[str | Path],
                      ours: Callable[[Path], bool], what: str, flag: str = "--out") -> Path:
    """A single output file: not an input, not a folder, and when it exists a file this
    command wrote (``ours(path)``); its folder is created and proven writable.

    Raises:
        ValueError: naming ``target`` and the problem.
    """
    target = Path(target)
    refuse_inputs(target, inputs, flag)
    if target.is_dir():
        raise ValueError(f"{target}: is a folder; {flag} names the {what} file to write")
    if target.exists() and not ours(target):
        raise ValueError(f"{target}: exists and is not a {what} this command wrote; it is "
                         f"left as it is: remove it or give another {flag}")
    writable_folder(target.parent, flag)
    return target


class OutputFolder:
    """A command's output folder: :meth:`prepare` before any work, then write.

    Args:
        folder: the folder (created by :meth:`prepare`).
        names: the ``fnmatch`` patterns of everything this run writes there.
        inputs: the command's input paths, never to be written over.
        flag: the option that named the folder, for messages.
    """

    def __init__(self, folder: str | Path, names: Sequence[str],
                 inputs: Iterable[str | Path] = (), flag: str = "--out") -> None:
        self.folder, self.names, self.flag = Path(folder), tuple(names), flag
        self.inputs = [Path(p) for p in inputs if str(p)]

    def written(self) -> set[str]:
        """The patterns the folder's list holds (empty without a list)."""
        try:
            return {line for line in (self.folder / MANIFEST).read_text().splitlines()
                    if line}
        except (OSError, UnicodeDecodeError):
            return set()

    def existing(self) -> list[tuple[Path, str]]:
        """(path, pattern) of every entry in the folder under one of this run's names."""
        if not self.folder.is_dir():
            return []
        return [(p, pat) for p in sorted(self.folder.iterdir()) for pat in self.names
                if fnmatch.fnmatchcase(p.name, pat)]

    def prepare(self, earlier: Literal["replace", "remove", "refuse"] = "replace",
                what: str = "outputs") -> OutputFolder:
        """Check the folder before any work (it is created and proven writable); then
        :meth:`claim` it just before the first write.

        An existing entry under this run's names must be one the folder's list says a
        command wrote, and not an input. ``earlier``: what becomes of such entries:
        ``replace``d as this run writes the same names, ``remove``d here (``--overwrite``)
        or ``refuse``d (a run that would leave an earlier run's ``what`` beside its own).

        Raises:
            ValueError: naming the entry or the folder and the problem.
        """
        writable_folder(self.folder, self.flag, keep=False)
        ours, found = self.written(), self.existing()
        for path, pattern in found:
            refuse_inputs(path, self.inputs, self.flag)
            if pattern not in ours:
                raise ValueError(f"{path}: exists and was not written by e2sr here; it is "
                                 f"left as it is: remove it or give another {self.flag}")
        if found and earlier == "refuse":
            raise ValueError(f"{self.folder}: holds the {what} of an earlier run "
                             f"({len(found)} file(s), e.g. {found[0][0].name}); "
                             f"--overwrite replaces them, or give another {self.flag}")
        if found and earlier == "remove":
            for path, _ in found:
                shutil.rmtree(path) if path.is_dir() else path.unlink()
        return self

    def claim(self) -> Path:
        """Record this run's names in the folder's list (before its first write: a run
        killed halfway leaves files the next run may replace); return the folder."""
        self.folder.mkdir(parents=True, exist_ok=True)
        ours = self.written()
        if not set(self.names) <= ours:
            write_text(self.folder / MANIFEST,
                       "".join(f"{n}\n" for n in sorted(ours | set(self.names))))
        return self.folder


def claim(out: str | Path | OutputFolder) -> Path:
    """The folder to write into: an :class:`OutputFolder` claimed, or a plain path
    created (a library caller's own folder)."""
    if isinstance(out, OutputFolder):
        return out.claim()
    Path(out).mkdir(parents=True, exist_ok=True)
    return Path(out)
