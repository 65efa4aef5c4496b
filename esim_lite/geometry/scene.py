"""A textured plane: the scene model of ESIM's planar renderer and of our dataset.

World frame: the plane is ``z = 0`` with its lit side facing ``+z``; the texture spans
``X in [-width_m/2, width_m/2]``, ``Y in [-height_m/2, height_m/2]``, texel row 0 along
``Y = +height_m/2`` and column 0 along ``X = -width_m/2`` (the image reads upright seen
from above with world +Y up). Texel ``(row i, col j)`` has its centre at texture
coordinates ``(j, i)`` (OpenCV convention) and at
``X = -width_m/2 + (j + 0.5) width_m / w``, ``Y = height_m/2 - (i + 0.5) height_m / h``.

The texture holds linear intensity (radiance of a diffuse plane under uniform light), so a
pixel's value does not depend on the viewing direction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.pose import Pose


def intersect_plane(pose: Pose, rays_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hits of camera rays on the plane ``z = 0``.

    Args:
        rays_c: float64[..., 3] ray directions in the camera frame (z = 1 normalised).
    Returns:
        (points_w float64[..., 3], depth float64[...]): world points and camera-frame depth
        Z of each hit; depth is -inf where the ray misses the plane (parallel or upward).
    """
    d_w = rays_c @ pose.r_wc.T
    dz = d_w[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(dz < 0, -pose.t_wc[2] / dz, -np.inf)
    points = pose.t_wc + np.where(np.isfinite(depth), depth, 0.0)[..., None] * d_w
    return points, depth


@dataclass(frozen=True, eq=False)
class PlanarScene:
    """Texture ``float32[h, w]`` (linear intensity, >= 0) stretched over a plane rectangle."""

    texture: np.ndarray
    width_m: float
    height_m: float

    def __post_init__(self) -> None:
        tex = self.texture
        if not isinstance(tex, np.ndarray) or tex.ndim != 2 or tex.dtype != np.float32:
            raise ValueError("PlanarScene.texture must be a float32[h, w] array")
        if min(tex.shape) < 2:
            raise ValueError(f"PlanarScene.texture is too small: {tex.shape}")
        if not np.all(np.isfinite(tex)) or tex.min() < 0:
            raise ValueError("PlanarScene.texture must be finite and non-negative")
        if self.width_m <= 0 or self.height_m <= 0:
            raise ValueError(f"plane size must be positive, got {self.width_m}x{self.height_m}")

    @property
    def texture_hw(self) -> tuple[int, int]:
        return int(self.texture.shape[0]), int(self.texture.shape[1])

    def texture_from_plane(self) -> np.ndarray:
        """float64[3, 3]: plane ``(X, Y, 1)`` to texture coordinates ``(col, row, 1)``."""
        h, w = self.texture_hw
        sx, sy = w / self.width_m, h / self.height_m
        return np.array([[sx, 0.0, w / 2 - 0.5], [0.0, -sy, h / 2 - 0.5], [0.0, 0.0, 1.0]])

    def texture_from_image(self, intrinsics: Intrinsics, pose: Pose) -> np.ndarray:
        """float64[3, 3] homography: image pixel ``(u, v, 1)`` to texture ``(col, row, 1)``.

        A plane point projects as ``K [r1 r2 t] (X, Y, 1)`` with ``r1, r2`` the first two
        columns of ``R_cw``; inverting that and chaining the texture map is exact.
        """
        r_cw, t_cw = pose.r_cw, pose.t_cw
        image_from_plane = intrinsics.matrix @ np.column_stack([r_cw[:, 0], r_cw[:, 1], t_cw])
        h = self.texture_from_plane() @ _adjugate(image_from_plane)
        return h / h[2, 2]  # the adjugate is the inverse times the determinant: it cancels

    def covers_view(self, intrinsics: Intrinsics, pose: Pose, margin_m: float = 0.0) -> bool:
        """True if every pixel of the camera sees the textured rectangle, on its lit side.

        The image rectangle maps to the plane by a homography, so with all four corner rays
        hitting the plane in front of the camera their convex hull is the whole footprint.
        """
        if pose.t_wc[2] <= 0:
            return False
        points, depth = intersect_plane(pose, intrinsics.corner_rays())
        if not np.all(np.isfinite(depth)) or np.any(depth <= 0):
            return False
        hw, hh = self.width_m / 2 - margin_m, self.height_m / 2 - margin_m
        return bool(np.all(np.abs(points[:, 0]) <= hw) and np.all(np.abs(points[:, 1]) <= hh))


def _adjugate(m: np.ndarray) -> np.ndarray:
    """float64[3, 3] adjugate of ``m`` (``det(m) inv(m)``), in closed form: a render step
    needs one per camera, and ``np.linalg.inv``'s call costs more than the arithmetic."""
    (a, b, c), (d, e, f), (g, h, i) = m.tolist()
    return np.array([[e * i - f * h, c * h - b * i, b * f - c * e],
                     [f * g - d * i, a * i - c * g, c * d - a * f],
                     [d * h - e * g, b * g - a * h, a * e - b * d]])
