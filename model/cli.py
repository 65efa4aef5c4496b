"""Command lines of the model: ``train``, ``reconstruct``, ``evaluate``, ``export-model`` and
``convert-checkpoint``."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
from dataclasses import replace
from pathlib import Path

from esim_lite.core.dataconf import ConfigError, load_config
from model.config import TrainConfig


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="train", description=__doc__)
    p.add_argument("--data", required=True, help="folder of shard_*.h5 files (or one shard)")
    p.add_argument("--config", help="YAML config, e.g. configs/train_x2_3s.yaml")
    p.add_argument("--out", default="runs/e2sri", help="checkpoints, logs, PNGs (default "
                   "runs/e2sri)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. optim.batch_size=4")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    p.add_argument("--overwrite", action="store_true",
                   help="start afresh in an OUT that holds another run, removing its files "
                        "(without --resume or --overwrite such a folder is refused)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        config = load_config(TrainConfig, args.config, args.set)
        with _claim_out(args, config.run.seed):
            if config.task == "flow":
                from model.training.flow_pretrain import pretrain_flow

                result = pretrain_flow(config, args.data, args.out, not args.no_progress)
                print(f"flow pre-training: {result['step']} steps; held-out EPE (px) "
                      f"{result['val']}; checkpoint {args.out}/flow_last.pt")
                return 0
            from model.training.train import psnr_summary, train

            result = train(config, args.data, args.out, resume=args.resume,
                           show_progress=not args.no_progress)
    except (ConfigError, FileNotFoundError, ValueError, FloatingPointError, OSError) as exc:
        print(f"train: error: {exc}", file=sys.stderr)
        return 2
    print(f"trained {result['step']} steps in {result['seconds']:.0f} s; validation: "
          f"{psnr_summary(result)}")
    if "png" in result:
        print(f"checkpoint {args.out}/last.pt, validation examples {result['png']}")
    return 0


def _claim_out(args: argparse.Namespace, seed: int):
    """The run folder, held for this run (rank 0 only under torchrun: it alone writes it)."""
    if int(os.environ.get("RANK", "0")) != 0:
        if args.resume and args.overwrite:
            raise ValueError("--resume continues the run in --out, --overwrite starts afresh "
                             "there: give one of them")
        return contextlib.nullcontext()
    from model.training.run_folder import RunFolder

    return RunFolder(args.out, seed, resume=args.resume, overwrite=args.overwrite)


def _out_folder(out: str, names: tuple[str, ...], inputs: list[str], earlier: str,
                what: str):
    """The output folder, checked before any work (:class:`esim_lite.core.outputs.
    OutputFolder`): a folder (or nothing yet) that is writable, where no file under this
    command's names is an input or a file e2sr did not write."""
    from esim_lite.core.outputs import OutputFolder

    return OutputFolder(out, names, inputs).prepare(earlier, what)


def _sensor(text: str | None) -> tuple[int, int] | None:
    if not text:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise ValueError(f"--sensor-size must look like 240x180 (width x height), got "
                         f"{text!r}") from exc
    return h, w


def _engine_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--engine", choices=["auto", "torch", "onnxruntime", "openvino",
                                        "openvino-bf16", "openvino-int8"],
                   default="auto", help="what runs the network: auto (default: on a CPU "
                   "openvino-bf16 where bfloat16 is OpenVINO's native precision (AMX) and the "
                   "network passed its quality check in it (>= 35 dB PSNR against float32 on "
                   "held-out simulated inputs, checked once and recorded with the export), "
                   "else the fastest installed float32 engine, openvino > onnxruntime > "
                   "torch; torch on a GPU), torch (eager PyTorch, the reference), onnxruntime "
                   "or openvino (float32; the 'fast' extra; exported once into ~/.cache/e2sr, "
                   "see docs/evaluation.md), openvino-bf16 (bfloat16 units needed), "
                   "openvino-int8 (quantised once, calibrated on simulated inputs: 30-33 dB "
                   "from float32)")


