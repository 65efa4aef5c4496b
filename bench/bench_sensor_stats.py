"""Event statistics of real recordings beside simulated ones made with the sensor preset
measured from them, on a comparable scene.

Run: .venv/bin/python bench/bench_sensor_stats.py [--seeds N] [--quick] [--out PATH]
         [--real-root DIR]   (default: ../shared/real_events beside the repository)

Two pairs, each skipped with a message when its real recordings are absent:

- ``davis346 street``: ``davis346/street.aedat4`` (a static DAVIS346 over a street with cars,
  2.36 s) against ``configs/datagen_dynamic.yaml`` + ``configs/sensors/davis346.yaml``: a
  346x260 static camera over a textured plane with 2-4 small, far, slow objects
  (:data:`CARS`), 2.4 s, the exact ``reference`` renderer, frames at 25 Hz (an APS's rate),
  no ground truth.
- ``davis240c ECD``: the eight 30,000-event Event Camera Dataset snippets (``ecd_snippets/``,
  5-106 ms each) against ``configs/datagen.yaml`` + ``configs/sensors/davis240c.yaml``: a
  240x180 camera moving over a textured plane (builtin textures, homography renderer, exact
  for a plane), 0.3 s.

Each simulated sequence is drawn and simulated in memory as ``datagen generate`` would
(``sample_sequence`` then ``simulate``; sequence ``i`` of seed 0), and every recording, real
or simulated, goes through the same estimators of :mod:`datagen.sensor_stats`: event_stats,
hot_pixels, background_activity (hot pixels left out) and refractory_period. Several
recordings (the ECD snippets, the seeds) are summarised by the rule ``datagen calibrate``
uses for a preset: the median for the rate, ON share and intervals; the smallest finite
value for the statistics each recording only bounds from above (background activity, with
the ON share of the same recording; refractory wall; hot-pixel share).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path

from datagen import sensor_stats as ss
from esim_lite.core.events import Events
from esim_lite.events.simulator import EventConfig

ROOT = Path(__file__).resolve().parents[1]
REAL_ROOT = ROOT.parent / "shared" / "real_events"
ECD = ("boxes_rotation", "boxes_translation", "dynamic_rotation", "dynamic_translation",
       "poster_rotation", "poster_translation", "shapes_rotation", "shapes_translation")
NO_GT = ("simulation.frames={mode: rate, rate_hz: 25.0, count: null}",
         "simulation.frames.ground_truth=[]")

#: Objects like the street's cars: small, far from the camera (slow on the sensor), moving
#: without spinning; datagen_dynamic's own objects (up to half the view, close, spinning at
#: up to 90 deg/s) fire ~5-10x the street's events and cost ~10x the render steps.
CARS = ("simulation.objects.size_fraction=[0.08, 0.2]",
        "simulation.objects.depth_fraction=[0.6, 0.9]",
        "simulation.objects.speed_m_s=[0.05, 0.2]",
        "simulation.objects.angular_speed_deg_s=[0.0, 10.0]")


@dataclass(frozen=True)
class Pair:
    """A real sensor's recordings and the simulated scene set beside them.

    Attributes:
        name: the table's title; real: recordings (any format ``open_recording`` reads);
        sensor_hw: (H, W) for readers that need it (ECD text), None to take the file's;
        configs: the dataset config, then the sensor preset; sets: ``--set`` overrides;
        quick: overrides for ``--quick`` (shorter), applied last.
    """

    name: str
    real: tuple[Path, ...]
    sensor_hw: tuple[int, int] | None
    configs: tuple[Path, ...]
    sets: tuple[str, ...]
    quick: tuple[str, ...]


def make_pairs(real_root: Path) -> list[Pair]:
    street = Pair(
        "davis346 street", (real_root / "davis346" / "street.aedat4",), None,
        (ROOT / "configs" / "datagen_dynamic.yaml", ROOT / "configs" / "sensors" / "davis346.yaml"),
        ("simulation.camera.width=346", "simulation.camera.height=260",
         "simulation.duration_s=2.4", *NO_GT, "simulation.objects.static_camera_share=1.0",
         "simulation.objects.count=[2, 4]", *CARS, "simulation.render.backend=reference"),
        ("simulation.duration_s=0.6",))
    ecd = Pair(
        "davis240c ECD", tuple(real_root / "ecd_snippets" / s for s in ECD), (180, 240),
        (ROOT / "configs" / "datagen.yaml", ROOT / "configs" / "sensors" / "davis240c.yaml"),
        ("simulation.camera.width=240", "simulation.camera.height=180",
         "simulation.duration_s=0.3", *NO_GT, "simulation.render.backend=homography"),
        ("simulation.duration_s=0.15",))
    return [street, ecd]


@dataclass(frozen=True)
class Row:
    """One recording's statistics (rates per pixel, intervals in ms)."""

    rate_hz: float
    on_share: float
    ba_hz: float
    ba_on: float
    iei_p1: float
    iei_p10: float
    iei_p50: float
    refractory_ms: float
    hot_share: float


