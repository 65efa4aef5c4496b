"""Exact visibility in a dynamic scene: which surface each camera ray sees, where, and how
that point moves in the image.

Every ray is intersected with the background plane and with the plane of every object in
float64; an object hit counts where it lies inside the patch and passes the alpha test
(bilinear alpha >= :data:`ALPHA_CUTOFF`, texels clamped at the border); the nearest hit in
front of the camera wins. This is the oracle that the renderers and the ground truth
(depth, surface ids, optical flow) are measured against.

:func:`surface_truth` computes the same per pixel centre in one compiled pass (numba, one
loop per pixel, no temporaries): the adaptive sampler needs the flow and ids at every render
step. :func:`surface_truth_reference` composes the numpy functions; a test holds the two
together.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
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


def surface_truth_reference(scene: DynamicScene, intrinsics: Intrinsics, camera: Pose,
                            camera_twist: Twist, object_poses: tuple[Pose, ...],
                            object_twists: tuple[Twist, ...]) -> SurfaceTruth:
    """Flow, depth and surface ids at every pixel centre, from :func:`trace`,
    :func:`point_velocity` and :func:`image_flow` (the numpy oracle)."""
    hits = trace(scene, camera, object_poses, intrinsics.pixel_rays())
    vel = point_velocity(scene, hits, object_poses, object_twists)
    flow = image_flow(intrinsics, camera, camera_twist, hits, vel)
    return SurfaceTruth(np.ascontiguousarray(flow.transpose(2, 0, 1), np.float32),
                        hits.depth.astype(np.float32), hits.ids)


def surface_truth(scene: DynamicScene, intrinsics: Intrinsics, camera: Pose,
                  camera_twist: Twist, object_poses: tuple[Pose, ...],
                  object_twists: tuple[Twist, ...]) -> SurfaceTruth:
    """Flow, depth and surface ids at every pixel centre of ``intrinsics`` (compiled; the
    same rules as :func:`surface_truth_reference`)."""
    k = len(scene.objects)
    if len(object_poses) != k or len(object_twists) != k:
        raise ValueError(f"{len(object_poses)} object poses and {len(object_twists)} twists "
                         f"for {k} objects")
    r_wo, t_wo = object_frames(scene, object_poses)
    packed = scene.packed
    boxes = sample_boxes(intrinsics, camera, r_wo, t_wo, packed.geom)
    v_o = np.array([tw.v_w for tw in object_twists], np.float64).reshape(k, 3)
    w_o = np.array([tw.w_w for tw in object_twists], np.float64).reshape(k, 3)
    flow, depth, ids = _truth_kernel(
        intrinsics.height, intrinsics.width, intrinsics.fx, intrinsics.fy, intrinsics.cx,
        intrinsics.cy, np.ascontiguousarray(camera.r_wc, np.float64),
        np.ascontiguousarray(camera.t_wc, np.float64),
        np.asarray(camera_twist.v_w, np.float64), np.asarray(camera_twist.w_w, np.float64),
        r_wo, t_wo, v_o, w_o, packed.geom, packed.shapes, packed.alphas, boxes, ALPHA_CUTOFF,
        MISS, packed.hulls, packed.hull_sizes)
    return SurfaceTruth(flow, depth, ids)


def sample_box(fine: Intrinsics, camera: Pose, obj: Pose, half_w: float, half_h: float
                ) -> tuple[int, int, int, int]:
    """(x0, x1, y0, y1), half-open, the samples of the ``fine`` grid whose rays can meet the
    patch: the bounding box of its projected corners plus one sample (the patch is convex,
    so a ray through it projects inside); the whole grid when a corner is not in front of
    the camera; an empty box when none is."""
    corners = np.array([[sx * half_w, sy * half_h, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    x_c = (corners @ obj.r_wc.T + obj.t_wc - camera.t_wc) @ camera.r_wc
    z = x_c[:, 2]
    if np.all(z <= 0):
        return 0, 0, 0, 0
    if np.any(z <= 1e-9):
        return 0, fine.width, 0, fine.height
    u = fine.fx * x_c[:, 0] / z + fine.cx
    v = fine.fy * x_c[:, 1] / z + fine.cy
    x0, x1 = max(0, math.floor(u.min()) - 1), min(fine.width, math.ceil(u.max()) + 2)
    y0, y1 = max(0, math.floor(v.min()) - 1), min(fine.height, math.ceil(v.max()) + 2)
    if x0 >= x1 or y0 >= y1:
        return 0, 0, 0, 0
    return x0, x1, y0, y1


def sample_boxes(fine: Intrinsics, camera: Pose, r_wo: np.ndarray, t_wo: np.ndarray,
                 geom: np.ndarray) -> np.ndarray:
    """int64[K, 4]: :func:`sample_box` of every object at once (compiled), from the arrays
    of :func:`object_frames` and ``DynamicScene.packed.geom``. A box only culls rays (one
    sample of margin), so what a renderer draws does not depend on its last bit; a test
    holds the two equal."""
    return _boxes_kernel(fine.fx, fine.fy, fine.cx, fine.cy, fine.width, fine.height,
                         np.ascontiguousarray(camera.r_wc, np.float64),
                         np.ascontiguousarray(camera.t_wc, np.float64), r_wo, t_wo, geom)


@numba.njit(cache=True, nogil=True)
def _boxes_kernel(fx, fy, cx, cy, width, height, r_wc, c, r_wo, t_wo, geom):
    k = r_wo.shape[0]
    boxes = np.zeros((k, 4), np.int64)
    for j in range(k):
        umin = vmin = np.inf
        umax = vmax = -np.inf
        behind = front = 0
        for sx in (-1.0, 1.0):
            for sy in (-1.0, 1.0):
                px, py = sx * geom[j, 0], sy * geom[j, 1]
                w = np.empty(3)  # corner in the world, relative to the camera
                for a in range(3):
                    w[a] = r_wo[j, a, 0] * px + r_wo[j, a, 1] * py + t_wo[j, a] - c[a]
                x = w[0] * r_wc[0, 0] + w[1] * r_wc[1, 0] + w[2] * r_wc[2, 0]
                y = w[0] * r_wc[0, 1] + w[1] * r_wc[1, 1] + w[2] * r_wc[2, 1]
                z = w[0] * r_wc[0, 2] + w[1] * r_wc[1, 2] + w[2] * r_wc[2, 2]
                if z <= 1e-9:
                    behind += 1
                if z > 0:
                    front += 1
                    u, v = fx * x / z + cx, fy * y / z + cy
                    umin, umax = min(umin, u), max(umax, u)
                    vmin, vmax = min(vmin, v), max(vmax, v)
        if front == 0:
            continue
        if behind > 0:
            boxes[j, 0], boxes[j, 1], boxes[j, 2], boxes[j, 3] = 0, width, 0, height
            continue
        x0, x1 = max(0, math.floor(umin) - 1), min(width, math.ceil(umax) + 2)
        y0, y1 = max(0, math.floor(vmin) - 1), min(height, math.ceil(vmax) + 2)
        if x0 < x1 and y0 < y1:
            boxes[j, 0], boxes[j, 1], boxes[j, 2], boxes[j, 3] = x0, x1, y0, y1
    return boxes


def object_frames(scene: DynamicScene, object_poses: tuple[Pose, ...]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The objects' poses as flat arrays for compiled kernels: ``r_wo`` float64[K, 3, 3]
    and ``t_wo`` float64[K, 3] (their surfaces: :attr:`DynamicScene.packed`)."""
    k = len(scene.objects)
    if len(object_poses) != k:
        raise ValueError(f"{len(object_poses)} object poses for {k} objects")
    r_wo = np.array([p.r_wc for p in object_poses], np.float64).reshape(k, 3, 3)
    t_wo = np.array([p.t_wc for p in object_poses], np.float64).reshape(k, 3)
    return r_wo, t_wo


