"""What a trained network's context branch paints: the same checkpoint with parts of the
branch's residual switched off, scored where no event fired.

Variants (each written as a checkpoint under ``--out``, ``context.out`` columns zeroed):
``full``; ``no-far`` (the far path off: the 16x16 cells of ``context_far: cells``, the
dilated path of ``dilated``); ``no-near`` (the 4x4 path off); ``none`` (the whole residual,
bias included: the network as if it had no branch); and with ``--gate TAU`` (repeatable)
``gate-TAU``: the far path off only where the event history says no event fired for many
times ``TAU`` stacks (``model.context_gate``, every tensor copied, docs/training.md). Each
is scored on a static-camera
split (``evaluate --normalize observed``: metrics inside the fired region, and
``invented``, the share of pixels outside it drawn more than 0.04 from their median level;
then ``--normalize affine`` on whole frames) and, when ``--real`` holds them, on the real
recordings with APS frames (``bench/bench_real.py``). A branch that carries levels into
event-free background shows as ``invented`` falling when it is off. The network was trained
with its branch on, so switching a part off is a diagnosis, not a model.

    .venv/bin/python bench/context_ablation.py runs/x2_context_frames/last.pt \
        --static shards/test_static_x2 --out out/context_ablation

The static split: ``datagen generate --config configs/datagen_realistic.yaml --config
configs/datagen_realistic_dynamic.yaml --config configs/datagen_test_dynamic.yaml --config
configs/datagen_static_small.yaml --n-seq 12 --seed 1003 --out shards/test_static_x2``.
"""

from __future__ import annotations

import argparse
import csv
import shlex
import subprocess
import sys
import time
from pathlib import Path

VARIANTS = ("full", "no-far", "no-near", "none")


def ablated(ckpt: dict, variant: str) -> dict:
    """A copy of checkpoint ``ckpt`` with ``variant``'s columns of the residual zeroed."""
    import copy

    net = ckpt["net"]
    width = int(net.get("context", 0))
    if not width:
        raise ValueError("the network has no context branch (model.context: 0)")
    out = copy.deepcopy(ckpt)
    weight, bias = out["model"]["context.out.weight"], out["model"]["context.out.bias"]
    if variant == "no-far":  # the near (4x4) path's columns come first, the far path's last
        weight[:, -width:] = 0
    elif variant == "no-near":
        weight[:, :width] = 0
    elif variant == "none":
        weight.zero_()
        bias.zero_()
    return out


def gated(source: str, tau: float) -> dict:
    """Checkpoint ``source``'s network with the history gate of time constant ``tau``
    (``model.context_gate``; the history channel added to its input if it has none, its
    columns zero, so only the gate changes what it computes)."""
    import dataclasses

    from esim_lite.core.dataconf import from_mapping, to_mapping, to_yaml
    from model import checkpoint
    from model.archs.e2sri_arch import E2SRI, NetConfig
    from model.training.warm_start import warm_start

    ckpt = checkpoint.load(source)
    cfg = checkpoint.config_of(ckpt, source)
    old = from_mapping(NetConfig, ckpt["net"], source=source)  # the config, not a network
    history = old.history if tau in old.history else old.history + (float(tau),)
    if old.history and history != old.history:
        raise ValueError(f"its event history ({list(old.history)}) has no time constant {tau}")
    net = E2SRI(dataclasses.replace(old, history=history, context_gate=float(tau)))
    warm_start(net, source)
    return {**ckpt, "model": net.state_dict(), "net": to_mapping(net.config),
            "config": to_yaml(dataclasses.replace(cfg, model=net.config))}


def rows(path: Path, **match: str) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return [r for r in csv.DictReader(fh) if all(r.get(k) == v for k, v in match.items())]


def num(row: dict[str, str] | None, key: str) -> str:
    if row is None or not row.get(key):
        return "-"
    return f"{float(row[key]):.3f}"


def run(cmd: list[str]) -> None:
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"{shlex.join(cmd)} failed:\n{done.stderr[-2000:]}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("checkpoint")
    p.add_argument("--static", required=True, help="a static-camera test split (folder)")
    p.add_argument("--real", default="../shared/real_events",
                   help="real recordings folder (skipped when absent)")
    p.add_argument("--out", default="out/context_ablation")
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    p.add_argument("--gate", type=float, action="append", default=[], metavar="TAU",
                   help="add the variant gate-TAU: the far path gated by the event history")
    p.add_argument("--every", type=int, default=4)
    args = p.parse_args(argv)

    from model import checkpoint

    t0 = time.perf_counter()
    out = Path(args.out)
    try:
        ckpt = checkpoint.load(args.checkpoint)
        variants = {v: ablated(ckpt, v) for v in args.variants}
        variants.update({f"gate-{t:g}": gated(args.checkpoint, t) for t in args.gate})
    except (OSError, ValueError) as exc:
        print(f"context_ablation: {args.checkpoint}: {exc}", file=sys.stderr)
        return 2
    if not Path(args.static).is_dir():
        print(f"context_ablation: {args.static}: no such split", file=sys.stderr)
        return 2
    real = Path(args.real).is_dir()
    evaluate = str(Path(sys.executable).with_name("evaluate"))
    bench_real = str(Path(__file__).with_name("bench_real.py"))
    table = []
    for name, state in variants.items():
        d = out / name
        d.mkdir(parents=True, exist_ok=True)
        path = checkpoint.save(d / "model.pt", **state)
        common = [evaluate, "--checkpoint", str(path), "--data", args.static, "--split", "all",
                  "--every", str(args.every), "--no-temporal"]
        try:
            run(common + ["--normalize", "observed", "--out", str(d / "static_observed")])
            run(common + ["--normalize", "affine", "--no-baselines",
                          "--out", str(d / "static_affine")])
            if real:
                run([sys.executable, bench_real, "--checkpoint", str(path), "--folder", args.real,
                     "--out", str(d / "real")])
        except RuntimeError as exc:
            print(f"context_ablation: {exc}", file=sys.stderr)
            return 1
        obs = rows(d / "static_observed" / "metrics.csv", sequence="average", protocol="hr",
                   method="ours")
        aff = rows(d / "static_affine" / "metrics.csv", sequence="average", protocol="hr",
                   method="ours")
        line = [name, *(num(obs[0] if obs else None, k) for k in ("ssim", "lpips", "invented")),
                *(num(aff[0] if aff else None, k) for k in ("psnr", "lpips"))]
        for rec in ("davis346/street", "davis346/robot_arm"):
            got = {n: rows(d / "real" / "real_benchmark.csv", sequence=rec, normalize=n,
                           method="ours") if real else [] for n in ("evreal", "observed")}
            ev, ob = (got[n][0] if got[n] else None for n in ("evreal", "observed"))
            line += [f"{num(ev, 'ssim')} / {num(ev, 'lpips')}", num(ob, "invented")]
        table.append(line)

    cmd = shlex.join(["python", "bench/context_ablation.py",
                      *(sys.argv[1:] if argv is None else argv)])
    print(f"`{cmd}` ({time.perf_counter() - t0:.0f} s)\n")
    print("| variant | static observed SSIM | LPIPS | invented | static affine PSNR | LPIPS "
          "| street EVREAL SSIM / LPIPS | street invented | robot_arm EVREAL SSIM / LPIPS "
          "| robot_arm invented |")
    print("|" + "---|" * 10)
    for line in table:
        print("| " + " | ".join(line) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
