"""datagen from-video: accuracy against the renderer's exact events, and cost on a long 1080p
video.

Run: PYTHONPATH=. .venv/bin/python bench/bench_from_video.py [--oracle] [--long SECONDS ...]
         [--workdir DIR]

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

esim_py itself is not run: building it (bench/esim_py/build.sh) needs an rpg_vid2e checkout
and OpenCV, Eigen and Boost headers, none of which this machine has; ``linear`` is its rule
(and bench/bench_events.py times its kernel against ours where it is built).
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


def long_video(work: Path, seconds: list[float]) -> None:
    print("| video | frames | interpolator | sequences | events | CPU s | sequences / CPU min "
          "| peak RSS MB |")
    print("|---|---:|---|---:|---:|---:|---:|---:|")
    for s in seconds:
        video = work / f"pan_{s:g}s.avi"
        if not video.exists():
            make_video(video, s)
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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--oracle", action="store_true")
    p.add_argument("--speeds", type=float, nargs="+", default=[0.5, 1, 2, 4, 8, 12])
    p.add_argument("--long", type=float, nargs="*", default=[])
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
    finally:
        if not args.workdir:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
