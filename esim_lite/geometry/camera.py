"""Pinhole cameras and the paired LR-event / HR-intensity rig.

Pixel convention (OpenCV's): pixel ``(col u, row v)`` has its centre at continuous image
coordinates ``(u, v)`` and covers ``[u-0.5, u+0.5] x [v-0.5, v+0.5]``; a centred principal
point is ``cx = (W-1)/2``. The camera frame is x right, y down, z forward (optical axis).

An HR camera of scale ``s`` shares the LR camera's centre and orientation and covers the
same continuous image rectangle ``[-0.5, W-0.5] x [-0.5, H-0.5]``, so HR pixel ``k`` along
an axis covers exactly LR interval ``[(k)/s - 0.5, (k+1)/s - 0.5]``:
``f_hr = s f``, ``c_hr = s (c + 0.5) - 0.5``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from esim_lite.core.scales import check_scales, hr_camera


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels plus the image size (height before width)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got {self.fx}, {self.fy}")

    @classmethod
    def from_fov(cls, width: int, height: int, fov_x_deg: float) -> Intrinsics:
        """Square pixels, centred principal point, horizontal field of view ``fov_x_deg``."""
        if not 0 < fov_x_deg < 180:
            raise ValueError(f"fov_x_deg must be in (0, 180), got {fov_x_deg}")
        f = (width / 2) / math.tan(math.radians(fov_x_deg) / 2)
        return cls(f, f, (width - 1) / 2, (height - 1) / 2, width, height)

    @property
    def hw(self) -> tuple[int, int]:
        return self.height, self.width

    @property
    def matrix(self) -> np.ndarray:
        """float64[3, 3] camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fov_x_deg(self) -> float:
        return math.degrees(2 * math.atan(self.width / (2 * self.fx)))

    def scaled(self, scale: float) -> Intrinsics:
        """Camera with ``scale`` times the pixels over exactly the same field of view."""
        if scale <= 0:
            raise ValueError(f"scale must be positive, got {scale}")
        w, h = round(self.width * scale), round(self.height * scale)
        if not (math.isclose(w, self.width * scale) and math.isclose(h, self.height * scale)):
            raise ValueError(f"scale {scale} does not give whole pixels for "
                             f"{self.width}x{self.height}")
        return Intrinsics(self.fx * scale, self.fy * scale, scale * (self.cx + 0.5) - 0.5,
                          scale * (self.cy + 0.5) - 0.5, w, h)

    def pixel_rays(self) -> np.ndarray:
        """float64[H, W, 3]: rays ``K^-1 (u, v, 1)`` through every pixel centre (z = 1)."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64),
                           np.arange(self.height, dtype=np.float64))
        return np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy,
                         np.ones_like(u)], axis=-1)

    def corner_rays(self) -> np.ndarray:
        """float64[4, 3]: rays through the four outer corners of the image rectangle."""
        us = np.array([-0.5, self.width - 0.5, self.width - 0.5, -0.5])
        vs = np.array([-0.5, -0.5, self.height - 0.5, self.height - 0.5])
        return np.stack([(us - self.cx) / self.fx, (vs - self.cy) / self.fy, np.ones(4)], 1)


def sample_grids(cameras: dict[str, Intrinsics], supersample: dict[str, int]
                 ) -> tuple[dict[str, int], dict[str, Intrinsics]]:
    """Per camera, the sub-pixel grid side (1 where ``supersample`` names none) and the
    ``s``-times finer camera whose pixel centres are the sample points.

    Raises:
        ValueError: a factor below 1.
    """
    factors = {name: int(supersample.get(name, 1)) for name in cameras}
    if any(s < 1 for s in factors.values()):
        raise ValueError(f"supersample factors must be >= 1, got {factors}")
    return factors, {name: cam.scaled(factors[name]) for name, cam in cameras.items()}


@dataclass(frozen=True)
class CameraRig:
    """The LR event camera and HR intensity cameras (one per scale) on one optical centre."""

    event: Intrinsics
    scales: tuple[int, ...] = (2,)

    def __post_init__(self) -> None:
        check_scales(self.scales, "scales")

    def hr(self, scale: int) -> Intrinsics:
        if scale not in self.scales:
            raise ValueError(f"scale {scale} is not in this rig's scales {self.scales}")
        return self.event.scaled(scale)

    def cameras(self) -> dict[str, Intrinsics]:
        """All cameras by name: ``"lr"`` and ``"hr_x{s}"``."""
        out = {"lr": self.event}
        out.update({hr_camera(s): self.event.scaled(s) for s in self.scales})
        return out
