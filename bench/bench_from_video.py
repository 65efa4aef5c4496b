"""datagen from-video: accuracy against the renderer's exact events, and cost on a long 1080p
video.

Run: PYTHONPATH=. .venv/bin/python bench/bench_from_video.py [--oracle] [--long SECONDS ...]
         [--esim-py DIR] [--workdir DIR]

``--oracle``: the oracle of tests/datagen/video_oracle.py (a 96x64 camera sliding over a
textured plane, rendered at its own adaptive rate, written as a 30 fps 16-bit PNG video,
9 frames) at several speeds; per-pixel count error and timing error of ``from-video``
``linear`` (esim_py's rule: log intensity linear in time per pixel) and ``flow`` against
the exact events, on the pixels more than ``speed + 2`` from the border.

``--long S``: a synthetic 1920x1080 30 fps MJPG video of S seconds (a photo panning 6
px a frame back and forth, slowly zooming), made here with cv2.VideoWriter, turned into a 128x128
x2 dataset (32 frames a sequence), each run in a child process (one worker): CPU time (user
+ sys) and peak resident memory (ru_maxrss); the machine is shared, so CPU time, not wall
time, is the measure. Streaming shows as a peak memory that does not grow with S.

``--esim-py DIR`` (with ``--long``; DIR holds the ``esim_py_memory`` module that
bench/esim_py/build.sh builds from an rpg_vid2e checkout): two more rows per video, the
same comparison as bench/bench_events.py. esim_py is fed the same LR frames ``from-video``
makes (the same decoding and :func:`datagen.video.optics.camera_images`, as 8-bit linear
intensity, esim_py's input), 32 frames a sequence at the video's own times, Cp = Cn = 0.2,
no interpolation between frames; beside it ``from-video`` with ``linear`` at the same
fixed thresholds, in a child process each.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def oracle(work: Path, speeds: list[float]) -> None:
    from datagen.shard import ShardReader
    from datagen.video.config import FromVideoConfig
    from datagen.video.from_video import from_video
    from esim_lite.core.dataconf import load_config
    from tests.datagen.video_oracle import THRESHOLD, compare, render

    print("| px / frame | exact events | interpolator | count error | timing error "
          "(frame intervals) | samples |")
    print("|---:|---:|---|---:|---:|---:|")
    for speed in speeds:
        r = render(work / f"video_{speed}", speed)
        for name in ("linear", "flow"):
            cfg = load_config(FromVideoConfig, None, [
                f"simulation.camera.width={r.sensor_hw[1]}",
                f"simulation.camera.height={r.sensor_hw[0]}", "simulation.camera.scales=[4]",
                f"simulation.events.thresholds.pos_range=[{THRESHOLD},{THRESHOLD}]",
                f"simulation.events.thresholds.neg_range=[{THRESHOLD},{THRESHOLD}]",
                f"video.frames_per_sequence={r.n_frames}", f"video.interpolator={name}"])
            out = work / f"out_{speed}_{name}"
            from_video([r.folder], out, cfg, show_progress=False)
            with ShardReader(out / "shard_00000.h5") as reader:
                events = reader.events("seq_000000")
                samples = reader.num_samples("seq_000000")
            c = compare(r.events, events, r.frame_interval_ns, int(np.ceil(speed)) + 2)
            print(f"| {speed:g} | {c.true_events:,} | {name} | {c.count_error:.3f} | "
                  f"{c.timing_error:.3f} | {samples} |")


def make_video(path: Path, seconds: float, fps: float = 30.0) -> Path:
    """A 1920x1080 MJPG video: a photo panning 6 px a frame back and forth, zooming."""
    from skimage import data

    photo = cv2.resize(data.astronaut(), (2600, 2600), interpolation=cv2.INTER_CUBIC)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (1920, 1080))
    n = int(round(seconds * fps))
    for k in range(n):
        zoom = 1.0 + 0.1 * k / max(n - 1, 1)
        pan = (6 * k) % 720  # back and forth over 360 px, 6 px a frame
        x = pan if pan < 360 else 720 - pan
        m = np.array([[zoom, 0, -(200 + x)], [0, zoom, -300]], np.float64)
        frame = cv2.warpAffine(photo, m, (1920, 1080), flags=cv2.INTER_LINEAR)
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


CHILD = """
import json, resource, sys, time
from datagen.cli import main
start = time.process_time()
rc = main(sys.argv[1:])
usage = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"rc": rc, "cpu_s": time.process_time() - start,
                  "maxrss_mb": usage.ru_maxrss / 1024}))
"""


def video_of(work: Path, seconds: float) -> Path:
    """The benchmark's synthetic video of ``seconds`` in ``work``, made once."""
    video = work / f"pan_{seconds:g}s.avi"
    return video if video.exists() else make_video(video, seconds)


