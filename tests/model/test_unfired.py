"""The unfired-smoothness loss: which pixels count as fired, and the TV outside them."""

from __future__ import annotations

import pytest
import torch

from model.config import LossConfig
from model.losses.similarity import SimilarityLoss
from model.losses.unfired import UnfiredSmoothness, fired_mask, unfired_tv


def stacks_with(points: list[tuple[int, int]], h: int = 16, w: int = 16,
                value: float = 0.5) -> torch.Tensor:
    """(1, 3, 3, h, w) stacks with one event's worth of ``value`` at each (y, x), spread
    over the stacks and channels so every case is seen."""
    s = torch.zeros(1, 3, 3, h, w)
    for i, (y, x) in enumerate(points):
        s[0, i % 3, (i // 3) % 3, y, x] = value if i % 2 == 0 else -value
    return s


def test_isolated_events_are_not_fired_and_an_edge_is_with_its_dilation():
    noise = stacks_with([(2, 2), (10, 12), (13, 4)])
    assert fired_mask(noise, dilate=0).sum() == 0
    assert fired_mask(noise, dilate=3).sum() == 0
    edge = stacks_with([(y, 8) for y in range(16)])
    bare = fired_mask(edge, dilate=0)[0, 0]
    # the ends of the line have one fired neighbour only
    assert bare[1:15, 8].all() and not bare[0, 8] and not bare[15, 8]
    assert bare.sum() == 14
    wide = fired_mask(edge, dilate=2)[0, 0]
    assert torch.equal(wide[5].nonzero().flatten(), torch.arange(6, 11))
    assert fired_mask(edge, min_neighbours=0, dilate=0)[0, 0, :, 8].all()


def test_no_gradient_flows_into_the_mask():
    s = stacks_with([(y, 8) for y in range(16)]).requires_grad_()
    assert not fired_mask(s).requires_grad


@pytest.mark.parametrize("scale", [1, 2, 4])
def test_a_step_where_nothing_fired_costs_its_height_per_crossing(scale):
    h = w = 8
    out = torch.zeros(2, 1, h * scale, w * scale)
    out[0, ..., 5 * scale:] = 0.3      # a vertical step: one crossing per row
    out[1, ..., 3 * scale:, :] = -0.2  # a horizontal step: one per column
    quiet = torch.zeros(2, 1, h, w)
    hh, ww = h * scale, w * scale
    pairs = hh * (ww - 1) + (hh - 1) * ww
    tv = unfired_tv(out, quiet)
    torch.testing.assert_close(tv, torch.tensor([0.3 * hh, 0.2 * ww]) / pairs)


def test_steps_inside_fired_pixels_and_flat_outputs_cost_nothing():
    h = w = 8
    out = torch.zeros(1, 1, 2 * h, 2 * w)
    out[..., 10:] = 1.0                # the step between HR columns 9 and 10 = LR column 4|5
    fired = torch.zeros(1, 1, h, w)
    fired[..., 5] = 1.0                # column 5 fired: the pair (9, 10) touches it
    assert unfired_tv(out, fired).item() == 0
    fired[..., 5] = 0
    fired[..., 4] = 1.0                # so does column 4 (pixel 9 belongs to it)
    assert unfired_tv(out, fired).item() == 0
    fired[..., 4] = 0
    assert unfired_tv(out, fired).item() > 0
    assert unfired_tv(torch.full((1, 1, 16, 16), 0.7), fired).item() == 0


def test_gradcheck_and_module_equals_function():
    torch.manual_seed(0)
    stacks = stacks_with([(y, 3) for y in range(6)], 6, 6)
    out = torch.rand(1, 1, 12, 12, dtype=torch.float64, requires_grad=True)
    fired = fired_mask(stacks).double()
    assert torch.autograd.gradcheck(lambda o: unfired_tv(o, fired), (out,))
    torch.testing.assert_close(UnfiredSmoothness()(out, stacks), unfired_tv(out, fired))


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="not an integer multiple"):
        unfired_tv(torch.zeros(1, 1, 15, 16), torch.zeros(1, 1, 8, 8))
    with pytest.raises(ValueError, match=r"\(B, n, c, H, W\)"):
        fired_mask(torch.zeros(1, 3, 8, 8))


def test_the_similarity_loss_adds_the_weighted_term_and_needs_the_stacks():
    torch.manual_seed(1)
    out, target = torch.rand(2, 1, 16, 16), torch.rand(2, 1, 16, 16)
    stacks = stacks_with([(y, 4) for y in range(8)], 8, 8).repeat(2, 1, 1, 1, 1)
    plain, _ = SimilarityLoss(0.0)(out, target)
    with_tv, parts = SimilarityLoss(0.0, unfired_tv=2.5)(out, target, stacks)
    expected = 2.5 * UnfiredSmoothness()(out, stacks).mean()
    torch.testing.assert_close(with_tv - plain, expected)
    assert parts["unfired_tv"] == pytest.approx(float(expected) / 2.5)
    with pytest.raises(ValueError, match="needs the input stacks"):
        SimilarityLoss(0.0, unfired_tv=1.0)(out, target)
    with pytest.raises(ValueError, match=">= 0"):
        LossConfig(unfired_tv=-1.0)


def test_training_with_the_term_lowers_it_on_a_quiet_ramp():
    """Gradient steps on the term alone flatten a ramp drawn where nothing fired."""
    out = torch.linspace(0, 1, 16).repeat(1, 1, 16, 1).requires_grad_()
    stacks = torch.zeros(1, 3, 3, 8, 8)
    loss = UnfiredSmoothness()
    start = float(loss(out, stacks).detach())
    opt = torch.optim.Adam([out], lr=0.01)
    for _ in range(200):
        opt.zero_grad()
        loss(out, stacks).sum().backward()
        opt.step()
    assert float(loss(out, stacks).detach()) < 0.5 * start
