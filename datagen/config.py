"""The dataset generator's configuration record."""

from __future__ import annotations

from dataclasses import dataclass, field

from datagen.sensor_ranges import SensorRanges
from datagen.textures import TextureConfig
from esim_lite.config import FrameConfig, SimulationConfig


@dataclass(frozen=True)
class DatagenConfig:
    """Settings of a synthetic dataset.

    Attributes:
        simulation: camera rig, motion, event model, sampling and rendering per sequence.
            The dataset default renders a frame at every 3,000th event (one SBN stack of
            3 x 1,000 events, the paper's choice at 128x128) and ends a sequence after 64
            frames plus 4 stacks of events (at most 4 s): about 57 samples of 7 stacks per
            sequence, whatever the scene's event rate.
        sensor_ranges: which settings of ``simulation.events`` are drawn per sequence
            (domain randomisation of the sensor; all off: every sequence has that sensor).
        textures: where plane textures come from and how they vary.
        sequences_per_shard: sequences per HDF5 file (the unit of work and of resumption).
    """

    simulation: SimulationConfig = field(default_factory=lambda: SimulationConfig(
        duration_s=4.0, frames=FrameConfig(mode="events", every_events=3000, count=64,
                                           tail_events=12000)))
    sensor_ranges: SensorRanges = field(default_factory=SensorRanges)
    textures: TextureConfig = field(default_factory=TextureConfig)
    sequences_per_shard: int = 4

    def __post_init__(self) -> None:
        if self.sequences_per_shard < 1:
            raise ValueError("sequences_per_shard must be >= 1")
