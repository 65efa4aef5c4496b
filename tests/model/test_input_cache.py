"""The precomputed-input cache gives the samples the shard path gives, and is safe to reuse."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest
import torch

from datagen.shard import find_shards
from esim_lite.core.stacking import StackConfig
from model.data.dataset import ShardSamples, index_samples
from model.data.input_cache import CacheSpec, InputCache, build_shard, cache_folder
from tests.model.conftest import tiny_config


def _setup(tiny_shards, **data):
    cfg = tiny_config()
    dcfg = dataclasses.replace(cfg.data, **data)
    shards = find_shards(tiny_shards)
    train, val = index_samples(shards, dcfg, cfg.model.n_stacks, cfg.model.scale)
    spec = CacheSpec(dcfg.stacks, dcfg.flow, cfg.model.n_stacks, cfg.model.scale)
    return cfg, dcfg, shards, train + val, spec


def test_cached_samples_equal_the_shard_path(tiny_shards):
    cfg, dcfg, shards, refs, spec = _setup(tiny_shards, crop=None, flips=False)
    cache = InputCache.build(shards, refs, spec)
    plain = ShardSamples(refs, dcfg, cfg.model.n_stacks, cfg.model.scale, True)
    cached = ShardSamples(refs, dcfg, cfg.model.n_stacks, cfg.model.scale, True, cache=cache)
    for i in range(len(refs)):
        a, b = plain[i], cached[i]
        for key in ("stacks", "lr", "hr"):
            assert torch.equal(a[key], b[key]), key
        # whole frames, no crop: the same DIS on the same images, stored in float16
        assert torch.allclose(a["flows"], b["flows"], atol=2e-2, rtol=1e-3)
        assert float(a["flows"].abs().max()) > 0  # DIS found motion: the check means something


def test_cropped_and_flipped_samples_keep_flow_signs(tiny_shards):
    """With crops and flips the stacks and frames are the shard path's exactly; the cached
    flow (DIS on whole frames, then cropped and flipped with its sign) points the same way
    as DIS run on the flipped crop itself."""
    cfg, dcfg, shards, refs, spec = _setup(tiny_shards)
    cache = InputCache.build(shards, refs, spec)
    plain = ShardSamples(refs, dcfg, cfg.model.n_stacks, cfg.model.scale, True, seed=3)
    cached = ShardSamples(refs, dcfg, cfg.model.n_stacks, cfg.model.scale, True, 3, cache)
    dots = []
    for i in range(len(refs)):
        a, b = plain[i], cached[i]
        assert torch.equal(a["stacks"], b["stacks"]) and torch.equal(a["hr"], b["hr"])
        dots.append(float((a["flows"] * b["flows"]).sum()))
    assert np.mean(dots) > 0


def test_cache_is_keyed_by_settings_and_an_interrupted_build_is_redone(tiny_shards, tmp_path):
    _, dcfg, shards, refs, spec = _setup(tiny_shards)
    folder = cache_folder(spec, shards[0])
    other = CacheSpec(StackConfig(events_per_channel=50), spec.flow, spec.n_stacks, spec.scale)
    assert cache_folder(other, shards[0]) != folder
    assert cache_folder(dataclasses.replace(spec, n_stacks=5), shards[0]) != folder
    # a build killed half-way leaves only a temporary folder: not taken for a cache
    target = tmp_path / "c" / "shard"
    (tmp_path / "c" / "shard.tmp-999").mkdir(parents=True)
    (tmp_path / "c" / "shard.tmp-999" / "stacks.npy").write_bytes(b"partial")
    mine = [r for r in refs if r.path == str(shards[0])]
    build_shard(target, shards[0], mine, spec)
    assert sorted(p.name for p in target.iterdir()) == ["flows.npy", "hr.npy", "keys.json",
                                                       "lr.npy", "rows.npy", "stacks.npy"]
    # ours is renamed into place; another process's temporary folder is not ours to delete
    assert sorted(p.name for p in target.parent.iterdir()) == ["shard", "shard.tmp-999"]


def test_only_what_the_cache_can_hold_is_accepted():
    with pytest.raises(ValueError, match="SBN"):
        CacheSpec(StackConfig(method="sbt"), "dis", 3, 2)
    with pytest.raises(ValueError, match="classical flow"):
        CacheSpec(StackConfig(), "exact", 3, 2)


def test_a_cache_missing_samples_another_dataset_needs_gets_its_own(tiny_shards, tmp_path):
    """Validation keeps a spread of frames whose choice depends on the whole dataset, so a
    shard cached for one folder of links can lack samples a second folder over the same
    shard asks for: the second gets a cache folder of its own, and the first, which a run
    may still be reading, stays as it was (two runs started together once lost a sample
    when the second replaced the first's folder)."""
    own = tmp_path / "shard_00000.h5"      # a private copy: no other test's cache beside it
    shutil.copy(find_shards(tiny_shards)[0], own)
    cfg, dcfg, shards, refs, spec = _setup(tmp_path, crop=None, flips=False)
    mine = [r for r in refs if r.path == str(shards[0])]
    assert shards == [own] and len(mine) >= 2
    first = InputCache.build(shards, mine[:1], spec)               # one sample only
    with pytest.raises(ValueError, match="no cached sample"):
        ShardSamples(mine[1:2], dcfg, cfg.model.n_stacks, cfg.model.scale, False,
                     cache=first)[0]
    folder = cache_folder(spec, shards[0])
    before = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    second = InputCache.build(shards, mine, spec)                  # all of the shard's samples
    plain = ShardSamples(mine, dcfg, cfg.model.n_stacks, cfg.model.scale, False)
    cached = ShardSamples(mine, dcfg, cfg.model.n_stacks, cfg.model.scale, False, cache=second)
    for i in range(len(mine)):
        assert torch.equal(plain[i]["hr"], cached[i]["hr"])
    # the first run's folder is untouched and still serves it, from a fresh process's view
    assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir()} == before
    again = InputCache(dict(first.folders))
    assert torch.equal(ShardSamples(mine[:1], dcfg, cfg.model.n_stacks, cfg.model.scale, False,
                                    cache=again)[0]["hr"], plain[0]["hr"])
    assert second.folders[str(shards[0])] != folder
    # a third build of either set finds its folder and builds nothing
    assert InputCache.build(shards, mine, spec).folders == second.folders
    assert InputCache.build(shards, mine[:1], spec).folders == first.folders
    assert not list(folder.parent.glob("*.tmp-*")) and not list(folder.parent.glob("*.old-*"))
