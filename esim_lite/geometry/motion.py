"""Exact image motion field of a static plane seen by a moving pinhole camera."""

from __future__ import annotations

import numpy as np

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.pose import Pose, Twist
from esim_lite.geometry.scene import intersect_plane


def plane_depth(intrinsics: Intrinsics, pose: Pose) -> np.ndarray:
    """float64[H, W] camera-frame depth Z of the plane ``z = 0`` at every pixel centre."""
    return intersect_plane(pose, intrinsics.pixel_rays())[1]


def motion_field(intrinsics: Intrinsics, pose: Pose, twist: Twist) -> np.ndarray:
    """float64[H, W, 2]: pixel velocity ``(du/dt, dv/dt)`` in pixels per second.

    Static points seen by a camera moving with linear velocity ``v`` and angular velocity
    ``w`` (camera frame) move as ``dP/dt = -v - w x P``; dividing by depth gives the
    classic image Jacobian in normalised coordinates, scaled by the focal lengths.
    """
    rays = intrinsics.pixel_rays()
    x, y = rays[..., 0], rays[..., 1]
    inv_z = 1.0 / plane_depth(intrinsics, pose)
    (vx, vy, vz), (wx, wy, wz) = twist.in_camera(pose)
    dx = (-vx + x * vz) * inv_z + x * y * wx - (1 + x * x) * wy + y * wz
    dy = (-vy + y * vz) * inv_z + (1 + y * y) * wx - x * y * wy - x * wz
    return np.stack([intrinsics.fx * dx, intrinsics.fy * dy], axis=-1)


def project_plane_point(intrinsics: Intrinsics, pose: Pose, point_w: np.ndarray) -> np.ndarray:
    """float64[..., 2] pixel coordinates of world points (used to check flows and renders)."""
    p_c = (np.asarray(point_w) - pose.t_wc) @ pose.r_wc
    uv = p_c[..., :2] / p_c[..., 2:3]
    return np.stack([intrinsics.fx * uv[..., 0] + intrinsics.cx,
                     intrinsics.fy * uv[..., 1] + intrinsics.cy], axis=-1)


def planar_flow(intrinsics: Intrinsics, pose_from: Pose, pose_to: Pose) -> np.ndarray:
    """float64[H, W, 2]: exact displacement (pixels) of every pixel's plane point between
    two camera poses (where the point is seen from ``pose_to`` minus where it was)."""
    points, depth = intersect_plane(pose_from, intrinsics.pixel_rays())
    uv = project_plane_point(intrinsics, pose_to, points)
    u, v = np.meshgrid(np.arange(intrinsics.width, dtype=np.float64),
                       np.arange(intrinsics.height, dtype=np.float64))
    flow = uv - np.stack([u, v], axis=-1)
    flow[~(depth > 0)] = 0.0
    return flow
