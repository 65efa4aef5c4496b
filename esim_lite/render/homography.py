"""Exact planar rendering by homography warping (the way ESIM renders planar scenes).

Each output pixel is the mean of ``s x s`` point samples at the centres of an ``s x s``
sub-pixel grid (a box pixel filter), each sample a bilinear lookup of the texture at the
exact point where its ray meets the plane. The sub-pixel grid is rendered as one image with
intrinsics scaled by ``s`` (see :meth:`Intrinsics.scaled`) and block-averaged.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from esim_lite.geometry.camera import Intrinsics, sample_grids
from esim_lite.geometry.pose import Pose
from esim_lite.geometry.scene import PlanarScene


class HomographyRenderer:
    """Renders each named camera's :class:`PlanarScene`; deterministic and thread-safe.

    Args:
        scenes: the plane seen by each camera (textures may be prefiltered per camera).
        cameras: intrinsics by camera name.
        supersample: sub-pixel grid side per camera name.
    """

    name = "homography"

    def __init__(self, scenes: dict[str, PlanarScene], cameras: dict[str, Intrinsics],
                 supersample: dict[str, int]) -> None:
        self.scenes = dict(scenes)
        self.cameras = dict(cameras)
        self.supersample, self._fine = sample_grids(self.cameras, supersample)

    def render(self, camera: str, pose: Pose, objects: Sequence[Pose] = ()) -> np.ndarray:
        """float32[H, W] linear intensity seen by ``camera`` at ``pose`` (one plane: no
        objects)."""
        if objects:
            raise ValueError("the homography renderer renders one plane, without objects")
        cam, fine, s = self.cameras[camera], self._fine[camera], self.supersample[camera]
        scene = self.scenes[camera]
        m = scene.texture_from_image(fine, pose)
        img = cv2.warpPerspective(scene.texture, m, (fine.width, fine.height),
                                  flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_REPLICATE)
        if s == 1:
            return img
        return cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)

    def close(self) -> None:
        pass
