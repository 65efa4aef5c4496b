"""Dynamic scenes: the drawn objects, their exact flow / depth / ids, the sampler's bound with
moving occlusion boundaries, static cameras, determinism and bad configurations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import binary_dilation

from datagen.config import DatagenConfig
from datagen.sampling import sample_sequence
from datagen.textures import TextureSampler, flat_background
from esim_lite.config import CameraConfig, SimulationConfig
from esim_lite.core.dataconf import ConfigError, from_mapping, load_config
from esim_lite.core.events import Events
from esim_lite.events.sampling import (
    BAND_PX,
    SamplingConfig,
    boundary_band,
    dynamic_bounds,
    edge_speed,
    log_change_rate_bound,
)
from esim_lite.events.simulator import EventSimulator
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.object_sampling import ObjectsConfig, static_trajectory
from esim_lite.geometry.objects import DynamicScene, ObjectPatch
from esim_lite.geometry.pose import Pose, so3_exp
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import LOOK_DOWN, BSplineTrajectory
from esim_lite.geometry.visibility import surface_truth, surface_truth_reference
from esim_lite.render.renderer import RenderConfig
from esim_lite.sequence import simulate
from tests.conftest import smooth_texture

ROOT = Path(__file__).resolve().parents[2]
DYNAMIC = ROOT / "configs" / "datagen_dynamic.yaml"


def dynamic_config(**overrides) -> DatagenConfig:
    """The shipped dynamic recipe at a small camera (objects as drawn for training)."""
    sets = {"simulation.camera.width": 64, "simulation.camera.height": 48,
            "simulation.render.backend": "reference", **overrides}
    return load_config(DatagenConfig, DYNAMIC, [f"{k}={v}" for k, v in sets.items()])


@pytest.fixture(scope="module")
def specs():
    cfg = dynamic_config(**{"simulation.objects.count": "[3, 6]",
                            "simulation.objects.static_camera_share": 0.5})
    sampler = TextureSampler(cfg.textures)
    return cfg, [sample_sequence(cfg.simulation, sampler, 11, i) for i in range(6)]


def test_drawn_sequences_have_objects_and_some_static_cameras(specs):
    cfg, seqs = specs
    assert all(3 <= len(s.objects) <= 6 for s in seqs)
    assert any(s.static_camera for s in seqs) and not all(s.static_camera for s in seqs)
    for s in seqs:
        if s.static_camera:
            p0, p1 = s.trajectory.pose(0.0), s.trajectory.pose(cfg.simulation.duration_s)
            np.testing.assert_allclose(p1.t_wc, p0.t_wc, atol=1e-12)
        assert all(o.name for o in s.objects)  # texture provenance


def test_same_seed_same_objects_and_object_free_configs_draw_as_before(specs):
    cfg, seqs = specs
    again = sample_sequence(cfg.simulation, TextureSampler(cfg.textures), 11, 2)
    for a, b in zip(seqs[2].objects, again.objects):
        np.testing.assert_array_equal(a.alpha, b.alpha)
        np.testing.assert_array_equal(a.surface.texture, b.surface.texture)
        np.testing.assert_array_equal(a.pose(0.3).t_wc, b.pose(0.3).t_wc)
    # turning objects on leaves the camera, texture and thresholds of moving-camera draws
    plain = DatagenConfig()
    tex = TextureSampler(plain.textures)
    sim = from_mapping(DatagenConfig, {"simulation": {"objects": {"count": [2, 2]}}}).simulation
    for i in range(3):
        a, b = sample_sequence(plain.simulation, tex, 4, i), sample_sequence(sim, tex, 4, i)
        np.testing.assert_array_equal(a.thresholds.pos, b.thresholds.pos)
        if not b.static_camera:  # a static camera needs a smaller plane
            np.testing.assert_array_equal(a.background.texture, b.background.texture)
            np.testing.assert_array_equal(a.trajectory.pose(0.2).r_wc,
                                          b.trajectory.pose(0.2).r_wc)


def test_flat_backgrounds_replace_only_static_camera_textures(specs):
    cfg, seqs = specs
    flat = dynamic_config(**{"simulation.objects.count": "[3, 6]",
                             "simulation.objects.static_camera_share": 0.5,
                             "simulation.objects.flat_background_share": 1.0})
    sampler = TextureSampler(flat.textures)
    for i, a in enumerate(seqs):
        b = sample_sequence(flat.simulation, sampler, 11, i)
        assert b.static_camera == a.static_camera
        np.testing.assert_array_equal(b.thresholds.pos, a.thresholds.pos)
        np.testing.assert_array_equal(b.trajectory.pose(0.3).t_wc, a.trajectory.pose(0.3).t_wc)
        for oa, ob in zip(a.objects, b.objects, strict=True):  # objects keep their textures
            np.testing.assert_array_equal(oa.surface.texture, ob.surface.texture)
        tex = b.background.texture
        assert tex.shape == a.background.texture.shape
        if not a.static_camera:  # a moving camera keeps its textured plane
            np.testing.assert_array_equal(tex, a.background.texture)
            continue
        assert b.texture_name == "flat background"
        # one level under a gentle field: within +-40% of its median, no texel-scale detail
        med = float(np.median(tex))
        assert tex.min() > 0.6 * med and tex.max() < 1.4 * med
        step = max(np.abs(np.diff(tex, axis=0)).max(), np.abs(np.diff(tex, axis=1)).max())
        assert step < 0.01 * med * 100 / min(tex.shape)
        tex_a = a.background.texture
        assert np.abs(np.diff(tex_a, axis=1)).mean() > 10 * np.abs(np.diff(tex, axis=1)).mean()


def test_flat_background_levels_span_the_range_and_repeat_with_the_seed():
    draws = [flat_background((40, 60), np.random.default_rng(s)) for s in range(200)]
    medians = np.array([np.median(d) for d in draws])
    assert medians.min() < 0.1 and medians.max() > 0.6  # dark and bright backgrounds
    np.testing.assert_array_equal(flat_background((40, 60), np.random.default_rng(3)), draws[3])
    assert all(d.dtype == np.float32 and 0 < d.min() and d.max() <= 1 for d in draws)
    with pytest.raises(ValueError, match="level_range"):
        flat_background((4, 4), np.random.default_rng(0), (0.5, 0.2))


def test_compiled_truth_equals_the_numpy_oracle(specs):
    cfg, seqs = specs
    rig = cfg.simulation.camera.rig()
    for s in seqs[:4]:
        for t in (0.0, 0.17):
            pose, tw = s.trajectory.pose_and_twist(t)
            poses, tws = s.scene.object_motion(t)
            for cam in rig.cameras().values():
                a = surface_truth(s.scene, cam, pose, tw, poses, tws)
                b = surface_truth_reference(s.scene, cam, pose, tw, poses, tws)
                np.testing.assert_array_equal(a.ids, b.ids)
                np.testing.assert_allclose(a.depth, b.depth, rtol=1e-6)
                np.testing.assert_allclose(a.flow, b.flow, rtol=1e-5, atol=1e-3)


def project(cam: Intrinsics, pose: Pose, points_w: np.ndarray) -> np.ndarray:
    x_c = (points_w - pose.t_wc) @ pose.r_wc
    return np.stack([cam.fx * x_c[:, 0] / x_c[:, 2] + cam.cx,
                     cam.fy * x_c[:, 1] / x_c[:, 2] + cam.cy], axis=1)


def test_flow_is_the_motion_of_projected_points_and_depth_the_plane_equation(specs):
    """Each visible point is followed on its own surface: its world point at ``t``, carried by
    its object's pose (fixed on the background) to ``t +- h`` and projected by the camera
    there; the central difference is the flow. The depth is the ray's hit with the plane of
    the surface the ids name."""
    cfg, seqs = specs
    cam = cfg.simulation.camera.rig().event
    h, t = 1e-5, 0.21
    rays = cam.pixel_rays().reshape(-1, 3)
    checked = 0
    for s in seqs[:4]:
        pose, tw = s.trajectory.pose_and_twist(t)
        poses, tws = s.scene.object_motion(t)
        gt = surface_truth(s.scene, cam, pose, tw, poses, tws)
        ids, depth = gt.ids.ravel(), gt.depth.ravel().astype(np.float64)
        d_w = rays @ pose.r_wc.T
        points = pose.t_wc + depth[:, None] * d_w  # ray z = 1: parameter = depth
        for k in np.unique(ids):
            sel = ids == k
            if k == 0:  # background z = 0
                plane_depth = -pose.t_wc[2] / d_w[sel, 2]
                local = [points[sel]] * 2
                cams = [s.trajectory.pose(t + h), s.trajectory.pose(t - h)]
            else:
                obj = s.objects[k - 1]
                o = poses[k - 1]
                n = o.r_wc[:, 2]
                plane_depth = (n @ (o.t_wc - pose.t_wc)) / (d_w[sel] @ n)
                x_o = (points[sel] - o.t_wc) @ o.r_wc
                local = [x_o @ obj.pose(t + h).r_wc.T + obj.pose(t + h).t_wc,
                         x_o @ obj.pose(t - h).r_wc.T + obj.pose(t - h).t_wc]
                cams = [s.trajectory.pose(t + h), s.trajectory.pose(t - h)]
            np.testing.assert_allclose(depth[sel], plane_depth, rtol=1e-6)
            fd = (project(cam, cams[0], local[0]) - project(cam, cams[1], local[1])) / (2 * h)
            flow = gt.flow.reshape(2, -1)[:, sel].T
            np.testing.assert_allclose(flow, fd, atol=0.05 + 1e-4 * np.abs(fd).max())
            checked += int(sel.sum())
    assert checked == 4 * cam.width * cam.height


def test_a_static_camera_sees_zero_background_flow(specs):
    _, seqs = specs
    s = next(s for s in seqs if s.static_camera)
    cam = Intrinsics.from_fov(64, 48, 60.0)
    for t in (0.05, 0.3):
        pose, tw = s.trajectory.pose_and_twist(t)
        gt = surface_truth(s.scene, cam, pose, tw, *s.scene.object_motion(t))
        assert np.all(gt.flow[:, gt.ids == 0] == 0)
        moving = gt.ids > 0
        if moving.any():
            assert np.abs(gt.flow[:, moving]).max() > 1.0


def test_objects_keep_returning_to_the_view(specs):
    """Objects leave the view but their centres stay within ``view_margin`` of it."""
    cfg, seqs = specs
    cam = cfg.simulation.camera.rig().event
    m = cfg.simulation.objects.view_margin
    for s in seqs:
        for t in np.linspace(0, cfg.simulation.duration_s, 9):
            centres = np.array([p.t_wc for p in s.scene.object_poses(t)])
            uv = project(cam, s.trajectory.pose(t), centres)
            slack = 0.15  # the B-spline between folded control points
            assert np.all(uv[:, 0] > -(m + slack) * cam.width)
            assert np.all(uv[:, 0] < (1 + m + slack) * cam.width)
            assert np.all(uv[:, 1] > -(m + slack) * cam.height)
            assert np.all(uv[:, 1] < (1 + m + slack) * cam.height)


def fast_disc(speed_px_s: float, duration_s: float) -> tuple[DynamicScene, BSplineTrajectory,
                                                                Intrinsics]:
    """A small bright textured disc 0.5 m in front of a static camera, crossing a dark
    textured background (1 m away) at ``speed_px_s``."""
    cam = Intrinsics.from_fov(48, 32, 60.0)
    cam_pose = Pose(LOOK_DOWN, np.array([0.0, 0.0, 1.0]))
    background = PlanarScene(0.05 + 0.1 * smooth_texture(3, (256, 256), sigma=4.0), 2.0, 2.0)
    hw = (48, 48)
    yy, xx = np.mgrid[0:48, 0:48]
    alpha = (((xx - 23.5) ** 2 + (yy - 23.5) ** 2) <= 22**2).astype(np.float32)
    tex = 0.5 + 0.5 * smooth_texture(5, hw, sigma=2.0)
    size = 0.08  # ~9 px across at 0.5 m
    v = speed_px_s * 0.5 / cam.fx  # m/s at depth 0.5
    n = int(np.ceil(duration_s / 0.05)) + 3
    x0 = -0.5 * 0.5 * cam.width / cam.fx  # enters from the left edge
    times = (np.arange(n) - 1) * 0.05
    positions = np.stack([x0 + v * times, np.zeros(n), np.full(n, 0.5)], 1)
    rot = so3_exp(np.array([np.pi, 0.0, 0.0]))  # facing the camera
    traj = BSplineTrajectory(positions, np.repeat(rot[None], n, 0), 0.05, duration_s)
    obj = ObjectPatch(PlanarScene(tex.astype(np.float32), size, size), alpha, traj, "disc")
    return (DynamicScene(background, (obj,)),
            static_trajectory(cam_pose, duration_s, 0.05), cam)


def run_disc(sampling: SamplingConfig, duration_s: float = 0.03):
    """The disc at 1,500 px/s: the scene, its trajectory and camera, the log image before
    every step, the steps' (start, end) ns, and the events."""
    scene, traj, cam = fast_disc(1500.0, duration_s)
    cfg = SimulationConfig(duration_s=duration_s, sampling=sampling,
                           camera=CameraConfig(width=cam.width, height=cam.height,
                                               scales=(2,)),
                           render=RenderConfig(backend="reference"))
    th = ContrastThresholds.uniform(0.2, 0.2, cam.hw)
    logs, times = [], []
    original = EventSimulator.step_log

    def recording(sim, log_img, t_ns):
        logs.append(sim.log_prev.copy())
        times.append((sim.t_ns, t_ns))
        return original(sim, log_img, t_ns)

    EventSimulator.step_log = recording
    try:
        events = Events.concatenate([c.events for c in simulate(scene, traj, th, cfg,
                                                                  np.random.default_rng(0))],
                                    cam.hw)
    finally:
        EventSimulator.step_log = original
    return scene, traj, cam, logs, times, events


