"""Mitsuba 3 rendering of the planar scene; the only module that imports mitsuba/drjit.

Noise-free by construction, because render noise would become fake events:
- the texture is loaded raw (linear values, no sRGB decoding), bilinear, ``clamp`` wrap;
- the film has ``s`` times the camera's resolution along each axis and one sample at the
  centre of each of its pixels, so the samples are exactly the ``s x s`` sub-pixel grid of
  :mod:`esim_lite.render_homography`; they are averaged into camera pixels here, in a fixed
  order. (With ``s*s`` samples per film pixel instead, drjit's LLVM backend, which splits a
  launch into blocks of 16,384 work items, sums the samples of pixels that straddle two
  blocks in thread-timing order: renders differed by 1-2 ulp from run to run, enough to
  move an event by nanoseconds. One sample per film pixel has nothing to sum.)
- the ``direct`` integrator samples only the BSDF under a constant unit environment, so a
  diffuse plane returns its albedo with zero variance;
- a fixed seed, and the scene is built once; per frame only ``sensor.to_world`` changes
  (``mi.traverse`` + ``params.update()``), so the JIT kernel compiles once.

Conventions bridged here: Mitsuba's camera frame is X left / Y up / Z forward, its pixel
centres sit at ``i + 0.5``, and a rectangle's bitmap row 0 lies at local ``y = -1``.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys

import numpy as np

from esim_lite.camera import Intrinsics
from esim_lite.pose import Pose
from esim_lite.scene import PlanarScene

log = logging.getLogger(__name__)

#: Oldest LLVM that Mitsuba's LLVM variants are tried with; older ones (Debian 12's 15)
#: abort the process on the first render ("Cannot select ... fminimum").
MIN_LLVM = (16, 0, 0)
_OPENCV_TO_MITSUBA = np.diag([-1.0, -1.0, 1.0, 1.0])
_variant_cache: dict[str, str] = {}

_PROBE = """
import numpy as np, mitsuba as mi
mi.set_variant({variant!r})
tex = mi.Bitmap(np.linspace(0, 1, 16, dtype=np.float32).reshape(4, 4, 1))
scene = mi.load_dict({{'type': 'scene',
  'integrator': {{'type': 'direct', 'emitter_samples': 0, 'bsdf_samples': 1}},
  'sensor': {{'type': 'perspective', 'fov': 40,
             'to_world': mi.ScalarTransform4f().translate([0, 0, -3]),
             'film': {{'type': 'hdrfilm', 'width': 8, 'height': 8,
                      'rfilter': {{'type': 'box'}}, 'pixel_format': 'luminance'}},
             'sampler': {{'type': 'stratified', 'sample_count': 4, 'jitter': False}}}},
  'env': {{'type': 'constant'}},
  'plane': {{'type': 'rectangle', 'flip_normals': True, 'bsdf': {{'type': 'diffuse',
            'reflectance': {{'type': 'bitmap', 'bitmap': tex, 'raw': True,
                            'wrap_mode': 'clamp'}}}}}}}})
img = np.array(mi.render(scene, seed=0))
assert np.isfinite(img).all() and img.max() > 0
"""


def _probe(variant: str) -> bool:
    """Render a tiny scene with ``variant`` in a child process (an LLVM abort kills only it)."""
    try:
        proc = subprocess.run([sys.executable, "-c", _PROBE.format(variant=variant)],
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
    """Renders each named camera's :class:`PlanarScene` with Mitsuba 3.

    One Mitsuba scene per camera, because each camera may see its own prefiltered texture.
    """

    name = "mitsuba"

    def __init__(self, scenes: dict[str, PlanarScene], cameras: dict[str, Intrinsics],
                 supersample: dict[str, int], variant: str = "auto",
                 threads: int | None = None) -> None:
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
        self._scenes, self._params, self._render = {}, {}, {}
        for name, cam in self.cameras.items():
            scene = mi.load_dict({
                "type": "scene",
                "integrator": {"type": "direct", "emitter_samples": 0, "bsdf_samples": 1},
                "env": {"type": "constant", "radiance": 1.0},
                "plane": self._plane(scenes[name]),
                "sensor": self._sensor(cam, self.supersample[name]),
            })
            self._scenes[name] = scene
            self._params[name] = mi.traverse(scene)
            self._render[name] = self._renderer_for(scene)

    def _renderer_for(self, scene):
        """A render call for ``scene``; on JIT variants a frozen function, which records the
        kernel launches once and replays them (the new camera transform is an opaque
        variable, so replays see it), saving ~2 ms of Python tracing per frame."""
        mi = self._mi
        if self.variant.startswith("scalar"):
            return lambda: mi.render(scene, seed=0)
        import drjit as dr

        frozen = dr.freeze(lambda s: mi.render(s, seed=0))
        return lambda: frozen(scene)

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
            # s x s film pixels per camera pixel, one centred sample each (see the module
            # doc); the principal point offset is a fraction of the film, so it is unchanged
            "film": {"type": "hdrfilm", "width": cam.width * supersample,
                     "height": cam.height * supersample, "rfilter": {"type": "box"},
                     "pixel_format": "luminance", "sample_border": False},
            "sampler": {"type": "stratified", "sample_count": 1, "jitter": False, "seed": 0},
        }

    def render(self, camera: str, pose: Pose) -> np.ndarray:
        """float32[H, W] linear intensity seen by ``camera`` at ``pose``."""
        mi = self._mi
        if mi.variant() != self.variant:  # the variant is process-global; another renderer
            mi.set_variant(self.variant)  # in this process may have switched it
        params = self._params[camera]
        params["sensor.to_world"] = mi.ScalarTransform4f(
            (pose.matrix() @ _OPENCV_TO_MITSUBA).tolist())
        params.update()
        fine = np.array(self._render[camera](), dtype=np.float32)[..., 0]
        s = self.supersample[camera]
        if s == 1:
            return fine
        total = np.zeros((fine.shape[0] // s, fine.shape[1] // s), np.float64)
        for i in range(s):  # the s x s samples of every pixel, summed in one fixed order
            for j in range(s):
                total += fine[i::s, j::s]
        return (total / (s * s)).astype(np.float32)

    def close(self) -> None:
        self._render.clear()
        self._params.clear()
        self._scenes.clear()
