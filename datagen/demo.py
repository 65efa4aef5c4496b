"""Simulate one sequence and draw what the cameras saw (the project's first main job)."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from datagen.config import DatagenConfig
from datagen.preview import contact_sheet, event_image, gray_to_rgb, write_png
from datagen.sampling import SequenceSpec, sample_sequence
from datagen.textures import TextureSampler
from esim_lite.sequence import SimulatedSequence, simulate_sequence

log = logging.getLogger(__name__)


def sequence_sheet(seq: SimulatedSequence, spec: SequenceSpec, backend: str, rows: int = 3
                   ) -> np.ndarray:
    """Contact sheet: for a few frames, the LR frame, each HR frame and the events since the
    previous frame."""
    lr = seq.frames["lr"]
    hr_names = [n for n in seq.frames if n != "lr"]
    picks = np.linspace(1, len(lr) - 1, rows).round().astype(int)
    panels = []
    for k in picks:
        t0, t1 = int(lr.t_ns[k - 1]), int(lr.t_ns[k])
        row = [(gray_to_rgb(lr.intensity[k]), f"LR {lr.hw[1]}x{lr.hw[0]} t={t1 / 1e6:.0f} ms")]
        row += [(gray_to_rgb(seq.frames[n].intensity[k]), f"{n} {seq.frames[n].hw[1]}x"
                 f"{seq.frames[n].hw[0]}") for n in hr_names]
        n_ev = int(np.searchsorted(seq.events.t_ns, t1) - np.searchsorted(seq.events.t_ns, t0))
        row.append((event_image(seq.events, t0, t1), f"events ({t0 / 1e6:.0f}, {t1 / 1e6:.0f}] ms:"
                    f" {n_ev}"))
        panels.append(row)
    th = seq.thresholds
    title = (f"sequence {spec.index} (seed {spec.seed}), {backend} renderer, texture "
             f"{spec.texture_name}\nC+ = {th.pos:.3f}, C- = {th.neg:.3f}, "
             f"{len(seq.events):,} events over {lr.t_ns[-1] / 1e9:.2f} s, "
             f"{len(seq.sample_poses):,} render samples")
    return contact_sheet(panels, title)


def run_demo(config: DatagenConfig, out_dir: str | Path, seed: int = 0, index: int = 0
             ) -> Path:
    """Simulate sequence ``index`` of dataset ``seed``; write and return the sheet's path."""
    sim = config.simulation
    spec = sample_sequence(sim, TextureSampler(config.textures), seed, index)
    start = time.perf_counter()
    seq = simulate_sequence(spec.scene, spec.trajectory, spec.thresholds, sim, spec.noise_rng)
    log.info("simulated %.2f s in %.1f s: %d events, %d render samples", sim.duration_s,
             time.perf_counter() - start, len(seq.events), len(seq.sample_poses))
    sheet = sequence_sheet(seq, spec, sim.render.backend)
    return write_png(Path(out_dir) / f"demo_seq{index:04d}.png", sheet)
