"""Events in, super-resolved images out: run a trained E2SRI on any recording.

Output times: the APS frames' timestamps when the file has frames, else the end of every
stack of events (SBN), else a given rate. For each output the events around it are stacked
exactly as in training (central stack ending at the output time), the flow to each side
stack is computed, and the network runs on the whole sensor (it is fully convolutional,
so any sensor size works). Events stream through a sliding window: memory does not grow
with the length of the recording.

The number of events per stack (:mod:`model.stack_size`): given, else scaled from
what the model was trained with by the recording's active pixels (real recordings) or by
the sensor area (the paper: ~3,000 per stack at 128x128 becomes ~7,900 at 240x180).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch
from tqdm import tqdm

from datagen.formats.base import READ_CHUNK_EVENTS
from datagen.recording import Recording
from esim_lite.core.atomic import atomic_path, write_text
from esim_lite.core.events import Events
from esim_lite.core.outputs import OutputFolder, claim
from esim_lite.core.stacking import StackConfig, stack_span_ns, stack_to_input, stacks_around
from model import checkpoint
from model.archs.e2sri_arch import CENTRAL_OF_MODE, E2SRI, central_input
from model.data.classical_flow import stack_flows
from model.inference.engines import Forward, load_engine
from model.inference.fill import FillConfig, fill_unobserved
from model.inference.quantize import CalibrationSource
from model.inference.temporal import consistency_step
from model.stack_size import Activity, StackChoice, choose_stack

log = logging.getLogger(__name__)
OUTPUTS = ("frame_[0-9][0-9][0-9][0-9][0-9][0-9].png", "timestamps.txt", "video.mp4")
"""The names :func:`reconstruct` writes into its folder."""
Mode = Literal["main", "complementary", "duo-pass"]


class EventWindow:
    """Random access by global event index to a chunked stream, keeping only what is still
    needed: below the last :meth:`forget` index, and (with ``keep``) more than ``keep``
    events behind the newest one read, events are dropped, unless ``pin`` holds them.
    ``keep_ns`` does the same by time: when a chunk is read, events more than ``keep_ns``
    older than the newest event *before* it are dropped (a read-ahead never reaches back
    further than the time it was asked for)."""

    def __init__(self, chunks: Iterator[Events], hw: tuple[int, int],
                 keep: int | None = None, keep_ns: int | None = None) -> None:
        if keep is not None and keep_ns is not None:
            raise ValueError("give keep or keep_ns, not both")
        self._chunks, self.hw, self.keep, self.keep_ns = chunks, hw, keep, keep_ns
        self.buf, self.offset, self.done = Events.empty(hw), 0, False
        self.pin: int | None = None

    @property
    def end(self) -> int:
        return self.offset + len(self.buf)

    def _pull(self) -> bool:
        try:
            chunk = next(self._chunks)
        except StopIteration:
            self.done = True
            return False
        newest = int(self.buf.t_ns[-1]) if len(self.buf) else None
        self.buf = Events.concatenate([self.buf, chunk], self.hw)
        floor = None  # reading far ahead must not grow memory without bound
        if self.keep is not None:
            floor = self.end - self.keep
        elif self.keep_ns is not None and newest is not None:
            floor = self.offset + int(np.searchsorted(self.buf.t_ns, newest - self.keep_ns))
        if floor is not None:
            self.forget(floor if self.pin is None else min(floor, self.pin))
        return True

    def index_after(self, t_ns: int) -> int:
        """Global index of the first event later than ``t_ns`` (reads ahead as needed)."""
        while not self.done and (not len(self.buf) or self.buf.t_ns[-1] <= t_ns):
            self._pull()
        return self.offset + int(np.searchsorted(self.buf.t_ns, t_ns, side="right"))

    def time_of(self, index: int) -> int | None:
        if index < self.offset:
            raise ValueError(f"event {index} was already dropped from the window (it keeps "
                             f"events from {self.offset} on)")
        while not self.done and self.end <= index:
            self._pull()
        return int(self.buf.t_ns[index - self.offset]) if index < self.end else None

    def slice(self, lo: int, hi: int) -> tuple[Events, int]:
        """(events [lo, hi) clipped to what exists, the global index of its first event)."""
        while not self.done and self.end < hi:
            self._pull()
        lo = max(lo, self.offset)
        return self.buf.slice(lo - self.offset, max(lo, min(hi, self.end)) - self.offset), lo

    def forget(self, index: int) -> None:
        if index > self.offset:
            new = min(index, self.end)
            self.buf = self.buf.slice(new - self.offset, len(self.buf))
            self.offset = new


@dataclass(frozen=True, eq=False)
class StackedEvents:
    """One output's input: ``stacks`` uint8[n, c, H, W] built from ``events`` (global index
    of its first event: ``first``); ``anchor``: global index of the first event after the
    output time; ``central``: the central stack's event range within ``events``."""

    stacks: np.ndarray
    events: Events
    first: int
    anchor: int
    central: tuple[int, int]