def per_pixel_times(ev: Events) -> dict[int, np.ndarray]:
    key = ev.y.astype(np.int64) * 100_000 + ev.x
    order = np.lexsort((ev.t_ns, key))
    keys, starts = np.unique(key[order], return_index=True)
    return dict(zip(keys.tolist(), np.split(ev.t_ns[order], starts[1:])))


def test_a_fast_small_object_keeps_the_per_step_bound_and_its_events():
    """A 9-pixel disc at 1,500 px/s over a static camera. Every step moves its edge at most
    ``max_edge_step_px`` and keeps the change off the boundary band within lambda C; against
    10 us fixed steps, the events are all there (2%) and a pixel's k-th event is on time to
    within the time the edge takes to move ``max_edge_step_px`` (95th percentile)."""
    adaptive = SamplingConfig()
    scene, traj, cam, logs, times, ev = run_disc(adaptive)
    *_, fine_times, ref = run_disc(SamplingConfig(adaptive=False, min_step_s=1e-5,
                                                  max_step_s=1e-5))
    assert len(times) < len(fine_times) / 10
    assert abs(len(ev) - len(ref)) <= 0.02 * len(ref)
    mine, theirs = per_pixel_times(ev), per_pixel_times(ref)
    errors = np.concatenate([np.abs(a[:len(b)] - b[:len(a)]) for k, a in mine.items()
                             if (b := theirs.get(k)) is not None])
    assert np.percentile(errors, 95) * 1e-9 <= adaptive.max_edge_step_px / 1500.0
    budget = adaptive.contrast_fraction * 0.2
    for k in range(len(logs) - 1):
        t0, t1 = times[k]
        dt = (t1 - t0) * 1e-9
        pose, tw = traj.pose_and_twist(t0 * 1e-9)
        gt = surface_truth(scene, cam, pose, tw, *scene.object_motion(t0 * 1e-9))
        edge_speed = np.hypot(*gt.flow[:, gt.ids > 0]).max() if (gt.ids > 0).any() else 0
        assert edge_speed * dt <= adaptive.max_edge_step_px * 1.01 or \
            dt <= adaptive.min_step_s * 1.01 or edge_speed == 0
        change = np.abs(logs[k + 1] - logs[k])
        change[boundary_band(gt.ids)] = 0
        assert change.max() <= budget * 1.0001 or dt <= adaptive.min_step_s * 1.01


