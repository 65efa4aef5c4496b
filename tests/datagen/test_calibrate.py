"""``datagen calibrate`` and its estimators: each checked against a sensor whose parameters
are known (simulated, or drawn directly), and the real recordings read when present."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from datagen import sensor_stats as ss
from datagen.calibrate import calibrate_events
from datagen.cli import main
from datagen.config import DatagenConfig
from esim_lite.core.dataconf import load_config
from esim_lite.core.events import Events
from esim_lite.events.simulator import EventSimulator
from esim_lite.events.thresholds import ContrastThresholds

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT.parent / "shared" / "real_events"
C_POS, C_NEG, SHOT, LEAK, HOT, REFRACTORY = 0.25, 0.40, 0.4, 0.2, 0.002, 300_000


def _events(x, y, t, p, hw) -> Events:
    order = np.argsort(t, kind="stable")
    return Events(np.asarray(x, np.int16)[order], np.asarray(y, np.int16)[order],
                  np.asarray(t, np.int64)[order], np.asarray(p, np.int8)[order], hw)


def _poisson_noise(hw, rate_hz, seconds, on_share, rng):
    n = rng.poisson(rate_hz * seconds * hw[0] * hw[1])
    pix = rng.integers(0, hw[0] * hw[1], n)
    p = np.where(rng.random(n) < on_share, 1, -1)
    return pix % hw[1], pix // hw[1], rng.integers(0, int(seconds * 1e9), n), p


@pytest.fixture(scope="module")
def oracle(tmp_path_factory) -> tuple[Path, dict]:
    """A simulated recording with known thresholds (ON != OFF), mismatch, refractory
    period, shot, leak and hot-pixel noise, exported as ECD text and calibrated back
    through the command line."""
    tmp = tmp_path_factory.mktemp("calibrate")
    sets = ["simulation.duration_s=1.5", "simulation.frames={mode: rate, rate_hz: 40, count: null}",
            "simulation.camera.width=96", "simulation.camera.height=72",
            "simulation.events.random_start=true",
            f"simulation.events.thresholds={{pos_range: [{C_POS}, {C_POS}], "
            f"neg_range: [{C_NEG}, {C_NEG}], mismatch_std: 0.03}}",
            f"simulation.events.refractory_ns={REFRACTORY}",
            f"simulation.events.noise={{shot_rate_hz: {SHOT}, leak_rate_hz: {LEAK}, "
            f"hot_pixel_fraction: {HOT}, hot_pixel_rate_hz: 50}}"]
    args = ["generate", "--config", str(ROOT / "configs" / "datagen_tiny.yaml"), "--n-seq", "1",
            "--out", str(tmp / "shards"), "--workers", "1", "--no-progress", "--seed", "0"]
    assert main([*args, *(a for s in sets for a in ("--set", s))]) == 0
    assert main(["export", str(tmp / "shards"), "--format", "txt", "--out",
                 str(tmp / "txt")]) == 0
    preset = tmp / "preset.yaml"
    assert main(["calibrate", str(tmp / "txt" / "shard_00000_seq_000000"), "--out",
                 str(preset)]) == 0
    return preset, yaml.safe_load(preset.read_text())


def test_calibration_recovers_a_simulated_sensor(oracle):
    """Thresholds within 15%, background activity (shot + leak) within a factor 1.5."""
    _, data = oracle
    ev = data["simulation"]["events"]
    c_pos, c_neg = np.mean(ev["thresholds"]["pos_range"]), np.mean(ev["thresholds"]["neg_range"])
    assert abs(c_pos / C_POS - 1) < 0.15 and abs(c_neg / C_NEG - 1) < 0.15
    noise = ev["noise"]
    ba = noise["shot_rate_hz"] + noise["leak_rate_hz"]
    assert 1 / 1.5 < ba / (SHOT + LEAK) < 1.5
    assert noise["leak_rate_hz"] > 0  # the ON excess of the quiet events is there
    assert 0.3 * HOT <= noise["hot_pixel_fraction"] <= 1.5 * HOT
    assert ev["refractory_ns"] >= REFRACTORY  # an upper bound: nothing fires faster
    assert ev["flicker"]["frequency_hz"] == 0.0


def test_the_preset_loads_on_top_of_a_dataset_config(oracle):
    preset, data = oracle
    cfg = load_config(DatagenConfig, [ROOT / "configs" / "datagen_dynamic.yaml", preset])
    ev = cfg.simulation.events
    assert list(ev.thresholds.pos_range) == data["simulation"]["events"]["thresholds"][
        "pos_range"]
    assert cfg.simulation.objects.enabled  # the base config's keys stay
    assert "# C+" in preset.read_text() and "bootstrap" in preset.read_text()


def test_refractory_period_is_the_wall_of_the_intervals():
    """A pixel array driven hard (a new random texture every 0.1 ms) fires as fast as its
    refractory period lets it: the estimate lands on the period."""
    hw, refractory = (30, 40), 1_000_000
    th = ContrastThresholds.uniform(0.1, 0.1, hw)
    rng = np.random.default_rng(0)
    sim = EventSimulator(np.full(hw, 0.5, np.float32), 0, th, refractory_ns=refractory)
    evs = [sim.step((0.05 + 0.9 * rng.random(hw)).astype(np.float32), k * 100_000)
           for k in range(1, 2001)]
    est = ss.refractory_period(Events.concatenate(evs, hw))
    assert refractory <= est.value * 1e9 < 1.1 * refractory


def test_background_activity_of_pure_poisson_noise():
    hw, rng = (60, 80), np.random.default_rng(1)
    ev = _events(*_poisson_noise(hw, 2.0, 3.0, 0.7, rng), hw)
    ba = ss.background_activity(ev)
    assert abs(ba.rate_hz.value / 2.0 - 1) < 0.05
    assert abs(ba.on_fraction.value - 0.7) < 0.05
    assert abs(ba.leak_hz - 2.0 * 0.4) < 0.15 and abs(ba.shot_hz - 2.0 * 0.6) < 0.15


def test_background_activity_leaves_out_a_moving_edge():
    """A bar sweeping the sensor fires every pixel it crosses, in a burst: none of those
    events may count as background."""
    hw, rng = (60, 80), np.random.default_rng(2)
    x, y, t, p = _poisson_noise(hw, 0.5, 2.0, 0.5, rng)
    ys, xs = np.mgrid[0:hw[0], 0:hw[1]]
    for k in range(3):  # the edge crosses at 100 px/s, three events a pixel
        te = (xs.ravel() * 0.01 + k * 2e-4 + 0.1) * 1e9
        x, y = np.concatenate([x, xs.ravel()]), np.concatenate([y, ys.ravel()])
        t, p = np.concatenate([t, te.astype(np.int64)]), np.concatenate([p, np.ones(te.size)])
    ba = ss.background_activity(_events(x, y, t, p, hw))
    assert abs(ba.rate_hz.value / 0.5 - 1) < 0.15


def test_hot_pixels_are_found_and_only_they():
    hw, rng = (60, 80), np.random.default_rng(3)
    x, y, t, p = _poisson_noise(hw, 1.0, 2.0, 0.5, rng)
    hot = rng.choice(hw[0] * hw[1], 10, replace=False)
    n = rng.poisson(100 * 2.0, 10)
    hx, hy = np.repeat(hot % hw[1], n), np.repeat(hot // hw[1], n)
    ev = _events(np.concatenate([x, hx]), np.concatenate([y, hy]),
                 np.concatenate([t, rng.integers(0, 2e9, n.sum())]),
                 np.concatenate([p, np.ones(n.sum())]), hw)
    found = ss.hot_pixels(ev)
    assert set(np.flatnonzero(found.mask)) == set(hot.tolist())
    assert abs(found.rate_hz / 100 - 1) < 0.15 and found.on_fraction > 0.98  # noise too


def test_flicker_line_area_and_events_per_cycle():
    """A lamp at 100 Hz on a quarter of the sensor fires 2 events a cycle there (ON on the
    rise, OFF on the fall) beside Poisson noise; a noise-only recording has no line."""
    hw, rng, seconds = (40, 60), np.random.default_rng(4), 1.0
    x, y, t, p = _poisson_noise(hw, 1.0, seconds, 0.5, rng)
    ys, xs = np.mgrid[0:20, 0:30]
    cycles = np.arange(int(100 * seconds))
    lit = xs.size
    jitter = rng.normal(0, 2e-4, (2, len(cycles), lit))
    tt = np.concatenate([cycles[:, None] * 0.01 + 0.0025 + jitter[0],
                         cycles[:, None] * 0.01 + 0.0075 + jitter[1]])
    pp = np.concatenate([np.ones((len(cycles), lit)), -np.ones((len(cycles), lit))])
    xx, yy = np.tile(xs.ravel(), (2 * len(cycles), 1)), np.tile(ys.ravel(), (2 * len(cycles), 1))
    tt = np.clip(tt, 0, seconds - 1e-6) * 1e9
    ev = _events(np.concatenate([x, xx.ravel()]), np.concatenate([y, yy.ravel()]),
                 np.concatenate([t, tt.ravel().astype(np.int64)]),
                 np.concatenate([p, pp.ravel()]), hw)
    lamp = ss.flicker(ev)
    assert lamp.detected and lamp.frequency_hz == 100.0
    assert abs(lamp.area_fraction - 0.25) < 0.02
    assert abs(lamp.events_per_cycle - 2.0) < 0.2
    # depth from events per cycle: 2 events at C = 0.2 each way is a swing of 0.2
    assert abs(lamp.depth(0.2, 0.2) - np.tanh(0.1)) < 0.02
    assert not ss.flicker(_events(*_poisson_noise(hw, 1.0, seconds, 0.5, rng), hw)).detected


def test_without_frames_the_preset_says_thresholds_need_them():
    hw, rng = (40, 60), np.random.default_rng(5)
    cal = calibrate_events(_events(*_poisson_noise(hw, 2.0, 1.0, 0.5, rng), hw), None, "x")
    assert cal.thresholds is None and any("need APS frames" in n for n in cal.notes)
    from datagen.calibrate import preset_yaml

    text = preset_yaml(cal)
    events = yaml.safe_load(text)["simulation"]["events"]
    assert "thresholds" not in events and "need APS frames" in text
    on = float(np.mean(cal.stats.on_fraction))
    assert f"implies C+/C- = {(1 - on) / on:.2f}" in text  # 0.5 ON: 1.00
    assert events["noise"]["shot_rate_hz"] > 0


def test_bad_recordings_fail_with_the_file_named(tmp_path, capsys):
    empty = tmp_path / "empty" / "events.txt"
    empty.parent.mkdir()
    empty.write_text("")
    short = tmp_path / "short" / "events.txt"
    short.parent.mkdir()
    short.write_text("".join(f"{i * 1e-6:.6f} {i % 10} {i % 7} 1\n" for i in range(50)))
    broken = tmp_path / "broken.aedat4"
    broken.write_bytes(b"not an aedat4 file")
    for path in (empty, short, broken, tmp_path / "missing.h5"):
        out = tmp_path / "preset.yaml"
        assert main(["calibrate", str(path), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert str(path.name) in err and "Traceback" not in err
        assert not out.exists()


@pytest.mark.skipif(not (REAL / "davis346").is_dir(), reason="real recordings not present")
def test_a_real_davis346_recording_with_frames(tmp_path):
    out = tmp_path / "davis346.yaml"
    assert main(["calibrate", str(REAL / "davis346" / "street.aedat4"), "--out", str(out)]) == 0
    ev = yaml.safe_load(out.read_text())["simulation"]["events"]
    for key in ("pos_range", "neg_range"):
        lo, hi = ev["thresholds"][key]
        assert 0.05 < lo < hi < 1.5  # the literature's range for DAVIS sensors
    assert ev["noise"]["shot_rate_hz"] + ev["noise"]["leak_rate_hz"] < 1.0
    load_config(DatagenConfig, [ROOT / "configs" / "datagen.yaml", out])
