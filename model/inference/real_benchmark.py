"""The real-data benchmark: every real recording of a folder through one model.

Layout of the folder (``../shared/real_events`` beside the repository by default), searched
at any depth: ``*.aedat4`` files (events and APS frames) and folders holding ``events.txt``
with ``images.txt`` (and ``exposures.txt``, :mod:`datagen.formats.ecd_text`) are scored;
folders with ``events.txt`` alone (the 240x180 ECD snippets, no frames) are shown in the
figure, not scored. Each recording is run once
(:func:`model.inference.evaluate.recording_outputs`, events per stack chosen for it, every
method's outputs averaged over each APS exposure) and scored by the verdict of
:mod:`model.inference.scene_motion`, measured from its events:

- ``moving: whole frame`` (the scene moves across most of the frame): whole-frame PSNR,
  SSIM and LPIPS under EVREAL's protocol and the affine fit;
- ``static camera: observed region`` (the background never fires, so a whole-frame texture
  metric rewards painting what no event saw): the affine fit inside the observed region
  (:mod:`model.inference.observed`) with ``invented``, plus whole-frame PSNR and SSIM under
  both whole-frame normalisations for reference, and no whole-frame LPIPS.

One table (``real_benchmark.md`` and ``.csv``) and one figure (``real_benchmark.png``).
Beside the methods, two images with no information about the recording
(:mod:`model.inference.references`) show each metric's floor, and over whole frames three
ceilings the best an output that knew only what fired could do.
"""

from __future__ import annotations

import csv
import io
import time
from dataclasses import dataclass, replace
from pathlib import Path

from datagen.recording import open_recording
from esim_lite.core.atomic import write_text
from model.inference.evaluate import (
    EvalOptions,
    ModelPool,
    SequenceOutputs,
    average_rows,
    recording_outputs,
    score,
    write_figure,
)
from model.inference.exposure import exposure_stats
from model.inference.observed import INVENTED_STEP
from model.inference.quantize import CalibrationSource
from model.inference.references import CEILINGS, SALT_AMPLITUDE, SALT_FRACTION
from model.inference.scene_motion import (
    MOVING,
    MOVING_SHARE,
    STATIC,
    SWING_EVENTS,
    SceneMotion,
    measure_scene_motion,
)
from model.losses.lpips import LPIPS

ECD_SENSOR_HW = (180, 240)
NORMALIZATIONS = ("evreal", "affine", "observed")
#: The normalisations that score whole frames.
WHOLE_FRAME = ("evreal", "affine")
METRICS = ("psnr", "ssim", "mse", "lpips", "ewarp", "coverage", "invented")


@dataclass(frozen=True)
class RealRecordings:
    """The recordings of a real-recordings folder: ``scored`` (AEDAT4 files and text
    folders with ``images.txt``) and ``shown`` (``events.txt`` files without frames)."""

    folder: Path
    scored: tuple[Path, ...]
    shown: tuple[Path, ...]


