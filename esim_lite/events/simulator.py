"""The event camera: turns a stream of rendered intensity samples into events."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from esim_lite.core.events import Events
from esim_lite.events.bandwidth import BandwidthConfig, PhotoreceptorLowPass
from esim_lite.events.flicker import FlickerConfig
from esim_lite.events.kernel import NEVER, TIE_TOL, esim_step_sorted
from esim_lite.events.latency import LatencyConfig, ReadoutDelay
from esim_lite.events.noise import NoiseConfig, NoiseModel, refractory_noise
from esim_lite.events.reference import numpy_step, python_step
from esim_lite.events.thresholds import ContrastThresholds, ThresholdConfig

KernelName = Literal["numba", "numpy", "python", "torch"]


@dataclass(frozen=True)
class EventConfig:
    """The event camera model.

    Attributes:
        log_eps: events compare ``log(log_eps + I)``; keeps black pixels finite.
        thresholds: ranges of the per-sequence contrast thresholds and per-pixel mismatch.
        refractory_ns: a pixel's events closer than this to its previous one are dropped.
        noise: shot noise, hot pixels and leak (all off by default).
        bandwidth: the photoreceptor's intensity-dependent low-pass (off by default).
        flicker: a lamp flickering on part of the view (off by default; the light, not the
            sensor, but set with the sensor's realism).
        latency: the readout's constant delay and per-event jitter of the timestamps (off by
            default; see :mod:`esim_lite.events.latency`).
        random_start: start every pixel at a random point between its two levels (its log
            intensity uniformly between ``C-`` below and ``C+`` above its reference), as
            the pixels of a running sensor stand when a recording starts; off: every pixel
            starts at its reference (ESIM, the paper). With leak on, pixels start between
            their reference and ``C+`` above it (a leaking pixel's steady state) either way.
    """

    log_eps: float = 1e-3
    thresholds: ThresholdConfig = field(default_factory=ThresholdConfig)
    refractory_ns: int = 0
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    bandwidth: BandwidthConfig = field(default_factory=BandwidthConfig)
    flicker: FlickerConfig = field(default_factory=FlickerConfig)
    latency: LatencyConfig = field(default_factory=LatencyConfig)
    random_start: bool = False

    def __post_init__(self) -> None:
        if self.log_eps <= 0:
            raise ValueError("log_eps must be > 0")
        if self.refractory_ns < 0:
            raise ValueError("refractory_ns must be >= 0")


class _NumbaKernel:
    """Adapts :func:`esim_step_sorted` to the reference signature. Its events come out in
    time order (``in_time_order``), so the simulator does not sort them; its work buffers
    start at twice the previous step's event count."""

    in_time_order = True

    def __init__(self) -> None:
        self.capacity = 4096

    def __call__(self, l0, l1, ref, last_t, c_pos, c_neg, t0, t1, refractory_ns, tol):
        events = esim_step_sorted(l0, l1, ref, last_t, c_pos, c_neg, t0, t1, refractory_ns,
                                  tol, self.capacity)
        self.capacity = max(4096, 2 * len(events[0]))
        return events


def _torch_kernel():
    from esim_lite.events.torch_kernel import TorchKernel  # torch only when this kernel is chosen

    return TorchKernel()


def log_intensity(intensity: np.ndarray, log_eps: float) -> np.ndarray:
    """float32 ``log(log_eps + I)`` of a linear intensity image (one new array)."""
    out = np.add(intensity, np.float32(log_eps), dtype=np.float32)
    return np.log(out, out=out)


class EventSimulator:
    """Per-pixel ESIM state for one sensor and one sequence.

    Args:
        first_intensity: float32[H, W] linear intensity at ``t0_ns``; sets the references.
        t0_ns: time of the first sample.
        thresholds: the sensor's (possibly mismatched) contrast thresholds.
        log_eps, refractory_ns: see :class:`EventConfig`.
        noise: a :class:`NoiseModel`, or None for a noise-free sensor.
        bandwidth: the photoreceptor low-pass (None or disabled: an infinitely fast one,
            the ESIM model).
        latency: the readout delay of the timestamps (None or disabled: none, events keep
            their comparator times); :meth:`finish` ends the recording.
        latency_rng: draws the jitter (needed when ``latency.jitter_us > 0``).
        start_phase: float[H, W] in [0, 1): where each pixel starts between its levels (0:
            at ``C+`` above its reference, 1: ``C-`` below; see ``EventConfig.random_start``);
            None: at its reference. With leak, a pixel starts a random share of the way to
            its next leak event either way: that is where a leaking pixel stands in its
            steady state, and a start below the reference would delay its first leak events
            (in a short sequence, leak at ``C+ / (C+ + C-)`` of its rate).
        kernel: ``numba`` (fast), the ``numpy``/``python`` reference implementations, or
            ``torch`` (:mod:`esim_lite.events.torch_kernel`, on CUDA when torch sees a GPU, else on
            the CPU; imported only when asked for).
    """

    def __init__(self, first_intensity: np.ndarray, t0_ns: int, thresholds: ContrastThresholds,
                 *, log_eps: float = 1e-3, refractory_ns: int = 0,
                 noise: NoiseModel | None = None, kernel: KernelName = "numba",
                 bandwidth: BandwidthConfig | None = None,
                 latency: LatencyConfig | None = None,
                 latency_rng: np.random.Generator | None = None,
                 start_phase: np.ndarray | None = None) -> None:
        self.hw = tuple(first_intensity.shape)
        if thresholds.pos_map.shape != self.hw:
            raise ValueError(f"threshold maps {thresholds.pos_map.shape} do not match the "
                             f"sensor {self.hw}")
        self.thresholds = thresholds
        self.log_eps = float(log_eps)
        self.refractory_ns = int(refractory_ns)
        self.noise = noise
        self._kernel = {"numba": _NumbaKernel, "numpy": lambda: numpy_step,
                        "python": lambda: python_step, "torch": _torch_kernel}[kernel]()
        self._kernel_in_order = bool(getattr(self._kernel, "in_time_order", False))
        self._c_pos = np.ascontiguousarray(thresholds.pos_map, np.float64)
        self._c_neg = np.ascontiguousarray(thresholds.neg_map, np.float64)
        self.t0_ns = int(t0_ns)
        self.t_ns = int(t0_ns)
        first_log = log_intensity(first_intensity, self.log_eps)
        self._bandwidth = bandwidth
        self.lowpass = PhotoreceptorLowPass(bandwidth, first_log, self.log_eps) \
            if bandwidth is not None and bandwidth.enabled else None
        self.log_prev = self._effective_log(first_log, self.t_ns)
        self.ref = self.log_prev.astype(np.float64)
        if noise is not None and noise.leak_phase is not None:  # part-way to a leak event
            self.ref -= noise.leak_phase * self._c_pos  # a leaking pixel's steady state
        elif start_phase is not None:  # L - ref uniform in (-C-, C+]
            self.ref += start_phase * (self._c_pos + self._c_neg) - self._c_pos
        self.last_t = np.full(self.hw, NEVER, np.int64)
        self.readout = ReadoutDelay(latency, self.hw, latency_rng) \
            if latency is not None and latency.enabled else None

    def _effective_log(self, log_img: np.ndarray, t_ns: int) -> np.ndarray:
        drift = None if self.noise is None else self.noise.leak_offset(
            self._c_pos, (t_ns - self.t0_ns) * 1e-9)
        return log_img if drift is None else log_img + drift

    def max_step(self, contrast_fraction: float) -> float:
        """The longest next step (s) that keeps the low-passed signal's own relaxation
        within ``contrast_fraction`` of each pixel's threshold in the direction it relaxes
        (``C+`` rising, ``C-`` falling; inf without a low-pass): the sampler's rule for the
        image, each pixel held to its own threshold."""
        if self.lowpass is None:
            return math.inf
        return self.lowpass.max_step(contrast_fraction * self._c_pos,
                                     contrast_fraction * self._c_neg)

    def step(self, intensity: np.ndarray, t_ns: int) -> Events:
        """Events between the previous sample and this linear intensity sample at ``t_ns``."""
        return self.step_log(log_intensity(intensity, self.log_eps), t_ns)

    def step_log(self, log_img: np.ndarray, t_ns: int) -> Events:
        """Like :meth:`step` for a log-intensity image (float32[H, W]); sorted by time.

        With a readout latency: the events read out by ``t_ns`` (their comparator times
        earlier, some of them in earlier steps)."""
        t_ns = int(t_ns)
        if t_ns <= self.t_ns:
            raise ValueError(f"samples must move forward in time: {t_ns} <= {self.t_ns}")
        if log_img.shape != self.hw:
            raise ValueError(f"sample shape {log_img.shape} does not match sensor {self.hw}")
        cur = np.ascontiguousarray(log_img, np.float32)
        light = np.exp(cur) - self.log_eps if self.noise is not None and \
            self.noise.config.shot_bright_factor < 1 else None
        if self.lowpass is not None:
            cur = self.lowpass.step(cur, (t_ns - self.t_ns) * 1e-9)
        if self.noise is not None:
            cur = self._effective_log(cur, t_ns)
        prev_last = self.last_t.copy() if self.noise is not None and self.refractory_ns \
            else None
        x, y, t, p = self._kernel(self.log_prev, cur, self.ref, self.last_t, self._c_pos,
                                  self._c_neg, self.t_ns, t_ns, self.refractory_ns, TIE_TOL)
        in_order = self._kernel_in_order
        if self.noise is not None:
            nx, ny, nt, np_ = self.noise.events(self.t_ns, t_ns, light)
            if len(nt) and prev_last is not None:
                keep = refractory_noise((x, y, t), (nx, ny, nt), prev_last, self.last_t,
                                        self.refractory_ns)
                nx, ny, nt, np_ = nx[keep], ny[keep], nt[keep], np_[keep]
            if len(nt):
                x, y = np.concatenate([x, nx]), np.concatenate([y, ny])
                t, p = np.concatenate([t, nt]), np.concatenate([p, np_])
                in_order = False
        self.log_prev, self.t_ns = cur, t_ns
        if not in_order:  # by time, then row, then column (stable: then emission)
            order = np.lexsort((x, y, t))
            x, y, t, p = x[order], y[order], t[order], p[order]
            events = Events(x, y, t, p, self.hw)
        else:
            events = Events.trusted(x, y, t, p, self.hw)  # the compiled kernel's own arrays
        return events if self.readout is None else self.readout.step(events, t_ns)

    def restart(self, intensity: np.ndarray, t_ns: int) -> None:
        """Jump to a new scene at ``t_ns`` without the events of the jump (a video's scene
        cut: a real sensor would burst there): each pixel's reference moves with its log
        intensity, so the pixel keeps where it stood between its levels; the low-pass
        settles at the new image; the interval since the last sample has no events, noise
        included. ``intensity``: float32[H, W] linear, as :meth:`step` takes it."""
        t_ns = int(t_ns)
        if t_ns <= self.t_ns:
            raise ValueError(f"samples must move forward in time: {t_ns} <= {self.t_ns}")
        if intensity.shape != self.hw:
            raise ValueError(f"sample shape {intensity.shape} does not match sensor {self.hw}")
        log_img = log_intensity(intensity, self.log_eps)
        if self.lowpass is not None:
            self.lowpass = PhotoreceptorLowPass(self._bandwidth, log_img, self.log_eps)
        new = self._effective_log(log_img, t_ns)
        self.ref += new.astype(np.float64) - self.log_prev.astype(np.float64)
        self.log_prev, self.t_ns = new, t_ns

    def finish(self) -> Events:
        """End the recording at the last sample: the events still waiting for their
        readout (always none, since every one due by the last sample came out with it) are
        dropped, as a recording that stops there loses them (see
        :mod:`esim_lite.events.latency`). Empty without latency."""
        if self.readout is None:
            return Events.empty(self.hw)
        return self.readout.finish(self.t_ns)