def fill_arguments(p: argparse.ArgumentParser) -> None:
    """``--fill`` and ``--fill-radius``: what the output gets where no event fired."""
    p.add_argument("--fill", choices=["none", "harmonic", "flat"], default="none",
                   help="what our output gets where no event fired (model/inference/fill.py): "
                   "none (default: the network's own fill), harmonic (the smoothest "
                   "continuation of the output where events fired), flat (each event-free "
                   "region one level, its rim's mean); see docs/evaluation.md")
    p.add_argument("--fill-radius", type=int, default=2,
                   help="LR pixels around every fired pixel where --fill keeps the network's "
                   "output (default 2)")


def fill_config(args: argparse.Namespace):
    """The :class:`model.inference.fill.FillConfig` of :func:`fill_arguments`' flags."""
    from model.inference.fill import FillConfig
    return FillConfig(mode=args.fill, radius=args.fill_radius)


def _stack_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--events-per-stack", type=int,
                   help="events per stack (default: chosen by --stack-rule)")
    p.add_argument("--stack-rule", choices=["auto", "active", "area"], default="auto",
                   help="how events per stack scale from the model's: active (by the pixels "
                   "active in the recording's first second), area (by sensor area, the "
                   "paper's rule), auto (default: active for recordings; for our shards, "
                   "the rule the model was trained with); see docs/evaluation.md")


def reconstruct_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="reconstruct", description="Super-resolved images from "
                                "an event recording (shard, HDF5, ECD text, AEDAT4, raw).")
    p.add_argument("input", help="recording: .h5, events.txt or its folder, .aedat4, .raw")
    p.add_argument("--checkpoint", help="a trained model (train's last.pt; default: the "
                   "model shipped for --scale)")
    p.add_argument("--scale", type=int, default=2, help="super-resolution factor of the "
                   "shipped model to use when no --checkpoint is given (default 2)")
    p.add_argument("--out", required=True, help="folder for frame_XXXXXX.png")
    p.add_argument("--overwrite", action="store_true", help="replace the frames an earlier "
                   "reconstruct left in --out (without it such a folder is refused)")
    p.add_argument("--mode", choices=["main", "complementary", "duo-pass"], default="main")
    p.add_argument("--first-pass", help="main model checkpoint for --mode duo-pass")
    p.add_argument("--sensor-size", help="WxH, when the file does not say (e.g. 240x180)")
    p.add_argument("--sequence", help="sequence of a shard (default: the first)")
    p.add_argument("--at", choices=["auto", "frames", "events", "rate"], default="auto",
                   help="output at APS frames, every stack of events, or --rate (default: "
                        "frames if the file has them, else events)")
    p.add_argument("--rate", type=float, help="outputs per second with --at rate")
    p.add_argument("--every", type=int, help="events between outputs with --at events "
                   "(default: one stack)")
    _stack_arguments(p)
    p.add_argument("--limit", type=int, help="stop after this many frames")
    p.add_argument("--mp4", action="store_true", help="also write video.mp4")
    p.add_argument("--temporal", type=float, metavar="WEIGHT",
                   help="blind temporal-consistency post-process (e.g. 0.6)")
    fill_arguments(p)
    p.add_argument("--device", help="cpu or cuda (default: cuda if present)")
    _engine_argument(p)
    p.add_argument("--no-progress", action="store_true")
    return p


