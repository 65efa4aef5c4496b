"""YAML configs into frozen dataclasses: errors name the file and the key."""

from __future__ import annotations

import pytest

from esim_lite.config import SimulationConfig
from esim_lite.core.dataconf import ConfigError, apply_overrides, load_yaml, load_yaml_text, to_yaml


def test_round_trip_through_yaml():
    cfg = SimulationConfig()
    assert load_yaml_text(SimulationConfig, to_yaml(cfg)) == cfg


def test_nested_values_and_overrides(tmp_path):
    path = tmp_path / "sim.yaml"
    path.write_text("duration_s: 2\ncamera:\n  scales: [2, 4]\nevents:\n  refractory_ns: 1000\n")
    cfg = load_yaml(SimulationConfig, path, ["render.backend=homography",
                                             "events.thresholds.pos_range=[0.2, 0.4]"])
    assert cfg.duration_s == 2.0 and cfg.camera.scales == (2, 4)
    assert cfg.events.refractory_ns == 1000
    assert cfg.render.backend == "homography"
    assert cfg.events.thresholds.pos_range == (0.2, 0.4)


@pytest.mark.parametrize("text, key, problem", [
    ("durration_s: 1\n", "durration_s", "unknown key"),
    ("camera:\n  widht: 3\n", "camera.widht", "unknown key"),
    ("render:\n  backend: vulkan\n", "render.backend", "not one of"),
    ("camera:\n  width: many\n", "camera.width", "expected an integer"),
    ("events:\n  thresholds:\n    pos_range: [0.5, 0.1]\n", "events.thresholds",
     "min <= max"),
    ("sampling:\n  adaptive: 1\n", "sampling.adaptive", "true/false"),
])
def test_bad_configs_name_the_file_and_key(tmp_path, text, key, problem):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_yaml(SimulationConfig, path)
    assert str(path) in str(err.value) and key in str(err.value) and problem in str(err.value)


def test_a_top_level_that_is_not_a_mapping_is_named(tmp_path):
    path = tmp_path / "list.yaml"
    path.write_text("- camera\n- width: 3\n")
    with pytest.raises(ConfigError, match=r"list.yaml: the top level must be a mapping .* "
                                          r"not a list"):
        load_yaml(SimulationConfig, path, ["camera.width=4"])


def test_missing_file_and_bad_override(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        load_yaml(SimulationConfig, tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="key=value"):
        apply_overrides({}, ["render.backend"])
    with pytest.raises(ConfigError, match="not a section"):
        apply_overrides({"duration_s": 1}, ["duration_s.x=2"])


def test_partial_sections_keep_the_parents_defaults():
    """A parent may default a nested section differently from that section's class; a
    partial override of the section must keep the parent's values for the other keys."""
    from datagen.config import DatagenConfig

    base = DatagenConfig()
    cfg = load_yaml_text(DatagenConfig, "simulation:\n  render:\n    backend: homography\n")
    assert cfg.simulation.render.backend == "homography"
    assert cfg.simulation.frames == base.simulation.frames
    assert cfg.simulation.duration_s == base.simulation.duration_s != SimulationConfig().duration_s


def test_scientific_notation_without_a_dot_is_a_number():
    """YAML 1.1 reads 1e-4 as a string; a float field accepts it anyway."""
    cfg = load_yaml_text(SimulationConfig, "sampling:\n  min_step_s: 1e-5\n")
    assert cfg.sampling.min_step_s == 1e-5


def test_load_config_applies_file_then_set_then_typed_values(tmp_path):
    """The loader both CLIs share: typed flag values win over ``--set`` strings, which win
    over the file; typed values get the same checks, errors name the file and key."""
    from esim_lite.core.dataconf import load_config

    path = tmp_path / "sim.yaml"
    path.write_text("duration_s: 2\ncamera:\n  scales: [2]\n")
    cfg = load_config(SimulationConfig, path, ["camera.scales=[4]", "camera.width=80"],
                      {"camera.scales": [2, 4]})
    assert cfg.camera.scales == (2, 4) and cfg.camera.width == 80 and cfg.duration_s == 2.0
    assert load_config(SimulationConfig, path) == load_yaml(SimulationConfig, path)
    defaults = load_config(SimulationConfig, None, values={"render.backend": "homography"})
    assert defaults.render.backend == "homography"
    assert defaults.camera == SimulationConfig().camera
    with pytest.raises(ConfigError, match=r"sim.yaml: camera.width: expected an integer"):
        load_config(SimulationConfig, path, values={"camera.width": "wide"})
    with pytest.raises(ConfigError, match=r"--set: camera.widht: unknown key"):
        load_config(SimulationConfig, None, values={"camera.widht": 3})


def test_several_files_layer_in_order_key_by_key(tmp_path):
    """Later files override earlier ones key by key (a deep merge), so a partial preset
    loads on top of a full config; ``--set`` and typed values still win over all files."""
    from esim_lite.core.dataconf import load_config

    base = tmp_path / "base.yaml"
    base.write_text("duration_s: 2\ncamera:\n  width: 80\n  scales: [2]\nevents:\n"
                    "  refractory_ns: 5\n  noise:\n    shot_rate_hz: 1.0\n")
    preset = tmp_path / "preset.yaml"
    preset.write_text("events:\n  noise:\n    leak_rate_hz: 0.5\n  refractory_ns: 7\n")
    last = tmp_path / "last.yaml"
    last.write_text("events:\n  refractory_ns: 9\ncamera:\n  scales: [4]\n")
    cfg = load_config(SimulationConfig, [base, preset])
    assert cfg.duration_s == 2.0 and cfg.camera.width == 80  # kept from the base
    assert cfg.events.noise.shot_rate_hz == 1.0 and cfg.events.noise.leak_rate_hz == 0.5
    assert cfg.events.refractory_ns == 7
    cfg = load_config(SimulationConfig, [base, preset, last], ["duration_s=3"])
    assert cfg.events.refractory_ns == 9 and cfg.camera.scales == (4,)  # lists replaced
    assert cfg.duration_s == 3.0 and cfg.events.noise.leak_rate_hz == 0.5
    assert load_config(SimulationConfig, [preset, base]).events.refractory_ns == 5
    assert load_config(SimulationConfig, [base]) == load_config(SimulationConfig, base)
    assert load_config(SimulationConfig, []) == SimulationConfig()


@pytest.mark.parametrize("text, key, problem", [
    ("events:\n  noise:\n    shot_rate: 1\n", "events.noise.shot_rate", "unknown key"),
    ("camera:\n  width: wide\n", "camera.width", "expected an integer"),
    ("events:\n  refractory_ns: -1\n", "events", "refractory_ns must be >= 0"),
])
def test_a_bad_key_in_a_later_file_names_that_file(tmp_path, text, key, problem):
    from esim_lite.core.dataconf import load_config

    first, second, third = (tmp_path / f"{n}.yaml" for n in ("first", "second", "third"))
    first.write_text("duration_s: 2\n")
    second.write_text(text)
    third.write_text("duration_s: 3\n")
    with pytest.raises(ConfigError) as err:
        load_config(SimulationConfig, [first, second, third])
    message = str(err.value)
    assert message.startswith(f"{second}: ") and key in message and problem in message
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        load_config(SimulationConfig, [first, tmp_path / "nope.yaml"])
