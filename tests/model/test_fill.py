"""The fill of what no event saw (model/inference/fill.py): against a direct sparse solve,
an analytic harmonic function, and the properties each mode promises."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg

from datagen.recording import open_recording
from model.cli import reconstruct_main
from model.inference.fill import FillConfig, fill_unobserved, fired_pixels, flat_fill, harmonic_fill
from model.inference.observed import region_of
from model.inference.reconstruct import Reconstructor


def direct_laplace(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """The same equations, written one pixel at a time and solved by LU: every unknown
    pixel's value is the mean of its 4 neighbours, a neighbour past the edge the pixel."""
    h, w = values.shape
    unknown = [(y, x) for y in range(h) for x in range(w) if not known[y, x]]
    index = {p: i for i, p in enumerate(unknown)}
    a = scipy.sparse.lil_matrix((len(unknown), len(unknown)))
    b = np.zeros(len(unknown))
    for i, (y, x) in enumerate(unknown):
        for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            yy, xx = y + dy, x + dx
            if not (0 <= yy < h and 0 <= xx < w):
                continue  # the pixel itself: adds to both sides, cancels
            a[i, i] += 1
            if known[yy, xx]:
                b[i] += values[yy, xx]
            else:
                a[i, index[(yy, xx)]] -= 1
    out = values.astype(np.float64).copy()
    solved = scipy.sparse.linalg.spsolve(a.tocsc(), b)
    for (y, x), v in zip(unknown, solved):
        out[y, x] = v
    return out


def test_harmonic_fill_equals_a_direct_solve():
    rng = np.random.default_rng(3)
    for h, w in ((37, 52), (64, 64)):
        values = rng.random((h, w)).astype(np.float32)
        known = rng.random((h, w)) < 0.02
        known[h // 3, :] = True  # a wall splits the frame into two regions
        got = harmonic_fill(values, known)
        np.testing.assert_array_equal(got[known], values[known])
        np.testing.assert_allclose(got, direct_laplace(values, known), atol=2e-4)


def test_harmonic_fill_reproduces_a_linear_ramp_inside_a_frame_of_it():
    yy, xx = np.mgrid[0:48, 0:60].astype(np.float32)
    ramp = 0.2 + 0.004 * xx + 0.007 * yy  # harmonic: its Laplacian is 0
    known = np.zeros(ramp.shape, bool)
    known[:2], known[-2:], known[:, :2], known[:, -2:] = True, True, True, True
    start = np.where(known, ramp, 0.9).astype(np.float32)
    np.testing.assert_allclose(harmonic_fill(start, known), ramp, atol=1e-4)


def test_flat_fill_gives_each_region_its_rims_mean_away_from_the_rim():
    values = np.zeros((40, 80), np.float32)
    known = np.zeros(values.shape, bool)
    known[:, 38:42] = True  # a wall of known pixels: two regions
    values[:, 38:40], values[:, 40:42] = 0.2, 0.8  # the rims: 0.2 on the left, 0.8 on the right
    got = flat_fill(values, known, transition=2.0)
    np.testing.assert_array_equal(got[known], values[known])
    np.testing.assert_allclose(got[:, :20], 0.2, atol=1e-3)
    np.testing.assert_allclose(got[:, 60:], 0.8, atol=1e-3)
    # flat fill is one level far from the rim; the harmonic one needs no such level
    assert got[:, :20].std() < 1e-3


def test_a_lone_event_is_not_support_but_two_adjacent_are():
    stacks = np.full((3, 3, 20, 20), 128, np.uint8)
    stacks[0, 1, 5, 5] = 200  # alone
    stacks[1, 0, 12, 12] = 60
    stacks[2, 2, 12, 13] = 200  # beside it, in another stack
    support = region_of(fired_pixels(stacks), 0, 1)
    assert not support[5, 5] and support[12, 12] and support[12, 13]
    assert support.sum() == 2
    assert region_of(fired_pixels(stacks), 0, 0).sum() == 3
    region = region_of(fired_pixels(stacks), 2, 1)
    assert region[12, 10] and region[14, 13] and not region[12, 16] and not region[15, 15]


def test_fill_keeps_the_network_where_events_fired_and_needs_events():
    rng = np.random.default_rng(0)
    image = rng.random((64, 96)).astype(np.float32)
    stacks = np.full((3, 3, 32, 48), 128, np.uint8)
    assert fill_unobserved(image, stacks, FillConfig("harmonic")) is image  # nothing fired
    stacks[1, 0, 10:20, 10:12] = 255
    for mode in ("harmonic", "flat"):
        got = fill_unobserved(image, stacks, FillConfig(mode, radius=1))
        keep = np.zeros((32, 48), bool)
        keep[10:20, 9:13] = keep[9:21, 10:12] = True  # the block grown by the 1-pixel disc
        keep = np.repeat(np.repeat(keep, 2, 0), 2, 1)
        np.testing.assert_array_equal(got[keep], image[keep])
        far = got[:, 60:]
        assert far.std() < 0.05 * image.std()  # the noise the network drew there is gone
    assert fill_unobserved(image, stacks, FillConfig("none")) is image
    with pytest.raises(ValueError, match="whole multiple"):
        fill_unobserved(image[:63], stacks, FillConfig("harmonic"))
    with pytest.raises(ValueError, match="fill mode"):
        FillConfig("smooth")


def test_reconstructor_applies_the_fill_and_the_cli_takes_it(tiny_shards, tiny_checkpoint,
                                                             tmp_path, capsys):
    rec = open_recording(sorted(tiny_shards.glob("shard_*.h5"))[0], sequence="seq_000001")
    model = Reconstructor.load(tiny_checkpoint, rec.sensor_hw, device="cpu")
    stacks = np.full((3, model.stacks.channels) + rec.sensor_hw, 128, np.uint8)
    stacks[:, :, 10:14, 20:30] = 200
    plain, _ = model.run(stacks, None)
    from dataclasses import replace
    filled, timing = replace(model, fill=FillConfig("flat")).run(stacks, None)
    np.testing.assert_array_equal(filled, fill_unobserved(plain, stacks, FillConfig("flat")))
    assert "fill" in timing and not np.array_equal(filled, plain)
    path = sorted(tiny_shards.glob("shard_*.h5"))[0]
    assert reconstruct_main([str(path), "--checkpoint", str(tiny_checkpoint), "--out",
                             str(tmp_path / "h"), "--fill", "harmonic", "--limit", "1",
                             "--no-progress"]) == 0
    assert "fill" in capsys.readouterr().out
    assert cv2.imread(str(sorted((tmp_path / "h").glob("frame_*.png"))[0]), 0) is not None


def test_fill_at_x4_keeps_whole_blocks_and_flattens_the_rest():
    rng = np.random.default_rng(5)
    image = rng.random((4 * 24, 4 * 40)).astype(np.float32)
    stacks = np.full((3, 3, 24, 40), 128, np.uint8)
    stacks[0, 2, 5:9, 5:9] = 30
    got = fill_unobserved(image, stacks, FillConfig("flat", radius=0))
    np.testing.assert_array_equal(got[20:36, 20:36], image[20:36, 20:36])  # the 4x4 LR block
    assert got[:, 100:].std() < 1e-3  # one region, one level, far from its rim
