"""A flickering lamp: events only where it lights the scene, as many as its swing gives."""

from __future__ import annotations

import math

import numpy as np
import pytest

from esim_lite.config import CameraConfig, SimulationConfig
from esim_lite.core.dataconf import ConfigError, from_mapping
from esim_lite.core.events import Events
from esim_lite.events.flicker import Flicker, FlickerConfig
from esim_lite.events.simulator import EventConfig
from esim_lite.events.thresholds import ContrastThresholds
from esim_lite.geometry.camera import Intrinsics
from esim_lite.geometry.object_sampling import static_trajectory
from esim_lite.geometry.pose import Pose
from esim_lite.geometry.scene import PlanarScene
from esim_lite.geometry.trajectory import LOOK_DOWN
from esim_lite.render.renderer import RenderConfig
from esim_lite.sequence import simulate


def test_a_flickering_lamp_fires_only_where_it_lights_at_its_swing():
    """A grey plane under a static camera, a 100 Hz lamp of depth 0.5 on 30% of the view:
    per period a lit pixel's log light swings by ``2 log((1+m)/(1-m))``, so with C = 0.2 it
    fires 5-6 ON and 5-6 OFF events per period; nothing fires elsewhere."""
    cam = Intrinsics.from_fov(32, 24, 60.0)
    scene = PlanarScene(np.full((64, 64), 0.4, np.float32), 4.0, 4.0)
    traj = static_trajectory(Pose(LOOK_DOWN, np.array([0.0, 0.0, 1.0])), 0.1, 0.05)
    flicker = FlickerConfig(frequency_hz=100.0, depth=0.5, area_fraction=0.3)
    cfg = SimulationConfig(duration_s=0.1, camera=CameraConfig(width=32, height=24,
                                                              scales=(2,)),
                           events=EventConfig(flicker=flicker),
                           render=RenderConfig(backend="homography"))
    th = ContrastThresholds.uniform(0.2, 0.2, cam.hw)
    ev = Events.concatenate([c.events for c in simulate(scene, traj, th, cfg,
                                                        np.random.default_rng(3))], cam.hw)
    lamp = Flicker(flicker, cam.hw, np.random.default_rng(3))  # the same draws
    lit = lamp.mask
    assert abs(lit.mean() - 0.3) < 0.05
    assert lit[ev.y, ev.x].all()
    per_pixel = np.bincount(ev.y.astype(np.int64) * 32 + ev.x, minlength=32 * 24)
    swing = math.log(1.5 / 0.5)  # one half-period, one direction
    periods = 0.1 * 100
    low, high = 2 * math.floor(swing / 0.2) * (periods - 1), 2 * math.ceil(swing / 0.2) * \
        (periods + 1)
    assert np.all((per_pixel[lit.ravel()] >= low) & (per_pixel[lit.ravel()] <= high))
    assert abs((ev.p > 0).mean() - 0.5) < 0.05


def test_the_step_bound_holds_the_log_change_of_the_modulation():
    cfg = FlickerConfig(frequency_hz=120.0, depth=0.6)
    lamp = Flicker(cfg, (4, 4), np.random.default_rng(0))
    dt = lamp.max_step(0.05)
    t = np.linspace(0, 1 / 120, 2000)
    g = np.array([lamp.gain(int(s * 1e9)) for s in t])
    rate = np.abs(np.diff(np.log(g))) / np.diff(t)
    assert rate.max() * dt <= 0.05 * 1.0001
    assert rate.max() * dt >= 0.05 * 0.99  # and is tight


@pytest.mark.parametrize(("key", "value"), [("frequency_hz", -1), ("depth", 1.0),
                                            ("area_fraction", 0)])
def test_bad_flicker_settings_fail_naming_the_key(key, value):
    with pytest.raises(ConfigError, match=f"flicker.{key}"):
        from_mapping(SimulationConfig, {"events": {"flicker": {"frequency_hz": 100,
                                                               key: value}}})
