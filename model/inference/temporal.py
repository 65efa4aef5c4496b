"""Temporal consistency of image sequences: flow warping, occlusion masks, the warping
error E_warp (Lai et al. 2018, as in the E2SRI paper's Table 6) and a blind post-process.

``E_warp`` between consecutive outputs: the second warped onto the first with a flow
(OpenCV DIS, medium preset), over the pixels passing Ruder et al.'s (2016)
forward-backward check, in units of 1e-3. The post-process blends each output with the
previous result warped onto it along the flow between consecutive outputs (occlusions
excluded); it needs only the previous frame, so it streams.
"""

from __future__ import annotations

import cv2
import numpy as np

from model.data.classical_flow import classical_flow


def _flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """DIS flow (medium preset) between two images with values in [0, 1]."""
    return classical_flow(_to8(a), _to8(b), preset=cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)


def _to8(img: np.ndarray) -> np.ndarray:
    return np.round(img.clip(0, 1) * 255).astype(np.uint8)


def warp(img: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """``img`` sampled at ``x + flow(x)`` (bilinear): brings frame t+1 back onto frame t."""
    h, w = img.shape
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(img, gx + flow[..., 0], gy + flow[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def non_occluded(forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """Ruder et al.'s forward-backward consistency mask (True where trustworthy)."""
    back = np.stack([warp(backward[..., 0], forward), warp(backward[..., 1], forward)], -1)
    h, w = forward.shape[:2]
    gx, gy = np.meshgrid(np.arange(w), np.arange(h))
    inside = (gx + forward[..., 0] >= 0) & (gx + forward[..., 0] <= w - 1) & \
        (gy + forward[..., 1] >= 0) & (gy + forward[..., 1] <= h - 1)
    err = np.sum((forward + back) ** 2, -1)
    return inside & (err <= 0.01 * (np.sum(forward**2, -1) + np.sum(back**2, -1)) + 0.5)


def reference_motion(references: list[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(forward flow, non-occlusion mask) between each consecutive pair of ``references``."""
    motion = []
    for a, b in zip(references[:-1], references[1:]):
        fw = _flow(a, b)
        motion.append((fw, non_occluded(fw, _flow(b, a))))
    return motion


def warp_error(outputs: list[np.ndarray], references: list[np.ndarray] | None = None,
               motion: list[tuple[np.ndarray, np.ndarray]] | None = None) -> float:
    """Mean E_warp (x1e-3) over consecutive pairs; flow and mask from ``references``, or
    given as ``motion`` (:func:`reference_motion`) when several outputs share them."""
    if motion is None:
        motion = reference_motion(references)
    errors = []
    for k, (fw, mask) in enumerate(motion):
        if mask.any():
            diff = outputs[k] - warp(outputs[k + 1], fw)
            errors.append(float(np.mean(diff[mask] ** 2)))
    return 1e3 * float(np.mean(errors)) if errors else float("nan")


def consistency_step(previous_output: np.ndarray, previous_result: np.ndarray,
                     output: np.ndarray, weight: float) -> np.ndarray:
    """One step of the blind temporal post-process: ``output`` blended with the previous
    result warped onto it (flow between the two raw outputs), occluded pixels untouched."""
    fw = _flow(output, previous_output)
    bw = _flow(previous_output, output)
    mask = non_occluded(fw, bw)
    prev = warp(previous_result, fw)
    return np.where(mask, weight * prev + (1 - weight) * output, output).astype(np.float32)


def temporally_consistent(outputs: list[np.ndarray], weight: float) -> list[np.ndarray]:
    """The blind post-process over a whole sequence (recursive: streamable)."""
    result = [outputs[0]]
    for k in range(1, len(outputs)):
        result.append(consistency_step(outputs[k - 1], result[-1], outputs[k], weight))
    return result
