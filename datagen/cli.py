"""datagen: synthetic event-camera datasets (HDF5 shards) for E2SRI training, from
simulated scenes or from videos."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Mapping
from pathlib import Path

from datagen.config import DatagenConfig
from datagen.shard import find_shards
from esim_lite.core.dataconf import ConfigError, load_config
from esim_lite.core.limits import cap_workers
from esim_lite.core.outputs import OutputFolder
from esim_lite.core.scales import SCALES

log = logging.getLogger("datagen")

AUTO = "auto"


def _index_or_auto(text: str) -> int | str:
    if text == AUTO:
        return AUTO
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer or 'auto', got {text!r}") from None


def _env_int(environ: Mapping[str, str], name: str, flag: str) -> int:
    raw = environ.get(name)
    if raw is None:
        raise ValueError(f"{flag} auto reads {name}, which is not set (run inside a SLURM job "
                         f"array, e.g. sbatch --array=0-7, or give a number)")
    try:
        return int(raw)
    except ValueError:
        raise ValueError(f"{flag} auto reads {name}, which is {raw!r}, not an integer") from None


def array_job(shard_index: int | str, num_shards: int | str,
              environ: Mapping[str, str] = os.environ) -> tuple[int, int]:
    """``(shard_index, num_shards)`` with ``auto`` taken from the SLURM job array.

    ``auto`` index: ``SLURM_ARRAY_TASK_ID`` minus ``SLURM_ARRAY_TASK_MIN`` when that is set
    (so ``--array=1-8`` gives 0..7); ``auto`` count: ``SLURM_ARRAY_TASK_COUNT``. The array
    must be one contiguous range (no step, no list), else some shards would never be written.

    Raises:
        ValueError: a variable ``auto`` needs is missing or not an integer (named), the array
            is not a contiguous range, or the index falls outside ``[0, num_shards)``.
    """
    if num_shards == AUTO:
        num_shards = _env_int(environ, "SLURM_ARRAY_TASK_COUNT", "--num-shards")
        if "SLURM_ARRAY_TASK_MIN" in environ and "SLURM_ARRAY_TASK_MAX" in environ:
            low = _env_int(environ, "SLURM_ARRAY_TASK_MIN", "--num-shards")
            high = _env_int(environ, "SLURM_ARRAY_TASK_MAX", "--num-shards")
            if high - low + 1 != num_shards:
                raise ValueError(
                    f"--num-shards auto: the job array {low}-{high} (SLURM_ARRAY_TASK_MIN, "
                    f"SLURM_ARRAY_TASK_MAX) has {num_shards} tasks (SLURM_ARRAY_TASK_COUNT), "
                    f"not one per index; submit a contiguous range such as "
                    f"--array=0-{num_shards - 1}")
    if shard_index == AUTO:
        task = _env_int(environ, "SLURM_ARRAY_TASK_ID", "--shard-index")
        low = _env_int(environ, "SLURM_ARRAY_TASK_MIN", "--shard-index") \
            if "SLURM_ARRAY_TASK_MIN" in environ else 0
        shard_index = task - low
        if not 0 <= shard_index < int(num_shards):
            raise ValueError(f"--shard-index auto: SLURM_ARRAY_TASK_ID {task} minus "
                             f"SLURM_ARRAY_TASK_MIN {low} is {shard_index}, outside [0, "
                             f"{num_shards}) of --num-shards")
    return int(shard_index), int(num_shards)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="datagen", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true")
    sub = parser.add_subparsers(dest="command", required=True)

    gen = sub.add_parser("generate", help="simulate sequences into HDF5 shards")
    gen.add_argument("--n-seq", type=int, required=True, help="number of sequences")
    gen.add_argument("--out", required=True, help="output folder for shard_XXXXX.h5 files")
    gen.add_argument("--config", action="append",
                     help="YAML config (default: built-in, see configs/); several are layered "
                          "in order, later files overriding earlier ones key by key, e.g. a "
                          "sensor preset after a dataset config")
    gen.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="override a config value, e.g. simulation.render.backend=homography")
    gen.add_argument("--seed", type=int, default=0, help="dataset seed (default 0)")
    gen.add_argument("--scale", help="HR scales: 2, 4, 8 or several, e.g. 2,4 "
                     "(default from the config)")
    gen.add_argument("--textures", nargs="+", metavar="SOURCE",
                     help="one or more folders or zip/pk3 files of images, or 'builtin'; "
                          "replaces the config's sources and their weights (default: the "
                          "config's, else built-in)")
    gen.add_argument("--texture-split", choices=["all", "train", "test"],
                     help="use only the train or test part of every texture source")
    gen.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                     help="worker processes (default: all cores)")
    gen.add_argument("--shard-index", type=_index_or_auto, default=0,
                     help="this job's index in a job array (default 0); auto: "
                          "SLURM_ARRAY_TASK_ID minus SLURM_ARRAY_TASK_MIN")
    gen.add_argument("--num-shards", type=_index_or_auto, default=1,
                     help="jobs splitting the dataset; job i writes shards k with k %% n == i "
                          "(default 1); auto: SLURM_ARRAY_TASK_COUNT")
    gen.add_argument("--no-progress", action="store_true", help="no progress bar")

    vid = sub.add_parser("from-video", help="videos (files, folders of frames) into an SR "
                         "training set: HR frames, LR frames and simulated LR events")
    vid.add_argument("inputs", nargs="+", metavar="INPUT",
                     help="a video file (anything OpenCV reads), a folder of frames with "
                          "timestamps.txt (seconds, one a line) or --fps, or a folder of "
                          "videos; several make one dataset")
    vid.add_argument("--out", required=True, help="output folder for shard_XXXXX.h5 files")
    vid.add_argument("--config", action="append",
                     help="YAML config (default: built-in, see configs/from_video.yaml); "
                          "several are layered in order, e.g. a sensor preset last")
    vid.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="override a config value, e.g. video.frames_per_sequence=16")
    vid.add_argument("--scale", type=int, choices=SCALES,
                     help="the HR scale (default from the config)")
    vid.add_argument("--sensor-size", help="the LR event sensor, WxH (default from the "
                     "config, 128x128)")
    vid.add_argument("--interpolator", choices=["flow", "linear"],
                     help="time between frames: flow (default) or linear (esim_py's rule)")
    vid.add_argument("--fps", type=float, help="frame rate of frame folders without "
                     "timestamps.txt")
    vid.add_argument("--seed", type=int, default=0, help="dataset seed (default 0)")
    vid.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                     help="worker processes (default: all cores)")
    vid.add_argument("--shard-index", type=_index_or_auto, default=0,
                     help="this job's index in a job array (default 0); auto: SLURM")
    vid.add_argument("--num-shards", type=_index_or_auto, default=1,
                     help="jobs splitting the dataset (default 1); auto: SLURM")
    vid.add_argument("--no-progress", action="store_true", help="no progress bar")

    ins = sub.add_parser("inspect", help="summarise shards (events, frames, objects, "
                         "ground truth, stored bytes)")
    ins.add_argument("target", help="a shard file or a folder of shards")

    pre = sub.add_parser("preview", help="a PNG per sequence: frames, events, SBN stack "
                         "(and flow and surface ids when the shard holds them)")
    pre.add_argument("target", help="a shard file or a folder of shards")
    pre.add_argument("--out", help="output folder (default: <target folder>/preview)")

    exp = sub.add_parser("export", help="sequences in another tool's format (one file or "
                         "folder each): event_utils HDF5, EVREAL .npy folder, ECD text")
    exp.add_argument("target", help="a shard file or a folder of shards")
    exp.add_argument("--format", required=True, choices=["event_utils", "evreal", "txt"])
    exp.add_argument("--out", required=True, help="output folder")
    exp.add_argument("--sequence", help="only this sequence (e.g. seq_000003)")

    cal = sub.add_parser("calibrate", help="a sensor preset (partial config) measured from a "
                         "recording: thresholds (with APS frames), background activity, hot "
                         "pixels, refractory period, flicker")
    cal.add_argument("recording", nargs="+", help="one or more recordings of one sensor, "
                     "any format reconstruct reads: .aedat4, .raw, .h5 (shard or "
                     "event_utils), events.txt or its folder, EVREAL folder")
    cal.add_argument("--out", required=True, help="the preset YAML to write")
    cal.add_argument("--sensor-size", help="WxH, when the file does not say (e.g. 240x180)")
    cal.add_argument("--sequence", help="a shard's sequence (default: the first)")
    return parser


def _sensor_size(text: str | None) -> tuple[int, int] | None:
    """(H, W) from ``WxH``."""
    if not text:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--sensor-size must look like 240x180 (width x height), got "
                         f"{text!r}") from None
    return h, w


def _calibrate(args: argparse.Namespace) -> int:
    from datagen.calibrate import calibrate_recording, is_preset, preset_yaml, summary_table
    from esim_lite.core.atomic import write_text
    from esim_lite.core.outputs import check_output_file

    check_output_file(args.out, args.recording, is_preset, "sensor preset")
    cals = [calibrate_recording(r, _sensor_size(args.sensor_size), args.sequence)
            for r in args.recording]
    command = "datagen calibrate " + " ".join(
        [*args.recording, *(["--sensor-size", args.sensor_size] if args.sensor_size else []),
         *(["--sequence", args.sequence] if args.sequence else []), "--out", args.out])
    text = preset_yaml(cals, command)
    write_text(args.out, text)
    for cal in cals:
        print(f"== {cal.source}")
        print(summary_table(cal))
        for note in cal.notes:
            print(f"not measured: {note}")
    print(f"preset written to {Path(args.out).resolve()}")
    return 0


def _flag_values(args: argparse.Namespace) -> dict[str, object]:
    """The config values the generate flags set, as dotted keys to typed values."""
    values: dict[str, object] = {}
    if args.scale:
        try:
            scales = [int(s) for s in args.scale.split(",")]
        except ValueError:
            scales = []
        if not scales or any(s not in SCALES for s in scales):
            raise ValueError(f"--scale must be {', '.join(map(str, SCALES))} or several joined "
                             f"by commas (e.g. 2,4); got {args.scale!r}")
        values["simulation.camera.scales"] = scales
    if args.textures:
        sources = [str(t) for t in args.textures]
        values["textures.source"] = sources[0] if len(sources) == 1 else sources
        values["textures.source_weights"] = None  # a config's weights were for its sources
    if args.texture_split:
        values["textures.split"] = args.texture_split
    return values


def _generate(args: argparse.Namespace) -> int:
    from datagen.generate import generate

    workers = _workers(args.workers)
    shard_index, num_shards = array_job(args.shard_index, args.num_shards)
    config = load_config(DatagenConfig, args.config, args.set, _flag_values(args))
    summary = generate(config, args.out, args.n_seq, seed=args.seed, workers=workers,
                       shard_index=shard_index, num_shards=num_shards,
                       show_progress=not args.no_progress)
    print(summary.line())
    print(f"shards in {Path(args.out).resolve()}")
    return 0


def _workers(requested: int) -> int:
    if requested < 1:
        raise ValueError(f"--workers must be at least 1, got {requested}")
    workers = cap_workers(requested)
    if workers < requested:
        log.warning("--workers %d: capped at the %d cores of this machine (more processes "
                    "would only hold more memory)", requested, workers)
    return workers


def _from_video(args: argparse.Namespace) -> int:
    from datagen.video.config import FromVideoConfig
    from datagen.video.from_video import from_video

    workers = _workers(args.workers)
    shard_index, num_shards = array_job(args.shard_index, args.num_shards)
    values: dict[str, object] = {}
    if args.scale:
        values["simulation.camera.scales"] = [args.scale]
    hw = _sensor_size(args.sensor_size)
    if hw is not None:
        values["simulation.camera.height"], values["simulation.camera.width"] = hw
    if args.interpolator:
        values["video.interpolator"] = args.interpolator
    config = load_config(FromVideoConfig, args.config, args.set, values)
    summary = from_video(args.inputs, args.out, config, seed=args.seed, workers=workers,
                         fps=args.fps, shard_index=shard_index, num_shards=num_shards,
                         show_progress=not args.no_progress)
    print(summary.line())
    print(f"shards in {Path(args.out).resolve()}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        if args.command == "generate":
            return _generate(args)
        if args.command == "calibrate":
            return _calibrate(args)
        if args.command == "from-video":
            return _from_video(args)
        paths = find_shards(args.target)
        if args.command == "inspect":
            from datagen.summary import describe_shard

            print("\n".join(describe_shard(p) for p in paths))
            return 0
        if args.command == "preview":
            from datagen.preview import preview_names, preview_shards
            from esim_lite.core.stacking import StackConfig

            out = Path(args.out) if args.out else paths[0].parent / "preview"
            folder = OutputFolder(out, preview_names(paths), paths).prepare()
            written = preview_shards(paths, folder, StackConfig())
            print(f"wrote {len(written)} preview PNG(s) to {out.resolve()}")
            return 0
        if args.command == "export":
            from datagen.export import export, export_names

            folder = OutputFolder(args.out, export_names(paths, args.format), paths).prepare()
            written = export(paths, args.format, folder, args.sequence)
            print(f"wrote {len(written)} {args.format} sequence(s) to {Path(args.out).resolve()}")
            return 0
    except (ConfigError, FileNotFoundError, ValueError, OSError) as exc:
        print(f"datagen: error: {exc}", file=sys.stderr)
        return 2
    return 1


if __name__ == "__main__":
    sys.exit(main())
