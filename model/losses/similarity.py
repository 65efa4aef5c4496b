"""The similarity loss of the paper: L1 + lambda * LPIPS(AlexNet)."""

from __future__ import annotations

import torch
from torch import nn

from model.losses.lpips import LPIPS


class SimilarityLoss(nn.Module):
    """``forward(output, target)`` on ``(B, 1, H, W)`` -> (scalar loss, {"l1", "lpips"}).

    ``lpips_weight`` = 0 skips LPIPS entirely (no weights needed)."""

    def __init__(self, lpips_weight: float = 0.01, lpips: LPIPS | None = None) -> None:
        super().__init__()
        self.lpips_weight = lpips_weight
        self.lpips = (lpips or LPIPS()) if lpips_weight > 0 else None

    def forward(self, output: torch.Tensor, target: torch.Tensor
                ) -> tuple[torch.Tensor, dict[str, float]]:
        l1 = torch.mean(torch.abs(output - target))
        parts = {"l1": float(l1.detach())}
        if self.lpips is None:
            return l1, parts
        perceptual = self.lpips(output.float(), target.float()).mean()
        parts["lpips"] = float(perceptual.detach())
        return l1 + self.lpips_weight * perceptual, parts
