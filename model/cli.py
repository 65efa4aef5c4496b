"""The ``train`` command line: train E2SRI on datagen shards."""

from __future__ import annotations

import argparse
import logging
import sys

from esim_lite.dataconf import ConfigError, apply_overrides, from_mapping, load_yaml
from model.config import TrainConfig


def load_config(path: str | None, overrides: list[str]) -> TrainConfig:
    if path:
        return load_yaml(TrainConfig, path, overrides)
    return from_mapping(TrainConfig, apply_overrides({}, overrides), source="--set")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train", description=__doc__)
    p.add_argument("--data", required=True, help="folder of shard_*.h5 files (or one shard)")
    p.add_argument("--config", help="YAML config, e.g. configs/train_x2_3s.yaml")
    p.add_argument("--out", default="runs/e2sri", help="checkpoints, logs, PNGs (default "
                   "runs/e2sri)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. optim.batch_size=4")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        config = load_config(args.config, args.set)
        if config.task == "flow":
            from model.flow_pretrain import pretrain_flow

            result = pretrain_flow(config, args.data, args.out, not args.no_progress)
            print(f"flow pre-training: {result['step']} steps; held-out EPE (px) "
                  f"{result['val']}; checkpoint {args.out}/flow_last.pt")
            return 0
        from model.train import psnr_summary, train

        result = train(config, args.data, args.out, resume=args.resume,
                       show_progress=not args.no_progress)
    except (ConfigError, FileNotFoundError, ValueError, FloatingPointError) as exc:
        print(f"train: error: {exc}", file=sys.stderr)
        return 2
    print(f"trained {result['step']} steps in {result['seconds']:.0f} s; validation: "
          f"{psnr_summary(result)}")
    if "png" in result:
        print(f"checkpoint {args.out}/last.pt, validation examples {result['png']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
