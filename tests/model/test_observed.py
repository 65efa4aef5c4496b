"""The observed region (model/inference/observed.py), the per-pixel SSIM and LPIPS maps it
averages, and the information-free references (model/inference/references.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from esim_lite.core.events import Events
from model.inference import observed as ob
from model.inference.evaluate import frame_metrics, normalized
from model.inference.references import SALT_AMPLITUDE, SALT_FRACTION, reference_image
from model.losses.lpips import LPIPS
from model.metrics.image import ssim, ssim_map
from tests.model.test_lpips_metrics import photo

REAL = Path(__file__).resolve().parents[3] / "shared" / "real_events" / "davis346"


@pytest.fixture(scope="module")
def lpips_net():
    return LPIPS()


def make_events(xy: list[tuple[int, int]], hw=(60, 80)) -> Events:
    x = np.array([p[0] for p in xy], np.int16)
    y = np.array([p[1] for p in xy], np.int16)
    n = len(xy)
    return Events(x, y, np.arange(n, dtype=np.int64) * 1000, np.ones(n, np.int8), hw)


def test_ssim_map_is_scikit_images_map_and_averages_to_ssim():
    x = photo(96)[0, 0].numpy()
    rng = np.random.default_rng(2)
    y = np.clip(x + 0.1 * rng.standard_normal(x.shape), 0, 1).astype(np.float32)
    _, full = structural_similarity(x.astype(np.float64), y.astype(np.float64), data_range=1.0,
                                    gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False, full=True)
    ours = ssim_map(torch.from_numpy(x)[None, None], torch.from_numpy(y)[None, None])[0, 0]
    np.testing.assert_allclose(ours.numpy(), full[5:-5, 5:-5], atol=1e-6)
    assert ours.mean().item() == pytest.approx(
        ssim(torch.from_numpy(x)[None, None], torch.from_numpy(y)[None, None]).item(), abs=1e-6)


def test_lpips_map_locates_the_distortion_and_averages_to_the_distance(lpips_net):
    x = photo(128)
    assert lpips_net.distance_map(x, x).abs().max().item() < 1e-6
    y = x.clone()
    y[..., :48, :48] = torch.rand(1, 1, 48, 48, generator=torch.Generator().manual_seed(0))
    dmap = lpips_net.distance_map(x, y)[0, 0]
    assert dmap.shape == x.shape[-2:]
    assert dmap[:40, :40].mean() > 5 * dmap[-40:, -40:].mean()
    assert dmap.mean().item() == pytest.approx(lpips_net(x, y).item(), rel=0.02)


def test_isolated_events_are_not_observed_and_an_edge_is_with_its_sides():
    lattice = [(x, y) for x in range(2, 80, 3) for y in range(2, 60, 3)]  # no two touch
    assert not ob.support_mask(make_events(lattice)).any()
    edge = [(x, 30) for x in range(10, 60)]
    noise = [(70, 5), (3, 55), (75, 50)]
    mask = ob.support_mask(make_events(edge + noise), radius=5)
    # the edge's end pixels have one fired neighbour, the rest two: supported x = 11..58
    rows = np.flatnonzero(mask[:, 35])
    assert rows.min() == 25 and rows.max() == 35  # +-5 rows about the edge
    cols = np.flatnonzero(mask[30])
    assert cols.min() == 11 - 5 and cols.max() == 58 + 5
    for x, y in noise:
        assert not mask[y, x]
    assert not mask[:20].any() and not mask[41:].any()
    assert np.array_equal(ob.support_mask(make_events(edge), radius=0)[30, 11:59],
                          np.ones(48, bool))


def test_the_affine_fit_uses_only_the_region():
    rng = np.random.default_rng(3)
    gt = rng.random((40, 50)).astype(np.float32) * 0.5 + 0.25
    mask = np.zeros(gt.shape, bool)
    mask[10:30, 10:40] = True
    pred = ((gt - 0.1) / 2).astype(np.float32)
    pred[~mask] = rng.random(int((~mask).sum()))
    mapped = ob.affine_in(pred, gt, mask)
    np.testing.assert_allclose(mapped[mask], gt[mask], atol=1e-5)


def test_masked_metrics_score_the_region_only(lpips_net):
    gt = photo(128)[0, 0].numpy()
    whole = np.ones(gt.shape, bool)
    rng = np.random.default_rng(4)
    noisy = np.clip(gt + 0.05 * rng.standard_normal(gt.shape), 0, 1).astype(np.float32)
    m = ob.masked_metrics(noisy, gt, whole, lpips_net)
    ref = frame_metrics(noisy, gt, lpips_net)
    assert m["psnr"] == pytest.approx(ref["psnr"], abs=1e-3)
    assert m["ssim"] == pytest.approx(ref["ssim"], abs=1e-6)
    assert m["lpips"] == pytest.approx(ref["lpips"], rel=0.02)
    assert m["coverage"] == 1.0
    # right inside a block, noise outside: perfect in the region, poor over the frame
    region = np.zeros(gt.shape, bool)
    region[20:100, 20:100] = True
    pred = gt.copy()
    pred[~region] = rng.random(int((~region).sum()))
    inside = ob.masked_metrics(pred, gt, region, lpips_net)
    frame = frame_metrics(pred, gt, lpips_net)
    assert inside["psnr"] == float("inf") and inside["mse"] == 0.0
    assert inside["ssim"] > frame["ssim"] + 0.3
    core = np.zeros(gt.shape, bool)  # windows (11x11) that lie wholly inside the block
    core[25:95, 25:95] = True
    assert ob.masked_metrics(pred, gt, core, lpips_net)["ssim"] == pytest.approx(1.0)
    assert inside["lpips"] < 0.6 * frame["lpips"]  # its deep layers see past the region
    assert inside["coverage"] == pytest.approx(80 * 80 / 128**2)
    small = np.zeros(gt.shape, bool)
    small[:4, :4] = True
    assert ob.masked_metrics(pred, gt, small, lpips_net) is None
    with pytest.raises(ValueError, match="differ in size"):
        ob.masked_metrics(pred, gt, small[:-1], lpips_net)


def test_references_carry_no_information():
    gt = photo(64)[0, 0].numpy()
    flat = reference_image("flat", gt, 0)
    assert np.unique(flat).size == 1 and flat[0, 0] == pytest.approx(gt.mean())
    region = np.zeros(gt.shape, bool)
    region[:20] = True
    assert reference_image("flat", gt, 0, region)[0, 0] == pytest.approx(gt[region].mean())
    big = np.full((300, 400), 0.4, np.float32)
    salt = reference_image("salt", big, 7)
    dots = np.abs(salt - 0.4) > 1e-6
    assert dots.mean() == pytest.approx(SALT_FRACTION, rel=0.2)
    np.testing.assert_allclose(np.abs(salt[dots] - 0.4), SALT_AMPLITUDE, atol=1e-6)
    assert np.array_equal(salt, reference_image("salt", big, 7))
    assert not np.array_equal(salt, reference_image("salt", big, 8))
    # the flat reference is what the affine fit makes of any flat image
    mapped, _ = normalized(np.full(gt.shape, 0.9, np.float32), gt, "affine")
    np.testing.assert_allclose(mapped, flat, atol=1e-5)
    with pytest.raises(ValueError, match="unknown reference"):
        reference_image("stripes", gt, 0)


def test_the_ceiling_is_the_target_where_seen_and_its_mean_elsewhere():
    gt = np.random.default_rng(1).random((20, 30)).astype(np.float32)
    region = np.zeros(gt.shape, bool)
    region[5:12, 8:20] = True
    ceiling = reference_image("seen+flat", gt, 0, region)
    np.testing.assert_array_equal(ceiling[region], gt[region])
    np.testing.assert_allclose(ceiling[~region], gt[~region].mean(), rtol=1e-6)
    # the best grey outside: any other level is further from the target there
    for level in (gt[~region].mean() - 0.05, gt[~region].mean() + 0.05, gt.mean() + 0.01):
        assert np.mean((ceiling - gt) ** 2) < np.mean((np.where(region, gt, level) - gt) ** 2)
    with pytest.raises(ValueError, match="needs an observed region"):
        reference_image("seen+flat", gt, 0)
    with pytest.raises(ValueError, match="needs an observed region"):
        reference_image("seen+flat", gt, 0, np.ones(gt.shape, bool))


def test_the_harmonic_ceiling_continues_the_target_smoothly():
    # a ramp along x seen at both ends is harmonic, with no flow across the top and bottom
    # edges: its smoothest continuation is the ramp itself
    ramp = np.tile(np.linspace(0.1, 0.9, 40, dtype=np.float32), (24, 1))
    region = np.zeros(ramp.shape, bool)
    region[:, :4] = region[:, -4:] = True
    ceiling = reference_image("seen+harmonic", ramp, 0, region)
    np.testing.assert_allclose(ceiling, ramp, atol=1e-3)
    flat = reference_image("seen+flat", ramp, 0, region)  # the right mean, the wrong shape
    assert np.mean(flat[~region] - ramp[~region]) == pytest.approx(0, abs=1e-6)
    assert np.abs(flat - ramp).max() > 0.3
    # on any target: the target where seen, each unseen pixel the mean of its 4 neighbours
    gt = np.random.default_rng(2).random((20, 30)).astype(np.float32)
    region = np.zeros(gt.shape, bool)
    region[5:12, 8:20] = True
    ceiling = reference_image("seen+harmonic", gt, 0, region)
    np.testing.assert_array_equal(ceiling[region], gt[region])
    p = np.pad(ceiling, 1, mode="edge")
    mean4 = (p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:]) / 4
    np.testing.assert_allclose(ceiling[~region], mean4[~region], atol=1e-4)
    with pytest.raises(ValueError, match="needs an observed region"):
        reference_image("seen+harmonic", gt, 0)


def test_the_salt_ceiling_adds_dots_only_where_nothing_was_seen():
    gt = np.random.default_rng(3).uniform(0.2, 0.8, (300, 400)).astype(np.float32)
    region = np.zeros(gt.shape, bool)
    region[100:200, 50:350] = True
    flat = reference_image("seen+flat", gt, 0, region)
    salt = reference_image("seen+salt", gt, 5, region)
    np.testing.assert_array_equal(salt[region], gt[region])
    dots = salt != flat
    assert not dots[region].any()
    assert dots[~region].mean() == pytest.approx(SALT_FRACTION, rel=0.25)
    np.testing.assert_allclose(np.abs(salt[dots] - flat[dots]), SALT_AMPLITUDE, atol=1e-6)
    assert np.array_equal(salt, reference_image("seen+salt", gt, 5, region))
    assert not np.array_equal(salt, reference_image("seen+salt", gt, 6, region))


@pytest.mark.skipif(not (REAL / "street.aedat4").exists(),
                    reason="../shared/real_events is not there")
def test_the_street_clips_observed_region_leaves_the_static_background_out():
    from datagen.recording import open_recording

    rec = open_recording(REAL / "street.aedat4")
    first = next(rec.events())
    mask = ob.support_mask(first.slice(0, 4000))
    # events come from the cars and from noise; most of the static street never fires
    assert 0.002 < mask.mean() < 0.3


def test_invented_counts_what_is_drawn_where_no_event_fired(lpips_net):
    gt = photo(128)[0, 0].numpy()
    mask = np.zeros(gt.shape, bool)
    mask[40:80, 40:80] = True
    pred = np.full(gt.shape, 0.3, np.float32)
    pred[mask] = gt[mask]
    assert ob.masked_metrics(pred, gt, mask, lpips_net)["invented"] == 0.0
    assert ob.invented_share(pred, mask) == 0.0
    # a dark cloud over a tenth of the unobserved pixels, and faint ripples that do not count
    outside = np.flatnonzero(~mask.ravel())
    cloud = outside[: outside.size // 10]
    flat = pred.ravel().copy()
    flat[cloud] -= 0.2
    flat[outside[outside.size // 10:: 2]] += 0.5 * ob.INVENTED_STEP
    assert ob.invented_share(flat.reshape(gt.shape), mask) == pytest.approx(0.1, abs=1e-3)
    # a region that leaves too few pixels outside has no such score
    assert "invented" not in ob.masked_metrics(pred, gt, np.ones(gt.shape, bool), lpips_net)
