"""Mitsuba 3 rendering of the planar scene and its moving objects; the only module that
imports mitsuba/drjit.

On the JIT variants (LLVM, CUDA) a camera is rendered as one wavefront of primary rays
(:class:`_RayCast`): a ray through the centre of every cell of the ``s x s`` sub-pixel grid
of :mod:`esim_lite.render.homography`, intersected with the plane by Mitsuba's rectangle
shape, turned into a surface interaction by it, and shaded by the plane's diffuse BSDF; a
second kernel averages the ``s x s`` samples of every camera pixel. The plane is diffuse
under a constant unit environment, so its radiance is its albedo in every direction:
exactly what Mitsuba's ``direct`` integrator returns with one BSDF sample (the scalar path
below), without the sampler, film, emitter query and scattered accumulation around it
(docs/benchmarks.md compares the two paths' time per frame). Both kernels are recorded once with
``drjit.freeze`` and replayed for every pose. Noise-free and bit-exact by construction:
- the texture is loaded raw (linear values, no sRGB decoding), bilinear, ``clamp`` wrap;
- each ray is one lane and each pixel's sum one lane of the second kernel (float64, a
  fixed order); nothing is accumulated across lanes, so the LLVM backend's split of a
  launch into blocks of 16,384 items (sums across lanes that straddle two blocks are added
  in thread-timing order) cannot change a bit: renders are the same with any thread count.

Objects (:class:`DynamicScene`): the same wavefront also meets every object, in the ray
kernel itself rather than as Mitsuba shapes. The camera's pose in each object's frame is 12
more opaque kernel inputs per object (computed in float64 on the host), so a new object pose
is a replay of the same frozen kernels: no ``mi.traverse``/``params.update`` of shape
transforms, no acceleration structure to rebuild, no re-tracing. Per object and lane: the ray
meets the object's plane ``z = 0`` at camera depth ``lam``; it counts where
``0 < lam < depth so far``, inside the patch and where the bilinear alpha (a drjit
``Texture2f`` holding texture and alpha as two channels, ``clamp``, texel centres as
:class:`PlanarScene`'s) passes :data:`ALPHA_CUTOFF`; then it replaces depth and value (the
texture channel). Objects are tested in scene order and win only when strictly nearer, as in
:func:`esim_lite.geometry.visibility.trace`. The background is hit and shaded by Mitsuba's
rectangle and BSDF exactly as without objects, and a scene without objects runs the
plane-only kernel unchanged.

Scalar variants (the fallback when drjit's LLVM is unusable) render the same scene with
``mi.render``: an ``s``-times larger film with one centred sample per film pixel and the
``direct`` integrator sampling only the BSDF; objects are laid over those samples in numpy
by :func:`esim_lite.geometry.visibility.trace` (the same sample rays, float64); the samples
are averaged in numpy, same order.

Conventions bridged here: the ray cast uses our camera frame (OpenCV's: x right, y down,
z forward; pixel centres at integers); Mitsuba's perspective sensor (scalar path) is X left,
Y up, Z forward with pixel centres at ``i + 0.5``; a rectangle's bitmap row 0 lies at local
``y = -1``.
"""

from __future__ import annotations

import gc
import logging
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.objects import (
    ALPHA_CUTOFF,
    DynamicScene,
    ObjectPatch,
    as_dynamic,
    relative_pose,
)
from esim_lite.geometry.pose import Pose
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.visibility import bilinear, trace

log = logging.getLogger(__name__)

#: Oldest LLVM that Mitsuba's LLVM variants are tried with; older ones (Debian 12's 15)
#: abort the process on the first render ("Cannot select ... fminimum").
MIN_LLVM = (16, 0, 0)
_OPENCV_TO_MITSUBA = np.diag([-1.0, -1.0, 1.0, 1.0])
_variant_cache: dict[str, str] = {}

