"""scripts/link_shards.sh: one training folder of links over several datasets."""

from __future__ import annotations

import subprocess
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "link_shards.sh"


def run(*args) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), *map(str, args)], capture_output=True,
                          text=True)


def test_links_every_shard_under_a_unique_name_and_keeps_the_cache(tmp_path):
    for name, n in (("plane", 2), ("dyn", 1)):
        (tmp_path / name).mkdir()
        for i in range(n):
            (tmp_path / name / f"shard_{i:05d}.h5").write_text(f"{name}{i}")
    out = tmp_path / "mix"
    (out / "cache").mkdir(parents=True)
    (out / "shard_stale_00000.h5").symlink_to(tmp_path / "plane" / "shard_00000.h5")
    done = run(out, tmp_path / "plane", tmp_path / "dyn")
    assert done.returncode == 0, done.stderr
    links = sorted(p.name for p in out.glob("shard_*.h5"))
    assert links == ["shard_dyn_00000.h5", "shard_plane_00000.h5", "shard_plane_00001.h5"]
    assert (out / "shard_dyn_00000.h5").read_text() == "dyn0"   # links to the real files
    assert (out / "cache").is_dir()                               # train's cache survives


def test_a_folder_without_shards_is_refused_and_nothing_changes(tmp_path):
    (tmp_path / "empty").mkdir()
    done = run(tmp_path / "mix", tmp_path / "empty")
    assert done.returncode == 2 and "empty: no shard_*.h5 files" in done.stderr
    assert not (tmp_path / "mix").exists()
