"""The context branch (``model.context``): a zero-initialised residual that widens what an
output pixel sees, without changing a warm-started network until training moves it."""

from __future__ import annotations

import pytest
import torch

from model import checkpoint
from model.archs.blocks import ContextBranch, cell_means
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
