"""Dynamic scenes: the textured background plane plus independently moving planar objects.

An object is a planar patch with a texture and an alpha shape. In its own frame the patch
lies in ``z = 0`` with the same texel convention as :class:`PlanarScene` (texture spanning
``X in [-width_m/2, width_m/2]``, ``Y in [-height_m/2, height_m/2]``, row 0 at
``Y = +height_m/2``); a point of it belongs to the object where the bilinear alpha is at
least :data:`ALPHA_CUTOFF` (the alpha test). Patches are two-sided. Each object follows its
own :class:`BSplineTrajectory` of object-to-world poses (``X_world = R @ X_obj + t``), so
position, orientation and their velocities exist at any time.

The background is the static plane ``z = 0`` of :mod:`esim_lite.geometry.scene`; surface
ids are 0 for it and ``k + 1`` for object ``k``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from esim_lite.geometry.pose import Pose, Twist
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import BSplineTrajectory

#: A point of an object is solid where its bilinear alpha is at least this.
ALPHA_CUTOFF = 0.5
#: Most objects a scene holds (ids are uint8 with 0 the background).
MAX_OBJECTS = 254


@dataclass(frozen=True, eq=False)
class ObjectPatch:
    """A textured planar patch with an alpha shape, moving along ``trajectory``.

    Attributes:
        surface: texture (float32[h, w], linear intensity) and size of the patch.
        alpha: float32[h, w] in [0, 1], on the texture's grid: where the object is solid.
        trajectory: object-to-world poses over the sequence.
        name: where the texture came from (provenance, recorded in shards).
    """

    surface: PlanarScene
    alpha: np.ndarray
    trajectory: BSplineTrajectory
    name: str = ""

    def __post_init__(self) -> None:
        a = self.alpha
        if not isinstance(a, np.ndarray) or a.dtype != np.float32 or \
                a.shape != self.surface.texture.shape:
            raise ValueError("ObjectPatch.alpha must be float32 with the texture's shape "
                             f"{self.surface.texture.shape}")
        if not np.all((a >= 0) & (a <= 1)):
            raise ValueError("ObjectPatch.alpha must lie in [0, 1]")

    def pose(self, t_s: float) -> Pose:
        return self.trajectory.pose(t_s)

    def pose_and_twist(self, t_s: float) -> tuple[Pose, Twist]:
        return self.trajectory.pose_and_twist(t_s)


@dataclass(frozen=True, eq=False)
class PackedSurfaces:
    """The objects' pose-free data as flat arrays for compiled kernels.

    Attributes:
        geom: float64[K, 6]: half width, half height, then the plane-to-texture map (col
            scale, col offset, row scale, row offset).
        shapes: int64[K, 3]: offset into the flat arrays, h, w.
        alphas, texels: float64, every object's alpha / texture raveled one after another.
        hulls: float64[K, M, 3]: half-planes ``a X + b Y <= e`` (object-plane metres) whose
            intersection holds every solid point of the object (:func:`support_halfplanes`);
            object ``k`` uses the first ``hull_sizes[k]`` rows.
        hull_sizes: int64[K]: half-planes per object; 0 for an object with no solid point.
    """

    geom: np.ndarray
    shapes: np.ndarray
    alphas: np.ndarray
    texels: np.ndarray
    hulls: np.ndarray
    hull_sizes: np.ndarray


@dataclass(frozen=True, eq=False)
class DynamicScene:
    """The static background plane and the moving objects in front of it."""

    background: PlanarScene
    objects: tuple[ObjectPatch, ...] = ()

    def __post_init__(self) -> None:
        if len(self.objects) > MAX_OBJECTS:
            raise ValueError(f"at most {MAX_OBJECTS} objects, got {len(self.objects)}")

    @cached_property
    def packed(self) -> PackedSurfaces:
        """The objects' surfaces for compiled kernels (built once, read-only)."""
        k = len(self.objects)
        geom = np.zeros((k, 6))
        shapes = np.zeros((k, 3), np.int64)
        offset = 0
        for j, obj in enumerate(self.objects):
            m = obj.surface.texture_from_plane()
            geom[j] = (obj.surface.width_m / 2, obj.surface.height_m / 2, m[0, 0], m[0, 2],
                       m[1, 1], m[1, 2])
            h, w = obj.alpha.shape
            shapes[j] = (offset, h, w)
            offset += h * w

        def flat(arrays):
            return np.concatenate([a.ravel() for a in arrays]).astype(np.float64) if k \
                else np.zeros(0)

        planes = [support_halfplanes(o.alpha, o.surface.texture_from_plane())
                  for o in self.objects]
        hulls = np.zeros((k, max([len(p) for p in planes], default=0), 3))
        for j, p in enumerate(planes):
            hulls[j, :len(p)] = p
        packed = PackedSurfaces(geom, shapes, flat([o.alpha for o in self.objects]),
                                flat([o.surface.texture for o in self.objects]), hulls,
                                np.array([len(p) for p in planes], np.int64))
        for a in (packed.geom, packed.shapes, packed.alphas, packed.texels, packed.hulls,
                  packed.hull_sizes):
            a.flags.writeable = False
        return packed

    def object_poses(self, t_s: float) -> tuple[Pose, ...]:
        """Object-to-world poses at ``t_s`` (in object order)."""
        return tuple(o.pose(t_s) for o in self.objects)

    def object_motion(self, t_s: float) -> tuple[tuple[Pose, ...], tuple[Twist, ...]]:
        """Poses and world-frame twists of every object at ``t_s``."""
        both = [o.pose_and_twist(t_s) for o in self.objects]
        return tuple(p for p, _ in both), tuple(w for _, w in both)