HEADER = ("events/pixel/s", "ON share", "BA rate (Hz/pixel)", "BA ON share", "IEI p1 (ms)",
          "IEI p10 (ms)", "IEI p50 (ms)", "refractory wall (ms)", "hot-pixel share")


def measure(events: Events) -> Row:
    """The benchmark's statistics of one recording, by the estimators ``calibrate`` uses."""
    st = ss.event_stats(events)
    hot = ss.hot_pixels(events)
    ba = ss.background_activity(events, hot.mask)
    ref = ss.refractory_period(events, hot.mask)
    return Row(st.rate_hz, st.on_fraction, ba.rate_hz.value, ba.on_fraction.value,
               *st.iei_ms[:3], ref.value * 1e3, hot.fraction)


def stated(sensor: EventConfig) -> Row:
    """What the simulator was told (the preset): background activity as shot + leak, its
    ON share (leak fires ON only), the refractory period and the hot-pixel share; nan for
    what the scene decides."""
    noise = sensor.noise
    ba = noise.shot_rate_hz + noise.leak_rate_hz
    ba_on = (noise.leak_rate_hz + noise.shot_rate_hz / 2) / ba if ba > 0 else math.nan
    return Row(math.nan, math.nan, ba, ba_on, math.nan, math.nan, math.nan,
               sensor.refractory_ns * 1e-6, noise.hot_pixel_fraction)


def summarise(rows: list[Row]) -> Row:
    """Several recordings as one row: medians, and the smallest finite value of the
    statistics a recording bounds from above (background activity with its own ON share,
    refractory wall, hot-pixel share), as ``datagen calibrate`` builds a preset."""
    def median(name: str) -> float:
        vals = [getattr(r, name) for r in rows if math.isfinite(getattr(r, name))]
        return statistics.median(vals) if vals else math.nan

    def smallest(name: str) -> Row | None:
        ok = [r for r in rows if math.isfinite(getattr(r, name))]
        return min(ok, key=lambda r: getattr(r, name)) if ok else None

    quiet, wall = smallest("ba_hz"), smallest("refractory_ms")
    return Row(median("rate_hz"), median("on_share"),
               quiet.ba_hz if quiet else math.nan, quiet.ba_on if quiet else math.nan,
               median("iei_p1"), median("iei_p10"), median("iei_p50"),
               wall.refractory_ms if wall else math.nan, min(r.hot_share for r in rows))


def real_events(pair: Pair) -> list[tuple[str, Events]]:
    from datagen.recording import open_recording  # readers only when they are needed

    return [(path.name, open_recording(path, pair.sensor_hw).read_all()) for path in pair.real]


def simulated_events(pair: Pair, quick: bool, index: int, seed: int = 0
                     ) -> tuple[Events, EventConfig]:
    """Sequence ``index`` of the pair's dataset (seed ``seed``), simulated in memory as
    ``datagen generate`` would simulate it: its events and the sensor it was given."""
    import dataclasses

    from datagen.config import DatagenConfig
    from datagen.sampling import sample_sequence
    from datagen.textures import TextureSampler
    from esim_lite.core.dataconf import load_config
    from esim_lite.sequence import simulate

    config = load_config(DatagenConfig, list(pair.configs),
                         [*pair.sets, *(pair.quick if quick else ())])
    spec = sample_sequence(config.simulation, TextureSampler(config.textures), seed, index,
                           config.sensor_ranges)
    sim = dataclasses.replace(config.simulation, events=spec.events)
    parts = [chunk.events for chunk in simulate(spec.scene, spec.trajectory, spec.thresholds,
                                                sim, spec.noise_rng)]
    return Events.concatenate(parts, sim.camera.rig().event.hw), spec.events


def _cell(value: float, missing: str = "n/a") -> str:
    if not math.isfinite(value):
        return missing
    return "0" if value == 0 else f"{value:.3g}"


