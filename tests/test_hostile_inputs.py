"""Hostile inputs across every command (issue 53): nothing a user owns is lost, a small
input cannot take the machine's memory, and every refusal is a message, not a traceback.

The memory cases run the command in a subprocess under an address-space cap
(``RLIMIT_AS``) a normal run of the same command stays well below (measured: reconstruct
about 2 GiB of address space with torch loaded, calibrate and the texture reader under
1 GiB), far below what the hostile input made the command take before (6 to 9 GB).
"""

from __future__ import annotations

import errno
import logging
import os
import pathlib
import resource
import shutil
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from datagen.cli import main as datagen_main
from esim_lite.core.dataconf import ConfigError, load_config, load_yaml_text
from model.cli import evaluate_main, export_main, reconstruct_main
from model.cli import main as train_main

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "configs" / "datagen_tiny.yaml"
GIB = 1 << 30


def run_capped(module: str, func: str, args: list[str], cap_gib: float,
               timeout: float = 240) -> subprocess.CompletedProcess:
    """``module.func(args)`` in a fresh interpreter whose address space is capped."""
    cap = int(cap_gib * GIB)

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

    code = f"import sys; from {module} import {func}; sys.exit({func}(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], preexec_fn=limit,
                          capture_output=True, text=True, timeout=timeout, cwd=ROOT)


def refused(proc_or_rc, err: str, *words: str) -> None:
    """A clear refusal: exit status 2, every word in the message, no traceback."""
    rc = getattr(proc_or_rc, "returncode", proc_or_rc)
    assert rc == 2, err[-2000:]
    assert "Traceback" not in err, err[-2000:]
    for w in words:
        assert w in err, (w, err[-2000:])