@numba.njit(cache=True, nogil=True)
def row_boxes(y, fx, fy, cx, cy, r_wc, origin, r_wo, boxes, hulls, hull_sizes, out):
    """Fills ``out`` (int64[K, 4]) with each object's box narrowed to row ``y``: the
    samples ``x0 <= x < x1`` of that row whose rays can meet the object's solid part (its
    :func:`~esim_lite.geometry.objects.support_halfplanes`, one sample of margin), empty
    where none can. Conservative, so a renderer that tests only these samples draws what
    it draws when testing the whole box. ``origin``: :func:`camera_in_objects`."""
    ry = (y - cy) / fy
    for j in range(boxes.shape[0]):
        out[j, 0], out[j, 1], out[j, 2], out[j, 3] = 0, 0, y, y + 1
        if not (boxes[j, 2] <= y < boxes[j, 3]) or boxes[j, 1] <= boxes[j, 0] \
                or hull_sizes[j] == 0:
            continue
        oz = origin[j, 2]
        if oz == 0:  # the camera in the object's plane sees it edge-on: no hit
            continue
        # the ray through (x, y) in the object's frame: p + x q (x in samples)
        p = np.zeros(3)
        q = np.zeros(3)
        for k in range(3):
            for a in range(3):
                p[k] += r_wo[j, a, k] * (r_wc[a, 1] * ry + r_wc[a, 2] - r_wc[a, 0] * cx / fx)
                q[k] += r_wo[j, a, k] * (r_wc[a, 0] / fx)
        lo, hi = -np.inf, np.inf
        # in front: oz dz <= 0. Inside the half-plane a X + b Y <= e, with X = ox - oz dx / dz
        # (Y alike): N / dz <= 0 for N = a (ox dz - oz dx) + b (oy dz - oz dy) - e dz, and dz
        # has the sign opposite to oz's in front, so -oz N <= 0. Each is c0 + c1 x <= 0.
        n = hull_sizes[j]
        for i in range(n + 1):
            if i == n:
                c0, c1 = oz * p[2], oz * q[2]
            else:
                a_, b_, e_ = hulls[j, i, 0], hulls[j, i, 1], hulls[j, i, 2]
                c0 = -oz * (a_ * (origin[j, 0] * p[2] - oz * p[0])
                            + b_ * (origin[j, 1] * p[2] - oz * p[1]) - e_ * p[2])
                c1 = -oz * (a_ * (origin[j, 0] * q[2] - oz * q[0])
                            + b_ * (origin[j, 1] * q[2] - oz * q[1]) - e_ * q[2])
            # c0 + c1 x <= 0
            if c1 > 0:
                hi = min(hi, -c0 / c1)
            elif c1 < 0:
                lo = max(lo, -c0 / c1)
            elif c0 > 0:
                lo, hi = np.inf, -np.inf
        if not (lo <= hi):  # empty (or NaN: keep the whole box)
            if lo > hi:
                continue
            out[j, 0], out[j, 1] = boxes[j, 0], boxes[j, 1]
            continue
        x0, x1 = boxes[j, 0], boxes[j, 1]  # the samples lo - 1 <= x <= hi + 1 of the box
        if lo - 1.0 > x0:
            if lo - 1.0 >= x1:
                continue
            x0 = int(math.ceil(lo - 1.0))
        if hi + 1.0 < x1 - 1:
            if hi + 1.0 < x0:
                continue
            x1 = int(math.floor(hi + 1.0)) + 1
        if x0 < x1:
            out[j, 0], out[j, 1] = x0, x1


