"""The simulator's configuration record (one sequence's worth of settings)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from esim_lite.core.limits import MAX_RENDER_PIXELS, check_sensor_hw
from esim_lite.core.scales import check_scales
from esim_lite.events.sampling import SamplingConfig
from esim_lite.events.simulator import EventConfig
from esim_lite.geometry.camera import CameraRig, Intrinsics
from esim_lite.geometry.object_sampling import ObjectsConfig
from esim_lite.geometry.trajectory import TrajectoryConfig
from esim_lite.render.renderer import RenderConfig


@dataclass(frozen=True)
class CameraConfig:
    """The LR event camera (square pixels, centred principal point) and the HR scales.

    Attributes:
        width, height: event sensor size in pixels (the paper's synthetic camera: 128x128).
        fov_x_deg: horizontal field of view.
        scales: HR intensity cameras to render, e.g. (2,), (4,) or (2, 4).
    """

    width: int = 128
    height: int = 128
    fov_x_deg: float = 60.0
    scales: tuple[int, ...] = (2,)

    def __post_init__(self) -> None:
        if self.width < 2 or self.height < 2:
            raise ValueError("sensor must be at least 2x2")
        check_scales(self.scales, "camera.scales")
        check_sensor_hw((self.height, self.width), "camera.width/height", "event sensor")
        hr = self.width * self.height * max(self.scales) ** 2
        if hr > MAX_RENDER_PIXELS:
            raise ValueError(f"camera.width/height: a {self.width}x{self.height} sensor at "
                             f"x{max(self.scales)} renders {hr:,} pixels a frame, more than "
                             f"{MAX_RENDER_PIXELS:,}")

    def rig(self) -> CameraRig:
        return CameraRig(Intrinsics.from_fov(self.width, self.height, self.fov_x_deg),
                         tuple(self.scales))


@dataclass(frozen=True)
class FrameConfig:
    """When the LR (APS-like) and HR frames are rendered.

    Attributes:
        mode: ``events``: a frame at t = 0 and at the timestamp of every ``every_events``-th
            event (the paper samples ground truth at the last event of each stack, so with
            ``every_events`` = one stack there is one stack between frames whatever the
            scene's event rate); ``rate``: frames every ``1 / rate_hz`` seconds, like an APS.
        every_events: events between frames in ``events`` mode.
        rate_hz: frame rate in ``rate`` mode.
        count: end the sequence early once it has this many frames and ``tail_events``
            more events (the future stacks of the last frame); None runs the full duration.
        tail_events: see ``count``.
        ground_truth: per-pixel truth rendered with every frame for every camera, any of
            ``flow`` (instantaneous optical flow of the visible surface, px/s), ``depth``
            (metres along the optical axis) and ``ids`` (visible surface, 0 = background).
    """

    mode: Literal["events", "rate"] = "events"
    every_events: int = 3000
    rate_hz: float = 50.0
    count: int | None = None
    tail_events: int = 12000
    ground_truth: tuple[Literal["flow", "depth", "ids"], ...] = ()

    def __post_init__(self) -> None:
        if self.every_events < 1 or self.rate_hz <= 0 or self.tail_events < 0:
            raise ValueError("every_events and rate_hz must be positive, tail_events >= 0")
        if len(set(self.ground_truth)) != len(self.ground_truth):
            raise ValueError(f"frames.ground_truth lists a kind twice: {self.ground_truth}")
        if self.count is not None and self.count < 1:
            raise ValueError("count must be >= 1 or null")


@dataclass(frozen=True)
class SimulationConfig:
    """Everything the simulator needs besides the scene and the random draws.

    Attributes:
        duration_s: sequence length (the maximum, when ``frames.count`` ends it earlier).
        objects: independently moving foreground objects and static cameras (off by
            default: one textured plane under a moving camera).
    """

    duration_s: float = 1.0
    frames: FrameConfig = field(default_factory=FrameConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    events: EventConfig = field(default_factory=EventConfig)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    objects: ObjectsConfig = field(default_factory=ObjectsConfig)

    def __post_init__(self) -> None:
        if self.duration_s <= 0:
            raise ValueError("duration_s must be positive")
        obj = self.objects
        if obj.static_camera_share > 0 and not obj.enabled and not self.events.noise.enabled:
            raise ValueError("objects.static_camera_share > 0 but objects.count allows no "
                             "object and events.noise is off: a static camera would see "
                             "nothing move")