_PROBE = """
import sys
sys.path.insert(0, {root!r})
import numpy as np
from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.pose import Pose
from esim_lite.render.mitsuba import MitsubaRenderer
from esim_lite.geometry.scene import PlanarScene
tex = np.linspace(0, 1, 16, dtype=np.float32).reshape(4, 4)
cam = Intrinsics(8.0, 8.0, 3.5, 3.5, 8, 8)
renderer = MitsubaRenderer({{"lr": PlanarScene(tex, 2.0, 2.0)}}, {{"lr": cam}}, {{"lr": 2}},
                           variant={variant!r})
img = renderer.render("lr", Pose(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 1.0])))
assert np.isfinite(img).all() and img.max() > 0
"""


def _probe(variant: str) -> bool:
    """Render a tiny scene with ``variant`` in a child process (an LLVM abort kills only it),
    through this module's own render path."""
    root = str(Path(__file__).resolve().parents[1])
    try:
        proc = subprocess.run([sys.executable, "-c", _PROBE.format(variant=variant, root=root)],
                              capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        return False
    if proc.returncode != 0:
        log.warning("mitsuba variant %s failed its probe render: %s", variant,
                    proc.stderr.strip().splitlines()[-1:] or proc.returncode)
    return proc.returncode == 0


def resolve_variant(requested: str = "auto") -> str:
    """The Mitsuba variant to use: ``requested`` itself, or the fastest that works here.

    ``auto`` tries ``cuda_ad_mono`` (GPU), then ``llvm_ad_mono`` when drjit's LLVM is at
    least :data:`MIN_LLVM` and a probe render in a child process succeeds, then falls back
    to ``scalar_rgb``. The environment variable ``E2SR_MITSUBA_VARIANT`` overrides ``auto``.
    """
    requested = os.environ.get("E2SR_MITSUBA_VARIANT", requested) if requested == "auto" \
        else requested
    if requested != "auto":
        return requested
    if "auto" in _variant_cache:
        return _variant_cache["auto"]
    import drjit as dr
    import mitsuba as mi

    available = mi.variants()
    chosen = "scalar_rgb"
    if "cuda_ad_mono" in available and dr.has_backend(dr.JitBackend.CUDA):
        chosen = "cuda_ad_mono"
    elif "llvm_ad_mono" in available:
        version = tuple(dr.detail.llvm_version())
        if version >= MIN_LLVM and _probe("llvm_ad_mono"):
            chosen = "llvm_ad_mono"
        else:
            log.warning("Mitsuba LLVM backend unusable (LLVM %s); using the slower "
                        "scalar_rgb variant. Install libllvm19 for speed.",
                        ".".join(map(str, version)))
    _variant_cache["auto"] = chosen
    return chosen


class MitsubaRenderer:
    """Renders each named camera's :class:`PlanarScene` or :class:`DynamicScene` with
    Mitsuba 3.

    One Mitsuba scene per camera, because each camera may see its own prefiltered texture.
    """

    name = "mitsuba"

    def __init__(self, scenes: dict[str, PlanarScene | DynamicScene],
                 cameras: dict[str, Intrinsics], supersample: dict[str, int],
                 variant: str = "auto", threads: int | None = None) -> None:
        import drjit as dr
        import mitsuba as mi

        self.variant = resolve_variant(variant)
        mi.set_variant(self.variant)
        if threads is not None and self.variant.startswith("llvm"):
            dr.set_thread_count(int(threads))
        self._mi = mi
        self.cameras = dict(cameras)
        self.supersample = {name: int(supersample.get(name, 1)) for name in self.cameras}
        self._mono = "mono" in self.variant
        self._jit = not self.variant.startswith("scalar")
        self._scenes, self._params, self._cast = {}, {}, {}
        self._dynamic = {name: as_dynamic(scenes[name]) for name in self.cameras}
        for name, cam in self.cameras.items():
            s = self.supersample[name]
            parts = {"type": "scene", "plane": self._plane(self._dynamic[name].background)}
            if not self._jit:
                parts.update({
                    "integrator": {"type": "direct", "emitter_samples": 0, "bsdf_samples": 1},
                    "env": {"type": "constant", "radiance": 1.0},
                    "sensor": self._sensor(cam, s)})
            scene = mi.load_dict(parts)
            self._scenes[name] = scene
            if self._jit:
                self._cast[name] = _RayCast(cam, s, self._dynamic[name].objects)
            else:
                self._params[name] = mi.traverse(scene)

    def _plane(self, scene: PlanarScene) -> dict:
        mi = self._mi
        # Bitmap row 0 sits at local y = -1 (world Y = -height/2); ours is at +height/2.
        tex = np.ascontiguousarray(np.flipud(scene.texture))[..., None]
        if not self._mono:
            tex = np.repeat(tex, 3, axis=2)
        to_world = mi.ScalarTransform4f().scale([scene.width_m / 2, scene.height_m / 2, 1.0])
        return {"type": "rectangle", "to_world": to_world,
                "bsdf": {"type": "diffuse", "reflectance": {
                    "type": "bitmap", "bitmap": mi.Bitmap(tex), "raw": True,
                    "wrap_mode": "clamp", "filter_type": "bilinear"}}}

    def _sensor(self, cam: Intrinsics, supersample: int) -> dict:
        mi = self._mi
        if not np.isclose(cam.fx, cam.fy, rtol=1e-9):
            raise ValueError(f"Mitsuba's perspective camera needs square pixels, got "
                             f"fx={cam.fx}, fy={cam.fy}")
        return {
            "type": "perspective", "fov_axis": "x", "fov": cam.fov_x_deg,
            # Mitsuba's centres sit at i + 0.5, ours at i; its offsets are fractions of the
            # film along its own X-left / Y-up axes, hence the minus signs.
            "principal_point_offset_x": -(cam.cx + 0.5 - cam.width / 2) / cam.width,
            "principal_point_offset_y": -(cam.cy + 0.5 - cam.height / 2) / cam.height,
            "near_clip": 1e-3, "far_clip": 1e4,
            "to_world": mi.ScalarTransform4f(np.eye(4).tolist()),
            # s x s film pixels per camera pixel, one centred sample each: nothing is summed
            # inside Mitsuba; the principal point offset is a fraction of the film
            "film": {"type": "hdrfilm", "width": cam.width * supersample,
                     "height": cam.height * supersample, "rfilter": {"type": "box"},
                     "pixel_format": "luminance", "sample_border": False},
            "sampler": {"type": "stratified", "sample_count": 1, "jitter": False, "seed": 0},
        }

    def _render_film(self, camera: str, pose: Pose) -> np.ndarray:
        mi = self._mi
        params = self._params[camera]
        params["sensor.to_world"] = mi.ScalarTransform4f(
            (pose.matrix() @ _OPENCV_TO_MITSUBA).tolist())
        params.update()
        return np.array(mi.render(self._scenes[camera], seed=0), dtype=np.float32)[..., 0]

    def _overlay_objects(self, camera: str, pose: Pose, objects: tuple[Pose, ...],
                         fine: np.ndarray) -> np.ndarray:
        """The scalar path's objects: ``fine`` (float32[H*s, W*s], the background's samples)
        with every sample whose ray meets an object first replaced by that object's texture,
        in numpy (float64 hits, the same sample rays as the film)."""
        scene = self._dynamic[camera]
        rays = self.cameras[camera].scaled(self.supersample[camera]).pixel_rays()
        hits = trace(scene, pose, objects, rays)
        out = fine.copy()
        for k, obj in enumerate(scene.objects):
            sel = hits.ids == k + 1
            if sel.any():
                out[sel] = bilinear(obj.surface.texture, hits.col[sel], hits.row[sel])
        return out

    def render(self, camera: str, pose: Pose, objects: Sequence[Pose] = ()) -> np.ndarray:
        """float32[H, W] linear intensity seen by ``camera`` at ``pose``, with the scene's
        objects at ``objects`` (object-to-world poses, in the scene's object order)."""
        mi = self._mi
        objects = tuple(objects)
        count = len(self._dynamic[camera].objects)
        if len(objects) != count:
            raise ValueError(f"camera {camera!r}: the scene has {count} objects, "
                             f"render() got {len(objects)} object poses")
        if mi.variant() != self.variant:  # the variant is process-global; another renderer
            mi.set_variant(self.variant)  # in this process may have switched it
        if self._jit:
            return self._cast[camera](self._scenes[camera], pose, objects)
        fine = self._render_film(camera, pose)
        if objects:
            fine = self._overlay_objects(camera, pose, objects, fine)
        s = self.supersample[camera]
        if s == 1:
            return fine
        total = np.zeros((fine.shape[0] // s, fine.shape[1] // s), np.float64)
        for i in range(s):  # the s x s samples of every pixel, summed in one fixed order
            for j in range(s):
                total += fine[i::s, j::s]
        return (total / (s * s)).astype(np.float32)

    def close(self) -> None:
        self._cast.clear()
        self._params.clear()
        self._scenes.clear()
        self._dynamic.clear()


class _RayCast:
    """Renders ``camera`` with ``s x s`` primary rays per pixel, one through the centre of
    every cell of its sub-pixel grid (OpenCV conventions), traced through a Mitsuba scene
    and past the scene's objects.

    Two kernels, recorded once as a frozen function of the scene, the pose (12 opaque
    floats: ``R_wc`` row by row, then ``t_wc``), the objects' textures and the camera's pose
    in every object's frame (12 opaque floats each, same layout), and replayed for every
    pose: the rays (one lane each, over the ``s``-times finer grid, so both cores share the
    work), then per camera pixel the sum of its ``s x s`` values in float64 in one fixed
    order (row by row), as the scalar path does in numpy. Rays that miss everything give 0.
    """

    def __init__(self, camera: Intrinsics, supersample: int,
                 objects: Sequence[ObjectPatch] = ()) -> None:
        import drjit as dr
        import mitsuba as mi

        self.camera = camera
        self.supersample = supersample
        # sizes are fixed per renderer: literals in the kernel; textures are kernel inputs
        self._sizes = [(float(o.surface.width_m), float(o.surface.height_m)) for o in objects]
        self._textures = [mi.Texture2f(
            mi.TensorXf(np.stack([o.surface.texture, o.alpha], axis=-1)),
            # the emulated lookup on CUDA too: hardware filtering rounds its weights to
            # 8 bits, which would move the alpha test's edges
            use_accel=False, filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Clamp)
            for o in objects]
        self._frozen = dr.freeze(self._trace)

    def _trace(self, scene, pose, textures, object_poses):
        import drjit as dr
        import mitsuba as mi

        s, cam = self.supersample, self.camera
        fine = cam.scaled(s)
        index = dr.arange(mi.UInt32, fine.width * fine.height)
        row = index // fine.width
        x = (mi.Float(index - row * fine.width) - fine.cx) / fine.fx
        y = (mi.Float(row) - fine.cy) / fine.fy
        m = pose  # 12 one-element arrays, read once per lane (a gather per lane was slower)
        direction = mi.Vector3f(m[0] * x + m[1] * y + m[2], m[3] * x + m[4] * y + m[5],
                                m[6] * x + m[7] * y + m[8])
        ray = mi.Ray3f(mi.Point3f(m[9], m[10], m[11]), dr.normalize(direction))
        # the scene's only shape is the plane: its own intersection routine, rather than
        # Scene.ray_intersect_preliminary's walk of an Embree hierarchy of one primitive
        # (hits equal to float32 rounding, but a slower kernel)
        (plane,) = scene.shapes()
        hit = plane.ray_intersect_preliminary(ray)
        si = hit.compute_surface_interaction(ray, mi.RayFlags.UV)
        radiance = plane.bsdf().eval_diffuse_reflectance(si, si.is_valid())
        samples = dr.select(si.is_valid(), radiance[0], 0.0)
        if textures:
            # the hit's camera-frame depth: ray.d is direction / |direction|, z(direction) = 1
            depth = dr.select(si.is_valid(), hit.t / dr.norm(direction), dr.inf)
            samples = self._occlude(x, y, depth, samples, textures, object_poses)
        if s == 1:
            return samples
        return self._box(samples)

    def _occlude(self, x, y, depth, samples, textures, object_poses):
        """``samples`` with every ray that meets a solid point of an object nearer than
        ``depth`` (camera-frame depth of the hit so far) given that object's texture."""
        import drjit as dr
        import mitsuba as mi

        for (width, height), tex, m in zip(self._sizes, textures, object_poses):
            # the ray (x, y, 1) from the camera centre, in the object's frame
            dx = m[0] * x + m[1] * y + m[2]
            dy = m[3] * x + m[4] * y + m[5]
            dz = m[6] * x + m[7] * y + m[8]
            lam = -m[11] / dz  # its camera depth at the object's plane z = 0 (two-sided)
            px, py = m[9] + lam * dx, m[10] + lam * dy
            inside = (lam > 0) & (lam < depth) & (dr.abs(px) <= width / 2) & \
                (dr.abs(py) <= height / 2)
            # texel centres at (j + 0.5) / w as in PlanarScene; row 0 at y = +height / 2
            texel = tex.eval(mi.Point2f(px * (1 / width) + 0.5, 0.5 - py * (1 / height)),
                             inside)
            solid = inside & (texel[1] >= ALPHA_CUTOFF)
            depth = dr.select(solid, lam, depth)
            samples = dr.select(solid, texel[0], samples)
        return samples

    def _box(self, samples):
        """Per camera pixel, the float64 mean of its ``s x s`` samples (row by row)."""
        import drjit as dr
        import mitsuba as mi

        s, cam = self.supersample, self.camera
        fine = cam.scaled(s)
        dr.eval(samples)  # the sum below reads neighbouring lanes: a second kernel
        pixel = dr.arange(mi.UInt32, cam.width * cam.height)
        prow = pixel // cam.width
        first = prow * (s * fine.width) + (pixel - prow * cam.width) * s
        total = mi.Float64(0.0)
        for i in range(s):
            for j in range(s):
                total += mi.Float64(dr.gather(mi.Float, samples, first + i * fine.width + j))
        return mi.Float(total / (s * s))

    def __call__(self, scene, pose: Pose, objects: tuple[Pose, ...] = ()) -> np.ndarray:
        """float32[H, W] radiance of ``scene`` seen from ``pose``, objects at ``objects``."""
        import drjit as dr
        import mitsuba as mi

        def opaque(p: Pose) -> list:
            packed = np.concatenate([p.r_wc.reshape(-1), p.t_wc]).astype(np.float32)
            return [dr.opaque(mi.Float, float(v)) for v in packed]

        # float64 on the host: the camera in each object's frame, one rigid map per object
        seen = [opaque(relative_pose(pose, p)) for p in objects]
        # No cyclic garbage collection inside the frozen call: a collection that freed
        # another renderer's drjit objects while this one was being recorded aborted the
        # process once (the test suite, 2-core AMD VM, 2026-12-07); collections wait until
        # the call returns. gc.disable is process-global: a render on another Python
        # thread ending first re-enables collection early (losing only this guard).
        collecting = gc.isenabled()
        gc.disable()
        try:
            values = self._frozen(scene, opaque(pose), self._textures, seen)
        finally:
            if collecting:
                gc.enable()
        return np.array(values, dtype=np.float32).reshape(self.camera.height,
                                                          self.camera.width)
