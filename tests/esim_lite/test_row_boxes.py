"""Per-row narrowing of the objects' boxes (the homography renderer's and the truth
kernel's ray culling): conservative against the numpy tracer, and a renderer drawing
through it draws exactly what it draws testing whole boxes."""

from __future__ import annotations

import numpy as np
import pytest

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.objects import (
    ALPHA_CUTOFF,
    SUPPORT_REACH,
    DynamicScene,
    ObjectPatch,
    support_halfplanes,
)
from esim_lite.geometry.pose import Pose
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.visibility import (
    bilinear,
    camera_in_objects,
    object_frames,
    row_boxes,
    sample_boxes,
    trace,
)
from esim_lite.render.homography import _overlay_kernel
from tests.conftest import smooth_texture
from tests.esim_lite.test_render_dynamic import (
    alpha_shape,
    camera_pose,
    random_objects,
    still,
)


@pytest.fixture(scope="module")
def background() -> PlanarScene:
    return PlanarScene(smooth_texture(3, (256, 256), sigma=2.0), 3.0, 3.0)


@pytest.mark.parametrize("kind", ["ellipse", "polygon", "noise", "full"])
def test_support_halfplanes_hold_every_solid_point_with_margin(kind):
    """Every point of the patch whose bilinear alpha passes the cutoff lies inside every
    half-plane, at least half a texel from its edge (the margin rounding cannot eat)."""
    rng = np.random.default_rng(5)
    hw = (37, 61)
    alpha = np.ones(hw, np.float32) if kind == "full" else alpha_shape(kind, hw, rng)
    surface = PlanarScene(np.zeros(hw, np.float32), 0.5, 0.3)
    m = surface.texture_from_plane()
    planes = support_halfplanes(alpha, m)
    assert len(planes) >= 3
    np.testing.assert_allclose(np.hypot(planes[:, 0], planes[:, 1]), 1.0)
    x = rng.uniform(-0.25, 0.25, 200_000)
    y = rng.uniform(-0.15, 0.15, 200_000)
    solid = bilinear(alpha, m[0, 0] * x + m[0, 2], m[1, 1] * y + m[1, 2]) >= ALPHA_CUTOFF
    assert solid.sum() > 1000
    slack = planes[:, 2][None] - (x[solid, None] * planes[:, 0] + y[solid, None] * planes[:, 1])
    texel = min(0.5 / hw[1], 0.3 / hw[0])
    assert slack.min() >= (SUPPORT_REACH - 1.0) * texel * 0.999
    if kind == "ellipse":  # and it is tighter than the patch: its corners lie outside
        corners = np.array([[0.25, 0.15], [-0.25, 0.15], [0.25, -0.15], [-0.25, -0.15]])
        outside = (corners @ planes[:, :2].T > planes[:, 2]).any(axis=1)
        assert outside.all()


def test_an_object_with_no_solid_texel_has_no_half_planes_and_no_samples(background):
    pose = Pose(np.eye(3), np.array([0.0, 0.0, 0.5]))
    obj = ObjectPatch(PlanarScene(np.ones((8, 8), np.float32), 0.4, 0.4),
                      np.zeros((8, 8), np.float32), still(pose))
    scene = DynamicScene(background, (obj,))
    assert scene.packed.hull_sizes.tolist() == [0]
    fine = Intrinsics.from_fov(64, 48, 60.0)
    rows = _narrowed(scene, fine, camera_pose(), (pose,))
    assert (rows[..., 1] <= rows[..., 0]).all()


def _narrowed(scene: DynamicScene, fine: Intrinsics, camera: Pose,
              poses: tuple[Pose, ...]) -> np.ndarray:
    """int64[H, K, 4]: :func:`row_boxes` of every row."""
    packed = scene.packed
    r_wo, t_wo = object_frames(scene, poses)
    boxes = sample_boxes(fine, camera, r_wo, t_wo, packed.geom)
    r_wc = np.ascontiguousarray(camera.r_wc, np.float64)
    origin = camera_in_objects(np.ascontiguousarray(camera.t_wc, np.float64), r_wo, t_wo)
    out = np.zeros((fine.height, len(poses), 4), np.int64)
    for y in range(fine.height):
        row_boxes(y, fine.fx, fine.fy, fine.cx, fine.cy, r_wc, origin, r_wo, boxes,
                  packed.hulls, packed.hull_sizes, out[y])
    return out


@pytest.mark.parametrize("seed", range(3))
def test_row_boxes_hold_every_sample_that_sees_the_object(background, seed):
    """Each object traced alone by the numpy tracer (so occluded parts count too): every
    sample that sees it lies in its narrowed box of that row, and the narrowed boxes hold
    fewer samples than the whole boxes."""
    rng = np.random.default_rng(seed)
    objects, poses = random_objects(rng, 5)
    scene = DynamicScene(background, tuple(objects))
    fine = Intrinsics.from_fov(96, 80, 60.0).scaled(3)
    rows = _narrowed(scene, fine, camera_pose(), tuple(poses))
    ys, xs = np.mgrid[0:fine.height, 0:fine.width]
    rays = np.stack([(xs - fine.cx) / fine.fx, (ys - fine.cy) / fine.fy,
                     np.ones(xs.shape)], axis=-1)
    narrowed = whole = visible = 0
    r_wo, t_wo = object_frames(scene, tuple(poses))
    boxes = sample_boxes(fine, camera_pose(), r_wo, t_wo, scene.packed.geom)
    for j, (obj, pose) in enumerate(zip(objects, poses)):
        seen = trace(DynamicScene(background, (obj,)), camera_pose(), (pose,), rays).ids == 1
        visible += int(seen.any())
        box = rows[:, j]
        inside = (xs >= box[:, None, 0]) & (xs < box[:, None, 1])
        assert not (seen & ~inside).any(), f"object {j}: a sample that sees it was culled"
        narrowed += int(inside.sum())
        whole += max(boxes[j, 1] - boxes[j, 0], 0) * max(boxes[j, 3] - boxes[j, 2], 0)
    assert visible >= 3
    assert narrowed < 0.9 * whole


@pytest.mark.parametrize("seed", range(3))
def test_overlay_through_narrowed_boxes_equals_whole_boxes(background, seed):
    """The overlay kernel with the objects' half-planes and with a half-plane that holds
    everywhere (whole boxes, only the in-front test): the same bits."""
    rng = np.random.default_rng(10 + seed)
    objects, poses = random_objects(rng, 6)
    scene = DynamicScene(background, tuple(objects))
    fine = Intrinsics.from_fov(96, 80, 60.0).scaled(4)
    packed = scene.packed
    camera = camera_pose()
    r_wo, t_wo = object_frames(scene, tuple(poses))
    boxes = sample_boxes(fine, camera, r_wo, t_wo, packed.geom)
    anywhere = np.tile(np.array([[[0.0, 0.0, 1.0]]]), (len(objects), 1, 1))
    images = []
    for hulls, sizes in ((packed.hulls, packed.hull_sizes),
                         (anywhere, np.ones(len(objects), np.int64))):
        img = np.full((fine.height, fine.width), 0.25, np.float32)
        _overlay_kernel(img, fine.fx, fine.fy, fine.cx, fine.cy,
                        np.ascontiguousarray(camera.r_wc, np.float64),
                        np.ascontiguousarray(camera.t_wc, np.float64), r_wo, t_wo,
                        packed.geom, packed.shapes, packed.alphas, packed.texels, boxes,
                        ALPHA_CUTOFF, hulls, sizes)
        images.append(img)
    assert (images[0] != 0.25).mean() > 0.05
    np.testing.assert_array_equal(images[0], images[1])