def ecd_folder(folder: Path, n: int = 3000, hw: tuple[int, int] = (30, 40)) -> Path:
    """A small Event Camera Dataset folder: events.txt with ``n`` events over 0.3 s."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    t = np.sort(rng.integers(0, 300_000, n)) * 1e-6
    rows = [f"{a:.6f} {b} {c} {d}\n" for a, b, c, d in zip(
        t, rng.integers(0, hw[1], n), rng.integers(0, hw[0], n), rng.integers(0, 2, n))]
    (folder / "events.txt").write_text("".join(rows))
    return folder


# ---------------------------------------------------------------- data loss


def test_calibrate_never_writes_over_a_recording_or_a_file_it_did_not_write(tmp_path, capsys):
    rec = ecd_folder(tmp_path / "rec") / "events.txt"
    before = rec.read_bytes()
    other = tmp_path / "notes.yaml"
    other.write_text("my own notes\n")
    for out in (rec, other):
        refused(datagen_main(["calibrate", str(rec), "--out", str(out)]),
                capsys.readouterr().err, str(out.name))
    assert rec.read_bytes() == before and other.read_text() == "my own notes\n"
    preset = tmp_path / "preset.yaml"
    assert datagen_main(["calibrate", str(rec), "--out", str(preset)]) == 0
    assert datagen_main(["calibrate", str(rec), "--out", str(preset)]) == 0  # its own: redone


def users_shard(tmp_path, content: str):
    """An output folder holding a user's file at the first shard's name (HDF5 or text):
    (the folder, the file)."""
    out = tmp_path / "d"
    out.mkdir()
    mine = out / "shard_00000.h5"
    if content == "hdf5":
        with h5py.File(mine, "w") as f:
            f.create_dataset("precious", data=np.arange(5))
    else:
        mine.write_text("precious")
    return out, mine


@pytest.mark.parametrize("content", ["hdf5", "text"])
def test_generate_never_removes_a_file_it_cannot_prove_it_wrote(tmp_path, capsys, content):
    out, mine = users_shard(tmp_path, content)
    before = mine.read_bytes()
    rc = datagen_main(["generate", "--config", str(TINY), "--n-seq", "1", "--out", str(out),
                       "--workers", "1", "--no-progress"])
    refused(rc, capsys.readouterr().err, "shard_00000.h5", "not one datagen wrote")
    assert mine.read_bytes() == before


def test_generate_removes_its_own_unfinished_shard(tmp_path):
    from datagen.shard import ShardWriter

    out = tmp_path / "d"
    out.mkdir()
    ShardWriter(out / "shard_00000.h5", "config: x\n", 0, [0]).close()  # ours, unfinished
    assert datagen_main(["generate", "--config", str(TINY), "--n-seq", "1", "--out", str(out),
                         "--workers", "1", "--no-progress"]) == 0
    with h5py.File(out / "shard_00000.h5", "r") as f:
        assert bool(f.attrs["complete"])


def test_export_and_preview_never_write_over_a_users_file(tiny_shards, tmp_path, capsys):
    shard = sorted(tiny_shards.glob("shard_*.h5"))[0]
    out = tmp_path / "e"
    out.mkdir()
    theirs = out / f"{shard.stem}_seq_000000"
    theirs.mkdir()
    (theirs / "keep.txt").write_text("mine")
    refused(datagen_main(["export", str(shard), "--format", "txt", "--out", str(out)]),
            capsys.readouterr().err, theirs.name, "not written by e2sr")
    assert (theirs / "keep.txt").read_text() == "mine"
    png = tmp_path / "p" / f"{shard.stem}_seq_000000.png"
    png.parent.mkdir()
    png.write_bytes(b"my picture")
    refused(datagen_main(["preview", str(shard), "--out", str(png.parent)]),
            capsys.readouterr().err, png.name)
    assert png.read_bytes() == b"my picture"
    fresh = tmp_path / "e2"  # a folder of its own is written, and rewritten
    for _ in range(2):
        assert datagen_main(["export", str(shard), "--format", "txt", "--out", str(fresh)]) == 0


def test_reconstruct_refuses_a_folder_of_older_frames_unless_overwrite(tmp_path, capsys):
    rec = ecd_folder(tmp_path / "rec", n=20_000)
    out = tmp_path / "frames"
    args = [str(rec), "--out", str(out), "--no-progress", "--engine", "torch"]
    assert reconstruct_main(args + ["--limit", "3"]) == 0
    assert len(list(out.glob("frame_*.png"))) == 3
    refused(reconstruct_main(args + ["--limit", "1"]), capsys.readouterr().err,
            "earlier run", "--overwrite")
    assert len(list(out.glob("frame_*.png"))) == 3
    assert reconstruct_main(args + ["--limit", "1", "--overwrite"]) == 0
    assert [p.name for p in out.glob("frame_*.png")] == ["frame_000000.png"]
    own = tmp_path / "mine"
    own.mkdir()
    (own / "timestamps.txt").write_text("my timestamps")
    refused(reconstruct_main([str(rec), "--out", str(own), "--no-progress", "--engine",
                              "torch", "--overwrite"]), capsys.readouterr().err,
            "timestamps.txt", "not written by e2sr")
    assert (own / "timestamps.txt").read_text() == "my timestamps"


# ---------------------------------------------------------------- memory


def billion_laughs(levels: int = 9) -> str:
    """Nested aliases of mappings: ~1 kB of text, 9^9 mappings once expanded."""
    lines = ["a0: &a0 {" + ", ".join(f"k{i}: lol" for i in range(9)) + "}"]
    for k in range(1, levels):
        lines.append(f"a{k}: &a{k} {{" + ", ".join(f"k{i}: *a{k - 1}" for i in range(9)) + "}")
    return "\n".join(lines) + "\n"


def test_nested_aliases_are_refused_before_they_expand(tmp_path):
    from datagen.config import DatagenConfig

    with pytest.raises(ConfigError, match="expands to more than"):
        load_yaml_text(DatagenConfig, billion_laughs(), source="bomb.yaml")
    with pytest.raises(ConfigError, match="contain itself"):
        load_yaml_text(DatagenConfig, "a: &a [1, *a]\n", source="loop.yaml")
    with pytest.raises(ConfigError, match="nested"):
        load_yaml_text(DatagenConfig, "a: " + "[" * 5000 + "]" * 5000 + "\n")
    ok = "simulation: &s\n  duration_s: 0.5\nsensor_ranges: {}\n"  # small aliases still load
    assert load_yaml_text(DatagenConfig, ok).simulation.duration_s == 0.5


@pytest.mark.parametrize("module,func,extra", [
    ("datagen.cli", "main", ["generate", "--n-seq", "1", "--out", "OUT"]),
    ("model.cli", "main", ["--data", "OUT", "--out", "OUT/run"]),
])
def test_a_config_bomb_stays_under_a_memory_cap(tmp_path, module, func, extra):
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(billion_laughs())
    assert bomb.stat().st_size < 2000
    args = [a.replace("OUT", str(tmp_path / "o")) for a in extra] + ["--config", str(bomb)]
    proc = run_capped(module, func, args, cap_gib=3)
    refused(proc, proc.stderr, "bomb.yaml", "expands to more than")


def test_a_recording_claiming_millions_of_events_at_one_time_streams(tmp_path):
    """Compressed zeros: every event at t = 0, pixel (0, 0). Before, reconstruct held
    every event of the recording's 'first second' (here all of them) at once."""
    path = tmp_path / "zeros.h5"
    n = 150_000_000  # 2 GB as int16/int16/float64/uint8 arrays, 2.5 MB on disk
    with h5py.File(path, "w") as f:
        f.attrs["sensor_resolution"] = [180, 240]
        for name, dtype in (("xs", np.int16), ("ys", np.int16), ("ts", np.float64),
                            ("ps", np.uint8)):
            f.create_dataset(f"events/{name}", shape=(n,), dtype=dtype, chunks=(1 << 20,),
                             compression="gzip")
    assert path.stat().st_size < 5_000_000
    proc = run_capped("model.cli", "reconstruct_main",
                      [path, "--out", tmp_path / "r", "--no-progress", "--engine", "torch",
                       "--limit", "2"], cap_gib=3)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert len(list((tmp_path / "r").glob("frame_*.png"))) == 1  # one time, one output