def reconstruct_main(argv: list[str] | None = None) -> int:
    args = reconstruct_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        from datagen.recording import open_recording
        from model import checkpoint
        from model.calibration import simulated_inputs
        from model.inference.pretrained import resolve
        from model.inference.reconstruct import OUTPUTS, Reconstructor, plan_outputs, reconstruct
        from model.stack_size import activity_for_rule

        out = _out_folder(args.out, OUTPUTS, [args.input, args.checkpoint or ""],
                          "remove" if args.overwrite else "refuse", "frames")
        ckpt = resolve(args.checkpoint, args.scale)
        rec = open_recording(args.input, _sensor(args.sensor_size), args.sequence)
        if args.mode != "main":  # the APS frames enter the network beside the events
            rec.check_frames_match()
        state = checkpoint.load(ckpt)
        activity = activity_for_rule(rec, args.stack_rule,
                                     checkpoint.config_of(state, str(ckpt)).data.stack_rule,
                                     args.events_per_stack)
        model = Reconstructor.from_state(state, str(ckpt), rec.sensor_hw, args.mode,
                                         args.first_pass, args.events_per_stack, args.device,
                                         args.engine, activity, simulated_inputs)
        model = replace(model, fill=fill_config(args))
        print(model.engine_line, flush=True)
        plan = plan_outputs(rec, model.stacks, args.at, args.rate, args.every)
        result = reconstruct(rec, model, out, plan, args.mp4, not args.no_progress,
                             args.limit, temporal=args.temporal)
    except (ConfigError, FileNotFoundError, ValueError, OSError) as exc:
        print(f"reconstruct: error: {exc}", file=sys.stderr)
        return 2
    n = len(result.frames)
    per = {k: 1e3 * v / max(n, 1) for k, v in result.seconds.items()}
    print(f"wrote {n} frame(s) to {args.out} ({rec.kind}, {rec.sensor_hw[1]}x{rec.sensor_hw[0]}"
          f" sensor, {model.stacks.events_per_stack} events per stack, engine "
          f"{model.engine_name}); ms per frame: "
          + ", ".join(f"{k} {v:.1f}" for k, v in per.items()))
    print(f"events per stack: {model.stack_choice.describe()}")
    return 0


def evaluate_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="evaluate", description="PSNR/SSIM/MSE/LPIPS and E_warp "
                                "of E2SRI and classical baselines (HF, direct integration, "
                                "complementary filter).")
    p.add_argument("--checkpoint", help="a trained model (default: the model shipped for "
                   "--scale)")
    p.add_argument("--scale", type=int, default=2, help="scale of the shipped model to use "
                   "when no --checkpoint is given (default 2)")
    p.add_argument("--data", help="shards to evaluate on (see --split)")
    p.add_argument("--split", choices=["val", "all"], default="val",
                   help="val: the checkpoint's held-out sequences of --data (default); all: "
                        "every sequence (a separate test set)")
    p.add_argument("--recording", action="append", default=[],
                   help="a recording (repeatable); with APS frames it is scored against "
                        "them, without it appears in the figure only")
    p.add_argument("--sensor-size", help="WxH of --recording files that do not store it")
    p.add_argument("--out", required=True, help="folder for metrics.md/.csv and figure.png")
    p.add_argument("--normalize", choices=["affine", "minmax", "evreal", "none", "observed"],
                   default="affine", help="intensity normalisation before the metrics "
                   "(model/inference/evaluate.py; evreal: EVREAL's standard protocol; "
                   "observed: the affine fit and the metrics where events fired)")
    p.add_argument("--every", type=int, default=1, help="every k-th frame")
    p.add_argument("--max-frames", type=int, help="per sequence")
    p.add_argument("--no-baselines", action="store_true")
    p.add_argument("--no-temporal", action="store_true", help="skip the ours+tc post-process")
    p.add_argument("--first-pass", help="main model checkpoint for a Duo-Pass model")
    _stack_arguments(p)
    p.add_argument("--exposure-average", action="store_true",
                   help="average every method's outputs inside each APS frame's exposure "
                   "window (AEDAT4 and a text folder's exposures.txt store it) before scoring")
    fill_arguments(p)
    _engine_argument(p)
    return p


def evaluate_main(argv: list[str] | None = None) -> int:
    args = evaluate_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        from model.calibration import simulated_inputs
        from model.inference.evaluate import BASELINES, OUTPUTS, EvalOptions, evaluate
        from model.inference.pretrained import resolve

        out = _out_folder(args.out, OUTPUTS, [*args.recording, args.data or "",
                                              args.checkpoint or ""], "replace", "metrics")
        options = EvalOptions(normalize=args.normalize, every=args.every,
                              max_frames=args.max_frames,
                              baselines=() if args.no_baselines else BASELINES,
                              temporal=not args.no_temporal, stack_rule=args.stack_rule,
                              events_per_stack=args.events_per_stack,
                              exposure_average=args.exposure_average,
                              fill=fill_config(args))
        rows = evaluate(resolve(args.checkpoint, args.scale), out, args.data,
                        args.recording, options, args.first_pass, args.split,
                        _sensor(args.sensor_size), args.engine, simulated_inputs)
    except (ConfigError, FileNotFoundError, ValueError, OSError) as exc:
        print(f"evaluate: error: {exc}", file=sys.stderr)
        return 2
    for r in rows:
        if r["sequence"] == "average":
            extra = (f"  E_warp {r['ewarp']:.2f}" if "ewarp" in r else "") + (
                f"  region {r['coverage']:.3f}  invented {r['invented']:.3f}"
                if "invented" in r else "")
            print(f"{r['protocol']:>2} {r['method']:<13} PSNR {r['psnr']:6.2f}  SSIM "
                  f"{r['ssim']:.3f}  MSE {r['mse']:.4f}  LPIPS {r.get('lpips', float('nan')):.3f}"
                  f"{extra}")
    print(f"tables: {args.out}/metrics.md (with the events per stack of each sequence), "
          f"{args.out}/metrics.csv; figure: {args.out}/figure.png")
    return 0


