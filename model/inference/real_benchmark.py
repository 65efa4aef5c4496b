"""The real-data benchmark: every real recording of a folder through one model.

Layout of the folder (``../shared/real_events`` beside the repository by default):
``davis346/*.aedat4`` (events and APS frames: scored) and ``ecd_snippets/*/events.txt``
(240x180 events only: shown in the figure, not scored). Each recording is run once
(:func:`model.inference.evaluate.recording_outputs`, events per stack chosen for it) and
the outputs are scored under three normalisations, EVREAL's protocol, the affine fit and
the affine fit inside the observed region (:func:`model.inference.evaluate.score`,
:mod:`model.inference.observed`), into one table (``real_benchmark.md`` and ``.csv``) and
one figure (``real_benchmark.png``). Beside the methods, two images with no information
about the recording (:mod:`model.inference.references`) show each metric's floor.
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
from model.losses.lpips import LPIPS

ECD_SENSOR_HW = (180, 240)
NORMALIZATIONS = ("evreal", "affine", "observed")
METRICS = ("psnr", "ssim", "mse", "lpips", "ewarp", "coverage", "invented")


@dataclass(frozen=True)
class RealRecordings:
    """The files of a real-recordings folder: ``scored`` (AEDAT4 with APS frames) and
    ``shown`` (ECD snippets' ``events.txt``, no frames)."""

    folder: Path
    scored: tuple[Path, ...]
    shown: tuple[Path, ...]


def find_recordings(folder: str | Path) -> RealRecordings:
    """The recordings under ``folder`` (see the module doc).

    Raises:
        FileNotFoundError: ``folder`` is not a folder, or holds none of those files.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder of real recordings")
    found = RealRecordings(folder, tuple(sorted(folder.glob("davis346/*.aedat4"))),
                           tuple(sorted(folder.glob("ecd_snippets/*/events.txt"))))
    if not found.scored and not found.shown:
        raise FileNotFoundError(f"{folder}: neither davis346/*.aedat4 nor "
                                f"ecd_snippets/*/events.txt")
    return found


@dataclass(frozen=True)
class RecordingReport:
    """What the benchmark did with one recording: events per stack (and their rule), its
    APS exposures (None without), how many outputs were averaged per scored frame."""

    name: str
    scored: bool
    stacks: str
    exposures: str | None
    averaged: tuple[int, ...]


@dataclass(frozen=True)
class BenchmarkResult:
    rows: list[dict]
    recordings: list[RecordingReport]
    table: Path
    csv: Path
    figure: Path
    seconds: float


def recording_name(path: Path) -> str:
    """``davis346/street`` or ``ecd/shapes_rotation``."""
    if path.name == "events.txt":
        return f"ecd/{path.parent.name}"
    return f"{path.parent.name}/{path.stem}"


def run_benchmark(ckpt: str | Path, folder: str | Path, out: str | Path,
                  options: EvalOptions | None = None, engine: str = "auto",
                  command: str = "", calibrate: CalibrationSource | None = None,
                  model_only: bool = False) -> BenchmarkResult:
    """Run and score every recording of ``folder`` (:func:`find_recordings`) with the model
    ``ckpt``; ``options.normalize`` is ignored (both of :data:`NORMALIZATIONS` are used;
    default options average over the APS exposures). Writes ``real_benchmark.md``, ``.csv``
    and ``.png`` into ``out``; ``command`` is quoted at the top of the table; ``calibrate``:
    for an ``openvino-int8`` engine."""
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
        reports.append(RecordingReport(seq.name, bool(seq.lr_targets),
                                       model.stack_choice.describe(),
                                       None if stats is None else stats.describe(),
                                       tuple(seq.averaged)))
    rows = score_all(sequences, pool.config.model.scale, options, model_only)
    seconds = time.perf_counter() - start
    table, table_csv = out / "real_benchmark.md", out / "real_benchmark.csv"
    used = f"{engine} ({', '.join(sorted(engines))})" if engine == "auto" else engine
    write_text(table, benchmark_markdown(rows, reports, options, ckpt, used, command, seconds))
    write_text(table_csv, benchmark_csv(rows))
    figure = write_figure(sequences, out / "real_benchmark.png", pool.config.model.scale)
    return BenchmarkResult(rows, reports, table, table_csv, figure, seconds)


def score_all(sequences: list[SequenceOutputs], scale: int, options: EvalOptions,
              model_only: bool = False) -> list[dict]:
    """Rows of :func:`score` (plus per-method averages over recordings) under each of
    :data:`NORMALIZATIONS`, each row tagged with its ``normalize``; ``model_only``: without
    the floors and ceilings (they do not depend on the model)."""
    lpips_net = LPIPS()
    rows, ceilings = [], None
    order = {s.name: i for i, s in enumerate(sequences)}
    for norm in NORMALIZATIONS:
        # the ceilings are compared as they are: one set of rows serves every whole-frame
        # normalisation (the harmonic one is a Laplace solve per frame)
        opts = replace(options, normalize=norm, references=not model_only,
                       ceilings=ceilings is None and not model_only)
        part = [r for s in sequences if s.lr_targets for r in score(s, scale, opts, lpips_net)]
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
    cols = ["sequence", "normalize", "protocol", "method", "frames", *METRICS]
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
              f"area-downsampled) against each APS frame but the first; exposure averaging "
              f"of ours: {averaging} (baselines at the frame's timestamp). PSNR dB, SSIM, MSE, "
              f"LPIPS (alex), E_warp x1e-3, region: the share of the frame scored, invented: "
              f"the share of the pixels outside it drawn more than {INVENTED_STEP} from their "
              f"median level; "
              f"`evreal`: EVREAL's protocol, `affine`: least-squares scale and offset per "
              f"frame, `observed`: the affine fit and the metrics inside the region where the "
              f"output's events fired with spatial support (static background that never "
              f"fired is left out). `flat` and `salt` carry no information about the "
              f"recording, compared as they are: a grey at the target's mean level (over the "
              f"region under `observed`) and that grey with random dots (+-{SALT_AMPLITUDE}) "
              f"on {100 * SALT_FRACTION:.1f}% of its pixels: the floors. The ceilings (whole "
              f"frames only) are the APS frame itself inside the observed region and "
              f"outside it: one grey at its true mean there (`seen+flat`: what an output "
              f"that draws nothing where no event fired scores at best), its smoothest "
              f"continuation from the region's rim (`seen+harmonic`), or that grey with "
              f"`salt`'s dots (`seen+salt`: no information added; where it beats the other "
              f"two, the metric rewards texture as such).", "",
              "Recordings:", ""]
    for r in reports:
        line = f"- {r.name} ({'scored' if r.scored else 'figure only'}): events per stack " \
               f"{r.stacks}"
        if r.exposures:
            line += f"; APS: {r.exposures}"
        if r.averaged:
            line += (f"; outputs averaged per frame: {min(r.averaged)}-{max(r.averaged)}")
        lines.append(line)
    lines += ["", "| recording | normalisation | method | frames | PSNR | SSIM | MSE | LPIPS "
              "| E_warp | region | invented |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cells = [f"{r[k]:.4f}" if k in r else "-" for k in METRICS]
        lines.append(f"| {r['sequence']} | {r['normalize']} | {r['method']} | {r['frames']} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
