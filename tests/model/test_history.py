"""The event-history input (model/data/history.py): exact ages, the same in training (shard
and cache paths) and in streaming reconstruction, and a warm start that changes nothing."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from datagen.shard import ShardReader, find_shards
from esim_lite.core.events import Events
from model.archs.e2sri_arch import E2SRI, NetConfig
from model.data.dataset import ShardSamples, index_samples
from model.data.history import EventAge, event_age, history_input, latest_index
from model.data.input_cache import CacheSpec, InputCache
from model.inference.reconstruct import EventWindow
from model.training.warm_start import warm_start
from tests.model.conftest import tiny_config
from tests.model.test_warm_start import LR_NET, saved_net


def random_events(n: int, hw=(6, 7), seed=0) -> Events:
    rng = np.random.default_rng(seed)
    # a few hot pixels and a few that never fire
    x = rng.integers(0, hw[1] - 2, n).astype(np.int16)
    y = rng.integers(0, hw[0], n).astype(np.int16)
    p = rng.choice(np.array([-1, 1], np.int8), n)
    return Events(x, y, np.arange(n, dtype=np.int64) * 1000, p, hw)


def brute_age(events: Events, anchor: int) -> np.ndarray:
    h, w = events.sensor_hw
    age = np.full((h, w), np.inf, np.float32)
    for i in range(anchor):  # the latest event before the anchor wins
        age[events.y[i], events.x[i]] = anchor - 1 - i
    return age


@pytest.mark.parametrize("anchor", [0, 1, 37, 200])
def test_age_is_the_events_since_each_pixels_latest_one(anchor):
    ev = random_events(200)
    got = event_age(latest_index(ev.slice(0, anchor), 0), anchor, ev.sensor_hw)
    np.testing.assert_array_equal(got, brute_age(ev, anchor))
    if anchor:
        assert got[ev.y[anchor - 1], ev.x[anchor - 1]] == 0
    assert np.isinf(got[:, -2:]).all()  # the last two columns never fire


def test_history_channels_fall_with_age_and_are_zero_where_nothing_fired():
    age = np.array([[0, 10, 100, np.inf]], np.float32)
    h = history_input(age, 10, (1.0, 8.0))
    assert h.shape == (2, 1, 4) and h.dtype == np.float32
    np.testing.assert_allclose(h[0, 0], [1, np.exp(-1), np.exp(-10), 0], rtol=1e-6)
    np.testing.assert_allclose(h[1, 0, 1], np.exp(-1 / 8), rtol=1e-6)
    assert (np.diff(h, axis=-1) < 0).all() and (h[1] >= h[0]).all()


def test_streaming_in_pieces_gives_the_one_shot_age():
    ev = random_events(500, seed=1)
    age = EventAge(ev.sensor_hw)
    for lo, hi in [(0, 40), (40, 41), (41, 300)]:
        age.advance(ev.slice(lo, 500), lo, hi)
        for anchor in (hi, hi + 7, 500):  # asked ahead, from the events still held
            np.testing.assert_array_equal(age.age_at(ev.slice(hi, 500), hi, anchor),
                                          brute_age(ev, anchor))
    with pytest.raises(ValueError, match="moved past"):
        age.age_at(ev.slice(300, 500), 300, 299)
    with pytest.raises(ValueError, match="needs events"):
        age.age_at(ev.slice(310, 500), 310, 400)  # events 300-310 are missing


def test_a_forgetting_window_keeps_the_whole_history():
    """The reconstruction window drops old events as it reads chunks and as outputs move
    on; the history still counts every event ever read."""
    ev = random_events(3000, seed=2)
    chunks = (ev.slice(k, k + 128) for k in range(0, 3000, 128))
    window = EventWindow(chunks, ev.sensor_hw, keep=300, history=True)
    for anchor in (250, 900, 901, 2500, 3000):
        np.testing.assert_array_equal(window.age_at(anchor), brute_age(ev, anchor))
        window.forget(anchor - 50)
    assert window.offset > 0  # it did forget


def _refs(tiny_shards, **data):
    cfg = tiny_config()
    dcfg = dataclasses.replace(cfg.data, **data)
    shards = find_shards(tiny_shards)
    train, val = index_samples(shards, dcfg, cfg.model.n_stacks, cfg.model.scale)
    return cfg, dcfg, shards, train + val


def test_training_samples_carry_the_history_of_their_whole_sequence(tiny_shards):
    """Shard path against the brute-force age of the sequence's events; the cache path
    equals the shard path, with crops and flips."""
    taus = (2.0, 16.0)
    cfg, dcfg, shards, refs = _refs(tiny_shards, crop=None, flips=False)
    plain = ShardSamples(refs, dcfg, 3, 2, False, history=taus)
    per_stack = dcfg.stacks.events_per_stack
    for i in (0, len(refs) // 2, len(refs) - 1):
        ref = refs[i]
        with ShardReader(ref.path) as reader:
            events = reader.events(ref.sequence, 0, ref.anchor)
        expected = history_input(brute_age(events, ref.anchor), per_stack, taus)
        item = plain[i]
        np.testing.assert_allclose(item["history"].numpy(), expected, rtol=1e-6)
        # every pixel that fired in the central stack is at most one stack old
        fired = (item["stacks"][1] != 0).any(0).numpy()
        assert fired.any() and (item["history"][0].numpy()[fired] >= np.exp(-1 / 2) - 1e-6).all()
    _, dcfg, shards, refs = _refs(tiny_shards)
    spec = CacheSpec(dcfg.stacks, dcfg.flow, 3, 2, history=True)
    cache = InputCache.build(shards, refs, spec)
    plain = ShardSamples(refs, dcfg, 3, 2, True, seed=4, history=taus)
    cached = ShardSamples(refs, dcfg, 3, 2, True, 4, cache, taus)
    for i in range(0, len(refs), 3):
        a, b = plain[i], cached[i]
        assert torch.equal(a["stacks"], b["stacks"])
        assert torch.allclose(a["history"], b["history"], rtol=1e-6)


def test_a_model_without_history_warm_starts_one_with_it_exactly(tmp_path):
    for fold in (1, 2):
        old, path = saved_net(tmp_path, dataclasses.replace(LR_NET, fold=fold))
        new = E2SRI(dataclasses.replace(LR_NET, fold=fold, history=(4.0, 32.0)))
        done = warm_start(new, path)
        assert set(done.widened) == {"efr0.0.0.weight", "efr.0.0.weight"} and not done.fresh
        stacks, flows = torch.randn(2, 3, 3, 10, 12), torch.randn(2, 3, 2, 10, 12)
        history = torch.rand(2, 2, 10, 12)
        with torch.no_grad():
            want = old(stacks, stacks[:, 1], flows)
            got = new(stacks, torch.cat([stacks[:, 1], history], 1), flows)
            scale = float(want.abs().max())  # random weights: large outputs
            assert float((got - want).abs().max()) < 1e-5 * scale
            # the history columns are live parameters, starting at zero
            new.efr0[0][0].weight[:, -1].fill_(1.0)
            moved = new(stacks, torch.cat([stacks[:, 1], history], 1), flows)
            assert float((moved - want).abs().max()) > 1e-3 * scale


def test_a_history_model_refuses_to_run_without_it():
    from model.archs.e2sri_arch import central_input

    cfg = dataclasses.replace(LR_NET, history=(4.0,))
    assert cfg.central_channels == 4
    stacks, flows = torch.zeros(1, 3, 3, 8, 8), torch.zeros(1, 3, 2, 8, 8)
    with pytest.raises(ValueError, match="event-history input"):
        central_input(cfg, stacks, flows, None, None)
    assert central_input(cfg, stacks, flows, None, None, torch.ones(1, 1, 8, 8)).shape[1] == 4
    with pytest.raises(ValueError, match="> 0"):
        NetConfig(history=(0.0,))


def test_reconstruction_feeds_a_trained_history_model_what_training_did(tiny_shards, tmp_path):
    """A model trained with the history gets, streaming a recording in small chunks, the
    history its training samples of the same frames had; and the run writes its frames."""
    from datagen.recording import open_recording
    from model.inference.reconstruct import Reconstructor, plan_outputs, reconstruct
    from model.training.train import train

    train(tiny_config("model.history=[2, 16]", "run.max_steps=2"), tiny_shards, tmp_path,
          show_progress=False)
    path = sorted(tiny_shards.glob("shard_*.h5"))[0]
    rec = open_recording(path, sequence="seq_000001")
    model = Reconstructor.load(tmp_path / "last.pt", rec.sensor_hw, device="cpu")
    assert model.net.config.history == (2.0, 16.0)
    cfg, dcfg, _, refs = _refs(tiny_shards, crop=None, flips=False)
    refs = [r for r in refs if r.path == str(path) and r.sequence == "seq_000001"]
    samples = ShardSamples(refs, dcfg, 3, 2, False, history=(2.0, 16.0))
    window = model.event_window(rec.events(37), rec.sensor_hw, 37)
    assert refs
    for i, ref in enumerate(refs):
        given = model.stacks_at(window, ref.t_ns)
        assert given.anchor == ref.anchor
        np.testing.assert_allclose(given.history, samples[i]["history"].numpy(), rtol=1e-6)
        window.forget(given.first)
    out = reconstruct(open_recording(path, sequence="seq_000001"), model, tmp_path / "rec",
                      plan_outputs(rec, model.stacks), show_progress=False, chunk=37)
    assert len(out.frames) == len(rec.frames)
