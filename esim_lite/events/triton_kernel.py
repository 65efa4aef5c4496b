"""The event model as one Triton kernel over a whole stack of samples (for GPUs).

:func:`esim_lite.events.torch_kernel.torch_step` launches some forty small kernels per sample; at
128 x 128 pixels a GPU spends that step waiting on launches. Here each program owns a block
of pixels and walks them through all T samples in registers, the way ``esim_torch``'s CUDA
kernel does, so a stack costs two launches however long it is:

1. ``count``: per (step, pixel), the number of events kept; an exclusive prefix sum over the
   step-major (T - 1, P) counts gives every pixel's write offset in every step;
2. ``write``: the same walk again, writing each event at its offset and the final state.

The list comes out step-major, pixel-major within a step, levels in order within a pixel, so
one stable sort by time gives the order of :class:`esim_lite.events.simulator.EventSimulator` (steps
concatenated, each by time, then row, column and emission).

Bit-exactness with the compiled kernel rests on the same float64 operations in the same
order; the kernels are compiled with ``enable_fp_fusion=False`` so that no multiply-add is
contracted into one rounding, and the tie tolerance is read from a float64 tensor (a Python
float argument would be passed as float32). On CPU tensors the kernels run in Triton's
interpreter (numpy) when ``TRITON_INTERPRET=1`` was set before triton was imported (Triton
builds its own library functions, e.g. ``tl.max``, for one mode at import), which is how the
tests check them without a GPU.
"""

from __future__ import annotations

import functools
import os

import torch
import triton
import triton.language as tl

from esim_lite.events.buffers import event_buffers

BLOCK = 128
#: Compile options of the CUDA kernel: no multiply-add contraction (two roundings stay two).
COMPILE_OPTIONS = {"enable_fp_fusion": False}
#: Its argument types, for compiling it ahead of time (tests inspect the PTX).
SIGNATURE = {"logs_ptr": "*fp32", "times_ptr": "*i64", "tol_ptr": "*fp64", "ref_ptr": "*fp64",
             "last_ptr": "*i64", "cpos_ptr": "*fp64", "cneg_ptr": "*fp64",
             "counts_ptr": "*i32", "offsets_ptr": "*i64", "x_ptr": "*i16", "y_ptr": "*i16",
             "t_ptr": "*i64", "p_ptr": "*i8", "n_px": "i32", "width": "i32", "n_steps": "i32",
             "refractory_ns": "i32", "WRITE": "constexpr", "BLOCK": "constexpr"}


