"""Training stacks by the active-pixel rule: per-sequence sizes, cache, and inference's choice."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from datagen.shard import ShardReader, find_shards
from esim_lite.core.stacking import StackConfig
from model.data.config import DataConfig
from model.data.dataset import ShardSamples, index_samples, sequence_stacks
from model.data.input_cache import CacheSpec, InputCache, cache_folder
from model.stack_size import MIN_ACTIVE_FRACTION, resolve_rule
from tests.model.conftest import tiny_config


def expected_per_channel(reader: ShardReader, seq: str, per_channel: int) -> int:
    """The rule computed here from scratch: pixels with >= 2 events in the first second."""
    ev = reader.events(seq)
    first = ev.t_ns < ev.t_ns[0] + 1_000_000_000
    h, w = ev.sensor_hw
    counts = np.zeros((h, w), int)
    np.add.at(counts, (ev.y[first].astype(int), ev.x[first].astype(int)), 1)
    fraction = min(max(np.count_nonzero(counts >= 2) / (h * w), MIN_ACTIVE_FRACTION), 1.0)
    return max(1, round(per_channel * fraction))


def active_data(**more) -> DataConfig:
    return dataclasses.replace(tiny_config().data, stack_rule="active", **more)


def test_each_sequence_gets_the_active_rules_size(tiny_shards):
    data = active_data()
    sizes = []
    for path in find_shards(tiny_shards):
        with ShardReader(path) as reader:
            for seq in reader.sequences():
                got = sequence_stacks(reader, seq, data)
                want = expected_per_channel(reader, seq, data.stacks.events_per_channel)
                assert got.events_per_channel == want
                assert sequence_stacks(reader, seq, tiny_config().data) == tiny_config().data.stacks
                sizes.append(want)
    assert min(sizes) < data.stacks.events_per_channel  # the rule changes something here


def test_samples_are_built_with_their_sequences_stacks(tiny_shards):
    cfg, data = tiny_config(), active_data(crop=None, flips=False)
    shards = find_shards(tiny_shards)
    train, val = index_samples(shards, data, cfg.model.n_stacks, cfg.model.scale)
    fixed, _ = index_samples(shards, cfg.data, cfg.model.n_stacks, cfg.model.scale)
    assert train and {r.events_per_channel for r in fixed} == {data.stacks.events_per_channel}
    samples = ShardSamples(train, data, cfg.model.n_stacks, cfg.model.scale, False)
    for i in range(0, len(train), max(1, len(train) // 6)):
        ref = train[i]
        reader = samples._reader(ref.path)
        events, built = samples._stacks(reader, ref)
        per_stack = 3 * ref.events_per_channel
        # three stacks' worth read, the central one ending at the frame's event
        assert len(events) == 3 * per_stack and built[1].end == 2 * per_stack
        assert all(0 < st.end - st.start <= per_stack for st in built)


def test_the_cache_gives_the_shard_paths_stacks_under_the_rule(tiny_shards):
    cfg, data = tiny_config(), active_data(crop=None, flips=False)
    shards = find_shards(tiny_shards)
    train, val = index_samples(shards, data, cfg.model.n_stacks, cfg.model.scale)
    refs = train + val
    spec = CacheSpec(data.stacks, data.flow, cfg.model.n_stacks, cfg.model.scale, "active")
    fixed = CacheSpec(data.stacks, data.flow, cfg.model.n_stacks, cfg.model.scale)
    assert cache_folder(spec, shards[0]) != cache_folder(fixed, shards[0])
    cache = InputCache.build(shards, refs, spec)
    plain = ShardSamples(refs, data, cfg.model.n_stacks, cfg.model.scale, False)
    cached = ShardSamples(refs, data, cfg.model.n_stacks, cfg.model.scale, False, cache=cache)
    for i in range(len(refs)):
        assert torch.equal(plain[i]["stacks"], cached[i]["stacks"])


def test_the_rule_is_checked_and_inference_follows_the_training_rule():
    with pytest.raises(ValueError, match="fixed or active"):
        DataConfig(stack_rule="area")
    with pytest.raises(ValueError, match="without overlap"):
        DataConfig(stacks=StackConfig(overlap=10), stack_rule="active")
    assert resolve_rule("auto", "shard") == "area"
    assert resolve_rule("auto", "shard", "active") == "active"
    assert resolve_rule("auto", "aedat4", "fixed") == "active"
    assert resolve_rule("area", "shard", "active") == "area"
