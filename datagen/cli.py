"""datagen: synthetic event-camera datasets (HDF5 shards) for E2SRI training."""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path

from datagen.config import DatagenConfig
from esim_lite.core.dataconf import ConfigError, apply_overrides, from_mapping, load_yaml
from esim_lite.geometry.camera import SCALES

log = logging.getLogger("datagen")


def load_config(path: str | None, overrides: list[str]) -> DatagenConfig:
    """The YAML at ``path`` (or the built-in defaults) with ``key=value`` overrides."""
    if path:
        return load_yaml(DatagenConfig, path, overrides)
    return from_mapping(DatagenConfig, apply_overrides({}, overrides), source="--set")


def shard_paths(target: str) -> list[Path]:
    """A shard file, or every ``shard_*.h5`` in a folder."""
    path = Path(target)
    if path.is_dir():
        found = sorted(path.glob("shard_*.h5"))
        if not found:
            raise FileNotFoundError(f"{path}: no shard_*.h5 files in this folder")
        return found
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    return [path]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="datagen", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true")
    sub = parser.add_subparsers(dest="command", required=True)

    gen = sub.add_parser("generate", help="simulate sequences into HDF5 shards")
    gen.add_argument("--n-seq", type=int, required=True, help="number of sequences")
    gen.add_argument("--out", required=True, help="output folder for shard_XXXXX.h5 files")
    gen.add_argument("--config", help="YAML config (default: built-in, see configs/)")
    gen.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="override a config value, e.g. simulation.render.backend=homography")
    gen.add_argument("--seed", type=int, default=0, help="dataset seed (default 0)")
    gen.add_argument("--scale", help="HR scales: 2, 4, 8 or several, e.g. 2,4 "
                     "(default from the config)")
    gen.add_argument("--textures", nargs="+", metavar="SOURCE",
                     help="one or more folders or zip/pk3 files of images, or 'builtin' "
                          "(default: built-in)")
    gen.add_argument("--texture-split", choices=["all", "train", "test"],
                     help="use only the train or test part of every texture source")
    gen.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                     help="worker processes (default: all cores)")
    gen.add_argument("--shard-index", type=int, default=0,
                     help="this job's index in a job array (default 0)")
    gen.add_argument("--num-shards", type=int, default=1,
                     help="jobs splitting the dataset; job i writes shards k with k %% n == i")
    gen.add_argument("--no-progress", action="store_true", help="no progress bar")

    ins = sub.add_parser("inspect", help="summarise shards")
    ins.add_argument("target", help="a shard file or a folder of shards")

    pre = sub.add_parser("preview", help="a PNG per sequence: frames, events, SBN stack")
    pre.add_argument("target", help="a shard file or a folder of shards")
    pre.add_argument("--out", help="output folder (default: <target folder>/preview)")

    exp = sub.add_parser("export", help="sequences in another tool's format (one file or "
                         "folder each): event_utils HDF5, EVREAL .npy folder, ECD text")
    exp.add_argument("target", help="a shard file or a folder of shards")
    exp.add_argument("--format", required=True, choices=["event_utils", "evreal", "txt"])
    exp.add_argument("--out", required=True, help="output folder")
    exp.add_argument("--sequence", help="only this sequence (e.g. seq_000003)")
    return parser


def _generate(args: argparse.Namespace) -> int:
    from datagen.generate import generate

    if args.workers < 1:
        raise ValueError(f"--workers must be at least 1, got {args.workers}")
    overrides = list(args.set)
    if args.scale:
        try:
            scales = [int(s) for s in args.scale.split(",")]
        except ValueError:
            scales = []
        if not scales or any(s not in SCALES for s in scales):
            raise ValueError(f"--scale must be {', '.join(map(str, SCALES))} or several joined "
                             f"by commas (e.g. 2,4); got {args.scale!r}")
        overrides.append(f"simulation.camera.scales=[{','.join(map(str, scales))}]")
    if args.textures:
        sources = [str(t) for t in args.textures]
        value = sources[0] if len(sources) == 1 else sources
        overrides.append(f"textures.source={json.dumps(value)}")
    if args.texture_split:
        overrides.append(f"textures.split={args.texture_split}")
    config = load_config(args.config, overrides)
    summary = generate(config, args.out, args.n_seq, seed=args.seed, workers=args.workers,
                       shard_index=args.shard_index, num_shards=args.num_shards,
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
        paths = shard_paths(args.target)
        if args.command == "inspect":
            from datagen.summary import describe_shard

            print("\n".join(describe_shard(p) for p in paths))
            return 0
        if args.command == "preview":
            from datagen.preview import preview_shards
            from esim_lite.core.stacking import StackConfig

            out = Path(args.out) if args.out else paths[0].parent / "preview"
            written = preview_shards(paths, out, StackConfig())
            print(f"wrote {len(written)} preview PNG(s) to {out.resolve()}")
            return 0
        if args.command == "export":
            from datagen.export import export

            written = export(paths, args.format, args.out, args.sequence)
            print(f"wrote {len(written)} {args.format} sequence(s) to {Path(args.out).resolve()}")
            return 0
    except (ConfigError, FileNotFoundError, ValueError, OSError) as exc:
        print(f"datagen: error: {exc}", file=sys.stderr)
        return 2
    return 1


if __name__ == "__main__":
    sys.exit(main())
