"""Memory across outputs (``model.memory``): the state one output leaves for the next, the
clips it trains on, and a recording's outputs carrying it in time order."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from datagen.recording import open_recording
from datagen.shard import find_shards
from esim_lite.core.stacking import StackConfig
from model import checkpoint
from model.archs.e2sri_arch import E2SRI, NetConfig
from model.data.config import DataConfig
from model.data.dataset import ClipSamples, SampleRef, ShardSamples, clips_of, index_samples
from model.inference.engines import load_engine
from model.inference.pretrained import shipped_checkpoint
from model.inference.reconstruct import Reconstructor, plan_outputs, reconstruct
from model.training.train import train
from model.training.warm_start import warm_start
from tests.model.conftest import tiny_config

SMALL = dict(base_channels=8, hr_channels=4, c_blocks=1, blocks=1, state="lr")


def inputs(hw, seed=0):
    g = torch.Generator().manual_seed(seed)
    stacks = torch.rand(1, 3, 3, *hw, generator=g) * 2 - 1
    return stacks, stacks[:, 1], torch.randn(1, 3, 2, *hw, generator=g)


@torch.no_grad()
def as_if_trained(net: E2SRI, hw) -> None:
    """A memory that counts and outputs inside [0, 1] (a 3-step model's are below 0)."""
    torch.nn.init.normal_(net.memory_in.weight, std=0.3)
    last = [m for m in net.mix.modules() if isinstance(m, torch.nn.Conv2d)][-1]
    last.bias += 0.5 - float(net(*inputs(hw)).mean())


def test_the_shipped_model_warm_starts_a_memory_model_exactly(tmp_path):
    shipped = checkpoint.load_model(shipped_checkpoint(2)).eval()
    net = E2SRI(NetConfig(**{**checkpoint.net_args(shipped), "memory": True})).eval()
    done = warm_start(net, shipped_checkpoint(2))
    assert done.fresh == ("memory_in.weight",)
    x = inputs((40, 48), seed=3)
    with torch.no_grad():
        want = shipped(*x)
        first, state = net(*x, return_state=True)  # no memory yet: the first output
        assert torch.equal(first, want)
        # a zero-initialised input convolution: a memory changes nothing until trained
        assert torch.equal(net(*x, memory=state), want)
        torch.nn.init.normal_(net.memory_in.weight, std=0.1)  # as if trained
        assert not torch.allclose(net(*x, memory=state), want, atol=1e-4)
        assert torch.equal(net(*x), want)  # without a memory it is still the source
    # the way back would drop the trained memory: refused
    source = checkpoint.save(tmp_path / "memory.pt", config="", net=checkpoint.net_args(net),
                             model=net.state_dict())
    with pytest.raises(ValueError, match="memory across outputs would be lost"):
        warm_start(E2SRI(shipped.config), source)


def test_the_state_carries_what_earlier_stacks_said():
    torch.manual_seed(0)
    net = E2SRI(NetConfig(**SMALL, memory=True)).eval()
    torch.nn.init.normal_(net.memory_in.weight, std=0.3)
    a, b = inputs((24, 32), seed=1), inputs((24, 32), seed=2)
    with torch.no_grad():
        _, after_a = net(*a, return_state=True)
        _, after_b = net(*b, return_state=True)
        # the same inputs give different outputs after different histories
        assert not torch.allclose(net(*a, memory=after_a), net(*a, memory=after_b), atol=1e-5)
        with pytest.raises(ValueError, match="memory must be"):
            net(*a, memory=after_a[..., :-1, :])
    plain = E2SRI(NetConfig(**SMALL))
    with pytest.raises(ValueError, match="no memory"):
        plain(*a, return_state=True)
    with pytest.raises(ValueError, match="state: lr"):
        NetConfig(memory=True)


def test_memory_and_clips_go_together():
    with pytest.raises(ValueError, match="go together"):
        tiny_config("model.state=lr", "model.memory=true")
    with pytest.raises(ValueError, match="go together"):
        tiny_config("data.clip=3")
    with pytest.raises(ValueError, match="data.clip"):
        DataConfig(clip=0)


def test_clips_are_consecutive_frames_cropped_alike(tiny_shards):
    data = DataConfig(stacks=StackConfig(events_per_channel=100), crop=32, clip=3)
    train_refs, _ = index_samples(find_shards(tiny_shards), data, 3, 2)
    clips = clips_of(train_refs, 3)
    assert clips and all(len(c) == 3 for c in clips)
    for c in clips:
        assert len({(r.path, r.sequence) for r in c}) == 1
        assert [r.frame for r in c] == list(range(c[0].frame, c[0].frame + 3))
    flat = [r for c in clips for r in c]
    assert len(set(flat)) == len(flat)  # each frame in at most one clip
    # the clip cut: a gap in the frames starts a new clip
    r0, r1, r2 = clips[0]
    assert clips_of([r0, r2], 2) == [] and clips_of([r0, r2, r1, r2], 2) == [(r1, r2)]
    assert clips_of([r0, r1, r2], 2) == [(r0, r1)]
    # a stride: interleaved clips, each frame in one
    run = [SampleRef("a.h5", "seq", k, 100 * k, 10 * k, 100) for k in range(1, 14)]
    strided = clips_of(run, 2, stride=3)
    assert [[r.frame for r in c] for c in strided] == \
        [[1, 4], [2, 5], [3, 6], [7, 10], [8, 11], [9, 12]]
    ds = ClipSamples(clips, data, 3, 2, train=True, seed=5)
    item = ds[0]
    assert item["stacks"].shape == (3, 3, 3, 32, 32) and item["hr"].shape == (3, 1, 64, 64)
    # every frame of the clip is the crop and flips its first frame would get as sample 0
    single = ShardSamples(list(clips[0]), data, 3, 2, train=True, seed=5)
    for t, ref in enumerate(clips[0]):
        want = single._sample(ref, 0)
        for k in ("stacks", "lr", "hr", "flows"):
            assert torch.equal(item[k][t], want[k]), (t, k)
    # consecutive frames of a moving scene differ; the crop window stays put
    assert not torch.equal(item["hr"][0], item["hr"][2])


def test_a_memory_model_trains_on_clips_and_reconstructs_in_time_order(tiny_shards,
                                                                        tmp_path):
    cfg = tiny_config("model.state=lr", "model.memory=true", "data.clip=3",
                      "run.max_steps=3", "run.val_batches=1")
    result = train(cfg, tiny_shards, tmp_path / "run", show_progress=False)
    assert result["step"] == 3 and np.isfinite(result["val"]["psnr"])
    net = checkpoint.load_model(tmp_path / "run" / "last.pt")
    assert net.config.memory and net.memory_in.weight.abs().sum() > 0  # it trained
    with pytest.raises(ValueError, match="torch engine only"):
        load_engine("onnxruntime", net, torch.device("cpu"), (48, 64))
    assert load_engine("auto", net, torch.device("cpu"), (48, 64)).name == "torch"
    # the outputs of a recording depend on what came before: the same stacks twice give
    # two outputs, and a reset gives the first again
    shard = find_shards(tiny_shards)[0]
    rec = open_recording(shard, sequence="seq_000001")
    model = Reconstructor.load(tmp_path / "run" / "last.pt", rec.sensor_hw, device="cpu")
    as_if_trained(model.net, rec.sensor_hw)
    plan = plan_outputs(rec, model.stacks, "events")
    one = reconstruct(rec, model, tmp_path / "a", plan, show_progress=False, limit=3)
    two = reconstruct(rec, model, tmp_path / "b", plan, show_progress=False, limit=3)
    # reconstruct resets the memory: the same recording gives the same frames
    for p, q in zip(one.frames, two.frames):
        assert p.read_bytes() == q.read_bytes()
    stacks = np.full((3, 3, *rec.sensor_hw), 128, np.uint8)
    stacks[:, 0, 10:20, 10:30] = 200
    model.reset()
    first, _ = model.run(stacks, None)
    second, _ = model.run(stacks, None)
    assert not np.allclose(first, second, atol=1e-4)
    model.reset()
    assert np.array_equal(model.run(stacks, None)[0], first)


def test_scoring_every_kth_frame_feeds_the_frames_between_to_the_memory(tiny_shards,
                                                                        tmp_path):
    from model.inference.evaluate import EvalOptions, run_sequence

    cfg = tiny_config("model.state=lr", "model.memory=true", "data.clip=2", "run.max_steps=1",
                      "run.val_batches=1")
    train(cfg, tiny_shards, tmp_path / "run", show_progress=False)
    rec = open_recording(find_shards(tiny_shards)[0], sequence="seq_000001")
    model = Reconstructor.load(tmp_path / "run" / "last.pt", rec.sensor_hw, device="cpu")
    as_if_trained(model.net, rec.sensor_hw)
    options = EvalOptions(baselines=(), temporal=False)
    ids = list(range(1, min(len(rec.frames), 8)))
    every = run_sequence(rec, model, ids, None, options, "all").images["ours"]
    some = run_sequence(rec, model, ids[::3], None, options, "some").images["ours"]
    for a, b in zip(every[::3], some):
        assert np.array_equal(a, b)
    assert not np.array_equal(every[1], run_sequence(rec, model, ids[1:2], None, options,
                                                      "alone").images["ours"][0])


def test_the_halo_probe_feeds_a_memory_the_outputs_before():
    from model.inference.halo_probe import memory_anchors, stack_window

    got = memory_anchors(10_000, 1_000)
    assert got == list(range(2_000, 10_000, 1_000))  # 8 outputs, every stack
    assert all(stack_window(a, 1_000).first >= 0 for a in got)
    assert memory_anchors(2_500, 1_000) == [] and memory_anchors(3_500, 1_000) == [2_500]


def test_the_memory_use_benchmark_sees_a_memory_only_when_it_counts(tiny_shards, tmp_path):
    from tests.conftest import REAL_EVENTS
    from tests.model.conftest import bench_module

    snippet = REAL_EVENTS / "ecd_snippets" / "shapes_translation"
    if not snippet.is_dir():
        pytest.skip("no real recordings beside the repository")
    bench = bench_module("memory_use")
    cfg = tiny_config("model.state=lr", "model.memory=true", "data.clip=2", "run.max_steps=1",
                      "run.val_batches=1")
    train(cfg, tiny_shards, tmp_path / "run", show_progress=False)
    ckpt = checkpoint.load(tmp_path / "run" / "last.pt")
    net = checkpoint.load_model(tmp_path / "run" / "last.pt")
    for name, std in (("zero", 0.0), ("used", 0.3)):
        as_if_trained(net, (48, 64))
        with torch.no_grad():
            torch.nn.init.normal_(net.memory_in.weight, std=std) if std else \
                net.memory_in.weight.zero_()
        checkpoint.save(tmp_path / f"{name}.pt", **{**ckpt, "model": net.state_dict()})
    zero = bench.memory_use(str(tmp_path / "zero.pt"), snippet, 4)
    used = bench.memory_use(str(tmp_path / "used.pt"), snippet, 4)
    assert zero["outputs"] == used["outputs"] == 4
    assert zero["last10"] == 0 and used["first"] == 0 < used["last10"]
