"""Dataset generation: schema round trip, determinism, resumption, interruption, errors."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from datagen import generate as gen
from datagen.cli import main
from datagen.config import DatagenConfig
from datagen.sampling import sample_sequence
from datagen.shard import ShardReader, frame_dtype
from datagen.textures import TextureSampler
from esim_lite.core.dataconf import load_config, load_yaml
from esim_lite.sequence import simulate_sequence

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "configs" / "datagen_tiny.yaml"


def tiny(**overrides) -> DatagenConfig:
    return load_config(DatagenConfig, TINY, [f"{k}={v}" for k, v in overrides.items()])


def read_all(folder: Path) -> dict[str, dict[str, np.ndarray]]:
    out = {}
    for path in sorted(folder.glob("shard_*.h5")):
        with ShardReader(path) as r:
            for name in r.sequences():
                rec = r.read(name)
                arrays = {"x": rec.events.x, "y": rec.events.y, "t": rec.events.t_ns,
                          "p": rec.events.p, "poses": rec.sample_poses,
                          "event_idx": rec.frame_event_idx}
                arrays.update({f"frame_{k}": v.intensity for k, v in rec.frames.items()})
                out[name] = arrays
    return out


def assert_same(a, b):
    assert a.keys() == b.keys()
    for name in a:
        for key in a[name]:
            np.testing.assert_array_equal(a[name][key], b[name][key], err_msg=f"{name}/{key}")


def test_default_config_file_matches_the_builtin_defaults():
    assert load_yaml(DatagenConfig, ROOT / "configs" / "datagen.yaml") == DatagenConfig()


def test_shard_round_trip_equals_the_simulation(tmp_path):
    cfg = tiny()
    summary = gen.generate(cfg, tmp_path, n_seq=1, seed=5, show_progress=False)
    assert summary.sequences == 1 and summary.events > 0
    spec = sample_sequence(cfg.simulation, TextureSampler(cfg.textures), 5, 0)
    seq = simulate_sequence(spec.scene, spec.trajectory, spec.thresholds, cfg.simulation,
                            spec.noise_rng)
    with ShardReader(tmp_path / "shard_00000.h5") as r:
        rec = r.read("seq_000000")
        for f in ("x", "y", "t_ns", "p"):  # float64 seconds give back every nanosecond
            np.testing.assert_array_equal(getattr(rec.events, f), getattr(seq.events, f))
        assert rec.events.sensor_hw == (48, 64)
        np.testing.assert_array_equal(rec.frames["lr"].t_ns, seq.frames["lr"].t_ns)
        np.testing.assert_array_equal(
            rec.frame_event_idx, np.searchsorted(seq.events.t_ns, seq.frames["lr"].t_ns, "right"))
        # stored frames recover log(eps + I) to 1% of the smallest threshold
        eps = cfg.simulation.events.log_eps
        for cam in ("lr", "hr_x2"):
            err = np.abs(np.log(eps + rec.frames[cam].intensity)
                         - np.log(eps + seq.frames[cam].intensity)).max()
            assert err <= 0.01 * rec.thresholds.min_threshold
        assert rec.cameras["hr_x2"].width == 128 and rec.cameras["lr"].height == 48
        assert r.num_samples("seq_000000") == len(seq.sample_poses) == len(rec.sample_poses)
        assert rec.thresholds.pos == pytest.approx(seq.thresholds.pos)
        assert "simulation:" in r.config_yaml and r.schema_version == 1
    with h5py.File(tmp_path / "shard_00000.h5", "r") as f:  # the layout as others read it
        g = f["seq_000000"]
        assert list(g.attrs["sensor_resolution"]) == [48, 64]
        assert set(np.unique(g["events/ps"][:])) <= {0, 1}
        assert g["events/ts"].dtype == np.float64 and g["events/xs"].dtype == np.int16


def test_frame_dtype_follows_the_precision_rule():
    assert frame_dtype(0.12) == np.float16
    assert frame_dtype(0.02) == np.float32  # float16 rounding would exceed 1% of 0.02


def test_same_data_whatever_the_workers_or_job_split(tmp_path):
    cfg = tiny()
    gen.generate(cfg, tmp_path / "one", n_seq=4, seed=3, workers=1, show_progress=False)
    gen.generate(cfg, tmp_path / "two", n_seq=4, seed=3, workers=2, show_progress=False)
    for i in range(2):  # a two-job array writing into one folder
        gen.generate(cfg, tmp_path / "split", n_seq=4, seed=3, shard_index=i, num_shards=2,
                     show_progress=False)
    one = read_all(tmp_path / "one")
    assert len(one) == 4
    assert_same(one, read_all(tmp_path / "two"))
    assert_same(one, read_all(tmp_path / "split"))
    other = read_all(Path(gen.generate(cfg, tmp_path / "seed4", n_seq=1, seed=4,
                                       show_progress=False) and tmp_path / "seed4"))
    assert not np.array_equal(other["seq_000000"]["t"][:50], one["seq_000000"]["t"][:50])


@pytest.mark.slow
def test_mitsuba_data_is_the_same_whatever_the_workers_or_render_threads(tmp_path):
    """The default renderer too: one worker, two workers (each forcing one render thread)
    and an explicit single render thread write the same bytes."""
    cfg = tiny(**{"simulation.render.backend": "mitsuba",
                  "simulation.camera.width": 128, "simulation.camera.height": 96,
                  "simulation.frames.count": 3})
    gen.generate(cfg, tmp_path / "one", n_seq=4, seed=3, workers=1, show_progress=False)
    gen.generate(cfg, tmp_path / "two", n_seq=4, seed=3, workers=2, show_progress=False)
    one = read_all(tmp_path / "one")
    assert_same(one, read_all(tmp_path / "two"))
    single = tiny(**{"simulation.render.backend": "mitsuba", "simulation.render.threads": 1,
                     "simulation.camera.width": 128, "simulation.camera.height": 96,
                     "simulation.frames.count": 3})
    gen.generate(single, tmp_path / "t1", n_seq=4, seed=3, workers=1, show_progress=False)
    t1 = read_all(tmp_path / "t1")
    for name in one:  # the stored configs differ (threads), the data must not
        for key in one[name]:
            np.testing.assert_array_equal(one[name][key], t1[name][key], err_msg=key)


def test_rerun_skips_complete_shards_and_redoes_broken_ones(tmp_path):
    cfg = tiny()
    gen.generate(cfg, tmp_path, n_seq=6, seed=1, show_progress=False)
    reference = read_all(tmp_path)
    again = gen.generate(cfg, tmp_path, n_seq=6, seed=1, show_progress=False)
    assert (again.shards_written, again.shards_skipped) == (0, 3)
    # a shard truncated on disk, a leftover temporary file, a missing shard
    (tmp_path / "shard_00001.h5").write_bytes(b"\x89HDF garbage")
    (tmp_path / "shard_00000.h5.tmp-12345").write_bytes(b"partial")
    (tmp_path / "shard_00002.h5").unlink()
    # a file datagen cannot prove it wrote is never removed: refused, named, left as it is
    with pytest.raises(ValueError, match="shard_00001.h5: is in the way of a shard"):
        gen.generate(cfg, tmp_path, n_seq=6, seed=1, show_progress=False)
    assert (tmp_path / "shard_00001.h5").read_bytes() == b"\x89HDF garbage"
    (tmp_path / "shard_00001.h5").unlink()
    again = gen.generate(cfg, tmp_path, n_seq=6, seed=1, show_progress=False)
    assert (again.shards_written, again.shards_skipped) == (2, 1)
    assert not list(tmp_path.glob("*.tmp-*"))
    assert_same(reference, read_all(tmp_path))


def test_a_different_config_does_not_overwrite_an_existing_dataset(tmp_path):
    gen.generate(tiny(), tmp_path, n_seq=2, seed=1, show_progress=False)
    with pytest.raises(ValueError, match="different config or seed"):
        gen.generate(tiny(), tmp_path, n_seq=2, seed=2, show_progress=False)


@pytest.mark.slow
def test_kill_9_leaves_no_complete_looking_half_shard(tmp_path):
    out = tmp_path / "shards"
    cmd = [sys.executable, "-m", "datagen.cli", "generate", "--config", str(TINY),
           "--n-seq", "8", "--out", str(out), "--workers", "1", "--seed", "9",
           "--no-progress", "--set", "simulation.frames.count=40",
           "--set", "simulation.duration_s=3.0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while time.time() < deadline and not list(out.glob("shard_00001.h5.tmp-*")):
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert list(out.glob("*.tmp-*")), "the run was killed while writing shard 1"
    for path in out.glob("shard_*.h5"):  # whatever has a final name is a finished shard
        with ShardReader(path) as r:
            assert len(r.sequences()) == 2
    assert subprocess.run(cmd).returncode == 0
    resumed = read_all(out)
    cfg = load_config(DatagenConfig, TINY, ["simulation.frames.count=40",
                                            "simulation.duration_s=3.0"])
    gen.generate(cfg, tmp_path / "clean", n_seq=8, seed=9, show_progress=False)
    assert_same(resumed, read_all(tmp_path / "clean"))
    assert not list(out.glob("*.tmp-*"))


def test_cli_errors_name_the_problem(tmp_path, capsys):
    args = ["generate", "--config", str(TINY), "--n-seq", "1", "--no-progress"]
    assert main(args + ["--out", str(tmp_path / "a"), "--set", "simulation.camera.widht=3"]) == 2
    assert "simulation.camera.widht: unknown key" in capsys.readouterr().err
    assert main(args + ["--out", str(tmp_path / "a"), "--set", "sequences_per_shard=0"]) == 2
    assert "sequences_per_shard must be >= 1" in capsys.readouterr().err
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(args + ["--out", str(blocker / "sub")]) == 2
    assert f"{blocker / 'sub'}: output folder is not writable" in capsys.readouterr().err
    assert main(args + ["--out", str(tmp_path / "b"), "--textures", str(tmp_path / "nope")]) == 2
    assert f"{tmp_path / 'nope'}: texture path does not exist" in capsys.readouterr().err
    assert main(args + ["--out", str(tmp_path / "c"), "--scale", "3"]) == 2
    assert "--scale must be 2, 4, 8 or several" in capsys.readouterr().err
    assert main(["inspect", str(tmp_path / "missing.h5")]) == 2
    assert "missing.h5: no such file" in capsys.readouterr().err
    assert main(args + ["--out", str(tmp_path / "d"), "--workers", "0"]) == 2
    assert "--workers must be at least 1, got 0" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_full_disk_is_reported_and_leaves_nothing_behind(tmp_path, monkeypatch):
    def full(self, events):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("datagen.shard.ShardWriter.append_events", full)
    with pytest.raises(gen.DiskFullError, match="disk full while writing"):
        gen.generate(tiny(), tmp_path, n_seq=1, show_progress=False)
    # no data file at all; only the writer lock's bookkeeping folder
    assert [p.name for p in tmp_path.iterdir()] == [".datagen"]


def test_reader_rejects_incomplete_and_foreign_files(tmp_path):
    path = tmp_path / "x.h5"
    with h5py.File(path, "w") as f:
        f.attrs["schema_version"] = 1
        f.attrs["complete"] = False
    with pytest.raises(ValueError, match="x.h5: incomplete shard"):
        ShardReader(path)
    with h5py.File(path, "w") as f:
        f.create_dataset("a", data=[1])
    with pytest.raises(ValueError, match="x.h5: not an e2sr shard"):
        ShardReader(path)
    path.write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match="x.h5: not a readable HDF5 file"):
        ShardReader(path)


def test_inspect_and_preview(tmp_path, capsys):
    gen.generate(tiny(), tmp_path, n_seq=2, seed=0, show_progress=False)
    assert main(["inspect", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "2 sequence(s)" in text and "seq_000001" in text and "events" in text
    assert main(["preview", str(tmp_path), "--out", str(tmp_path / "png")]) == 0
    pngs = sorted((tmp_path / "png").glob("*.png"))
    assert len(pngs) == 2
    from PIL import Image

    img = np.asarray(Image.open(pngs[0]))
    assert img.ndim == 3 and img.shape[0] > 100 and img.std() > 10


def test_preview_of_a_sequence_with_only_its_first_frame(tmp_path):
    """A static camera watching little motion can end before its events fill one frame
    interval: the shard holds frame 0 only, and its preview shows that frame and the events
    before it instead of failing on an empty sheet."""
    gen.generate(tiny(**{"simulation.frames.every_events": 10 ** 9}), tmp_path, n_seq=1,
                 seed=0, show_progress=False)
    with ShardReader(tmp_path / "shard_00000.h5") as r:
        assert len(r.frame_times_ns("seq_000000")) == 1
    assert main(["preview", str(tmp_path), "--out", str(tmp_path / "png")]) == 0
    from PIL import Image

    img = np.asarray(Image.open(tmp_path / "png" / "shard_00000_seq_000000.png"))
    assert img.ndim == 3 and img.shape[0] > 48 and img.std() > 10


def test_shards_record_the_library_versions_and_inspect_shows_them(tmp_path, capsys):
    """Bytes are reproducible per software stack only, so each shard names its stack;
    a shard from before that still reads and inspects."""
    import importlib.metadata as md
    import json
    import shutil

    import cv2

    gen.generate(tiny(), tmp_path, n_seq=1, seed=0, show_progress=False)
    path = tmp_path / "shard_00000.h5"
    running = {"numpy": np.__version__, "opencv": cv2.__version__,
               "mitsuba": md.version("mitsuba"), "drjit": md.version("drjit"),
               "numba": md.version("numba"), "h5py": h5py.__version__,
               "hdf5": h5py.version.hdf5_version, "e2sr": md.version("e2sr")}
    with h5py.File(path, "r") as f:
        assert json.loads(f.attrs["versions"]) == running
    with ShardReader(path) as r:
        assert r.versions == running
    assert main(["inspect", str(path)]) == 0
    text = capsys.readouterr().out
    assert "versions: " + ", ".join(f"{k} {v}" for k, v in running.items()) in text
    old = tmp_path / "old" / "shard_00000.h5"
    old.parent.mkdir()
    shutil.copy(path, old)
    with h5py.File(old, "a") as f:
        del f.attrs["versions"]
    with ShardReader(old) as r:
        assert r.versions is None and len(r.read("seq_000000").events) > 0
    assert main(["inspect", str(old)]) == 0
    assert "versions: not recorded" in capsys.readouterr().out


def test_recording_versions_leaves_mitsuba_unimported():
    """Version lookup must not import Mitsuba (which would also be the moment a variant
    gets chosen): a fresh interpreter, so no other test has imported it first."""
    code = ("import sys; from datagen.shard import library_versions; library_versions(); "
            "print('mitsuba' in sys.modules, 'drjit' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    assert out.split() == ["False", "False"]


def test_worker_count_is_not_part_of_the_dataset_identity(tmp_path):
    """A dataset started with one --workers value resumes with another."""
    gen.generate(tiny(), tmp_path, n_seq=4, seed=2, workers=2, show_progress=False)
    (tmp_path / "shard_00001.h5").unlink()
    again = gen.generate(tiny(), tmp_path, n_seq=4, seed=2, workers=1, show_progress=False)
    assert (again.shards_written, again.shards_skipped) == (1, 1)


def _hold_lock(folder: Path, seed: int, job: tuple[int, int] = (0, 1)) -> subprocess.Popen:
    """A second live process holding the folder's writer lock (as a running datagen does)."""
    code = ("import sys, time; from datagen.lock import FolderLock\n"
            f"with FolderLock({str(folder)!r}, {seed}, 'cfg', {job[0]}, {job[1]}):\n"
            "    print('held', flush=True); time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                            cwd=ROOT)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_writer_is_refused_and_a_killed_one_leaves_no_stuck_lock(tmp_path, capsys):
    out = tmp_path / "ds"
    other = _hold_lock(out, seed=5)
    try:
        args = ["generate", "--config", str(TINY), "--n-seq", "2", "--no-progress",
                "--workers", "1", "--out", str(out)]
        assert main(args) == 2
        err = capsys.readouterr().err
        assert f"{out}: another datagen is writing to this folder: pid {other.pid}" in err
        assert "Traceback" not in err and not list(out.glob("shard_*"))
    finally:
        other.send_signal(signal.SIGKILL)
        other.wait()
    assert main(args) == 0  # the kernel dropped the dead process's lock
    assert len(list(out.glob("shard_*.h5"))) == 1


def test_array_jobs_share_a_folder_only_within_one_dataset(tmp_path, capsys):
    other = _hold_lock(tmp_path, seed=5, job=(0, 2))  # job 0 of 2 is running, no shard yet
    try:
        args = ["generate", "--config", str(TINY), "--n-seq", "4", "--no-progress",
                "--workers", "1", "--out", str(tmp_path), "--num-shards", "2"]
        assert main(args + ["--shard-index", "0", "--seed", "5"]) == 2  # the same job
        assert "another datagen is writing" in capsys.readouterr().err
        assert main(args + ["--shard-index", "1", "--seed", "6"]) == 2  # another dataset
        assert "holds the dataset of seed 5" in capsys.readouterr().err
        assert main(["generate", "--config", str(TINY), "--n-seq", "4", "--no-progress",
                     "--out", str(tmp_path)]) == 2  # a plain run waits for the array
        assert "another datagen is writing" in capsys.readouterr().err
    finally:
        other.kill()
        other.wait()
    assert not list(tmp_path.glob("shard_*"))


def test_a_folder_holds_one_dataset(tmp_path, capsys):
    args = ["generate", "--config", str(TINY), "--no-progress", "--workers", "1",
            "--out", str(tmp_path)]
    assert main(args + ["--n-seq", "2", "--seed", "5"]) == 0
    # different shards (3rd sequence: shard 1) of another seed: refused, not mixed in
    assert main(args + ["--n-seq", "4", "--seed", "6"]) == 2
    assert "holds the dataset of seed 5" in capsys.readouterr().err
    assert len(list(tmp_path.glob("shard_*.h5"))) == 1
    assert main(args + ["--n-seq", "4", "--seed", "5"]) == 0  # growing it is fine
    assert len(list(tmp_path.glob("shard_*.h5"))) == 2


def test_only_dead_processes_temporary_files_are_removed(tmp_path):
    from datagen.lock import stale_temporary

    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    try:
        live = tmp_path / f"shard_00000.h5.tmp-{sleeper.pid}"
        gone = tmp_path / f"shard_00000.h5.tmp-{dead.pid}"
        assert not stale_temporary(live) and stale_temporary(gone)
        live.write_bytes(b"being written")
        gone.write_bytes(b"left behind")
        gen.generate(tiny(), tmp_path, n_seq=1, show_progress=False)
        assert live.is_file() and not gone.exists()
    finally:
        sleeper.kill()
        sleeper.wait()


SLURM_VARS = ("SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT", "SLURM_ARRAY_TASK_MIN",
              "SLURM_ARRAY_TASK_MAX")


def test_slurm_array_tasks_split_one_dataset_with_auto(tmp_path, monkeypatch):
    """``--shard-index auto --num-shards auto`` in an array ``--array=1-2``: each task
    writes its own shards into the shared folder, together exactly the plain run's dataset."""
    for name in SLURM_VARS:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("SLURM_ARRAY_TASK_COUNT", "2")
    monkeypatch.setenv("SLURM_ARRAY_TASK_MIN", "1")
    monkeypatch.setenv("SLURM_ARRAY_TASK_MAX", "2")
    out = tmp_path / "array"
    args = ["generate", "--config", str(TINY), "--n-seq", "6", "--seed", "3", "--workers",
            "1", "--no-progress", "--out", str(out), "--shard-index", "auto",
            "--num-shards", "auto"]
    per_task = {}
    for task in (1, 2):
        monkeypatch.setenv("SLURM_ARRAY_TASK_ID", str(task))
        before = set(out.glob("shard_*.h5"))
        assert main(args) == 0
        per_task[task] = {}
        for path in set(out.glob("shard_*.h5")) - before:
            with ShardReader(path) as r:
                per_task[task][path.name] = set(r.sequences())
    # 6 sequences, 2 per shard: task 1 (index 0) writes shards 0 and 2, task 2 shard 1
    assert sorted(per_task[1]) == ["shard_00000.h5", "shard_00002.h5"]
    assert sorted(per_task[2]) == ["shard_00001.h5"]
    seqs = [set().union(*per_task[t].values()) for t in (1, 2)]
    assert not seqs[0] & seqs[1]
    assert seqs[0] | seqs[1] == {f"seq_{i:06d}" for i in range(6)}
    gen.generate(tiny(), tmp_path / "plain", n_seq=6, seed=3, show_progress=False)
    assert_same(read_all(tmp_path / "plain"), read_all(out))


@pytest.mark.parametrize("env, expected", [
    ({"SLURM_ARRAY_TASK_ID": "5", "SLURM_ARRAY_TASK_COUNT": "8"}, (5, 8)),
    ({"SLURM_ARRAY_TASK_ID": "0", "SLURM_ARRAY_TASK_COUNT": "8", "SLURM_ARRAY_TASK_MIN": "0",
      "SLURM_ARRAY_TASK_MAX": "7"}, (0, 8)),
    ({"SLURM_ARRAY_TASK_ID": "8", "SLURM_ARRAY_TASK_COUNT": "8", "SLURM_ARRAY_TASK_MIN": "1",
      "SLURM_ARRAY_TASK_MAX": "8"}, (7, 8)),
])
def test_auto_shard_index_and_count_come_from_the_array(env, expected):
    from datagen.cli import array_job

    assert array_job("auto", "auto", env) == expected
    assert array_job("auto", 8, env) == expected  # a number is taken as it is
    assert array_job(2, "auto", env) == (2, 8)
    assert array_job(2, 3, {}) == (2, 3)  # no auto: the environment is not read


@pytest.mark.parametrize("env, flags, message", [
    ({"SLURM_ARRAY_TASK_COUNT": "2"}, ["--shard-index", "auto", "--num-shards", "auto"],
     "--shard-index auto reads SLURM_ARRAY_TASK_ID, which is not set"),
    ({"SLURM_ARRAY_TASK_ID": "0"}, ["--shard-index", "auto", "--num-shards", "auto"],
     "--num-shards auto reads SLURM_ARRAY_TASK_COUNT, which is not set"),
    ({"SLURM_ARRAY_TASK_ID": "0", "SLURM_ARRAY_TASK_COUNT": "two"}, ["--num-shards", "auto"],
     "--num-shards auto reads SLURM_ARRAY_TASK_COUNT, which is 'two', not an integer"),
    ({"SLURM_ARRAY_TASK_ID": "x1", "SLURM_ARRAY_TASK_COUNT": "2"}, ["--shard-index", "auto",
                                                                     "--num-shards", "2"],
     "--shard-index auto reads SLURM_ARRAY_TASK_ID, which is 'x1', not an integer"),
    ({"SLURM_ARRAY_TASK_ID": "3", "SLURM_ARRAY_TASK_COUNT": "4", "SLURM_ARRAY_TASK_MIN": "1",
      "SLURM_ARRAY_TASK_MAX": "7"}, ["--shard-index", "auto", "--num-shards", "auto"],
     "the job array 1-7 (SLURM_ARRAY_TASK_MIN, SLURM_ARRAY_TASK_MAX) has 4 tasks"),
    ({"SLURM_ARRAY_TASK_ID": "4"}, ["--shard-index", "auto", "--num-shards", "4"],
     "SLURM_ARRAY_TASK_ID 4 minus SLURM_ARRAY_TASK_MIN 0 is 4, outside [0, 4)"),
])
def test_auto_without_a_usable_array_variable_is_a_named_error(tmp_path, monkeypatch, capsys,
                                                                env, flags, message):
    for name in SLURM_VARS:
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    out = tmp_path / "ds"
    assert main(["generate", "--config", str(TINY), "--n-seq", "2", "--no-progress",
                 "--out", str(out)] + flags) == 2
    err = capsys.readouterr().err
    assert err.startswith("datagen: error: ") and message in err and "Traceback" not in err
    assert not out.exists()  # refused before anything is written


def test_shard_index_is_a_number_or_auto(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["generate", "--n-seq", "2", "--out", "x", "--shard-index", "first"])
    assert exc.value.code == 2
    assert "expected an integer or 'auto', got 'first'" in capsys.readouterr().err


def _children(pid: int) -> set[int]:
    """Direct children of ``pid`` (from /proc: Linux)."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.add(int(stat.parent.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
def test_workers_exit_when_datagen_is_killed(tmp_path):
    """SIGKILL runs no cleanup in the parent: its workers (and the progress queue's
    server) must notice on their own and stop, not render on into orphaned temp files."""
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "d"
    proc = subprocess.Popen([sys.executable, "-m", "datagen.cli", "generate", "--n-seq", "16",
                             "--out", str(out), "--workers", "2", "--no-progress"],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while len(_children(proc.pid)) < 4 and time.monotonic() < deadline:  # tracker,
            time.sleep(0.2)                                  # manager and two workers
        kids = _children(proc.pid)
        assert len(kids) >= 4, "datagen did not start its workers"
        time.sleep(2)  # the workers are rendering now
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    deadline = time.monotonic() + 15
    while any(_alive(k) for k in kids) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not [k for k in kids if _alive(k)]
