"""Warm starts: an x4 network from an x2 one (model/training/warm_start.py)."""

from __future__ import annotations

import dataclasses

import pytest
import torch
import torch.nn.functional as F

from esim_lite.core.dataconf import to_yaml
from model import checkpoint
from model.archs.e2sri_arch import E2SRI, NetConfig
from model.config import TrainConfig
from model.training.setup import Distributed
from model.training.train import build_state
from model.training.warm_start import warm_start

LR_NET = NetConfig(scale=2, n_stacks=3, base_channels=8, hr_channels=4, c_blocks=1, blocks=1,
                   state="lr")


def saved_net(tmp_path, config: NetConfig, seed: int = 0):
    torch.manual_seed(seed)
    net = E2SRI(config)
    for p in net.parameters():  # not the default init: copies must be real copies
        p.data.normal_(0, 0.3)
    path = tmp_path / f"x{config.scale}.pt"
    checkpoint.save(path, model=net.state_dict(), net=checkpoint.net_args(net),
                    config=to_yaml(TrainConfig(model=config)))
    return net, path


def test_x2_to_x4_copies_everything_and_lifts_by_nearest_upsampling(tmp_path):
    old, path = saved_net(tmp_path, LR_NET)
    new = E2SRI(dataclasses.replace(LR_NET, scale=4))
    done = warm_start(new, path)
    assert set(done.lifted) == {"mix.1.weight", "mix.1.bias"} and not done.fresh
    old_state = old.state_dict()
    for name, value in new.state_dict().items():
        if name in done.copied:
            assert torch.equal(value, old_state[name]), name
    # oracle: the lifted HR features are the old ones, each repeated over 2 x 2 pixels
    features = torch.randn(1, 2 * LR_NET.base_channels, 6, 5)
    with torch.no_grad():
        lifted_old, lifted_new = old.mix[:4](features), new.mix[:4](features)
    assert lifted_new.shape[-2:] == (6 * 4, 5 * 4)
    expected = F.interpolate(lifted_old, scale_factor=2, mode="nearest")
    assert torch.allclose(lifted_new, expected, atol=1e-6)


def test_a_fresh_x4_net_differs_from_the_warm_one(tmp_path):
    """Guards the test above: without the warm start the lift is not an upsampled copy."""
    old, _ = saved_net(tmp_path, LR_NET)
    new = E2SRI(dataclasses.replace(LR_NET, scale=4))
    features = torch.randn(1, 2 * LR_NET.base_channels, 6, 5)
    with torch.no_grad():
        expected = F.interpolate(old.mix[:4](features), scale_factor=2, mode="nearest")
        assert not torch.allclose(new.mix[:4](features), expected, atol=1e-3)


def test_a_shuffle_lift_model_starts_a_smooth_lift_one(tmp_path):
    """The shipped models (plain pixel shuffle) warm-start the anti-grid variant: every
    tensor copied, and the lift's output is the old one through the fixed filter."""
    old, path = saved_net(tmp_path, LR_NET)
    new = E2SRI(dataclasses.replace(LR_NET, lift="smooth"))
    done = warm_start(new, path)
    assert not done.fresh and not done.lifted and len(done.copied) == len(new.state_dict())
    features = torch.randn(1, 2 * LR_NET.base_channels, 6, 5)
    with torch.no_grad():
        shuffled, smoothed = old.mix[:3](features), new.mix[:3](features)
    taps = torch.tensor([0.25, 0.5, 0.25])
    kernel = (taps[:, None] * taps[None, :]).expand(shuffled.shape[1], 1, 3, 3)
    expected = F.conv2d(F.pad(shuffled, (1, 1, 1, 1), mode="replicate"), kernel,
                        groups=shuffled.shape[1])
    assert torch.allclose(smoothed, expected, atol=1e-6)


def test_hr_state_keeps_the_scale_dependent_layers_fresh(tmp_path):
    _, path = saved_net(tmp_path, dataclasses.replace(LR_NET, state="hr"))
    done = warm_start(E2SRI(dataclasses.replace(LR_NET, state="hr", scale=4)), path)
    assert done.fresh and not done.lifted
    assert all(n.startswith(("rnet_c", "rnet_a", "down")) for n in done.fresh)
    assert any(n.startswith("efr") for n in done.copied)


def test_refuses_other_architectures_and_smaller_scales(tmp_path):
    _, path = saved_net(tmp_path, LR_NET)
    with pytest.raises(ValueError, match="differs in base_channels"):
        warm_start(E2SRI(dataclasses.replace(LR_NET, scale=4, base_channels=16)), path)
    _, path4 = saved_net(tmp_path, dataclasses.replace(LR_NET, scale=4))
    with pytest.raises(ValueError, match="x4 model cannot start an x2"):
        warm_start(E2SRI(LR_NET), path4)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt"):
        warm_start(E2SRI(LR_NET), junk)


def test_training_starts_from_init_from(tmp_path):
    old, path = saved_net(tmp_path, LR_NET)
    cfg = TrainConfig(model=dataclasses.replace(LR_NET, scale=4))
    cfg = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, init_from=str(path)))
    state = build_state(cfg, Distributed(), steps_per_epoch=10)
    new, ref = state.net.state_dict(), old.state_dict()
    assert all(torch.equal(new[k], ref[k]) for k in ref if not k.startswith("mix.1."))


def test_a_warm_started_run_resumes_without_its_source(tiny_checkpoint, tiny_shards, tmp_path):
    """The warm start applies once: resuming reads the run's own checkpoint, so the source
    may be gone (a later session, a re-exported model)."""
    import shutil

    from model.training.train import train
    from tests.model.conftest import tiny_config

    source = tmp_path / "source.pt"
    shutil.copy(tiny_checkpoint, source)
    out = tmp_path / "run"
    train(tiny_config("run.max_steps=2", f"run.init_from={source}"), tiny_shards, out,
          show_progress=False)
    source.unlink()
    result = train(tiny_config("run.max_steps=4", f"run.init_from={source}"), tiny_shards,
                   out, resume=True, show_progress=False)
    assert checkpoint.load(out / "last.pt")["step"] == 4 and result is not None