def _ratio(sim: float, real: float) -> str:
    if not (math.isfinite(sim) and math.isfinite(real)):
        return "n/a"
    if real == 0:
        return "both 0" if sim == 0 else "inf"
    return f"{sim / real:.2f}"


def table(pair: Pair, real: Row, sim: Row, told: Row, n_real: int, n_sim: int
          ) -> list[str]:
    names = [f.name for f in fields(Row)]

    def line(label: str, row: Row, missing: str = "n/a") -> str:
        return f"| {label} | " + " | ".join(_cell(getattr(row, n), missing)
                                            for n in names) + " |"

    return [f"| {pair.name} | " + " | ".join(HEADER) + " |",
            "|---" * (len(HEADER) + 1) + "|",
            line(f"real ({n_real})", real),
            line(f"simulated ({n_sim})", sim),
            "| sim / real | " + " | ".join(_ratio(getattr(sim, n), getattr(real, n))
                                           for n in names) + " |",
            line("preset (told to the simulator)", told, "")]


def per_source(named: list[tuple[str, Events, Row]]) -> list[str]:
    lines = ["| source | events | seconds | " + " | ".join(HEADER) + " |",
             "|---" * (len(HEADER) + 3) + "|"]
    for name, ev, row in named:
        lines.append(f"| {name} | {len(ev):,} | {ss.duration_s(ev):.3f} | "
                     + " | ".join(_cell(getattr(row, f.name)) for f in fields(Row)) + " |")
    return lines


NOTES = (
    "Events/pixel/s, IEI p50 and the refractory wall follow the scene (speed, texture "
    "contrast, object count): compare them as scenes, not sensors. The sensor's own "
    "statistics are the ON share, the background activity (BA) rate and ON share, the IEI "
    "low percentiles where bursts reach the refractory period, and the hot-pixel share.",
    "BA and the refractory wall are upper bounds (signal leaks into quiet cells; a slow "
    "scene never shows the wall); several recordings keep the smallest, as calibrate does. "
    "n/a: not measurable (BA needs at least three whole bins of quiet space-time).",
)


def run_pair(pair: Pair, seeds: int, quick: bool) -> list[str] | None:
    missing = [p for p in pair.real if not p.exists()]
    if missing:
        print(f"# {pair.name}: skipped, {len(missing)} real recording(s) absent "
              f"(first: {missing[0]})", flush=True)
        return None
    reals = [(name, ev, measure(ev)) for name, ev in real_events(pair)]
    sims, seconds = [], []
    for index in range(seeds):
        start = time.perf_counter()
        ev, sensor = simulated_events(pair, quick, index)
        seconds.append(time.perf_counter() - start)
        sims.append((f"simulated seq {index}", ev, measure(ev)))
    lines = table(pair, summarise([r for _, _, r in reals]),
                  summarise([r for _, _, r in sims]), stated(sensor), len(reals), len(sims))
    lines += ["", *per_source(reals + sims), "",
              f"Simulated: {seeds} sequence(s), seed 0, {statistics.median(seconds):.0f} s "
              "each (median, simulation only); configs "
              + " + ".join(str(p.relative_to(ROOT)) for p in pair.configs) + " with "
              + ", ".join(f"`{s}`" for s in (*pair.sets, *(pair.quick if quick else ())))
              + "."]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=3,
                        help="simulated sequences per pair (sequence indices 0..N-1)")
    parser.add_argument("--quick", action="store_true",
                        help="shorter simulated sequences (a smoke run)")
    parser.add_argument("--out", type=Path, help="also write the tables here (markdown)")
    parser.add_argument("--real-root", type=Path, default=REAL_ROOT,
                        help="folder holding davis346/ and ecd_snippets/")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    start = time.perf_counter()
    command = " ".join([".venv/bin/python bench/bench_sensor_stats.py",
                        *(sys.argv[1:] if argv is None else argv)])
    out = [f"`{command}`", ""]
    print(out[0], flush=True)
    for pair in make_pairs(args.real_root):
        lines = run_pair(pair, args.seeds, args.quick)
        if lines is None:
            continue
        print("\n" + "\n".join(lines), flush=True)
        out += [*lines, ""]
    notes = [*NOTES, f"Total {time.perf_counter() - start:.0f} s."]
    print("\n" + "\n".join(notes))
    out += notes
    if args.out:
        args.out.write_text("\n".join(out) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
