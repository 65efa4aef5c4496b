"""The ``datagen`` command line."""

from __future__ import annotations

import argparse
import logging
import sys

from datagen.config import DatagenConfig
from esim_lite.dataconf import ConfigError, apply_overrides, from_mapping, load_yaml

log = logging.getLogger("datagen")


def load_config(path: str | None, overrides: list[str]) -> DatagenConfig:
    """The YAML at ``path`` (or the built-in defaults) with ``key=value`` overrides."""
    if path:
        return load_yaml(DatagenConfig, path, overrides)
    return from_mapping(DatagenConfig, apply_overrides({}, overrides), source="--set")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="YAML config (default: built-in defaults)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. simulation.render.backend=homography")
    p.add_argument("--seed", type=int, default=0, help="dataset seed (default 0)")
    p.add_argument("-v", "--verbose", action="store_true")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="datagen", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="simulate one sequence and write a PNG contact sheet")
    _common(demo)
    demo.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    demo.add_argument("--index", type=int, default=0, help="sequence index (default 0)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        config = load_config(args.config, args.set)
        if args.command == "demo":
            from datagen.demo import run_demo

            path = run_demo(config, args.out, seed=args.seed, index=args.index)
            print(f"contact sheet written to {path.resolve()}")
            return 0
    except (ConfigError, FileNotFoundError, ValueError) as exc:
        print(f"datagen: error: {exc}", file=sys.stderr)
        return 2
    return 1


if __name__ == "__main__":
    sys.exit(main())
