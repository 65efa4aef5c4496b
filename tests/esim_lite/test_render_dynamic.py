"""Dynamic scenes in the Mitsuba backend: moving alpha-tested objects over the background,
against the exact reference renderer (float64 ray tracing in numpy)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.objects import DynamicScene, ObjectPatch, relative_pose
from esim_lite.geometry.pose import Pose, so3_exp
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import LOOK_DOWN, BSplineTrajectory
from esim_lite.geometry.visibility import object_frames, sample_box, sample_boxes, trace
from esim_lite.render.mitsuba import MitsubaRenderer
from esim_lite.render.reference import ReferenceRenderer
from esim_lite.render.renderer import RenderConfig, make_renderer
from tests.conftest import smooth_texture


def psnr(a: np.ndarray, b: np.ndarray, peak: float = 1.0) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(peak**2 / mse)


def still(pose: Pose) -> BSplineTrajectory:
    """A trajectory that stays at ``pose`` (the renderers only read the poses given)."""
    return BSplineTrajectory(np.repeat(pose.t_wc[None], 4, 0), np.repeat(pose.r_wc[None], 4, 0),
                             1.0, 1.0)


def camera_pose() -> Pose:
    return Pose(so3_exp(np.array([0.08, -0.06, 0.0])) @ LOOK_DOWN @ so3_exp(np.array([0, 0, 0.3])),
                np.array([0.03, -0.02, 1.0]))


def alpha_shape(kind: str, hw: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """float32[h, w] in [0, 1]: a soft-edged ellipse, polygon or blotchy noise mask."""
    h, w = hw
    if kind == "ellipse":
        mask = np.zeros(hw, np.float32)
        axes = (int(w * rng.uniform(0.25, 0.5)), int(h * rng.uniform(0.25, 0.5)))
        cv2.ellipse(mask, (w // 2, h // 2), axes, float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
    elif kind == "polygon":
        mask = np.zeros(hw, np.float32)
        angles = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(3, 8))))
        radius = rng.uniform(0.3, 0.5, angles.size)
        pts = np.stack([w / 2 + radius * w * np.cos(angles), h / 2 + radius * h * np.sin(angles)],
                       axis=1)
        cv2.fillPoly(mask, [np.round(pts).astype(np.int32)], 1.0)
    else:  # thresholded smooth noise: holes and islands
        mask = (smooth_texture(int(rng.integers(1 << 30)), hw, sigma=h / 12) > 0.5)
        mask = mask.astype(np.float32)
    return np.clip(cv2.GaussianBlur(mask, (0, 0), 1.0), 0.0, 1.0).astype(np.float32)


def random_objects(rng: np.random.Generator, count: int) -> tuple[list[ObjectPatch], list[Pose]]:
    """``count`` overlapping objects in front of the background at z in [0.15, 0.75]; the
    first is tilted by ~0.7 rad, the second straddles the edge of the view."""
    kinds = ("ellipse", "polygon", "noise")
    objects, poses = [], []
    for k in range(count):
        hw = (int(rng.integers(24, 160)), int(rng.integers(24, 160)))
        size = rng.uniform(0.2, 0.55, 2)
        surface = PlanarScene(smooth_texture(int(rng.integers(1 << 30)), hw, sigma=2.0),
                              float(size[0]), float(size[1]))
        tilt = rng.normal(0.0, 1.0, 3)
        tilt *= (0.7 if k == 0 else rng.uniform(0.0, 0.4)) / np.linalg.norm(tilt)
        centre = np.array([*rng.uniform(-0.35, 0.35, 2), rng.uniform(0.15, 0.75)])
        if k == 1:  # on the right edge of the view at its depth (half-angle ~30 degrees)
            centre[:2] = [0.03 + 0.57 * (1.0 - centre[2]), -0.1]
        pose = Pose(so3_exp(tilt), centre)
        alpha = alpha_shape(kinds[k % 3], hw, rng)
        objects.append(ObjectPatch(surface, alpha, still(pose), f"object{k}"))
        poses.append(pose)
    return objects, poses


def renderers(scene: DynamicScene, cam: Intrinsics, s: int, **kwargs):
    return (MitsubaRenderer({"lr": scene}, {"lr": cam}, {"lr": s}, **kwargs),
            ReferenceRenderer({"lr": scene}, {"lr": cam}, {"lr": s}))


@pytest.fixture(scope="module")
def background() -> PlanarScene:
    return PlanarScene(smooth_texture(7, (512, 512), sigma=2.0), 3.0, 3.0)


@pytest.mark.parametrize(("size", "s", "seed"), [(128, 3, 0), (128, 3, 1), (512, 2, 2)])
def test_mitsuba_matches_the_reference_on_random_dynamic_scenes(background, size, s, seed):
    rng = np.random.default_rng(seed)
    objects, poses = random_objects(rng, int(rng.integers(3, 9)))
    scene = DynamicScene(background, tuple(objects))
    cam = Intrinsics(size * 0.87, size * 0.87, size / 2 - 0.5 + size / 40,
                     size / 2 - 0.5 - size / 25, size, size)
    mitsuba, reference = renderers(scene, cam, s)
    assert mitsuba.variant != "scalar_rgb"
    img = mitsuba.render("lr", camera_pose(), poses)
    exact = reference.render("lr", camera_pose(), poses)
    bare = ReferenceRenderer({"lr": DynamicScene(background)}, {"lr": cam}, {"lr": s}).render(
        "lr", camera_pose())
    assert img.shape == (size, size) and img.dtype == np.float32
    assert np.mean(np.abs(exact - bare) > 0.02) > 0.15  # the objects cover much of the view
    edge = trace(DynamicScene(background, (objects[1],)), camera_pose(), (poses[1],),
                 cam.pixel_rays()).ids == 1
    assert 0 < edge.mean() < 0.5 and edge[:, -1].any()  # partly outside the view
    assert psnr(img, exact) >= 40.0
    mitsuba.close()


@pytest.mark.parametrize(("size", "s", "seed"), [(128, 4, 0), (128, 3, 1), (96, 2, 2)])
def test_homography_backend_matches_the_reference_on_random_dynamic_scenes(background, size,
                                                                           s, seed):
    """The warped background with objects ray cast only inside their boxes: the exact
    renderer's image, and the plane path's bit for bit where the objects are not."""
    rng = np.random.default_rng(seed)
    objects, poses = random_objects(rng, int(rng.integers(3, 9)))
    scene = DynamicScene(background, tuple(objects))
    cam = Intrinsics(size * 0.87, size * 0.87, size / 2 - 0.5 + size / 40,
                     size / 2 - 0.5 - size / 25, size, size)
    config = RenderConfig(backend="homography", supersample_lr=s)
    img = make_renderer(scene, {"lr": cam}, config).render("lr", camera_pose(), poses)
    exact = ReferenceRenderer({"lr": scene}, {"lr": cam}, {"lr": s}).render(
        "lr", camera_pose(), poses)
    bare = make_renderer(background, {"lr": cam}, config).render("lr", camera_pose())
    assert img.shape == (size, size) and img.dtype == np.float32
    assert np.mean(np.abs(exact - bare) > 0.02) > 0.15  # the objects cover much of the view
    assert psnr(img, exact) >= 50.0
    ids = trace(scene, camera_pose(), tuple(poses), cam.scaled(s).pixel_rays()).ids
    clear = ids.reshape(size, s, size, s).max(axis=(1, 3)) == 0
    np.testing.assert_array_equal(img[clear], bare[clear])


def test_dynamic_scene_without_objects_renders_the_plane_path_bit_for_bit(background):
    cam = Intrinsics.from_fov(96, 80, 60.0)
    alone = MitsubaRenderer({"lr": background}, {"lr": cam}, {"lr": 3})
    dynamic = MitsubaRenderer({"lr": DynamicScene(background)}, {"lr": cam}, {"lr": 3})
    np.testing.assert_array_equal(dynamic.render("lr", camera_pose()),
                                  alone.render("lr", camera_pose()))


def test_an_object_covering_the_view_shows_only_its_texture(background):
    """A 4 m opaque tilted board 0.5 m below the camera: the image is that board seen as a
    plane by the exact homography backend, and nothing of the background."""
    cam = Intrinsics.from_fov(64, 48, 60.0)
    tex = smooth_texture(3, (256, 256), sigma=2.0)
    board = PlanarScene(tex, 4.0, 4.0)
    pose = Pose(so3_exp(np.array([0.3, -0.2, 0.5])), np.array([0.05, 0.0, 0.5]))
    obj = ObjectPatch(board, np.ones(tex.shape, np.float32), still(pose))
    mitsuba = MitsubaRenderer({"lr": DynamicScene(background, (obj,))}, {"lr": cam}, {"lr": 3})
    img = mitsuba.render("lr", camera_pose(), [pose])
    seen = relative_pose(camera_pose(), pose)  # the camera in the board's frame
    assert board.covers_view(cam, seen)
    exact = make_renderer(board, {"lr": cam}, RenderConfig(backend="homography")).render(
        "lr", seen)
    assert psnr(img, exact) >= 50.0
    bare = mitsuba_background(background, cam)
    assert psnr(img, bare) < 25.0


def mitsuba_background(background: PlanarScene, cam: Intrinsics, s: int = 3) -> np.ndarray:
    return MitsubaRenderer({"lr": background}, {"lr": cam}, {"lr": s}).render("lr", camera_pose())


def test_an_object_with_zero_alpha_is_invisible(background):
    cam = Intrinsics.from_fov(64, 48, 60.0)
    tex = np.ones((32, 32), np.float32)
    pose = Pose(np.eye(3), np.array([0.0, 0.0, 0.5]))
    obj = ObjectPatch(PlanarScene(tex, 2.0, 2.0), np.zeros_like(tex), still(pose))
    mitsuba = MitsubaRenderer({"lr": DynamicScene(background, (obj,))}, {"lr": cam}, {"lr": 3})
    np.testing.assert_array_equal(mitsuba.render("lr", camera_pose(), [pose]),
                                  mitsuba_background(background, cam))


def flat_square(value: float, side_m: float, z_m: float) -> tuple[ObjectPatch, Pose]:
    tex = np.full((8, 8), value, np.float32)
    pose = Pose(np.eye(3), np.array([0.0, 0.0, z_m]))
    return ObjectPatch(PlanarScene(tex, side_m, side_m), np.ones_like(tex), still(pose)), pose


@pytest.mark.parametrize("small_in_front", [True, False])
def test_the_nearer_of_two_overlapping_objects_wins(background, small_in_front):
    """A small square over the middle of a larger one: the middle shows the small one when
    it is nearer and the large one when that is nearer, whatever the objects' order."""
    cam = Intrinsics.from_fov(64, 64, 60.0)
    z_small, z_large = (0.6, 0.3) if small_in_front else (0.3, 0.6)
    small, large = flat_square(0.9, 0.1, z_small), flat_square(0.2, 0.4, z_large)
    looking = Pose(LOOK_DOWN, np.array([0.0, 0.0, 1.0]))
    images = []
    for pair in ((small, large), (large, small)):
        scene = DynamicScene(background, tuple(obj for obj, _ in pair))
        mitsuba = MitsubaRenderer({"lr": scene}, {"lr": cam}, {"lr": 3})
        images.append(mitsuba.render("lr", looking, [pose for _, pose in pair]))
    np.testing.assert_array_equal(images[0], images[1])
    # in pixels: the small square spans 25-39 or 28-36, the large one 16-48 or 4-60
    middle, ring = images[0][30:34, 30:34], images[0][30:34, 18:21]
    np.testing.assert_allclose(middle, 0.9 if small_in_front else 0.2, atol=1e-6)
    np.testing.assert_allclose(ring, 0.2, atol=1e-6)
    assert np.abs(images[0][:3, :3] - 0.2).min() > 1e-3  # the corners: background