def test_a_static_camera_fires_only_on_and_around_the_objects():
    scene, traj, cam = fast_disc(600.0, 0.05)
    cfg = SimulationConfig(duration_s=0.05, camera=CameraConfig(width=cam.width,
                                                                height=cam.height, scales=(2,)),
                           render=RenderConfig(backend="reference"))
    th = ContrastThresholds.uniform(0.2, 0.2, cam.hw)
    ev = [c.events for c in simulate(scene, traj, th, cfg, np.random.default_rng(0))]
    x = np.concatenate([e.x for e in ev])
    y = np.concatenate([e.y for e in ev])
    assert len(x) > 100
    covered = np.zeros(cam.hw, bool)
    for t in np.linspace(0, 0.05, 200):
        pose, tw = traj.pose_and_twist(t)
        covered |= surface_truth(scene, cam, pose, tw, *scene.object_motion(t)).ids > 0
    near = binary_dilation(covered, iterations=1)  # pixels the disc's edge touched
    assert near[y, x].all()
    assert near.mean() < 0.6  # the disc swept part of the view, not all of it


@pytest.mark.parametrize(("key", "value", "problem"), [
    ("simulation.objects.size_fraction", "[0.5, 1.5]", "larger than the view"),
    ("simulation.objects.depth_fraction", "[0.3, 1.2]", "between the camera"),
    ("simulation.objects.count", "[5, 2]", "objects.count"),
    ("simulation.objects.static_camera_share", "1.5", "static_camera_share"),
    ("simulation.objects.flat_background_share", "-0.1", "flat_background_share"),
    ("simulation.objects.shapes", "[circle]", "shapes"),
    ("simulation.sampling.max_edge_step_px", "0", "max_edge_step_px"),
])
def test_impossible_object_configs_fail_at_load_naming_the_key(key, value, problem):
    with pytest.raises(ConfigError) as err:
        load_config(DatagenConfig, DYNAMIC, [f"{key}={value}"])
    assert problem in str(err.value)
    assert key.rsplit(".", 1)[0] in str(err.value)


