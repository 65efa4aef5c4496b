"""Shared fixtures: small procedural textures, scenes and trajectories (all seeded), and a
tiny simulated dataset."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import TrajectoryConfig, plane_extent_covering, sample_trajectory

REAL_EVENTS = Path(__file__).resolve().parents[2] / "shared" / "real_events"
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def tiny_shards(tmp_path_factory) -> Path:
    """A tiny simulated dataset (configs/datagen_tiny.yaml, 4 sequences), made once per
    test session and shared by the datagen and model tests."""
    from datagen.config import DatagenConfig
    from datagen.generate import generate
    from esim_lite.core.dataconf import load_config

    out = tmp_path_factory.mktemp("tiny_shards")
    cfg = load_config(DatagenConfig, ROOT / "configs" / "datagen_tiny.yaml")
    generate(cfg, out, n_seq=4, seed=11, show_progress=False)
    return out


def smooth_texture(seed: int, hw: tuple[int, int] = (384, 384), sigma: float = 3.0,
                   lo: float = 0.05, hi: float = 1.0) -> np.ndarray:
    """float32 band-limited random texture in [lo, hi] (a stand-in for a photograph)."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.random(hw).astype(np.float32), (0, 0), sigma)
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return (lo + (hi - lo) * tex).astype(np.float32)


def photo_texture() -> np.ndarray:
    """float32 linear texture from scikit-image's bundled 512x512 'camera' photograph."""
    from skimage import data

    return (data.camera().astype(np.float32) / 255.0).clip(0.01, 1.0)


def scene_and_trajectory(camera: Intrinsics, seed: int, duration_s: float = 0.3,
                         config: TrajectoryConfig | None = None,
                         texture: np.ndarray | None = None):
    """A random trajectory and a plane sized to fill the view for all of it."""
    rng = np.random.default_rng(seed)
    traj = sample_trajectory(config or TrajectoryConfig(), duration_s, camera, rng)
    tex = photo_texture() if texture is None else texture
    traj, w, h = plane_extent_covering(traj, camera, tex.shape[1] / tex.shape[0])
    return PlanarScene(tex, w, h), traj
