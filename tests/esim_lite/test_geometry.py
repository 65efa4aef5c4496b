"""Cameras, poses, trajectories and the motion field against analytic answers."""

from __future__ import annotations

import numpy as np
import pytest

from esim_lite.geometry.camera import CameraRig, Intrinsics
from esim_lite.geometry.motion import motion_field, project_plane_point
from esim_lite.geometry.pose import Pose, matrix_from_quat, quat_from_matrix, so3_exp, so3_log
from esim_lite.geometry.scene import intersect_plane
from esim_lite.geometry.trajectory import LOOK_DOWN, TrajectoryConfig, sample_trajectory
from tests.conftest import scene_and_trajectory


def test_hr_pixels_tile_lr_pixels_exactly():
    lr = Intrinsics(100.0, 100.0, 40.0, 29.5, 80, 60)
    for s in (2, 4):
        hr = lr.scaled(s)
        assert (hr.width, hr.height) == (80 * s, 60 * s)
        # the same continuous image rectangle: identical corner rays, identical FOV
        np.testing.assert_allclose(hr.corner_rays(), lr.corner_rays(), atol=1e-12)
        # the centre of LR pixel u is the centre of HR pixels s*u .. s*u+s-1
        u = np.arange(80)
        hr_centres = ((s * u[:, None] + np.arange(s)[None]) - hr.cx) / hr.fx
        np.testing.assert_allclose(hr_centres.mean(1), (u - lr.cx) / lr.fx, atol=1e-12)


def test_rig_names_and_fov():
    rig = CameraRig(Intrinsics.from_fov(128, 128, 60.0), (2, 4))
    cams = rig.cameras()
    assert list(cams) == ["lr", "hr_x2", "hr_x4"]
    assert cams["hr_x4"].width == 512 and cams["hr_x2"].height == 256
    assert all(np.isclose(c.fov_x_deg, 60.0) for c in cams.values())
    with pytest.raises(ValueError, match="not in this rig"):
        rig.hr(3)


def test_so3_and_quaternion_round_trips():
    rng = np.random.default_rng(0)
    for _ in range(200):
        w = rng.normal(size=3)
        w *= rng.uniform(0, np.pi - 1e-3) / np.linalg.norm(w)
        r = so3_exp(w)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(so3_log(r), w, atol=1e-9)
        np.testing.assert_allclose(matrix_from_quat(quat_from_matrix(r)), r, atol=1e-12)
    near_pi = so3_exp(np.array([0.0, np.pi - 1e-9, 0.0]))
    np.testing.assert_allclose(np.abs(so3_log(near_pi)), [0, np.pi, 0], atol=1e-6)