@pytest.mark.parametrize(("sets", "problem"), [
    (["simulation.objects.count=[0, 0]", "simulation.objects.static_camera_share=0.3"],
     "static camera would see nothing move"),
])
def test_contradicting_object_settings_fail_at_load(sets, problem):
    with pytest.raises(ConfigError) as err:
        load_config(DatagenConfig, DYNAMIC, sets)
    assert problem in str(err.value)
    assert "simulation" in str(err.value)


def test_the_dynamic_config_documents_every_objects_key():
    cfg = load_config(DatagenConfig, DYNAMIC)
    assert cfg.simulation.objects.enabled and cfg.simulation.render.backend == "mitsuba"
    assert set(cfg.simulation.frames.ground_truth) == {"flow", "depth", "ids"}
    text = DYNAMIC.read_text()
    for name in ObjectsConfig.__dataclass_fields__:
        assert f"    {name}:" in text, name


def test_compiled_sampler_bounds_equal_the_numpy_ones(specs):
    cfg, seqs = specs
    cam = cfg.simulation.camera.rig().event
    rng = np.random.default_rng(0)
    for s in seqs[:3]:
        pose, tw = s.trajectory.pose_and_twist(0.1)
        gt = surface_truth(s.scene, cam, pose, tw, *s.scene.object_motion(0.1))
        log_img = np.log(rng.uniform(0.01, 1, cam.hw)).astype(np.float32)
        rate, speed, band = dynamic_bounds(log_img, gt.flow, gt.ids, BAND_PX)
        flow = gt.flow.transpose(1, 2, 0).astype(np.float64)
        assert rate == pytest.approx(log_change_rate_bound(log_img, flow, gt.ids).max(),
                                     rel=1e-12)
        assert speed == pytest.approx(edge_speed(flow, gt.ids), rel=1e-6)
        np.testing.assert_array_equal(band, boundary_band(gt.ids, BAND_PX))
        # without the ids, the boundaries' contrast would count as a gradient
        assert log_change_rate_bound(log_img, flow).max() >= rate


