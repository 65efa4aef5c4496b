"""The compiled per-pixel ESIM event kernel (numba).

Model (Rebecq et al., ESIM, CoRL 2018), per pixel between two rendered samples
``(t0, L0)`` and ``(t1, L1)`` of the log intensity, with reference level ``ref``:

- the pixel emits one event per threshold level ``ref + k C+`` (ON) or ``ref - k C-``
  (OFF) reached by ``L1``; level ``k`` gets the timestamp where the straight line from
  ``L0`` to ``L1`` crosses it, rounded to the nanosecond;
- the reference moves to the last level reached, ``ref + n C``;
- an event closer than ``refractory_ns`` to the pixel's previous *emitted* event is
  dropped, but its level still moves the reference (ESIM's rule).

Tie rule: a level counts as reached when ``L1`` is within :data:`TIE_TOL` of it, so a change
of exactly ``C`` (up to float32 rounding of the log image, < 5e-7 for ``|L| < 8``) fires
exactly one event, stamped at ``t1``. The reference is kept in float64 and advanced by
``n * C`` per step (one rounding per step, not per event), so it does not drift over
millions of events the way repeated float32 additions do.

Speed (bench/bench_events.py): a step runs in two passes, a vectorised flagging of the
pixels that reach a level and the emission loop over the flagged ones, which never
reallocates its buffers (when they are full it returns, and the caller grows them and
resumes at that pixel); then a radix sort by time puts the events in the order
``np.lexsort((x, y, t))`` would, so the caller sorts nothing.
"""

from __future__ import annotations

import numba
import numpy as np

#: Levels within this distance (log units) of L1 count as reached; see the module doc.
TIE_TOL = 1e-6
#: ``last_t`` value of a pixel that never fired.
NEVER = np.iinfo(np.int64).min // 4


@numba.njit(cache=True, nogil=True)
def _grow(buf_x, buf_y, buf_t, buf_p, need):
    cap = max(2 * buf_x.shape[0], need)
    nx = np.empty(cap, np.int16)
    ny = np.empty(cap, np.int16)
    nt = np.empty(cap, np.int64)
    npol = np.empty(cap, np.int8)
    n = buf_x.shape[0]
    nx[:n] = buf_x
    ny[:n] = buf_y
    nt[:n] = buf_t
    npol[:n] = buf_p
    return nx, ny, nt, npol