@numba.njit(cache=True, nogil=True)
def bilinear_at(flat, off, h, w, col, row):
    """Bilinear lookup of the [h, w] image stored at ``flat[off:off + h w]`` (row-major),
    texels clamped (as :func:`bilinear`); compiled."""
    x = min(max(col, 0.0), w - 1.0)
    y = min(max(row, 0.0), h - 1.0)
    x0 = min(int(np.floor(x)), w - 2)
    y0 = min(int(np.floor(y)), h - 2)
    fx, fy = x - x0, y - y0
    a00 = flat[off + y0 * w + x0]
    a01 = flat[off + y0 * w + x0 + 1]
    a10 = flat[off + (y0 + 1) * w + x0]
    a11 = flat[off + (y0 + 1) * w + x0 + 1]
    top = a00 * (1 - fx) + a01 * fx
    bottom = a10 * (1 - fx) + a11 * fx
    return top * (1 - fy) + bottom * fy


@numba.njit(cache=True, nogil=True)
def camera_in_objects(c, r_wo, t_wo):
    """float64[K, 3]: the camera centre ``c`` in every object's frame (compiled)."""
    k_objects = r_wo.shape[0]
    origin = np.empty((k_objects, 3))
    for j in range(k_objects):
        for a in range(3):
            origin[j, a] = (r_wo[j, 0, a] * (c[0] - t_wo[j, 0]) + r_wo[j, 1, a] *
                            (c[1] - t_wo[j, 1]) + r_wo[j, 2, a] * (c[2] - t_wo[j, 2]))
    return origin


@numba.njit(cache=True, nogil=True, inline="always")
def nearest_hit(d0, d1, d2, c_z, x, y, origin, r_wo, geom, shapes, alphas, boxes, cutoff):
    """The nearest alpha-tested hit of the world ray ``(d0, d1, d2)`` from a camera at
    height ``c_z`` through sample ``(x, y)``, as :func:`trace` finds it (compiled):
    ``(depth, surface, col, row)``, surface -1 for nothing, 0 the background, ``k + 1``
    object ``k``; ``col, row``: the object's texture coordinates. An object is tested only
    where ``(x, y)`` lies in its box ``boxes[k]`` (:func:`sample_box`)."""
    best = np.inf
    hit = -1
    col = row = 0.0
    if d2 != 0:
        lam = -c_z / d2
        if lam > 0 and np.isfinite(lam):
            best, hit = lam, 0
    for j in range(r_wo.shape[0]):
        if x < boxes[j, 0] or x >= boxes[j, 1] or y < boxes[j, 2] or y >= boxes[j, 3]:
            continue
        do_z = r_wo[j, 0, 2] * d0 + r_wo[j, 1, 2] * d1 + r_wo[j, 2, 2] * d2
        if do_z == 0:
            continue
        lam = -origin[j, 2] / do_z
        if not (lam > 0 and lam < best):
            continue
        do_x = r_wo[j, 0, 0] * d0 + r_wo[j, 1, 0] * d1 + r_wo[j, 2, 0] * d2
        do_y = r_wo[j, 0, 1] * d0 + r_wo[j, 1, 1] * d1 + r_wo[j, 2, 1] * d2
        px = origin[j, 0] + lam * do_x
        py = origin[j, 1] + lam * do_y
        if abs(px) > geom[j, 0] or abs(py) > geom[j, 1]:
            continue
        oc = geom[j, 2] * px + geom[j, 3]
        orow = geom[j, 4] * py + geom[j, 5]
        if bilinear_at(alphas, shapes[j, 0], shapes[j, 1], shapes[j, 2], oc, orow) >= cutoff:
            best, hit, col, row = lam, j + 1, oc, orow
    return best, hit, col, row


