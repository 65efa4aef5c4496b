"""The simulator's configuration record (one sequence's worth of settings)."""

from __future__ import annotations

from dataclasses import dataclass, field

from esim_lite.camera import CameraRig, Intrinsics
from esim_lite.renderer import RenderConfig
from esim_lite.sampling import SamplingConfig
from esim_lite.simulator import EventConfig
from esim_lite.trajectory import TrajectoryConfig


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
        if not self.scales or any(s not in (1, 2, 3, 4, 8) for s in self.scales):
            raise ValueError(f"scales must be a non-empty subset of 1,2,3,4,8; got {self.scales}")

    def rig(self) -> CameraRig:
        return CameraRig(Intrinsics.from_fov(self.width, self.height, self.fov_x_deg),
                         tuple(self.scales))


@dataclass(frozen=True)
class SimulationConfig:
    """Everything the simulator needs besides the scene and the random draws.

    Attributes:
        duration_s: sequence length.
        frame_rate_hz: rate of the LR (APS-like) and HR frames.
    """

    duration_s: float = 1.0
    frame_rate_hz: float = 50.0
    camera: CameraConfig = field(default_factory=CameraConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    events: EventConfig = field(default_factory=EventConfig)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    render: RenderConfig = field(default_factory=RenderConfig)

    def __post_init__(self) -> None:
        if self.duration_s <= 0 or self.frame_rate_hz <= 0:
            raise ValueError("duration_s and frame_rate_hz must be positive")