def _sweep(logs_ptr, times_ptr, tol_ptr, ref_ptr, last_ptr, cpos_ptr, cneg_ptr, counts_ptr,
           offsets_ptr, x_ptr, y_ptr, t_ptr, p_ptr, n_px, width, n_steps, refractory_ns,
           WRITE: tl.constexpr, BLOCK: tl.constexpr):
    # A plain function: _kernel compiles it (CUDA) or interprets it (CPU tensors).
    pix = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    m = pix < n_px
    tol = tl.load(tol_ptr)
    ref = tl.load(ref_ptr + pix, mask=m, other=0.0)
    last = tl.load(last_ptr + pix, mask=m, other=0)
    cp = tl.load(cpos_ptr + pix, mask=m, other=1.0)
    cn = tl.load(cneg_ptr + pix, mask=m, other=1.0)
    old = tl.load(logs_ptr + pix, mask=m, other=0.0).to(tl.float64)
    t_prev = tl.load(times_ptr)
    zero = tl.zeros([BLOCK], tl.int64)
    pix64 = pix.to(tl.int64)
    for s in range(1, n_steps):
        t_cur = tl.load(times_ptr + s)
        row = (s - 1) * n_px + pix64
        new = tl.load(logs_ptr + s * n_px + pix64, mask=m, other=0.0).to(tl.float64)
        d = new - ref
        up = d >= cp - tol
        down = d <= tol - cn
        active = (up | down) & m
        pol = tl.where(up, 1.0, -1.0).to(tl.float64)
        c = tl.where(up, cp, -cn)
        k = tl.floor((new - ref + pol * tol) / c).to(tl.int64)
        k = tl.where(active, k, zero)
        slope = new - old
        rising = slope * pol > 0
        safe_slope = tl.where(rising, slope, 1.0)
        dt = (t_cur - t_prev).to(tl.float64)
        n = zero
        if WRITE:
            base = tl.load(offsets_ptr + row, mask=m, other=0)
        for i in range(1, tl.max(k, 0) + 1):
            reached = active & (k >= i)
            level = (zero + i).to(tl.float64)
            frac = tl.where(rising, (ref + level * c - old) / safe_slope, 0.0)
            frac = tl.minimum(tl.maximum(frac, 0.0), 1.0)
            t = t_prev + tl.floor(frac * dt + 0.5).to(tl.int64)
            keep = reached & (t - last >= refractory_ns)
            if WRITE:
                pos = base + n
                tl.store(x_ptr + pos, (pix % width).to(tl.int16), mask=keep)
                tl.store(y_ptr + pos, (pix // width).to(tl.int16), mask=keep)
                tl.store(t_ptr + pos, t, mask=keep)
                tl.store(p_ptr + pos, pol.to(tl.int8), mask=keep)
            n += keep.to(tl.int64)
            last = tl.where(keep, t, last)
        if not WRITE:
            tl.store(counts_ptr + row, n.to(tl.int32), mask=m)
        ref = tl.where(active, ref + k.to(tl.float64) * c, ref)
        old = new
        t_prev = t_cur
    if WRITE:
        tl.store(ref_ptr + pix, ref, mask=m)
        tl.store(last_ptr + pix, last, mask=m)


def interpreting() -> bool:
    """Whether this process runs Triton kernels in the interpreter."""
    knobs = getattr(triton, "knobs", None)  # triton >= 3.4
    if knobs is not None:
        return bool(knobs.runtime.interpret)
    return os.environ.get("TRITON_INTERPRET", "0") == "1"


@functools.cache
def _kernel():
    return triton.jit(_sweep)  # an interpreted function when TRITON_INTERPRET=1


def sweep(logs: torch.Tensor, times: torch.Tensor, ref: torch.Tensor, last_t: torch.Tensor,
          c_pos: torch.Tensor, c_neg: torch.Tensor, refractory_ns: int, tol: float
          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Events of the samples ``logs[1:]`` after ``logs[0]``; updates ``ref``/``last_t``.

    Args:
        logs: float32 (T, H, W) log intensity, contiguous; T >= 2.
        times: int64 (T,) sample times in ns, increasing.
        ref, last_t, c_pos, c_neg: (H, W) sensor state and thresholds as in
            :func:`esim_lite.events.torch_kernel.torch_step`, contiguous.
    All on one device: CUDA (compiled) or the CPU (Triton's interpreter; slow, for tests).
    Returns:
        (x, y, t, p) int16, int16, int64, int8 (N,) in the simulator's order.
    """
    n_steps, h, w = logs.shape
    n_px = h * w
    dev = logs.device
    if n_steps * n_px >= 2**31:
        raise ValueError(f"{n_steps} samples of {h}x{w} exceed one launch; pass fewer")
    if dev.type == "cpu" and not interpreting():
        raise ValueError("the Triton event kernel runs on CPU tensors only in Triton's "
                         "interpreter: set TRITON_INTERPRET=1 before triton is imported")
    kern = _kernel()
    tol_t = torch.tensor([tol], dtype=torch.float64, device=dev)
    counts = torch.empty((n_steps - 1, n_px), dtype=torch.int32, device=dev)  # pass 1 fills it
    grid = (triton.cdiv(n_px, BLOCK),)
    extra = {} if dev.type == "cpu" else COMPILE_OPTIONS
    unused = event_buffers(1, dev)  # pass 1 writes no events and reads no offsets
    no_offsets = torch.empty(1, dtype=torch.int64, device=dev)
    kern[grid](logs, times, tol_t, ref, last_t, c_pos, c_neg, counts, no_offsets, *unused,
               n_px, w, n_steps, int(refractory_ns), False, BLOCK, **extra)
    flat = counts.reshape(-1).to(torch.int64)
    ends = torch.cumsum(flat, 0)
    total = int(ends[-1]) if flat.numel() else 0
    offsets = (ends - flat).reshape(n_steps - 1, n_px)
    out = event_buffers(total, dev) if total else unused  # pass 2 also writes the state
    kern[grid](logs, times, tol_t, ref, last_t, c_pos, c_neg, counts, offsets, *out, n_px, w,
               n_steps, int(refractory_ns), True, BLOCK, **extra)
    if total == 0:
        return event_buffers(0, dev)
    order = torch.sort(out[2], stable=True).indices
    return tuple(v[order] for v in out)