def test_dynamic_renders_are_the_same_bits_whatever_the_thread_count(background):
    """Moving objects rendered twice with drjit's default threads and once each with one
    and two threads: bit for bit equal."""
    import drjit as dr

    rng = np.random.default_rng(5)
    objects, poses = random_objects(rng, 6)
    scene = DynamicScene(background, tuple(objects))
    cam = Intrinsics(110.0, 110.0, 63.5, 63.5, 128, 128)
    step = Pose(so3_exp(np.array([0.0, 0.0, 0.02])), np.array([0.004, -0.003, 0.002]))
    frames = [[Pose(p.r_wc @ np.linalg.matrix_power(step.r_wc, k), p.t_wc + k * step.t_wc)
               for p in poses] for k in range(8)]
    before = dr.thread_count()
    images = []
    try:
        for threads in (None, 1, 2, None):
            if threads is not None:
                dr.set_thread_count(threads)
            r = MitsubaRenderer({"lr": scene}, {"lr": cam}, {"lr": 3})
            images.append(np.stack([r.render("lr", camera_pose(), f) for f in frames]))
            r.close()
            dr.set_thread_count(before)
    finally:
        dr.set_thread_count(before)
    assert np.abs(np.diff(images[0], axis=0)).max() > 0.1  # the objects do move
    for other in images[1:]:
        np.testing.assert_array_equal(images[0], other)


