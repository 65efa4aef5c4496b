"""Halo probe (issue 23): why dark objects on a bright ground get halos.

Run: .venv/bin/python bench/bench_halo.py --out out/halo [--quick]
         [--model NAME=CKPT ...] [--ecd DIR] [--threads 1]

1. Simulated oracle: a camera moving over posters of dark shapes on a bright ground (the
   ECD ``shapes`` scene), exact ground truth; signed error ``output - truth`` in rings
   around the shapes (LR px from the boundary), inside them, far from them, and over the
   pixels the shapes left during the stacks' time window (``trail``). One factor at a time:
   model, sensor (clean / the DAVIS240C preset / the realistic recipe's ranges), events per
   stack (x 0.25 .. 2 of training's 9,000), normalisation (raw output, clip = what
   ``reconstruct`` writes and EVREAL scores, affine fit, minmax), shape darkness, ground
   texture and camera speed.
2. The ECD ``shapes_*`` snippets at several events per stack: a figure and a label-free
   statistic (output level in the rings around Otsu-segmented dark shapes, relative to the
   far background, as a fraction of the contrast), checked first on the simulated outputs.
3. The loss: L1 and LPIPS of the outputs with and without their ring errors, and the sign
   of LPIPS' gradient in the rings.

Markdown tables on stdout (the command first), figures in ``--out``. Metric code:
:mod:`model.inference.halo_probe`.
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ECD = ROOT.parent / "shared" / "real_events" / "ecd_snippets"
TRAINED_PER_STACK = 9000
NORMS = ("raw", "clip", "affine", "minmax")
RINGS_SHOWN = ("inside", "out 0-1", "out 1-2", "out 2-5", "out 5-10", "far >12")


# ------------------------------------------------------------------ helpers


def _fmt(v: float, signed: bool = True) -> str:
    if v is None or not np.isfinite(v):
        return "-"
    return f"{v:+.3f}" if signed else f"{v:.3f}"


def _mean(rows: list[dict], key: str) -> float:
    vals = [r[key] for r in rows if key in r and np.isfinite(r[key])]
    return float(np.mean(vals)) if vals else math.nan


def _group(rows: list[dict], keys: tuple[str, ...]) -> dict[tuple, list[dict]]:
    out: dict[tuple, list[dict]] = defaultdict(list)
    for r in rows:
        out[tuple(r[k] for k in keys)].append(r)
    return out


def _table(header: list[str], lines: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(c) + " |" for c in lines]
    return "\n".join(out)


def _signed_rgb(err: np.ndarray, span: float = 0.5) -> np.ndarray:
    """uint8[H, W, 3]: red where ``err`` > 0 (too bright), blue where < 0, white at 0."""
    a = np.clip(err / span, -1, 1)[..., None]
    white = np.ones(err.shape + (3,), np.float32)
    red, blue = np.array([0.85, 0.1, 0.1]), np.array([0.1, 0.2, 0.9])
    rgb = np.where(a > 0, white * (1 - a) + red * a, white * (1 + a) - blue * a)
    return (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)


# ------------------------------------------------------------------ setup


def sensors(names: list[str]):
    """name -> (SimulationConfig, SensorRanges or None)."""
    from datagen.config import DatagenConfig
    from esim_lite.core.dataconf import load_config

    base = ROOT / "configs"
    layers = {"clean": [base / "datagen.yaml"],
              "davis240c": [base / "datagen.yaml", base / "sensors" / "davis240c.yaml"],
              "recipe": [base / "datagen.yaml", base / "datagen_realistic.yaml"]}
    out = {}
    for n in names:
        cfg = load_config(DatagenConfig, layers[n])
        out[n] = (cfg.simulation, cfg.sensor_ranges if n == "recipe" else None)
    return out


def make_sequences(sensor: str, sim, ranges, spec, n_seq: int, seed: int, min_events: int,
                   duration_s: float):
    import dataclasses

    from model.inference.halo_probe import probe_simulation, simulate_poster

    seqs = []
    for i in range(n_seq):
        s = probe_simulation(sim, duration_s)
        if ranges is not None:  # the recipe draws each sequence's sensor from its ranges
            s = dataclasses.replace(s, events=ranges.draw(s.events, np.random.default_rng(
                [seed, i, 7])))
        seqs.append(simulate_poster(spec, s, np.random.default_rng([seed, i]), min_events))
    return seqs


def anchors_of(n_events: int, max_per_stack: int, n_out: int) -> list[int]:
    lo, hi = 2 * max_per_stack, n_events - max_per_stack
    if hi < lo:
        return []
    return sorted({int(a) for a in np.linspace(lo, hi, n_out + 2)[1:-1]})


def warm_memory(model, window, ev, anchor: int, per_stack: int) -> None:
    """A model with memory across outputs (``model.memory``) first sees the outputs of the
    ``per_stack`` events before ``anchor`` (up to 8), as ``reconstruct`` would have run it;
    any other model is left as it is."""
    from model.inference.halo_probe import memory_anchors, raw_output

    model.reset()
    if not model.net.config.memory:
        return
    for a in memory_anchors(anchor, per_stack, model.net.config.n_stacks):
        given = model.stacks_at(window, int(ev.t_ns[a - 1]))
        raw_output(model, given.stacks, given.history)


# ------------------------------------------------------------------ simulated oracle


def probe_sequences(seqs, models: dict, factors: list[float], n_out: int, tag: dict,
                    keep_examples: bool = False) -> tuple[list[dict], list[dict]]:
    """Rows of ring errors for every sequence x output x model x events per stack x
    normalisation; and (with ``keep_examples``) the images of each sequence's first output."""
    from model.inference.evaluate import normalized
    from model.inference.halo_probe import (
        border_mask,
        raw_output,
        ring_errors,
        ring_masks,
        self_rings,
        stack_window,
        swept_error,
    )
    from model.inference.reconstruct import EventWindow
    from model.inference.stack_size import activity_of

    per_stack = {f: int(round(TRAINED_PER_STACK * f)) for f in factors}
    rows, examples = [], []
    for si, seq in enumerate(seqs):
        ev, hw = seq.events, seq.events.sensor_hw
        anchors = anchors_of(len(ev), max(per_stack.values()), n_out)
        active = activity_of(ev)
        t_out = [int(ev.t_ns[a - 1]) for a in anchors]
        gts = seq.render_hr(t_out)
        for oi, (a, t, gt) in enumerate(zip(anchors, t_out, gts)):
            dark = seq.dark_mask(gt)
            valid = border_mask(gt.shape, 2 * 8)
            masks = ring_masks(dark, seq.scale, valid)
            for f, n in per_stack.items():
                win = stack_window(a, n)
                t_first = int(ev.t_ns[win.first])
                t_before = np.linspace(t_first, t, 6)[:-1].astype(np.int64)
                past = [seq.dark_mask(g) for g in seq.render_hr(t_before)]
                t_central = int(ev.t_ns[a - n])
                base = dict(tag, seq=si, out=oi, factor=f, per_stack=n,
                            active_frac=active.fraction,
                            span_ms=(int(ev.t_ns[win.last - 1]) - t_first) * 1e-6,
                            central_ms=(t - t_central) * 1e-6,
                            motion_px=seq.motion_px(t_central, t))
                for mname, model in models.items():
                    m = model.with_stacks(n)
                    window = EventWindow(iter([ev]), hw, history=bool(m.net.config.history))
                    warm_memory(m, window, ev, a, n)
                    given = m.stacks_at(window, t)
                    raw = raw_output(m, given.stacks, given.history)
                    for norm in NORMS:
                        if norm == "raw":
                            pred, target = raw, gt
                        elif norm == "clip":
                            pred, target = np.clip(raw, 0, 1), gt
                        else:
                            pred, target = normalized(raw, gt, norm)
                        r = dict(base, model=mname, norm=norm,
                                 **ring_errors(pred, target, masks),
                                 trail=swept_error(pred, target, dark, past, valid))
                        if norm == "clip":
                            r.update({f"self {k}": v for k, v in
                                      self_rings(pred, seq.scale, 16).items()})
                            r.update({f"gtself {k}": v for k, v in
                                      self_rings(gt, seq.scale, 16).items()})
                        rows.append(r)
                    if keep_examples and oi == 0:
                        examples.append(dict(seq=si, model=mname, factor=f, gt=gt,
                                             out=np.clip(raw, 0, 1), masks=masks,
                                             dark=dark,
                                             events=window.slice(a - n, a)[0]))
    return rows, examples


