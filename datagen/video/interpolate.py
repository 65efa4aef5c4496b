"""Intensity between two video frames: the pluggable interpolators of ``from-video``.

An interpolator turns two neighbouring frames (their paired-camera images) into a
:class:`Between`, which gives the LR linear intensity at any fraction ``tau`` of the time
from the first frame to the second (``tau = 0`` and ``1``: the frames themselves) and says
how far the content moves (which sets how many samples the event camera takes) and
whether the two frames are one scene at all.

- ``linear`` (esim_py's rule): each LR pixel's log intensity is linear in time. It knows
  nothing of motion: an edge moving several pixels fades out at one place and in at the
  other instead of moving.
- ``flow``: OpenCV DIS optical flow between the working images, forward ``F01`` and
  backward ``F10``; the flow from time ``tau`` back to each frame is approximated as in
  Super SloMo (Jiang et al. 2018), ``F_t0 = -(1 - tau) tau F01 + tau^2 F10`` and
  ``F_t1 = (1 - tau)^2 F01 - tau (1 - tau) F10`` (exact for a constant flow); both frames
  are warped there (bilinear, backward) and blended with weights ``(1 - tau) V_t0`` and
  ``tau V_t1``, where ``V_t0`` is 0 on content that appears only in the second frame and
  ``V_t1`` 0 on content that disappears (the forward-backward check's occlusion masks,
  warped likewise; floored at ``visibility_floor``), so occluded content comes from the
  frame that shows it. The blend is linear light, warped at the working resolution, then
  area-averaged to LR (no weights are downloaded: DIS is classical).

A scene cut (more than ``scene_cut_fraction`` of the pixels fail the forward-backward
check) is reported by both, and the sequence's sensor restarts there instead of firing
the jump.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from datagen.video.config import VideoConfig
from datagen.video.optics import CameraImages, block_mean

_PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
            "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
            "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}


def _encode_u8(linear: np.ndarray) -> np.ndarray:
    """uint8 gamma-encoded image (1/2.2) of linear intensity: what DIS matches on."""
    return (np.clip(linear, 0.0, 1.0) ** (1 / 2.2) * 255.0 + 0.5).astype(np.uint8)


def _warp(image: np.ndarray, grid: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """``image`` sampled at ``x + flow(x)`` (bilinear, edges replicated)."""
    m = grid + flow
    return cv2.remap(image, m[..., 0], m[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def occlusion(f01: np.ndarray, f10: np.ndarray, grid: np.ndarray, alpha: float,
              beta: float) -> np.ndarray:
    """bool[H, W]: pixels of frame 0 whose forward flow the backward flow at its target
    does not bring back (occluded in frame 1, or flow failed there)."""
    back = _warp(f10, grid, f01)
    err = np.sum((f01 + back) ** 2, axis=-1)
    return err > alpha * (np.sum(f01 ** 2, axis=-1) + np.sum(back ** 2, axis=-1)) + beta ** 2


def block_any(mask: np.ndarray, k: int) -> np.ndarray:
    """bool[H / k, W / k]: blocks holding any set pixel."""
    if k == 1:
        return mask
    h, w = mask.shape
    return mask.reshape(h // k, k, w // k, k).any(axis=(1, 3))


@dataclass(frozen=True, eq=False)
class FlowPair:
    """The flows between two working images and what they say.

    Attributes:
        f01, f10: float32[H, W, 2] forward and backward flow (working pixels, x first).
        occ0, occ1: bool[H, W]: frame 0's content missing from frame 1, and the reverse.
        motion_px: the largest flow magnitude of either, in LR pixels.
        cut: whether the two frames are different scenes.
    """

    f01: np.ndarray
    f10: np.ndarray
    occ0: np.ndarray
    occ1: np.ndarray
    motion_px: float
    cut: bool


class FlowEstimator:
    """DIS flow both ways between working images, with the occlusion masks and the cut
    rule of a :class:`VideoConfig`."""

    def __init__(self, config: VideoConfig) -> None:
        self.config = config
        self._dis = cv2.DISOpticalFlow_create(_PRESETS[config.flow.preset])
        self._grid: np.ndarray | None = None

    def grid(self, hw: tuple[int, int]) -> np.ndarray:
        """float32[H, W, 2] pixel coordinates (x, y)."""
        if self._grid is None or self._grid.shape[:2] != hw:
            ys, xs = np.mgrid[0:hw[0], 0:hw[1]].astype(np.float32)
            self._grid = np.stack([xs, ys], -1)
        return self._grid

    def pair(self, work0: np.ndarray, work1: np.ndarray) -> FlowPair:
        cfg = self.config
        u0, u1 = _encode_u8(work0), _encode_u8(work1)
        f01 = self._dis.calc(u0, u1, None)
        f10 = self._dis.calc(u1, u0, None)
        grid = self.grid(work0.shape)
        a, b = cfg.flow.occlusion_alpha, cfg.flow.occlusion_beta_px * cfg.work_scale
        occ0, occ1 = occlusion(f01, f10, grid, a, b), occlusion(f10, f01, grid, a, b)
        motion = float(np.sqrt(max(np.max(np.sum(f01 ** 2, -1)),
                                   np.max(np.sum(f10 ** 2, -1))))) / cfg.work_scale
        cut = cfg.scene_cut_fraction is not None and \
            0.5 * (occ0.mean() + occ1.mean()) > cfg.scene_cut_fraction
        return FlowPair(f01, f10, occ0, occ1, motion, bool(cut))


class Between:
    """The LR intensity between two frames (see the module doc)."""

    motion_px: float = 0.0
    cut: bool = False

    def at(self, tau: float) -> tuple[np.ndarray, np.ndarray | None]:
        """(float32[h, w] LR linear intensity at ``tau`` in [0, 1], bool[h, w] pixels
        whose value comes from an occlusion there, where no time step bounds the change,
        or None)."""
        raise NotImplementedError


class LinearBetween(Between):
    """Log intensity linear in time, per LR pixel."""

    def __init__(self, lr0: np.ndarray, lr1: np.ndarray, log_eps: float, cut: bool) -> None:
        self._l0 = np.log(lr0.astype(np.float64) + log_eps)
        self._l1 = np.log(lr1.astype(np.float64) + log_eps)
        self._eps, self.cut = log_eps, cut

    def at(self, tau: float) -> tuple[np.ndarray, None]:
        log = (1.0 - tau) * self._l0 + tau * self._l1
        return (np.exp(log) - self._eps).astype(np.float32), None


class FlowBetween(Between):
    """Occlusion-aware warping along DIS flow (see the module doc)."""

    def __init__(self, work0: np.ndarray, work1: np.ndarray, flows: FlowPair,
                 grid: np.ndarray, config: VideoConfig) -> None:
        self._w0, self._w1, self._f, self._grid = work0, work1, flows, grid
        self._o0 = flows.occ0.astype(np.float32)
        self._o1 = flows.occ1.astype(np.float32)
        self._k, self._floor = config.work_scale, config.flow.visibility_floor
        self.motion_px, self.cut = flows.motion_px, flows.cut

    def at(self, tau: float) -> tuple[np.ndarray, np.ndarray]:
        f = self._f
        ft0 = (-(1.0 - tau) * tau) * f.f01 + (tau * tau) * f.f10
        ft1 = ((1.0 - tau) ** 2) * f.f01 - (tau * (1.0 - tau)) * f.f10
        i0, i1 = _warp(self._w0, self._grid, ft0), _warp(self._w1, self._grid, ft1)
        gone = _warp(self._o0, self._grid, ft0)  # content of frame 0 about to be hidden
        new = _warp(self._o1, self._grid, ft1)  # content of frame 1 not yet shown
        w0 = (1.0 - tau) * np.maximum(1.0 - new, self._floor)
        w1 = tau * np.maximum(1.0 - gone, self._floor)
        work = (w0 * i0 + w1 * i1) / (w0 + w1)
        lr = block_mean(np.ascontiguousarray(work, np.float32), self._k)
        return lr, block_any((gone > 0) | (new > 0), self._k)


class Interpolator:
    """Makes the :class:`Between` of two neighbouring frames for one configuration."""

    def __init__(self, config: VideoConfig, log_eps: float) -> None:
        self.config, self.log_eps = config, log_eps
        needs_flow = config.interpolator == "flow" or config.scene_cut_fraction is not None
        self._flow = FlowEstimator(config) if needs_flow else None

    @property
    def name(self) -> str:
        return self.config.interpolator

    def between(self, a: CameraImages, b: CameraImages) -> Between:
        flows = None if self._flow is None else self._flow.pair(a.work, b.work)
        if self.config.interpolator == "linear":
            return LinearBetween(a.images["lr"], b.images["lr"], self.log_eps,
                                 flows is not None and flows.cut)
        return FlowBetween(a.work, b.work, flows, self._flow.grid(a.work.shape), self.config)
