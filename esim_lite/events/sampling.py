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

With moving objects the prediction uses the exact flow of each pixel's visible surface.
Where one surface passes in front of another the image is not continuous in time: a
sub-pixel sample that changes surface changes its pixel by a finite amount in an
arbitrarily short step. The review then keeps shortening a rejected step only while the
change shrinks with it; a change that stays when the step shrinks is a jump at an
occlusion boundary and is accepted (counted in ``jumps``), so such steps cannot drive the
sampler down to ``min_step_s`` for the rest of the sequence.

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
#: With moving objects, a retry at most this fraction of the rejected step ...
JUMP_SHRINK = 0.6
#: ... that keeps at least this fraction of its change is a jump, not a fast change.
JUMP_KEEP = 0.7


@dataclass(frozen=True)
class SamplingConfig:
    """Render-time selection.

    Attributes:
        adaptive: predict-and-verify steps; otherwise sample every ``max_step_s``.
        contrast_fraction: lambda: the largest per-step log change allowed, as a fraction of
            the smallest contrast threshold.
        min_step_s, max_step_s: bounds on the time between samples.
    """

    adaptive: bool = True
    contrast_fraction: float = 0.5
    min_step_s: float = 2e-5
    max_step_s: float = 5e-3

    def __post_init__(self) -> None:
        if not 0 < self.contrast_fraction <= 1:
            raise ValueError("contrast_fraction must be in (0, 1]")
        if not 0 < self.min_step_s <= self.max_step_s:
            raise ValueError("need 0 < min_step_s <= max_step_s")


def log_change_rate_bound(log_img: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """float64[H, W] predicted ``|dL/dt|`` bound (log units/s) at every pixel (reference).

    Args:
        log_img: float32[H, W] log intensity.
        flow: float64[H, W, 2] pixel velocity (px/s), e.g. from :func:`motion_field`.
    """
    lg = log_img.astype(np.float64)
    dx = np.abs(np.diff(lg, axis=1))
    dy = np.abs(np.diff(lg, axis=0))
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


class AdaptiveSampler:
    """Proposes the next step for one camera and reviews the realised change."""

    def __init__(self, config: SamplingConfig, camera: Intrinsics, min_threshold: float):
        self.config = config
        self.camera = camera
        self.budget = config.contrast_fraction * float(min_threshold)
        self.gain = 1.0
        self.rejected = 0
        self.jumps = 0
        self._rate = 0.0
        self._dynamic = False
        self._tried: tuple[float, float] | None = None

    def propose(self, log_img: np.ndarray, pose: Pose, twist: Twist,
                flow: np.ndarray | None = None) -> float:
        """Seconds to the next sample, from the current log image and the motion.

        Args:
            flow: float64[H, W, 2] exact motion field of the visible surfaces (px/s), for
                scenes whose objects move on their own; None: the static plane's field,
                computed here from the camera's ``pose`` and ``twist``.
        """
        cfg = self.config
        if not cfg.adaptive:
            return cfg.max_step_s
        self._dynamic, self._tried = flow is not None, None
        if flow is not None:
            self._rate = float(log_change_rate_bound(log_img, flow).max())
        else:
            cam = self.camera
            v_c, w_c = twist.in_camera(pose)
            self._rate = max_log_change_rate(log_img, cam.fx, cam.fy, cam.cx, cam.cy,
                                             np.ascontiguousarray(pose.r_wc[2]),
                                             float(pose.t_wc[2]), v_c, w_c)
        if self._rate <= 0:
            return cfg.max_step_s
        dt = SAFETY * self.budget / (self.gain * self._rate)
        return float(np.clip(dt, cfg.min_step_s, cfg.max_step_s))

    def review(self, change: float, dt_s: float) -> float | None:
        """Report a rendered step's largest ``|L1 - L0|``; None accepts it, else retry with
        the returned (shorter) step in seconds."""
        cfg = self.config
        if not cfg.adaptive:
            return None
        if self._dynamic:
            return self._review_dynamic(change, dt_s)
        if self._rate > 0 and dt_s > 0:
            observed = change / (self._rate * dt_s)
            self.gain = observed if observed > self.gain else 0.8 * self.gain + 0.2 * observed
            self.gain = max(self.gain, 1e-3)
        if change <= self.budget or dt_s <= cfg.min_step_s * (1 + 1e-9):
            return None
        self.rejected += 1
        return max(cfg.min_step_s, dt_s * SAFETY * self.budget / change)

    def _review_dynamic(self, change: float, dt_s: float) -> float | None:
        """The review with moving objects, whose edges (and the lines where surfaces cross)
        make the image jump: a sub-pixel sample that changes surface changes its pixel by a
        finite amount however short the step. A retry that shortens the step by at least
        :data:`JUMP_SHRINK` but keeps at least :data:`JUMP_KEEP` of the change is such a
        jump: it is accepted (no step would resolve it). The gain stays 1 (ESIM's rule as it
        is): jumps of every size below the budget would otherwise teach it that every step
        overshoots."""
        cfg = self.config
        tried, self._tried = self._tried, None
        jump = tried is not None and dt_s <= JUMP_SHRINK * tried[0] and \
            change >= JUMP_KEEP * tried[1]
        if jump:
            self.jumps += 1
            return None
        if change <= self.budget or dt_s <= cfg.min_step_s * (1 + 1e-9):
            return None
        self.rejected += 1
        self._tried = (dt_s, change)
        return max(cfg.min_step_s, dt_s * SAFETY * self.budget / change)
