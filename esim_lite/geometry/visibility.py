"""Exact visibility in a dynamic scene: which surface each camera ray sees, where, and how
that point moves in the image.

Every ray is intersected with the background plane and with the plane of every object in
float64; an object hit counts where it lies inside the patch and passes the alpha test
(bilinear alpha >= :data:`ALPHA_CUTOFF`, texels clamped at the border); the nearest hit in
front of the camera wins. This is the oracle that the renderers and the ground truth
(depth, surface ids, optical flow) are measured against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.objects import ALPHA_CUTOFF, DynamicScene
from esim_lite.geometry.pose import Pose, Twist

#: Surface id of a ray that hits nothing (the sky; never in a valid sequence).
MISS = 255


def bilinear(image: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """float64 bilinear lookup of ``image`` [h, w] at texture coordinates (texel centres at
    integers), coordinates clamped to the texture (border texels extend outward)."""
    h, w = image.shape
    x = np.clip(col, 0.0, w - 1.0)
    y = np.clip(row, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2)
    fx, fy = x - x0, y - y0
    img = image.astype(np.float64, copy=False)
    top = img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx
    bottom = img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


@dataclass(frozen=True, eq=False)
class Hits:
    """What each ray sees (arrays of the rays' shape).

    Attributes:
        ids: uint8 surface id: 0 background, ``k + 1`` object ``k``, :data:`MISS` nothing.
        depth: float64 camera-frame depth Z of the hit (inf on a miss).
        col, row: float64 texture coordinates of the hit in its surface's texture.
        points_w: float64[..., 3] world coordinates of the hit.
    """

    ids: np.ndarray
    depth: np.ndarray
    col: np.ndarray
    row: np.ndarray
    points_w: np.ndarray


def _plane_hit(origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Ray parameter of the hit with the local plane ``z = 0`` (inf where none ahead)."""
    dz = direction[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -origin[2] / dz
    return np.where(np.isfinite(lam) & (lam > 0), lam, np.inf)


def trace(scene: DynamicScene, camera: Pose, object_poses: tuple[Pose, ...],
          rays_c: np.ndarray) -> Hits:
    """Nearest alpha-tested hit of every ray.

    Args:
        rays_c: float64[..., 3] ray directions in the camera frame with z = 1, so a ray's
            parameter at a hit is its camera-frame depth.
    """
    if len(object_poses) != len(scene.objects):
        raise ValueError(f"{len(object_poses)} object poses for {len(scene.objects)} objects")
    d_w = rays_c @ camera.r_wc.T
    shape = rays_c.shape[:-1]
    best = _plane_hit(camera.t_wc, d_w)
    ids = np.where(np.isfinite(best), 0, MISS).astype(np.uint8)
    bg = scene.background
    local = camera.t_wc + np.where(np.isfinite(best), best, 0.0)[..., None] * d_w
    m = bg.texture_from_plane()
    col = m[0, 0] * local[..., 0] + m[0, 2]
    row = m[1, 1] * local[..., 1] + m[1, 2]
    for k, (obj, pose) in enumerate(zip(scene.objects, object_poses)):
        r_ow = pose.r_wc.T
        origin = r_ow @ (camera.t_wc - pose.t_wc)
        d_o = d_w @ r_ow.T
        lam = _plane_hit(origin, d_o)
        closer = lam < best
        if not closer.any():
            continue
        p = origin + np.where(closer, lam, 0.0)[..., None] * d_o
        surf = obj.surface
        inside = closer & (np.abs(p[..., 0]) <= surf.width_m / 2) & \
            (np.abs(p[..., 1]) <= surf.height_m / 2)
        mo = surf.texture_from_plane()
        c = mo[0, 0] * p[..., 0] + mo[0, 2]
        r = mo[1, 1] * p[..., 1] + mo[1, 2]
        solid = np.zeros(shape, bool)
        if inside.any():
            solid[inside] = bilinear(obj.alpha, c[inside], r[inside]) >= ALPHA_CUTOFF
        best = np.where(solid, lam, best)
        ids = np.where(solid, np.uint8(k + 1), ids)
        col = np.where(solid, c, col)
        row = np.where(solid, r, row)
    points = camera.t_wc + np.where(np.isfinite(best), best, 0.0)[..., None] * d_w
    return Hits(ids, best, col, row, points)


def shade(scene: DynamicScene, hits: Hits) -> np.ndarray:
    """float64 radiance of every hit: its surface's bilinear texture (0 on a miss)."""
    out = np.zeros(hits.ids.shape)
    surfaces = [scene.background.texture] + [o.surface.texture for o in scene.objects]
    for k, tex in enumerate(surfaces):
        sel = hits.ids == k
        if sel.any():
            out[sel] = bilinear(tex, hits.col[sel], hits.row[sel])
    return out


def point_velocity(scene: DynamicScene, hits: Hits, object_poses: tuple[Pose, ...],
                   object_twists: tuple[Twist, ...]) -> np.ndarray:
    """float64[..., 3] world velocity of every hit point (zero on the static background):
    ``v + w x (X - t)`` of the object that carries it."""
    vel = np.zeros(hits.points_w.shape)
    for k, (pose, twist) in enumerate(zip(object_poses, object_twists)):
        sel = hits.ids == k + 1
        if sel.any():
            arm = hits.points_w[sel] - pose.t_wc
            vel[sel] = twist.v_w + np.cross(twist.w_w, arm)
    return vel


def image_flow(intrinsics: Intrinsics, camera: Pose, camera_twist: Twist, hits: Hits,
               velocity_w: np.ndarray) -> np.ndarray:
    """float64[..., 2] instantaneous image velocity (px/s) of the hit points: the motion
    field of the visible surface (zero on a miss).

    A point at ``X_c`` (camera frame) moves as ``dX_c/dt = R_cw (V - v - w x (X - c))`` for
    camera centre ``c``, velocity ``v`` and angular velocity ``w`` (world frame); the pinhole
    projection ``u = fx X/Z + cx`` then gives ``du/dt = fx (dX Z - X dZ) / Z^2``.
    """
    rel = hits.points_w - camera.t_wc
    x_c = rel @ camera.r_wc
    dx_w = velocity_w - camera_twist.v_w - np.cross(camera_twist.w_w, rel)
    dx_c = dx_w @ camera.r_wc
    valid = np.isfinite(hits.depth) & (x_c[..., 2] > 0)
    z = np.where(valid, x_c[..., 2], 1.0)
    du = intrinsics.fx * (dx_c[..., 0] * z - x_c[..., 0] * dx_c[..., 2]) / z**2
    dv = intrinsics.fy * (dx_c[..., 1] * z - x_c[..., 1] * dx_c[..., 2]) / z**2
    flow = np.stack([du, dv], axis=-1)
    flow[~valid] = 0.0
    return flow


@dataclass(frozen=True, eq=False)
class SurfaceTruth:
    """Per-pixel ground truth of one camera at one time (pixel-centre rays).

    Attributes:
        flow: float32[2, H, W] image velocity in px/s (channel 0 = x).
        depth: float32[H, W] camera-frame depth in metres.
        ids: uint8[H, W] visible surface (0 = background).
    """

    flow: np.ndarray
    depth: np.ndarray
    ids: np.ndarray


def surface_truth(scene: DynamicScene, intrinsics: Intrinsics, camera: Pose,
                  camera_twist: Twist, object_poses: tuple[Pose, ...],
                  object_twists: tuple[Twist, ...]) -> SurfaceTruth:
    """Flow, depth and surface ids at every pixel centre of ``intrinsics``."""
    hits = trace(scene, camera, object_poses, intrinsics.pixel_rays())
    vel = point_velocity(scene, hits, object_poses, object_twists)
    flow = image_flow(intrinsics, camera, camera_twist, hits, vel)
    return SurfaceTruth(np.ascontiguousarray(flow.transpose(2, 0, 1), np.float32),
                        hits.depth.astype(np.float32), hits.ids)
