"""The exact reference renderer: every sample ray traced in float64 through the dynamic
scene, nearest alpha-tested hit, bilinear texture, ``s x s`` samples per pixel averaged.

Two implementations of the same rules:

- :meth:`ReferenceRenderer.render_numpy` composes :func:`esim_lite.geometry.visibility.trace`
  and :func:`~esim_lite.geometry.visibility.shade` on every sample ray (numpy, slow): the
  oracle that the Mitsuba backend and the compiled path are measured against;
- :meth:`ReferenceRenderer.render` (the backend ``reference``) runs one compiled pass
  (numba, rows shared between threads, one writer per sample so the result does not depend
  on the thread count) and tests an object only for the samples inside the image-space
  bounding box of its projected patch, where the ray can meet it. That culling is what
  makes a CPU ray caster of a few planar objects fast: most rays meet only the
  background.

It renders single-plane scenes too, where it agrees with the homography backend.
"""

from __future__ import annotations

from collections.abc import Sequence

import numba
import numpy as np

from esim_lite.geometry.camera import Intrinsics, sample_grids
from esim_lite.geometry.objects import ALPHA_CUTOFF, DynamicScene
from esim_lite.geometry.pose import Pose
from esim_lite.geometry.visibility import (
    MISS,
    bilinear_at,
    camera_in_objects,
    nearest_hit,
    object_frames,
    sample_boxes,
    shade,
    trace,
)


class ReferenceRenderer:
    """Renders each named camera's :class:`DynamicScene` exactly; deterministic.

    Args:
        scenes: the scene seen by each camera (backgrounds may be prefiltered per camera).
        cameras: intrinsics by camera name.
        supersample: sub-pixel grid side per camera name.
        threads: threads of the compiled pass (None: numba's default, all cores); the
            image does not depend on it.
    """

    name = "reference"

    def __init__(self, scenes: dict[str, DynamicScene], cameras: dict[str, Intrinsics],
                 supersample: dict[str, int], threads: int | None = None) -> None:
        if threads is not None and threads < 1:
            raise ValueError(f"threads must be >= 1 or None, got {threads}")
        self.threads = threads
        self.scenes = dict(scenes)
        self.cameras = dict(cameras)
        self.supersample, self._fine = sample_grids(self.cameras, supersample)
        self._background = {}
        for name, scene in self.scenes.items():
            bg = scene.background
            m = bg.texture_from_plane()
            tex = np.ascontiguousarray(bg.texture, np.float32)
            self._background[name] = (tex, np.array([m[0, 0], m[0, 2], m[1, 1], m[1, 2]]))

    def render(self, camera: str, pose: Pose, objects: Sequence[Pose] = ()) -> np.ndarray:
        """float32[H, W] linear intensity seen by ``camera`` at ``pose`` with the objects at
        ``objects`` (object-to-world poses, in the scene's object order); compiled."""
        cam, s, scene = self.cameras[camera], self.supersample[camera], self.scenes[camera]
        fine = self._fine[camera]
        objects = tuple(objects)
        r_wo, t_wo = object_frames(scene, objects)
        packed = scene.packed
        boxes = sample_boxes(fine, pose, r_wo, t_wo, packed.geom)
        tex, bg_map = self._background[camera]
        if self.threads is not None:
            numba.set_num_threads(min(self.threads, numba.config.NUMBA_NUM_THREADS))
        img, missed = _render_kernel(
            cam.height, cam.width, s, fine.fx, fine.fy, fine.cx, fine.cy,
            np.ascontiguousarray(pose.r_wc, np.float64),
            np.ascontiguousarray(pose.t_wc, np.float64), tex, bg_map, r_wo, t_wo, packed.geom,
            packed.shapes, packed.alphas, packed.texels, boxes, ALPHA_CUTOFF)
        if missed:
            raise ValueError(f"camera {camera!r} sees past the background plane at this pose")
        return img

    def render_numpy(self, camera: str, pose: Pose, objects: Sequence[Pose] = ()
                     ) -> np.ndarray:
        """The same image from :func:`trace` and :func:`shade` on every sample ray (the
        numpy oracle)."""
        cam, s, scene = self.cameras[camera], self.supersample[camera], self.scenes[camera]
        hits = trace(scene, pose, tuple(objects), self._fine[camera].pixel_rays())
        if np.any(hits.ids == MISS):
            raise ValueError(f"camera {camera!r} sees past the background plane at this pose")
        img = shade(scene, hits)
        if s > 1:
            img = img.reshape(cam.height, s, cam.width, s).mean(axis=(1, 3))
        return img.astype(np.float32)

    def close(self) -> None:
        pass


@numba.njit(cache=True, nogil=True, parallel=True)
def _render_kernel(height, width, s, fx, fy, cx, cy, r_wc, c, tex, bg_map, r_wo, t_wo,
                   geom, shapes, alphas, texels, boxes, cutoff):
    """float32[H, W] mean of the ``s x s`` samples of every pixel, and whether a ray missed
    everything."""
    fh, fw = height * s, width * s
    samples = np.empty((fh, fw))
    missed = np.zeros(fh, np.bool_)
    origin = camera_in_objects(c, r_wo, t_wo)
    th, tw = tex.shape
    xs = (np.arange(fw) - cx) / fx
    for yf in numba.prange(fh):
        ry = (yf - cy) / fy
        for xf in range(fw):
            rx = xs[xf]
            d0 = r_wc[0, 0] * rx + r_wc[0, 1] * ry + r_wc[0, 2]
            d1 = r_wc[1, 0] * rx + r_wc[1, 1] * ry + r_wc[1, 2]
            d2 = r_wc[2, 0] * rx + r_wc[2, 1] * ry + r_wc[2, 2]
            best, hit, col, row = nearest_hit(d0, d1, d2, c[2], xf, yf, origin, r_wo, geom,
                                              shapes, alphas, boxes, cutoff)
            if hit < 0:
                missed[yf] = True
                samples[yf, xf] = 0.0
            elif hit == 0:
                bx = c[0] + best * d0
                by = c[1] + best * d1
                samples[yf, xf] = _texel(tex, th, tw, bg_map[0] * bx + bg_map[1],
                                         bg_map[2] * by + bg_map[3])
            else:
                j = hit - 1
                samples[yf, xf] = bilinear_at(texels, shapes[j, 0], shapes[j, 1],
                                              shapes[j, 2], col, row)
    img = np.empty((height, width), np.float32)
    inv = 1.0 / (s * s)
    for y in numba.prange(height):
        for x in range(width):
            total = 0.0
            for i in range(s):
                for j in range(s):
                    total += samples[y * s + i, x * s + j]
            img[y, x] = total * inv
    return img, missed.any()


@numba.njit(cache=True, nogil=True)
def _texel(tex, h, w, col, row):
    """Bilinear lookup of the 2-D ``tex``, texels clamped (as ``visibility.bilinear``)."""
    x = min(max(col, 0.0), w - 1.0)
    y = min(max(row, 0.0), h - 1.0)
    x0 = min(int(np.floor(x)), w - 2)
    y0 = min(int(np.floor(y)), h - 2)
    fx, fy = x - x0, y - y0
    top = np.float64(tex[y0, x0]) * (1 - fx) + np.float64(tex[y0, x0 + 1]) * fx
    bottom = np.float64(tex[y0 + 1, x0]) * (1 - fx) + np.float64(tex[y0 + 1, x0 + 1]) * fx
    return top * (1 - fy) + bottom * fy
