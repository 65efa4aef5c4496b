"""What a DVS sensor is like, measured from its events (and APS frames when there are some).

Each estimator takes :class:`Events` (and :class:`Frames`) and returns a plain number or a
small record with its uncertainty; :mod:`datagen.calibrate` turns them into a sensor preset
and ``bench/bench_sensor_stats.py`` compares real recordings with simulated ones. The
estimators assume the simulator's sensor model (esim_lite.events): a pixel fires when its
log intensity moves a contrast threshold away from its reference, background activity is
spatially and temporally independent of the scene, a hot pixel fires far above its
neighbours, and a refractory period separates a pixel's events.

- **Contrast thresholds** (needs frames): between two frames a pixel's log intensity
  changes by ``dL = C+ N_on - C- N_off + r``, with ``r`` bounded by one threshold (where the
  pixel stands between its reference levels). A least-squares fit of ``dL`` on the event
  counts over every well-exposed pixel and frame interval gives ``C+`` and ``C-`` (v2e
  matches counts against frame changes the same way). The spread between pixels comes from
  per-pixel gains fitted on the odd and on the even intervals separately: their covariance
  across pixels is the true spread (the fitting noise of the two halves is independent).
  The uncertainty is a bootstrap over frame intervals.
- **Background activity**: events in space-time cells whose neighbourhood (5x5 pixels, the
  cell's time bin and the two beside it) holds no other event. For noise that is independent
  of the scene, the count in a cell does not depend on its neighbours, so the rate over
  quiet cells is unbiased; signal events, which come in clusters along moving edges, are
  left out. Bins widen until the estimate stops falling (less signal leaking in) or too
  little quiet volume is left. The ON share of those events splits the rate into leak
  (ON only) and shot noise (either polarity).
- **Hot pixels**: a pixel that fires at least ``HOT_MIN_EVENTS`` and ``HOT_RATIO`` times
  more than the busiest of its 8 neighbours.
- **Refractory period**: a low quantile of the intervals between a pixel's consecutive
  events (hot pixels left out). With a scene fast enough to make a pixel fire in bursts,
  the intervals pile up at the refractory period; with a slow scene it is an upper bound.
- **Flicker**: a line at 100 or 120 Hz in the spectra of the ON and the OFF event rates
  (their sum has its line at twice that when a lamp fires as many of each), the share of
  pixels whose events lock to its phase, and the modulation depth their events per cycle
  imply for given thresholds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from esim_lite.core.events import Events
from esim_lite.core.frames import Frames

#: A hot pixel fires at least this many events ...
HOT_MIN_EVENTS = 20
#: ... and this many times more than the busiest of its 8 neighbours.
HOT_RATIO = 8.0
#: Mains flicker lines looked for (50 Hz and 60 Hz grids).
FLICKER_LINES_HZ = (100.0, 120.0)
#: A line counts as flicker when its power is this many times the median nearby.
FLICKER_MIN_RATIO = 10.0
#: Frame pixels used for thresholds: well exposed in both frames (linear intensity).
EXPOSED = (0.05, 0.95)
#: Pixels used for thresholds move at least this much in log intensity over the frames.
MIN_CHANGE = 1.0


@dataclass(frozen=True)
class Estimate:
    """A measured value and its standard uncertainty (``nan`` when not measurable)."""

    value: float
    std: float

    def __str__(self) -> str:
        return f"{self.value:.4g} +- {self.std:.2g}"


@dataclass(frozen=True)
class Thresholds:
    """Contrast thresholds estimated from events against frames.

    Attributes:
        pos, neg: ON and OFF thresholds (log units).
        mismatch: relative spread of a pixel's thresholds around them (std / mean).
        intervals: frame intervals used; pixels: pixels with a per-pixel gain in both halves.
    """

    pos: Estimate
    neg: Estimate
    mismatch: Estimate
    intervals: int
    pixels: int


@dataclass(frozen=True)
class BackgroundActivity:
    """Background activity per pixel.

    Attributes:
        rate_hz: events per pixel per second away from the scene's signal.
        on_fraction: their ON share (leak fires ON only; shot noise either way).
        bin_s: the time bin of the quiet cells used; events: events counted.
        quiet_fraction: share of the recording's pixel-time that was quiet.
    """

    rate_hz: Estimate
    on_fraction: Estimate
    bin_s: float
    events: int
    quiet_fraction: float

    @property
    def leak_hz(self) -> float:
        """The ON-only part of the rate: ``rate (2 on - 1)``, at least 0."""
        return max(0.0, self.rate_hz.value * (2 * self.on_fraction.value - 1))

    @property
    def shot_hz(self) -> float:
        """The either-polarity part: the rest of the rate."""
        return max(0.0, self.rate_hz.value - self.leak_hz)


@dataclass(frozen=True)
class HotPixels:
    """Pixels firing far above their neighbours.

    Attributes:
        mask: bool[H, W]; fraction: their share of the sensor; rate_hz: their median rate
            (nan without any); on_fraction: ON share of their events.
    """

    mask: np.ndarray
    fraction: float
    rate_hz: float
    on_fraction: float


@dataclass(frozen=True)
class Flicker:
    """A mains flicker line in the event rate.

    Attributes:
        frequency_hz: the stronger of the 100 and 120 Hz lines; line_ratio: its power over
            the median power nearby; detected: ``line_ratio >= FLICKER_MIN_RATIO``.
        area_fraction: share of the sensor whose events lock to the line's phase.
        events_per_cycle: median events per cycle at those pixels.
    """

    frequency_hz: float
    line_ratio: float
    detected: bool
    area_fraction: float
    events_per_cycle: float

    def depth(self, c_pos: float, c_neg: float) -> float:
        """The modulation depth ``m`` that makes ``events_per_cycle`` events at thresholds
        ``c_pos``/``c_neg``: a swing of ``ln((1 + m) / (1 - m))`` in log light fires
        ``swing / C+`` ON and ``swing / C-`` OFF events per cycle."""
        swing = self.events_per_cycle / (1 / c_pos + 1 / c_neg)
        return float(math.tanh(swing / 2))


@dataclass(frozen=True)
class EventStats:
    """Summary statistics of an event stream.

    Attributes:
        duration_s, events: span and count; rate_hz: events per pixel per second;
        on_fraction: ON share; active_fraction: share of pixels with any event;
        iei_ms: percentiles (1, 10, 50, 90, 99) of the intervals between a pixel's
            consecutive events, milliseconds.
    """

    duration_s: float
    events: int
    rate_hz: float
    on_fraction: float
    active_fraction: float
    iei_ms: tuple[float, float, float, float, float]


IEI_PERCENTILES = (1, 10, 50, 90, 99)


def _pixels(events: Events) -> np.ndarray:
    return events.y.astype(np.int64) * events.sensor_hw[1] + events.x.astype(np.int64)


def duration_s(events: Events) -> float:
    """The span of the events, seconds (at least 1 us)."""
    return max(float(events.t_ns[-1] - events.t_ns[0]), 1e3) * 1e-9


def inter_event_intervals(events: Events, exclude: np.ndarray | None = None) -> np.ndarray:
    """int64 intervals (ns) between each pixel's consecutive events, pixels in ``exclude``
    (bool[H, W]) left out."""
    pix = _pixels(events)
    keep = slice(None) if exclude is None else ~exclude.ravel()[pix]
    pix, t = pix[keep], events.t_ns[keep]
    order = np.lexsort((t, pix))
    pix, t = pix[order], t[order]
    same = pix[1:] == pix[:-1]
    return np.diff(t)[same]


def event_stats(events: Events) -> EventStats:
    """Rate, ON share, active pixels and inter-event-interval percentiles."""
    h, w = events.sensor_hw
    dur = duration_s(events)
    iei = inter_event_intervals(events)
    pct = tuple(float(v) * 1e-6 for v in np.percentile(iei, IEI_PERCENTILES)) if len(iei) \
        else (math.nan,) * len(IEI_PERCENTILES)
    counts = np.bincount(_pixels(events), minlength=h * w)
    return EventStats(dur, len(events), len(events) / (h * w * dur),
                      float(np.mean(events.p > 0)), float(np.mean(counts > 0)), pct)


def hot_pixels(events: Events) -> HotPixels:
    """Pixels with at least ``HOT_MIN_EVENTS`` events and ``HOT_RATIO`` times the count of
    the busiest of their 8 neighbours."""
    h, w = events.sensor_hw
    pix = _pixels(events)
    counts = np.bincount(pix, minlength=h * w).reshape(h, w)
    footprint = np.ones((3, 3), bool)
    footprint[1, 1] = False
    busiest = ndimage.maximum_filter(counts, footprint=footprint, mode="constant")
    mask = (counts >= HOT_MIN_EVENTS) & (counts >= HOT_RATIO * np.maximum(busiest, 1))
    if not mask.any():
        return HotPixels(mask, 0.0, math.nan, math.nan)
    on = np.bincount(pix, weights=(events.p > 0).astype(float), minlength=h * w)
    return HotPixels(mask, float(mask.mean()),
                     float(np.median(counts[mask]) / duration_s(events)),
                     float(on.reshape(h, w)[mask].sum() / counts[mask].sum()))


_NEIGHBOURHOOD = np.array([(db, dy, dx) for db in (-1, 0, 1) for dy in range(-2, 3)
                           for dx in range(-2, 3)], np.int64)


def _quiet_rate(events: Events, bin_s: float, keep: np.ndarray, on: np.ndarray
                ) -> tuple[float, float, int, int, float]:
    """(rate, ON share, events, quiet cells, quiet fraction) over space-time cells with no
    other event in their 5x5 x 3-bin neighbourhood. Whole bins only (a partial last bin is
    left out), and neither the first nor the last one (their neighbourhoods reach outside
    the recording). Sparse: only cells near an event are visited, one neighbourhood offset
    at a time (memory in proportion to the events, not 75 times that)."""
    h, w = events.sensor_hw
    bin_ns = max(int(round(bin_s * 1e9)), 1)
    full = int((events.t_ns[-1] - events.t_ns[0]) // bin_ns)
    if full < 3:
        return math.nan, math.nan, 0, 0, 0.0
    b = (events.t_ns[keep] - events.t_ns[0]) // bin_ns
    cells = (b * h + events.y[keep]) * w + events.x[keep]
    occupied, own = np.unique(cells, return_counts=True)
    own_on = np.bincount(np.searchsorted(occupied, cells[on[keep]]), minlength=len(occupied))
    # the events in every occupied cell's neighbourhood (its own included)
    total = np.zeros(len(occupied), np.int64)
    for ids, src in _neighbours(occupied, h, w, 0, len(occupied)):
        j = np.searchsorted(occupied, ids).clip(max=len(occupied) - 1)
        hit = occupied[j] == ids
        np.add.at(total, src[hit], own[j[hit]])
    ob = occupied // (h * w)
    valid_occ = (ob >= 1) & (ob < full - 1)
    quiet_occ = valid_occ & (total - own == 0)
    # a cell within reach of an event is noisy unless the only events there are its own
    n_noisy = _reached(occupied, h, w, h * w, (full - 1) * h * w) - int(quiet_occ.sum())
    n_cells = (full - 2) * h * w
    n_quiet = n_cells - n_noisy
    n_ev = int(own[quiet_occ].sum())
    if n_quiet <= 0:
        return math.nan, math.nan, 0, 0, 0.0
    on_share = float(own_on[quiet_occ].sum() / n_ev) if n_ev else math.nan
    return n_ev / (n_quiet * bin_s), on_share, n_ev, n_quiet, n_quiet / n_cells


def _neighbours(occupied: np.ndarray, h: int, w: int, lo: int, hi: int):
    """(cell ids, index of the source cell) of each neighbourhood offset of the occupied
    cells ``lo..hi-1``, only those inside the sensor and from bin 0 on; one offset at a
    time."""
    src = np.arange(lo, hi)
    ob, rem = np.divmod(occupied[lo:hi], h * w)
    oy, ox = np.divmod(rem, w)
    for db, dy, dx in _NEIGHBOURHOOD:
        ny, nx, nb = oy + dy, ox + dx, ob + db
        ok = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w) & (nb >= 0)
        yield ((nb * h + ny) * w + nx)[ok], src[ok]


def _reached(occupied: np.ndarray, h: int, w: int, first: int, stop: int) -> int:
    """How many distinct cells with ids in ``[first, stop)`` lie in the neighbourhood of an
    occupied cell, counted on a bitmap one block of cell ids at a time."""
    reach = h * w + 2 * w + 2  # the farthest a neighbour's id lies from its cell's
    span = max(1 << 23, 2 * reach)
    home = np.unique(occupied // span)
    count = 0
    for block in np.unique(np.concatenate([home - 1, home, home + 1])):
        a, z = max(int(block) * span, first), min((int(block) + 1) * span, stop)
        lo, hi = np.searchsorted(occupied, [a - reach, z + reach])
        if z <= a or lo == hi:
            continue
        mask = np.zeros(z - a, bool)
        for ids, _ in _neighbours(occupied, h, w, int(lo), int(hi)):
            mask[ids[(ids >= a) & (ids < z)] - a] = True
        count += int(np.count_nonzero(mask))
    return count


def background_activity(events: Events, exclude: np.ndarray | None = None
                        ) -> BackgroundActivity:
    """Background-activity rate per pixel (see the module docstring), leaving out the
    pixels in ``exclude`` (bool[H, W], e.g. hot pixels) entirely.

    Bins of 1 ms and up, doubling while the estimate keeps falling by more than its own
    uncertainty and at least a tenth of the pixel-time stays quiet; the last such bin wins.
    """
    keep = np.ones(len(events), bool) if exclude is None else ~exclude.ravel()[_pixels(events)]
    on = events.p > 0
    dur = duration_s(events)
    best = None
    bin_s = 1e-3
    while bin_s <= dur / 4:
        rate, on_share, n_ev, n_quiet, frac = _quiet_rate(events, bin_s, keep, on)
        if n_quiet == 0 or frac < 0.1:
            break
        current = (rate, on_share, n_ev, bin_s, frac)
        if best is not None:
            err = best[0] / math.sqrt(max(best[2], 1))
            if best[0] - rate <= err:  # no longer falling: signal no longer leaks in
                best = current if n_ev > best[2] else best
                break
        best = current
        bin_s *= 2
    if best is None:
        return BackgroundActivity(Estimate(math.nan, math.nan), Estimate(math.nan, math.nan),
                                  math.nan, 0, 0.0)
    rate, on_share, n_ev, bin_s, frac = best
    n = max(n_ev, 1)
    on_std = math.sqrt(max(on_share * (1 - on_share), 0.25 / n) / n) if n_ev else math.nan
    return BackgroundActivity(Estimate(rate, rate / math.sqrt(n)), Estimate(on_share, on_std),
                              bin_s, n_ev, frac)


def refractory_period(events: Events, exclude: np.ndarray | None = None,
                      quantile: float = 0.001) -> Estimate:
    """A low ``quantile`` of the intervals between a pixel's events (seconds), with the
    spread between the quantiles at half and twice ``quantile`` as its uncertainty."""
    iei = inter_event_intervals(events, exclude)
    if len(iei) < 100:
        return Estimate(math.nan, math.nan)
    lo, mid, hi = np.quantile(iei, [quantile / 2, quantile, min(2 * quantile, 1.0)]) * 1e-9
    return Estimate(float(mid), float(hi - lo) / 2)


def flicker(events: Events, exclude: np.ndarray | None = None, bin_s: float = 2.5e-4
            ) -> Flicker:
    """The stronger of the 100/120 Hz lines in the event-rate spectrum (module docstring)."""
    h, w = events.sensor_hw
    dur = duration_s(events)
    pix_all = _pixels(events)
    keep = np.ones(len(events), bool) if exclude is None else ~exclude.ravel()[pix_all]
    t = (events.t_ns[keep] - events.t_ns[0]) * 1e-9
    n_bins = int(dur / bin_s)
    if n_bins < 64 or dur < 0.05:
        return Flicker(math.nan, math.nan, False, 0.0, math.nan)
    slot = np.minimum((t / bin_s).astype(np.int64), n_bins - 1)
    on = events.p[keep] > 0
    power = np.zeros(n_bins // 2 + 1)
    for part in (on, ~on):  # ON and OFF apart: a lamp's fundamental is in each
        rate = np.bincount(slot[part], minlength=n_bins).astype(np.float64)
        power += np.abs(np.fft.rfft((rate - rate.mean()) * np.hanning(n_bins))) ** 2
    freqs = np.fft.rfftfreq(n_bins, bin_s)
    df = freqs[1]
    best = (math.nan, 0.0)
    for f in FLICKER_LINES_HZ:
        line = np.abs(freqs - f) <= max(2 * df, 2.0)
        near = (np.abs(freqs - f) > max(4 * df, 5.0)) & (freqs >= 0.5 * f) & (freqs <= 2.5 * f)
        if not line.any() or near.sum() < 4:
            continue
        ratio = float(power[line].max() / max(np.median(power[near]), 1e-12))
        if ratio > best[1]:
            best = (float(f), ratio)
    f, ratio = best
    if not ratio >= FLICKER_MIN_RATIO:
        return Flicker(f, ratio, False, 0.0, math.nan)
    # phase locking per pixel: Rayleigh test of the phases at f of its ON events, and of
    # its OFF events (half a cycle apart under a sine: together they would cancel)
    pix = pix_all[keep]
    phase = 2 * np.pi * f * t
    n = np.bincount(pix, minlength=h * w).astype(np.float64)
    z = np.zeros(h * w)
    for part in (on, ~on):
        m = np.bincount(pix[part], minlength=h * w).astype(np.float64)
        c = np.bincount(pix[part], weights=np.cos(phase[part]), minlength=h * w)
        s = np.bincount(pix[part], weights=np.sin(phase[part]), minlength=h * w)
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.fmax(z, np.where(m >= 2, (c ** 2 + s ** 2) / m, 0.0))
    locked = (n >= 4) & (z > 6.0)  # Rayleigh p < 0.0025 per pixel
    per_cycle = float(np.median(n[locked]) / (dur * f)) if locked.any() else math.nan
    return Flicker(f, ratio, True, float(locked.mean()), per_cycle)


def replay_counts(logs: np.ndarray, c_pos: np.ndarray | float, c_neg: np.ndarray | float,
                  phase: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """ON and OFF counts an ideal pixel fires while its log intensity moves linearly from
    each frame's value to the next (``logs``: float[T, P]): the event model's hysteresis (a
    reversal must cross both thresholds' worth before it fires) included, which a
    count-per-change ratio leaves out. The reference starts ``phase`` (in [0, 1), default
    0.5) of the way from ``L - C+`` to ``L + C-``: a pixel of a running sensor stands
    anywhere between its two levels when a recording starts."""
    share = 0.5 if phase is None else phase
    ref = logs[0] - c_pos + share * (np.asarray(c_pos) + np.asarray(c_neg))
    on = np.zeros(logs.shape[1])
    off = np.zeros(logs.shape[1])
    for row in logs[1:]:
        up = np.floor(np.maximum(row - ref, 0.0) / c_pos)
        down = np.floor(np.maximum(ref - row, 0.0) / c_neg)
        ref = ref + up * c_pos - down * c_neg
        on += up
        off += down
    return on, off


def _match(logs: np.ndarray, n_on: float, n_off: float, phase: np.ndarray, rounds: int = 8
           ) -> tuple[float, float]:
    """(C+, C-) whose replayed totals over ``logs`` equal the observed ``n_on``, ``n_off``:
    each threshold bisected in turn (its own count falls as it grows) until both settle
    to 0.1% or ``rounds`` pass."""
    c_pos = c_neg = 0.2
    for _ in range(rounds):
        before = (c_pos, c_neg)
        for which in ("pos", "neg"):
            lo, hi = 0.01, 4.0
            for _ in range(16):
                mid = math.sqrt(lo * hi)
                on, off = replay_counts(logs, mid if which == "pos" else c_pos,
                                        mid if which == "neg" else c_neg, phase)
                fired = on.sum() if which == "pos" else off.sum()
                target = n_on if which == "pos" else n_off
                lo, hi = (mid, hi) if fired > target else (lo, mid)
            if which == "pos":
                c_pos = math.sqrt(lo * hi)
            else:
                c_neg = math.sqrt(lo * hi)
        if abs(c_pos / before[0] - 1) < 1e-3 and abs(c_neg / before[1] - 1) < 1e-3:
            break
    return c_pos, c_neg


def thresholds(events: Events, frames: Frames, log_eps: float = 1e-3,
               exposed: tuple[float, float] = EXPOSED, exclude: np.ndarray | None = None,
               background: BackgroundActivity | None = None,
               min_change: float = MIN_CHANGE, n_boot: int = 10,
               seed: int = 0) -> Thresholds:
    """ON/OFF thresholds and their spread between pixels from events against frames.

    The thresholds are the ones for which an ideal pixel, its log intensity moving linearly
    from frame to frame, fires as many ON and as many OFF events as the sensor did, over the
    pixels well exposed in every frame whose log intensity moves at least ``min_change``
    in all (summed over frame intervals; chosen by the frames, never by their counts, so
    that noise weighs less without biasing the fit; :func:`replay_counts`). Changes that
    the frames do not see (a reversal inside one interval) fire events the replay does not
    count, so with frames far apart for the scene's motion the estimate runs low. The
    uncertainty is a bootstrap over pixels; the spread between pixels is the covariance of
    per-pixel gains (observed against replayed counts) of the first and second half of the
    recording, whose fitting noise is independent. Pixels in ``exclude`` (bool[H, W], e.g.
    hot pixels) are left out, and the events ``background`` activity fires in that time are
    taken off the observed counts (ON and OFF by its ON share).

    Raises:
        ValueError: fewer than two frames, frames of another size than the events' sensor,
            or no well-exposed pixel that fired both ways.
    """
    if len(frames) < 2:
        raise ValueError("thresholds need at least two frames")
    if frames.hw != events.sensor_hw:
        raise ValueError(f"frames {frames.hw} and events {events.sensor_hw} differ in size")
    h, w = events.sensor_hw
    img = frames.intensity.reshape(len(frames), -1)
    good = _fit_pixels(img, log_eps, exposed, min_change, exclude)
    inside = (events.t_ns > frames.t_ns[0]) & (events.t_ns <= frames.t_ns[-1])
    pix = events.y[inside].astype(np.int64) * w + events.x[inside]
    on = events.p[inside] > 0
    n_on = np.bincount(pix[on], minlength=h * w).astype(float)
    n_off = np.bincount(pix[~on], minlength=h * w).astype(float)
    use = np.flatnonzero(good & ((n_on + n_off) > 0))
    if not len(use) or n_on[use].sum() == 0 or n_off[use].sum() == 0:
        raise ValueError("no pixel well exposed in every frame fired both ON and OFF events "
                         "between the first and last frame")
    logs = np.log(log_eps + img[:, use].astype(np.float64))
    noise_on, noise_off = _background_counts(background,
                                             (frames.t_ns[-1] - frames.t_ns[0]) * 1e-9)

    def signal(pick: np.ndarray) -> tuple[float, float]:
        return (max(n_on[use][pick].sum() - noise_on * len(pick), 1.0),
                max(n_off[use][pick].sum() - noise_off * len(pick), 1.0))

    everyone = np.arange(len(use))
    rng = np.random.default_rng(seed)
    phase = rng.random(len(use))
    c_pos, c_neg = _match(logs, *signal(everyone), phase)
    boot = []
    for _ in range(n_boot):
        pick = rng.integers(0, len(use), len(use))
        boot.append(_match(logs[:, pick], *signal(pick), phase[pick], rounds=4))
    pos_std, neg_std = (float(v) for v in np.std(np.array(boot), axis=0))
    mismatch, pixels = _mismatch(logs, c_pos, c_neg, phase, frames, events.t_ns[inside],
                                 h * w, pix, use)
    return Thresholds(Estimate(float(c_pos), pos_std), Estimate(float(c_neg), neg_std),
                      mismatch, len(frames) - 1, pixels)


def _fit_pixels(img: np.ndarray, log_eps: float, exposed: tuple[float, float],
                min_change: float, exclude: np.ndarray | None) -> np.ndarray:
    """bool[H * W]: the pixels the thresholds are fitted on (``img``: [T, H * W] frames):
    well exposed in every frame, their log intensity moving at least ``min_change`` in
    all, not in ``exclude``. Chosen by the frames alone: no bias on the counts."""
    lo, hi = exposed
    good = np.all((img >= lo) & (img <= hi), axis=0)
    moving = np.abs(np.diff(np.log(log_eps + img.astype(np.float64)), axis=0)).sum(0)
    good &= moving >= min_change
    if exclude is not None:
        good &= ~exclude.ravel()
    return good


def _background_counts(background: BackgroundActivity | None, span_s: float
                       ) -> tuple[float, float]:
    """ON and OFF events per pixel that ``background`` activity fires in ``span_s``."""
    if background is None or not math.isfinite(background.rate_hz.value):
        return 0.0, 0.0
    share = background.on_fraction.value if math.isfinite(
        background.on_fraction.value) else 0.5
    return (background.rate_hz.value * share * span_s,
            background.rate_hz.value * (1 - share) * span_s)


def _mismatch(logs: np.ndarray, c_pos: float, c_neg: float, phase: np.ndarray,
              frames: Frames, t_ns: np.ndarray, size: int, pix: np.ndarray, use: np.ndarray
              ) -> tuple[Estimate, int]:
    """The spread of thresholds between pixels (std / mean) and the pixels it rests on: the
    covariance of per-pixel gains (replayed / observed counts) on the first and on the
    second half of the frames, whose fitting noise is independent. ``t_ns``, ``pix``: the
    times and flat pixel indices (of ``size``) of the events between the first and last
    frame; ``use``: the fitted pixels, the columns of ``logs``."""
    mid_t = frames.t_ns[len(frames) // 2]
    gains = []
    for part, sel in ((slice(0, len(frames) // 2 + 1), t_ns <= mid_t),
                      (slice(len(frames) // 2, None), t_ns > mid_t)):
        obs = np.bincount(pix[sel], minlength=size).astype(float)[use]
        r_on, r_off = replay_counts(logs[part], c_pos, c_neg, phase)
        rep = r_on + r_off
        with np.errstate(invalid="ignore", divide="ignore"):
            gains.append(np.where((obs >= 4) & (rep >= 4), rep / obs, np.nan))
    both = np.isfinite(gains[0]) & np.isfinite(gains[1])
    if both.sum() < 20:
        return Estimate(math.nan, math.nan), int(both.sum())
    g0, g1 = gains[0][both], gains[1][both]
    cov = float(np.mean((g0 - g0.mean()) * (g1 - g1.mean())))
    scale = float(np.mean(np.concatenate([g0, g1])))
    spread = math.sqrt(max(cov, 0.0)) / scale
    spread_std = float(np.std(g0 - g1) / math.sqrt(2 * both.sum())) / scale
    return Estimate(spread, spread_std), int(both.sum())
