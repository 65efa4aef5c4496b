"""A training target that leaves what no event saw to a smooth fill.

On simulated data the ground truth is known everywhere, also where no event fired during
a sample's stacks: a static background's texture under a static camera, the far side of a
flat region. Nothing event-based can know those values, so L1 and LPIPS against them teach
a network to guess them from the events it does see: the level next to a moving edge is
set by that edge's contrast, the level far from it by the data's average, and between the
two the network draws the dark cloud around a small bright car over a static street that
docs/models.md measures (``invented``). A smoothness penalty on the output
(model/losses/unfired.py) does not remove it: a cloud is smooth.

This module replaces the target where nothing fired by a smooth fill from the target's
values where events did fire: each unseen pixel takes the levels of the seen pixels around
it, nearer ones weighing more. Where an object's edges fired, its interior is filled from
the inner side of its edges (the dark interior of a dark object stays dark: the halo fix
is still taught); a static background is filled from the background side of the edges that
touch it, so its level carries on flat instead of falling to the data's mean. A crop where
nothing fired gets its own mean (a flat guess: nothing better is knowable). Seen pixels
keep their exact values.

The fill is harmonic: the solution of Laplace's equation over the unseen pixels with the
seen ones as fixed values (and no flux across the image's border), so each unseen region
is filled from its own boundary only: the interior of a dark object enclosed by its fired
edge takes the inner side of that edge and nothing of the background beyond it. A pyramid
fill (push-pull, Gortler et al., *The Lumigraph*, 1996) would mix both sides at its coarse
levels and fill a dark object lighter than its rim: the halo this project fights. The
harmonic fill never leaves the range of the seen values (maximum principle), is exact on
constants and commutes with flips. It is solved by conjugate gradients on the 4-neighbour
Laplacian, started from the push-pull fill (a good guess that the iterations correct).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from model.losses.unfired import fired_mask


def pyramid_fill(image: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
    """Push-pull: ``image`` (B, C, H, W) where ``known`` (B, 1, H, W, in [0, 1]) is 1, else
    a pyramid of mask-weighted 2x2 means blended from the coarsest level down (each pixel
    keeps its own block mean in proportion to the seen share of its block); an image with
    nothing seen takes its own mean. The harmonic fill's starting guess. No gradient."""
    _check(image, known)
    with torch.no_grad():
        image, known = image.detach().float(), known.detach().float().clamp(0, 1)
        levels = [(image * known, known)]
        while max(levels[-1][1].shape[-2:]) > 1:
            value, weight = levels[-1]
            levels.append((F.avg_pool2d(value, 2, ceil_mode=True),
                           F.avg_pool2d(weight, 2, ceil_mode=True)))
        value, weight = levels[-1]
        mean = image.mean(dim=(-2, -1), keepdim=True)
        filled = torch.where(weight > 0, value / weight.clamp_min(1e-12), mean)
        for value, weight in reversed(levels[:-1]):
            coarse = F.interpolate(filled, size=value.shape[-2:], mode="bilinear",
                                   align_corners=False)
            own = value / weight.clamp_min(1e-12)
            filled = weight * own + (1 - weight) * coarse
        return torch.where(known >= 1, image, filled)


def _check(image: torch.Tensor, known: torch.Tensor) -> None:
    if image.ndim != 4 or known.ndim != 4 or known.shape[1] != 1 \
            or known.shape[0] != image.shape[0] or known.shape[-2:] != image.shape[-2:]:
        raise ValueError(f"image (B, C, H, W) and known (B, 1, H, W) of one size expected, "
                         f"got {tuple(image.shape)} and {tuple(known.shape)}")


def _neighbour_sum(x: torch.Tensor) -> torch.Tensor:
    """Sum of each pixel's 4 neighbours inside the image."""
    p = F.pad(x, (1, 1, 1, 1))
    return p[..., :-2, 1:-1] + p[..., 2:, 1:-1] + p[..., 1:-1, :-2] + p[..., 1:-1, 2:]


def smooth_fill(image: torch.Tensor, known: torch.Tensor, tol: float = 1e-5,
                max_iter: int | None = None) -> torch.Tensor:
    """``image`` (B, C, H, W), ``known`` (B, 1, H, W) with 1 where the value is seen ->
    ``image`` on the seen pixels, the harmonic fill of them elsewhere (module doc): conjugate
    gradients until every image's residual is below ``tol`` times the size of its terms (or
    ``max_iter``, default ``4 * (H + W)``). A connected unseen region touching no seen
    pixel keeps the pyramid fill's mean of it; an image with nothing seen takes its own mean.
    No gradient."""
    _check(image, known)
    with torch.no_grad():
        image = image.detach().float()
        seen = known.detach().float() >= 0.5
        free = (~seen).float()
        start = pyramid_fill(image, seen.float())
        degree = _neighbour_sum(torch.ones_like(free))

        def apply(x: torch.Tensor) -> torch.Tensor:  # the Laplacian on the free pixels
            return (degree * x - _neighbour_sum(x)) * free

        rhs = _neighbour_sum(image * seen) * free
        x = start * free
        r = rhs - apply(x)
        p = r.clone()
        rr = (r * r).sum(dim=(-2, -1), keepdim=True)
        # relative to the size of the equation's terms (rhs is 0 where nothing is seen)
        scale = (rhs * rhs).sum(dim=(-2, -1), keepdim=True) \
            + ((degree * x) ** 2).sum(dim=(-2, -1), keepdim=True)
        limit = (tol ** 2) * scale.clamp_min(1e-20)
        for _ in range(max_iter if max_iter is not None else 4 * sum(image.shape[-2:])):
            if bool((rr <= limit).all()):
                break
            ap = apply(p)
            pap = (p * ap).sum(dim=(-2, -1), keepdim=True)
            alpha = torch.where(pap > 0, rr / pap.clamp_min(1e-30), torch.zeros_like(pap))
            x = x + alpha * p
            r = r - alpha * ap
            rr_new = (r * r).sum(dim=(-2, -1), keepdim=True)
            p = r + torch.where(rr > 0, rr_new / rr.clamp_min(1e-30), torch.zeros_like(rr)) * p
            rr = rr_new
        return torch.where(seen, image, x)


class UnseenFill(nn.Module):
    """``forward(target, stacks)`` -> the target (B, 1, sH, sW) with every HR pixel outside
    the :func:`~model.losses.unfired.fired_mask` of ``stacks`` (B, n, c, H, W; at least 2
    fired neighbours, widened by ``dilate`` LR pixels) replaced by :func:`smooth_fill` of
    the pixels inside it."""

    def __init__(self, dilate: int = 2, min_neighbours: int = 2) -> None:
        super().__init__()
        if dilate < 0 or min_neighbours < 0:
            raise ValueError("dilate and min_neighbours must be >= 0")
        self.dilate, self.min_neighbours = dilate, min_neighbours

    def forward(self, target: torch.Tensor, stacks: torch.Tensor) -> torch.Tensor:
        seen = fired_mask(stacks, self.min_neighbours, self.dilate)
        scale = target.shape[-1] // seen.shape[-1]
        if scale < 1 or seen.shape[-2] * scale != target.shape[-2] \
                or seen.shape[-1] * scale != target.shape[-1]:
            raise ValueError(f"target {tuple(target.shape[-2:])} is not an integer multiple "
                             f"of the stacks' {tuple(seen.shape[-2:])}")
        if scale > 1:
            seen = F.interpolate(seen, scale_factor=scale, mode="nearest")
        return smooth_fill(target, seen)
