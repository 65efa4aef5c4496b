"""Paper-style evaluation: E2SRI and classical baselines through one protocol.

For every evaluated frame each method produces an image from the events before (and
around) it: ``ours`` (the network), ``hf`` (high-pass filter), ``direct`` (event
integration) and ``complementary`` (complementary filter with the APS frames strictly
before the frame, so it is never scored against its own input). Two protocols, as in the
paper:
- ``hr`` (its Table 4): at HR against the HR ground truth (baselines upsampled bicubic);
- ``lr`` (its Table 1): at the sensor size against the APS/LR frame (ours area-downsampled).
Before the metrics the prediction is normalised, because event-only methods have no
absolute intensity: ``affine`` (default) maps it by the least-squares scale and offset to
the target, so every method is scored on structure with its best intensity mapping;
``minmax`` stretches both images by their 1st..99th percentiles (common, but on flat scenes
it amplifies a flat output's small variations: on a held-out moon sequence it cut all
event-only methods from ~25 dB to 8-11 dB); ``evreal`` is EVREAL's standard protocol
(Ercan et al. 2023): outputs of methods with an absolute intensity (the network, which is
trained to predict it, and the complementary filter, anchored to APS frames) are clipped to
[0, 1] and compared as they are, while methods without one (HF, direct integration) have
their output stretched by its 1st..99th percentiles; the target is never changed. ``none``
compares raw values. ``observed`` scores only the observed region, where the output's
events fired with spatial support (:mod:`model.inference.observed`), with the affine fit
made inside it: what event-only methods can know, apart from what no event saw.

Scoring real recordings: events per stack are chosen per recording
(:mod:`model.stack_size`; the active-pixel rule by default for real files, the
area rule for our shards); with ``exposure_average`` every method's outputs inside each APS
frame's exposure window are averaged before scoring (:mod:`model.inference.exposure`): ours
at our stack boundaries there and at the frame, the baselines at the same times from the
previous frame on (an event filter cannot go back).

Temporal stability (the paper's Table 6): ``E_warp`` between consecutive outputs with the
flow of the ground-truth frames; ``ours+tc`` is our outputs after the blind post-process
(both in :mod:`model.inference.temporal`).
"""

from __future__ import annotations

import copy
import csv
import io
import logging
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch

from datagen.formats.base import READ_CHUNK_EVENTS
from datagen.recording import Recording, open_recording
from datagen.shard import ShardReader, find_shards
from esim_lite.core.atomic import write_text
from esim_lite.core.figures import contact_sheet, event_image, gray_to_rgb, write_png
from esim_lite.core.outputs import OutputFolder, claim
from esim_lite.core.scales import hr_camera
from model import checkpoint
from model.archs.e2sri_arch import mode_of
from model.data.dataset import index_samples
from model.inference.baselines import EventFilter, FilterConfig, upsample
from model.inference.exposure import boundary_times, exposure_average
from model.inference.fill import FillConfig
from model.inference.observed import (
    MIN_PIXELS,
    affine_in,
    masked_metrics,
    support_mask,
    upscale_mask,
)
from model.inference.quantize import CalibrationSource
from model.inference.reconstruct import OutputPlan, Reconstructor, output_times
from model.inference.references import CEILINGS, REFERENCES, reference_image
from model.inference.temporal import reference_motion, temporally_consistent, warp_error
from model.losses.lpips import LPIPS
from model.metrics.image import mse, psnr, ssim
from model.stack_size import Rule, StackChoice, activity_for_rule

log = logging.getLogger(__name__)
BASELINES = ("hf", "direct", "complementary")
OUTPUTS = ("metrics.md", "metrics.csv", "figure.png")
"""The names :func:`evaluate` writes into its folder."""


@dataclass(frozen=True)
class EvalOptions:
    """``normalize``: see the module doc; ``every``: evaluate every k-th eligible frame;
    ``max_frames`` per sequence; ``tc_weight``: weight of the warped previous output in the
    temporal post-process; ``stack_rule`` and ``events_per_stack`` choose the stacks
    (:mod:`model.stack_size`); ``exposure_average``: average every method's outputs over
    each APS frame's exposure window where the file stores it; ``references``: also score
    the information-free references and, with ``ceilings``, the whole-frame ceilings
    (:mod:`model.inference.references`); ``fill``: what our outputs get where no event
    fired (:mod:`model.inference.fill`)."""

    normalize: Literal["affine", "minmax", "evreal", "none", "observed"] = "affine"
    every: int = 1
    max_frames: int | None = None
    baselines: tuple[str, ...] = BASELINES
    temporal: bool = True
    tc_weight: float = 0.6
    filters: FilterConfig = field(default_factory=FilterConfig)
    stack_rule: Rule = "auto"
    events_per_stack: int | None = None
    exposure_average: bool = False
    references: bool = False
    ceilings: bool = True
    fill: FillConfig = field(default_factory=FillConfig)


