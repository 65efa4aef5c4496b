"""Classical optical flow between SBN stacks (OpenCV's DIS or Farneback), computed in the data
pipeline on the CPU: the default FNet input of E2SRI (the paper used a pretrained FlowNet2 it
did not fine-tune; no such weights are reachable here, and the authors' released code also
used a classical method). The learnable alternative is :class:`model.archs.flow.FlowNet`.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np


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
    if method == "dis":  # a fresh instance: a reused one carries state from its last call
        return cv2.DISOpticalFlow_create(preset).calc(a, b, None)
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