@numba.njit(cache=True, nogil=True)
def _truth_kernel(height, width, fx, fy, cx, cy, r_wc, c, v_c, w_c, r_wo, t_wo, v_o, w_o,
                  geom, shapes, alphas, boxes, cutoff, miss, hulls, hull_sizes):
    flow = np.zeros((2, height, width), np.float32)
    depth = np.empty((height, width), np.float32)
    ids = np.empty((height, width), np.uint8)
    origin = camera_in_objects(c, r_wo, t_wo)
    row = np.zeros_like(boxes)
    for y in range(height):
        row_boxes(y, fx, fy, cx, cy, r_wc, origin, r_wo, boxes, hulls, hull_sizes, row)
        ux0, ux1 = width, 0  # the samples of the row that any object's narrowed box holds
        for j in range(row.shape[0]):
            if row[j, 1] > row[j, 0]:
                ux0, ux1 = min(ux0, row[j, 0]), max(ux1, row[j, 1])
        ry = (y - cy) / fy
        e0, e1, e2 = r_wc[0, 1] * ry, r_wc[1, 1] * ry, r_wc[2, 1] * ry
        for x in range(width):
            rx = (x - cx) / fx
            d0 = r_wc[0, 0] * rx + e0 + r_wc[0, 2]
            d1 = r_wc[1, 0] * rx + e1 + r_wc[1, 2]
            d2 = r_wc[2, 0] * rx + e2 + r_wc[2, 2]
            if ux0 <= x < ux1:
                best, hit, _, _ = nearest_hit(d0, d1, d2, c[2], x, y, origin, r_wo, geom,
                                              shapes, alphas, row, cutoff)
            else:  # the background alone (nearest_hit's first test)
                best, hit = np.inf, -1
                if d2 != 0:
                    lam = -c[2] / d2
                    if lam > 0 and np.isfinite(lam):
                        best, hit = lam, 0
            if hit < 0:
                ids[y, x] = miss
                depth[y, x] = np.inf
                continue
            ids[y, x] = hit
            depth[y, x] = best
            # world point, its velocity, and its image velocity
            rel0, rel1, rel2 = best * d0, best * d1, best * d2
            vx = vy = vz = 0.0
            if hit > 0:
                j = hit - 1
                ax = c[0] + rel0 - t_wo[j, 0]
                ay = c[1] + rel1 - t_wo[j, 1]
                az = c[2] + rel2 - t_wo[j, 2]
                vx = v_o[j, 0] + w_o[j, 1] * az - w_o[j, 2] * ay
                vy = v_o[j, 1] + w_o[j, 2] * ax - w_o[j, 0] * az
                vz = v_o[j, 2] + w_o[j, 0] * ay - w_o[j, 1] * ax
            dxw = vx - v_c[0] - (w_c[1] * rel2 - w_c[2] * rel1)
            dyw = vy - v_c[1] - (w_c[2] * rel0 - w_c[0] * rel2)
            dzw = vz - v_c[2] - (w_c[0] * rel1 - w_c[1] * rel0)
            xc = r_wc[0, 0] * rel0 + r_wc[1, 0] * rel1 + r_wc[2, 0] * rel2
            yc = r_wc[0, 1] * rel0 + r_wc[1, 1] * rel1 + r_wc[2, 1] * rel2
            zc = r_wc[0, 2] * rel0 + r_wc[1, 2] * rel1 + r_wc[2, 2] * rel2
            if not zc > 0:
                continue
            dxc = r_wc[0, 0] * dxw + r_wc[1, 0] * dyw + r_wc[2, 0] * dzw
            dyc = r_wc[0, 1] * dxw + r_wc[1, 1] * dyw + r_wc[2, 1] * dzw
            dzc = r_wc[0, 2] * dxw + r_wc[1, 2] * dyw + r_wc[2, 2] * dzw
            flow[0, y, x] = fx * (dxc * zc - xc * dzc) / (zc * zc)
            flow[1, y, x] = fy * (dyc * zc - yc * dzc) / (zc * zc)
    return flow, depth, ids
