"""The event model of :mod:`esim_lite.events.kernel` in torch, for any torch device.

Same model, tie rule and float64 reference as the compiled kernel, and the same events bit
for bit: every quantity is computed by the same IEEE float64 operations in the same order
(``d = L1 - ref``; ``k = floor((L1 - ref + pol * tol) / C)``; a level's time
``t0 + floor(frac * dt + 0.5)`` with ``frac = (ref + i * C - L0) / (L1 - L0)``; the new
reference ``ref + k * C``). Each operation is its own eager torch kernel, so no compiler can
fuse a multiply and an add into one rounding (do not wrap these functions in
``torch.compile``).

A step is vectorised over pixels: the pixels that reach a level, then one entry per event
(``repeat_interleave`` of the active pixels by their level count), then a stable sort by time
of that pixel-major list, which is the order ``np.lexsort((x, y, t))`` gives. The refractory
rule (an event closer than ``refractory_ns`` to the pixel's previous emitted one is dropped,
its level still moves the reference) is sequential per pixel; it is applied one level index at
a time over all pixels, so its cost grows with the busiest pixel's event count, not the
pixel count.

Two entry points: :func:`torch_step` (the reference signature of the other kernels, on
tensors) and :class:`TorchEventCamera`, which keeps the sensor state on its device and turns
a stack of log images into events, like ``esim_torch``'s ``EventSimulator_torch``. On CUDA
with Triton installed the camera runs the stack through :mod:`esim_lite.events.triton_kernel`
instead (two launches per stack rather than some forty per sample), with the same events.
torch is imported only by these modules and :mod:`esim_lite.events.buffers`.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from typing import Literal

import numpy as np
import torch

from esim_lite.core.events import Events
from esim_lite.events.buffers import event_buffers
from esim_lite.events.kernel import NEVER, TIE_TOL
from esim_lite.events.thresholds import ContrastThresholds

#: Samples x pixels per Triton launch: bounds its (T - 1, P) count and offset buffers.
_TRITON_CELLS = 2**26

Backend = Literal["auto", "torch", "triton"]


def default_device() -> torch.device:
    """CUDA when torch sees a GPU, else the CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def resolve_backend(backend: Backend, device: torch.device) -> str:
    """``auto``: the Triton kernel on CUDA when triton is installed, else per-step torch."""
    if backend not in ("auto", "torch", "triton"):
        raise ValueError(f"unknown event backend {backend!r} (auto, torch, triton)")
    if backend != "auto":
        return backend
    has_triton = importlib.util.find_spec("triton") is not None
    return "triton" if device.type == "cuda" and has_triton else "torch"