#: Methods whose output has an absolute intensity (compared as they are under ``evreal``).
ABSOLUTE = ("ours", "ours+tc", "complementary")


def _stretch(img: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(img, (1, 99))
    return ((img - lo) / max(hi - lo, 1e-6)).clip(0, 1).astype(np.float32)


def normalized(pred: np.ndarray, gt: np.ndarray, mode: str, absolute: bool = True
               ) -> tuple[np.ndarray, np.ndarray]:
    """(prediction, target) ready for the metrics under ``mode`` (see the module doc);
    ``absolute``: whether the method predicts absolute intensity (used by ``evreal``)."""
    if mode == "none":
        return pred, gt
    if mode == "evreal":
        return (pred.clip(0, 1).astype(np.float32) if absolute else _stretch(pred)), gt
    if mode == "affine":
        a = np.stack([pred.ravel(), np.ones(pred.size)], 1)
        coef, *_ = np.linalg.lstsq(a, gt.ravel(), rcond=None)
        return (coef[0] * pred + coef[1]).clip(0, 1).astype(np.float32), gt
    return _stretch(pred), _stretch(gt)


def frame_metrics(pred: np.ndarray, gt: np.ndarray, lpips_net: LPIPS | None) -> dict:
    p, g = torch.from_numpy(pred)[None, None], torch.from_numpy(gt)[None, None]
    out = {"psnr": float(psnr(p, g)), "ssim": float(ssim(p, g)), "mse": float(mse(p, g))}
    if lpips_net is not None and min(pred.shape) >= 32:
        with torch.inference_mode():
            out["lpips"] = float(lpips_net(p, g))
    return out


@dataclass
class SequenceOutputs:
    """Every method's images at the evaluated frames, with the targets; ``stack_choice``:
    the events per stack used; ``averaged``: per frame, how many of our outputs were
    averaged over its exposure (empty when not averaging); ``support``: per frame, the
    observed region at the sensor size (:func:`model.inference.observed.support_mask` of
    the events behind our output at the frame's time)."""

    name: str
    images: dict[str, list[np.ndarray]]
    lr_targets: list[np.ndarray]
    hr_targets: list[np.ndarray] | None
    event_images: list[np.ndarray]
    stack_choice: StackChoice | None = None
    averaged: list[int] = field(default_factory=list)
    support: list[np.ndarray] = field(default_factory=list)


class ModelPool:
    """A checkpoint read once; its network (and engine) prepared once per sensor size, with
    the events per stack chosen for each recording (``options.stack_rule``); ``calibrate``:
    for an ``openvino-int8`` engine (:func:`model.inference.engines.load_engine`)."""

    def __init__(self, ckpt: str | Path, options: EvalOptions, first_pass: str | None = None,
                 engine: str = "torch", calibrate: CalibrationSource | None = None) -> None:
        self.ckpt, self.options, self.first_pass, self.engine = str(ckpt), options, \
            first_pass, engine
        self.calibrate = calibrate
        self.state = checkpoint.load(ckpt)
        self.config = checkpoint.config_of(self.state, self.ckpt)
        self._by_hw: dict[tuple[int, int], Reconstructor] = {}

    def for_recording(self, rec: Recording) -> Reconstructor:
        hw = rec.sensor_hw
        if hw not in self._by_hw:
            self._by_hw[hw] = Reconstructor.from_state(
                self.state, self.ckpt, hw, mode_of(self.config.model), self.first_pass,
                engine=self.engine, calibrate=self.calibrate)
        given = self.options.events_per_stack
        model = replace(self._by_hw[hw].with_stacks(given, activity_for_rule(
            rec, self.options.stack_rule, self.config.data.stack_rule, given)),
            fill=self.options.fill)
        log.info("%s: %s events per stack", rec.path, model.stack_choice.describe())
        return model

    def engine_lines(self) -> list[str]:
        """Per sensor size prepared, which engine ran the network and why."""
        return [f"{hw[1]}x{hw[0]}: {model.engine_line}" for hw, model in self._by_hw.items()]


def run_sequence(recording: Recording, model: Reconstructor, frame_ids: list[int],
                 hr_frames: list[np.ndarray] | None, options: EvalOptions,
                 name: str) -> SequenceOutputs:
    """Stream the recording once; produce every method's image at each frame in order."""
    frames = recording.frames
    filters = {m: EventFilter(m, recording.sensor_hw, options.filters) for m in options.baselines}
    out = SequenceOutputs(name, {m: [] for m in ("ours", *options.baselines)}, [], None
                          if hr_frames is None else [], [], model.stack_choice)
    exposures = recording.exposures_ns if options.exposure_average else None
    chunk_size = READ_CHUNK_EVENTS
    window = model.event_window(recording.events(chunk_size), recording.sensor_hw, chunk_size)
    fed, next_frame, fed_t = 0, 0, None
    window.pin = fed  # the baselines have consumed the events before this index (and time)
    for pos, k in enumerate(frame_ids):
        t = int(frames.t_ns[k])
        given = model.stacks_at(window, t)
        anchor = given.anchor
        aps = _aps_of(model, frames, k)
        ours, _ = model.run(given.stacks, aps)
        exposure, times = None, [t]
        if exposures is not None:
            exposure = exposures[k]
            times = exposure_times(model, window, t, exposure)
            ours, n = _over_exposure(model, window, t, ours, aps, times, exposure)
            out.averaged.append(n)
        # baselines see every event up to t and the APS frames strictly before t, in order
        while next_frame < len(frames) and frames.t_ns[next_frame] < t:
            tf = int(frames.t_ns[next_frame])
            upto = window.index_after(tf)
            since = window.slice(fed, upto)[0]
            for f in filters.values():
                f.add_events(since)
                f.add_frame(frames.intensity[next_frame], tf)
            fed, next_frame = max(fed, upto), next_frame + 1
            fed_t = tf if fed_t is None else max(fed_t, tf)
            window.pin = fed
        for m, img in _baseline_images(filters, window, fed, fed_t, times, t, exposure).items():
            out.images[m].append(img)  # at sensor size; upsampled for the HR protocol
        fed, fed_t = anchor, t
        window.pin = fed
        keep = min(fed, given.first)
        if exposures is not None and pos + 1 < len(frame_ids):  # the next exposure's start
            keep = min(keep, model.first_needed(window, int(exposures[frame_ids[pos + 1], 0])))
        window.forget(keep)
        out.images["ours"].append(ours)
        out.lr_targets.append(frames.intensity[k])
        if hr_frames is not None:
            out.hr_targets.append(hr_frames[pos])
        out.event_images.append(event_image(given.events.slice(*given.central)))
        out.support.append(support_mask(given.events))
    return out


def _aps_of(model: Reconstructor, frames, k: int) -> np.ndarray | None:
    return frames.intensity[k] if model.net.config.central == "aps" else None


def exposure_times(model: Reconstructor, window, t: int, exposure: np.ndarray) -> list[int]:
    """The times every method is sampled at for a frame at ``t`` with ``exposure`` (start,
    end): our stack boundaries inside it and ``t`` (:mod:`model.inference.exposure`)."""
    start, end = int(exposure[0]), int(exposure[1])
    return sorted(set(boundary_times(window, model.stacks.events_per_stack, start, end)) | {t})


def _over_exposure(model: Reconstructor, window, t: int, at_t: np.ndarray,
                   aps: np.ndarray | None, times: list[int], exposure: np.ndarray
                   ) -> tuple[np.ndarray, int]:
    """Our outputs at ``times`` (at ``t``: ``at_t``, already made), averaged over
    ``exposure`` (:func:`exposure_average`)."""
    images = [at_t if u == t else _run_at(model, window, u, aps) for u in times]
    return exposure_average(times, images, (int(exposure[0]), int(exposure[1])))


def _baseline_images(filters: dict[str, EventFilter], window, fed: int, fed_t: int | None,
                     times: list[int], t: int, exposure: np.ndarray | None
                     ) -> dict[str, np.ndarray]:
    """Each baseline's image at ``t`` (``exposure`` None), or the mean of its images at
    ``times`` averaged over ``exposure`` as ours is. The filters have the events before index
    ``fed`` (up to time ``fed_t``) and end with those up to ``t``; the samples after ``t``
    are taken on copies, and samples before ``fed_t`` (a window reaching back past the
    previous frame) are left out: a filter cannot go back."""
    samples = [u for u in times if fed_t is None or u >= fed_t]
    images: dict[str, list[np.ndarray]] = {m: [] for m in filters}
    pos, fed_now = fed, filters
    for u in samples:
        if u > t and fed_now is filters:  # past the frame: feed copies, keep the filters at t
            fed_now = copy.deepcopy(filters)
        upto = window.index_after(u)
        chunk = window.slice(pos, upto)[0]
        for m, f in fed_now.items():
            f.add_events(chunk)
            images[m].append(f.image(u))
        pos = upto
    if exposure is None:
        return {m: imgs[0] for m, imgs in images.items()}
    span = (int(exposure[0]), int(exposure[1]))
    return {m: exposure_average(samples, imgs, span)[0] for m, imgs in images.items()}


def _run_at(model: Reconstructor, window, t: int, aps: np.ndarray | None) -> np.ndarray:
    given = model.stacks_at(window, t)
    return model.run(given.stacks, aps)[0]


def unscored_sequence(recording: Recording, model: Reconstructor, options: EvalOptions,
                      name: str, limit: int = 64) -> SequenceOutputs:
    """Without APS frames there is nothing to score against: outputs of the network and of
    HF at the end of every stack (the first ``limit``), for the figure only."""
    chunk_size = READ_CHUNK_EVENTS
    window = model.event_window(recording.events(chunk_size), recording.sensor_hw, chunk_size)
    hf = EventFilter("hf", recording.sensor_hw, options.filters)
    out = SequenceOutputs(name, {"ours": [], "hf": []}, [], None, [], model.stack_choice)
    fed = window.pin = 0
    plan = OutputPlan("events", model.stacks.events_per_stack)
    for t, _ in output_times(plan, recording, window):
        given = model.stacks_at(window, t)
        ours, _ = model.run(given.stacks, None)
        hf.add_events(window.slice(fed, given.anchor)[0])
        fed = window.pin = given.anchor
        window.forget(min(fed, given.first))
        out.images["ours"].append(ours)
        out.images["hf"].append(hf.image(t))
        out.event_images.append(event_image(given.events.slice(*given.central)))
        if len(out.images["ours"]) >= limit:
            break
    if not out.images["ours"]:
        raise ValueError(f"{recording.path}: fewer events than one output needs "
                         f"({model.net.config.n_stacks} stacks of "
                         f"{model.stacks.events_per_stack})")
    return out


def recording_outputs(rec: Recording, model: Reconstructor, options: EvalOptions,
                      name: str) -> SequenceOutputs:
    """A real recording: scored against its APS frames (all but the first, which has no
    events before it) when it has them, else outputs for the figure only."""
    if rec.frames is None:
        return unscored_sequence(rec, model, options, name)
    rec.check_frames_match()
    ids = list(range(1, len(rec.frames)))[::options.every][:options.max_frames]
    return run_sequence(rec, model, ids, None, options, name)


def _down(img: np.ndarray, scale: int) -> np.ndarray:
    h, w = img.shape
    return cv2.resize(img, (w // scale, h // scale), interpolation=cv2.INTER_AREA)


def score(seq: SequenceOutputs, scale: int, options: EvalOptions, lpips_net) -> list[dict]:
    """Rows (sequence, protocol, method, metrics averaged over frames, E_warp)."""
    rows = []
    protocols = {"lr": seq.lr_targets}
    if seq.hr_targets is not None:
        protocols = {"hr": seq.hr_targets, **protocols}
    methods = dict(seq.images)
    if options.temporal and len(methods["ours"]) > 1:
        methods["ours+tc"] = temporally_consistent(methods["ours"], options.tc_weight)
    for proto, targets in protocols.items():
        motion = None  # the targets' flows: every normalisation leaves targets method-free
        for method, images in methods.items():
            if method.startswith("ours"):  # the network's output is at HR
                preds = [_down(im, scale) for im in images] if proto == "lr" else images
            else:  # baselines work at the sensor size
                preds = [upsample(im, scale) for im in images] if proto == "hr" else images
            if options.normalize == "observed":
                pairs, per_frame = _observed(seq, preds, targets, scale if proto == "hr"
                                             else 1, lpips_net)
            else:
                pairs = [normalized(p, g, options.normalize, method in ABSOLUTE)
                         for p, g in zip(preds, targets)]
                per_frame = [frame_metrics(p, g, lpips_net) for p, g in pairs]
            row = {"sequence": seq.name, "protocol": proto, "method": method,
                   "frames": len(per_frame), **_mean_metrics(per_frame)}
            if options.normalize == "observed":  # E_warp is a whole-frame measure
                rows.append(row)
                continue
            if motion is None:
                motion = reference_motion([g for _, g in pairs])
            row["ewarp"] = warp_error([p for p, _ in pairs], motion=motion)
            rows.append(row)
        if options.references:
            rows += _reference_rows(seq, proto, targets, scale if proto == "hr" else 1,
                                    options, lpips_net)
    return rows


def _reference_rows(seq: SequenceOutputs, proto: str, targets: list[np.ndarray],
                    scale: int, options: EvalOptions, lpips_net) -> list[dict]:
    """Rows of the information-free references (:mod:`model.inference.references`),
    compared as they are: under ``observed`` made at the region's mean level and scored
    inside it, otherwise at the frame's mean level and scored over the frame; then, over
    whole frames only, the ceilings (the target where events fired; outside, one grey, the
    target's smoothest continuation, or the grey with random dots)."""
    rows = []
    for kind in REFERENCES:
        per_frame = []
        for i, g in enumerate(targets):
            if options.normalize != "observed":
                per_frame.append(frame_metrics(reference_image(kind, g, i), g, lpips_net))
                continue
            mask = upscale_mask(seq.support[i], scale)
            if int(mask.sum()) >= MIN_PIXELS:
                per_frame.append(masked_metrics(reference_image(kind, g, i, mask), g, mask,
                                                lpips_net))
        rows.append({"sequence": seq.name, "protocol": proto, "method": kind,
                     "frames": len(per_frame), **_mean_metrics(per_frame)})
    if (options.normalize == "observed" or not options.ceilings
            or len(seq.support) != len(targets)):
        return rows
    for kind in CEILINGS:
        per_frame = []
        for i, (g, region) in enumerate(zip(targets, seq.support)):
            mask = upscale_mask(region, scale)
            if 0 < int(mask.sum()) < mask.size:
                per_frame.append(frame_metrics(reference_image(kind, g, i, mask), g, lpips_net))
        if per_frame:
            rows.append({"sequence": seq.name, "protocol": proto, "method": kind,
                         "frames": len(per_frame), **_mean_metrics(per_frame)})
    return rows


def _mean_metrics(per_frame: list[dict]) -> dict:
    """Each metric's mean over the frames that have it (``invented`` needs enough
    unobserved pixels)."""
    keys = dict.fromkeys(k for m in per_frame for k in m)
    return {k: float(np.mean([m[k] for m in per_frame if k in m])) for k in keys}


def _observed(seq: SequenceOutputs, preds: list[np.ndarray], targets: list[np.ndarray],
              scale: int, lpips_net) -> tuple[list, list[dict]]:
    """(pairs, metrics) of the frames whose observed region is large enough, the
    prediction fitted inside the region (``observed`` normalisation)."""
    if len(seq.support) != len(targets):
        raise ValueError(f"{seq.name}: no observed regions to score under 'observed'")
    pairs, per_frame = [], []
    for p, g, region in zip(preds, targets, seq.support):
        mask = upscale_mask(region, scale)
        if int(mask.sum()) < MIN_PIXELS:  # too small to score: no fit either
            continue
        mapped = affine_in(p, g, mask)
        pairs.append((mapped, g))
        per_frame.append(masked_metrics(mapped, g, mask, lpips_net))
    return pairs, per_frame


def evaluate(ckpt: str | Path, out: str | Path | OutputFolder, data: str | Path | None = None,
             recordings: list[str] | None = None, options: EvalOptions | None = None,
             first_pass: str | None = None, split: Literal["val", "all"] = "val",
             sensor_hw: tuple[int, int] | None = None, engine: str = "torch",
             calibrate: CalibrationSource | None = None) -> list[dict]:
    """Evaluate on shards and/or real recordings with APS frames; writes ``metrics.csv``,
    ``metrics.md`` and ``figure.png`` into ``out``; returns the rows.

    ``split``: ``val`` scores the held-out sequences of ``data`` by the checkpoint's own
    split (its validation set), ``all`` every sequence (a separate test set). Recordings
    without APS frames (``sensor_hw`` for formats that do not store it) are not scored:
    they appear in the figure as events | HF | ours. ``engine`` runs the network
    (:mod:`model.inference.engines`; ``calibrate`` for ``openvino-int8``)."""
    options = options or EvalOptions()
    pool = ModelPool(ckpt, options, first_pass, engine, calibrate)  # a refused one writes nothing
    out = claim(out)
    cfg = pool.config
    lpips_net = LPIPS()
    sequences: list[SequenceOutputs] = []
    if data is not None:
        train, val = index_samples(find_shards(data), cfg.data, cfg.model.n_stacks,
                                   cfg.model.scale)
        if split == "all":
            val = train + val
        if not val:
            raise ValueError(f"{data}: no held-out sequences (val_fraction "
                             f"{cfg.data.val_fraction}); --split all scores every sequence")
        by_seq: dict[tuple[str, str], list[int]] = {}
        for ref in val:
            by_seq.setdefault((ref.path, ref.sequence), []).append(ref.frame)
        for (path, seq), frames in sorted(by_seq.items()):
            frames = frames[::options.every][:options.max_frames]
            rec = open_recording(path, sequence=seq)
            model = pool.for_recording(rec)
            with ShardReader(path) as reader:
                hr = [reader.frame(seq, hr_camera(cfg.model.scale), k) for k in frames]
            sequences.append(run_sequence(rec, model, frames, hr, options,
                                          f"{Path(path).name}/{seq}"))
    for path in recordings or []:
        rec = open_recording(path, sensor_hw)
        sequences.append(recording_outputs(rec, pool.for_recording(rec), options, _short(path)))
    if not sequences:
        raise ValueError("nothing to evaluate: give --data and/or --recording")
    rows = [r for s in sequences if s.lr_targets
            for r in score(s, cfg.model.scale, options, lpips_net)]
    rows += average_rows(rows)
    write_tables(rows, out, options, run_notes(sequences, options), pool.engine_lines())
    write_figure(sequences, out / "figure.png", cfg.model.scale)
    return rows


def _short(path: str | Path) -> str:
    """A recording's name in tables and figures: its last two path components."""
    return "/".join(Path(path).parts[-2:])


def average_rows(rows: list[dict]) -> list[dict]:
    """One ``average`` row per (protocol, method): the mean over sequences."""
    out = []
    keys = sorted({(r["protocol"], r["method"]) for r in rows})
    for proto, method in keys:
        sel = [r for r in rows if r["protocol"] == proto and r["method"] == method]
        avg = {"sequence": "average", "protocol": proto, "method": method,
               "frames": sum(r["frames"] for r in sel)}
        for k in ("psnr", "ssim", "mse", "lpips", "ewarp", "coverage", "invented"):
            vals = [r[k] for r in sel if k in r and np.isfinite(r[k])]
            if vals:
                avg[k] = float(np.mean(vals))
        out.append(avg)
    return out


def run_notes(sequences: list[SequenceOutputs], options: EvalOptions) -> list[str]:
    """Markdown lines saying, per sequence, the events per stack and their rule, and whether
    (and over how many outputs) ours was averaged over the APS exposures."""
    lines = []
    for seq in sequences:
        if seq.stack_choice is not None:
            line = f"- {seq.name}: {seq.stack_choice.describe()} events per stack"
            if seq.averaged:
                line += (f"; ours averaged over each frame's exposure: {min(seq.averaged)}-"
                         f"{max(seq.averaged)} output(s) per frame (mean "
                         f"{np.mean(seq.averaged):.2f})")
            lines.append(line)
    if options.exposure_average and not any(s.averaged for s in sequences):
        lines.append("- exposure averaging asked for, but no file stores exposure windows")
    return lines


def write_tables(rows: list[dict], out: Path, options: EvalOptions,
                 notes: list[str] | None = None, engines: list[str] | None = None) -> None:
    """``metrics.csv`` and ``metrics.md`` (the latter headed by the normalisation, the
    engine of "ours" per sensor size (``engines``) and the events per stack (``notes``))."""
    metrics = ["psnr", "ssim", "mse", "lpips", "ewarp"]
    heads = ["PSNR", "SSIM", "MSE", "LPIPS", "E_warp"]
    if any("coverage" in r or "invented" in r for r in rows):  # the observed region's
        metrics, heads = metrics + ["coverage", "invented"], heads + ["region", "invented"]
    cols = ["sequence", "protocol", "method", "frames", *metrics]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: r.get(k, "") for k in cols})
    write_text(out / "metrics.csv", buf.getvalue())
    lines = [f"Normalisation: {options.normalize}. PSNR dB, SSIM, MSE, LPIPS (alex), "
             f"E_warp x1e-3 (lower is better except PSNR and SSIM)"
             + ("; region: the share of the frame scored, invented: the share of the pixels "
                "outside it drawn more than 0.04 from their median level" if "invented" in metrics
                else "") + ".", ""]
    if engines:
        lines += ["Network engine (ours):", "", *(f"- {e}" for e in engines), ""]
    if notes:
        lines += ["Events per stack:", "", *notes, ""]
    for proto in ("hr", "lr"):
        sel = [r for r in rows if r["protocol"] == proto]
        if not sel:
            continue
        title = "HR output vs HR ground truth" if proto == "hr" else \
            "output at sensor size vs APS/LR frame"
        lines += [f"### {title}", "", "| sequence | method | frames | " + " | ".join(heads)
                  + " |", "|---|---|---|" + "---|" * len(heads)]
        for r in sel:
            cells = [f"{r[k]:.4f}" if k in r else "-" for k in metrics]
            lines.append(f"| {r['sequence']} | {r['method']} | {r['frames']} | "
                         + " | ".join(cells) + " |")
        lines.append("")
    write_text(out / "metrics.md", "\n".join(lines))


def _detail_centre(img: np.ndarray) -> tuple[float, float]:
    """(row, col) as fractions of the size: where the smoothed gradient energy peaks."""
    gy, gx = np.gradient(img.astype(np.float32))
    energy = cv2.GaussianBlur(gx * gx + gy * gy, (0, 0), max(img.shape) / 16)
    y, x = np.unravel_index(int(np.argmax(energy)), energy.shape)
    return y / img.shape[0], x / img.shape[1]


def write_figure(sequences: list[SequenceOutputs], path: Path, scale: int) -> Path:
    """Per sequence, its middle frame: events | observed region (scored sequences) | HF |
    ours | ground truth, each image with a 4x zoomed crop where the ground truth has the
    most detail."""
    rows = []
    with_region = any(s.support and (s.hr_targets is not None or s.lr_targets)
                      for s in sequences)
    for seq in sequences:
        k = len(seq.images["ours"]) // 2
        ours = seq.images["ours"][k]
        hf = seq.images.get("hf")  # absent with --no-baselines
        base = hf[k] if hf else None
        if seq.hr_targets is not None or not seq.lr_targets:  # compared at HR
            target = seq.hr_targets[k] if seq.hr_targets is not None else None
            base = upsample(base, scale) if base is not None else None
        else:  # against APS frames at the sensor size
            target, ours = seq.lr_targets[k], _down(ours, scale)
        row = [(seq.event_images[k], f"events: {seq.name}")]
        if seq.support and target is not None:
            row.append((gray_to_rgb(seq.support[k].astype(np.float32)), "observed region"))
        elif with_region:  # keep the columns aligned
            row.append((np.full(seq.event_images[k].shape, 255, np.uint8), ""))
        cy, cx = _detail_centre(target if target is not None else ours)
        panels = ([(base, "HF")] if base is not None else []) + [(ours, "ours")]
        if target is not None:
            panels.append((target, "ground truth"))
        for img, label in panels:
            img = normalized(img, img, "minmax")[0]
            h, w = img.shape
            y0 = int(np.clip(cy * h - h // 8, 0, h - h // 4))
            x0 = int(np.clip(cx * w - w // 8, 0, w - w // 4))
            crop = img[y0:y0 + h // 4, x0:x0 + w // 4]
            zoom = cv2.resize(crop, (w, h), interpolation=cv2.INTER_NEAREST)
            row += [(gray_to_rgb(img), label), (gray_to_rgb(zoom), f"{label} (4x zoom)")]
        rows.append(row)
    return write_png(path, contact_sheet(rows, "evaluation examples (middle frame)", 200))