def _metrics_of(path: Path) -> object:
    """What ``export-model --metrics`` records: a result.json's ``val`` entry, or the text
    of a metrics.csv (at most a config's size).

    Raises:
        ValueError: naming ``path``: not a file, too large, or not a JSON object.
    """
    import json

    from esim_lite.core.limits import MAX_CONFIG_BYTES

    if not path.is_file():
        raise ValueError(f"{path}: --metrics names a result.json or metrics.csv file, and "
                         f"this is {'a folder' if path.is_dir() else 'not there'}")
    if path.stat().st_size > MAX_CONFIG_BYTES:
        raise ValueError(f"{path}: {path.stat().st_size:,} bytes, more than a metrics file "
                         f"holds ({MAX_CONFIG_BYTES:,})")
    text = path.read_text(errors="replace")
    if path.suffix != ".json":
        return text
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a JSON object (train's result.json is one)")
    return data.get("val")


def export_main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="export-model", description="Ship a trained checkpoint "
                                "as the package's default model of its scale (float16 "
                                "weights and a SHA-256 in model/weights/manifest.json).")
    p.add_argument("checkpoint", help="a training checkpoint (train's last.pt)")
    p.add_argument("--data", default="", help="what it was trained on (for the manifest)")
    p.add_argument("--recipe", default="", help="the command that trained it")
    p.add_argument("--metrics", help="a result.json or metrics.csv to record beside it")
    args = p.parse_args(argv)
    try:
        from model import checkpoint
        from model.inference.pretrained import export

        state = checkpoint.load(args.checkpoint)
        info = {"data": args.data, "recipe": args.recipe, "step": state.get("step"),
                "train_hours_2_cores": round(float(state.get("train_seconds") or 0) / 3600, 3)}
        if args.metrics:
            info["metrics"] = _metrics_of(Path(args.metrics))
        target = export(args.checkpoint, info=info)
    except (ConfigError, FileNotFoundError, ValueError, OSError) as exc:
        print(f"export-model: error: {exc}", file=sys.stderr)
        return 2
    print(f"shipped {target} ({target.stat().st_size / 1e6:.2f} MB)")
    return 0


def convert_main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="convert-checkpoint", description="Rewrite a checkpoint "
                                "that e2sr refuses to load (its pickle names code, not only "
                                "tensors and plain containers) as plain data. Converting "
                                "unpickles the file the unsafe way, running whatever it "
                                "names: do it only for a file you trust.")
    p.add_argument("source", help="the checkpoint to convert")
    p.add_argument("out", help="the converted checkpoint (a new file; never overwritten)")
    p.add_argument("--trust", action="store_true", help="required: you trust where SOURCE "
                   "came from (converting runs what its pickle names)")
    args = p.parse_args(argv)
    if not args.trust:
        print(f"convert-checkpoint: error: {args.source}: converting runs whatever the file's "
              f"pickle names; pass --trust if you trust where it came from", file=sys.stderr)
        return 2
    try:
        from model import checkpoint

        target = checkpoint.convert_trusted(args.source, args.out)
    except (FileNotFoundError, FileExistsError, ValueError) as exc:
        print(f"convert-checkpoint: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {target}: loads as data only")
    return 0


if __name__ == "__main__":
    sys.exit(main())
