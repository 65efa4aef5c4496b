"""The unseen-fill target: seen pixels kept, the rest a smooth fill of them."""

from __future__ import annotations

import pytest
import torch

from model.config import LossConfig
from model.losses.similarity import SimilarityLoss
from model.losses.unfired import fired_mask
from model.losses.unseen import UnseenFill, pyramid_fill, smooth_fill


@pytest.mark.parametrize("hw", [(32, 32), (13, 21), (1, 7)])
def test_seen_pixels_are_kept_and_the_fill_stays_inside_their_range(hw):
    g = torch.Generator().manual_seed(1)
    image = torch.rand(3, 2, *hw, generator=g)
    known = (torch.rand(3, 1, *hw, generator=g) < 0.3).float()
    known[:, :, 0, 0] = 1  # at least one seen pixel per image
    out = smooth_fill(image, known)
    seen = known.expand_as(image).bool()
    assert torch.equal(out[seen], image[seen])
    for b in range(3):
        for c in range(2):
            values = image[b, c][known[b, 0].bool()]
            assert out[b, c].min() >= values.min() - 1e-6
            assert out[b, c].max() <= values.max() + 1e-6


def test_a_constant_fills_exactly_and_nothing_seen_takes_the_mean():
    image = torch.rand(2, 1, 24, 40)
    known = torch.zeros(2, 1, 24, 40)
    known[0, :, 5:9, 30:33] = 1
    image[0][known[0].bool()] = 0.37
    out = smooth_fill(image, known)
    assert torch.allclose(out[0], torch.full_like(out[0], 0.37), atol=1e-6)
    assert torch.allclose(out[1], image[1].mean().expand_as(out[1]), atol=1e-6)


def test_the_fill_is_monotone_between_two_seen_levels():
    image = torch.zeros(1, 1, 32, 64)
    known = torch.zeros(1, 1, 32, 64)
    known[..., :8] = 1  # level 0 on the left
    image[..., 56:] = 1.0
    known[..., 56:] = 1  # level 1 on the right
    out = smooth_fill(image, known)[0, 0]
    # the analytic answer: linear from the last 0 column (7) to the first 1 column (56)
    ramp = ((torch.arange(64.0) - 7) / 49).clamp(0, 1)
    assert torch.allclose(out, ramp.expand_as(out), atol=1e-4)


def test_the_fill_is_harmonic_where_nothing_was_seen():
    g = torch.Generator().manual_seed(4)
    image = torch.rand(2, 1, 40, 56, generator=g)
    known = (torch.rand(2, 1, 40, 56, generator=g) < 0.05).float()
    out = smooth_fill(image, known, tol=1e-7)
    p = torch.nn.functional.pad(out, (1, 1, 1, 1), mode="replicate")  # no flux at the border
    laplace = p[..., :-2, 1:-1] + p[..., 2:, 1:-1] + p[..., 1:-1, :-2] + p[..., 1:-1, 2:] - 4 * out
    assert laplace[known == 0].abs().max() < 1e-4
    assert laplace[known == 1].abs().max() > 0.1  # the seen pixels are not smoothed


def test_a_dark_objects_interior_is_filled_dark_and_the_background_light():
    yy, xx = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
    r = ((yy - 31.5) ** 2 + (xx - 31.5) ** 2).sqrt()
    image = torch.where(r < 14, 0.1, 0.8)[None, None]
    noise = 0.5 * torch.rand(1, 1, 64, 64, generator=torch.Generator().manual_seed(0))
    truth = image + noise  # texture nothing saw, inside and outside
    known = ((r - 14).abs() < 2).float()[None, None]  # the edge fired
    out = smooth_fill(truth, known)[0, 0]
    assert out[r < 8].max() < 0.45 < out[(r > 22) & (r < 30)].min()
    # the unseen texture is gone: inside and outside vary far less than the truth
    assert out[r < 8].std() < 0.2 * truth[0, 0][r < 8].std()
    # a pyramid fill mixes both sides of the edge and fills the dark interior light
    assert pyramid_fill(truth, known)[0, 0][r < 8].min() > 0.6


def test_the_fill_commutes_with_flips():
    g = torch.Generator().manual_seed(2)
    image = torch.rand(1, 1, 32, 32, generator=g)
    known = (torch.rand(1, 1, 32, 32, generator=g) < 0.1).float()
    for dims in ((-1,), (-2,), (-2, -1)):
        flipped = smooth_fill(image.flip(dims), known.flip(dims))
        assert torch.allclose(flipped, smooth_fill(image, known).flip(dims), atol=1e-6)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="one size"):
        smooth_fill(torch.rand(1, 1, 8, 8), torch.ones(1, 1, 8, 9))
    with pytest.raises(ValueError, match="one size"):
        smooth_fill(torch.rand(1, 1, 8, 8), torch.ones(1, 2, 8, 8))
    with pytest.raises(ValueError, match="integer multiple"):
        UnseenFill()(torch.rand(1, 1, 20, 20), torch.zeros(1, 3, 3, 8, 8))
    with pytest.raises(ValueError, match="fill_dilate"):
        LossConfig(fill_dilate=-1)


@pytest.mark.parametrize("scale", [1, 2, 4])
def test_unseen_fill_keeps_the_target_on_the_widened_fired_region(scale):
    stacks = torch.zeros(1, 3, 3, 16, 16)
    stacks[0, 1, 0, :, 8] = 0.5  # an edge down column 8
    target = torch.rand(1, 1, 16 * scale, 16 * scale)
    out = UnseenFill(dilate=1)(target, stacks)
    seen = fired_mask(stacks, 2, 1)
    seen = torch.nn.functional.interpolate(seen, scale_factor=scale, mode="nearest").bool()
    assert seen.any() and (~seen).any()
    assert torch.equal(out[seen], target[seen])
    assert not torch.allclose(out[~seen], target[~seen])
    # far from the edge the fill is flat: it varies less than the truth there
    far = out[0, 0, :, :4 * scale]
    assert far.std() < 0.5 * target[0, 0, :, :4 * scale].std()
    # no event at all: the target's mean everywhere
    empty = UnseenFill()(target, torch.zeros(1, 3, 3, 16, 16))
    assert torch.allclose(empty, target.mean().expand_as(target), atol=1e-6)


def test_the_similarity_loss_scores_the_filled_target_and_needs_the_stacks():
    torch.manual_seed(0)
    stacks = torch.zeros(2, 3, 3, 16, 16)
    stacks[:, 0, 1, 4:12, 4:12] = 0.3
    target, output = torch.rand(2, 1, 32, 32), torch.rand(2, 1, 32, 32)
    filled = UnseenFill(dilate=2)(target, stacks)
    loss, parts = SimilarityLoss(0.0, fill_unseen=True, fill_dilate=2)(output, target, stacks)
    assert torch.isclose(loss, (output - filled).abs().mean())
    plain, _ = SimilarityLoss(0.0)(output, target, stacks)
    assert not torch.isclose(loss, plain)
    with pytest.raises(ValueError, match="needs the input stacks"):
        SimilarityLoss(0.0, fill_unseen=True)(output, target)
