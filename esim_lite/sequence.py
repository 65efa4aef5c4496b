"""Simulate one sequence: render along the trajectory, emit events, render frames."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from esim_lite.config import FrameConfig, SimulationConfig
from esim_lite.core.events import Events
from esim_lite.core.frames import Frames
from esim_lite.core.streams import derived_rng
from esim_lite.events.flicker import Flicker
from esim_lite.events.latency import readout_rng
from esim_lite.events.noise import NoiseModel
from esim_lite.events.sampling import AdaptiveSampler
from esim_lite.events.simulator import EventConfig, EventSimulator, log_intensity
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.geometry.camera import CameraRig
from esim_lite.geometry.objects import DynamicScene, as_dynamic
from esim_lite.geometry.pose import Pose, Twist
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import BSplineTrajectory
from esim_lite.geometry.visibility import SurfaceTruth, surface_truth
from esim_lite.render.antialias import texels_per_sample
from esim_lite.render.renderer import RenderConfig, Renderer, make_renderer, supersample_for

#: Spawn key of the pixels' random starting points (``events.random_start``).
START_STREAM_KEY = 0x57A7


@dataclass(frozen=True, eq=False)
class FrameSample:
    """All cameras rendered at one frame time: ``images[name]`` is float32[H, W].

    ``object_poses``: the objects' object-to-world poses at the frame (none for a plane
    alone); ``truth[name]``: per-pixel flow, depth and surface ids of each camera, when the
    configuration asks for ground truth (``frames.ground_truth``).
    """

    t_ns: int
    pose: Pose
    images: dict[str, np.ndarray]
    object_poses: tuple[Pose, ...] = ()
    truth: dict[str, SurfaceTruth] | None = None


@dataclass(frozen=True, eq=False)
class SimulationChunk:
    """A piece of a sequence in time order.

    Attributes:
        events: events since the previous chunk.
        frames: frames whose time was passed since the previous chunk.
        sample_poses: float64[S, 8] ``t_s, tx, ty, tz, qx, qy, qz, qw`` at every render
            sample (the adaptive time grid) in this chunk.
    """

    events: Events
    frames: list[FrameSample]
    sample_poses: np.ndarray


@dataclass(frozen=True, eq=False)
class SimulatedSequence:
    """A whole simulated sequence (see :func:`simulate_sequence`)."""

    events: Events
    frames: dict[str, Frames]
    frame_poses: np.ndarray
    sample_poses: np.ndarray
    rig: CameraRig
    thresholds: ContrastThresholds


def frame_times_ns(duration_s: float, frame_rate_hz: float) -> np.ndarray:
    """int64 frame timestamps ``k / rate`` for ``k = 0 ..`` up to the duration."""
    n = int(np.floor(duration_s * frame_rate_hz + 1e-9)) + 1
    return np.round(np.arange(n) * (1e9 / frame_rate_hz)).astype(np.int64)


class FrameSchedule:
    """Decides when frames are due (see :class:`FrameConfig`) and when the sequence is done.

    A frame is always due at t = 0; :meth:`due` then gets every event batch in time order.
    """

    def __init__(self, config: FrameConfig, duration_s: float) -> None:
        self.config = config
        self.rate_times = frame_times_ns(duration_s, config.rate_hz)[1:]
        self.n_frames = 1
        self.events_seen = 0
        self.events_at_last_frame = 0
        self._next = 0 if config.mode == "rate" else config.every_events

    def due(self, batch: Events, t_ns: int) -> list[int]:
        """Frame times (ns) falling in the step that produced ``batch`` and ended at ``t_ns``."""
        cfg, times = self.config, []
        room = np.inf if cfg.count is None else cfg.count - self.n_frames
        if cfg.mode == "rate":
            while len(times) < room and self._next < len(self.rate_times) and \
                    self.rate_times[self._next] <= t_ns:
                ft = int(self.rate_times[self._next])
                times.append(ft)
                self._next += 1
                self.events_at_last_frame = self.events_seen + int(
                    np.searchsorted(batch.t_ns, ft, side="right"))
        else:
            while len(times) < room and self._next <= self.events_seen + len(batch):
                times.append(int(batch.t_ns[self._next - self.events_seen - 1]))
                self.events_at_last_frame = self._next
                self._next += cfg.every_events
        self.n_frames += len(times)
        self.events_seen += len(batch)
        return times

    def done(self) -> bool:
        cfg = self.config
        return (cfg.count is not None and self.n_frames >= cfg.count
                and self.events_seen >= self.events_at_last_frame + cfg.tail_events)


def _pose_row(t_ns: int, pose: Pose) -> np.ndarray:
    return np.concatenate([[t_ns * 1e-9], pose.to_tq()])


def sample_footprints(scene: PlanarScene | DynamicScene, trajectory: BSplineTrajectory,
                      rig: CameraRig, config: RenderConfig) -> dict[str, float]:
    """Per camera, the largest texels-per-sample of the background over the trajectory (for
    prefiltering)."""
    plane = as_dynamic(scene).background
    poses = [trajectory.pose(t) for t in trajectory.sample_times(0.01)]
    return {name: texels_per_sample(plane, cam, supersample_for(name, config), poses)
            for name, cam in rig.cameras().items()}


class _Stage:
    """Everything that moves, evaluated at one time: the camera and the objects."""

    def __init__(self, scene: DynamicScene, trajectory: BSplineTrajectory, rig: CameraRig,
                 truth: bool) -> None:
        self.scene, self.trajectory, self.rig, self.truth = scene, trajectory, rig, truth

    def at(self, t_ns: int) -> tuple[Pose, Twist, tuple[Pose, ...], tuple[Twist, ...]]:
        pose, twist = self.trajectory.pose_and_twist(t_ns * 1e-9)
        poses, twists = self.scene.object_motion(t_ns * 1e-9)
        return pose, twist, poses, twists

    def motion(self, pose: Pose, twist: Twist, poses: tuple[Pose, ...],
               twists: tuple[Twist, ...]) -> tuple[np.ndarray | None, np.ndarray | None]:
        """float32[2, H, W] motion field of what the event camera sees and uint8[H, W] the
        surface ids (None, None: a plane alone, whose flow the sampler computes itself)."""
        if not self.scene.objects:
            return None, None
        gt = surface_truth(self.scene, self.rig.event, pose, twist, poses, twists)
        return gt.flow, gt.ids

    def frame(self, renderer: Renderer, t_ns: int) -> FrameSample:
        pose, twist, poses, twists = self.at(t_ns)
        images = {n: renderer.render(n, pose, poses) for n in renderer.cameras}
        truth = None
        if self.truth:
            cams = self.rig.cameras()
            truth = {n: surface_truth(self.scene, cams[n], pose, twist, poses, twists)
                     for n in renderer.cameras}
        return FrameSample(t_ns, pose, images, poses, truth)


def simulate(scene: PlanarScene | DynamicScene, trajectory: BSplineTrajectory,
             thresholds: ContrastThresholds,
             config: SimulationConfig, rng: np.random.Generator,
             renderer: Renderer | None = None, chunk_events: int = 1_000_000,
             ) -> Iterator[SimulationChunk]:
    """Stream a sequence as chunks of about ``chunk_events`` events (bounded memory).

    Args:
        scene, trajectory: what is seen (a plane, or a plane with moving objects) and how
            the rig moves; the trajectory must last at least ``config.duration_s``.
        thresholds: the event camera's thresholds (see :func:`sample_thresholds`).
        rng: drives the noise model, the lamp and the readout jitter (a stream derived
            from it without drawing from it); everything else is already drawn.
        renderer: a renderer for ``config.camera.rig().cameras()``; built from
            ``config.render`` (and closed at the end) when None.
    """
    rig = config.camera.rig()
    if trajectory.duration_s + 1e-9 < config.duration_s:
        raise ValueError(f"trajectory lasts {trajectory.duration_s}s, the sequence "
                         f"{config.duration_s}s")
    own_renderer = renderer is None
    if own_renderer:
        renderer = make_renderer(scene, rig.cameras(), config.render,
                                 sample_footprints(scene, trajectory, rig, config.render))
    try:
        stage = _Stage(as_dynamic(scene), trajectory, rig, bool(config.frames.ground_truth))
        yield from _run(renderer, stage, thresholds, config, rig, rng, chunk_events)
    finally:
        if own_renderer:
            renderer.close()


@dataclass(frozen=True, eq=False)
class EventCamera:
    """One sequence's event sensor and its light: ``sim`` turns log images into events,
    ``flicker`` (None: none) modulates the light it sees (:meth:`light`)."""

    sim: EventSimulator
    flicker: Flicker | None

    def light(self, image: np.ndarray, t_ns: int) -> np.ndarray:
        """What the event camera sees of the linear ``image`` at ``t_ns``."""
        return image if self.flicker is None else self.flicker.apply(image, t_ns)


def event_camera(events: EventConfig, thresholds: ContrastThresholds,
                 rng: np.random.Generator, first_image: np.ndarray, t0_ns: int = 0
                 ) -> EventCamera:
    """The event camera of one sequence, set at ``first_image`` (float32[H, W] linear).

    ``rng`` (the sequence's noise stream) builds, in this order, the noise model, the lamp,
    the readout jitter's stream and the pixels' random start, so every user of this
    function draws the same sensor from the same stream. The pixels start from
    ``first_image`` under the lamp at ``t0_ns``.
    """
    hw = tuple(first_image.shape)
    noise = NoiseModel(events.noise, hw, rng) if events.noise.enabled else None
    flicker = Flicker(events.flicker, hw, rng) if events.flicker.enabled else None
    image = first_image if flicker is None else flicker.apply(first_image, t0_ns)
    latency_rng = readout_rng(rng) if events.latency.enabled else None
    start = derived_rng(rng, START_STREAM_KEY, "random_start").random(hw) \
        if events.random_start else None
    sim = EventSimulator(image, t0_ns, thresholds, log_eps=events.log_eps,
                         refractory_ns=events.refractory_ns, noise=noise,
                         bandwidth=events.bandwidth, latency=events.latency,
                         latency_rng=latency_rng, start_phase=start)
    return EventCamera(sim, flicker)


def _run(renderer: Renderer, stage: _Stage, thresholds: ContrastThresholds,
         config: SimulationConfig, rig: CameraRig, rng: np.random.Generator,
         chunk_events: int) -> Iterator[SimulationChunk]:
    ev_cfg = config.events
    t_end = int(round(config.duration_s * 1e9))
    t = 0
    state = stage.at(0)
    pose, twist = state[0], state[1]
    first = renderer.render("lr", pose, state[2])
    camera = event_camera(ev_cfg, thresholds, rng, first, t)
    sim, flicker, light = camera.sim, camera.flicker, camera.light
    image = light(first, 0)
    sampler = AdaptiveSampler(config.sampling, rig.event, min(thresholds.pos, thresholds.neg),
                              np.minimum(thresholds.pos_map, thresholds.neg_map))
    schedule = FrameSchedule(config.frames, config.duration_s)
    log_img = log_intensity(image, ev_cfg.log_eps)
    frames = [stage.frame(renderer, 0)]
    events, poses, n_events = [], [_pose_row(t, pose)], 0

    while t < t_end and not schedule.done():
        step_s = sampler.propose(log_img, pose, twist, *stage.motion(*state))
        # what changes with nothing moving: the low-passed signal relaxing, the lamp
        still = min(sim.max_step(config.sampling.contrast_fraction),
                    math.inf if flicker is None else flicker.max_step(sampler.strict_budget))
        if still < step_s:
            step_s = max(still, config.sampling.min_step_s)
        while True:
            t_new = min(t + max(1, int(round(step_s * 1e9))), t_end)
            new_state = stage.at(t_new)
            new_log = log_intensity(light(renderer.render("lr", new_state[0], new_state[2]),
                                          t_new), ev_cfg.log_eps)
            change = sampler.change(log_img, new_log)
            step_s = sampler.review(change, (t_new - t) * 1e-9)
            if step_s is None:
                break
        t, state, log_img = t_new, new_state, new_log
        pose, twist = state[0], state[1]
        batch = sim.step_log(log_img, t)
        for ft in schedule.due(batch, t):
            frames.append(stage.frame(renderer, ft))
        events.append(batch)
        poses.append(_pose_row(t, pose))
        n_events += len(batch)
        if n_events >= chunk_events:
            yield SimulationChunk(Events.concatenate(events, rig.event.hw), frames,
                                  np.array(poses))
            events, frames, poses, n_events = [], [], [], 0
    tail = sim.finish()  # the recording stops at the last sample (readout latency)
    for ft in schedule.due(tail, t):
        frames.append(stage.frame(renderer, ft))
    events.append(tail)
    yield SimulationChunk(Events.concatenate(events, rig.event.hw), frames,
                          np.array(poses).reshape(-1, 8))


def simulate_sequence(scene: PlanarScene | DynamicScene, trajectory: BSplineTrajectory,
                      thresholds: ContrastThresholds, config: SimulationConfig,
                      rng: np.random.Generator, renderer: Renderer | None = None
                      ) -> SimulatedSequence:
    """Run :func:`simulate` to the end and gather everything in memory."""
    chunks = list(simulate(scene, trajectory, thresholds, config, rng, renderer))
    rig = config.camera.rig()
    samples = [f for c in chunks for f in c.frames]
    names = list(samples[0].images)
    t_ns = np.array([f.t_ns for f in samples], np.int64)
    frames = {n: Frames(np.stack([f.images[n] for f in samples]), t_ns) for n in names}
    return SimulatedSequence(
        events=Events.concatenate([c.events for c in chunks], rig.event.hw),
        frames=frames,
        frame_poses=np.stack([_pose_row(f.t_ns, f.pose) for f in samples]),
        sample_poses=np.concatenate([c.sample_poses for c in chunks]),
        rig=rig, thresholds=thresholds)