def test_scalar_variant_renders_objects_too(background):
    rng = np.random.default_rng(3)
    objects, poses = random_objects(rng, 4)
    scene = DynamicScene(background, tuple(objects))
    cam = Intrinsics.from_fov(48, 40, 60.0)
    scalar, reference = renderers(scene, cam, 2, variant="scalar_rgb")
    exact = reference.render("lr", camera_pose(), poses)
    assert psnr(scalar.render("lr", camera_pose(), poses), exact) >= 40.0


def test_object_poses_must_match_the_objects(background):
    obj, pose = flat_square(0.5, 0.2, 0.5)
    cam = Intrinsics.from_fov(32, 32, 60.0)
    mitsuba = MitsubaRenderer({"lr": DynamicScene(background, (obj,))}, {"lr": cam}, {"lr": 1})
    with pytest.raises(ValueError, match="1 objects, render.. got 0"):
        mitsuba.render("lr", camera_pose())


@pytest.mark.parametrize(("size", "s", "seed"), [(64, 3, 0), (96, 2, 1), (128, 1, 4)])
def test_compiled_reference_equals_the_numpy_oracle(background, size, s, seed):
    """The compiled reference (bounding-box culling, threads) against trace + shade on every
    sample ray: the same float64 arithmetic, so the same image to float32 rounding; also
    with an object so close and tilted that part of it is behind the camera (no box)."""
    rng = np.random.default_rng(seed)
    objects, poses = random_objects(rng, int(rng.integers(3, 9)))
    near = Pose(so3_exp(np.array([1.3, 0.0, 0.2])), camera_pose().t_wc + [0.0, 0.05, -0.05])
    big = PlanarScene(smooth_texture(9, (64, 64), sigma=2.0), 0.6, 0.6)
    objects.append(ObjectPatch(big, np.ones((64, 64), np.float32), still(near), "near"))
    poses.append(near)
    cam = Intrinsics.from_fov(size, size * 3 // 4, 60.0)
    ref = ReferenceRenderer({"lr": DynamicScene(background, tuple(objects))}, {"lr": cam},
                            {"lr": s})
    for k in range(2):
        moved = [Pose(p.r_wc, p.t_wc + k * np.array([0.01, -0.02, 0.0])) for p in poses]
        fast = ref.render("lr", camera_pose(), moved)
        slow = ref.render_numpy("lr", camera_pose(), moved)
        np.testing.assert_allclose(fast, slow, rtol=0, atol=2e-7)
    hits = trace(DynamicScene(background, tuple(objects)), camera_pose(), tuple(poses),
                 cam.pixel_rays())
    assert (hits.ids == len(objects)).any()  # the near object is seen


def test_reference_refuses_a_view_past_the_background(background):
    cam = Intrinsics.from_fov(32, 32, 60.0)
    ref = ReferenceRenderer({"lr": DynamicScene(background)}, {"lr": cam}, {"lr": 1})
    sideways = Pose(so3_exp(np.array([1.5, 0.0, 0.0])) @ LOOK_DOWN, np.array([0.0, 0.0, 1.0]))
    for render in (ref.render, ref.render_numpy):
        with pytest.raises(ValueError, match="sees past the background"):
            render("lr", sideways)


def test_compiled_reference_is_the_same_whatever_the_threads(background):
    rng = np.random.default_rng(6)
    objects, poses = random_objects(rng, 5)
    scene = DynamicScene(background, tuple(objects))
    cam = Intrinsics.from_fov(80, 60, 60.0)
    images = [ReferenceRenderer({"lr": scene}, {"lr": cam}, {"lr": 3}, threads=t).render(
        "lr", camera_pose(), poses) for t in (None, 1, 2)]
    for other in images[1:]:
        np.testing.assert_array_equal(images[0], other)


@pytest.mark.parametrize("seed", range(4))
def test_sample_boxes_equal_sample_box_for_each_object(background, seed):
    """The compiled boxes of all objects at once against :func:`sample_box` per object, on
    random scenes plus an object partly behind the camera (whole grid) and one wholly
    behind it (empty box)."""
    rng = np.random.default_rng(seed)
    objects, poses = random_objects(rng, int(rng.integers(3, 9)))
    flip = so3_exp(np.array([np.pi, 0.0, 0.0]))
    near = Pose(so3_exp(np.array([1.3, 0.0, 0.2])), camera_pose().t_wc + [0.0, 0.05, -0.05])
    behind = Pose(flip, camera_pose().t_wc + camera_pose().r_wc @ np.array([0.0, 0.0, -0.5]))
    for pose in (near, behind):
        objects.append(ObjectPatch(PlanarScene(np.ones((8, 8), np.float32), 0.6, 0.6),
                                   np.ones((8, 8), np.float32), still(pose)))
        poses.append(pose)
    scene = DynamicScene(background, tuple(objects))
    fine = Intrinsics.from_fov(96, 80, 60.0).scaled(3)
    r_wo, t_wo = object_frames(scene, tuple(poses))
    boxes = sample_boxes(fine, camera_pose(), r_wo, t_wo, scene.packed.geom)
    expected = [sample_box(fine, camera_pose(), p, g[0], g[1])
                for p, g in zip(poses, scene.packed.geom)]
    np.testing.assert_array_equal(boxes, np.array(expected, np.int64))
    assert tuple(expected[-2]) == (0, fine.width, 0, fine.height)
    assert tuple(expected[-1]) == (0, 0, 0, 0)


def test_homography_backend_reuses_the_background_only_while_the_camera_stays(background):
    """A static camera's background warp is kept between renders: each render equals a
    fresh renderer's, whether the objects moved, the camera moved, or it came back."""
    rng = np.random.default_rng(7)
    objects, poses = random_objects(rng, 4)
    scene = DynamicScene(background, tuple(objects))
    cam = Intrinsics.from_fov(80, 64, 60.0)
    config = RenderConfig(backend="homography", supersample_lr=3)
    kept = make_renderer(scene, {"lr": cam}, config)
    moved = [Pose(p.r_wc, p.t_wc + np.array([0.03, -0.02, 0.0])) for p in poses]
    other = Pose(camera_pose().r_wc, camera_pose().t_wc + np.array([0.05, 0.0, 0.0]))
    images = []
    for pose, objs in ((camera_pose(), poses), (camera_pose(), moved), (other, poses),
                       (camera_pose(), poses), (camera_pose(), moved), (camera_pose(), poses)):
        img = kept.render("lr", pose, objs)
        fresh = make_renderer(scene, {"lr": cam}, config).render("lr", pose, objs)
        np.testing.assert_array_equal(img, fresh)
        images.append(img)
    assert not np.array_equal(images[0], images[1])
    assert not np.array_equal(images[0], images[2])
    np.testing.assert_array_equal(images[0], images[3])
    np.testing.assert_array_equal(images[0], images[5])  # drawn over the kept warp's copy
