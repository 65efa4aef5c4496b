"""Smoothness where no event fired: total variation of the output over unfired pixels.

An event camera reports intensity *changes*; a region where no pixel fired during a
sample's stacks carries no evidence of any structure inside it. Under a moving camera such
a region is flat in the scene (its texture would have fired); under a static camera it is a
static background whose texture nothing event-based can know. Either way the best guess is
flat, and any gradient an output draws there is invented: the clouds, stripes and halos a
network with a wide receptive field carries from moving edges into event-free background
(docs/notes/halos.md, docs/models.md). The L1 term alone does not forbid them: on simulated
data a cloud near an edge is often on the right side of the truth's mean.

This term penalises ``|d/dx out| + |d/dy out|`` between HR neighbours that both lie in
unfired pixels, averaged over all HR pixel pairs (so its weight reads on L1's scale). It
lets each connected event-free region take any single level (a dark object's interior, a
light background): levels change only where events fired.

"Fired" follows the observed region of the real benchmark (model/inference/observed.py):
a pixel with a net event in any stack and at least ``min_neighbours`` such pixels among
its 8 neighbours (isolated noise and hot pixels do not count), dilated by ``dilate`` LR
pixels (a square) so the sides of an edge stay free to differ.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def fired_mask(stacks: torch.Tensor, min_neighbours: int = 2, dilate: int = 1
               ) -> torch.Tensor:
    """``stacks`` (B, n, c, H, W) in [-1, 1] with 0 = no event -> float (B, 1, H, W), 1
    where a supported event fired (module doc), 0 elsewhere. No gradient."""
    if stacks.ndim != 5:
        raise ValueError(f"stacks must be (B, n, c, H, W), got {tuple(stacks.shape)}")
    if min_neighbours < 0 or dilate < 0:
        raise ValueError("min_neighbours and dilate must be >= 0")
    with torch.no_grad():
        fired = (stacks.detach().abs().amax(dim=(1, 2)) > 1e-6).float().unsqueeze(1)
        neighbours = F.avg_pool2d(F.pad(fired, (1, 1, 1, 1)), 3, 1) * 9 - fired
        supported = fired * (neighbours >= min_neighbours - 0.5).float()
        if dilate:
            supported = F.max_pool2d(supported, 2 * dilate + 1, 1, dilate)
    return supported


def unfired_tv(output: torch.Tensor, fired: torch.Tensor) -> torch.Tensor:
    """Total variation of ``output`` (B, 1, sH, sW) between horizontal and vertical
    neighbours that both lie outside ``fired`` (B, 1, H, W), the LR mask brought to the
    output's size by nearest-neighbour repetition; mean over all neighbour pairs -> (B,)."""
    if output.ndim != 4 or fired.ndim != 4 or output.shape[0] != fired.shape[0]:
        raise ValueError(f"output (B, 1, sH, sW) and fired (B, 1, H, W) expected, got "
                         f"{tuple(output.shape)} and {tuple(fired.shape)}")
    scale = output.shape[-1] // fired.shape[-1]
    if scale < 1 or fired.shape[-2] * scale != output.shape[-2] \
            or fired.shape[-1] * scale != output.shape[-1]:
        raise ValueError(f"output {tuple(output.shape[-2:])} is not an integer multiple of "
                         f"the mask {tuple(fired.shape[-2:])}")
    quiet = 1.0 - (fired if scale == 1 else
                   F.interpolate(fired, scale_factor=scale, mode="nearest"))
    dx = (output[..., :, 1:] - output[..., :, :-1]).abs() * quiet[..., :, 1:] * quiet[..., :, :-1]
    dy = (output[..., 1:, :] - output[..., :-1, :]).abs() * quiet[..., 1:, :] * quiet[..., :-1, :]
    pairs = dx[0].numel() + dy[0].numel()
    return (dx.flatten(1).sum(1) + dy.flatten(1).sum(1)) / pairs


class UnfiredSmoothness(nn.Module):
    """``forward(output, stacks)`` -> (B,) :func:`unfired_tv` of ``output`` outside the
    :func:`fired_mask` of ``stacks``."""

    def __init__(self, min_neighbours: int = 2, dilate: int = 1) -> None:
        super().__init__()
        self.min_neighbours, self.dilate = min_neighbours, dilate

    def forward(self, output: torch.Tensor, stacks: torch.Tensor) -> torch.Tensor:
        return unfired_tv(output, fired_mask(stacks, self.min_neighbours, self.dilate))