@dataclass(frozen=True, eq=False)
class Reconstructor:
    """A loaded network (plus its first pass for Duo-Pass) and how to stack events for it.

    ``engine`` runs the network's forward pass (:mod:`model.inference.engines`; None: the
    network in eager PyTorch); ``first_pass`` is the first pass's, on the same engine;
    ``stack_choice``: how ``stacks.events_per_channel`` was chosen (None: set by hand);
    ``fill``: how :meth:`run` fills what no event saw after the network
    (:mod:`model.inference.fill`; the default leaves the network's output)."""

    net: E2SRI
    first_pass: Forward | None
    stacks: StackConfig
    device: torch.device
    engine: Forward | None = None
    stack_choice: StackChoice | None = None
    fill: FillConfig = FillConfig()

    @classmethod
    def load(cls, ckpt: str | Path, sensor_hw: tuple[int, int], mode: Mode = "main",
             first_pass: str | Path | None = None, events_per_stack: int | None = None,
             device: str | None = None, engine: str = "torch",
             activity: Activity | None = None,
             calibrate: CalibrationSource | None = None) -> Reconstructor:
        """Read ``ckpt`` and prepare it for a ``sensor_hw`` sensor (see :meth:`from_state`)."""
        return cls.from_state(checkpoint.load(ckpt), str(ckpt), sensor_hw, mode, first_pass,
                              events_per_stack, device, engine, activity, calibrate)

    @classmethod
    def from_state(cls, state: dict, ckpt: str, sensor_hw: tuple[int, int],
                   mode: Mode = "main", first_pass: str | Path | None = None,
                   events_per_stack: int | None = None, device: str | None = None,
                   engine: str = "torch", activity: Activity | None = None,
                   calibrate: CalibrationSource | None = None) -> Reconstructor:
        """From an already loaded checkpoint ``state`` (``ckpt`` names it in errors);
        ``engine``: ``torch``, ``onnxruntime``, ``openvino``, ``openvino-bf16``,
        ``openvino-int8`` (calibrated on what ``calibrate`` makes) or ``auto``
        (:func:`model.inference.engines.load_engine`).
        Events per stack: ``events_per_stack``, else by the recording's ``activity``
        (active-pixel rule), else by sensor area (:func:`model.stack_size.choose_stack`)."""
        dev = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        net = checkpoint.model_from(state, dev, ckpt)
        if net.config.central != CENTRAL_OF_MODE[mode]:
            raise ValueError(f"{ckpt}: a model with central input {net.config.central!r} "
                             f"cannot run in mode {mode!r} (needs {CENTRAL_OF_MODE[mode]!r})")
        if net.config.flow == "none":
            log.info("%s: a model without flow input", ckpt)
        first = None
        if mode == "duo-pass":
            path = first_pass or checkpoint.config_of(state).run.first_pass
            if not path:
                raise ValueError("duo-pass needs --first-pass (a main model checkpoint)")
            first = load_engine(engine, checkpoint.load_model(path, dev), dev, sensor_hw,
                                calibrate=calibrate)
        data = checkpoint.config_of(state, ckpt).data
        trained = data.stacks
        trained_hw = tuple(state.get("sensor_hw") or checkpoint.TRAINED_SENSOR_HW)
        if "sensor_hw" not in state:
            log.warning("%s records no training sensor size; assuming the paper's %dx%d "
                        "(stack sizes scale from it)", ckpt, trained_hw[1], trained_hw[0])
        choice = choose_stack(trained.events_per_channel, trained.channels, trained_hw,
                              sensor_hw, events_per_stack, activity)
        return cls(net, first, replace(trained, events_per_channel=choice.events_per_channel),
                   dev, load_engine(engine, net, dev, sensor_hw, stack_rule=data.stack_rule,
                                    calibrate=calibrate),
                   choice)

    def with_stacks(self, given: int | None = None, activity: Activity | None = None
                    ) -> Reconstructor:
        """The same network (and engine) with events per stack chosen afresh from the
        model's trained ones (:func:`model.stack_size.choose_stack`): for another
        recording of the same sensor size."""
        base = self.stack_choice
        if base is None:
            raise ValueError("this Reconstructor's stacks were set by hand; load it with "
                             "Reconstructor.load or from_state to rechoose them")
        choice = choose_stack(base.trained, base.channels, base.trained_hw, base.sensor_hw,
                              given, activity)
        return replace(self, stacks=replace(self.stacks,
                                            events_per_channel=choice.events_per_channel),
                       stack_choice=choice)

    @property
    def engine_name(self) -> str:
        """The engine running the network (``torch`` when none was given)."""
        return getattr(self.engine, "name", "torch")

    @property
    def engine_line(self) -> str:
        """Which engine runs the network and why: ``engine openvino-bf16 (auto: bf16 (this
        CPU's native precision) passed its quality check, ...)``."""
        return f"engine {self.engine_name} ({getattr(self.engine, 'why', 'asked for')})"

    def event_window(self, chunks: Iterator[Events], hw: tuple[int, int],
                     chunk_size: int) -> EventWindow:
        """A window over ``chunks`` holding what the stacks of one output need (SBN: a
        count of events; SBT: a time span), plus the read-ahead of ``chunk_size`` chunks."""
        n = self.net.config.n_stacks
        if self.stacks.method == "sbt":
            return EventWindow(chunks, hw, keep_ns=(n + 1) * stack_span_ns(self.stacks))
        return EventWindow(chunks, hw, keep=n * self.stacks.events_per_stack + 2 * chunk_size)

    def first_needed(self, window: EventWindow, t_ns: int) -> int:
        """Global index of the first event the stacks of an output at ``t_ns`` read."""
        cfg, half = self.stacks, self.net.config.n_stacks // 2
        if cfg.method == "sbt":
            return window.index_after(t_ns - (half + 1) * stack_span_ns(cfg))
        return window.index_after(t_ns) - (half + 1) * cfg.events_per_stack

    def stacks_at(self, window: EventWindow, t_ns: int) -> StackedEvents:
        """The network's stacks for an output at ``t_ns``: the central one ends at the last
        event at or before ``t_ns`` (SBN) or at ``t_ns`` (SBT)."""
        cfg, n = self.stacks, self.net.config.n_stacks
        half = n // 2
        anchor = window.index_after(t_ns)
        lo = self.first_needed(window, t_ns)
        if cfg.method == "sbt":
            hi = window.index_after(t_ns + half * stack_span_ns(cfg))
        else:
            hi = anchor + half * cfg.events_per_stack
        events, first = window.slice(lo, hi)
        built = stacks_around(events, cfg, n, anchor - first, t_ns)
        centre = built[half]
        return StackedEvents(np.stack([st.image for st in built]), events, first, anchor,
                             (centre.start, centre.end))

    @torch.inference_mode()
    def run(self, stacks: np.ndarray, aps: np.ndarray | None) -> tuple[np.ndarray, dict]:
        """(float32[sH, sW] image in [0, 1], seconds spent in flow and network) for uint8
        stacks ``[n, c, H, W]`` (and the APS frame for Complementary)."""
        timing = {}
        start = time.perf_counter()
        flows = stack_flows(stacks) if self.net.config.flow == "given" else \
            np.zeros((len(stacks), 2) + stacks.shape[-2:], np.float32)
        timing["flow"] = time.perf_counter() - start
        start = time.perf_counter()
        x = torch.from_numpy(stack_to_input(stacks))[None].to(self.device)
        f = torch.from_numpy(flows)[None].to(self.device)
        central = self._central(x, f, aps)
        out = self.forward(x, central, f).clamp(0, 1)[0, 0].float().cpu().numpy()
        if self.device.type == "cuda":
            torch.cuda.synchronize()
        timing["network"] = time.perf_counter() - start
        if self.fill.mode != "none":
            start = time.perf_counter()
            out = fill_unobserved(out, stacks, self.fill)
            timing["fill"] = time.perf_counter() - start
        return out, timing

    def forward(self, x: torch.Tensor, central: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
        """The network's output before the clamp, on the engine."""
        return (self.engine or self.net)(x, central, f)

    def _central(self, x, f, aps):
        if aps is not None:
            aps = torch.from_numpy(aps.astype(np.float32))[None, None].to(self.device)
        return central_input(self.net.config, x, f, aps, self.first_pass)


@dataclass(frozen=True)
class OutputPlan:
    """``at``: ``frames`` (APS timestamps), ``events`` (every ``every_events``) or ``rate``."""

    at: Literal["frames", "events", "rate"]
    every_events: int = 0
    rate_hz: float = 0.0


def plan_outputs(recording: Recording, stacks: StackConfig, at: str = "auto",
                 rate_hz: float | None = None, every_events: int | None = None) -> OutputPlan:
    if at == "auto":
        at = "frames" if recording.frames is not None else "rate" if rate_hz else "events"
    if at == "frames" and recording.frames is None:
        raise ValueError(f"{recording.path}: has no APS frames to output at")
    if at == "rate" and not rate_hz:
        raise ValueError("output at a rate needs --rate HZ")
    return OutputPlan(at, every_events or stacks.events_per_stack, rate_hz or 0.0)


def output_times(plan: OutputPlan, recording: Recording, window: EventWindow
                 ) -> Iterator[tuple[int, int | None]]:
    """(time in ns, index of the APS frame or None) of every output, in order."""
    if plan.at == "frames":
        for k, t in enumerate(recording.frames.t_ns):
            yield int(t), k
        return
    t0 = window.time_of(0)
    if plan.at == "rate":
        step = int(round(1e9 / plan.rate_hz))
        t = t0
        while window.time_of(window.index_after(t)) is not None:
            yield t, None
            t += step
        return
    k = plan.every_events
    while (t := window.time_of(k - 1)) is not None:
        yield t, None
        # events sharing one timestamp give one output: the next is at a later time
        k = max(k + plan.every_events, window.index_after(t) + 1)


@dataclass(frozen=True)
class ReconstructResult:
    frames: list[Path]
    times_ns: list[int]
    seconds: dict[str, float]


def reconstruct(recording: Recording, model: Reconstructor, out: str | Path | OutputFolder,
                plan: OutputPlan, mp4: bool = False, show_progress: bool = True,
                limit: int | None = None, chunk: int = READ_CHUNK_EVENTS,
                temporal: float | None = None) -> ReconstructResult:
    """Write ``frame_XXXXXX.png`` (and ``timestamps.txt``, ``video.mp4``) into ``out``.

    ``temporal``: weight of the blind temporal-consistency post-process (None: off); it
    needs only the previous frame, so memory stays bounded."""
    window = model.event_window(recording.events(chunk), recording.sensor_hw, chunk)
    seconds = {"stacking": 0.0, "flow": 0.0, "network": 0.0}
    paths, times, previous = [], [], None
    total = len(recording.frames) if plan.at == "frames" else None
    bar = tqdm(total=total, disable=not show_progress, unit="frame", desc="reconstruct")
    for t, k in output_times(plan, recording, window):
        start = time.perf_counter()
        given = model.stacks_at(window, t)
        window.forget(given.first)
        seconds["stacking"] += time.perf_counter() - start
        aps = recording.frames.intensity[k] if k is not None else None
        image, timing = model.run(given.stacks, aps)
        for key, v in timing.items():
            seconds[key] = seconds.get(key, 0.0) + v
        if temporal is not None:
            raw = image
            if previous is not None:
                image = consistency_step(previous[0], previous[1], raw, temporal)
            previous = (raw, image)
        if not paths:  # the folder appears with the first frame, never empty
            out = claim(out)
        path = out / f"frame_{len(paths):06d}.png"
        with atomic_path(path, ".tmp.png") as tmp:
            cv2.imwrite(str(tmp), np.round(image * 255).astype(np.uint8))
        paths.append(path)
        times.append(t)
        bar.update(1)
        if limit is not None and len(paths) >= limit:
            break
    bar.close()
    if not paths:
        raise ValueError(f"{recording.path}: too few events for one output ({plan.at}: the "
                         f"first needs {plan.every_events if plan.at == 'events' else 1:,} "
                         f"event(s) and a stack of {model.stacks.events_per_stack:,}); "
                         f"nothing written")
    out = claim(out)
    write_text(out / "timestamps.txt",
               "".join(f"{i} {t * 1e-9:.9f}\n" for i, t in enumerate(times)))
    if mp4 and paths:
        write_mp4(paths, out / "video.mp4", times)
    return ReconstructResult(paths, times, seconds)


def write_mp4(paths: list[Path], target: Path, times_ns: list[int]) -> Path:
    """An MP4 of the frames at their median output rate (OpenCV's encoder)."""
    first = cv2.imread(str(paths[0]), cv2.IMREAD_GRAYSCALE)
    gaps = np.diff(times_ns)
    fps = float(np.clip(1e9 / np.median(gaps), 1, 240)) if len(gaps) else 10.0
    writer = cv2.VideoWriter(str(target), cv2.VideoWriter_fourcc(*"mp4v"), fps,
                             (first.shape[1], first.shape[0]), isColor=False)
    if not writer.isOpened():
        raise ValueError(f"{target}: OpenCV cannot write MP4 here")
    for p in paths:
        writer.write(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))
    writer.release()
    return target
