"""Rendering: the Mitsuba backend against the exact homography oracle, geometry, antialiasing."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage import data

from esim_lite.events.simulator import EventSimulator
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.geometry.camera import CameraRig, Intrinsics
from esim_lite.geometry.motion import project_plane_point
from esim_lite.geometry.pose import Pose, so3_exp
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import LOOK_DOWN
from esim_lite.render import mitsuba as render_mitsuba
from esim_lite.render.antialias import texels_per_sample
from esim_lite.render.renderer import RenderConfig, make_renderer
from esim_lite.sequence import sample_footprints
from tests.conftest import scene_and_trajectory, smooth_texture


def psnr(a: np.ndarray, b: np.ndarray, peak: float = 1.0) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(peak**2 / mse)


def tilted_pose() -> Pose:
    return Pose(so3_exp(np.array([0.2, -0.15, 0.0])) @ LOOK_DOWN @ so3_exp(np.array([0, 0, 0.7])),
                np.array([0.25, -0.15, 1.1]))


@pytest.fixture(scope="module")
def photo_scene() -> PlanarScene:
    tex = data.camera().astype(np.float32) / 255.0
    return PlanarScene(tex, 3.0, 3.0)


@pytest.mark.parametrize("size", [128, 512])
def test_mitsuba_matches_the_homography_oracle(photo_scene, size):
    # an off-centre principal point exercises every axis convention (image, texture)
    cam = Intrinsics(size * 0.87, size * 0.87, size / 2 - 0.5 + size / 40,
                     size / 2 - 0.5 - size / 25, size, size)
    cams = {"lr": cam}
    pose = tilted_pose()
    assert photo_scene.covers_view(cam, pose)
    exact = make_renderer(photo_scene, cams, RenderConfig(backend="homography")).render("lr", pose)
    mitsuba = make_renderer(photo_scene, cams, RenderConfig(backend="mitsuba"))
    img = mitsuba.render("lr", pose)
    mitsuba.close()
    assert img.shape == (size, size) and img.dtype == np.float32
    assert exact.std() > 0.1  # a real image, not a flat one
    assert psnr(img, exact) >= 40.0


def test_mitsuba_renders_the_same_bits_whatever_the_thread_count(photo_scene):
    """Renders of a moving camera, repeated with drjit's default thread pool and with one
    thread: bit for bit equal. (With s*s samples per film pixel the pixels whose samples
    straddle two of the LLVM backend's 16,384-item blocks were summed in thread-timing
    order: 15-21 of 40 x 128 x 128 pixels differed between such runs.)"""
    import drjit as dr

    cam = Intrinsics(110.0, 110.0, 63.5, 63.5, 128, 128)
    poses = [Pose(tilted_pose().r_wc, tilted_pose().t_wc + [0.002 * k, 0.001 * k, 0])
             for k in range(12)]
    before = dr.thread_count()
    images = []
    try:
        for threads in (None, 1, None):
            if threads is not None:
                dr.set_thread_count(threads)
            r = make_renderer(photo_scene, {"lr": cam}, RenderConfig(backend="mitsuba"))
            images.append(np.stack([r.render("lr", p) for p in poses]))
            r.close()
            dr.set_thread_count(before)
    finally:
        dr.set_thread_count(before)
    np.testing.assert_array_equal(images[0], images[1])
    np.testing.assert_array_equal(images[0], images[2])


def test_mitsuba_pixel_is_the_fixed_order_mean_of_its_sub_pixel_rays(photo_scene):
    """The second kernel's box filter, against numpy: a 3x3-supersampled render equals the
    one-sample render of the 3x finer camera, summed per pixel in float64 row by row, bit
    for bit (the rays are the same: cell centres of the fine grid)."""
    cam = Intrinsics(70.0, 70.0, 30.2, 21.6, 60, 44)
    pose = tilted_pose()
    coarse = make_renderer(photo_scene, {"lr": cam},
                           RenderConfig(backend="mitsuba", supersample_lr=3))
    fine = make_renderer(photo_scene, {"lr": cam.scaled(3)},
                         RenderConfig(backend="mitsuba", supersample_lr=1))
    samples = fine.render("lr", pose)
    total = np.zeros(cam.hw)
    for i in range(3):
        for j in range(3):
            total += samples[i::3, j::3]
    np.testing.assert_array_equal(coarse.render("lr", pose), (total / 9).astype(np.float32))
    assert samples.std() > 0.1


def test_homography_renders_a_point_where_it_projects():
    tex = np.zeros((200, 300), np.float32)
    tex[120:123, 70:73] = 1.0  # a 3x3 texel square; centre texel (row 121, col 71)
    scene = PlanarScene(tex, 3.0, 2.0)
    x_w = -1.5 + (71 + 0.5) * 3.0 / 300
    y_w = 1.0 - (121 + 0.5) * 2.0 / 200
    cam = Intrinsics(150.0, 150.0, 40.3, 33.7, 80, 64)
    pose = Pose(so3_exp(np.array([0.05, 0.1, 0.0])) @ LOOK_DOWN,
                np.array([x_w + 0.05, y_w - 0.04, 1.0]))
    img = make_renderer(scene, {"lr": cam}, RenderConfig(backend="homography",
                                                         supersample_lr=4)).render("lr", pose)
    v, u = np.mgrid[0:64, 0:80]
    centroid = np.array([(img * u).sum(), (img * v).sum()]) / img.sum()
    expected = project_plane_point(cam, pose, np.array([x_w, y_w, 0.0]))
    np.testing.assert_allclose(centroid, expected, atol=0.05)


@pytest.mark.parametrize("backend", ["homography", "mitsuba"])
def test_hr_frame_area_downsampled_matches_lr_frame(photo_scene, backend):
    rig = CameraRig(Intrinsics.from_fov(128, 128, 60.0), (2, 4))
    rng_scene, traj = scene_and_trajectory(rig.event, 0, duration_s=0.2,
                                           texture=photo_scene.texture)
    cfg = RenderConfig(backend=backend)
    renderer = make_renderer(rng_scene, rig.cameras(), cfg,
                             sample_footprints(rng_scene, traj, rig, cfg))
    pose = traj.pose(0.1)
    lr = renderer.render("lr", pose)
    for s in (2, 4):
        hr = renderer.render(f"hr_x{s}", pose)
        down = cv2.resize(hr, (128, 128), interpolation=cv2.INTER_AREA)
        assert psnr(down, lr) >= 30.0, s
    renderer.close()


def test_antialiasing_removes_flicker_events_of_unresolvable_texture():
    """A 1-texel checkerboard far below the camera's resolution looks uniform grey to a real
    camera, so sliding over it must not make events; unfiltered point sampling flickers."""
    cam = Intrinsics.from_fov(48, 48, 60.0)
    yy, xx = np.mgrid[0:1500, 0:1500]
    tex = (0.2 + 0.6 * ((xx + yy) % 2)).astype(np.float32)
    scene = PlanarScene(tex, 3.0, 3.0)
    poses = [Pose(LOOK_DOWN, np.array([0.001 * k, 0.0007 * k, 1.0])) for k in range(40)]
    counts = {}
    for label, footprint in (("raw", 0.0), ("prefiltered", None)):
        if footprint is None:
            footprint = texels_per_sample(scene, cam, 2, poses)
            assert footprint > 4  # far below resolution indeed
        r = make_renderer(scene, {"lr": cam}, RenderConfig(backend="homography"),
                          {"lr": footprint})
        th = ContrastThresholds.uniform(0.15, 0.15, cam.hw)
        sim = EventSimulator(r.render("lr", poses[0]), 0, th)
        counts[label] = sum(len(sim.step(r.render("lr", p), 1000 * (k + 1)))
                            for k, p in enumerate(poses[1:]))
        img = r.render("lr", poses[5])
        counts[label + "_std"] = float(img.std())
    assert counts["raw"] > 1000
    assert counts["prefiltered"] == 0
    assert counts["prefiltered_std"] < 0.01


def test_variant_falls_back_to_scalar_with_old_llvm(monkeypatch):
    import drjit

    monkeypatch.delenv("E2SR_MITSUBA_VARIANT", raising=False)
    monkeypatch.setattr(render_mitsuba, "_variant_cache", {})
    monkeypatch.setattr(drjit.detail, "llvm_version", lambda: (15, 0, 6))
    monkeypatch.setattr(drjit, "has_backend", lambda backend: False)
    probed = []
    monkeypatch.setattr(render_mitsuba, "_probe", lambda v: probed.append(v) or True)
    assert render_mitsuba.resolve_variant("auto") == "scalar_rgb"
    assert probed == []  # too old: never even tried, since trying can abort the process
    monkeypatch.setattr(render_mitsuba, "_variant_cache", {})
    monkeypatch.setattr(drjit.detail, "llvm_version", lambda: (19, 1, 7))
    assert render_mitsuba.resolve_variant("auto") == "llvm_ad_mono"
    assert probed == ["llvm_ad_mono"]
    monkeypatch.setenv("E2SR_MITSUBA_VARIANT", "scalar_rgb")
    assert render_mitsuba.resolve_variant("auto") == "scalar_rgb"


def test_scalar_variant_matches_too(photo_scene):
    """The fallback used where LLVM is too old renders the same image."""
    cam = Intrinsics.from_fov(48, 40, 55.0)
    pose = tilted_pose()
    exact = make_renderer(photo_scene, {"lr": cam}, RenderConfig(backend="homography"))
    scalar = make_renderer(photo_scene, {"lr": cam},
                           RenderConfig(backend="mitsuba", mitsuba_variant="scalar_rgb"))
    assert psnr(scalar.render("lr", pose), exact.render("lr", pose)) >= 40.0


def test_bad_render_settings_are_rejected():
    with pytest.raises(ValueError, match="supersample"):
        RenderConfig(supersample_lr=0)
    scene = PlanarScene(smooth_texture(0, (32, 32)), 1.0, 1.0)
    with pytest.raises(ValueError, match="square pixels"):  # Mitsuba's perspective sensor
        make_renderer(scene, {"lr": Intrinsics(100, 90, 10, 10, 20, 20)},
                      RenderConfig(backend="mitsuba", mitsuba_variant="scalar_rgb"))


def test_mitsuba_ray_cast_takes_non_square_pixels(photo_scene):
    """The JIT variants cast the rays of our pinhole model themselves, so fx != fy works
    (the scalar fallback's perspective sensor refuses it, above)."""
    cam = Intrinsics(120.0, 95.0, 50.3, 33.1, 96, 72)
    pose = tilted_pose()
    exact = make_renderer(photo_scene, {"lr": cam}, RenderConfig(backend="homography"))
    mitsuba = make_renderer(photo_scene, {"lr": cam}, RenderConfig(backend="mitsuba"))
    assert mitsuba.variant != "scalar_rgb"
    assert psnr(mitsuba.render("lr", pose), exact.render("lr", pose)) >= 40.0
