"""Event generation throughput: compiled kernel, numpy, a per-pixel Python loop and esim_py.

Run: .venv/bin/python bench/bench_events.py [--frames N] [--repeats R]
         [--esim-py bench/esim_py/build]   (after: bash bench/esim_py/build.sh PATH/TO/rpg_vid2e)
         [--torch cpu cuda]                (the torch kernel on these devices; default: cpu,
                                            and cuda when torch sees a GPU)

Frames are rendered first (homography, 128x128, photo texture, a default-speed trajectory)
and kept in memory as 8-bit images, the input esim_py reads. Two densities: a ``sparse`` case
(frames 0.8 ms apart, about 0.02 events per pixel per step) and a ``dense`` one (the same
texture moving fast: frames 7 ms apart, about 0.15). Timed, on one pinned core:

- kernel: the bare per-pixel state update on float32 log images (numba, numpy, Python; the
  compiled kernel also puts its events in time order, the others leave that to the step);
- full: from 8-bit frames in memory to one time-sorted event list: ``EventSimulator.step``
  per frame (u8 -> linear -> log, kernel, time order, Events record) and the final
  ``Events.concatenate``; for esim_py, its own per-frame conversion (convertTo, cv::log),
  ``imageCallback`` (crossings, per-frame std::sort) and the (N, 4) result matrix; for the
  torch kernel (``esim_lite.events.torch_kernel``), the 8-bit frames as one tensor moved to the
  device, u8 -> linear -> log there, ``TorchEventCamera.simulate`` (state on the device;
  backend ``torch``: one vectorised step per frame; ``triton``, on CUDA: the whole stack in
  two launches) and the events back on the host as an ``Events`` record.

Like for like: the same frames, ``log(u8 / 255 + 1e-3)``, Cp = Cn = 0.2, no refractory
period, no noise; the ``numba + noise`` / ``+ low-pass`` rows add DAVIS-like noise and a
300 Hz photoreceptor low-pass (``full`` only: they are steps of the simulator, not of the
kernel). Every implementation is timed in turn within each repeat (medians), so a
slow spell of the machine falls on all alike. The Python loop runs once, on the first 30
frames only (~10^3 times slower).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from dataclasses import dataclass

import cv2
import numpy as np
from skimage import data

from esim_lite.core.events import Events
from esim_lite.events.bandwidth import BandwidthConfig
from esim_lite.events.kernel import NEVER, TIE_TOL
from esim_lite.events.noise import NoiseConfig, NoiseModel
from esim_lite.events.reference import numpy_step, python_step
from esim_lite.events.simulator import EventSimulator, _NumbaKernel, log_intensity
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import TrajectoryConfig, plane_extent_covering, sample_trajectory
from esim_lite.render.renderer import RenderConfig, make_renderer

THRESHOLD = 0.2
LOG_EPS = 1e-3
CASES = {"sparse": 0.8, "dense": 7.0}  # ms between frames


def make_frames(n: int, step_s: float) -> np.ndarray:
    """uint8[n + 1, 128, 128] frames of a textured plane along a smooth trajectory."""
    cam = Intrinsics.from_fov(128, 128, 60.0)
    traj = sample_trajectory(TrajectoryConfig(), 2.0, cam, np.random.default_rng(1))
    tex = cv2.resize(data.camera().astype(np.float32) / 255, (1024, 1024)).clip(0.01, 1)
    traj, w, h = plane_extent_covering(traj, cam, 1.0)
    r = make_renderer(PlanarScene(cv2.GaussianBlur(tex, (0, 0), 1.0), w, h), {"lr": cam},
                      RenderConfig(backend="homography"))
    times = np.arange(n + 1) * step_s
    times = times % (2 * traj.duration_s)  # ping-pong along the trajectory if it is short
    times = np.where(times > traj.duration_s, 2 * traj.duration_s - times, times)
    return np.stack([np.round(r.render("lr", traj.pose(t)).clip(0, 1) * 255).astype(np.uint8)
                     for t in times])


def linear(u8: np.ndarray) -> np.ndarray:
    return u8.astype(np.float32) * np.float32(1 / 255)


def kernel_run(kernel, logs: np.ndarray) -> int:
    """All steps of a bare kernel from fresh state; returns the number of events."""
    th = ContrastThresholds.uniform(THRESHOLD, THRESHOLD, logs.shape[1:])
    ref = logs[0].astype(np.float64)
    last = np.full(logs.shape[1:], NEVER, np.int64)
    n_events = 0
    for k in range(1, len(logs)):
        out = kernel(logs[k - 1], logs[k], ref, last, th.pos_map, th.neg_map,
                     (k - 1) * 1000, k * 1000, 0, TIE_TOL)
        n_events += len(out[0])
    return n_events


#: The sensor options of the "numba + ..." rows: DAVIS-like noise rates (shot 0.1 Hz, 0.1%
#: hot pixels at 10 Hz, leak 0.2 Hz per pixel) and a 300 Hz photoreceptor (v2e's default).
NOISE = NoiseConfig(shot_rate_hz=0.1, hot_pixel_fraction=1e-3, hot_pixel_rate_hz=10.0,
                    leak_rate_hz=0.2)
LOW_PASS = BandwidthConfig(cutoff_hz=300.0)


def simulate(kind: str, frames: np.ndarray, step_ns: int, noise: bool = False,
             low_pass: bool = False) -> Events:
    """Frames in memory -> one time-sorted event list, with e2sr's EventSimulator (with
    :data:`NOISE` and/or :data:`LOW_PASS` when asked)."""
    th = ContrastThresholds.uniform(THRESHOLD, THRESHOLD, frames.shape[1:])
    model = NoiseModel(NOISE, frames.shape[1:], np.random.default_rng(0)) if noise else None
    sim = EventSimulator(linear(frames[0]), 0, th, log_eps=LOG_EPS, kernel=kind, noise=model,
                         bandwidth=LOW_PASS if low_pass else None)
    parts = [sim.step(linear(frames[k]), k * step_ns) for k in range(1, len(frames))]
    return Events.concatenate(parts, frames.shape[1:])


def torch_kernel_run(logs, device, backend: str) -> int:
    """All steps of the bare torch (per step) or Triton (per stack) kernel on log images
    already on ``device``; returns the number of events."""
    import torch

    from esim_lite.events.torch_kernel import torch_step

    h, w = logs.shape[1:]
    c = torch.full((h, w), THRESHOLD, dtype=torch.float64, device=device)
    ref = logs[0].to(torch.float64)
    last = torch.full((h, w), NEVER, dtype=torch.int64, device=device)
    if backend == "triton":
        from esim_lite.events.triton_kernel import sweep

        times = torch.arange(len(logs), dtype=torch.int64, device=device) * 1000
        n_events = sweep(logs, times, ref, last, c, c, 0, TIE_TOL)[0].numel()
    else:
        n_events = 0
        for k in range(1, len(logs)):
            n_events += torch_step(logs[k - 1], logs[k], ref, last, c, c, (k - 1) * 1000,
                                   k * 1000, 0, TIE_TOL)[0].numel()
    if device.type == "cuda":
        torch.cuda.synchronize()
    return n_events


def torch_simulate(frames: np.ndarray, step_ns: int, device, backend: str) -> Events:
    """Frames in memory -> one time-sorted event list, with the torch camera on ``device``."""
    import torch

    from esim_lite.events.torch_kernel import TorchEventCamera

    th = ContrastThresholds.uniform(THRESHOLD, THRESHOLD, frames.shape[1:])
    u8 = torch.from_numpy(frames).to(device)
    logs = torch.log(u8.to(torch.float32) * np.float32(1 / 255) + np.float32(LOG_EPS))
    cam = TorchEventCamera(th, device=device, backend=backend)
    return cam.simulate(logs, [k * step_ns for k in range(len(frames))])


def torch_variants(devices: list[str]) -> list[tuple[str, str]]:
    """(device, backend) pairs to time: per-step torch everywhere, Triton on CUDA."""
    import importlib.util

    out = []
    for dev in devices:
        out.append((dev, "torch"))
        if dev.startswith("cuda") and importlib.util.find_spec("triton") is not None:
            out.append((dev, "triton"))
    return out


def esim_py_events(module, frames: np.ndarray, step_ns: int) -> np.ndarray:
    sim = module.EventSimulator(THRESHOLD, THRESHOLD, 0.0, LOG_EPS, True)
    return module.generate_from_frames(sim, frames, [k * step_ns * 1e-9
                                                     for k in range(len(frames))])


def interleaved(jobs: dict, repeats: int) -> dict:
    """Median seconds and last result of each job, the jobs taking turns in every repeat
    (so that a slower or faster spell of the machine falls on all of them alike)."""
    runs = {name: [] for name in jobs}
    out = {}
    for _ in range(repeats):
        for name, job in jobs.items():
            start = time.perf_counter()
            out[name] = job()
            runs[name].append(time.perf_counter() - start)
    return {name: (statistics.median(runs[name]), out[name]) for name in jobs}


@dataclass
class Row:
    case: str
    name: str
    kernel_ups: float | None  # pixel-updates/s of the bare kernel
    full_ups: float  # pixel-updates/s frames -> sorted list
    events: int
    density: float


def run_case(case: str, step_ms: float, n_frames: int, repeats: int, esim_py,
             torch_devices: list[str]) -> list[Row]:
    frames = make_frames(n_frames, step_ms * 1e-3)
    logs = log_intensity(linear(frames), LOG_EPS)
    step_ns = int(round(step_ms * 1e6))
    px = frames.shape[1] * frames.shape[2]
    impls = {"numba (compiled)": (_NumbaKernel(), "numba", len(frames)),
             "numpy per frame": (numpy_step, "numpy", len(frames))}
    jobs = {}
    for name, (kernel, kind, n) in impls.items():
        jobs[name + "/kernel"] = lambda kernel=kernel, n=n: kernel_run(kernel, logs[:n])
        jobs[name + "/full"] = lambda kind=kind, n=n: simulate(kind, frames[:n], step_ns)
    sensor = {"numba + noise": (True, False), "numba + low-pass": (False, True),
              "numba + noise + low-pass": (True, True)}
    for name, (noise, low_pass) in sensor.items():
        jobs[name + "/full"] = lambda noise=noise, low_pass=low_pass: simulate(
            "numba", frames, step_ns, noise, low_pass)
    torch_names = []
    if torch_devices:
        import torch
    for dev, backend in torch_variants(torch_devices):
        device = torch.device(dev)
        name = f"{backend} ({dev})"
        torch_names.append(name)
        dev_logs = torch.from_numpy(logs).to(device)
        jobs[name + "/kernel"] = lambda d=device, g=dev_logs, b=backend: torch_kernel_run(g, d, b)
        jobs[name + "/full"] = lambda d=device, b=backend: torch_simulate(frames, step_ns, d, b)
    if esim_py is not None:
        jobs["esim_py (C++, from memory)/full"] = lambda: esim_py_events(esim_py, frames,
                                                                          step_ns)
    timed = interleaved(jobs, repeats)
    python_n = 31  # the Python loop: once, on the first 30 steps
    timed.update(interleaved({
        "python per-pixel loop/kernel": lambda: kernel_run(python_step, logs[:python_n]),
        "python per-pixel loop/full": lambda: simulate("python", frames[:python_n], step_ns)},
        1))
    rows = []
    for name in [*impls, *sensor, *torch_names, "python per-pixel loop",
                 "esim_py (C++, from memory)"]:
        if name + "/full" not in timed:
            continue
        n = python_n if name.startswith("python") else len(frames)
        updates = px * (n - 1)
        full, events = timed[name + "/full"]
        kernel = timed.get(name + "/kernel", (None,))[0]
        rows.append(Row(case, name, updates / kernel if kernel else None, updates / full,
                        len(events), len(events) / updates))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--esim-py", metavar="DIR",
                        help="folder holding the esim_py_memory module (bench/esim_py/build.sh)")
    parser.add_argument("--torch", nargs="*", metavar="DEVICE", default=None,
                        help="torch devices to time (default: cpu, and cuda when present; "
                             "none: --torch with no device)")
    parser.add_argument("--core", type=int, default=None,
                        help="CPU core to pin to (default: the last one available)")
    args = parser.parse_args(argv)
    core = args.core if args.core is not None else max(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    cv2.setNumThreads(1)
    esim_py = None
    if args.esim_py:
        sys.path.insert(0, args.esim_py)
        import esim_py_memory as esim_py
    torch_devices = args.torch
    if torch_devices is None:
        import torch

        torch_devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    if torch_devices:
        import torch

        torch.set_num_threads(1)  # the CPU side on the pinned core too
    warm = make_frames(3, 1e-3)  # compile
    simulate("numba", warm, 1000), kernel_run(_NumbaKernel(), log_intensity(linear(warm),
                                                                            LOG_EPS))
    for dev, backend in torch_variants(torch_devices):  # CUDA context, Triton compile
        torch_simulate(warm, 1000, torch.device(dev), backend)
    rows = [r for case in args.cases
            for r in run_case(case, CASES[case], args.frames, args.repeats, esim_py,
                              torch_devices)]
    print(f"# {' '.join(['python'] + sys.argv)}")
    print(f"# 128x128, {args.frames} steps, C = {THRESHOLD}, 8-bit frames in memory, "
          f"one core (cpu {core})"
          + (f"; torch {torch.__version__}" if torch_devices else "")
          + (f", GPU {torch.cuda.get_device_name()}" if "cuda" in torch_devices else ""))
    print("| case | implementation | events/px/step | events | kernel Mpx-updates/s |"
          " full Mpx-updates/s | full vs esim_py |")
    print("|---|---|---|---|---|---|---|")
    for case in args.cases:
        mine = [r for r in rows if r.case == case]
        ref = next((r.full_ups for r in mine if r.name.startswith("esim_py")), None)
        for r in mine:
            kern = f"{r.kernel_ups / 1e6:.1f}" if r.kernel_ups else "-"
            vs = f"{r.full_ups / ref:.2f}x" if ref else "-"
            print(f"| {case} | {r.name} | {r.density:.4f} | {r.events:,} | {kern} | "
                  f"{r.full_ups / 1e6:.1f} | {vs} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
