"""Halo probe (issue 23): measure the signed error around dark objects on a bright ground.

Two kinds of measurement:

- **With ground truth** (simulated oracle scenes): the dark objects' mask comes from the
  exact HR ground truth; every HR pixel gets its distance to the objects' boundary in LR
  pixels (:func:`boundary_distance`), and :func:`ring_errors` averages the signed error
  ``output - truth`` in rings outside the objects (``out 1-2``, ``out 2-5``, ...), inside
  them and far from them. A halo is a systematic signed error in the rings that the far
  background does not share. :func:`swept_error` does the same over the pixels an object
  covered earlier in the stacks' time window but no longer covers (ghost trails).
- **Without labels** (real recordings): :func:`self_rings` segments the dark objects in
  the output itself (Otsu) and reports the output's level in the same rings relative to
  its own far background, as a fraction of the far background's contrast to the objects.

The probe scenes (:func:`poster_texture`, :func:`simulate_poster`) follow the Event
Camera Dataset's ``shapes`` sequences: a camera moving over a flat poster of dark shapes on
a bright, optionally lightly textured ground, simulated with the project's own simulator
(:mod:`esim_lite.sequence`, exact homography rendering of the plane).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from esim_lite.config import FrameConfig, SimulationConfig
from esim_lite.core.events import Events
from esim_lite.core.stacking import stack_to_input
from esim_lite.events.thresholds import sample_thresholds
from esim_lite.geometry.camera import hr_camera
from esim_lite.geometry.object_sampling import ObjectsConfig
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import (
    BSplineTrajectory,
    plane_extent_covering,
    sample_trajectory,
)
from esim_lite.render.renderer import make_renderer
from esim_lite.sequence import sample_footprints, simulate
from model.data.classical_flow import stack_flows

#: Rings outside the dark objects: (name, lo, hi) in LR pixels of distance to the boundary,
#: ``lo < d <= hi``; ``far`` is the background reference.
OUTER_RINGS: tuple[tuple[str, float, float], ...] = (
    ("out 0-1", 0.0, 1.0), ("out 1-2", 1.0, 2.0), ("out 2-5", 2.0, 5.0),
    ("out 5-10", 5.0, 10.0), ("far >12", 12.0, math.inf))
#: Inside the objects, deeper than this (LR px) from the boundary.
INSIDE_DEPTH = 1.0
#: Fewest pixels a region needs for its mean to be reported (else NaN).
MIN_PIXELS = 30
RING_NAMES = ("inside",) + tuple(name for name, _, _ in OUTER_RINGS)


# ---------------------------------------------------------------- ring metric


def boundary_distance(dark: np.ndarray, scale: int) -> tuple[np.ndarray, np.ndarray]:
    """(outside, inside) float32[H, W]: each pixel's Euclidean distance, in LR pixels, to
    the nearest pixel of the other side of ``dark`` (bool[H, W] at HR, ``scale`` HR pixels
    per LR pixel); 0 on the other side. Without any dark pixel ``outside`` is +inf."""
    if dark.ndim != 2 or dark.dtype != bool:
        raise ValueError(f"dark must be a bool[H, W] mask, got {dark.dtype}{dark.shape}")
    if scale < 1:
        raise ValueError(f"scale must be >= 1, got {scale}")
    if not dark.any():
        return np.full(dark.shape, np.inf, np.float32), np.zeros(dark.shape, np.float32)
    outside = cv2.distanceTransform((~dark).astype(np.uint8), cv2.DIST_L2, 5) / scale
    inside = cv2.distanceTransform(dark.astype(np.uint8), cv2.DIST_L2, 5) / scale
    return outside.astype(np.float32), inside.astype(np.float32)


def ring_masks(dark: np.ndarray, scale: int, valid: np.ndarray | None = None
               ) -> dict[str, np.ndarray]:
    """bool[H, W] per name of :data:`RING_NAMES` (``valid``: pixels allowed at all, e.g.
    away from the image border)."""
    outside, inside = boundary_distance(dark, scale)
    keep = np.ones(dark.shape, bool) if valid is None else valid
    masks = {"inside": dark & (inside > INSIDE_DEPTH) & keep}
    for name, lo, hi in OUTER_RINGS:
        masks[name] = ~dark & (outside > lo) & (outside <= hi) & keep
    return masks


def border_mask(hw: tuple[int, int], margin: int) -> np.ndarray:
    """bool[H, W]: True except within ``margin`` pixels of the image border (where the
    nearest object may lie outside the view, so distances are unknown)."""
    m = np.zeros(hw, bool)
    m[margin:hw[0] - margin, margin:hw[1] - margin] = True
    return m


def masked_mean(values: np.ndarray, mask: np.ndarray) -> float:
    """Mean of ``values`` over ``mask`` (NaN with fewer than :data:`MIN_PIXELS` pixels)."""
    n = int(mask.sum())
    return float(values[mask].mean()) if n >= MIN_PIXELS else math.nan


def ring_errors(pred: np.ndarray, gt: np.ndarray, masks: dict[str, np.ndarray]
                ) -> dict[str, float]:
    """Mean signed error ``pred - gt`` per ring of ``masks`` (see :func:`ring_masks`)."""
    if pred.shape != gt.shape:
        raise ValueError(f"pred {pred.shape} and gt {gt.shape} differ in shape")
    err = pred.astype(np.float64) - gt.astype(np.float64)
    return {name: masked_mean(err, m) for name, m in masks.items()}


def swept_error(pred: np.ndarray, gt: np.ndarray, dark_now: np.ndarray,
                dark_before: Iterable[np.ndarray], valid: np.ndarray | None = None) -> float:
    """Mean signed error over the pixels dark at some earlier time (``dark_before``: bool
    masks) but not now: where an object was during the stacks' window and left (a ghost
    trail is a negative error there)."""
    swept = np.zeros(dark_now.shape, bool)
    for d in dark_before:
        swept |= d
    swept &= ~dark_now
    if valid is not None:
        swept &= valid
    return masked_mean(pred.astype(np.float64) - gt.astype(np.float64), swept)


def otsu_dark(image: np.ndarray) -> np.ndarray:
    """bool[H, W]: the dark side of Otsu's threshold on ``image`` stretched by its 1st..99th
    percentiles, opened by a 3x3 square (drops isolated dark specks)."""
    lo, hi = np.percentile(image, (1, 99))
    g = np.clip((image - lo) / max(hi - lo, 1e-6), 0, 1)
    u8 = np.round(g * 255).astype(np.uint8)
    _, light = cv2.threshold(u8, 0, 1, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    dark = (1 - light).astype(np.uint8)
    return cv2.morphologyEx(dark, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).astype(bool)


def self_rings(image: np.ndarray, scale: int, margin: int = 0) -> dict[str, float]:
    """Label-free halo statistic of one output: with the dark objects segmented by
    :func:`otsu_dark`, per ring of :data:`RING_NAMES` the mean level minus the far
    background's, divided by the far background's level minus the objects' (``inside``):
    0 = as bright as the far background, +0.2 = brighter by a fifth of the contrast.
    ``margin``: HR pixels at the border left out."""
    dark = otsu_dark(image)
    masks = ring_masks(dark, scale, border_mask(image.shape, margin) if margin else None)
    level = {name: masked_mean(image.astype(np.float64), m) for name, m in masks.items()}
    far, inside = level["far >12"], level["inside"]
    contrast = far - inside
    if not np.isfinite(contrast) or abs(contrast) < 1e-6:
        return {name: math.nan for name in RING_NAMES}
    return {name: (v - far) / contrast for name, v in level.items()}


# ---------------------------------------------------------------- probe scenes


@dataclass(frozen=True)
class PosterSpec:
    """A flat poster of dark shapes on a bright ground (ECD ``shapes``-like).

    Attributes:
        background: linear intensity of the ground.
        dark: intensity of the shapes.
        texture_amp: relative amplitude of a smooth texture on the ground (0: flat).
        density_per_m2: shapes per square metre of poster (the default camera, 60 degrees
            at about 1 m, sees about 1.3 m2: some 6 shapes, as in the ECD ``shapes``).
        radius_m: (min, max) shape radius (0.05-0.09 m: 5-10 px on the 128x128 camera).
        speed: factor on the camera trajectory's linear and angular speeds.
    """

    background: float = 0.8
    dark: float = 0.05
    texture_amp: float = 0.0
    density_per_m2: float = 4.5
    radius_m: tuple[float, float] = (0.05, 0.09)
    speed: float = 1.0


def _star(cx: float, cy: float, r: float, n: int, phase: float) -> np.ndarray:
    ang = phase + np.arange(2 * n) * np.pi / n
    rad = np.where(np.arange(2 * n) % 2 == 0, r, 0.45 * r)
    return np.stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang)], 1)


def poster_texture(spec: PosterSpec, hw: tuple[int, int], width_m: float,
                   rng: np.random.Generator) -> np.ndarray:
    """float32[h, w] linear intensity of a ``width_m`` wide poster: filled circles,
    squares, triangles, stars and bars at ``spec.dark`` on ``spec.background`` (times a
    smooth texture of relative amplitude ``spec.texture_amp``)."""
    h, w = hw
    texels_per_m = w / width_m
    ground = np.full(hw, spec.background, np.float32)
    if spec.texture_amp > 0:
        noise = cv2.GaussianBlur(rng.normal(size=hw).astype(np.float32), (0, 0),
                                 0.05 * texels_per_m)
        noise /= max(float(np.abs(noise).max()), 1e-9)
        ground *= 1 + spec.texture_amp * noise
    mask = np.zeros(hw, np.uint8)
    n_shapes = int(round(spec.density_per_m2 * width_m * h / texels_per_m))
    for _ in range(n_shapes):
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        r = rng.uniform(*spec.radius_m) * texels_per_m
        kind, phase = int(rng.integers(5)), rng.uniform(0, 2 * np.pi)
        if kind == 0:
            cv2.circle(mask, (int(cx), int(cy)), int(r), 1, -1, cv2.LINE_8)
            continue
        if kind == 4:  # a bar: long rectangle
            c, s = math.cos(phase), math.sin(phase)
            half = np.array([[-r, -0.35 * r], [r, -0.35 * r], [r, 0.35 * r], [-r, 0.35 * r]])
            pts = half @ np.array([[c, s], [-s, c]]) + (cx, cy)
        elif kind == 3:
            pts = _star(cx, cy, r, 5, phase)
        else:  # triangle (1) or square (2)
            n = 3 if kind == 1 else 4
            ang = phase + np.arange(n) * 2 * np.pi / n
            pts = np.stack([cx + r * np.cos(ang), cy + r * np.sin(ang)], 1)
        cv2.fillPoly(mask, [np.round(pts).astype(np.int32)], 1)
    return np.where(mask > 0, np.float32(spec.dark), ground).astype(np.float32)


@dataclass(frozen=True, eq=False)
class ProbeSequence:
    """One simulated probe sequence: its events, the poster and the camera path, so the
    ground truth can be rendered at any time (:meth:`render_hr`)."""

    events: Events
    plane: PlanarScene
    trajectory: BSplineTrajectory
    sim: SimulationConfig
    scale: int
    dark_level: float

    def render_hr(self, times_ns: Iterable[int]) -> list[np.ndarray]:
        """float32[sH, sW] ground truth at each time (the simulator's own HR camera)."""
        rig = self.sim.camera.rig()
        name = hr_camera(self.scale)
        cams = {name: rig.cameras()[name]}
        foot = sample_footprints(self.plane, self.trajectory, rig, self.sim.render)
        renderer = make_renderer(self.plane, cams, self.sim.render, {name: foot[name]})
        try:
            return [renderer.render(name, self.trajectory.pose(t * 1e-9)) for t in times_ns]
        finally:
            renderer.close()

    def dark_mask(self, gt: np.ndarray) -> np.ndarray:
        """bool: the shapes' pixels, those closer to the shapes' level than to the
        ground's (exact for a two-level poster; anti-aliased boundary pixels split at the
        midpoint; also right for light shapes on a dark ground)."""
        ground = float(np.median(gt))
        return np.abs(gt - self.dark_level) < np.abs(gt - ground)

    def motion_px(self, t0_ns: int, t1_ns: int) -> float:
        """Median displacement (LR px) of the plane's points in view between two times."""
        rig = self.sim.camera.rig()
        cam = rig.event
        h0 = self.plane.texture_from_image(cam, self.trajectory.pose(t0_ns * 1e-9))
        h1 = self.plane.texture_from_image(cam, self.trajectory.pose(t1_ns * 1e-9))
        v, u = np.mgrid[0:cam.height:8, 0:cam.width:8]
        p1 = np.stack([u.ravel(), v.ravel(), np.ones(u.size)]).astype(np.float64)
        p0 = np.linalg.inv(h0) @ (h1 @ p1)
        p0 = p0[:2] / p0[2]
        return float(np.median(np.hypot(*(p0 - p1[:2]))))


def _faster(traj_cfg, factor: float):
    return dataclasses.replace(
        traj_cfg, speed_m_s=tuple(s * factor for s in traj_cfg.speed_m_s),
        angular_speed_deg_s=tuple(s * factor for s in traj_cfg.angular_speed_deg_s))


def probe_simulation(sim: SimulationConfig, duration_s: float) -> SimulationConfig:
    """``sim`` set up for probe posters: no moving objects, exact homography rendering of
    the plane, frames off (the probe renders its ground truth itself)."""
    return dataclasses.replace(
        sim, duration_s=duration_s, objects=ObjectsConfig(),
        frames=FrameConfig(mode="rate", rate_hz=1.0 / duration_s, count=None, ground_truth=()),
        render=dataclasses.replace(sim.render, backend="homography", supersample_lr=3,
                                   supersample_hr=2, threads=1))


def simulate_poster(spec: PosterSpec, sim: SimulationConfig, rng: np.random.Generator,
                    min_events: int, scale: int = 2) -> ProbeSequence:
    """Simulate a camera (``sim.trajectory``'s random motion, times ``spec.speed``) over a
    poster of ``spec`` until ``min_events`` events (or ``sim.duration_s``).

    ``sim`` should come through :func:`probe_simulation`; ``rng`` draws the trajectory,
    the poster, the thresholds and the sensor noise, in that order."""
    sim = dataclasses.replace(sim, trajectory=_faster(sim.trajectory, spec.speed))
    rig = sim.camera.rig()
    traj = sample_trajectory(sim.trajectory, sim.duration_s, rig.event, rng)
    traj, width_m, height_m = plane_extent_covering(traj, rig.event, aspect=None)
    f_hr = rig.event.fx * max(sim.camera.scales)
    tex_w = int(np.ceil(width_m * f_hr / sim.trajectory.height_m[0]))
    tex_h = max(2, int(round(tex_w * height_m / width_m)))
    plane = PlanarScene(poster_texture(spec, (tex_h, tex_w), width_m, rng), width_m, height_m)
    thresholds = sample_thresholds(sim.events.thresholds, rig.event.hw, rng)
    parts, n = [], 0
    chunks = simulate(plane, traj, thresholds, sim, rng, chunk_events=max(min_events // 8, 1))
    try:
        for chunk in chunks:
            parts.append(chunk.events)
            n += len(chunk.events)
            if n >= min_events:
                break
    finally:
        chunks.close()
    events = Events.concatenate(parts, rig.event.hw)
    return ProbeSequence(events, plane, traj, sim, scale, spec.dark)


# ---------------------------------------------------------------- network


@dataclass(frozen=True, eq=False)
class StackWindow:
    """The event indices of one output's SBN stacks: ``[first, anchor)`` before the output
    time (the central stack is the last ``per_stack`` of them), ``[anchor, last)`` after."""

    first: int
    anchor: int
    last: int


def stack_window(anchor: int, per_stack: int, n_stacks: int = 3) -> StackWindow:
    """Indices read by ``Reconstructor.stacks_at`` for SBN stacks around ``anchor``."""
    half = n_stacks // 2
    return StackWindow(anchor - (half + 1) * per_stack, anchor, anchor + half * per_stack)


@torch.inference_mode()
def raw_output(model, stacks: np.ndarray, history: np.ndarray | None = None) -> np.ndarray:
    """float32[sH, sW]: the network's output for uint8 ``stacks[n, c, H, W]`` (and the
    event history of a model that reads one) *before* the clamp to [0, 1] that
    ``Reconstructor.run`` applies (main mode, eager PyTorch). A model with memory across
    outputs reads and updates ``model.memory`` as :meth:`Reconstructor.run` does."""
    net = model.net
    flows = stack_flows(stacks) if net.config.flow == "given" else \
        np.zeros((len(stacks), 2) + stacks.shape[-2:], np.float32)
    x = torch.from_numpy(stack_to_input(stacks))[None].to(model.device)
    f = torch.from_numpy(flows)[None].to(model.device)
    central = model._central(x, f, None, history)
    return model.forward(x, central, f, eager=True)[0, 0].float().cpu().numpy()


def memory_anchors(anchor: int, per_stack: int, n_stacks: int = 3, before: int = 8
                   ) -> list[int]:
    """Anchors of up to ``before`` outputs, one every ``per_stack`` events, before the one at
    ``anchor``, whose stacks all lie inside the events (the first starts at index >= 0): what
    a model with memory across outputs has seen before it, as ``reconstruct`` would have
    fed it at the end of every stack."""
    need = (n_stacks // 2 + 1) * per_stack
    return [a for a in range(anchor - before * per_stack, anchor, per_stack) if a >= need]
