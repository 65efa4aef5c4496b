"""The configuration record of ``datagen from-video`` (videos in, a training set out).

The sensor keys sit where ``datagen generate``'s do (``simulation.events``,
``simulation.sampling``, ``simulation.camera``, ``sensor_ranges``), so a sensor preset
(configs/sensors/*.yaml) loads on top of a from-video config as it does on a dataset
config; the scene keys of ``generate`` (trajectory, objects, render, frames) have no
meaning for a video and are refused.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from datagen.sensor_ranges import SensorRanges
from esim_lite.config import CameraConfig
from esim_lite.core.scales import SCALES
from esim_lite.events.sampling import SamplingConfig
from esim_lite.events.simulator import EventConfig


@dataclass(frozen=True)
class VideoSimulationConfig:
    """The simulated sensor and how densely it samples time between video frames.

    Attributes:
        camera: the LR event sensor (``width``, ``height``) and the HR ``scales``;
            ``fov_x_deg`` only sets the nominal intrinsics stored with the frames (a
            video's lens is unknown).
        events: the event camera model, as in ``datagen generate``.
        sampling: ``contrast_fraction`` (lambda: no interpolated sample changes a pixel's
            log intensity by more than lambda times its threshold, outside occlusions),
            ``min_step_s`` (the shortest step that bound may force), ``max_step_s`` (the
            longest step between samples, whatever the video does); ``adaptive: false``
            keeps only the motion and ``max_step_s`` rules.
    """

    camera: CameraConfig = field(default_factory=CameraConfig)
    events: EventConfig = field(default_factory=EventConfig)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)


@dataclass(frozen=True)
class FlowConfig:
    """The ``flow`` interpolator: OpenCV DIS optical flow, forward and backward.

    Attributes:
        preset: DIS preset (``ultrafast``, ``fast``, ``medium``).
        max_motion_px: no pixel moves more than this (LR pixels) between two samples; the
            largest flow between two video frames sets the number of samples.
        occlusion_alpha, occlusion_beta_px: a pixel is occluded in the other frame when
            its forward and backward flows disagree:
            ``|F01(x) + F10(x + F01(x))|^2 > alpha (|F01|^2 + |F10|^2) + beta^2``
            (Sundaram, Brox and Keutzer 2010).
        visibility_floor: weight kept by a warped frame where it is occluded (so that the
            interpolated frame at the video frame's own time is that frame).
    """

    preset: Literal["ultrafast", "fast", "medium"] = "medium"
    max_motion_px: float = 0.5
    occlusion_alpha: float = 0.01
    occlusion_beta_px: float = 0.5
    visibility_floor: float = 0.1

    def __post_init__(self) -> None:
        if not self.max_motion_px > 0:
            raise ValueError(f"flow.max_motion_px must be > 0, got {self.max_motion_px}")
        if self.occlusion_alpha < 0 or self.occlusion_beta_px < 0:
            raise ValueError("flow.occlusion_alpha and occlusion_beta_px must be >= 0")
        if not 0 < self.visibility_floor <= 1:
            raise ValueError(f"flow.visibility_floor must be in (0, 1], got "
                             f"{self.visibility_floor}")


@dataclass(frozen=True)
class VideoConfig:
    """How videos become sequences.

    Attributes:
        frames_per_sequence: video frames per sequence (a sequence's frames are the
            video's, its HR ground truth).
        stride_frames: video frames between the starts of consecutive sequences (None:
            ``frames_per_sequence``, sequences side by side); a clip yields
            ``1 + (N - frames_per_sequence) // stride`` sequences, none when shorter.
        interpolator: ``flow`` (DIS flow both ways, occlusion-aware warping) or ``linear``
            (esim_py's rule: log intensity linear in time per pixel).
        work_scale: the interpolator warps frames at this multiple of the LR size, then
            area-averages them to LR (1: warps the LR frames themselves, which blurs a
            sharp texture between frames); at most the largest of ``camera.scales``.
        colour: ``srgb``: file values are sRGB-encoded (8-bit video, PNG, JPEG) and are
            linearised with the sRGB curve; ``linear``: file values are linear intensity.
            Colour is then reduced to luminance ``0.2126 R + 0.7152 G + 0.0722 B`` of the
            linear values (the sRGB/Rec.709 primaries' Y).
        scene_cut_fraction: a scene cut is declared between two frames when more than this
            share of pixels fail the forward-backward flow check; the sensor then restarts
            at the new frame without events (no burst). None: never.
        flow: the ``flow`` interpolator's settings.
    """

    frames_per_sequence: int = 32
    stride_frames: int | None = None
    interpolator: Literal["flow", "linear"] = "flow"
    work_scale: int = 2
    colour: Literal["srgb", "linear"] = "srgb"
    scene_cut_fraction: float | None = 0.75
    flow: FlowConfig = field(default_factory=FlowConfig)

    def __post_init__(self) -> None:
        if self.frames_per_sequence < 2:
            raise ValueError(f"video.frames_per_sequence must be >= 2, got "
                             f"{self.frames_per_sequence}")
        if self.stride_frames is not None and self.stride_frames < 1:
            raise ValueError(f"video.stride_frames must be >= 1 or null, got "
                             f"{self.stride_frames}")
        if self.work_scale not in (1, *SCALES):
            raise ValueError(f"video.work_scale must be 1 or one of {SCALES}, got "
                             f"{self.work_scale}")
        if self.scene_cut_fraction is not None and not 0 < self.scene_cut_fraction <= 1:
            raise ValueError(f"video.scene_cut_fraction must be in (0, 1] or null, got "
                             f"{self.scene_cut_fraction}")

    @property
    def stride(self) -> int:
        return self.stride_frames or self.frames_per_sequence

    def sequences_in(self, n_frames: int) -> int:
        """How many sequences a clip of ``n_frames`` frames yields."""
        if n_frames < self.frames_per_sequence:
            return 0
        return 1 + (n_frames - self.frames_per_sequence) // self.stride


@dataclass(frozen=True)
class FromVideoConfig:
    """Settings of a from-video dataset.

    Attributes:
        simulation: the LR sensor, its HR scales, the event model and time sampling.
        sensor_ranges: the sensor settings drawn per sequence, as in ``datagen generate``
            (domain randomisation; all off by default).
        video: sequences, interpolation, colour and scene cuts.
        sequences_per_shard: sequences per HDF5 file (the unit of work and of resumption).
    """

    simulation: VideoSimulationConfig = field(default_factory=VideoSimulationConfig)
    sensor_ranges: SensorRanges = field(default_factory=SensorRanges)
    video: VideoConfig = field(default_factory=VideoConfig)
    sequences_per_shard: int = 4

    def __post_init__(self) -> None:
        if self.sequences_per_shard < 1:
            raise ValueError("sequences_per_shard must be >= 1")
        finest = max(self.simulation.camera.scales)
        if self.video.work_scale > finest:
            raise ValueError(f"video.work_scale {self.video.work_scale} is above the finest "
                             f"HR scale {finest} (the interpolator warps frames derived "
                             f"from the finest HR frames)")
