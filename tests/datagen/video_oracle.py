"""The from-video oracle: a sequence rendered by our own simulator (its events exact), its HR
frames written as a low-frame-rate video (a lossless 16-bit PNG folder with
``timestamps.txt``), and measures comparing ``from-video``'s events with the simulator's.

The camera looks straight down at a textured plane and slides sideways at a constant
speed, so everything moves by the same ``px_per_frame`` LR pixels between video frames.
The direct events sample the LR camera with 4 x 4 points a pixel; the HR x4 camera
samples one point a pixel at the same places, so the block mean of the video frames is the
LR image the simulator saw at those times: what differs is only what happens between
frames. Shared by tests/datagen/test_video_oracle.py and bench/bench_from_video.py.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from esim_lite.config import CameraConfig, FrameConfig, SimulationConfig
from esim_lite.core.events import Events
from esim_lite.events.sampling import SamplingConfig
from esim_lite.events.simulator import EventConfig
from esim_lite.events.thresholds import ContrastThresholds, ThresholdConfig
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import LOOK_DOWN, BSplineTrajectory
from esim_lite.render.renderer import RenderConfig
from esim_lite.sequence import simulate_sequence

THRESHOLD = 0.2
HEIGHT_M = 1.0


@dataclass(frozen=True, eq=False)
class Rendered:
    """The simulator's own events and the video folder made of its HR frames."""

    events: Events
    folder: Path
    sensor_hw: tuple[int, int]
    frame_interval_ns: int
    n_frames: int


def texture(seed: int, hw: tuple[int, int], sigma: float) -> np.ndarray:
    """float32 band-limited random texture in [0.05, 1]."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.random(hw).astype(np.float32), (0, 0), sigma)
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return (0.05 + 0.95 * tex).astype(np.float32)


def write_png_video(frames: np.ndarray, t_ns: np.ndarray, folder: Path) -> Path:
    """Linear float frames as 16-bit sRGB-encoded PNGs with their ``timestamps.txt``."""
    folder.mkdir(parents=True, exist_ok=True)
    for k, frame in enumerate(frames):
        v = np.clip(frame, 0.0, 1.0).astype(np.float64)
        enc = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
        cv2.imwrite(str(folder / f"{k:05d}.png"), np.round(enc * 65535).astype(np.uint16))
    (folder / "timestamps.txt").write_text("".join(f"{t * 1e-9:.9f}\n" for t in t_ns))
    return folder


def render(folder: Path, px_per_frame: float, fps: float = 30.0, n_frames: int = 9,
           sensor_hw: tuple[int, int] = (64, 96), seed: int = 0,
           sigma: float = 1.0) -> Rendered:
    """Simulate the sliding camera for ``n_frames`` video frames and write the video."""
    h, w = sensor_hw
    duration = (n_frames - 1) / fps
    cam = CameraConfig(width=w, height=h, fov_x_deg=60.0, scales=(4,))
    fx = cam.rig().event.fx
    speed = px_per_frame * fps * HEIGHT_M / fx  # m/s sideways
    knots, spacing = n_frames + 4, 1.0 / fps
    times = (np.arange(knots) - 1) * spacing
    positions = np.stack([speed * times, np.zeros(knots), np.full(knots, HEIGHT_M)], 1)
    traj = BSplineTrajectory(positions, np.repeat(LOOK_DOWN[None], knots, 0), spacing,
                             duration)
    half_w = HEIGHT_M * (w / 2 + 4) / fx  # the view, with a margin
    extent_x = 2 * half_w + speed * duration + 0.2
    extent_y = 2 * HEIGHT_M * (h / 2 + 4) / fx + 0.2
    tex_w = int(extent_x * fx * 4 / HEIGHT_M * 2)  # 2 texels per HR pixel
    tex = texture(seed, (int(tex_w * extent_y / extent_x), tex_w), sigma * 8)
    scene = PlanarScene(tex, extent_x, extent_y)
    traj = traj.shifted(np.array([-(speed * duration) / 2, 0.0, 0.0]))
    config = SimulationConfig(
        duration_s=duration, camera=cam,
        frames=FrameConfig(mode="rate", rate_hz=fps),
        events=EventConfig(thresholds=ThresholdConfig((THRESHOLD,) * 2, (THRESHOLD,) * 2)),
        sampling=SamplingConfig(),
        render=RenderConfig(backend="homography", supersample_lr=4, supersample_hr=1))
    thresholds = ContrastThresholds.uniform(THRESHOLD, THRESHOLD, sensor_hw)
    seq = simulate_sequence(scene, traj, thresholds, config, np.random.default_rng(seed))
    hr = seq.frames["hr_x4"]
    write_png_video(hr.intensity, hr.t_ns, folder)
    return Rendered(seq.events, folder, sensor_hw, int(round(1e9 / fps)), len(hr))


def count_maps(events: Events) -> np.ndarray:
    """int64[2, H, W]: ON and OFF events per pixel."""
    h, w = events.sensor_hw
    out = np.zeros((2, h, w), np.int64)
    np.add.at(out, ((events.p < 0).astype(np.int64), events.y.astype(np.int64),
                    events.x.astype(np.int64)), 1)
    return out


@dataclass(frozen=True)
class Comparison:
    """How ``from-video``'s events differ from the simulator's (on the interior pixels).

    Attributes:
        count_error: sum over pixels and polarities of ``|n_video - n_true|``, over the
            true count (0: every pixel fires as often as it should).
        timing_error: mean ``|t_video - t_true|`` of the k-th events of each pixel and
            polarity (paired in order), in frame intervals.
        true_events, video_events: event counts.
    """

    count_error: float
    timing_error: float
    true_events: int
    video_events: int


def compare(truth: Events, video: Events, frame_interval_ns: int, margin: int) -> Comparison:
    """Per-pixel counts and timing of ``video`` against ``truth``, leaving out ``margin``
    pixels at the border (where new content enters the view, which no interpolator of
    two frames can know)."""
    h, w = truth.sensor_hw
    inner = np.zeros((h, w), bool)
    inner[margin:h - margin, margin:w - margin] = True
    a, b = count_maps(truth)[:, inner], count_maps(video)[:, inner]
    count_error = float(np.abs(a - b).sum() / max(a.sum(), 1))
    return Comparison(count_error, _timing(truth, video, inner) / frame_interval_ns,
                      int(a.sum()), int(b.sum()))


def _timing(truth: Events, video: Events, inner: np.ndarray) -> float:
    def by_pixel(ev: Events) -> dict[tuple[int, int, int], np.ndarray]:
        keep = inner[ev.y, ev.x]
        key = (ev.y[keep].astype(np.int64) * 65536 + ev.x[keep]) * 2 + (ev.p[keep] < 0)
        order = np.lexsort((ev.t_ns[keep], key))
        key, t = key[order], ev.t_ns[keep][order]
        cuts = np.flatnonzero(np.diff(key)) + 1
        return {int(k[0]): v for k, v in zip(np.split(key, cuts), np.split(t, cuts))
                if len(k)}

    ta, tb = by_pixel(truth), by_pixel(video)
    errors = [np.abs(ta[k][:n] - tb[k][:n]) for k in ta.keys() & tb.keys()
              if (n := min(len(ta[k]), len(tb[k])))]
    return float(np.concatenate(errors).mean()) if errors else float("nan")
