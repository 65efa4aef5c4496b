"""Filling what no event saw, after the network.

A pixel whose neighbourhood fired no event in an output's stacks carries no evidence of its
own: under a moving camera it lies on a surface flat along the motion, under a static camera
it is a background that never changed. The network fills such regions from what it learned
(the halos, the cloud around moving objects and the invented background texture of
docs/models.md); this module replaces that fill by one drawn from the observed region alone:

- ``harmonic``: the smoothest continuation (the discrete Laplace equation, 4-neighbour,
  with the network's output fixed where events were seen and no flow across the frame's
  edges), solved by conjugate gradients from a coarse-to-fine start;
- ``flat``: each connected unobserved region takes one level, the mean of the network's
  output along its rim, reached from the rim over a short transition
  (``transition`` LR pixels) from the harmonic continuation, so no seam is drawn.

What counts as observed: the pixels that fired in any of the output's stacks and have at
least ``min_neighbours`` fired neighbours among their 8 (the background-activity filter of
Delbruck's event denoising: a lone event is more often noise than an edge), dilated by
``radius`` LR pixels (a disc), which is where the network's own output is kept. The fill
is solved at the events' resolution (the output averaged over ``scale x scale`` blocks; it
is smooth by construction) and brought to the output's bilinearly.

The fill is a post-process of :meth:`model.inference.reconstruct.Reconstructor.run`, so it
applies to every engine; ``none`` (the default) leaves the output as the network drew it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.linalg import cg

from model.inference.observed import region_of, upscale_mask

Mode = Literal["none", "harmonic", "flat"]
MODES: tuple[str, ...] = ("none", "harmonic", "flat")

#: Jacobi sweeps per level of the coarse-to-fine start of the Laplace solve.
SWEEPS = 10
#: Relative residual at which the conjugate-gradient Laplace solve stops.
RTOL = 1e-5

_JACOBI = np.array([[0, .25, 0], [.25, 0, .25], [0, .25, 0]], np.float32)


@dataclass(frozen=True)
class FillConfig:
    """``mode``: ``none``, ``harmonic`` or ``flat`` (module doc); ``radius``: LR pixels of
    the network's output kept around every observed pixel; ``min_neighbours``: fired
    8-neighbours a fired pixel needs to count (0: every fired pixel); ``transition``: LR
    pixels over which ``flat`` reaches a region's level from its rim."""

    mode: Mode = "none"
    radius: int = 2
    min_neighbours: int = 1
    transition: float = 3.0

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"fill mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.radius < 0 or not 0 <= self.min_neighbours <= 8 or not self.transition > 0:
            raise ValueError(f"fill needs radius >= 0, 0 <= min_neighbours <= 8 and "
                             f"transition > 0, got {self.radius}, {self.min_neighbours}, "
                             f"{self.transition}")


def fired_pixels(stacks: np.ndarray) -> np.ndarray:
    """bool[H, W]: pixels that fired in any of the uint8 stacks ``[n, c, H, W]`` (128: no
    event)."""
    return (np.asarray(stacks) != 128).any(axis=(0, 1))


def harmonic_fill(values: np.ndarray, known: np.ndarray, rtol: float = RTOL) -> np.ndarray:
    """float32 image equal to ``values`` where ``known`` and harmonic elsewhere: each unknown
    pixel the mean of its 4 neighbours, a neighbour past the frame's edge being the pixel
    itself (no flow across the edge). Solved by conjugate gradients to ``rtol`` from a
    coarse-to-fine start (:func:`_cascade`). Where nothing is known it returns ``values``."""
    values = np.asarray(values, np.float32)
    known = np.asarray(known, bool)
    if known.all() or not known.any():
        return values.copy()
    start = _cascade(values, known)
    matrix, rhs, unknown = _laplace_system(values, known)
    solved, info = cg(matrix, rhs, x0=start.ravel()[unknown].astype(np.float64), rtol=rtol,
                      maxiter=10 * int(np.sqrt(unknown.size)) + 100)
    out = values.ravel().copy()
    out[unknown] = solved if info == 0 else start.ravel()[unknown]
    return out.reshape(values.shape)


