"""Smooth random 6-DoF camera trajectories over the plane.

A trajectory is a uniform cumulative cubic B-spline on SO(3) x R^3: position
``p(u) = c_i + sum_j B~_j(u) (c_{i+j} - c_{i+j-1})`` and orientation
``R(u) = R_i prod_j Exp(B~_j(u) Log(R_{i+j-1}^T R_{i+j}))`` (Kim et al. 1995; Lovegrove
et al. 2013). It is C2 in position and orientation, so pose, linear and angular velocity
exist at any time; the angular velocity uses the closed-form recursion of Sommer et al.
(CVPR 2020) instead of finite differences.

Random control points come from a persistent random walk whose per-knot speeds are drawn
from configurable ranges; orientation is a downward-looking camera with bounded tilt and
free roll about the optical axis, so the camera stays on the lit side (``z > 0``) looking at
the plane. :func:`plane_extent_covering` then sizes the textured plane so that it fills the
view for the whole sequence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.pose import Pose, Twist, so3_exp, so3_log
from esim_lite.geometry.scene import intersect_plane

#: Camera looking straight down at the plane, image up = world +Y (texture upright).
LOOK_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])

_BASIS = np.array([[6.0, 0.0, 0.0, 0.0], [5.0, 3.0, -3.0, 1.0], [1.0, 3.0, 3.0, -2.0],
                   [0.0, 0.0, 0.0, 1.0]]) / 6.0


@numba.njit(cache=True, nogil=True)
def _evaluate(positions, rotations, deltas, spacing, i, u):
    """Pose ``(R_wc, t_wc)`` and world-frame velocities ``(v, w)`` in segment ``i`` at ``u``.

    The angular velocity follows Sommer et al.'s recursion for cumulative B-splines:
    ``w_j = A_j^T w_{j-1} + dB~_j d_j`` with ``A_j = Exp(B~_j d_j)``, in the body frame.
    """
    b = _BASIS @ np.array([1.0, u, u * u, u ** 3])
    db = _BASIS @ np.array([0.0, 1.0, 2 * u, 3 * u * u])
    position = positions[i].copy()
    velocity = np.zeros(3)
    r = rotations[i].copy()
    omega = np.zeros(3)
    for j in range(1, 4):
        dp = positions[i + j] - positions[i + j - 1]
        position += b[j] * dp
        velocity += db[j] * dp
        d = deltas[i + j - 1]
        a = so3_exp(b[j] * d)
        r = r @ a
        omega = a.T @ omega + db[j] * d
    return r, position, velocity / spacing, r @ (omega / spacing)


@dataclass(frozen=True, eq=False)
class BSplineTrajectory:
    """Camera-to-world poses along a uniform cumulative cubic B-spline.

    Attributes:
        positions: float64[N, 3] control positions (m), N >= 4.
        rotations: float64[N, 3, 3] control orientations ``R_wc``.
        knot_spacing_s: time between control points.
        duration_s: the valid time range is ``[0, duration_s]``, at most ``(N-3) * spacing``.
    """

    positions: np.ndarray
    rotations: np.ndarray
    knot_spacing_s: float
    duration_s: float

    def __post_init__(self) -> None:
        n = len(self.positions)
        if n < 4 or self.rotations.shape != (n, 3, 3) or self.positions.shape != (n, 3):
            raise ValueError("a cubic B-spline needs >= 4 matching control poses")
        if self.knot_spacing_s <= 0:
            raise ValueError("knot_spacing_s must be positive")
        if not 0 < self.duration_s <= (n - 3) * self.knot_spacing_s + 1e-12:
            raise ValueError(f"duration {self.duration_s}s exceeds the spline's "
                             f"{(n - 3) * self.knot_spacing_s}s")

    @cached_property
    def _deltas(self) -> np.ndarray:
        """float64[N-1, 3]: ``Log(R_k^T R_{k+1})`` of consecutive control orientations."""
        r = self.rotations
        return np.stack([so3_log(np.ascontiguousarray(r[k].T @ r[k + 1]))
                         for k in range(len(r) - 1)])

    def _segment(self, t: float) -> tuple[int, float]:
        if not -1e-9 <= t <= self.duration_s + 1e-9:
            raise ValueError(f"t={t}s outside the trajectory [0, {self.duration_s}]s")
        s = min(max(t, 0.0), self.duration_s) / self.knot_spacing_s
        i = min(int(math.floor(s)), len(self.positions) - 4)
        return i, s - i

    def pose(self, t: float) -> Pose:
        """Camera pose at time ``t`` seconds."""
        return self.pose_and_twist(t)[0]

    def twist(self, t: float) -> Twist:
        """Camera linear and angular velocity (world frame) at time ``t`` seconds."""
        return self.pose_and_twist(t)[1]

    def pose_and_twist(self, t: float) -> tuple[Pose, Twist]:
        i, u = self._segment(t)
        r, p, v, w = _evaluate(self.positions, self.rotations, self._deltas,
                               self.knot_spacing_s, i, u)
        return Pose(r, p), Twist(v, w)

    def shifted(self, offset_m: np.ndarray) -> BSplineTrajectory:
        """The same motion translated by ``offset_m`` (float64[3])."""
        return BSplineTrajectory(self.positions + np.asarray(offset_m, np.float64),
                                 self.rotations, self.knot_spacing_s, self.duration_s)

    def sample_times(self, step_s: float) -> np.ndarray:
        """Regular times from 0 to ``duration_s`` inclusive with spacing at most ``step_s``."""
        n = max(2, int(math.ceil(self.duration_s / step_s)) + 1)
        return np.linspace(0.0, self.duration_s, n)


@dataclass(frozen=True)
class TrajectoryConfig:
    """Ranges of the random camera motion.

    Attributes:
        knot_spacing_s: control-point spacing; smaller means more agile motion.
        height_m: (min, max) camera height above the plane.
        max_tilt_deg: largest angle between the optical axis and the plane normal.
        speed_m_s: (min, max) speed of the control-point random walk.
        angular_speed_deg_s: (min, max) rotation rate of the control-point random walk.
        direction_persistence: 0..1, how much each step keeps the previous direction.
        wander_m: the camera centre stays within this distance of its start in x and y.
    """

    knot_spacing_s: float = 0.25
    height_m: tuple[float, float] = (0.8, 1.2)
    max_tilt_deg: float = 20.0
    speed_m_s: tuple[float, float] = (0.1, 0.5)
    angular_speed_deg_s: tuple[float, float] = (10.0, 60.0)
    direction_persistence: float = 0.7
    wander_m: float = 0.6

    def __post_init__(self) -> None:
        for name in ("height_m", "speed_m_s", "angular_speed_deg_s"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ValueError(f"{name} must be a range 0 <= min <= max, got {(lo, hi)}")
        if self.height_m[0] <= 0:
            raise ValueError("height_m must be positive: the camera stays above the plane")
        if not 0 <= self.max_tilt_deg < 80:
            raise ValueError("max_tilt_deg must be in [0, 80)")
        if self.knot_spacing_s <= 0 or self.wander_m < 0:
            raise ValueError("knot_spacing_s must be positive and wander_m non-negative")
        if not 0 <= self.direction_persistence < 1:
            raise ValueError("direction_persistence must be in [0, 1)")


def reflect(value: float, lo: float, hi: float) -> float:
    """Fold ``value`` back into ``[lo, hi]`` like a billiard ball."""
    if hi <= lo:
        return lo
    span = hi - lo
    x = (value - lo) % (2 * span)
    return lo + (x if x <= span else 2 * span - x)


def persistent_walk(n: int, dim: int, speeds: tuple[float, float], dt: float,
                     persistence: float, rng: np.random.Generator) -> np.ndarray:
    """float64[n, dim] steps: random directions with memory, lengths speed * dt."""
    steps = np.zeros((n, dim))
    direction = rng.normal(size=dim)
    for k in range(n):
        fresh = rng.normal(size=dim)
        direction = persistence * direction / np.linalg.norm(direction) + \
            (1 - persistence) * fresh / np.linalg.norm(fresh)
        steps[k] = rng.uniform(*speeds) * dt * direction / np.linalg.norm(direction)
    return steps


def sample_trajectory(config: TrajectoryConfig, duration_s: float, camera: Intrinsics,
                      rng: np.random.Generator) -> BSplineTrajectory:
    """Draw a random smooth trajectory of ``duration_s`` seconds.

    Raises:
        ValueError: if the tilt range lets the view reach the horizon (a plane could then
            never fill the view).
    """
    half_diag = math.atan(math.hypot(camera.width / (2 * camera.fx),
                                     camera.height / (2 * camera.fy)))
    if math.radians(config.max_tilt_deg) + half_diag >= math.radians(85):
        raise ValueError(f"max_tilt_deg={config.max_tilt_deg} plus the camera's half "
                         f"diagonal field of view reaches the horizon")
    dt = config.knot_spacing_s
    n = int(math.ceil(duration_s / dt)) + 3
    lo_h, hi_h = config.height_m
    max_tilt = math.radians(config.max_tilt_deg)

    trans = persistent_walk(n, 3, config.speed_m_s, dt, config.direction_persistence, rng)
    rot = persistent_walk(n, 3, tuple(math.radians(w) for w in config.angular_speed_deg_s),
                           dt, config.direction_persistence, rng)
    p = np.array([0.0, 0.0, rng.uniform(lo_h, hi_h)])
    tilt = rng.normal(size=2)
    tilt *= rng.uniform(0, max_tilt) / max(np.linalg.norm(tilt), 1e-12)
    roll = rng.uniform(-math.pi, math.pi)
    positions, rotations = [], []
    for k in range(n):
        if k:
            p = p + trans[k]
            p = np.array([reflect(p[0], -config.wander_m, config.wander_m),
                          reflect(p[1], -config.wander_m, config.wander_m),
                          reflect(p[2], lo_h, hi_h)])
            tilt = tilt + rot[k, :2]
            norm = np.linalg.norm(tilt)
            if norm > max_tilt:  # reflect radially at the tilt bound
                tilt *= reflect(norm, 0.0, max_tilt) / norm
            roll += rot[k, 2]
        positions.append(p.copy())
        rotations.append(so3_exp(np.array([tilt[0], tilt[1], 0.0])) @ LOOK_DOWN
                         @ so3_exp(np.array([0.0, 0.0, roll])))
    return BSplineTrajectory(np.array(positions), np.array(rotations), dt, duration_s)


def footprint_bounds(trajectory: BSplineTrajectory, camera: Intrinsics,
                     step_s: float = 0.005) -> np.ndarray:
    """float64[4] ``(xmin, xmax, ymin, ymax)`` of everything the camera sees on ``z = 0``.

    Raises:
        ValueError: if at some time a corner ray misses the plane (camera below the plane
            or looking at the horizon).
    """
    rays = camera.corner_rays()
    pts = []
    for t in trajectory.sample_times(step_s):
        pose = trajectory.pose(t)
        hit, depth = intersect_plane(pose, rays)
        if pose.t_wc[2] <= 0 or not np.all(np.isfinite(depth)) or np.any(depth <= 0):
            raise ValueError(f"at t={t:.4f}s the camera does not see the plane in every pixel")
        pts.append(hit[:, :2])
    pts = np.concatenate(pts)
    return np.array([pts[:, 0].min(), pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max()])


def plane_extent_covering(trajectory: BSplineTrajectory, camera: Intrinsics,
                          aspect: float | None, margin: float = 0.05, step_s: float = 0.005
                          ) -> tuple[BSplineTrajectory, float, float]:
    """Centre the trajectory's footprint on the origin and size a plane to cover it.

    Args:
        aspect: texture width / height, kept by the plane so texels stay square; None
            takes the footprint's own aspect (the texture is then cropped to it).
        margin: relative enlargement of the plane beyond the sampled footprint (covers the
            motion between the sampled times).
    Returns:
        (shifted trajectory, plane width_m, plane height_m).
    """
    xmin, xmax, ymin, ymax = footprint_bounds(trajectory, camera, step_s)
    centre = np.array([(xmin + xmax) / 2, (ymin + ymax) / 2, 0.0])
    w, h = (xmax - xmin) * (1 + margin), (ymax - ymin) * (1 + margin)
    if aspect is not None:
        w, h = max(w, h * aspect), max(h, w / aspect)
    return trajectory.shifted(-centre), w, h