def torch_step(l0: torch.Tensor, l1: torch.Tensor, ref: torch.Tensor, last_t: torch.Tensor,
               c_pos: torch.Tensor, c_neg: torch.Tensor, t0: int, t1: int,
               refractory_ns: int, tol: float
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Advance every pixel from sample ``(t0, l0)`` to ``(t1, l1)``; updates state in place.

    Args:
        l0, l1: float32 (H, W) log intensity at the previous and the new sample.
        ref: float64 (H, W) reference levels, contiguous (updated).
        last_t: int64 (H, W) time of each pixel's last emitted event, contiguous (updated).
        c_pos, c_neg: float64 (H, W) per-pixel thresholds.
        t0, t1: sample times in ns, t1 > t0.
        refractory_ns, tol: see :mod:`esim_lite.events.kernel`.
    All tensors on one device.
    Returns:
        (x, y, t, p): int16, int16, int64, int8 (N,) on that device, sorted by time, then
        row, then column, then emission (the compiled kernel's order).
    """
    h, w = l1.shape
    dev = l1.device
    new_all = l1.to(torch.float64).reshape(-1)
    ref_flat, last_flat = ref.view(-1), last_t.view(-1)
    d = new_all - ref_flat
    up = d >= c_pos.reshape(-1) - tol
    down = d <= tol - c_neg.reshape(-1)
    idx = torch.nonzero(up | down).squeeze(1)  # active pixels, row-major
    if idx.numel() == 0:
        return event_buffers(0, dev)
    up_a = up[idx]
    pol = torch.where(up_a, 1.0, -1.0).to(torch.float64)
    c = torch.where(up_a, c_pos.reshape(-1)[idx], -c_neg.reshape(-1)[idx])
    r = ref_flat[idx]
    new = new_all[idx]
    old = l0.reshape(-1)[idx].to(torch.float64)
    k = torch.floor((new - r + pol * tol) / c).to(torch.int64)
    ref_flat[idx] = r + k.to(torch.float64) * c

    counts = k.clamp(min=0)
    ends = torch.cumsum(counts, 0)
    starts = ends - counts
    total = int(ends[-1])
    last_a = last_flat[idx]
    if total == 0:
        return event_buffers(0, dev)
    owner = torch.repeat_interleave(torch.arange(idx.numel(), device=dev), counts,
                                    output_size=total)
    t = _level_times(owner, starts, total, pol, c, r, old, new, t0, t1)
    keep, last = _refractory(t, owner, counts, starts, ends, last_a, refractory_ns)
    last_flat[idx] = last
    pix = idx[owner[keep]]
    t = t[keep]
    order = torch.sort(t, stable=True).indices
    pix = pix[order]
    return ((pix % w).to(torch.int16), (pix // w).to(torch.int16), t[order],
            pol[owner[keep]][order].to(torch.int8))


def _level_times(owner: torch.Tensor, starts: torch.Tensor, total: int, pol: torch.Tensor,
                 c: torch.Tensor, r: torch.Tensor, old: torch.Tensor, new: torch.Tensor,
                 t0: int, t1: int) -> torch.Tensor:
    """int64 (total,): the time of every level crossed, one entry per event of the active
    pixel ``owner`` (levels ``1..k`` in order), interpolated linearly between the samples
    (``old`` at ``t0``, ``new`` at ``t1``) from the pixel's reference ``r`` and signed
    threshold ``c``."""
    dev = owner.device
    level = (torch.arange(total, device=dev) - starts[owner] + 1).to(torch.float64)
    slope = new - old
    rising = (slope * pol > 0)[owner]
    frac = (r[owner] + level * c[owner] - old[owner]) / slope[owner]
    frac = torch.where(rising, frac, torch.zeros((), dtype=torch.float64, device=dev))
    frac = frac.clamp(0.0, 1.0)
    return t0 + torch.floor(frac * float(t1 - t0) + 0.5).to(torch.int64)


def _refractory(t: torch.Tensor, owner: torch.Tensor, counts: torch.Tensor,
                starts: torch.Tensor, ends: torch.Tensor, last_a: torch.Tensor,
                refractory_ns: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(keep, last): bool (total,), which events the refractory rule lets through, and the
    active pixels' new time of their last emitted event (``last_a`` where none is)."""
    if refractory_ns == 0:
        # Within a pixel the times do not decrease, so every event after the first kept
        # one is kept too and the rule reduces to a comparison with the previous step's.
        keep = t - last_a[owner] >= 0
        tail = (ends - 1).clamp(min=0)
        fired = (counts > 0) & keep[tail]
        return keep, torch.where(fired, t[tail], last_a)
    keep = torch.empty(t.numel(), dtype=torch.bool, device=t.device)
    last = last_a.clone()
    for j in range(int(counts.max())):
        m = torch.nonzero(counts > j).squeeze(1)
        pos = starts[m] + j
        tj = t[pos]
        ok = tj - last[m] >= refractory_ns
        keep[pos] = ok
        last[m] = torch.where(ok, tj, last[m])
    return keep, last


class TorchEventCamera:
    """A noise-free event camera whose state lives on a torch device.

    Feed it log-intensity images in time order with :meth:`simulate`; the first image ever
    fed sets the references and emits nothing. Gives the events of
    :class:`esim_lite.events.simulator.EventSimulator` (noise off) bit for bit.

    Args:
        thresholds: the sensor's contrast thresholds (per-pixel maps).
        refractory_ns: see :class:`esim_lite.events.simulator.EventConfig`.
        device: where state and computation live (default: :func:`default_device`).
        backend: ``torch`` (:func:`torch_step` per sample), ``triton``
            (:func:`esim_lite.events.triton_kernel.sweep` per stack; CUDA, or CPU in Triton's
            interpreter) or ``auto`` (:func:`resolve_backend`).
    """

    def __init__(self, thresholds: ContrastThresholds, *, refractory_ns: int = 0,
                 device: torch.device | str | None = None, backend: Backend = "auto") -> None:
        if refractory_ns < 0:
            raise ValueError("refractory_ns must be >= 0")
        self.device = torch.device(device) if device is not None else default_device()
        self.backend = resolve_backend(backend, self.device)
        self.hw = tuple(thresholds.pos_map.shape)
        self.refractory_ns = int(refractory_ns)
        self._c_pos = torch.as_tensor(np.asarray(thresholds.pos_map, np.float64),
                                      device=self.device)
        self._c_neg = torch.as_tensor(np.asarray(thresholds.neg_map, np.float64),
                                      device=self.device)
        self.ref: torch.Tensor | None = None
        self.last_t = torch.full(self.hw, NEVER, dtype=torch.int64, device=self.device)
        self.log_prev: torch.Tensor | None = None
        self.t_ns: int | None = None

    def simulate_tensors(self, log_images: torch.Tensor | np.ndarray, t_ns: Sequence[int]
                         ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Events of a stack of samples, as tensors on the camera's device.

        Args:
            log_images: float32 (T, H, W) log intensity, ``log(log_eps + I)``.
            t_ns: T sample times in ns, increasing and after the previous call's last.
        Returns:
            (x, y, t, p) as in :func:`torch_step`, all steps in time order.
        """
        logs = torch.as_tensor(log_images).to(self.device, torch.float32)
        times = [int(v) for v in t_ns]
        if logs.ndim != 3 or tuple(logs.shape[1:]) != self.hw:
            raise ValueError(f"log_images must be (T, {self.hw[0]}, {self.hw[1]}), got "
                             f"{tuple(logs.shape)}")
        if len(times) != logs.shape[0]:
            raise ValueError(f"{logs.shape[0]} images but {len(times)} timestamps")
        seq = ([] if self.t_ns is None else [self.t_ns]) + times
        if any(b <= a for a, b in zip(seq, seq[1:])):
            raise ValueError("samples must move forward in time")
        start = 0
        if self.ref is None and times:
            self.log_prev, self.t_ns = logs[0], times[0]
            self.ref = logs[0].to(torch.float64)
            start = 1
        parts = []
        if self.backend == "triton":
            from esim_lite.events.triton_kernel import sweep

            per_launch = max(1, _TRITON_CELLS // logs[0].numel())
            for a in range(start, len(times), per_launch):
                b = min(a + per_launch, len(times))
                stack = torch.cat([self.log_prev[None], logs[a:b]]).contiguous()
                t = torch.tensor([self.t_ns, *times[a:b]], dtype=torch.int64,
                                 device=self.device)
                parts.append(sweep(stack, t, self.ref, self.last_t, self._c_pos,
                                   self._c_neg, self.refractory_ns, TIE_TOL))
                self.log_prev, self.t_ns = logs[b - 1], times[b - 1]
        else:
            for k in range(start, len(times)):
                parts.append(torch_step(self.log_prev, logs[k], self.ref, self.last_t,
                                        self._c_pos, self._c_neg, self.t_ns, times[k],
                                        self.refractory_ns, TIE_TOL))
                self.log_prev, self.t_ns = logs[k], times[k]
        if not parts:
            return event_buffers(0, self.device)
        return tuple(torch.cat([p[i] for p in parts]) for i in range(4))

    def simulate(self, log_images: torch.Tensor | np.ndarray, t_ns: Sequence[int]) -> Events:
        """:meth:`simulate_tensors`, gathered into an :class:`Events` record on the host."""
        x, y, t, p = (v.cpu().numpy() for v in self.simulate_tensors(log_images, t_ns))
        return Events.trusted(x, y, t, p, self.hw)


class TorchKernel:
    """Adapts :func:`torch_step` to the numpy signature of the other kernels (for
    :class:`esim_lite.events.simulator.EventSimulator`): on the CPU the state arrays are shared with
    torch, elsewhere they are copied to the device and back at every step."""

    in_time_order = True

    def __init__(self, device: torch.device | str | None = None) -> None:
        self.device = torch.device(device) if device is not None else default_device()

    def __call__(self, l0, l1, ref, last_t, c_pos, c_neg, t0, t1, refractory_ns, tol):
        on = self.device
        ref_t, last_tt = torch.from_numpy(ref), torch.from_numpy(last_t)
        if on.type != "cpu":
            ref_t, last_tt = ref_t.to(on), last_tt.to(on)
        out = torch_step(*(torch.from_numpy(np.ascontiguousarray(a)).to(on)
                           for a in (l0, l1)), ref_t, last_tt,
                         *(torch.from_numpy(a).to(on) for a in (c_pos, c_neg)),
                         int(t0), int(t1), int(refractory_ns), float(tol))
        if on.type != "cpu":
            ref[...] = ref_t.cpu().numpy()
            last_t[...] = last_tt.cpu().numpy()
        return tuple(v.cpu().numpy() for v in out)