def test_dynamic_datasets_are_the_same_whatever_the_workers(tmp_path):
    """Objects, static cameras and ground truth: one worker and two write the same bytes."""
    from datagen import generate as gen
    from datagen.shard import ShardReader

    cfg = dynamic_config(**{"simulation.camera.width": 32, "simulation.camera.height": 24,
                            "simulation.duration_s": 0.2, "simulation.frames.count": 2,
                            "simulation.frames.every_events": 300,
                            "simulation.frames.tail_events": 300,
                            "simulation.objects.count": "[1, 3]",
                            "simulation.objects.static_camera_share": 0.5,
                            "sequences_per_shard": 1})
    for workers, out in ((1, "one"), (2, "two")):
        gen.generate(cfg, tmp_path / out, n_seq=3, seed=2, workers=workers,
                     show_progress=False)
    seen = 0
    for path in sorted((tmp_path / "one").glob("shard_*.h5")):
        with ShardReader(path) as a, ShardReader(tmp_path / "two" / path.name) as b:
            for name in a.sequences():
                ra, rb = a.read(name), b.read(name)
                np.testing.assert_array_equal(ra.events.t_ns, rb.events.t_ns)
                np.testing.assert_array_equal(ra.events.x, rb.events.x)
                for cam in a.frame_names(name):
                    np.testing.assert_array_equal(a.flow(name, cam), b.flow(name, cam))
                    np.testing.assert_array_equal(a.ids(name, cam), b.ids(name, cam))
                    np.testing.assert_array_equal(ra.frames[cam].intensity,
                                                  rb.frames[cam].intensity)
                seen += a.num_objects(name)
    assert seen > 0