def long_video(work: Path, seconds: list[float]) -> None:
    print("| video | frames | interpolator | sequences | events | CPU s | sequences / CPU min "
          "| peak RSS MB |")
    print("|---|---:|---|---:|---:|---:|---:|---:|")
    for s in seconds:
        video = video_of(work, s)
        frames = int(round(s * 30))
        for name in ("linear", "flow"):
            out = work / f"long_{s:g}_{name}"
            args = ["from-video", str(video), "--out", str(out), "--sensor-size", "128x128",
                    "--scale", "2", "--interpolator", name, "--workers", "1", "--no-progress"]
            res = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True,
                                 text=True, cwd=ROOT, check=True)
            lines = res.stdout.strip().splitlines()
            stats = json.loads(lines[-1])
            found = re.search(r"(\d+) sequences, ([\d,]+) events", lines[0])
            seqs, events = int(found.group(1)), found.group(2)
            print(f"| 1920x1080 {s:g} s MJPG | {frames} | {name} | {seqs} | {events} | "
                  f"{stats['cpu_s']:.1f} | {seqs / stats['cpu_s'] * 60:.1f} | "
                  f"{stats['maxrss_mb']:.0f} |")


ESIM_CHILD = """
import json, resource, sys, time
import cv2, numpy as np
video, esim_dir, per_seq = sys.argv[1], sys.argv[2], int(sys.argv[3])
start = time.process_time()
sys.path.insert(0, esim_dir)
import esim_py_memory as esim
from datagen.video.optics import camera_images
cap = cv2.VideoCapture(video)
frames, times, seqs, events = [], [], 0, 0
while True:
    ok, frame = cap.read()
    if not ok:
        break
    times.append(cap.get(cv2.CAP_PROP_POS_MSEC) * 1e-3)
    rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    lr = camera_images(rgb, (128, 128), (2,), 1, "srgb").images["lr"]
    frames.append(np.clip(np.round(lr * 255), 0, 255).astype(np.uint8))
    if len(frames) == per_seq:
        sim = esim.EventSimulator(0.2, 0.2, 0.0, 1e-3, True)
        events += len(esim.generate_from_frames(sim, np.stack(frames),
                                                [t - times[0] for t in times]))
        seqs, frames, times = seqs + 1, [], []
usage = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"sequences": seqs, "events": events, "cpu_s": time.process_time() - start,
                  "maxrss_mb": usage.ru_maxrss / 1024}))
"""


def esim_rows(work: Path, seconds: list[float], esim_dir: Path) -> None:
    """``from-video`` ``linear`` against esim_py fed the same LR frames (fixed C = 0.2)."""
    print("| video | pipeline | sequences | events | CPU s | sequences / CPU min "
          "| peak RSS MB |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for s in seconds:
        video = video_of(work, s)
        out = work / f"esim_cmp_{s:g}"
        args = ["from-video", str(video), "--out", str(out), "--sensor-size", "128x128",
                "--scale", "2", "--interpolator", "linear", "--workers", "1", "--no-progress",
                "--set", "simulation.events.thresholds.pos_range=[0.2,0.2]",
                "--set", "simulation.events.thresholds.neg_range=[0.2,0.2]"]
        res = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True,
                             text=True, cwd=ROOT, check=True)
        lines = res.stdout.strip().splitlines()
        ours = json.loads(lines[-1])
        found = re.search(r"(\d+) sequences, ([\d,]+) events", lines[0])
        theirs = json.loads(subprocess.run(
            [sys.executable, "-c", ESIM_CHILD, str(video), str(esim_dir), "32"],
            capture_output=True, text=True, cwd=ROOT, check=True).stdout.strip()
            .splitlines()[-1])
        for name, seqs, events, st in (
                ("from-video linear (shards: LR + HR frames, events)", int(found.group(1)),
                 found.group(2), ours),
                ("esim_py (C++), fed the same LR frames (events in memory)",
                 theirs["sequences"], f"{theirs['events']:,}", theirs)):
            print(f"| 1920x1080 {s:g} s MJPG | {name} | {seqs} | {events} | "
                  f"{st['cpu_s']:.1f} | {seqs / st['cpu_s'] * 60:.1f} | "
                  f"{st['maxrss_mb']:.0f} |", flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--oracle", action="store_true")
    p.add_argument("--speeds", type=float, nargs="+", default=[0.5, 1, 2, 4, 8, 12])
    p.add_argument("--long", type=float, nargs="*", default=[])
    p.add_argument("--esim-py", type=Path, metavar="DIR",
                   help="with --long: also time esim_py (built by bench/esim_py/build.sh)")
    p.add_argument("--workdir")
    args = p.parse_args()
    work = Path(args.workdir or tempfile.mkdtemp(prefix="bench_from_video_"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"command: {' '.join(['bench/bench_from_video.py', *sys.argv[1:]])}")
    try:
        if args.oracle:
            oracle(work, args.speeds)
        if args.long:
            long_video(work, args.long)
            if args.esim_py:
                esim_rows(work, args.long, args.esim_py.resolve())
    finally:
        if not args.workdir:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
