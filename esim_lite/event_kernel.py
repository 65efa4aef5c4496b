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
    dt = float(t1 - t0)
    n = 0
    for y in range(h):
        for x in range(w):
            r = ref[y, x]
            new = np.float64(l1[y, x])
            d = new - r
            if d >= c_pos[y, x] - tol:
                c = c_pos[y, x]
                pol = 1
            elif d <= tol - c_neg[y, x]:
                c = -c_neg[y, x]
                pol = -1
            else:
                continue
            k = int(np.floor((d + pol * tol) / c))
            if n + k > buf_x.shape[0]:
                buf_x, buf_y, buf_t, buf_p = _grow(buf_x, buf_y, buf_t, buf_p, n + k)
            old = np.float64(l0[y, x])
            slope = new - old
            last = last_t[y, x]
            for i in range(1, k + 1):
                # Levels the line does not reach from above (slope of the wrong sign: only
                # when the caller moved ref behind L0) were already passed at t0.
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
    return n, buf_x, buf_y, buf_t, buf_p