def test_pose_inverse_and_plane_intersection():
    pose = Pose(so3_exp(np.array([0.2, -0.1, 0.5])) @ LOOK_DOWN, np.array([0.3, 0.1, 1.5]))
    cam = Intrinsics.from_fov(32, 24, 50.0)
    pts, depth = intersect_plane(pose, cam.pixel_rays())
    assert np.all(depth > 0)
    np.testing.assert_allclose(pts[..., 2], 0.0, atol=1e-12)
    uv = project_plane_point(cam, pose, pts)
    u, v = np.meshgrid(np.arange(32.0), np.arange(24.0))
    np.testing.assert_allclose(uv[..., 0], u, atol=1e-9)
    np.testing.assert_allclose(uv[..., 1], v, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_twist_matches_finite_differences(seed):
    cam = Intrinsics.from_fov(64, 48, 60.0)
    traj = sample_trajectory(TrajectoryConfig(), 1.0, cam, np.random.default_rng(seed))
    h = 1e-6
    for t in np.linspace(0.01, 0.99, 23):
        pose, tw = traj.pose_and_twist(t)
        ahead, behind = traj.pose(t + h), traj.pose(t - h)
        np.testing.assert_allclose(tw.v_w, (ahead.t_wc - behind.t_wc) / (2 * h), atol=1e-6)
        w_fd = so3_log(ahead.r_wc @ behind.r_wc.T) / (2 * h)
        np.testing.assert_allclose(tw.w_w, w_fd, atol=1e-6)


def test_trajectory_is_continuous_across_knots():
    cam = Intrinsics.from_fov(64, 48, 60.0)
    traj = sample_trajectory(TrajectoryConfig(), 1.0, cam, np.random.default_rng(3))
    for k in range(1, 4):
        t = k * traj.knot_spacing_s
        a, b = traj.pose_and_twist(t - 1e-9), traj.pose_and_twist(t + 1e-9)
        np.testing.assert_allclose(a[0].t_wc, b[0].t_wc, atol=1e-7)
        np.testing.assert_allclose(a[0].r_wc, b[0].r_wc, atol=1e-7)
        np.testing.assert_allclose(a[1].v_w, b[1].v_w, atol=1e-6)
        np.testing.assert_allclose(a[1].w_w, b[1].w_w, atol=1e-6)


@pytest.mark.parametrize("seed", range(4))
def test_random_trajectories_respect_their_ranges_and_see_only_texture(seed):
    cfg = TrajectoryConfig(max_tilt_deg=20.0, height_m=(0.8, 1.2), speed_m_s=(0.2, 0.6))
    cam = Intrinsics.from_fov(64, 48, 60.0)
    scene, traj = scene_and_trajectory(cam, seed, duration_s=1.0, config=cfg)
    for t in traj.sample_times(0.001):
        pose = traj.pose(t)
        assert 0.8 - 1e-9 <= pose.t_wc[2] <= 1.2 + 1e-9  # lit side, height range
        tilt = np.degrees(np.arccos(-pose.r_wc[2, 2]))
        assert tilt <= 20.0 + 0.5
        assert scene.covers_view(cam, pose)
    speeds = [np.linalg.norm(traj.twist(t).v_w) for t in traj.sample_times(0.01)]
    assert 0.05 < np.median(speeds) < 0.6


def test_same_seed_same_trajectory():
    cam = Intrinsics.from_fov(64, 48, 60.0)
    a = sample_trajectory(TrajectoryConfig(), 0.5, cam, np.random.default_rng(11))
    b = sample_trajectory(TrajectoryConfig(), 0.5, cam, np.random.default_rng(11))
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.rotations, b.rotations)


def test_motion_field_matches_projected_finite_differences():
    cam = Intrinsics(90.0, 90.0, 30.5, 21.0, 64, 48)
    traj = sample_trajectory(TrajectoryConfig(angular_speed_deg_s=(60, 90)), 0.5, cam,
                             np.random.default_rng(5))
    t, h = 0.2, 1e-6
    pose, tw = traj.pose_and_twist(t)
    pts, _ = intersect_plane(pose, cam.pixel_rays())
    fd = (project_plane_point(cam, traj.pose(t + h), pts)
          - project_plane_point(cam, traj.pose(t - h), pts)) / (2 * h)
    flow = motion_field(cam, pose, tw)
    assert np.abs(flow).max() > 10
    np.testing.assert_allclose(flow, fd, atol=1e-4 * np.abs(fd).max())


def test_planar_flow_is_the_exact_displacement_and_integrates_the_motion_field():
    from esim_lite.geometry.motion import planar_flow

    cam = Intrinsics(90.0, 90.0, 30.5, 21.0, 64, 48)
    traj = sample_trajectory(TrajectoryConfig(angular_speed_deg_s=(60, 90)), 0.5, cam,
                             np.random.default_rng(6))
    a, b = traj.pose(0.1), traj.pose(0.13)
    flow = planar_flow(cam, a, b)
    pts, _ = intersect_plane(a, cam.pixel_rays())
    u, v = np.meshgrid(np.arange(64.0), np.arange(48.0))
    np.testing.assert_allclose(flow, project_plane_point(cam, b, pts) - np.stack([u, v], -1),
                               atol=1e-9)
    # over a short interval it is the motion field times the time step
    h = 1e-5
    np.testing.assert_allclose(planar_flow(cam, a, traj.pose(0.1 + h)) / h,
                               motion_field(cam, a, traj.twist(0.1)), rtol=1e-3, atol=1e-3)
    assert np.abs(planar_flow(cam, a, a)).max() < 1e-9
