"""The similarity loss of the paper, L1 + lambda * LPIPS(AlexNet), and an optional
smoothness term where no event fired (model/losses/unfired.py)."""

from __future__ import annotations

import torch
from torch import nn

from model.losses.lpips import LPIPS
from model.losses.unfired import UnfiredSmoothness


class SimilarityLoss(nn.Module):
    """``forward(output, target, stacks=None)`` on ``(B, 1, H, W)`` outputs and targets and
    the ``(B, n, c, h, w)`` input stacks -> (scalar loss, {"l1", "lpips", "unfired_tv"}).

    ``lpips_weight`` = 0 skips LPIPS entirely (no weights needed); ``unfired_tv`` > 0 adds
    that weight times :class:`UnfiredSmoothness`, which needs the stacks."""

    def __init__(self, lpips_weight: float = 0.01, lpips: LPIPS | None = None,
                 unfired_tv: float = 0.0, unfired_dilate: int = 1) -> None:
        super().__init__()
        self.lpips_weight, self.unfired_weight = lpips_weight, unfired_tv
        self.lpips = (lpips or LPIPS()) if lpips_weight > 0 else None
        self.unfired = UnfiredSmoothness(dilate=unfired_dilate) if unfired_tv > 0 else None

    def forward(self, output: torch.Tensor, target: torch.Tensor,
                stacks: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, float]]:
        loss = torch.mean(torch.abs(output - target))
        parts = {"l1": float(loss.detach())}
        if self.lpips is not None:
            perceptual = self.lpips(output.float(), target.float()).mean()
            parts["lpips"] = float(perceptual.detach())
            loss = loss + self.lpips_weight * perceptual
        if self.unfired is not None:
            if stacks is None:
                raise ValueError("the unfired-smoothness term needs the input stacks")
            smooth = self.unfired(output.float(), stacks).mean()
            parts["unfired_tv"] = float(smooth.detach())
            loss = loss + self.unfired_weight * smooth
        return loss, parts