def ring_table(rows: list[dict], keys: tuple[str, ...], extra: tuple[str, ...] = ()) -> str:
    header = list(keys) + list(extra) + list(RINGS_SHOWN) + ["trail", "n"]
    lines = []
    for k, g in _group(rows, keys).items():
        cells = [str(x) for x in k]
        cells += [f"{_mean(g, e):,.0f}" if e == "per_stack" else _fmt(_mean(g, e), False)
                  for e in extra]
        cells += [_fmt(_mean(g, ring)) for ring in RINGS_SHOWN + ("trail",)]
        lines.append(cells + [str(len(g))])
    return _table(header, lines)


# ------------------------------------------------------------------ real snippets


def ecd_probe(models: dict, folder: Path, names: list[str], factors: list[float],
              n_out: int, out: Path):
    from datagen.recording import open_recording
    from esim_lite.core.figures import contact_sheet, event_image, gray_to_rgb, write_png
    from model.inference.evaluate import normalized
    from model.inference.halo_probe import raw_output, self_rings, stack_window
    from model.inference.reconstruct import EventWindow
    from model.inference.stack_size import activity_of, choose_stack

    rows, fig_rows = [], []
    for name in names:
        rec = open_recording(folder / name, (180, 240))
        ev = rec.read_all()
        act = activity_of(ev)
        rule = choose_stack(3000, 3, (128, 128), (180, 240), None, act).events_per_stack
        sizes = [("active", rule)] + [(f"x{f:g}", int(round(rule * f))) for f in factors
                                      if f != 1.0] + [("area", 23730)]
        for mname, model in models.items():
            row = [(event_image(ev.slice(len(ev) // 2 - rule, len(ev) // 2)),
                    f"{name}: events ({rule:,})")]
            for label, n in sizes:
                m = model.with_stacks(n)
                fit = anchors_of(len(ev), n, n_out)
                anchors = fit or [len(ev) // 2]  # too few events: partial stacks (as evaluate)
                stats, shown = [], None
                for a in anchors:
                    window = EventWindow(iter([ev]), ev.sensor_hw,
                                         history=bool(m.net.config.history))
                    t = int(ev.t_ns[a - 1])
                    warm_memory(m, window, ev, a, n)
                    given = m.stacks_at(window, t)
                    img = np.clip(raw_output(m, given.stacks, given.history), 0, 1)
                    stats.append(self_rings(img, 2, 16))
                    shown = img if shown is None else shown
                win = stack_window(anchors[0], n)
                span = (int(ev.t_ns[min(win.last, len(ev)) - 1])
                        - int(ev.t_ns[max(win.first, 0)])) * 1e-6
                r = dict(recording=name, model=mname, rule=label, per_stack=n,
                         outputs=len(anchors), full=bool(fit), span_ms=span)
                for k in stats[0]:
                    r[k] = float(np.nanmean([s[k] for s in stats]))
                rows.append(r)
                row.append((gray_to_rgb(normalized(shown, shown, "minmax")[0]),
                            f"{mname} {label} {n:,} ({span:.0f} ms)"))
            fig_rows.append(row)
    path = write_png(out / "ecd_shapes_eps.png", contact_sheet(
        fig_rows, "ECD shapes snippets: one output per events-per-stack (1..99 percentile "
        "display stretch, as docs/figures)", 180))
    return rows, path


# ------------------------------------------------------------------ loss


def loss_probe(examples: list[dict], lpips_weight: float = 0.3) -> list[dict]:
    """L1 and LPIPS (128x128 HR tiles, as the training crops) of each example output, of
    the output with its mean ring errors removed, and the descent direction of LPIPS and
    of L1 + w LPIPS averaged over each ring."""
    import torch

    from model.inference.halo_probe import boundary_distance
    from model.losses.lpips import LPIPS

    net = LPIPS()
    rows = []

    def tiles(x):
        h, w = x.shape[-2:]
        return torch.cat([x[..., i:i + 128, j:j + 128] for i in range(0, h - 127, 128)
                          for j in range(0, w - 127, 128)])

    for ex in examples:
        gt, out, masks = ex["gt"], ex["out"], ex["masks"]
        # the mean error as a smooth function of the distance outside the shapes (linear
        # between ring centres): subtracting it adds no steps at the ring borders
        outside, _ = boundary_distance(ex["dark"], 2)
        centres, errs = [], []
        for ring, c in (("out 0-1", 0.5), ("out 1-2", 1.5), ("out 2-5", 3.5),
                        ("out 5-10", 7.5), ("far >12", 14.0)):
            if masks[ring].sum():
                centres.append(c)
                errs.append(float((out - gt)[masks[ring]].mean()))
        profile = np.where(ex["dark"], 0.0, np.interp(outside, centres, errs)).astype(np.float32)
        far = errs[-1]
        no_halo = np.clip(out - np.where(ex["dark"], 0.0, profile - far), 0, 1).astype(np.float32)
        no_profile = np.clip(out - profile, 0, 1).astype(np.float32)
        g = torch.from_numpy(gt)[None, None]
        for label, img in (("output", out), ("halo removed (near = far)", no_halo),
                           ("all ring errors removed", no_profile)):
            x = torch.from_numpy(img)[None, None].clone().requires_grad_(True)
            lp = net(tiles(x), tiles(g)).mean()
            l1 = (x - g).abs().mean()
            grad = torch.autograd.grad(lp, x)[0][0, 0].numpy()
            l1, lp = float(l1.detach()), float(lp.detach())
            r = dict(model=ex["model"], factor=ex["factor"], image=label, l1=l1, lpips=lp,
                     loss=l1 + lpips_weight * lp)
            for ring in ("out 1-2", "out 2-5", "far >12"):
                m = masks[ring]
                r[f"-dLPIPS {ring}"] = float(-grad[m].mean() * 1e4) if m.sum() else math.nan
            rows.append(r)
    return rows


# ------------------------------------------------------------------ figure


def sim_figure(examples: list[dict], out: Path, seq: int = 0) -> Path:
    from esim_lite.core.figures import contact_sheet, event_image, gray_to_rgb, write_png

    rows = []
    chosen = [e for e in examples if e["seq"] == seq]
    for mname in dict.fromkeys(e["model"] for e in chosen):
        row, err_row = [], []
        for e in [e for e in chosen if e["model"] == mname]:
            if not row:
                row.append((gray_to_rgb(e["gt"]), "ground truth"))
                err_row.append((event_image(e["events"]), "central stack (x1)"))
            row.append((gray_to_rgb(e["out"]), f"{mname} x{e['factor']:g} (clip)"))
            err_row.append((_signed_rgb(e["out"] - e["gt"]), "error (red +, blue -; +-0.5)"))
        rows += [row, err_row]
    return write_png(out / f"sim_seq{seq}.png", contact_sheet(
        rows, "simulated poster: outputs per events-per-stack factor (of 9,000) and signed "
        "error", 200))


# ------------------------------------------------------------------ main


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="out/halo", help="folder for the figures")
    p.add_argument("--quick", action="store_true", help="1 sequence per setting, fewer "
                   "factors (about a minute)")
    p.add_argument("--model", action="append", metavar="NAME=CKPT",
                   help="models to compare (default: shipped=the shipped x2 and, if there, "
                   "x2_real=runs/x2_real/last.pt)")
    p.add_argument("--ecd", default=str(ECD), help="the ECD snippets folder")
    p.add_argument("--seqs", type=int, help="sequences per setting (default 3; quick 1)")
    p.add_argument("--outputs", type=int, default=3, help="outputs per sequence")
    p.add_argument("--seed", type=int, default=23)
    p.add_argument("--threads", type=int, default=1, help="torch / numba / OpenCV threads")
    args = p.parse_args(argv)
    command = " ".join([".venv/bin/python bench/bench_halo.py",
                        shlex.join(sys.argv[1:] if argv is None else argv)]).strip()
    print(f"Command: `{command}`\n")

    import cv2
    import numba
    import torch

    torch.set_num_threads(args.threads)
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    cv2.setNumThreads(args.threads)
    from model.inference.halo_probe import PosterSpec
    from model.inference.pretrained import resolve
    from model.inference.reconstruct import Reconstructor

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    specs = args.model or [f"shipped={resolve(None, 2)}"] + (
        [f"x2_real={ROOT / 'runs/x2_real/last.pt'}"]
        if (ROOT / "runs/x2_real/last.pt").is_file() else [])
    models = {}
    for s in specs:
        name, _, path = s.partition("=")
        models[name] = Reconstructor.load(path, (128, 128), events_per_stack=TRAINED_PER_STACK,
                                          device="cpu", engine="torch")
        print(f"- model `{name}`: {path}")
    quick = args.quick
    n_seq = args.seqs or (1 if quick else 3)
    factors = [0.25, 1.0, 2.0] if quick else [0.25, 0.5, 1.0, 2.0]
    sensor_names = ["clean", "davis240c"] if quick else ["clean", "davis240c", "recipe"]
    need = int(3 * TRAINED_PER_STACK * max(factors) + 4 * TRAINED_PER_STACK)
    start = time.perf_counter()

    # 1a-d: model x sensor x events per stack x normalisation
    rows, examples = [], []
    for sname, (sim, ranges) in sensors(sensor_names).items():
        seqs = make_sequences(sname, sim, ranges, PosterSpec(), n_seq, args.seed, need, 3.0)
        r, ex = probe_sequences(seqs, models, factors, args.outputs, dict(sensor=sname),
                                keep_examples=sname == "clean")
        rows += r
        examples += ex
    print(f"\n(simulated grid: {time.perf_counter() - start:.0f} s)\n")
    clip = [r for r in rows if r["norm"] == "clip"]
    print("## 1. Simulated posters: signed error (output - truth) per ring, clip "
          "normalisation\n")
    print("Rings in LR px from the shapes' boundary; `trail`: pixels a shape covered during "
          "the stacks' window but not at the output time; `motion_px`: median image motion "
          "during the central stack; `active_frac`: the active-pixel rule's fraction.\n")
    print(ring_table(clip, ("model", "sensor", "factor"),
                     ("per_stack", "central_ms", "motion_px", "active_frac")))
    print("\n## 2. Normalisations (factor 1 = 9,000 events per stack)\n")
    one = [r for r in rows if r["factor"] == 1.0]
    print(ring_table(one, ("model", "sensor", "norm")))
    print("\n## 3. Label-free statistic on the same simulated outputs (clip)\n")
    print("Output level in each ring around Otsu-segmented dark shapes minus the far "
          "background's, / (far - inside); `gt` row: the same on the ground truth.\n")
    keys = ("inside", "out 1-2", "out 2-5", "out 5-10")
    lines = []
    for k, g in _group(clip, ("model", "sensor", "factor")).items():
        lines.append([*map(str, k)] + [_fmt(_mean(g, f"self {x}")) for x in keys])
    lines.append(["gt", "all", "-"] + [_fmt(_mean(clip, f"gtself {x}")) for x in keys])
    print(_table(["model", "sensor", "factor"] + list(keys), lines))
    fig = sim_figure(examples, out)
    print(f"\nFigure: {fig}")

    # 1e: darkness, ground texture, speed (first model, clean sensor)
    first = {k: models[k] for k in list(models)[:1]}
    variants = [("dark 0.05 (base)", PosterSpec()), ("dark 0.3", PosterSpec(dark=0.3)),
                ("dark 0.55", PosterSpec(dark=0.55)),
                ("textured ground 0.15", PosterSpec(texture_amp=0.15)),
                ("speed x3", PosterSpec(speed=3.0))]
    if quick:
        variants = variants[1:3]
    vf = [1.0] if quick else [0.25, 1.0]
    sim, ranges = sensors(["clean"])["clean"]
    vrows = []
    for label, spec in variants:
        seqs = make_sequences("clean", sim, ranges, spec, n_seq, args.seed,
                              int(3 * TRAINED_PER_STACK * max(vf) + 4 * TRAINED_PER_STACK),
                              8.0)
        r, _ = probe_sequences(seqs, first, vf, args.outputs, dict(scene=label))
        vrows += [x for x in r if x["norm"] == "clip"]
    print(f"\n## 4. Scene variants ({list(first)[0]}, clean sensor, clip)\n")
    print(ring_table(vrows, ("scene", "factor"), ("central_ms", "motion_px")))

    # 1e (bis): is the event-free level a constant prior? vary the true ground level
    grounds = [(0.3, 0.02), (0.5, 0.05), (0.8, 0.05), (0.95, 0.05), (0.2, 0.8)]
    if quick:
        grounds = [(0.3, 0.02), (0.95, 0.05)]
    grows = []
    for ground, shade in grounds:
        seqs = make_sequences("clean", sim, ranges, PosterSpec(background=ground, dark=shade),
                              n_seq, args.seed, int(3 * TRAINED_PER_STACK * max(vf)
                                                    + 4 * TRAINED_PER_STACK), 8.0)
        r, _ = probe_sequences(seqs, models, vf, args.outputs,
                               dict(ground=ground, shapes=shade))
        grows += [x for x in r if x["norm"] == "clip"]
    print("\n## 4b. Output level (clip) per ring against the true ground level (clean "
          "sensor)\n")
    print("Levels, not errors: ring error + the true level (shapes inside, ground outside). "
          "The last row has light shapes on a dark ground.\n")
    lines = []
    for k, g in _group(grows, ("model", "ground", "shapes", "factor")).items():
        ground, shade = k[1], k[2]
        lines.append([*map(str, k)] + [f"{_mean(g, 'inside') + shade:.3f}"]
                     + [f"{_mean(g, ring) + ground:.3f}"
                        for ring in ("out 1-2", "out 2-5", "out 5-10", "far >12")])
    print(_table(["model", "ground", "shapes", "factor", "inside", "out 1-2", "out 2-5",
                  "out 5-10", "far >12"], lines))

    # 2: real snippets
    folder = Path(args.ecd)
    if folder.is_dir():
        names = ["shapes_translation"] if quick else ["shapes_rotation", "shapes_translation"]
        erows, path = ecd_probe(models, folder, names, [0.25, 0.5, 1.0, 2.0], 2 if quick else 3,
                                out)
        print("\n## 5. ECD shapes snippets: label-free statistic per events per stack\n")
        header = ["recording", "model", "rule", "per_stack", "span_ms", "outputs"] + \
            list(keys)
        lines = [[r["recording"], r["model"], r["rule"], f"{r['per_stack']:,}",
                  f"{r['span_ms']:.0f}", f"{r['outputs']}{'' if r['full'] else ' (partial)'}"]
                 + [_fmt(r[k]) for k in keys] for r in erows]
        print(_table(header, lines))
        print(f"\nFigure: {path}")
    else:
        print(f"\n(ECD snippets not found at {folder}: section 5 skipped)")

    # 3: loss
    lrows = loss_probe([e for e in examples if e["factor"] == 1.0])
    print("\n## 6. Loss: the outputs with and without their ring errors (128x128 HR tiles)\n")
    print("`halo removed`: the output minus its mean error profile over the distance "
          "outside the shapes, relative to the far background's (near rings brought to the "
          "far level); `all ring errors removed`: minus the whole profile.\n")
    print("`-dLPIPS`: minus LPIPS' gradient (x1e4) averaged over a ring: > 0 means LPIPS "
          "would brighten those pixels.\n")
    lk = ["l1", "lpips", "loss", "-dLPIPS out 1-2", "-dLPIPS out 2-5", "-dLPIPS far >12"]
    lines = [[*map(str, k)] + [_fmt(_mean(g, c), signed=c.startswith("-")) for c in lk]
             for k, g in _group(lrows, ("model", "image")).items()]
    print(_table(["model", "image"] + lk, lines))
    print(f"\n(total {time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
