"""The dataset generator's configuration record."""

from __future__ import annotations

from dataclasses import dataclass, field

from datagen.textures import TextureConfig
from esim_lite.config import SimulationConfig


@dataclass(frozen=True)
class DatagenConfig:
    """Settings of a synthetic dataset.

    Attributes:
        simulation: camera rig, motion, event model, sampling and rendering per sequence.
        textures: where plane textures come from and how they vary.
    """

    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    textures: TextureConfig = field(default_factory=TextureConfig)
