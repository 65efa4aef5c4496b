"""Adaptive choice of render times: predict with ESIM's rule, then verify.

Between two samples a pixel's log intensity is taken as linear; if it changes by more than a
threshold, crossings get wrong timestamps, and if it goes up and back down, events are lost.
ESIM therefore picks the next sample so that the largest predicted change stays below a
fraction ``lambda`` of the contrast threshold, predicting ``dL/dt = -grad L . flow`` with the
flow of the (here exactly known) scene geometry.

The prediction alone does not keep that promise: near dark pixels ``log(eps + I)`` rises much
faster within a pixel than the difference to the neighbour suggests, and we measured single
steps with 6-15x the intended change. So the sampler works like an ODE step-size
controller: it proposes ``dt`` from the prediction scaled by a learnt gain (observed /
predicted change of recent steps), the caller renders the sample and reports the realised
largest change, and a step exceeding ``lambda C`` is retried shorter. Accepted steps thus
satisfy the bound by construction, except at ``min_step_s``.

With moving objects the image is not continuous where one surface passes in front of
another: a sub-pixel sample that changes surface changes its pixel by a finite amount in an
arbitrarily short step, so no step bounds the change there and a verify step that insists
drives the sampler to ``min_step_s`` for the rest of the sequence. Such steps are bounded as
ESIM bounds all of them, by motion: the surfaces' exact flow (known from the geometry) moves
no occlusion boundary by more than ``max_edge_step_px`` per step. Everywhere else the
prediction and the verify step work as for a plane, with two changes: the gradient is not
taken across a boundary (neighbours on different surfaces), and the verified change leaves
out the band of pixels around the boundaries and at the image border (where objects enter),
which the motion bound covers instead.

Gradient bound used by the prediction: ``|u| Gx + |v| Gy``, where ``Gx`` is the larger
one-sided difference of ``L`` along x over the rows y-1..y+1 (and ``Gy`` likewise), so that
diagonal motion also sees its neighbours' edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy.ndimage import maximum_filter

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.pose import Pose, Twist

#: Proposed steps aim at this fraction of the allowed change, leaving room for error.
SAFETY = 0.8
#: Half-width (px) of the band around occlusion boundaries left out of the verified change.
BAND_PX = 2


@dataclass(frozen=True)
class SamplingConfig:
    """Render-time selection.

    Attributes:
        adaptive: predict-and-verify steps; otherwise sample every ``max_step_s``.
        contrast_fraction: lambda: the largest per-step log change allowed, as a fraction of
            the smallest contrast threshold.
        min_step_s, max_step_s: bounds on the time between samples.
        max_edge_step_px: with moving objects, the farthest an occlusion boundary may move
            in one step (pixels, from the exact flow of the surfaces on either side).
    """

    adaptive: bool = True
    contrast_fraction: float = 0.5
    min_step_s: float = 2e-5
    max_step_s: float = 5e-3
    max_edge_step_px: float = 0.5

    def __post_init__(self) -> None:
        if not 0 < self.contrast_fraction <= 1:
            raise ValueError("contrast_fraction must be in (0, 1]")
        if not 0 < self.min_step_s <= self.max_step_s:
            raise ValueError("need 0 < min_step_s <= max_step_s")
        if not self.max_edge_step_px > 0:
            raise ValueError("max_edge_step_px must be positive")


def log_change_rate_bound(log_img: np.ndarray, flow: np.ndarray,
                          ids: np.ndarray | None = None) -> np.ndarray:
    """float64[H, W] predicted ``|dL/dt|`` bound (log units/s) at every pixel (reference).

    Args:
        log_img: float32[H, W] log intensity.
        flow: float64[H, W, 2] pixel velocity (px/s), e.g. from :func:`motion_field`.
        ids: uint8[H, W] visible surface per pixel; differences between neighbours on
            different surfaces are left out (an occlusion boundary is not a gradient).
    """
    lg = log_img.astype(np.float64)
    dx = np.abs(np.diff(lg, axis=1))
    dy = np.abs(np.diff(lg, axis=0))
    if ids is not None:
        dx[ids[:, 1:] != ids[:, :-1]] = 0.0
        dy[ids[1:] != ids[:-1]] = 0.0
    gx = np.zeros_like(lg)
    gy = np.zeros_like(lg)
    gx[:, :-1] = dx
    gx[:, 1:] = np.maximum(gx[:, 1:], dx)
    gy[:-1] = dy
    gy[1:] = np.maximum(gy[1:], dy)
    gx = maximum_filter(gx, size=(3, 1), mode="nearest")
    gy = maximum_filter(gy, size=(1, 3), mode="nearest")
    return np.abs(flow[..., 0]) * gx + np.abs(flow[..., 1]) * gy


@numba.njit(cache=True, nogil=True)
def _one_sided_max(lg, axis_x):
    """max(|L - L_prev|, |L_next - L|) along x (``axis_x``) or y, then max over the
    perpendicular 3-neighbourhood; float64[H, W]."""
    h, w = lg.shape
    side = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            if axis_x:
                a = abs(np.float64(lg[y, x]) - lg[y, x - 1]) if x > 0 else 0.0
                b = abs(np.float64(lg[y, x + 1]) - lg[y, x]) if x < w - 1 else 0.0
            else:
                a = abs(np.float64(lg[y, x]) - lg[y - 1, x]) if y > 0 else 0.0
                b = abs(np.float64(lg[y + 1, x]) - lg[y, x]) if y < h - 1 else 0.0
            side[y, x] = max(a, b)
    out = np.empty((h, w))
    for y in range(h):
        for x in range(w):
            m = side[y, x]
            if axis_x:
                if y > 0:
                    m = max(m, side[y - 1, x])
                if y < h - 1:
                    m = max(m, side[y + 1, x])
            else:
                if x > 0:
                    m = max(m, side[y, x - 1])
                if x < w - 1:
                    m = max(m, side[y, x + 1])
            out[y, x] = m
    return out


@numba.njit(cache=True, nogil=True)
def max_log_change_rate(log_img, fx, fy, cx, cy, r_z, t_z, v_c, w_c):
    """Largest :func:`log_change_rate_bound` over the image with the plane's flow inlined.

    Args:
        log_img: float32[H, W].
        fx, fy, cx, cy: intrinsics.
        r_z: float64[3], third row of ``R_wc`` (ray direction -> world z).
        t_z: camera height above the plane ``z = 0``.
        v_c, w_c: float64[3] linear/angular camera velocity in the camera frame.
    """
    h, w = log_img.shape
    gx = _one_sided_max(log_img, True)
    gy = _one_sided_max(log_img, False)
    xs = (np.arange(w) - cx) / fx
    best = 0.0
    for y in range(h):
        yn = (y - cy) / fy
        for x in range(w):
            xn = xs[x]
            dz = r_z[0] * xn + r_z[1] * yn + r_z[2]
            inv_z = -dz / t_z if dz < 0 else 0.0
            u = fx * ((-v_c[0] + xn * v_c[2]) * inv_z + xn * yn * w_c[0]
                      - (1 + xn * xn) * w_c[1] + yn * w_c[2])
            v = fy * ((-v_c[1] + yn * v_c[2]) * inv_z + (1 + yn * yn) * w_c[0]
                      - xn * yn * w_c[1] - xn * w_c[2])
            best = max(best, abs(u) * gx[y, x] + abs(v) * gy[y, x])
    return best


def boundary_pixels(ids: np.ndarray) -> np.ndarray:
    """bool[H, W]: pixels with a 4-neighbour on another surface (either side of an
    occlusion boundary)."""
    edge = np.zeros(ids.shape, bool)
    dx = ids[:, 1:] != ids[:, :-1]
    dy = ids[1:] != ids[:-1]
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:] |= dy
    edge[:-1] |= dy
    return edge


def boundary_band(ids: np.ndarray, width: int = BAND_PX) -> np.ndarray:
    """bool[H, W]: pixels within ``width`` of an occlusion boundary (neighbours on different
    surfaces) or of the image border."""
    edge = boundary_pixels(ids)
    band = maximum_filter(edge, size=2 * width + 1, mode="constant", cval=False) if \
        edge.any() else edge
    band[:width] = band[-width:] = True
    band[:, :width] = band[:, -width:] = True
    return band


def edge_speed(flow: np.ndarray, ids: np.ndarray) -> float:
    """Largest flow magnitude (px/s) of the pixels on either side of an occlusion boundary."""
    edge = boundary_pixels(ids)
    if not edge.any():
        return 0.0
    return float(np.sqrt((flow[edge] ** 2).sum(-1)).max())


@numba.njit(cache=True, nogil=True)
def dynamic_bounds(log_img, flow, ids, band_px):
    """(largest :func:`log_change_rate_bound` with ``ids``, :func:`edge_speed`,
    :func:`boundary_band` of ``band_px``) in one compiled pass; ``flow`` is float[2, H, W]
    (channel 0 = x)."""
    h, w = log_img.shape
    gx = np.zeros((h, w))
    gy = np.zeros((h, w))
    edge = np.zeros((h, w), np.bool_)
    for y in range(h):
        for x in range(w - 1):
            if ids[y, x] != ids[y, x + 1]:
                edge[y, x] = edge[y, x + 1] = True
            else:
                d = abs(np.float64(log_img[y, x + 1]) - log_img[y, x])
                gx[y, x] = max(gx[y, x], d)
                gx[y, x + 1] = max(gx[y, x + 1], d)
    for y in range(h - 1):
        for x in range(w):
            if ids[y, x] != ids[y + 1, x]:
                edge[y, x] = edge[y + 1, x] = True
            else:
                d = abs(np.float64(log_img[y + 1, x]) - log_img[y, x])
                gy[y, x] = max(gy[y, x], d)
                gy[y + 1, x] = max(gy[y + 1, x], d)
    rate = 0.0
    speed2 = 0.0
    for y in range(h):
        for x in range(w):
            u, v = np.float64(flow[0, y, x]), np.float64(flow[1, y, x])
            mx = gx[y, x]  # the x difference over rows y-1..y+1
            if y > 0:
                mx = max(mx, gx[y - 1, x])
            if y < h - 1:
                mx = max(mx, gx[y + 1, x])
            my = gy[y, x]  # the y difference over columns x-1..x+1
            if x > 0:
                my = max(my, gy[y, x - 1])
            if x < w - 1:
                my = max(my, gy[y, x + 1])
            rate = max(rate, abs(u) * mx + abs(v) * my)
            if edge[y, x]:
                speed2 = max(speed2, u * u + v * v)
    band = np.zeros((h, w), np.bool_)
    for y in range(h):
        for x in range(w):
            if edge[y, x]:
                band[max(0, y - band_px):min(h, y + band_px + 1),
                     max(0, x - band_px):min(w, x + band_px + 1)] = True
    band[:band_px] = True
    band[h - band_px:] = True
    band[:, :band_px] = True
    band[:, w - band_px:] = True
    return rate, np.sqrt(speed2), band


@numba.njit(cache=True, nogil=True)
def _weighted_change(before, after, weight, band):
    """:meth:`AdaptiveSampler.change` in one compiled pass (float32 as numpy computes it):
    the largest ``|after - before| * weight`` outside ``band``."""
    h, w = before.shape
    best = np.float32(0.0)
    for y in range(h):
        for x in range(w):
            if not band[y, x]:
                best = max(best, abs(after[y, x] - before[y, x]) * weight[y, x])
    return best


class AdaptiveSampler:
    """Proposes the next step for one camera and reviews the realised change."""

    def __init__(self, config: SamplingConfig, camera: Intrinsics, min_threshold: float,
                 pixel_thresholds: np.ndarray | None = None):
        """``min_threshold``: the budget is ``lambda`` times it. ``pixel_thresholds``
        (float[H, W], each pixel's smaller threshold, at least ``min_threshold``): with
        mismatch, each pixel's change is held to ``lambda`` times its *own* threshold
        (the review weighs it by ``min_threshold / threshold``) instead of every pixel to
        the smallest one; :attr:`strict_budget` stays ``lambda`` times the smallest."""
        self.config = config
        self.camera = camera
        self.budget = config.contrast_fraction * float(min_threshold)
        self.strict_budget = self.budget
        self._weight = None
        if pixel_thresholds is not None:
            low = float(np.min(pixel_thresholds))
            self.strict_budget = config.contrast_fraction * low
            if float(np.max(pixel_thresholds)) > low:
                self._weight = (float(min_threshold) / pixel_thresholds).astype(np.float32)
        self.gain = 1.0
        self.rejected = 0
        self.edge_limited = 0
        self._rate = 0.0
        self._band: np.ndarray | None = None

    def propose(self, log_img: np.ndarray, pose: Pose, twist: Twist,
                flow: np.ndarray | None = None, ids: np.ndarray | None = None) -> float:
        """Seconds to the next sample, from the current log image and the motion.

        Args:
            flow: float[2, H, W] exact motion field of the visible surfaces (px/s, channel
                0 = x, as :class:`~esim_lite.geometry.visibility.SurfaceTruth` holds it),
                for scenes whose objects move on their own; None: the static plane's
                field, computed here from the camera's ``pose`` and ``twist``.
            ids: uint8[H, W] the visible surface of every pixel (with ``flow``).
        """
        cfg = self.config
        self._band = None
        if not cfg.adaptive:
            return cfg.max_step_s
        edge_dt = np.inf
        if flow is not None:
            if ids is None:
                raise ValueError("propose: a flow for moving objects needs the surface ids")
            self._rate, speed, self._band = dynamic_bounds(log_img, flow, ids, BAND_PX)
            if speed > 0:
                edge_dt = cfg.max_edge_step_px / speed
        else:
            cam = self.camera
            v_c, w_c = twist.in_camera(pose)
            self._rate = max_log_change_rate(log_img, cam.fx, cam.fy, cam.cx, cam.cy,
                                             np.ascontiguousarray(pose.r_wc[2]),
                                             float(pose.t_wc[2]), v_c, w_c)
        dt = SAFETY * self.budget / (self.gain * self._rate) if self._rate > 0 else np.inf
        if edge_dt < dt and edge_dt < cfg.max_step_s:
            self.edge_limited += 1
        return float(np.clip(min(dt, edge_dt), cfg.min_step_s, cfg.max_step_s))

    def change(self, log_before: np.ndarray, log_after: np.ndarray) -> float:
        """The largest ``|L1 - L0|`` that the review checks (weighed by each pixel's
        threshold when the sampler has them): every pixel for a plane; with moving
        objects, every pixel outside the band around the occlusion boundaries and the image
        border seen at the proposal (the motion bound covers that band)."""
        before = np.ascontiguousarray(log_before, np.float32)
        after = np.ascontiguousarray(log_after, np.float32)
        if self._weight is None and self._band is None:
            return float(np.abs(after - before).max())
        shape = before.shape
        weight = self._weight if self._weight is not None else np.ones(shape, np.float32)
        band = self._band if self._band is not None else np.zeros(shape, np.bool_)
        return float(_weighted_change(before, after, weight, band))

    def review(self, change: float, dt_s: float) -> float | None:
        """Report a rendered step's :meth:`change`; None accepts it, else retry with the
        returned (shorter) step in seconds."""
        cfg = self.config
        if not cfg.adaptive:
            return None
        if self._rate > 0 and dt_s > 0:
            observed = change / (self._rate * dt_s)
            self.gain = observed if observed > self.gain else 0.8 * self.gain + 0.2 * observed
            self.gain = max(self.gain, 1e-3)
        if change <= self.budget or dt_s <= cfg.min_step_s * (1 + 1e-9):
            return None
        self.rejected += 1
        return max(cfg.min_step_s, dt_s * SAFETY * self.budget / change)