def find_recordings(folder: str | Path) -> RealRecordings:
    """The recordings anywhere under ``folder`` (see the module doc), sorted by path.

    Raises:
        FileNotFoundError: ``folder`` is not a folder, or holds none of those files.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder of real recordings")
    texts = sorted(folder.rglob("events.txt"))
    with_frames = [p.parent for p in texts if (p.parent / "images.txt").is_file()]
    found = RealRecordings(folder, tuple(sorted([*folder.rglob("*.aedat4"), *with_frames])),
                           tuple(p for p in texts if p.parent not in with_frames))
    if not found.scored and not found.shown:
        raise FileNotFoundError(f"{folder}: no *.aedat4 file and no events.txt in it or "
                                f"below it")
    return found


@dataclass(frozen=True)
class RecordingReport:
    """What the benchmark did with one recording: events per stack (and their rule), its
    APS exposures (None without), how many outputs were averaged per scored frame, and for a
    scored one its scene motion (the verdict that chose the scores)."""

    name: str
    scored: bool
    stacks: str
    exposures: str | None
    averaged: tuple[int, ...]
    motion: SceneMotion | None = None


@dataclass(frozen=True)
class BenchmarkResult:
    rows: list[dict]
    recordings: list[RecordingReport]
    table: Path
    csv: Path
    figure: Path
    seconds: float


def recording_name(path: Path) -> str:
    """``davis346/street`` (a file), ``davis346_esl/checkerboard`` (a text folder) or
    ``ecd/shapes_rotation`` (an ``events.txt`` without frames)."""
    if path.name == "events.txt":
        return f"ecd/{path.parent.name}"
    return f"{path.parent.name}/{path.stem if path.is_file() else path.name}"


def run_benchmark(ckpt: str | Path, folder: str | Path, out: str | Path,
                  options: EvalOptions | None = None, engine: str = "auto",
                  command: str = "", calibrate: CalibrationSource | None = None,
                  model_only: bool = False) -> BenchmarkResult:
    """Run and score every recording of ``folder`` (:func:`find_recordings`) with the model
    ``ckpt``; ``options.normalize`` is ignored (each recording's verdict picks the
    normalisations, :func:`score_all`; default options average over the APS exposures).
    Writes ``real_benchmark.md``, ``.csv`` and ``.png`` into ``out``; ``command`` is quoted
    at the top of the table; ``calibrate``: for an ``openvino-int8`` engine."""
    start = time.perf_counter()
    found = find_recordings(folder)
    options = options or EvalOptions(exposure_average=True)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    pool = ModelPool(ckpt, options, engine=engine, calibrate=calibrate)
    sequences, reports, engines = [], [], set()
    for path, hw in [(p, None) for p in found.scored] + [(p, ECD_SENSOR_HW) for p in found.shown]:
        rec = open_recording(path, hw)
        model = pool.for_recording(rec)
        engines.add(model.engine_name)
        seq = recording_outputs(rec, model, options, recording_name(path))
        stats = exposure_stats(rec)
        sequences.append(seq)
        motion = measure_scene_motion(rec) if seq.lr_targets else None
        reports.append(RecordingReport(seq.name, bool(seq.lr_targets),
                                       model.stack_choice.describe(),
                                       None if stats is None else stats.describe(),
                                       tuple(seq.averaged), motion))
    motions = {r.name: r.motion for r in reports if r.motion is not None}
    rows = score_all(sequences, motions, pool.config.model.scale, options, model_only)
    seconds = time.perf_counter() - start
    table, table_csv = out / "real_benchmark.md", out / "real_benchmark.csv"
    used = f"{engine} ({', '.join(sorted(engines))})" if engine == "auto" else engine
    write_text(table, benchmark_markdown(rows, reports, options, ckpt, used, command, seconds))
    write_text(table_csv, benchmark_csv(rows))
    figure = write_figure(sequences, out / "real_benchmark.png", pool.config.model.scale)
    return BenchmarkResult(rows, reports, table, table_csv, figure, seconds)


def score_all(sequences: list[SequenceOutputs], motions: dict[str, SceneMotion], scale: int,
              options: EvalOptions, model_only: bool = False) -> list[dict]:
    """Rows of :func:`score` for the scored sequences, each tagged with its ``normalize``
    and ``verdict`` (``motions``: by sequence name): a moving scene's under the whole-frame
    :data:`WHOLE_FRAME` normalisations with LPIPS, a static camera's under those without
    LPIPS and under ``observed``; per verdict and normalisation, the average over its
    recordings when it has several. ``model_only``: without the floors and ceilings (they
    do not depend on the model)."""
    lpips_net = LPIPS()
    rows = []
    for verdict in (MOVING, STATIC):
        group = [s for s in sequences if s.lr_targets and motions[s.name].verdict == verdict]
        if group:
            moving = verdict == MOVING
            part = _score_group(group, scale, options, lpips_net if moving else None,
                                lpips_net, WHOLE_FRAME if moving else NORMALIZATIONS,
                                model_only)
            rows += [{"verdict": verdict, **({"swept": motions[r["sequence"]].swept_share}
                                             if r["sequence"] in motions else {}), **r}
                     for r in part]
    return rows


def _score_group(sequences: list[SequenceOutputs], scale: int, options: EvalOptions,
                 whole_lpips: LPIPS | None, region_lpips: LPIPS, norms: tuple[str, ...],
                 model_only: bool = False) -> list[dict]:
    """Rows of :func:`score` (plus per-method averages over ``sequences``) under each of
    ``norms``; LPIPS over whole frames only with ``whole_lpips``; without the floors and
    ceilings with ``model_only``."""
    rows, ceilings = [], None
    order = {s.name: i for i, s in enumerate(sequences)}
    for norm in norms:
        # the ceilings are compared as they are: one set of rows serves every whole-frame
        # normalisation (the harmonic one is a Laplace solve per frame)
        opts = replace(options, normalize=norm, references=not model_only,
                       ceilings=ceilings is None and not model_only)
        net = region_lpips if norm == "observed" else whole_lpips
        part = [r for s in sequences for r in score(s, scale, opts, net)]
        if norm != "observed":
            if ceilings is None:
                ceilings = [r for r in part if r["method"] in CEILINGS]
            else:
                part = sorted(part + [dict(r) for r in ceilings],
                              key=lambda r: order[r["sequence"]])
        if len({r["sequence"] for r in part}) > 1:
            part += average_rows(part)
        rows += [{"normalize": norm, **r} for r in part]
    return rows


def benchmark_csv(rows: list[dict]) -> str:
    cols = ["sequence", "verdict", "swept", "normalize", "protocol", "method", "frames",
            *METRICS]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: r.get(k, "") for k in cols})
    return buf.getvalue()


def benchmark_markdown(rows: list[dict], reports: list[RecordingReport],
                       options: EvalOptions, ckpt: str | Path, engine: str, command: str,
                       seconds: float) -> str:
    averaging = "on" if options.exposure_average else "off"
    lines = ["## Real-data benchmark", ""]
    if command:
        lines += [f"`{command}` ({seconds:.0f} s)", ""]
    lines += [f"Model `{ckpt}`, engine `{engine}`. Output at the sensor size (ours "
              f"area-downsampled) against each APS frame but the first; exposure averaging: "
              f"{averaging} (every method's outputs inside each frame's exposure window "
              f"averaged). Each recording is scored by the verdict of its events: the swept "
              f"share is the share of the pixels whose running polarity sum spans at least "
              f"{SWING_EVENTS} events with at least 2 of their 8 neighbours doing the same "
              f"(flicker swings by one, hot pixels have no neighbours); from "
              f"{100 * MOVING_SHARE:.0f}% the scene moves across most of the frame and is "
              f"scored over whole frames (`{MOVING}`), below it the camera is taken as static "
              f"and scored in the observed region, with whole-frame PSNR and SSIM for "
              f"reference and no whole-frame LPIPS, which rewards texture painted where no "
              f"event fired (`{STATIC}`).", "",
              f"PSNR dB, SSIM, MSE, LPIPS (alex), E_warp x1e-3, region: the share of the frame "
              f"scored, invented: the share of the pixels outside it drawn more than "
              f"{INVENTED_STEP} from their median level (lower is better); `evreal`: EVREAL's "
              f"protocol, `affine`: least-squares scale and offset per frame, `observed`: the "
              f"affine fit and the metrics inside the region where the output's events fired "
              f"with spatial support. `flat` and `salt` carry no information about the "
              f"recording, compared as they are: a grey at the target's mean level (over the "
              f"region under `observed`) and that grey with random dots (+-{SALT_AMPLITUDE}) "
              f"on {100 * SALT_FRACTION:.1f}% of its pixels: the floors. The ceilings (whole "
              f"frames only) are the APS frame itself inside the observed region and "
              f"outside it: one grey at its true mean there (`seen+flat`), its smoothest "
              f"continuation from the region's rim (`seen+harmonic`), or that grey with "
              f"`salt`'s dots (`seen+salt`: no information added; where it beats the other "
              f"two, the metric rewards texture as such).", "",
              "| recording | swept share | verdict | events per stack | APS | outputs averaged "
              "per frame |", "|---|---|---|---|---|---|"]
    for r in reports:
        share, verdict = (("-", "figure only") if r.motion is None else
                          (f"{100 * r.motion.swept_share:.1f}%", r.motion.verdict))
        averaged = f"{min(r.averaged)}-{max(r.averaged)}" if r.averaged else "-"
        lines.append(f"| {r.name} | {share} | {verdict} | {r.stacks} | {r.exposures or '-'} "
                     f"| {averaged} |")
    for verdict, title in ((MOVING, "Moving: whole frame"),
                           (STATIC, "Static camera: observed region (whole-frame PSNR and "
                                    "SSIM for reference)")):
        sel = [r for r in rows if r["verdict"] == verdict]
        if not sel:
            continue
        lines += ["", f"### {title}", "", "| recording | normalisation | method | frames | "
                  "PSNR | SSIM | MSE | LPIPS | E_warp | region | invented |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in sel:
            cells = [f"{r[k]:.4f}" if k in r else "-" for k in METRICS]
            lines.append(f"| {r['sequence']} | {r['normalize']} | {r['method']} | "
                         f"{r['frames']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