def _laplace_system(values: np.ndarray, known: np.ndarray):
    """The 5-point Laplace equations of the unknown pixels: (sparse matrix, right-hand side,
    flat indices of the unknowns)."""
    h, w = values.shape
    flat_known = known.ravel()
    unknown = np.flatnonzero(~flat_known)
    slot = np.full(h * w, -1, np.int64)
    slot[unknown] = np.arange(unknown.size)
    y, x = np.divmod(unknown, w)
    diagonal = np.full(unknown.size, 4.0)
    rhs = np.zeros(unknown.size)
    given = np.where(known, values, 0).ravel().astype(np.float64)
    rows, cols = [np.arange(unknown.size)], [np.arange(unknown.size)]
    for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        q = np.clip(y + dy, 0, h - 1) * w + np.clip(x + dx, 0, w - 1)
        itself = q == unknown
        diagonal -= itself
        rhs += np.where(flat_known[q] & ~itself, given[q], 0.0)
        free = ~flat_known[q] & ~itself
        rows.append(np.flatnonzero(free))
        cols.append(slot[q[free]])
    data = np.concatenate([diagonal, -np.ones(sum(r.size for r in rows[1:]))])
    matrix = csr_matrix((data, (np.concatenate(rows), np.concatenate(cols))),
                        shape=(unknown.size, unknown.size))
    return matrix, rhs, unknown


def _cascade(values: np.ndarray, known: np.ndarray, sweeps: int = SWEEPS) -> np.ndarray:
    """A fast approximation of :func:`harmonic_fill`: the half-size problem (known values
    averaged over 2x2 blocks) solved the same way, brought back bilinearly and relaxed by
    Jacobi sweeps."""
    h, w = values.shape
    if min(h, w) <= 2:
        u = np.full_like(values, values[known].mean())
    else:
        v = np.pad(np.where(known, values, 0), ((0, h % 2), (0, w % 2)))
        k = np.pad(known.astype(np.float32), ((0, h % 2), (0, w % 2)))
        hh, ww = v.shape[0] // 2, v.shape[1] // 2
        vs = v.reshape(hh, 2, ww, 2).sum((1, 3))
        ks = k.reshape(hh, 2, ww, 2).sum((1, 3))
        coarse_known = ks > 0
        coarse = np.where(coarse_known, vs / np.maximum(ks, 1), 0).astype(np.float32)
        if coarse_known.any():
            coarse = _cascade(coarse, coarse_known, sweeps)
        u = cv2.resize(coarse, (2 * ww, 2 * hh), interpolation=cv2.INTER_LINEAR)[:h, :w]
    u = np.where(known, values, u)
    for _ in range(sweeps):
        u = np.where(known, values, cv2.filter2D(u, -1, _JACOBI, borderType=cv2.BORDER_REFLECT))
    return u.astype(np.float32)


def flat_fill(values: np.ndarray, known: np.ndarray, transition: float) -> np.ndarray:
    """``values`` where ``known``; each 4-connected unknown region one level, the mean of
    the known pixels on its rim (8-neighbours of the region), reached from the harmonic
    continuation with weight ``exp(-distance / transition)`` (pixels)."""
    values = np.asarray(values, np.float32)
    known = np.asarray(known, bool)
    if known.all() or not known.any():
        return values.copy()
    smooth = harmonic_fill(values, known)
    n, labels = cv2.connectedComponents((~known).astype(np.uint8), connectivity=4)
    # a rim pixel takes the largest label among its 8 neighbours (unknown ones carry 1..n-1)
    beside = cv2.dilate(labels.astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.int64)
    rim = known & (beside > 0)
    count = np.bincount(beside[rim], minlength=n)
    total = np.bincount(beside[rim], weights=values[rim], minlength=n)
    level = np.where(count > 0, total / np.maximum(count, 1), values[known].mean())
    flat = level.astype(np.float32)[labels]
    dist = cv2.distanceTransform((~known).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    weight = np.exp(-dist / transition)
    return np.where(known, values, flat + (smooth - flat) * weight).astype(np.float32)


def fill_unobserved(image: np.ndarray, stacks: np.ndarray, config: FillConfig) -> np.ndarray:
    """The network's output ``image`` (float32[sH, sW]) with what no event of the uint8
    ``stacks`` ``[n, c, H, W]`` saw filled by ``config.mode``; unchanged for ``none`` or
    when no pixel counts as observed."""
    if config.mode == "none":
        return image
    support = region_of(fired_pixels(stacks), 0, config.min_neighbours)
    if not support.any():
        return image
    h, w = stacks.shape[-2:]
    sy, sx = image.shape[0] // h, image.shape[1] // w
    if sy * h != image.shape[0] or sx * w != image.shape[1] or sy != sx:
        raise ValueError(f"output {image.shape} is not a whole multiple of the stacks' "
                         f"{(h, w)}")
    lr_known = region_of(support, config.radius, 0)  # the support, dilated
    lr_image = cv2.resize(image.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    if config.mode == "harmonic":
        lr_filled = harmonic_fill(lr_image, lr_known)
    else:
        lr_filled = flat_fill(lr_image, lr_known, config.transition)
    filled = cv2.resize(lr_filled, (image.shape[1], image.shape[0]),
                        interpolation=cv2.INTER_LINEAR)
    known = upscale_mask(lr_known, sy)
    return np.clip(np.where(known, image, filled), 0.0, 1.0).astype(np.float32)
