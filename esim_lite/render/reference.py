"""The exact reference renderer: every sample ray traced in float64 through the dynamic
scene (:func:`esim_lite.geometry.visibility.trace`), nearest alpha-tested hit, bilinear
texture, ``s x s`` samples per pixel averaged in a fixed order.

Slow (numpy) and exact: the oracle that the Mitsuba backend is measured against on scenes
with objects. It renders single-plane scenes too, where it agrees with the homography
backend.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.objects import DynamicScene
from esim_lite.geometry.pose import Pose
from esim_lite.geometry.visibility import MISS, shade, trace


class ReferenceRenderer:
    """Renders each named camera's :class:`DynamicScene` exactly; deterministic.

    Args:
        scenes: the scene seen by each camera (backgrounds may be prefiltered per camera).
        cameras: intrinsics by camera name.
        supersample: sub-pixel grid side per camera name.
    """

    name = "reference"

    def __init__(self, scenes: dict[str, DynamicScene], cameras: dict[str, Intrinsics],
                 supersample: dict[str, int]) -> None:
        self.scenes = dict(scenes)
        self.cameras = dict(cameras)
        self.supersample = {name: int(supersample.get(name, 1)) for name in self.cameras}
        if any(s < 1 for s in self.supersample.values()):
            raise ValueError(f"supersample factors must be >= 1, got {self.supersample}")
        self._rays = {name: cam.scaled(self.supersample[name]).pixel_rays()
                      for name, cam in self.cameras.items()}

    def render(self, camera: str, pose: Pose, objects: Sequence[Pose] = ()) -> np.ndarray:
        """float32[H, W] linear intensity seen by ``camera`` at ``pose`` with the objects at
        ``objects`` (object-to-world poses, in the scene's object order)."""
        cam, s, scene = self.cameras[camera], self.supersample[camera], self.scenes[camera]
        hits = trace(scene, pose, tuple(objects), self._rays[camera])
        if np.any(hits.ids == MISS):
            raise ValueError(f"camera {camera!r} sees past the background plane at this pose")
        img = shade(scene, hits)
        if s > 1:
            img = img.reshape(cam.height, s, cam.width, s).mean(axis=(1, 3))
        return img.astype(np.float32)

    def close(self) -> None:
        pass
