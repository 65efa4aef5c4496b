"""Random moving objects for dynamic scenes: how many, their shapes, sizes, depths and
smooth 6-DoF trajectories, and whether the camera stands still.

Objects are placed from the camera's pose at the start: the centre of each lies on a ray
through a random image point (some outside the view, so objects enter and leave it) at a
depth between the camera and the background, the patch roughly facing the camera with a
random tilt and roll. From there each follows a persistent random walk of control poses
(the camera trajectory's machinery), kept at heights between the background and the
camera's lowest point, so objects always stay in front of the background, and folded back
(like a billiard ball) into the view widened by ``view_margin`` as the camera sees it at each
control point's time: objects leave the view and come back, so a static camera keeps
seeing motion for the whole sequence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.pose import Pose, so3_exp
from esim_lite.geometry.trajectory import BSplineTrajectory, persistent_walk, reflect

Shape = Literal["ellipse", "polygon", "blob"]


@dataclass(frozen=True)
class ObjectsConfig:
    """Independently moving foreground objects and static cameras (all off by default).

    Attributes:
        count: (min, max) objects per sequence, drawn uniformly.
        static_camera_share: share of sequences whose camera stands still (only objects
            move); a static camera with nothing moving is redrawn with at least one object
            unless sensor noise is on.
        size_fraction: (min, max) of an object's longer side as a fraction of the view's
            width at its depth.
        depth_fraction: (min, max) of an object's distance from the camera along the optical
            axis, as a fraction of the camera's height above the background (0 = at the
            camera, 1 = on the background).
        aspect: (min, max) width / height of the patch.
        shapes: alpha shapes to draw from: ``ellipse``, ``polygon`` (star-shaped, 3-9
            vertices), ``blob`` (a smooth random cut-out).
        speed_m_s: (min, max) speed of the control-point random walk.
        angular_speed_deg_s: (min, max) rotation rate of the control-point random walk.
        max_tilt_deg: largest angle between a patch's normal and the optical axis at the start.
        knot_spacing_s: control-point spacing of the objects' trajectories.
        direction_persistence: 0..1, how much each step keeps the previous direction.
        view_margin: object centres stay within this fraction of the image size outside
            the view (they start there, leave the view and come back).
        flat_background_share: share of the static-camera sequences whose background is
            a flat level under a gentle illumination gradient instead of a texture
            (datagen/textures.py ``flat_background``): where no event ever fires the truth
            is then one smooth field, so carrying an object's level into its surround costs
            the loss at first order instead of vanishing in an unknown texture
            (docs/models.md, run M).
    """

    count: tuple[int, int] = (0, 0)
    static_camera_share: float = 0.0
    size_fraction: tuple[float, float] = (0.15, 0.5)
    depth_fraction: tuple[float, float] = (0.3, 0.85)
    aspect: tuple[float, float] = (0.6, 1.6)
    shapes: tuple[Shape, ...] = ("ellipse", "polygon", "blob")
    speed_m_s: tuple[float, float] = (0.05, 0.4)
    angular_speed_deg_s: tuple[float, float] = (0.0, 90.0)
    max_tilt_deg: float = 35.0
    knot_spacing_s: float = 0.25
    direction_persistence: float = 0.7
    view_margin: float = 0.25
    flat_background_share: float = 0.0

    def __post_init__(self) -> None:
        lo, hi = self.count
        if not 0 <= lo <= hi <= 254:
            raise ValueError(f"objects.count must be a range 0 <= min <= max <= 254, got "
                             f"{self.count}")
        if not 0 <= self.static_camera_share <= 1:
            raise ValueError("objects.static_camera_share must be in [0, 1]")
        if not 0 <= self.flat_background_share <= 1:
            raise ValueError("objects.flat_background_share must be in [0, 1]")
        lo, hi = self.size_fraction
        if not 0 < lo <= hi <= 1:
            raise ValueError(f"objects.size_fraction must be a range in (0, 1] (an object "
                             f"larger than the view cannot fit it), got {self.size_fraction}")
        lo, hi = self.depth_fraction
        if not 0 < lo <= hi < 1:
            raise ValueError(f"objects.depth_fraction must be a range in (0, 1): objects lie "
                             f"between the camera (0) and the background (1), got "
                             f"{self.depth_fraction}")
        for name in ("aspect", "speed_m_s", "angular_speed_deg_s"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi or (name == "aspect" and lo <= 0):
                raise ValueError(f"objects.{name} must be a range 0 < min <= max, got "
                                 f"{(lo, hi)}")
        if not self.shapes or any(s not in ("ellipse", "polygon", "blob") for s in self.shapes):
            raise ValueError(f"objects.shapes must name ellipse, polygon or blob, got "
                             f"{self.shapes}")
        if not 0 <= self.max_tilt_deg < 80:
            raise ValueError("objects.max_tilt_deg must be in [0, 80)")
        if self.knot_spacing_s <= 0 or not 0 <= self.direction_persistence < 1:
            raise ValueError("objects.knot_spacing_s must be positive and "
                             "objects.direction_persistence in [0, 1)")
        if self.view_margin < 0:
            raise ValueError("objects.view_margin must be >= 0")

    @property
    def enabled(self) -> bool:
        return self.count[1] > 0


@dataclass(frozen=True, eq=False)
class ObjectDraw:
    """One object's geometry before its texture is chosen.

    Attributes:
        width_m, height_m: patch size.
        texture_width: texels across, so that the finest camera sees at least one texel per
            pixel at the object's nearest depth.
        alpha: float32[h, w] 0/1 shape mask (``h`` from the aspect).
        shape: which alpha shape.
        trajectory: object-to-world poses.
    """

    width_m: float
    height_m: float
    texture_width: int
    alpha: np.ndarray
    shape: str
    trajectory: BSplineTrajectory


def static_trajectory(pose: Pose, duration_s: float, knot_spacing_s: float
                      ) -> BSplineTrajectory:
    """A camera (or object) standing still at ``pose`` for ``duration_s``."""
    n = int(math.ceil(duration_s / knot_spacing_s)) + 3
    return BSplineTrajectory(np.repeat(pose.t_wc[None], n, 0),
                             np.repeat(pose.r_wc[None], n, 0), knot_spacing_s, duration_s)


def alpha_shape(shape: str, h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """float32[h, w] 0/1 mask of a random ``shape`` touching most of the patch."""
    mask = np.zeros((h, w), np.uint8)
    cx, cy = (w - 1) / 2, (h - 1) / 2
    if shape == "ellipse":
        axes = (max(1, int(w / 2 * rng.uniform(0.6, 1.0))),
                max(1, int(h / 2 * rng.uniform(0.6, 1.0))))
        cv2.ellipse(mask, (int(round(cx)), int(round(cy))), axes, 0, 0, 360, 1, -1)
    elif shape == "polygon":
        n = int(rng.integers(3, 10))
        angles = np.sort(rng.uniform(0, 2 * np.pi, n))
        radii = rng.uniform(0.45, 1.0, n)
        pts = np.stack([cx + radii * np.cos(angles) * w / 2,
                        cy + radii * np.sin(angles) * h / 2], 1)
        cv2.fillPoly(mask, [np.round(pts).astype(np.int32)], 1)
    elif shape == "blob":
        noise = rng.normal(size=(h, w)).astype(np.float32)
        sigma = 0.12 * min(h, w)
        smooth = cv2.GaussianBlur(noise, (0, 0), sigma)
        smooth /= max(float(smooth.std()), 1e-12)
        yy, xx = np.mgrid[0:h, 0:w]
        r2 = ((xx - cx) / (w / 2)) ** 2 + ((yy - cy) / (h / 2)) ** 2
        field = smooth + 2.5 * (1 - r2)  # a blob around the centre, ragged by the noise
        mask[field > 1.5] = 1
    else:
        raise ValueError(f"unknown alpha shape {shape!r}")
    if mask.sum() < 0.05 * h * w:  # degenerate draw: fall back to the inscribed ellipse
        cv2.ellipse(mask, (int(round(cx)), int(round(cy))), (max(1, w // 2), max(1, h // 2)),
                    0, 0, 360, 1, -1)
    return mask.astype(np.float32)


def _start_pose(config: ObjectsConfig, camera: Intrinsics, cam_pose: Pose, depth: float,
                rng: np.random.Generator) -> Pose:
    """Object-to-world pose at the start: centre on a random image ray at ``depth``, the
    patch facing the camera, tilted and rolled at random."""
    m = config.view_margin
    u = rng.uniform(-m, 1 + m) * camera.width - 0.5
    v = rng.uniform(-m, 1 + m) * camera.height - 0.5
    ray_c = np.array([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0])
    centre = cam_pose.t_wc + depth * (cam_pose.r_wc @ ray_c)
    tilt = rng.normal(size=2)
    tilt *= rng.uniform(0, math.radians(config.max_tilt_deg)) / max(np.linalg.norm(tilt),
                                                                     1e-12)
    roll = rng.uniform(-math.pi, math.pi)
    # object z axis towards the camera (patch facing it), then tilt and roll
    facing = cam_pose.r_wc @ np.diag([1.0, -1.0, -1.0])
    r = facing @ so3_exp(np.array([tilt[0], tilt[1], 0.0])) @ so3_exp(np.array([0, 0, roll]))
    return Pose(r, centre)


def sample_objects(config: ObjectsConfig, n: int, duration_s: float, camera: Intrinsics,
                   finest_fx: float, cam_trajectory: BSplineTrajectory,
                   rng: np.random.Generator) -> list[ObjectDraw]:
    """Draw ``n`` objects for a camera following ``cam_trajectory`` (world: background plane
    ``z = 0``, camera above it).

    Args:
        finest_fx: focal length (px) of the finest camera of the rig (texture resolution).
    """
    times = cam_trajectory.sample_times(0.01)
    heights = np.array([cam_trajectory.pose(t).t_wc[2] for t in times])
    h_min = float(heights.min())
    cam0 = cam_trajectory.pose(0.0)
    view_w = camera.width / camera.fx  # view width per metre of depth
    out = []
    for _ in range(n):
        depth = rng.uniform(*config.depth_fraction) * float(cam0.t_wc[2])
        size = rng.uniform(*config.size_fraction) * view_w * depth
        aspect = rng.uniform(*config.aspect)
        w_m, h_m = (size, size / aspect) if aspect >= 1 else (size * aspect, size)
        start = _start_pose(config, camera, cam0, depth, rng)
        z_lo = (1 - config.depth_fraction[1]) * h_min
        z_hi = (1 - config.depth_fraction[0]) * h_min
        traj = _walk(config, start, duration_s, (z_lo, z_hi), camera, cam_trajectory, rng)
        nearest = min(depth, config.depth_fraction[0] * h_min)  # closest it can come
        tex_w = max(16, int(np.ceil(w_m * finest_fx / nearest)))
        tex_h = max(16, int(round(tex_w * h_m / w_m)))
        shape = config.shapes[int(rng.integers(len(config.shapes)))]
        alpha = alpha_shape(shape, tex_h, tex_w, rng)
        out.append(ObjectDraw(w_m, h_m, tex_w, alpha, shape, traj))
    return out


def _walk(config: ObjectsConfig, start: Pose, duration_s: float, z_range: tuple[float, float],
          camera: Intrinsics, cam_trajectory: BSplineTrajectory, rng: np.random.Generator
          ) -> BSplineTrajectory:
    """Control poses of a persistent random walk from ``start``: heights kept in
    ``z_range`` (reflected), centres folded into the widened view of the camera at each
    control point's time."""
    dt = config.knot_spacing_s
    n = int(math.ceil(duration_s / dt)) + 3
    trans = persistent_walk(n, 3, config.speed_m_s, dt, config.direction_persistence, rng)
    rot = persistent_walk(n, 3, tuple(math.radians(w) for w in config.angular_speed_deg_s),
                          dt, config.direction_persistence, rng)
    z_lo, z_hi = z_range
    p = start.t_wc.copy()
    p[2] = reflect(p[2], z_lo, z_hi)
    r = start.r_wc.copy()
    positions, rotations = [], []
    for k in range(n):
        if k:
            p = p + trans[k]
            p[2] = reflect(p[2], z_lo, z_hi)
            r = r @ so3_exp(rot[k])
        # control point k shapes the curve around time (k - 1) * dt
        cam = cam_trajectory.pose(min(max((k - 1) * dt, 0.0), cam_trajectory.duration_s))
        positions.append(_fold_into_view(p, cam, camera, config.view_margin))
        rotations.append(r.copy())
    return BSplineTrajectory(np.array(positions), np.array(rotations), dt, duration_s)


def _fold_into_view(point: np.ndarray, cam: Pose, camera: Intrinsics, margin: float
                    ) -> np.ndarray:
    """``point`` with its image position folded into the view widened by ``margin`` (a
    fraction of the image size per side), its depth kept."""
    p_c = cam.r_cw @ (point - cam.t_wc)
    z = float(p_c[2])
    if z <= 0:
        return point.copy()
    x_lo = (-margin * camera.width - 0.5 - camera.cx) / camera.fx
    x_hi = ((1 + margin) * camera.width - 0.5 - camera.cx) / camera.fx
    y_lo = (-margin * camera.height - 0.5 - camera.cy) / camera.fy
    y_hi = ((1 + margin) * camera.height - 0.5 - camera.cy) / camera.fy
    folded = np.array([reflect(p_c[0] / z, x_lo, x_hi) * z,
                       reflect(p_c[1] / z, y_lo, y_hi) * z, z])
    return cam.r_wc @ folded + cam.t_wc
