"""The context branch (``model.context``): a zero-initialised residual that widens what an
output pixel sees, without changing a warm-started network until training moves it."""

from __future__ import annotations

import pytest
import torch

from model import checkpoint
from model.archs.blocks import (
    GATE_CELL,
    PUSH_PULL_FULL,
    ContextBranch,
    cell_means,
    history_gate,
    push_pull,
    support_means,
)
from model.archs.e2sri_arch import E2SRI, NetConfig
from model.inference.pretrained import shipped_checkpoint
from model.training.warm_start import warm_start

SMALL = dict(base_channels=8, hr_channels=4, c_blocks=1, blocks=1, state="lr")


def inputs(hw, seed=0, requires_grad=False):
    g = torch.Generator().manual_seed(seed)
    stacks = torch.rand(1, 3, 3, *hw, generator=g) * 2 - 1
    flows = torch.randn(1, 3, 2, *hw, generator=g)
    stacks.requires_grad_(requires_grad)
    return stacks, stacks[:, 1], flows


def reach(net: E2SRI, hw=(160, 160)) -> float:
    """The farthest LR distance (Chebyshev) from the central output pixel at which the
    stacks change it."""
    stacks, central, flows = inputs(hw, requires_grad=True)
    out = net(stacks, central, flows)
    s = net.config.scale
    out[0, 0, hw[0] * s // 2, hw[1] * s // 2].backward()
    g = stacks.grad.abs().sum(dim=(0, 1, 2))
    ys, xs = torch.nonzero(g > 0, as_tuple=True)
    return float(torch.maximum((ys - hw[0] // 2).abs(), (xs - hw[1] // 2).abs()).max())


def test_the_branch_starts_as_the_identity():
    branch = ContextBranch(16, 8)
    x = torch.randn(2, 16, 37, 51)
    assert torch.equal(branch(x), x)


def test_the_branch_handles_sizes_its_cells_do_not_divide():
    branch = ContextBranch(4, 3, factors=(4, 16))
    torch.nn.init.normal_(branch.out.weight)
    for hw in [(37, 51), (16, 16), (5, 3)]:
        x = torch.randn(1, 4, *hw)
        assert branch(x).shape == x.shape
    # cells cut by the border average the pixels they hold: against a direct loop
    x = torch.randn(1, 2, 37, 51)
    for f in branch.factors:
        cells = cell_means(x, f)
        assert cells.shape[-2:] == (-(-37 // f), -(-51 // f))
        for i in range(cells.shape[-2]):
            for j in range(cells.shape[-1]):
                want = x[..., i * f:(i + 1) * f, j * f:(j + 1) * f].mean(dim=(-2, -1))
                assert torch.allclose(cells[..., i, j], want, atol=1e-6)


def test_the_branch_widens_the_receptive_field():
    torch.manual_seed(0)
    plain = E2SRI(NetConfig(**SMALL)).eval()
    wide = E2SRI(NetConfig(**SMALL, context=8)).eval()
    wide.load_state_dict(plain.state_dict(), strict=False)
    torch.nn.init.normal_(wide.context.out.weight, std=0.1)  # as if trained
    near, far = reach(plain), reach(wide)
    assert near < 40  # the convolutions alone
    assert far >= 48  # the 16x16 cells' two convolutions and the interpolation


def test_a_plain_model_warm_starts_a_context_model_exactly(tmp_path):
    # the plain source: the shipped x2 network without its context branch (the shipped
    # model has one since run K), saved as a checkpoint of its own
    shipped = checkpoint.load_model(shipped_checkpoint(2))
    args = {**checkpoint.net_args(shipped), "context": 0}
    plain = E2SRI(NetConfig(**args)).eval()
    kept = {k: v for k, v in shipped.state_dict().items() if not k.startswith("context.")}
    plain.load_state_dict(kept)
    source = checkpoint.save(tmp_path / "plain.pt", config="", net=args,
                             model=plain.state_dict())
    net = E2SRI(NetConfig(**{**args, "context": 16})).eval()
    done = warm_start(net, source)
    assert done.fresh and all(name.startswith("context.") for name in done.fresh)
    x = inputs((40, 48), seed=3)
    with torch.no_grad():
        assert torch.equal(net(*x), plain(*x))
    # a context model warm-starts from the shipped (context) model as itself
    again = E2SRI(NetConfig(**checkpoint.net_args(shipped))).eval()
    assert warm_start(again, shipped_checkpoint(2)).fresh == ()
    with torch.no_grad():
        assert torch.equal(again(*x), shipped(*x))
    # the way back would drop the trained branch: refused
    with pytest.raises(ValueError, match="context branch"):
        warm_start(E2SRI(NetConfig(**args)), shipped_checkpoint(2))


def test_a_context_needs_the_lr_state():
    with pytest.raises(ValueError, match="model.context"):
        NetConfig(context=8)  # state: hr
    with pytest.raises(ValueError, match="model.context"):
        NetConfig(state="lr", context=-1)


def test_the_dilated_far_path_reaches_as_far_with_a_finer_grain():
    torch.manual_seed(0)
    net = E2SRI(NetConfig(**SMALL, context=8, context_far="dilated")).eval()
    assert torch.equal(net.context(x := torch.randn(1, 16, 37, 51)), x)  # identity at start
    torch.nn.init.normal_(net.context.out.weight, std=0.1)  # as if trained
    assert reach(net) >= 56  # 4x4 cells, +-15 cells of dilated convolutions
    for hw in [(37, 51), (16, 16), (5, 3)]:  # sizes its cells do not divide
        y = torch.randn(1, 16, *hw)
        assert net.context(y).shape == y.shape
    # it reads 4x4 cell means: a change inside one cell that keeps its mean changes
    # nothing, and a change of one cell's mean reaches pixels over 48 LR pixels away
    branch = net.context
    torch.nn.init.zeros_(branch.out.weight)
    torch.nn.init.normal_(branch.out.weight[:, 8:], std=0.1)  # the far path only
    base = torch.randn(1, 16, 128, 128, generator=torch.Generator().manual_seed(2))
    inside = base.clone()
    inside[..., 60, 60] += 1.0
    inside[..., 61, 62] -= 1.0  # same 4x4 cell, same mean
    moved = base.clone()
    moved[..., 60:64, 60:64] += 1.0
    with torch.no_grad():
        out0, out1, out2 = branch(base), branch(inside), branch(moved)
    far_only = (out1 - inside) - (out0 - base)
    assert far_only.abs().max() < 1e-5
    diff = (out2 - moved - out0 + base).abs().sum(dim=1)[0] > 1e-6
    ys, xs = torch.nonzero(diff, as_tuple=True)
    assert torch.maximum((ys - 62).abs(), (xs - 62).abs()).max() >= 48


def trained_context_model(path, seed, **cfg) -> tuple[E2SRI, object]:
    """A small context model with its branch's residual as if trained, saved to ``path``."""
    torch.manual_seed(seed)
    net = E2SRI(NetConfig(**SMALL, context=8, **cfg)).eval()
    torch.nn.init.normal_(net.context.out.weight, std=0.1)
    return net, checkpoint.save(path, config="", net=checkpoint.net_args(net),
                                model=net.state_dict())


def test_a_cells_model_warm_starts_a_dilated_one_as_itself_without_its_16x16_path(tmp_path):
    cells, path = trained_context_model(tmp_path / "cells.pt", 1)
    dilated = E2SRI(NetConfig(**SMALL, context=8, context_far="dilated")).eval()
    done = warm_start(dilated, path)
    assert any(name.startswith("context.far.") for name in done.fresh)
    assert "context.out.weight" in done.copied
    # the oracle: the old network with the 16x16 path's columns of the residual zeroed
    with torch.no_grad():
        cells.context.out.weight[:, 8:] = 0
        x = inputs((40, 48), seed=5)
        assert torch.equal(dilated(*x), cells(*x))
    # and back again would lose the dilated path: refused
    path = checkpoint.save(tmp_path / "dil.pt", config="", net=checkpoint.net_args(dilated),
                           model=dilated.state_dict())
    with pytest.raises(ValueError, match="far path"):
        warm_start(E2SRI(NetConfig(**SMALL, context=8)), path)


def test_a_cells_model_warm_starts_one_without_a_far_path_as_its_no_far_ablation(tmp_path):
    cells, path = trained_context_model(tmp_path / "cells.pt", 1)
    near = E2SRI(NetConfig(**SMALL, context=8, context_far="none")).eval()
    done = warm_start(near, path)
    assert "context.out.weight (near columns)" in done.copied and not done.fresh
    assert near.context.factors == (4,) and near.context.out.weight.shape[1] == 8
    assert reach(near) < 48 <= reach(cells)  # the 16x16 cells' reach is gone
    # the oracle: bench/context_ablation.py's no-far, the 16x16 path's columns zeroed
    with torch.no_grad():
        cells.context.out.weight[:, 8:] = 0
        x = inputs((40, 48), seed=5)
        assert torch.allclose(near(*x), cells(*x), atol=1e-6)
    path = checkpoint.save(tmp_path / "near.pt", config="", net=checkpoint.net_args(near),
                           model=near.state_dict())
    with pytest.raises(ValueError, match="without a far path"):
        warm_start(E2SRI(NetConfig(**SMALL, context=8)), path)


def test_context_far_is_checked():
    with pytest.raises(ValueError, match="gates the far path"):
        NetConfig(**SMALL, context=8, context_far="none", history=(8.0,), context_gate=8.0)
    with pytest.raises(ValueError, match="model.context_far"):
        NetConfig(state="lr", context=8, context_far="pyramid")


def context_ablation():
    from tests.model.conftest import bench_module
    return bench_module("context_ablation")


@pytest.mark.parametrize("far", ["cells", "dilated"])
def test_the_ablation_switches_off_exactly_the_named_path(far):
    torch.manual_seed(2)
    net = E2SRI(NetConfig(**SMALL, context=8, context_far=far)).eval()
    torch.nn.init.normal_(net.context.out.weight, std=0.1)  # as if trained
    torch.nn.init.normal_(net.context.out.bias, std=0.1)
    ckpt = {"config": "", "net": checkpoint.net_args(net), "model": net.state_dict()}
    bench = context_ablation()
    x = inputs((36, 44), seed=6)
    plain = E2SRI(NetConfig(**SMALL)).eval()  # the oracle for "none": no branch at all
    plain.load_state_dict({k: v for k, v in net.state_dict().items()
                           if not k.startswith("context.")})
    with torch.no_grad():
        full = net(*x)
        for variant in bench.VARIANTS:
            ablated = E2SRI(net.config).eval()
            ablated.load_state_dict(bench.ablated(ckpt, variant)["model"])
            got = ablated(*x)
            if variant == "full":
                assert torch.equal(got, full)
            elif variant == "none":
                assert torch.allclose(got, plain(*x), atol=1e-6)
            else:  # one path's share gone: the output moves, and the other path still acts
                assert not torch.allclose(got, full) and not torch.allclose(got, plain(*x))
        # the oracle for "no-far": the far path's features replaced by zeros in the sum
        branch = net.context
        feats = torch.randn(1, 16, 36, 44)
        weight = bench.ablated(ckpt, "no-far")["model"]["context.out.weight"]
        near = torch.nn.functional.interpolate(
            branch.paths[0](cell_means(feats, 4)), scale_factor=4, mode="bilinear",
            align_corners=False)[..., :36, :44]
        near = torch.nn.functional.conv2d(near, weight[:, :8], branch.out.bias)
        ablated = E2SRI(net.config).eval()
        ablated.load_state_dict(bench.ablated(ckpt, "no-far")["model"])
        assert torch.allclose(ablated.context(feats), feats + near, atol=1e-5)
    # the checkpoint itself is untouched
    assert torch.equal(ckpt["model"]["context.out.weight"], net.context.out.weight)


def test_the_ablation_refuses_a_network_without_a_branch():
    net = E2SRI(NetConfig(**SMALL))
    ckpt = {"config": "", "net": checkpoint.net_args(net), "model": net.state_dict()}
    with pytest.raises(ValueError, match="no context branch"):
        context_ablation().ablated(ckpt, "none")


def test_the_whole_frame_path_starts_at_zero_and_reaches_every_pixel():
    torch.manual_seed(2)
    net = E2SRI(NetConfig(**SMALL, context=8, context_global=True)).eval()
    x = torch.randn(1, 16, 37, 51)
    assert torch.equal(net.context(x), x)  # both residuals start at zero
    torch.nn.init.normal_(net.context.g_out.weight, std=0.1)  # as if trained
    assert reach(net, hw=(300, 300)) >= 149  # the far corner: beyond the cells' +-63
    branch = ContextBranch(16, 8, global_path=True)
    torch.nn.init.normal_(branch.g_out.weight, std=0.1)
    # the path reads the frame mean: a change in one corner of a frame far wider than the
    # cells reach moves the pixels in the opposite corner
    base = torch.randn(1, 16, 64, 200, generator=torch.Generator().manual_seed(4))
    moved = base.clone()
    moved[..., 60:, 190:] += 2.0
    with torch.no_grad():
        d = (branch(moved) - branch(base))[..., :8, :8]
    assert d.abs().amax() > 1e-4  # 180 pixels away


def test_a_context_model_warm_starts_a_whole_frame_one_exactly(tmp_path):
    src, path = trained_context_model(tmp_path / "ctx.pt", 3)
    net = E2SRI(NetConfig(**SMALL, context=8, context_global=True)).eval()
    done = warm_start(net, path)
    assert done.fresh and all(n.startswith("context.g_") for n in done.fresh)
    x = inputs((40, 48), seed=6)
    with torch.no_grad():
        assert torch.equal(net(*x), src(*x))
    refuses_to_lose(net, tmp_path / "glob.pt", "whole-frame path", "context_global")


def refuses_to_lose(net: E2SRI, path, what: str, flag: str) -> None:
    """A warm start that would drop ``net``'s branch path ``flag`` is refused (naming
    ``what``), and so is the flag without a branch to hold it."""
    path = checkpoint.save(path, config="", net=checkpoint.net_args(net), model=net.state_dict())
    with pytest.raises(ValueError, match=what):
        warm_start(E2SRI(NetConfig(**SMALL, context=8)), path)
    with pytest.raises(ValueError, match=flag):
        NetConfig(**SMALL, **{flag: True})


def test_support_means_count_only_the_pixels_that_fired():
    g = torch.Generator().manual_seed(7)
    p = torch.randn(2, 3, 37, 51, generator=g)
    fired = (torch.rand(2, 1, 37, 51, generator=g) < 0.2).float()
    fired[0, :, :16, :16] = 0  # a cell where nothing fired
    cells, share, frame, frame_share = support_means(p, fired, 16)
    # against a direct loop over the cells (border cells hold fewer pixels)
    for b in range(2):
        for i in range(cells.shape[-2]):
            for j in range(cells.shape[-1]):
                m = fired[b, 0, i * 16:(i + 1) * 16, j * 16:(j + 1) * 16].bool()
                want = p[b, :, i * 16:(i + 1) * 16, j * 16:(j + 1) * 16][:, m].mean(dim=1) \
                    if m.any() else torch.zeros(3)
                assert torch.allclose(cells[b, :, i, j], want, atol=1e-5)
                assert share[b, 0, i, j] == pytest.approx(m.float().mean().item(), abs=1e-6)
        want = p[b][:, fired[b, 0].bool()].mean(dim=1)
        assert torch.allclose(frame[b, :, 0, 0], want, atol=1e-5)
    assert torch.equal(cells[0, :, 0, 0], torch.zeros(3))
    # what unfired pixels hold does not count
    again = support_means(p + 100.0 * (1 - fired), fired, 16)
    for a, b in zip(again, (cells, share, frame, frame_share)):
        assert torch.allclose(a, b, atol=1e-4)


def test_push_pull_fills_a_cell_from_the_frame_in_proportion_to_what_fired():
    cells = torch.tensor([[[[1.0, 1.0, 1.0]]]])
    share = torch.tensor([[[[0.0, PUSH_PULL_FULL / 4, 0.5]]]])
    frame = torch.tensor([[[[5.0]]]])
    assert torch.allclose(push_pull(cells, share, frame), torch.tensor([[[[5.0, 4.0, 1.0]]]]))


def test_the_support_path_carries_the_fired_pixels_level_past_the_cells_reach():
    torch.manual_seed(3)
    branch = ContextBranch(16, 8, support=True).eval()
    x = torch.randn(1, 16, 64, 300)
    fired = torch.zeros(1, 1, 64, 300)
    fired[..., 20:44, 250:290] = 1  # events only near the right edge
    assert torch.equal(branch(x, fired), x)  # its residual starts at zero
    torch.nn.init.normal_(branch.s_out.weight, std=0.1)  # as if trained
    with torch.no_grad():
        base = branch(x, fired)[..., :8, :8]  # 240 pixels from any event
        moved = x.clone()
        moved[..., 20:44, 250:290] += 2.0  # the fired pixels' features
        assert (branch(moved, fired)[..., :8, :8] - base).abs().amax() > 1e-3
        quiet = x.clone()
        quiet[..., :, 150:] += 2.0 * (1 - fired[..., :, 150:])  # far unfired pixels only
        assert torch.allclose(branch(quiet, fired)[..., :8, :8], base, atol=1e-5)
    with pytest.raises(ValueError, match="support map"):
        branch(x)


def test_a_context_model_warm_starts_a_support_one_exactly(tmp_path):
    src, path = trained_context_model(tmp_path / "ctx.pt", 4)
    net = E2SRI(NetConfig(**SMALL, context=8, context_support=True)).eval()
    done = warm_start(net, path)
    assert done.fresh and all(n.startswith("context.s_") for n in done.fresh)
    stacks, central, flows = inputs((40, 48), seed=8)
    stacks = stacks * (torch.rand(stacks.shape[-2:]) < 0.1)  # events at a tenth of the pixels
    with torch.no_grad():
        assert torch.equal(net(stacks, central, flows), src(stacks, central, flows))
        torch.nn.init.normal_(net.context.s_out.weight, std=0.1)
        # no event anywhere: the shares and means are 0, not a division by zero
        blank = torch.zeros_like(stacks)
        assert torch.isfinite(net(blank, blank[:, 1], flows)).all()
    refuses_to_lose(net, tmp_path / "sup.pt", "support path", "context_support")


def test_the_history_gate_is_the_history_averaged_over_the_near_cells():
    h = torch.full((1, 1, 37, 45), 0.7)
    assert torch.allclose(history_gate(h), h)  # a uniform history passes as it is
    assert torch.equal(history_gate(torch.zeros(1, 1, 37, 45)), torch.zeros(1, 1, 37, 45))
    one = torch.zeros(1, 1, 40, 40)
    one[0, 0, 21, 18] = 1.0  # a lone event (noise) opens the far path over its cell, weakly
    g = history_gate(one)
    assert 0 < g.max() <= 1 / GATE_CELL ** 2 + 1e-6
    assert g[..., :8, :].max() == 0 and g[..., 32:, :].max() == 0  # and nowhere far from it


def test_the_gate_is_the_far_path_weighted_per_pixel(tmp_path):
    """Oracles: a history where every pixel just fired gives the ungated network; one where
    none ever fired gives it with the far path's columns of the residual zeroed; a gate
    that is 1 on one half and 0 on the other gives each of those on its half."""
    plain, path = trained_context_model(tmp_path / "plain.pt", 3)
    torch.nn.init.normal_(plain.context.out.bias, std=0.1)
    path = checkpoint.save(path, config="", net=checkpoint.net_args(plain),
                           model=plain.state_dict())
    gated = E2SRI(NetConfig(**SMALL, context=8, history=(32.0,), context_gate=32.0)).eval()
    done = warm_start(gated, path)
    assert not done.fresh  # the gate has no parameters; only the history's columns are new
    no_far = E2SRI(plain.config).eval()
    no_far.load_state_dict(plain.state_dict())
    with torch.no_grad():
        no_far.context.out.weight[:, 8:] = 0
        stacks, central, flows = inputs((48, 64), seed=7)
        ones, zeros = torch.ones(1, 1, 48, 64), torch.zeros(1, 1, 48, 64)
        want = plain(stacks, central, flows)
        assert torch.allclose(gated(stacks, torch.cat([central, ones], 1), flows), want,
                              atol=1e-5)
        cut = no_far(stacks, central, flows)
        assert not torch.allclose(cut, want, atol=1e-3)  # the far path does act
        assert torch.allclose(gated(stacks, torch.cat([central, zeros], 1), flows), cut,
                              atol=1e-5)
        half = torch.cat([ones[..., :32], zeros[..., 32:]], dim=-1)
        got = gated(stacks, torch.cat([central, half], 1), flows)
        # the gate is 1 up to LR column 29 and 0 from 34 (the 4x4 cells' bilinear blend);
        # Mix, after the branch, reaches a few LR pixels: compare 6 away from both
        assert torch.allclose(got[..., : 2 * 24], want[..., : 2 * 24], atol=1e-5)
        assert torch.allclose(got[..., 2 * 40:], cut[..., 2 * 40:], atol=1e-5)
        assert not torch.allclose(got[..., 2 * 40:], want[..., 2 * 40:], atol=1e-3)


def test_the_gate_needs_its_history_channel_and_a_branch():
    with pytest.raises(ValueError, match="context_gate"):
        NetConfig(**SMALL, context=8, history=(4.0,), context_gate=32.0)
    with pytest.raises(ValueError, match="context_gate"):
        NetConfig(**SMALL, history=(32.0,), context_gate=32.0)
    with pytest.raises(ValueError, match="context_gate"):
        NetConfig(**{**SMALL, "fold": 2}, context=8, history=(32.0,), context_gate=32.0)


def test_the_ablation_writes_a_gated_checkpoint_that_computes_as_the_network(tmp_path):
    from esim_lite.core.dataconf import to_yaml
    from model.config import TrainConfig

    net, _ = trained_context_model(tmp_path / "k.pt", 4)
    cfg = to_yaml(TrainConfig(model=net.config))
    path = checkpoint.save(tmp_path / "k.pt", config=cfg, net=checkpoint.net_args(net),
                           model=net.state_dict())
    ckpt = context_ablation().gated(str(path), 16)
    gated = checkpoint.model_from(ckpt)
    assert gated.config.context_gate == 16 and gated.config.history == (16.0,)
    assert checkpoint.config_of(ckpt).model == gated.config  # what the data pipeline reads
    stacks, central, flows = inputs((32, 40), seed=8)
    with torch.no_grad():
        assert torch.allclose(gated(stacks, torch.cat([central, torch.ones(1, 1, 32, 40)], 1),
                                    flows), net(stacks, central, flows), atol=1e-5)
