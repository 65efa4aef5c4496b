"""bench/cloud_profile.py: distances from the support and the banded profile against direct
computation."""

from __future__ import annotations

import numpy as np

from tests.model.conftest import bench_module


def test_distance_from_support_is_euclidean():
    bench = bench_module("cloud_profile")
    rng = np.random.default_rng(3)
    support = np.zeros((37, 53), bool)
    support[rng.integers(0, 37, 6), rng.integers(0, 53, 6)] = True
    d = bench.distance_from(support)
    ys, xs = np.nonzero(support)
    yy, xx = np.mgrid[:37, :53]
    brute = np.sqrt((yy[..., None] - ys) ** 2 + (xx[..., None] - xs) ** 2).min(axis=-1)
    np.testing.assert_allclose(d, brute, atol=1e-3)
    assert (d[support] == 0).all()


def test_profile_bands_and_gap():
    """An output that is the target plus an offset set by the pixel's band gives that
    offset as the band's error and the offsets' difference (plus the target's) as the gap."""
    bench = bench_module("cloud_profile")
    h, w = 40, 200
    support = np.zeros((h, w), bool)
    support[:, :2] = True                       # distance = column - 1 beyond the strip
    d = bench.distance_from(support)
    rng = np.random.default_rng(0)
    target = rng.uniform(0.2, 0.4, (h, w))
    offset = np.where(d < bench.NEAR, -0.1, np.where(d >= bench.FAR, 0.2, 0.05))
    out = target + offset
    result = bench.profile([out, out], [target, target], [support, support])
    for lo, hi, n, g, p, mae in result["bands"]:
        k = (d >= lo) & (d < hi)
        assert n == 2 * k.sum()
        if n:
            assert np.isclose(g, target[k].mean()) and np.isclose(p, out[k].mean())
            assert np.isclose(mae, np.abs(offset[k]).mean())
    near, far = d < bench.NEAR, d >= bench.FAR
    assert np.isclose(result["aps_gap"], target[far].mean() - target[near].mean())
    assert np.isclose(result["gap"], result["aps_gap"] + 0.3)
