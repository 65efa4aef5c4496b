"""The same sequences simulated with both render backends: events, samples and time.

Run: .venv/bin/python bench/compare_backends.py [--n-seq N] [--seed S]
Sequence i of dataset seed S (default config: 128x128, x2, built-in textures) is simulated
once with the exact homography renderer and once with Mitsuba; the table shows how close
the event streams are and what each costs. "off by > 10 us": the share of events of either
stream with no event of the same pixel and polarity in the other within 10 us. The
adaptive sampler picks its next time from the image it just saw, so last-bit render
differences move the sample times, and with them the interpolated timestamps (by ~0.2 us
typically); a pixel grazing a threshold fires in one stream only. The renders themselves
are compared at the same 20 poses along the trajectory: largest |difference| of
``log(I + eps)`` over all pixels, for the event camera and the HR camera.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from datagen.config import DatagenConfig
from datagen.sampling import sample_sequence
from datagen.textures import TextureSampler
from esim_lite.render.renderer import make_renderer
from esim_lite.sequence import sample_footprints, simulate_sequence


def run(config: DatagenConfig, backend: str, seed: int, index: int):
    render = dataclasses.replace(config.simulation.render, backend=backend)
    sim = dataclasses.replace(config.simulation, render=render)
    spec = sample_sequence(sim, TextureSampler(config.textures), seed, index)
    start = time.perf_counter()
    seq = simulate_sequence(spec.scene, spec.trajectory, spec.thresholds, sim, spec.noise_rng)
    return seq, time.perf_counter() - start, spec


def render_gap(config: DatagenConfig, spec, n_poses: int = 20) -> dict:
    """Per camera, the largest |log(I + eps) difference| between the backends' renders of
    the same ``n_poses`` poses of the sampled sequence ``spec``."""
    sim = config.simulation
    rig = sim.camera.rig()
    poses = [spec.trajectory.pose(t) for t in np.linspace(0, sim.duration_s, n_poses)]
    logs = {}
    for backend in ("homography", "mitsuba"):
        cfg = dataclasses.replace(sim.render, backend=backend)
        renderer = make_renderer(spec.scene, rig.cameras(), cfg,
                                 sample_footprints(spec.scene, spec.trajectory, rig, cfg))
        logs[backend] = {name: np.log(np.stack([renderer.render(name, p) for p in poses])
                                      .astype(np.float64) + sim.events.log_eps)
                         for name in rig.cameras()}
        renderer.close()
    return {name: float(np.abs(logs["mitsuba"][name] - logs["homography"][name]).max())
            for name in rig.cameras()}


def unmatched(a, b, tol_ns: int = 10_000) -> int:
    """Events of ``a`` with no event of the same pixel and polarity in ``b`` within
    ``tol_ns``, plus the same the other way round."""
    span = max(int(e.t_ns.max()) if len(e) else 0 for e in (a, b)) + 2 * tol_ns + 1

    def keys(ev):  # (pixel, polarity) major, time minor: one sorted int64 per event
        cell = (ev.y.astype(np.int64) * ev.sensor_hw[1] + ev.x) * 2 + (ev.p > 0)
        return np.sort(cell * span + ev.t_ns)

    def missing(src, dst):
        if len(dst) < 2:
            return len(src)
        i = np.clip(np.searchsorted(dst, src), 1, len(dst) - 1)
        near = np.minimum(np.abs(dst[i] - src), np.abs(dst[i - 1] - src))
        return int(np.count_nonzero(near > tol_ns))

    ka, kb = keys(a), keys(b)
    return missing(ka, kb) + missing(kb, ka)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n-seq", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    config = DatagenConfig()
    print(f"# {' '.join(['python'] + sys.argv)}")
    print("| seq | texture | events homography | events mitsuba | difference | off by > 10 us "
          "| max log gap lr / hr | samples | s homography | s mitsuba | mitsuba / homography |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    totals = np.zeros(5)
    for i in range(args.n_seq):
        a, ta, spec = run(config, "homography", args.seed, i)
        b, tb, _ = run(config, "mitsuba", args.seed, i)
        gap = render_gap(config, spec)
        name = spec.texture_name
        diff = (len(b.events) - len(a.events)) / len(a.events)
        lost = unmatched(a.events, b.events)
        totals += [len(a.events), len(b.events), lost, ta, tb]
        print(f"| {i} | {name} | {len(a.events):,} | {len(b.events):,} | {diff:+.4%} | "
              f"{lost / (len(a.events) + len(b.events)):.2%} | {gap['lr']:.1e} / "
              f"{gap['hr_x2']:.1e} | {len(a.sample_poses):,} | {ta:.1f} | {tb:.1f} | "
              f"{tb / ta:.2f} |", flush=True)
    ne_a, ne_b, lost, ta, tb = totals
    print(f"| all | | {ne_a:,.0f} | {ne_b:,.0f} | {(ne_b - ne_a) / ne_a:+.4%} | "
          f"{lost / (ne_a + ne_b):.2%} | | | {ta:.1f} | {tb:.1f} | {tb / ta:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