#: How far (texels) :func:`support_halfplanes` reaches past the centre of a texel with
#: alpha > 0: a bilinear alpha above 0 needs such a texel within 1 in each axis; the other
#: half texel is a margin that rounding in the renderers' spans cannot eat.
SUPPORT_REACH = 1.5


def support_halfplanes(alpha: np.ndarray, texture_from_plane: np.ndarray) -> np.ndarray:
    """float64[M, 3]: half-planes ``a X + b Y <= e`` (``a, b`` unit, object-plane metres)
    bounding the convex hull of every point within :data:`SUPPORT_REACH` texels of a texel
    with alpha > 0, so every point whose bilinear alpha passes :data:`ALPHA_CUTOFF` lies
    inside all of them (empty: no texel has alpha > 0). Renderers use them only to skip
    rays that cannot meet the object; the alpha test still decides every hit."""
    rows = np.flatnonzero((alpha > 0).any(axis=1))
    if not len(rows):
        return np.zeros((0, 3))
    solid = alpha[rows] > 0
    left = solid.argmax(axis=1)
    right = alpha.shape[1] - 1 - solid[:, ::-1].argmax(axis=1)
    r = SUPPORT_REACH
    cols = np.concatenate([left - r, left - r, right + r, right + r]).astype(np.float64)
    rws = np.concatenate([rows - r, rows + r, rows - r, rows + r]).astype(np.float64)
    (sx, _, ox), (_, sy, oy) = texture_from_plane[0], texture_from_plane[1]
    hull = _convex_hull(np.column_stack([(cols - ox) / sx, (rws - oy) / sy]))
    edge = np.roll(hull, -1, axis=0) - hull
    normal = np.column_stack([edge[:, 1], -edge[:, 0]])  # outward for a CCW hull
    length = np.hypot(normal[:, 0], normal[:, 1])
    keep = length > 0
    normal = normal[keep] / length[keep, None]
    return np.column_stack([normal, (normal * hull[keep]).sum(axis=1)])


def _convex_hull(points: np.ndarray) -> np.ndarray:
    """float64[N, 2]: the convex hull's vertices counter-clockwise (Andrew's monotone
    chain; collinear points dropped)."""
    pts = np.unique(points, axis=0)  # sorted by x, then y
    if len(pts) < 3:
        return pts

    def chain(seq: np.ndarray) -> list[np.ndarray]:
        out: list[np.ndarray] = []
        for p in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = chain(pts), chain(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def as_dynamic(scene: PlanarScene | DynamicScene) -> DynamicScene:
    """A :class:`DynamicScene` for either scene type (a plane alone has no objects)."""
    return scene if isinstance(scene, DynamicScene) else DynamicScene(scene)


def relative_pose(camera: Pose, frame: Pose) -> Pose:
    """The camera's pose in ``frame``'s coordinates (``frame^-1 o camera``): how an object's
    own plane sees the camera, so plane-only code (homographies, footprints) applies."""
    r = frame.r_wc.T @ camera.r_wc
    t = frame.r_wc.T @ (camera.t_wc - frame.t_wc)
    return Pose(r, t)