def png_bomb(path: Path, side: int = 20000) -> None:
    """A gray 8-bit PNG of ``side`` x ``side`` zeros, written row block by row block."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return len(data).to_bytes(4, "big") + body + zlib.crc32(body).to_bytes(4, "big")

    comp, row = zlib.compressobj(9), b"\0" * (side + 1)
    idat = b"".join(comp.compress(row * 1000) for _ in range(side // 1000)) + comp.flush()
    ihdr = side.to_bytes(4, "big") * 2 + bytes([8, 0, 0, 0, 0])
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat)
                     + chunk(b"IEND", b""))


def test_a_texture_claiming_400_megapixels_is_skipped_under_a_memory_cap(tmp_path):
    folder = tmp_path / "tex"
    folder.mkdir()
    png_bomb(folder / "bomb.png")
    shutil.make_archive(str(tmp_path / "tex"), "zip", folder)
    assert (tmp_path / "tex.zip").stat().st_size < 1_000_000
    code = ("import sys; from datagen.textures import ImageLibrary\n"
            "lib = ImageLibrary(sys.argv[1]); img = lib.read(0)\n"
            "sys.exit(0 if img is None and lib.skipped == 1 else 1)")
    cap = int(1.5 * GIB)
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "tex.zip")],
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (cap, cap)),
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "larger than e2sr decodes" in proc.stderr


def test_calibrate_holds_memory_in_proportion_to_the_events_not_75_times(tmp_path):
    path = tmp_path / "many.h5"
    n, rng = 500_000, np.random.default_rng(1)
    with h5py.File(path, "w") as f:
        f.attrs["sensor_resolution"] = [180, 240]
        f.create_dataset("events/xs", data=rng.integers(0, 240, n).astype(np.int16))
        f.create_dataset("events/ys", data=rng.integers(0, 180, n).astype(np.int16))
        f.create_dataset("events/ts", data=np.sort(rng.uniform(0, 2.0, n)))
        f.create_dataset("events/ps", data=rng.integers(0, 2, n).astype(np.uint8))
    proc = run_capped("datagen.cli", "main",
                      ["calibrate", path, "--out", tmp_path / "p.yaml"], cap_gib=2)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "background_rate_hz" in (tmp_path / "p.yaml").read_text() or \
        (tmp_path / "p.yaml").stat().st_size > 0


def test_calibrate_refuses_more_events_than_it_holds(tmp_path, monkeypatch, capsys):
    import datagen.formats.base as base

    rec = ecd_folder(tmp_path / "rec", n=5000)
    monkeypatch.setattr(base, "MAX_EVENTS_HELD", 1000)
    monkeypatch.setattr(base.Recording.read_all, "__defaults__", (1000,))
    refused(datagen_main(["calibrate", str(rec), "--out", str(tmp_path / "p.yaml")]),
            capsys.readouterr().err, "more than 1,000 events")
    assert not (tmp_path / "p.yaml").exists()


def test_workers_are_capped_at_the_cores(tmp_path, monkeypatch, caplog):
    import datagen.generate

    seen = {}

    def fake(config, out, n_seq, **kw):
        seen.update(kw)
        raise ValueError("stop here")

    monkeypatch.setattr(datagen.generate, "generate", fake)
    with caplog.at_level(logging.WARNING):
        assert datagen_main(["generate", "--config", str(TINY), "--n-seq", "1", "--out",
                             str(tmp_path), "--workers", "1000"]) == 2
    assert seen["workers"] == (os.cpu_count() or 1) < 1000
    assert "capped at the" in caplog.text


@pytest.mark.parametrize("size", [["20000", "20000"], ["100000", "48"]])
def test_a_sensor_too_large_to_simulate_is_refused_at_load(tmp_path, capsys, size):
    rc = datagen_main(["generate", "--config", str(TINY), "--n-seq", "1", "--out",
                       str(tmp_path), "--set", f"simulation.camera.width={size[0]}",
                       "--set", f"simulation.camera.height={size[1]}"])
    refused(rc, capsys.readouterr().err, "larger than e2sr handles", "--set")
    assert not list(tmp_path.glob("shard_*"))


def test_a_recording_claiming_a_huge_sensor_is_refused(tmp_path):
    from datagen.recording import open_recording

    path = tmp_path / "big.h5"
    with h5py.File(path, "w") as f:
        f.attrs["sensor_resolution"] = [100_000, 100_000]
        for name in ("xs", "ys", "ts", "ps"):
            f.create_dataset(f"events/{name}", data=np.zeros(10, np.int16))
    with pytest.raises(ValueError, match="big.h5: sensor size 100000x100000 is larger"):
        open_recording(path)


# ---------------------------------------------------------------- tracebacks


def test_many_events_sharing_one_timestamp(tmp_path):
    folder = tmp_path / "same"
    folder.mkdir()
    rows = [f"0.{i:06d} {i % 40} {i % 30} 1\n" for i in range(5000)]
    rows += [f"0.100000 {i % 40} {i % 30} {i % 2}\n" for i in range(100_000)]
    rows += [f"0.2{i:05d} {i % 40} {i % 30} 1\n" for i in range(5000)]
    (folder / "events.txt").write_text("".join(rows))
    out = tmp_path / "r"
    assert reconstruct_main([str(folder), "--out", str(out), "--no-progress", "--engine",
                             "torch", "--sensor-size", "40x30"]) == 0
    times = [float(v.split()[1]) for v in (out / "timestamps.txt").read_text().splitlines()]
    assert times == sorted(set(times))  # one output per time


def test_unreadable_textures_are_skipped(tmp_path, caplog):
    from datagen.textures import ImageLibrary

    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "text.png").write_text("not an image")
    cv2.imwrite(str(tmp_path / "good.png"), np.full((32, 32), 128, np.uint8))
    lib = ImageLibrary(tmp_path)
    with caplog.at_level(logging.WARNING):
        images = [lib.read(i) for i in range(len(lib))]
    assert sum(img is not None for img in images) == 1 and lib.skipped == 2
    assert "empty.png" in caplog.text and "text.png" in caplog.text


@pytest.mark.parametrize("fmt", ["EVT2", "EVT3"])
def test_a_raw_file_with_a_random_payload(tmp_path, capsys, fmt):
    path = tmp_path / f"random_{fmt}.raw"
    header = f"% evt {fmt[-1]}.0\n% format {fmt};height=180;width=240\n% end\n".encode()
    path.write_bytes(header + np.random.default_rng(0).integers(0, 256, 200_000, np.uint8)
                     .tobytes())
    refused(reconstruct_main([str(path), "--out", str(tmp_path / "r"), "--no-progress",
                              "--engine", "torch"]), capsys.readouterr().err, path.name)
    refused(datagen_main(["calibrate", str(path), "--out", str(tmp_path / "p.yaml")]),
            capsys.readouterr().err, path.name, "cannot be read")


def read_only(monkeypatch, folder: Path) -> None:
    """Every mkdir and file creation under ``folder`` fails as on a read-only disk."""
    real_mkdir, real_open = pathlib.Path.mkdir, pathlib.Path.open

    def inside(p) -> bool:
        return Path(p).resolve().is_relative_to(folder.resolve())

    def mkdir(self, *a, **kw):
        if inside(self):
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return real_mkdir(self, *a, **kw)

    def open_(self, mode="r", *a, **kw):
        if inside(self) and any(c in mode for c in "wax+"):
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return real_open(self, mode, *a, **kw)

    monkeypatch.setattr(pathlib.Path, "mkdir", mkdir)
    monkeypatch.setattr(pathlib.Path, "open", open_)


def test_a_read_only_out_is_a_clear_error(tmp_path, monkeypatch, capsys):
    rec = ecd_folder(tmp_path / "rec", n=20_000)
    ro = tmp_path / "ro"
    read_only(monkeypatch, ro)
    refused(reconstruct_main([str(rec), "--out", str(ro / "f"), "--no-progress", "--engine",
                              "torch"]), capsys.readouterr().err, "not writable")
    refused(evaluate_main(["--recording", str(rec), "--out", str(ro / "m"), "--engine",
                           "torch"]), capsys.readouterr().err, "not writable")


def test_an_infinite_frame_time_is_named(tmp_path, capsys):
    rec = ecd_folder(tmp_path / "rec")
    (rec / "images").mkdir()
    cv2.imwrite(str(rec / "images" / "0.png"), np.zeros((30, 40), np.uint8))
    (rec / "images.txt").write_text("inf images/0.png\n")
    refused(reconstruct_main([str(rec), "--out", str(tmp_path / "r"), "--no-progress"]),
            capsys.readouterr().err, "images.txt: line 1", "not a finite time")


def test_export_model_metrics_must_be_a_file(tmp_path, capsys):
    ckpt = ROOT / "model" / "weights" / "e2sr_x2.pt"
    refused(export_main([str(ckpt), "--metrics", str(tmp_path)]), capsys.readouterr().err,
            str(tmp_path), "a folder")


# ---------------------------------------------------------------- unclear or silent


def test_hr_frames_outside_the_unit_range_are_refused_when_a_shard_is_opened(tiny_shards,
                                                                           tmp_path):
    from model.data.config import DataConfig
    from model.data.dataset import index_samples

    path = tmp_path / "shard_00000.h5"
    shutil.copy(sorted(tiny_shards.glob("shard_*.h5"))[0], path)
    with h5py.File(path, "a") as f:
        seq = sorted(k for k in f if k.startswith("seq_"))[0]
        shape = f[seq]["frames/hr_x2"].shape
        del f[seq]["frames/hr_x2"]
        f[seq].create_dataset("frames/hr_x2", data=np.full(shape, 10**12, np.int64))
    with pytest.raises(ValueError, match=f"{seq}/frames/hr_x2: int64"):
        index_samples([path], DataConfig(), 3, 2)
    with h5py.File(path, "a") as f:
        f[seq]["frames/hr_x2"][...] = 0
        del f[seq]["frames/hr_x2"]
        f[seq].create_dataset("frames/hr_x2", data=np.full(shape, 1e6, np.float32))
    with pytest.raises(ValueError, match="frame 0 holds values 1e\\+06"):
        index_samples([path], DataConfig(), 3, 2)


def test_aps_frames_of_another_size_than_the_sensor_are_named(tmp_path, capsys):
    rec = ecd_folder(tmp_path / "rec", n=20_000, hw=(30, 40))
    (rec / "images").mkdir()
    rows = []
    for k in range(3):
        cv2.imwrite(str(rec / "images" / f"{k}.png"), np.full((20, 24), 100, np.uint8))
        rows.append(f"{0.1 * k:.3f} images/{k}.png\n")
    (rec / "images.txt").write_text("".join(rows))
    refused(evaluate_main(["--recording", str(rec), "--sensor-size", "40x30", "--out",
                           str(tmp_path / "m"), "--engine", "torch", "--no-baselines"]),
            capsys.readouterr().err, "APS frames are 24x20", "sensor is 40x30")


def test_a_bad_set_value_names_the_set_not_the_file(tmp_path):
    from datagen.config import DatagenConfig

    with pytest.raises(ConfigError, match=r"^--set simulation.camera.width=wide: "):
        load_config(DatagenConfig, TINY, ["simulation.camera.width=wide"])
    with pytest.raises(ConfigError, match=r"bad.yaml: "):  # the file's own error
        bad = tmp_path / "bad.yaml"
        bad.write_text("simulation:\n  camera:\n    width: wide\n")
        load_config(DatagenConfig, [TINY, bad], ["simulation.duration_s=1"])


def test_train_out_on_a_read_only_disk(tiny_shards, tmp_path, monkeypatch, capsys):
    ro = tmp_path / "ro"
    read_only(monkeypatch, ro)
    rc = train_main(["--data", str(tiny_shards), "--config", str(ROOT / "configs" /
                                                                 "train_tiny.yaml"),
                     "--out", str(ro / "run"), "--no-progress"])
    refused(rc, capsys.readouterr().err, "ro")


def test_from_video_refuses_a_frame_claiming_400_megapixels_by_its_header(tmp_path, capsys):
    folder = tmp_path / "frames"
    folder.mkdir()
    png_bomb(folder / "00000.png")
    (folder / "timestamps.txt").write_text("0\n")
    out = tmp_path / "out"
    refused(datagen_main(["from-video", str(folder), "--out", str(out), "--workers", "1",
                          "--no-progress"]),
            capsys.readouterr().err, "00000.png", "larger than e2sr decodes")
    assert not out.exists()


@pytest.mark.parametrize("content", ["hdf5", "text"])
def test_from_video_never_removes_a_file_it_cannot_prove_it_wrote(tmp_path, capsys, content):
    folder = tmp_path / "frames"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(4):
        cv2.imwrite(str(folder / f"{k}.png"), rng.integers(0, 255, (64, 64), np.uint8))
    out, mine = users_shard(tmp_path, content)
    before = mine.read_bytes()
    rc = datagen_main(["from-video", str(folder), "--fps", "30", "--sensor-size", "32x32",
                       "--set", "video.frames_per_sequence=4", "--out", str(out),
                       "--workers", "1", "--no-progress"])
    refused(rc, capsys.readouterr().err, "shard_00000.h5", "not a shard datagen wrote")
    assert mine.read_bytes() == before