@numba.njit(cache=True, nogil=True)
def esim_step(l0, l1, ref, last_t, c_pos, c_neg, t0, t1, refractory_ns, tol,
              buf_x, buf_y, buf_t, buf_p):
    """Advance every pixel from sample ``(t0, l0)`` to ``(t1, l1)``; updates state in place.

    Args:
        l0, l1: float32[H, W] log intensity at the previous and the new sample.
        ref: float64[H, W] reference levels (updated).
        last_t: int64[H, W] time of each pixel's last emitted event (updated).
        c_pos, c_neg: float64[H, W] per-pixel thresholds.
        t0, t1: int64 sample times in ns, t1 > t0.
        buf_*: output buffers (int16 x, int16 y, int64 t, int8 p), grown if needed.
    Returns:
        (n, buf_x, buf_y, buf_t, buf_p): the first ``n`` buffer entries are the events, in
        pixel order (row-major), each pixel's events in time order.
    """
    h, w = l1.shape
    padded = np.zeros((h * w + 7) // 8 * 8, np.int8)  # whole 8-byte words
    flags = padded[:h * w].reshape(h, w)
    _flag_pixels(l1, ref, c_pos, c_neg, tol, flags)
    words = padded.view(np.uint64)
    n, q = 0, 0
    while True:
        n, q = _emit(l0, l1, ref, last_t, c_pos, c_neg, flags, words, t0, t1, refractory_ns,
                     tol, buf_x, buf_y, buf_t, buf_p, n, q)
        if q == h * w:
            return n, buf_x, buf_y, buf_t, buf_p
        buf_x, buf_y, buf_t, buf_p = _grow(buf_x, buf_y, buf_t, buf_p, 0)


@numba.njit(cache=True, nogil=True)
def _flag_pixels(l1, ref, c_pos, c_neg, tol, flags):
    """First pass: ``flags[y, x]`` = +1 where the pixel reaches an ON level, -1 an OFF
    level, 0 neither. Compares and selects only, so the compiler vectorises it."""
    h, w = l1.shape
    for y in range(h):
        for x in range(w):
            d = np.float64(l1[y, x]) - ref[y, x]
            up = d >= c_pos[y, x] - tol
            down = d <= tol - c_neg[y, x]
            flags[y, x] = 1 if up else (-1 if down else 0)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _emit(l0, l1, ref, last_t, c_pos, c_neg, flags, words, t0, t1, refractory_ns, tol,
          buf_x, buf_y, buf_t, buf_p, n, start):
    """Second pass, from pixel ``start`` (row-major index) with ``n`` events already in the
    buffers: the events of every flagged pixel. ``words``: the flags read 8 at a time, so
    that runs of 8 quiet pixels cost one test. Stops before a pixel whose events would not
    fit and returns ``(n, that pixel)`` so that the caller grows the buffers and resumes
    (``(n, H * W)`` when done); the buffers are never reallocated inside this loop, so it
    keeps their pointers in registers."""
    h, w = l1.shape
    size = h * w
    dt = float(t1 - t0)
    cap = buf_x.shape[0]
    for wi in range(start // 8, words.shape[0]):
        if words[wi] == 0:
            continue
        first = max(8 * wi, start)
        y = first // w
        x = first - y * w
        for q in range(first, min(8 * wi + 8, size)):
            pol = flags[y, x]
            if pol != 0:
                c = c_pos[y, x] if pol > 0 else -c_neg[y, x]
                r = ref[y, x]
                new = np.float64(l1[y, x])
                k = int(np.floor((new - r + pol * tol) / c))
                if n + k > cap:
                    return n, q
                old = np.float64(l0[y, x])
                slope = new - old
                last = last_t[y, x]
                for i in range(1, k + 1):
                    # Levels the line does not reach from above (slope of the wrong sign:
                    # only when the caller moved ref behind L0) were already passed at t0.
                    frac = (r + i * c - old) / slope if slope * pol > 0 else 0.0
                    frac = min(max(frac, 0.0), 1.0)
                    t = t0 + np.int64(np.floor(frac * dt + 0.5))
                    if t - last >= refractory_ns:
                        buf_x[n] = x
                        buf_y[n] = y
                        buf_t[n] = t
                        buf_p[n] = pol
                        n += 1
                        last = t
                last_t[y, x] = last
                ref[y, x] = r + k * c
            x += 1
            if x == w:
                x = 0
                y += 1
    return n, size


@numba.njit(cache=True, nogil=True)
def time_order(t, n, t0, span):
    """Stable permutation that sorts ``t[:n]`` (int64, all in ``[t0, t0 + span]``) by time.

    An LSD radix sort on the offsets ``t - t0`` in bytes, as many passes as ``span`` has bytes,
    skipping a pass whose byte is the same for every event: O(n) per pass, and stable, so
    events with equal times keep the order they were emitted in.
    """
    order = np.arange(n)
    key = np.empty(n, np.int64)
    for i in range(n):
        key[i] = t[i] - t0
    tmp_order = np.empty(n, np.int64)
    tmp_key = np.empty(n, np.int64)
    count = np.empty(256, np.int64)
    shift = 0
    while shift < 63 and (span >> shift) > 0:
        count[:] = 0
        for i in range(n):
            count[(key[i] >> shift) & 255] += 1
        if n > 0 and count[(key[0] >> shift) & 255] != n:
            total = 0
            for d in range(256):
                c = count[d]
                count[d] = total
                total += c
            for i in range(n):
                d = (key[i] >> shift) & 255
                j = count[d]
                tmp_order[j] = order[i]
                tmp_key[j] = key[i]
                count[d] = j + 1
            order, tmp_order = tmp_order, order
            key, tmp_key = tmp_key, key
        shift += 8
    return order


@numba.njit(cache=True, nogil=True)
def esim_step_sorted(l0, l1, ref, last_t, c_pos, c_neg, t0, t1, refractory_ns, tol,
                     capacity):
    """:func:`esim_step` with its events returned in time order, in new exact-size arrays.

    Pixels are visited in row-major order and each pixel's events come out in time order, so a
    stable sort by time gives the order of ``np.lexsort((x, y, t))``: by time, then row, then
    column, then emission. ``capacity``: size of the first work buffers (a guess of the
    number of events; they grow as needed).

    Returns:
        (x, y, t, p): the events.
    """
    cap = max(capacity, 16)
    n, buf_x, buf_y, buf_t, buf_p = esim_step(
        l0, l1, ref, last_t, c_pos, c_neg, t0, t1, refractory_ns, tol,
        np.empty(cap, np.int16), np.empty(cap, np.int16), np.empty(cap, np.int64),
        np.empty(cap, np.int8))
    order = time_order(buf_t, n, t0, t1 - t0)
    x = np.empty(n, np.int16)
    y = np.empty(n, np.int16)
    t = np.empty(n, np.int64)
    p = np.empty(n, np.int8)
    for i in range(n):
        j = order[i]
        x[i] = buf_x[j]
        y[i] = buf_y[j]
        t[i] = buf_t[j]
        p[i] = buf_p[j]
    return x, y, t, p
