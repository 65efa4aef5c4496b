"""Per-sequence random draws: texture, plane, trajectory and thresholds from (seed, index).

Each sequence owns a ``SeedSequence([seed, index])``; its components draw from independent
child streams, so a sequence is the same whichever worker, shard or order produces it, and
changing e.g. the texture source leaves trajectories and thresholds unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from datagen.textures import TextureSampler
from esim_lite.config import SimulationConfig
from esim_lite.events.thresholds import ContrastThresholds, sample_thresholds
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import (
    BSplineTrajectory,
    plane_extent_covering,
    sample_trajectory,
)


def sequence_streams(seed: int, index: int) -> dict[str, np.random.Generator]:
    """Independent generators for each random component of sequence ``index``."""
    names = ("trajectory", "texture", "thresholds", "noise")
    children = np.random.SeedSequence([int(seed), int(index)]).spawn(len(names))
    return {n: np.random.default_rng(c) for n, c in zip(names, children)}


@dataclass(frozen=True, eq=False)
class SequenceSpec:
    """Everything drawn for one sequence before simulating it."""

    index: int
    seed: int
    scene: PlanarScene
    trajectory: BSplineTrajectory
    thresholds: ContrastThresholds
    texture_name: str
    noise_rng: np.random.Generator


def texture_width(sim: SimulationConfig, plane_width_m: float) -> int:
    """Texels across the plane so the largest HR camera sees >= 1 texel per pixel even at the
    closest camera height."""
    rig = sim.camera.rig()
    f_hr = rig.event.fx * max(sim.camera.scales)
    return int(np.ceil(plane_width_m * f_hr / sim.trajectory.height_m[0]))


def sample_sequence(sim: SimulationConfig, textures: TextureSampler, seed: int, index: int
                    ) -> SequenceSpec:
    """Draw sequence ``index`` of the dataset with master ``seed``."""
    rng = sequence_streams(seed, index)
    rig = sim.camera.rig()
    traj = sample_trajectory(sim.trajectory, sim.duration_s, rig.event, rng["trajectory"])
    traj, width_m, height_m = plane_extent_covering(traj, rig.event, aspect=None)
    tex, name = textures.sample(rng["texture"], width_m / height_m,
                                texture_width(sim, width_m))
    thresholds = sample_thresholds(sim.events.thresholds, rig.event.hw, rng["thresholds"])
    return SequenceSpec(index, seed, PlanarScene(tex, width_m, height_m), traj, thresholds,
                        name, rng["noise"])
