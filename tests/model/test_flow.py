"""FNet: classical flow on stacks, exact flow targets, pre-training the learnable FNet."""

from __future__ import annotations

import numpy as np
import torch

from datagen.shard import find_shards
from esim_lite.core.stacking import StackConfig
from model.data.classical_flow import classical_flow, stack_flows
from model.data.config import DataConfig
from model.data.dataset import ShardSamples, index_samples
from model.training.flow_pretrain import pretrain_flow
from model.training.train import train
from tests.model.conftest import tiny_config


def test_classical_flow_finds_a_known_shift():
    rng = np.random.default_rng(0)
    import cv2

    img = (cv2.GaussianBlur(rng.random((64, 64)).astype(np.float32), (0, 0), 2) * 255
           ).astype(np.uint8)
    shifted = np.roll(img, (2, 3), axis=(0, 1))  # content moves +3 px in x, +2 px in y
    flow = classical_flow(img, shifted)
    inner = flow[10:-10, 10:-10]
    assert np.allclose(np.median(inner[..., 0]), 3, atol=0.3)
    assert np.allclose(np.median(inner[..., 1]), 2, atol=0.3)
    stacks = np.stack([np.stack([img] * 3), np.stack([img] * 3), np.stack([shifted] * 3)])
    flows = stack_flows(stacks)
    assert flows.shape == (3, 2, 64, 64) and np.all(flows[1] == 0)


def test_classical_flow_does_not_depend_on_earlier_calls():
    """OpenCV's DIS object keeps state between calls (0.0009 px on this pair when reused):
    a reconstruction's first frame then differed from the same frame made later in the
    process by up to 3 grey levels."""
    import cv2

    rng = np.random.default_rng(1)
    a, c = ((cv2.GaussianBlur(rng.random((60, 80)), (0, 0), 2) * 255).astype(np.uint8)
            for _ in range(2))
    first = classical_flow(a, np.roll(a, 2, axis=1))
    classical_flow(c, np.roll(c, -3, axis=0))
    np.testing.assert_array_equal(classical_flow(a, np.roll(a, 2, axis=1)), first)


def test_classical_flow_on_a_sensor_smaller_than_dis_accepts():
    """DIS refuses images under 12 pixels; tiny sensors get a flow of their own size (a
    smooth blob moving +1 px in x stays +1 px after the padding)."""
    yy, xx = np.mgrid[0:10, 0:9]
    img = (120 + 100 * np.exp(-((xx - 4) ** 2 + (yy - 5) ** 2) / 6)).astype(np.uint8)
    moved = (120 + 100 * np.exp(-((xx - 5) ** 2 + (yy - 5) ** 2) / 6)).astype(np.uint8)
    flow = classical_flow(img, moved)
    assert flow.shape == (10, 9, 2) and np.isfinite(flow).all()
    assert np.median(flow[3:8, 3:7, 0]) > 0.3


def test_exact_flows_follow_crops_and_flips(tiny_shards):
    data = DataConfig(stacks=StackConfig(events_per_channel=100), crop=32, flow="exact")
    refs, _ = index_samples(find_shards(tiny_shards), data, 3, 2)
    whole = ShardSamples(refs, DataConfig(stacks=data.stacks, crop=None, flow="exact",
                                          flips=False), 3, 2, True)[0]["flows"]
    assert whole.abs().max() > 0.1 and torch.all(whole[1] == 0)
    for epoch in range(6):  # several crops and flip combinations
        ds = ShardSamples(refs, data, 3, 2, True, seed=1)
        ds.set_epoch(epoch)
        crop = ds[0]["flows"]
        # find where the crop came from, with which flips, and check the flow values
        found = False
        for fx in (False, True):
            for fy in (False, True):
                w = whole.clone()
                if fx:
                    w = w.flip(-1) * torch.tensor([-1.0, 1.0]).view(2, 1, 1)
                if fy:
                    w = w.flip(-2) * torch.tensor([1.0, -1.0]).view(2, 1, 1)
                for y0 in range(w.shape[-2] - 31):
                    for x0 in range(w.shape[-1] - 31):
                        if torch.allclose(w[..., y0:y0 + 32, x0:x0 + 32], crop):
                            found = True
        assert found, epoch


def test_flow_pretraining_beats_zero_flow_and_initialises_the_learned_fnet(tiny_shards,
                                                                            tmp_path):
    cfg = tiny_config("task=flow", "run.max_steps=60", "optim.lr=3e-3", "optim.batch_size=2")
    result = pretrain_flow(cfg, tiny_shards, tmp_path / "flow", show_progress=False)
    assert result["train_epe_last"] < result["train_epe_first"]
    assert result["val"]["learned"] < result["val_before"]["learned"]
    assert set(result["val"]) == {"learned", "zero", "dis"}
    out = train(tiny_config("model.flow=learned", "run.max_steps=1",
                            f"run.flow_init={tmp_path / 'flow' / 'flow_last.pt'}"),
                tiny_shards, tmp_path / "e2sri", show_progress=False)
    assert out["step"] == 1
