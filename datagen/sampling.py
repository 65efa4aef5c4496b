"""Per-sequence random draws: texture, plane, trajectory, thresholds and moving objects
from (seed, index).

Each sequence owns a ``SeedSequence([seed, index])``; its components draw from independent
child streams, so a sequence is the same whichever worker, shard or order produces it, and
changing e.g. the texture source leaves trajectories and thresholds unchanged. The objects
(and the static-camera draw) have streams of their own, after the original four, so a
configuration without objects draws exactly what it drew before objects existed; the
sensor (``sensor_ranges``) and the flat static-camera background have the last ones, for
the same reason.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from datagen.sensor_ranges import SensorRanges
from datagen.textures import TextureSampler, flat_background
from esim_lite.config import SimulationConfig
from esim_lite.events.simulator import EventConfig
from esim_lite.events.thresholds import ContrastThresholds, sample_thresholds
from esim_lite.geometry.object_sampling import sample_objects, static_trajectory
from esim_lite.geometry.objects import DynamicScene, ObjectPatch
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import (
    BSplineTrajectory,
    plane_extent_covering,
    sample_trajectory,
)


def sequence_streams(seed: int, index: int) -> dict[str, np.random.Generator]:
    """Independent generators for each random component of sequence ``index``."""
    names = ("trajectory", "texture", "thresholds", "noise", "objects", "object_textures",
             "sensor", "background")
    children = np.random.SeedSequence([int(seed), int(index)]).spawn(len(names))
    return {n: np.random.default_rng(c) for n, c in zip(names, children)}


@dataclass(frozen=True, eq=False)
class SequenceSpec:
    """Everything drawn for one sequence before simulating it.

    ``events`` is the sequence's sensor: the config's own (the same object) unless
    ``sensor_drawn``, when it was drawn from the dataset's ``sensor_ranges``.
    """

    index: int
    seed: int
    scene: PlanarScene | DynamicScene
    trajectory: BSplineTrajectory
    thresholds: ContrastThresholds
    texture_name: str
    noise_rng: np.random.Generator
    events: EventConfig
    static_camera: bool = False
    sensor_drawn: bool = False

    @property
    def objects(self) -> tuple[ObjectPatch, ...]:
        return self.scene.objects if isinstance(self.scene, DynamicScene) else ()

    @property
    def background(self) -> PlanarScene:
        return self.scene.background if isinstance(self.scene, DynamicScene) else self.scene


def texture_width(sim: SimulationConfig, plane_width_m: float) -> int:
    """Texels across the plane so the largest HR camera sees >= 1 texel per pixel even at the
    closest camera height."""
    rig = sim.camera.rig()
    f_hr = rig.event.fx * max(sim.camera.scales)
    return int(np.ceil(plane_width_m * f_hr / sim.trajectory.height_m[0]))


def sample_sequence(sim: SimulationConfig, textures: TextureSampler, seed: int, index: int,
                    sensor: SensorRanges | None = None) -> SequenceSpec:
    """Draw sequence ``index`` of the dataset with master ``seed``; with ``sensor`` ranges
    on, its sensor too (everything else then sees that sensor: thresholds' mismatch, the
    static-camera rule)."""
    rng = sequence_streams(seed, index)
    drawn = sensor is not None and sensor.enabled
    if drawn:
        sim = dataclasses.replace(sim, events=sensor.draw(sim.events, rng["sensor"]))
    rig = sim.camera.rig()
    traj = sample_trajectory(sim.trajectory, sim.duration_s, rig.event, rng["trajectory"])
    n_objects, static = draw_dynamics(sim, rng["objects"])
    if static:
        traj = static_trajectory(traj.pose(0.0), sim.duration_s, traj.knot_spacing_s)
    traj, width_m, height_m = plane_extent_covering(traj, rig.event, aspect=None)
    aspect, texels = width_m / height_m, texture_width(sim, width_m)
    flat_share = sim.objects.flat_background_share
    if static and flat_share > 0 and rng["background"].random() < flat_share:
        tex, name = flat_background(textures.shape(aspect, texels), rng["background"]), \
            "flat background"
    else:  # (the texture stream serves only this draw: skipping it changes nothing else)
        tex, name = textures.sample(rng["texture"], aspect, texels)
    thresholds = sample_thresholds(sim.events.thresholds, rig.event.hw, rng["thresholds"])
    plane = PlanarScene(tex, width_m, height_m)
    if not sim.objects.enabled:
        return SequenceSpec(index, seed, plane, traj, thresholds, name, rng["noise"],
                            sim.events, sensor_drawn=drawn)
    finest = rig.event.fx * max(sim.camera.scales)
    draws = sample_objects(sim.objects, n_objects, sim.duration_s, rig.event, finest, traj,
                           rng["objects"])
    objects = []
    for draw in draws:
        otex, oname = textures.sample(rng["object_textures"], draw.width_m / draw.height_m,
                                      draw.texture_width)
        otex = cv2.resize(otex, draw.alpha.shape[::-1], interpolation=cv2.INTER_AREA) \
            if otex.shape != draw.alpha.shape else otex
        objects.append(ObjectPatch(PlanarScene(np.ascontiguousarray(otex, np.float32),
                                               draw.width_m, draw.height_m),
                                   draw.alpha, draw.trajectory, f"{oname} ({draw.shape})"))
    return SequenceSpec(index, seed, DynamicScene(plane, tuple(objects)), traj, thresholds,
                        name, rng["noise"], sim.events, static, drawn)


def draw_dynamics(sim: SimulationConfig, rng: np.random.Generator) -> tuple[int, bool]:
    """(object count, static camera?) of one sequence. A static camera with nothing moving
    is redrawn with at least one object, unless sensor noise is on (then noise alone is a
    sequence)."""
    cfg = sim.objects
    if not cfg.enabled:
        return 0, False
    static = bool(rng.random() < cfg.static_camera_share)
    lo, hi = cfg.count
    if static and not sim.events.noise.enabled:
        lo = max(lo, 1)
    return int(rng.integers(lo, hi + 1)), static
