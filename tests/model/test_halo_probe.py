"""The halo probe's metrics: known synthetic halos are found with their sign and width,
halo-free images read ~0, and the probe poster is what it says."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from model.inference.halo_probe import (
    RING_NAMES,
    PosterSpec,
    ProbeSequence,
    boundary_distance,
    otsu_dark,
    poster_texture,
    ring_errors,
    ring_masks,
    self_rings,
    stack_window,
    swept_error,
)

SCALE = 2


def disc_scene(hw=(256, 256), centres=((80, 80), (176, 170)), radius=20,
               ground=0.8, dark=0.05) -> tuple[np.ndarray, np.ndarray]:
    """(ground truth float32[H, W], dark mask): dark discs on a flat ground, at HR."""
    mask = np.zeros(hw, np.uint8)
    for c in centres:
        cv2.circle(mask, c, radius, 1, -1)
    dark_mask = mask.astype(bool)
    return np.where(dark_mask, dark, ground).astype(np.float32), dark_mask


def with_halo(gt: np.ndarray, dark: np.ndarray, amp: float, lo: float, hi: float
              ) -> np.ndarray:
    """``gt`` plus ``amp`` on the pixels between ``lo`` and ``hi`` LR px outside ``dark``."""
    outside, _ = boundary_distance(dark, SCALE)
    return (gt + amp * ((outside > lo) & (outside <= hi))).astype(np.float32)


def test_boundary_distance_of_a_half_plane():
    dark = np.zeros((40, 40), bool)
    dark[:, :20] = True
    outside, inside = boundary_distance(dark, SCALE)
    # column 20 + k is k + 1 HR px from the nearest dark column: (k + 1) / 2 LR px
    np.testing.assert_allclose(outside[10, 20:30], (np.arange(10) + 1) / SCALE, atol=0.02)
    np.testing.assert_allclose(inside[10, 10:20], (np.arange(10, 0, -1)) / SCALE, atol=0.02)
    assert np.all(outside[dark] == 0) and np.all(inside[~dark] == 0)


def test_boundary_distance_rejects_bad_input():
    with pytest.raises(ValueError, match="bool"):
        boundary_distance(np.zeros((4, 4), np.uint8), SCALE)
    with pytest.raises(ValueError, match="scale"):
        boundary_distance(np.zeros((4, 4), bool), 0)
    outside, _ = boundary_distance(np.zeros((4, 4), bool), SCALE)
    assert np.all(np.isinf(outside))


def test_rings_partition_the_outside():
    _, dark = disc_scene()
    masks = ring_masks(dark, SCALE)
    assert set(masks) == set(RING_NAMES)
    outer = [m for n, m in masks.items() if n != "inside"]
    assert not np.any(np.sum(outer, axis=0) > 1)  # no pixel in two rings
    assert not np.any(masks["inside"] & ~dark)


def test_halo_free_output_reads_zero():
    gt, dark = disc_scene()
    errs = ring_errors(gt.copy(), gt, ring_masks(dark, SCALE))
    assert all(abs(v) < 1e-9 for v in errs.values())


@pytest.mark.parametrize("amp", [0.2, -0.15])
@pytest.mark.parametrize("band", [(1.0, 2.0), (2.0, 5.0)])
def test_known_halo_found_with_its_sign_and_width(amp, band):
    gt, dark = disc_scene()
    pred = with_halo(gt, dark, amp, *band)
    errs = ring_errors(pred, gt, ring_masks(dark, SCALE))
    name = {(1.0, 2.0): "out 1-2", (2.0, 5.0): "out 2-5"}[band]
    assert errs[name] == pytest.approx(amp, abs=1e-6)
    for other in RING_NAMES:
        if other != name:
            assert abs(errs[other]) < 1e-6, other


def test_a_global_offset_is_not_a_halo_relative_to_far():
    gt, dark = disc_scene()
    errs = ring_errors(gt - 0.1, gt, ring_masks(dark, SCALE))
    assert errs["out 1-2"] - errs["far >12"] == pytest.approx(0, abs=1e-6)
    assert errs["far >12"] == pytest.approx(-0.1, abs=1e-6)


def test_too_small_ring_is_nan():
    gt, dark = disc_scene(hw=(64, 64), centres=((32, 32),), radius=20)
    errs = ring_errors(gt, gt, ring_masks(dark, SCALE))
    assert math.isnan(errs["far >12"])


def test_shape_mismatch_raises():
    gt, dark = disc_scene()
    with pytest.raises(ValueError, match="shape"):
        ring_errors(gt[:-1], gt, ring_masks(dark, SCALE))


def test_swept_error_reads_a_ghost_trail():
    gt, dark_now = disc_scene(centres=((100, 128),))
    _, dark_before = disc_scene(centres=((90, 128),))  # the disc moved 10 px right
    trail = dark_before & ~dark_now
    pred = np.where(trail, 0.4, gt).astype(np.float32)  # a grey ghost where it was
    assert swept_error(pred, gt, dark_now, [dark_before]) == pytest.approx(0.4 - 0.8)
    assert swept_error(gt, gt, dark_now, [dark_before]) == pytest.approx(0.0)


def test_self_rings_match_a_known_relative_halo():
    gt, dark = disc_scene()
    assert abs(self_rings(gt, SCALE)["out 2-5"]) < 1e-6
    # +0.15 over a contrast of 0.75: a fifth of the contrast
    pred = with_halo(gt, dark, 0.15, 2.0, 5.0)
    rel = self_rings(pred, SCALE)
    assert rel["out 2-5"] == pytest.approx(0.15 / 0.75, abs=0.01)
    assert rel["inside"] == pytest.approx(-1.0)
    assert abs(rel["out 5-10"]) < 0.01


def test_otsu_dark_finds_the_discs():
    gt, dark = disc_scene()
    rng = np.random.default_rng(0)
    noisy = gt + rng.normal(0, 0.03, gt.shape).astype(np.float32)
    found = otsu_dark(noisy)
    assert (found == dark).mean() > 0.995


def test_poster_texture_two_levels_and_seeded():
    spec = PosterSpec()
    a = poster_texture(spec, (200, 300), 2.0, np.random.default_rng(1))
    b = poster_texture(spec, (200, 300), 2.0, np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    assert set(np.unique(a)) == {np.float32(spec.dark), np.float32(spec.background)}
    share = float((a == np.float32(spec.dark)).mean())
    assert 0.02 < share < 0.4


def test_poster_texture_ground_texture_is_relative():
    spec = PosterSpec(texture_amp=0.1)
    a = poster_texture(spec, (200, 300), 2.0, np.random.default_rng(1))
    ground = a[a > 0.5]
    assert ground.min() >= 0.8 * 0.9 - 1e-6 and ground.max() <= 0.8 * 1.1 + 1e-6


def test_stack_window_matches_reconstructor_indices():
    # Reconstructor.first_needed: anchor - (n // 2 + 1) * per_stack; the last side stack
    # ends n // 2 stacks after the anchor
    w = stack_window(30_000, 9_000)
    assert (w.first, w.anchor, w.last) == (12_000, 30_000, 39_000)


@pytest.mark.parametrize("ground,shape", [(0.8, 0.05), (0.2, 0.8)])
def test_dark_mask_finds_the_shapes_either_way(ground, shape):
    gt, discs = disc_scene(ground=ground, dark=shape)
    seq = ProbeSequence(events=None, plane=None, trajectory=None, sim=None, scale=SCALE,
                        dark_level=shape)
    np.testing.assert_array_equal(seq.dark_mask(gt), discs)
