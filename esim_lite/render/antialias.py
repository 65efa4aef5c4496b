"""Texture reduction for views far below the texture's resolution (aliasing = fake events).

A camera integrates light over each pixel. Both renderers approximate that integral with
``s x s`` point samples of the bilinear texture; when one sample covers many texels the
result depends on where the samples fall, and a moving camera sees it flicker, which the
event model turns into events. Supersampling fixes this while a sample covers a few texels;
beyond :data:`MAX_TEXELS_PER_SAMPLE` (worst view along the sequence) the texture is first
box-reduced like a mip-map level. Both backends render the same texture.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import cv2
import numpy as np

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.pose import Pose
from esim_lite.geometry.scene import PlanarScene


def texels_per_sample(scene: PlanarScene, camera: Intrinsics, supersample: int,
                      poses: Iterable[Pose]) -> float:
    """Largest texel footprint of one sample over ``poses``: the largest singular value of
    the image-to-texture Jacobian, at the image corners and centre."""
    fine = camera.scaled(supersample)
    pts = np.array([[-0.5, -0.5, 1.0], [fine.width - 0.5, -0.5, 1.0],
                    [-0.5, fine.height - 0.5, 1.0], [fine.width - 0.5, fine.height - 0.5, 1.0],
                    [fine.cx, fine.cy, 1.0]])
    hs = np.stack([scene.texture_from_image(fine, pose) for pose in poses])  # [P, 3, 3]
    p = np.einsum("pij,nj->pni", hs, pts)  # [P, N, 3]
    tex = p[..., :2] / p[..., 2:3]
    jac = (hs[:, None, :2, :2] - tex[..., :, None] * hs[:, None, 2:3, :2]) / p[..., 2, None, None]
    # closed-form largest singular value of 2x2 matrices
    fro2 = np.sum(jac**2, axis=(-2, -1))
    det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
    s_max = np.sqrt(0.5 * (fro2 + np.sqrt(np.maximum(fro2**2 - 4 * det**2, 0.0))))
    return float(s_max.max())


#: Supersampling handles up to this many texels per sample; beyond it, a mip reduction.
MAX_TEXELS_PER_SAMPLE = 4.0


def prefiltered(scene: PlanarScene, texels_per_sample_max: float,
                limit: float = MAX_TEXELS_PER_SAMPLE) -> PlanarScene:
    """The plane with its texture box-reduced by the smallest power of two that brings the
    worst footprint ``m`` to at most ``limit`` texels per sample (unchanged if already so).

    A Gaussian band-limit for point sampling removes detail that box quadrature keeps: on
    photographs it cost 3-24% of the events of an exact (8x8-sample) render, while 3x3 raw
    samples were within +2% (bench/bench_antialias.py). So the reduction is kept for what
    supersampling cannot resolve (many texels per sample, where it would flicker).
    """
    m = texels_per_sample_max
    if m <= limit:
        return scene
    factor = 2 ** int(math.ceil(math.log2(m / limit)))
    h, w = scene.texture.shape
    size = (max(2, round(w / factor)), max(2, round(h / factor)))
    tex = cv2.resize(scene.texture, size, interpolation=cv2.INTER_AREA)
    return PlanarScene(np.ascontiguousarray(tex, np.float32), scene.width_m, scene.height_m)
