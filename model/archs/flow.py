"""FNet, learned: optical flow between the central stack and each side stack, inside the model.

The paper used a pretrained FlowNet2 it did not fine-tune; no such weights are reachable
here. Two options:
- classical (default): :mod:`model.data.classical_flow` (OpenCV's DIS or Farneback on the
  stacks seen as gray images), run in the data pipeline on the CPU;
- learned: :class:`FlowNet`, a small network inside the model, trainable end to end or
  pre-trained on the exact flow the simulator knows
  (:func:`esim_lite.geometry.motion.planar_flow`).
"""

from __future__ import annotations

import torch
from torch import nn

from model.archs.blocks import conv


class FlowNet(nn.Module):
    """A small learnable FNet: ``(central, side)`` stacks ``(B, c, H, W)`` -> flow
    ``(B, 2, H, W)`` in pixels. Dilated convolutions give it a ~30 pixel field of view
    without downsampling (inputs are 64x64 crops)."""

    def __init__(self, stack_channels: int = 3, width: int = 32) -> None:
        super().__init__()
        layers = [conv(2 * stack_channels, width)]
        for d in (1, 2, 4, 8, 1):
            layers.append(conv(width, width, 3, 1, d) if d == 1 else
                          nn.Sequential(nn.Conv2d(width, width, 3, 1, d, dilation=d),
                                        nn.PReLU(width)))
        layers.append(conv(width, 2, act=False))
        self.body = nn.Sequential(*layers)

    def forward(self, central: torch.Tensor, side: torch.Tensor) -> torch.Tensor:
        return self.body(torch.cat([central, side], dim=1))
