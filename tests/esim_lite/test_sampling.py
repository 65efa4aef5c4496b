"""Adaptive sampling: the per-step bound holds, and it is what keeps events from being lost."""

from __future__ import annotations

import numpy as np
import pytest

from esim_lite.config import CameraConfig, SimulationConfig
from esim_lite.events.sampling import SamplingConfig, log_change_rate_bound, max_log_change_rate
from esim_lite.events.simulator import EventSimulator
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.motion import motion_field
from esim_lite.geometry.trajectory import TrajectoryConfig, sample_trajectory
from esim_lite.render.renderer import RenderConfig
from esim_lite.sequence import simulate
from tests.conftest import scene_and_trajectory, smooth_texture

# Hand-shake speeds: features cross pixels within one 50 Hz frame.
FAST = TrajectoryConfig(speed_m_s=(2.0, 3.0), angular_speed_deg_s=(300, 400))


def test_compiled_rate_bound_equals_the_numpy_reference():
    cam = Intrinsics(70.0, 70.0, 30.2, 22.9, 64, 48)
    traj = sample_trajectory(FAST, 0.5, cam, np.random.default_rng(2))
    log_img = np.log(smooth_texture(1, (48, 64), sigma=1.0) + 1e-3)
    for t in (0.05, 0.3):
        pose, tw = traj.pose_and_twist(t)
        v_c, w_c = tw.in_camera(pose)
        fast = max_log_change_rate(log_img, cam.fx, cam.fy, cam.cx, cam.cy,
                                   np.ascontiguousarray(pose.r_wc[2]), pose.t_wc[2], v_c, w_c)
        ref = log_change_rate_bound(log_img, motion_field(cam, pose, tw)).max()
        assert fast == pytest.approx(ref, rel=1e-12)


def stripes() -> np.ndarray:
    """Thin bright lines on a dark ground, about one event pixel wide at 1 m."""
    tex = np.full((1024, 1024), 0.05, np.float32)
    for k in range(0, 1024, 37):
        tex[:, k:k + 6] = 0.9
        tex[k:k + 6, :] = 0.9
    return tex


def run(sampling: SamplingConfig, seed: int = 4, duration_s: float = 0.25):
    """Simulate a fast trajectory over a photo-like texture, recording each step's change."""
    cfg = SimulationConfig(duration_s=duration_s, sampling=sampling, trajectory=FAST,
                           camera=CameraConfig(width=64, height=48, scales=(2,)),
                           render=RenderConfig(backend="homography"))
    rig = cfg.camera.rig()
    scene, traj = scene_and_trajectory(rig.event, seed, duration_s, FAST, texture=stripes())
    th = ContrastThresholds.uniform(0.2, 0.2, rig.event.hw)
    changes, steps = [], []
    original = EventSimulator.step_log

    def recording(sim, log_img, t_ns):
        changes.append(float(np.abs(log_img - sim.log_prev).max()))
        steps.append(t_ns - sim.t_ns)
        return original(sim, log_img, t_ns)

    EventSimulator.step_log = recording
    try:
        n_events = sum(len(c.events) for c in simulate(scene, traj, th, cfg,
                                                        np.random.default_rng(0)))
    finally:
        EventSimulator.step_log = original
    return np.array(changes), np.array(steps), n_events


def test_adaptive_steps_keep_the_log_change_under_lambda_c():
    cfg = SamplingConfig(contrast_fraction=0.5)
    changes, steps, _ = run(cfg)
    bound = 0.5 * 0.2
    at_min = steps <= cfg.min_step_s * 1e9 + 1
    assert len(changes) > 100
    assert np.all(changes[~at_min] <= bound + 1e-6)
    assert at_min.mean() < 0.01


def test_without_adaptive_sampling_fast_motion_loses_events():
    """Reference: a brute-force 20 us grid. Adaptive sampling matches it with far fewer
    samples; sampling only at a 50 Hz frame rate silently loses a large share of them."""
    _, steps_ref, n_ref = run(SamplingConfig(adaptive=False, max_step_s=2e-5))
    _, steps_ad, n_ad = run(SamplingConfig())
    _, _, n_coarse = run(SamplingConfig(adaptive=False, max_step_s=0.02))  # 50 Hz frames
    assert len(steps_ad) < len(steps_ref) / 2
    assert abs(n_ad - n_ref) <= 0.005 * n_ref
    assert n_coarse < 0.8 * n_ref


def test_with_mismatch_each_pixel_is_held_to_its_own_threshold():
    """A step may move a pixel by lambda times its own threshold, not by lambda times the
    smallest one on the sensor; the still-image bounds keep the strict budget."""
    from esim_lite.events.sampling import AdaptiveSampler

    cam = Intrinsics.from_fov(8, 4, 60.0)
    pixel = np.full((4, 8), 0.4)
    pixel[:, :4] = 0.2  # left half: the low thresholds
    cfg = SamplingConfig(contrast_fraction=0.5)
    per_pixel = AdaptiveSampler(cfg, cam, 0.2, pixel)
    strict = AdaptiveSampler(cfg, cam, 0.2)
    before = np.zeros((4, 8), np.float32)
    right = before.copy()
    right[:, 4:] = 0.15  # 0.375 of the right half's 0.4: within lambda = 0.5
    left = before.copy()
    left[:, :4] = 0.15  # 0.75 of the left half's 0.2: over
    assert per_pixel.review(per_pixel.change(before, right), 1e-3) is None
    assert strict.review(strict.change(before, right), 1e-3) is not None
    assert per_pixel.review(per_pixel.change(before, left), 1e-3) is not None
    assert per_pixel.strict_budget == strict.budget == pytest.approx(0.1)


@pytest.mark.parametrize("weighted", [False, True])
@pytest.mark.parametrize("banded", [False, True])
def test_change_equals_the_numpy_expression_bit_for_bit(weighted, banded):
    """The compiled review (per-pixel threshold weights, the occlusion band left out)
    against the numpy expression it replaced: the same float32 maximum."""
    from esim_lite.events.sampling import AdaptiveSampler

    rng = np.random.default_rng(3)
    hw = (48, 64)
    cam = Intrinsics.from_fov(hw[1], hw[0], 60.0)
    pixel = rng.uniform(0.12, 0.8, hw) if weighted else None
    sampler = AdaptiveSampler(SamplingConfig(contrast_fraction=1.0), cam, 0.12, pixel)
    band = rng.random(hw) < 0.3
    if banded:
        sampler._band = band
    before = rng.normal(0, 1, hw).astype(np.float32)
    after = (before + rng.normal(0, 0.2, hw)).astype(np.float32)
    diff = np.abs(after - before)
    if weighted:
        diff = diff * sampler._weight
    if banded:
        diff = np.where(band, 0.0, diff)
    assert sampler.change(before, after) == float(diff.max())
