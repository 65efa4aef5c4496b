"""Exact planar rendering by homography warping (the way ESIM renders planar scenes), with
moving objects ray cast only where they can be seen.

Each output pixel is the mean of ``s x s`` point samples at the centres of an ``s x s``
sub-pixel grid (a box pixel filter), each sample a bilinear lookup of the texture at the
exact point where its ray meets the plane. The sub-pixel grid is rendered as one image with
intrinsics scaled by ``s`` (see :meth:`Intrinsics.scaled`) and block-averaged.

With objects (a :class:`DynamicScene`), the background is warped as above and only the
samples inside an object's image-space box (:func:`sample_boxes`, the rays that can meet its
patch) are traced, by the reference renderer's rules (:func:`nearest_hit`: nearest
alpha-tested hit in float64, bilinear texel): most samples of a view see the background
alone, so this costs a fraction of tracing every sample.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numba
import numpy as np

from esim_lite.geometry.camera import Intrinsics, sample_grids
from esim_lite.geometry.objects import ALPHA_CUTOFF, DynamicScene, as_dynamic
from esim_lite.geometry.pose import Pose
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.visibility import (
    bilinear_at,
    camera_in_objects,
    nearest_hit,
    object_frames,
    row_boxes,
    sample_boxes,
)


class HomographyRenderer:
    """Renders each named camera's :class:`PlanarScene` or :class:`DynamicScene`;
    deterministic and thread-safe.

    Args:
        scenes: the scene seen by each camera (textures may be prefiltered per camera).
        cameras: intrinsics by camera name.
        supersample: sub-pixel grid side per camera name.
    """

    name = "homography"

    def __init__(self, scenes: dict[str, PlanarScene | DynamicScene],
                 cameras: dict[str, Intrinsics], supersample: dict[str, int]) -> None:
        self.scenes = {name: as_dynamic(scene) for name, scene in scenes.items()}
        self.cameras = dict(cameras)
        self.supersample, self._fine = sample_grids(self.cameras, supersample)
        self._kept: dict[str, tuple[tuple[bytes, bytes], np.ndarray | None]] = {}

    def render(self, camera: str, pose: Pose, objects: Sequence[Pose] = ()) -> np.ndarray:
        """float32[H, W] linear intensity seen by ``camera`` at ``pose`` with the scene's
        objects at ``objects`` (object-to-world poses, in the scene's object order)."""
        cam, fine, s = self.cameras[camera], self._fine[camera], self.supersample[camera]
        scene = self.scenes[camera]
        objects = tuple(objects)
        if len(objects) != len(scene.objects):
            raise ValueError(f"camera {camera!r}: the scene has {len(scene.objects)} "
                             f"objects, render() got {len(objects)} object poses")
        if objects:
            img = self._overlay(scene, fine, pose, objects, self._background(camera, pose))
        else:
            img = self._warp(scene, fine, pose)
        if s == 1:
            return img
        return cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)

    @staticmethod
    def _warp(scene: DynamicScene, fine: Intrinsics, pose: Pose) -> np.ndarray:
        """float32[H*s, W*s]: the background plane's samples at ``pose``."""
        bg = scene.background
        return cv2.warpPerspective(bg.texture, bg.texture_from_image(fine, pose),
                                   (fine.width, fine.height),
                                   flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                   borderMode=cv2.BORDER_REPLICATE)

    def _background(self, camera: str, pose: Pose) -> np.ndarray:
        """The background's samples at ``pose``, for the objects to be drawn into (the
        caller's to change). A camera that renders the same pose twice in a row (a static
        camera watching moving objects: its poses are bit-identical) gets its second warp
        kept and a copy of it from then on; a moving camera's warps are handed over."""
        key = (pose.r_wc.tobytes(), pose.t_wc.tobytes())
        kept = self._kept.get(camera)
        if kept is None or kept[0] != key:
            self._kept[camera] = (key, None)
            return self._warp(self.scenes[camera], self._fine[camera], pose)
        if kept[1] is None:
            kept = (key, self._warp(self.scenes[camera], self._fine[camera], pose))
            self._kept[camera] = kept
        return kept[1].copy()

    @staticmethod
    def _overlay(scene: DynamicScene, fine: Intrinsics, pose: Pose,
                 objects: tuple[Pose, ...], img: np.ndarray) -> np.ndarray:
        """The objects drawn into ``img`` (the freshly warped background: changed in
        place, no copy)."""
        packed = scene.packed
        r_wo, t_wo = object_frames(scene, objects)
        boxes = sample_boxes(fine, pose, r_wo, t_wo, packed.geom)
        if not np.any((boxes[:, 1] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 2])):
            return img
        _overlay_kernel(img, fine.fx, fine.fy, fine.cx, fine.cy,
                        np.ascontiguousarray(pose.r_wc, np.float64),
                        np.ascontiguousarray(pose.t_wc, np.float64), r_wo, t_wo, packed.geom,
                        packed.shapes, packed.alphas, packed.texels, boxes, ALPHA_CUTOFF,
                        packed.hulls, packed.hull_sizes)
        return img

    def close(self) -> None:
        pass


@numba.njit(cache=True, nogil=True)
def _overlay_kernel(img, fx, fy, cx, cy, r_wc, c, r_wo, t_wo, geom, shapes, alphas, texels,
                    boxes, cutoff, hulls, hull_sizes):
    """In place: every sample of ``img`` (float32[H*s, W*s], the warped background) inside
    an object's box whose ray meets an object before the background gets that object's
    texel (the reference renderer's :func:`nearest_hit` and bilinear lookup). Per row, each
    box is first narrowed to the samples that can meet the object's solid part
    (:func:`row_boxes`), which changes which rays are tested, not what they hit."""
    fh, fw = img.shape
    origin = camera_in_objects(c, r_wo, t_wo)
    y0, y1 = fh, 0
    for j in range(boxes.shape[0]):
        if boxes[j, 1] > boxes[j, 0] and boxes[j, 3] > boxes[j, 2]:
            y0, y1 = min(y0, boxes[j, 2]), max(y1, boxes[j, 3])
    row = np.zeros_like(boxes)
    for yf in range(y0, y1):
        ry = (yf - cy) / fy
        row_boxes(yf, fx, fy, cx, cy, r_wc, origin, r_wo, boxes, hulls, hull_sizes, row)
        for j in range(row.shape[0]):  # each narrowed box's samples of the row, once
            for xf in range(row[j, 0], row[j, 1]):
                seen = False
                for k in range(j):
                    if row[k, 0] <= xf < row[k, 1]:
                        seen = True
                if seen:
                    continue
                rx = (xf - cx) / fx
                d0 = r_wc[0, 0] * rx + r_wc[0, 1] * ry + r_wc[0, 2]
                d1 = r_wc[1, 0] * rx + r_wc[1, 1] * ry + r_wc[1, 2]
                d2 = r_wc[2, 0] * rx + r_wc[2, 1] * ry + r_wc[2, 2]
                _, hit, col, rw = nearest_hit(d0, d1, d2, c[2], xf, yf, origin, r_wo, geom,
                                              shapes, alphas, row, cutoff)
                if hit > 0:
                    h = hit - 1
                    img[yf, xf] = bilinear_at(texels, shapes[h, 0], shapes[h, 1],
                                              shapes[h, 2], col, rw)
