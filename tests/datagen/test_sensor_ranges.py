"""Per-sequence sensor randomisation (``sensor_ranges``): draws, determinism, what shards
record, and that a config without ranges draws and writes what it did before."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from datagen import generate as gen
from datagen.cli import main
from datagen.config import DatagenConfig
from datagen.sampling import sample_sequence
from datagen.sensor_ranges import RANGE_LIMITS, SensorRanges
from datagen.shard import SENSOR_ATTRS, ShardReader, sensor_attrs
from datagen.textures import TextureSampler
from esim_lite.core.dataconf import ConfigError, load_config, load_yaml_text
from esim_lite.events.simulator import EventConfig
from esim_lite.sequence import simulate_sequence

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "configs" / "datagen_tiny.yaml"
#: Every range on, each with its own span.
ALL = SensorRanges(mismatch_std=(0.0, 0.05), refractory_us=(0.0, 500.0),
                   shot_rate_hz=(0.01, 10.0), shot_bright_factor=(0.25, 1.0),
                   leak_rate_hz=(0.001, 1.0), hot_pixel_fraction=(0.0, 0.01),
                   hot_pixel_rate_hz=(1.0, 1000.0), cutoff_hz=(30.0, 3000.0),
                   bandwidth_share=0.7, flicker_share=0.4, flicker_depth=(0.05, 0.6),
                   flicker_area=(0.1, 0.9))


def tiny(*overrides: str) -> DatagenConfig:
    return load_config(DatagenConfig, TINY, list(overrides))


def draws(ranges: SensorRanges, n: int = 4000, seed: int = 0) -> dict[str, np.ndarray]:
    """``n`` drawn sensors as arrays of their stored values (:data:`SENSOR_ATTRS`)."""
    rng = np.random.default_rng(seed)
    rows = [sensor_attrs(ranges.draw(EventConfig(), rng)) for _ in range(n)]
    return {k: np.array([r[k] for r in rows], float) for k in SENSOR_ATTRS}


def test_draws_stay_inside_their_ranges_and_cover_them():
    d = draws(ALL)
    stored = {"mismatch_std": "mismatch_std", "refractory_us": "refractory_ns",
              "shot_rate_hz": "shot_rate_hz", "shot_bright_factor": "shot_bright_factor",
              "leak_rate_hz": "leak_rate_hz", "hot_pixel_fraction": "hot_pixel_fraction",
              "hot_pixel_rate_hz": "hot_pixel_rate_hz"}
    for name, key in stored.items():
        lo, hi = getattr(ALL, name)
        values = d[key] / (1e3 if key == "refractory_ns" else 1.0)
        assert lo <= values.min() and values.max() <= hi, name
        if name in ALL.log_uniform:  # coverage in the space the draw is uniform in
            values, lo, hi = np.log(values), np.log(lo), np.log(hi)
        span = hi - lo  # 4000 draws reach within 0.5% of either end
        assert values.min() - lo < 0.005 * span and hi - values.max() < 0.005 * span, name
    lamp = d["flicker_hz"] > 0
    for key, (lo, hi) in (("flicker_depth", ALL.flicker_depth),
                          ("flicker_area", ALL.flicker_area)):
        assert lo <= d[key][lamp].min() < lo + 0.01 and hi - 0.01 < d[key][lamp].max() <= hi
    on = d["cutoff_hz"] > 0
    assert 30.0 <= d["cutoff_hz"][on].min() and d["cutoff_hz"][on].max() <= 3000.0


def test_log_uniform_ranges_are_uniform_in_log_and_the_others_in_value():
    d = draws(ALL)
    for key in ("shot_rate_hz", "leak_rate_hz", "hot_pixel_rate_hz"):
        lo, hi = getattr(ALL, key)
        assert np.median(d[key]) == pytest.approx(np.sqrt(lo * hi), rel=0.15), key
        counts, _ = np.histogram(np.log(d[key]), bins=4, range=(np.log(lo), np.log(hi)))
        assert counts.min() > 0.85 * len(d[key]) / 4, key  # flat in log
    cutoff = d["cutoff_hz"][d["cutoff_hz"] > 0]
    assert np.median(cutoff) == pytest.approx(np.sqrt(30.0 * 3000.0), rel=0.15)
    assert np.median(d["shot_bright_factor"]) == pytest.approx(0.625, abs=0.03)
    linear = SensorRanges(shot_rate_hz=(0.01, 10.0), log_uniform=())
    assert np.median(draws(linear)["shot_rate_hz"]) == pytest.approx(5.0, rel=0.1)


def test_shares_choose_how_often_a_lamp_and_a_low_pass_appear():
    d = draws(ALL)
    lamp = d["flicker_hz"] > 0
    assert lamp.mean() == pytest.approx(0.4, abs=0.03)
    assert set(np.unique(d["flicker_hz"][lamp])) == {100.0, 120.0}
    assert (d["flicker_hz"][lamp] == 100.0).mean() == pytest.approx(0.5, abs=0.05)
    assert (d["cutoff_hz"] > 0).mean() == pytest.approx(0.7, abs=0.03)
    # without ranges of their own, the config's fixed cutoff and lamp are kept or dropped
    fixed = dataclasses.replace(EventConfig(), bandwidth=dataclasses.replace(
        EventConfig().bandwidth, cutoff_hz=300.0))
    sensors = [SensorRanges(bandwidth_share=0.5).draw(fixed, np.random.default_rng(i))
               for i in range(200)]
    assert {s.bandwidth.cutoff_hz for s in sensors} == {0.0, 300.0}
    assert SensorRanges(flicker_share=0.0).draw(EventConfig(), np.random.default_rng(0)) \
        .flicker.frequency_hz == 0.0


def test_turning_one_range_on_leaves_the_others_draws_unchanged():
    one = SensorRanges(shot_rate_hz=(0.1, 10.0))
    two = dataclasses.replace(one, refractory_us=(10.0, 100.0), flicker_share=0.5)
    a = one.draw(EventConfig(), np.random.default_rng(7))
    b = two.draw(EventConfig(), np.random.default_rng(7))
    assert a.noise == b.noise and a.refractory_ns == 0 < b.refractory_ns


def test_off_keeps_the_configs_sensor_itself():
    assert not SensorRanges().enabled and not DatagenConfig().sensor_ranges.enabled
    cfg = tiny()
    spec = sample_sequence(cfg.simulation, TextureSampler(cfg.textures), 3, 1,
                           cfg.sensor_ranges)
    assert spec.events is cfg.simulation.events and not spec.sensor_drawn


def test_the_sensor_stream_leaves_every_other_draw_unchanged():
    """An unrandomised config draws exactly what it drew before sensor ranges existed: the
    same trajectory, texture, thresholds and noise stream as with every range on."""
    cfg = tiny()
    tex = TextureSampler(cfg.textures)
    for index in range(3):
        plain = sample_sequence(cfg.simulation, tex, 9, index)
        ranged = sample_sequence(cfg.simulation, tex, 9, index, ALL)
        assert ranged.sensor_drawn and ranged.events != cfg.simulation.events
        assert plain.texture_name == ranged.texture_name
        np.testing.assert_array_equal(plain.trajectory.positions, ranged.trajectory.positions)
        np.testing.assert_array_equal(plain.background.texture, ranged.background.texture)
        assert (plain.thresholds.pos, plain.thresholds.neg) == \
            (ranged.thresholds.pos, ranged.thresholds.neg)
        assert plain.noise_rng.random() == ranged.noise_rng.random()


def test_the_sensor_is_determined_by_seed_and_index():
    cfg = tiny()
    tex = TextureSampler(cfg.textures)
    a = sample_sequence(cfg.simulation, tex, 4, 2, ALL).events
    assert a == sample_sequence(cfg.simulation, tex, 4, 2, ALL).events
    assert a != sample_sequence(cfg.simulation, tex, 4, 3, ALL).events
    assert a != sample_sequence(cfg.simulation, tex, 5, 2, ALL).events


def test_drawn_mismatch_reaches_the_threshold_maps():
    cfg = tiny()
    spec = sample_sequence(cfg.simulation, TextureSampler(cfg.textures), 1, 0,
                           SensorRanges(mismatch_std=(0.02, 0.03)))
    assert 0.02 <= spec.events.thresholds.mismatch_std <= 0.03
    assert spec.thresholds.has_mismatch


@pytest.mark.parametrize("text, key, problem", [
    ("shot_rate_hz: [5, 1]", "shot_rate_hz", "min <= max"),
    ("refractory_us: [-1, 10]", "refractory_us", "0.0 <= min"),
    ("shot_rate_hz: [0, 10]", "shot_rate_hz", "log-uniformly, so min must be > 0"),
    ("hot_pixel_fraction: [0, 2]", "hot_pixel_fraction", "<= 1.0"),
    ("flicker_depth: [0.1, 1.0]", "flicker_depth", "max must be < 1"),
    ("flicker_area: [0, 0.5]", "flicker_area", "min must be > 0"),
    ("flicker_share: 1.5", "flicker_share", "probability in [0, 1]"),
    ("bandwidth_share: -0.1", "bandwidth_share", "probability in [0, 1]"),
    ("flicker_frequencies_hz: []", "flicker_frequencies_hz", "frequencies > 0"),
    ("log_uniform: [shot_rate]", "log_uniform", "unknown name"),
    ("leak_rate: [1, 2]", "sensor_ranges.leak_rate", "unknown key"),
    ("cutoff_hz: [1, 2, 3]", "sensor_ranges.cutoff_hz", "matches none of"),
])
def test_bad_ranges_name_the_key(text, key, problem):
    with pytest.raises(ConfigError) as err:
        load_yaml_text(DatagenConfig, f"sensor_ranges: {{{text}}}", source="cfg.yaml")
    assert "cfg.yaml" in str(err.value) and key in str(err.value) \
        and problem in str(err.value), str(err.value)


def test_every_range_is_documented_in_the_default_config():
    text = (ROOT / "configs" / "datagen.yaml").read_text()
    section = text.split("\nsensor_ranges:")[1].split("\ntextures:")[0]
    for name in (*RANGE_LIMITS, "bandwidth_share", "flicker_share", "flicker_frequencies_hz",
                 "log_uniform"):
        assert f"\n  {name}:" in section and "#" in section.split(f"\n  {name}:")[1] \
            .split("\n")[0], name


def refractory_gaps(events) -> np.ndarray:
    """Time between each event and the previous one at the same pixel (ns)."""
    order = np.lexsort((events.t_ns, events.x, events.y))
    pix = events.y[order].astype(np.int64) * 1000 + events.x[order]
    t = events.t_ns[order]
    same = pix[1:] == pix[:-1]
    return np.diff(t)[same]


def test_a_generated_sequence_stores_and_obeys_the_sensor_it_drew(tmp_path, capsys):
    cfg = tiny("sensor_ranges.refractory_us=[10000, 30000]")  # the tiny scene is slow
    gen.generate(cfg, tmp_path, n_seq=2, seed=2, show_progress=False)
    tex = TextureSampler(cfg.textures)
    with ShardReader(tmp_path / "shard_00000.h5") as r:
        for index, name in enumerate(r.sequences()):
            spec = sample_sequence(cfg.simulation, tex, 2, index, cfg.sensor_ranges)
            stored = r.sensor(name)
            assert stored == sensor_attrs(spec.events)
            assert 10_000_000 <= stored["refractory_ns"] <= 30_000_000
            assert r.summary(name).sensor == stored
            gaps = refractory_gaps(r.events(name))
            assert len(gaps) and gaps.min() >= stored["refractory_ns"]
    # the last sequence without a refractory period fires faster than that
    plain = tiny()
    spec = sample_sequence(plain.simulation, tex, 2, 1)
    seq = simulate_sequence(spec.scene, spec.trajectory, spec.thresholds, plain.simulation,
                            spec.noise_rng)
    assert (refractory_gaps(seq.events) < stored["refractory_ns"]).mean() > 0.05
    assert main(["inspect", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count("sensor: refractory") == 2 and f"{stored['refractory_ns'] / 1e3:g} us" in out


def short_sequence_events(shot: tuple[float, float]) -> tuple[int, float]:
    """(events, drawn shot rate) of a 0.1 s tiny sequence whose shot noise is drawn from
    ``shot`` (a fixed duration: frames at a rate, no frame count ending it)."""
    cfg = tiny("simulation.duration_s=0.1", "simulation.frames.mode=rate",
               "simulation.frames.rate_hz=20", "simulation.frames.count=null",
               f"sensor_ranges.shot_rate_hz=[{shot[0]}, {shot[1]}]")
    spec = sample_sequence(cfg.simulation, TextureSampler(cfg.textures), 1, 0,
                           cfg.sensor_ranges)
    sim = dataclasses.replace(cfg.simulation, events=spec.events)
    seq = simulate_sequence(spec.scene, spec.trajectory, spec.thresholds, sim, spec.noise_rng)
    return len(seq.events), spec.events.noise.shot_rate_hz


def test_drawn_shot_noise_shows_in_the_event_count():
    n_low, low = short_sequence_events((0.1, 0.3))
    n_high, high = short_sequence_events((100.0, 300.0))
    assert 0.1 <= low <= 0.3 and 100 <= high <= 300
    pixels_s = 64 * 48 * 0.1  # the extra events are about the shot rate x pixels x time
    assert n_high - n_low == pytest.approx((high - low) * pixels_s, rel=0.1)


def test_shards_without_ranges_record_no_sensor(tmp_path, capsys):
    gen.generate(tiny(), tmp_path, n_seq=1, seed=0, show_progress=False)
    with ShardReader(tmp_path / "shard_00000.h5") as r:
        assert r.sensor("seq_000000") is None and r.summary("seq_000000").sensor is None
        assert not set(SENSOR_ATTRS) & set(r.file["seq_000000"].attrs)
    assert main(["inspect", str(tmp_path)]) == 0
    assert "sensor:" not in capsys.readouterr().out


def test_a_sensor_preset_layers_on_a_dataset_config_from_the_command_line(tmp_path):
    preset = tmp_path / "sensor.yaml"
    preset.write_text("simulation:\n  events:\n    refractory_ns: 100000\n"
                      "sensor_ranges:\n  shot_rate_hz: [0.5, 2.0]\n")
    out = tmp_path / "data"
    assert main(["generate", "--config", str(TINY), "--config", str(preset), "--n-seq", "1",
                 "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    with ShardReader(out / "shard_00000.h5") as r:
        cfg = load_yaml_text(DatagenConfig, r.config_yaml)
        sensor = r.sensor("seq_000000")
    assert cfg.simulation.camera.width == 64  # from the dataset config
    assert cfg.simulation.events.refractory_ns == 100_000  # from the preset
    assert sensor["refractory_ns"] == 100_000 and 0.5 <= sensor["shot_rate_hz"] <= 2.0
