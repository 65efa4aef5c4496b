"""Two plain implementations of the event model of :mod:`esim_lite.events.kernel`.

They exist as test oracles and benchmark baselines, written independently of the compiled
kernel: ``python_step`` is the model read aloud (one pixel, one level at a time);
``numpy_step`` is the vectorised per-frame version one would write first in numpy. All three
share the signature ``step(l0, l1, ref, last_t, c_pos, c_neg, t0, t1, refractory_ns, tol)``,
update ``ref``/``last_t`` in place and return ``(x, y, t, p)`` arrays in any order.
"""

from __future__ import annotations

import math

import numpy as np


def python_step(l0, l1, ref, last_t, c_pos, c_neg, t0, t1, refractory_ns, tol):
    """Per-pixel Python loop: walk the levels one at a time while they are reached."""
    xs, ys, ts, ps = [], [], [], []
    h, w = l1.shape
    for y in range(h):
        for x in range(w):
            old, new = float(l0[y, x]), float(l1[y, x])
            level_up = ref[y, x] + c_pos[y, x]
            level_down = ref[y, x] - c_neg[y, x]
            if new >= level_up - tol:
                pol, step = 1, c_pos[y, x]
            elif new <= level_down + tol:
                pol, step = -1, -c_neg[y, x]
            else:
                continue
            k = 0
            while pol * (new - (ref[y, x] + (k + 1) * step)) >= -tol:
                k += 1
            for i in range(1, k + 1):
                level = ref[y, x] + i * step
                frac = (level - old) / (new - old) if (new - old) * pol > 0 else 0.0
                t = t0 + math.floor(min(max(frac, 0.0), 1.0) * (t1 - t0) + 0.5)
                if t - last_t[y, x] >= refractory_ns:
                    xs.append(x)
                    ys.append(y)
                    ts.append(t)
                    ps.append(pol)
                    last_t[y, x] = t
            ref[y, x] = ref[y, x] + k * step
    return (np.array(xs, np.int16), np.array(ys, np.int16), np.array(ts, np.int64),
            np.array(ps, np.int8))


def numpy_step(l0, l1, ref, last_t, c_pos, c_neg, t0, t1, refractory_ns, tol):
    """Vectorised over pixels; loops only over the k-th level of the busiest pixel."""
    old = l0.astype(np.float64)
    new = l1.astype(np.float64)
    d = new - ref
    up = d >= c_pos - tol
    down = ~up & (d <= tol - c_neg)
    step = np.where(up, c_pos, -c_neg)
    pol = np.where(up, 1, -1).astype(np.int8)
    k = np.zeros(ref.shape, np.int64)
    active = up | down
    k[active] = np.floor((d[active] + pol[active] * tol) / step[active]).astype(np.int64)
    iy, ix = np.nonzero(active)
    ka, ra, sa = k[iy, ix], ref[iy, ix], step[iy, ix]
    oa, slope, pa = old[iy, ix], new[iy, ix] - old[iy, ix], pol[iy, ix]
    la = last_t[iy, ix].copy()
    out = []
    dt = float(t1 - t0)
    for i in range(1, int(ka.max(initial=0)) + 1):
        m = ka >= i
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.where(slope[m] * pa[m] > 0, (ra[m] + i * sa[m] - oa[m]) / slope[m], 0.0)
        t = t0 + np.floor(np.clip(frac, 0.0, 1.0) * dt + 0.5).astype(np.int64)
        keep = t - la[m] >= refractory_ns
        idx = np.nonzero(m)[0][keep]
        la[idx] = t[keep]
        out.append((ix[idx], iy[idx], t[keep], pa[idx]))
    last_t[iy, ix] = la
    ref[active] = ra + ka * sa
    if not out:
        return (np.empty(0, np.int16), np.empty(0, np.int16), np.empty(0, np.int64),
                np.empty(0, np.int8))
    return (np.concatenate([o[0] for o in out]).astype(np.int16),
            np.concatenate([o[1] for o in out]).astype(np.int16),
            np.concatenate([o[2] for o in out]), np.concatenate([o[3] for o in out]))
