"""The Events record."""

from __future__ import annotations

import numpy as np
import pytest

from esim_lite.core.events import Events


def make(n=5, t=None, x=None):
    return Events(np.arange(n, dtype=np.int16) if x is None else x, np.zeros(n, np.int16),
                  np.arange(n, dtype=np.int64) if t is None else t, np.ones(n, np.int8), (4, 8))


def test_dtypes_and_lengths_are_checked():
    with pytest.raises(ValueError, match="int16"):
        Events(np.zeros(2, np.int32), np.zeros(2, np.int16), np.zeros(2, np.int64),
               np.ones(2, np.int8), (4, 4))
    with pytest.raises(ValueError, match="entries"):
        Events(np.zeros(3, np.int16), np.zeros(2, np.int16), np.zeros(2, np.int64),
               np.ones(2, np.int8), (4, 4))


def test_validate_names_the_source():
    with pytest.raises(ValueError, match="rec.h5: event coordinates outside"):
        make(2, x=np.array([0, 9], np.int16)).validate("rec.h5")
    with pytest.raises(ValueError, match="not sorted"):
        make(3, t=np.array([0, 2, 1], np.int64)).validate()


def test_concatenate_slice_and_counts():
    a, b = make(3), make(2)
    c = Events.concatenate([a, b])
    assert len(c) == 5 and c.slice(1, 3).x.tolist() == [1, 2]
    img = c.count_image()
    assert img.shape == (2, 4, 8) and img[0].sum() == 5 and img[1].sum() == 0
    assert len(Events.concatenate([], (4, 8))) == 0


def test_atomic_writes_replace_whole_files_or_nothing(tmp_path):
    import os

    from esim_lite.core.atomic import atomic_path, write_text

    target = tmp_path / "sub" / "out.txt"
    write_text(target, "first")
    assert target.read_text() == "first"
    assert oct(target.stat().st_mode & 0o777) == oct(0o666 & ~_umask())  # not mkstemp's 0600
    try:
        with atomic_path(target) as tmp:
            tmp.write_text("half of the seco")
            raise RuntimeError("killed mid-write")
    except RuntimeError:
        pass
    assert target.read_text() == "first" and sorted(os.listdir(target.parent)) == ["out.txt"]


def test_atomic_path_with_a_fixed_temporary_name(tmp_path):
    """``unique=False`` (datagen's ``shard_XXXXX.h5.tmp-<pid>``): the temporary is exactly
    the target's name plus the suffix, not made beforehand, renamed or removed like any."""
    import os

    from esim_lite.core.atomic import atomic_path

    target = tmp_path / "shard.h5"
    suffix = f".tmp-{os.getpid()}"
    with atomic_path(target, suffix, unique=False) as tmp:
        assert tmp == tmp_path / f"shard.h5{suffix}" and not tmp.exists()
        tmp.write_text("whole")
    assert target.read_text() == "whole" and sorted(os.listdir(tmp_path)) == ["shard.h5"]
    assert oct(target.stat().st_mode & 0o777) == oct(0o666 & ~_umask())
    with pytest.raises(RuntimeError), atomic_path(target, suffix, unique=False) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed mid-write")
    assert target.read_text() == "whole" and sorted(os.listdir(tmp_path)) == ["shard.h5"]


def _umask() -> int:
    import os

    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_atomic_folders_replace_whole_folders_or_nothing(tmp_path):
    import pytest

    from esim_lite.core.atomic import atomic_folder

    target = tmp_path / "out"
    with atomic_folder(target) as tmp:
        (tmp / "a.txt").write_text("1")
    assert (target / "a.txt").read_text() == "1"
    with pytest.raises(RuntimeError), atomic_folder(target) as tmp:
        (tmp / "b.txt").write_text("2")
        raise RuntimeError("interrupted")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no temporary left
    assert sorted(p.name for p in target.iterdir()) == ["a.txt"]  # the old folder intact


def test_the_trusted_constructor_builds_the_same_record():
    a = make(4)
    b = Events.trusted(a.x, a.y, a.t_ns, a.p, (4, 8))
    assert isinstance(b, Events) and b.sensor_hw == a.sensor_hw and len(b) == 4
    for name in ("x", "y", "t_ns", "p"):
        assert getattr(b, name) is getattr(a, name)
    with pytest.raises(AttributeError):  # still frozen
        b.x = a.y
