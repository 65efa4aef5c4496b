"""FNet: optical flow between the central stack and each side stack.

The paper used a pretrained FlowNet2 it did not fine-tune; no such weights are reachable
here. Two options:
- classical (default): OpenCV's DIS (or Farneback) on the stacks seen as gray images, run in
  the data pipeline on the CPU (the authors' released code also used a classical method);
- learned: :class:`FlowNet`, a small network inside the model, trainable end to end or
  pre-trained on the exact flow the simulator knows (:func:`esim_lite.motion.planar_flow`).
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np
import torch
from torch import nn

from model.archs.blocks import conv

_DIS: dict[int, cv2.DISOpticalFlow] = {}  # one instance per preset, made on first use


def stack_to_gray(stack: np.ndarray) -> np.ndarray:
    """uint8[H, W]: the mean over an SBN stack's channels (128 where nothing fired)."""
    return np.round(stack.astype(np.float32).mean(axis=0)).astype(np.uint8)


def classical_flow(a: np.ndarray, b: np.ndarray,
                   method: Literal["dis", "farneback"] = "dis",
                   preset: int = cv2.DISOPTICAL_FLOW_PRESET_FAST) -> np.ndarray:
    """float32[H, W, 2] flow (dx, dy) in pixels from gray image ``a`` to ``b`` (uint8);
    ``preset`` is DIS's speed/quality preset."""
    h, w = a.shape
    if min(h, w) < 16:  # DIS needs >= 12 pixels; tiny sensors are padded, then cropped
        pad = ((0, max(0, 16 - h)), (0, max(0, 16 - w)))
        big = classical_flow(np.pad(a, pad, mode="edge"), np.pad(b, pad, mode="edge"),
                             method, preset)
        return np.ascontiguousarray(big[:h, :w])
    if method == "dis":
        dis = _DIS.get(preset)
        if dis is None:
            dis = _DIS[preset] = cv2.DISOpticalFlow_create(preset)
        return dis.calc(a, b, None)
    if method == "farneback":
        return cv2.calcOpticalFlowFarneback(a, b, None, 0.5, 3, 9, 3, 5, 1.1, 0)
    raise ValueError(f"unknown classical flow method {method!r}")


def stack_flows(stacks: np.ndarray, method: Literal["dis", "farneback"] = "dis"
                ) -> np.ndarray:
    """float32[n, 2, H, W]: flow from the central stack to each stack (zeros for itself).

    Args:
        stacks: uint8[n, c, H, W] SBN stacks, central one in the middle.
    """
    n, _, h, w = stacks.shape
    mid = n // 2
    centre = stack_to_gray(stacks[mid])
    out = np.zeros((n, 2, h, w), np.float32)
    for j in range(n):
        if j != mid:
            out[j] = classical_flow(centre, stack_to_gray(stacks[j]), method).transpose(2, 0, 1)
    return out


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
