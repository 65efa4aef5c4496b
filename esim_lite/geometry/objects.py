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
    """

    geom: np.ndarray
    shapes: np.ndarray
    alphas: np.ndarray
    texels: np.ndarray


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

        packed = PackedSurfaces(geom, shapes, flat([o.alpha for o in self.objects]),
                                flat([o.surface.texture for o in self.objects]))
        for a in (packed.geom, packed.shapes, packed.alphas, packed.texels):
            a.flags.writeable = False
        return packed

    def object_poses(self, t_s: float) -> tuple[Pose, ...]:
        """Object-to-world poses at ``t_s`` (in object order)."""
        return tuple(o.pose(t_s) for o in self.objects)

    def object_motion(self, t_s: float) -> tuple[tuple[Pose, ...], tuple[Twist, ...]]:
        """Poses and world-frame twists of every object at ``t_s``."""
        both = [o.pose_and_twist(t_s) for o in self.objects]
        return tuple(p for p, _ in both), tuple(w for _, w in both)


def as_dynamic(scene: PlanarScene | DynamicScene) -> DynamicScene:
    """A :class:`DynamicScene` for either scene type (a plane alone has no objects)."""
    return scene if isinstance(scene, DynamicScene) else DynamicScene(scene)


def relative_pose(camera: Pose, frame: Pose) -> Pose:
    """The camera's pose in ``frame``'s coordinates (``frame^-1 o camera``): how an object's
    own plane sees the camera, so plane-only code (homographies, footprints) applies."""
    r = frame.r_wc.T @ camera.r_wc
    t = frame.r_wc.T @ (camera.t_wc - frame.t_wc)
    return Pose(r, t)
