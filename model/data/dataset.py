"""Training samples from datagen shards: SBN stacks around a frame, its LR and HR frames.

A sample is ``n`` stacks whose central one ends at frame ``k``'s event index (the paper
samples ground truth at the last event of the central stack), its neighbours adjacent or
overlapped before and after; the HR frame ``k`` is the target and the LR frame ``k`` the APS
input of the Complementary extension. Training samples are random LR crops (HR crop at the
same place, ``scale`` times larger; the rig makes them tile exactly) with random flips;
validation samples are whole frames. Randomness derives from ``(seed, epoch, index)`` only,
so any worker count, order or resumption gives the same samples.
"""

from __future__ import annotations

import logging
import math
import os
import zlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from datagen.shard import ShardReader
from esim_lite.core.scales import hr_camera
from esim_lite.core.stacking import (
    StackConfig,
    stack_fit_warnings,
    stack_span_ns,
    stack_to_input,
    stacks_around,
)
from esim_lite.geometry.motion import planar_flow
from esim_lite.geometry.pose import Pose
from model.data.classical_flow import stack_flows
from model.data.config import DataConfig
from model.data.input_cache import InputCache
from model.stack_size import ACTIVE_WINDOW_S, activity_of, choose_stack

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SampleRef:
    path: str
    sequence: str
    frame: int
    anchor: int  # events before the frame (the central SBN stack ends here)
    t_ns: int  # the frame's time (the central SBT stack ends here)
    events_per_channel: int  # the sequence's SBN stacks (data.stack_rule)

    def stacks(self, config: StackConfig) -> StackConfig:
        """``config`` with this sample's events per channel."""
        if config.events_per_channel == self.events_per_channel:
            return config
        return replace(config, events_per_channel=self.events_per_channel)


def sequence_stacks(reader: ShardReader, sequence: str, data: DataConfig) -> StackConfig:
    """The SBN settings of one sequence's samples under ``data.stack_rule``: ``fixed``, the
    configured ones; ``active``, reconstruction's active-pixel rule applied to the
    sequence's first second (:func:`model.stack_size.choose_stack`), the
    sequence's sensor counting as the trained one."""
    if data.stack_rule == "fixed":
        return data.stacks
    first = reader.events(sequence, 0, 1)
    if not len(first):
        return data.stacks
    # a millisecond past the window: activity_of cuts at the window exactly
    end = reader.event_index_at(sequence, int(first.t_ns[0]) + round(ACTIVE_WINDOW_S * 1e9)
                                + 1_000_000)
    activity = activity_of(reader.events(sequence, 0, end))
    hw = activity.sensor_hw
    choice = choose_stack(data.stacks.events_per_channel, data.stacks.channels, hw, hw,
                          activity=activity)
    return replace(data.stacks, events_per_channel=choice.events_per_channel)


def split_sequences(keys: list[str], val_fraction: float) -> set[str]:
    """The held-out sequence keys: the ``ceil(fraction * N)`` with the smallest CRC32, so the
    split is deterministic and, with >= 2 sequences, never empty."""
    if val_fraction <= 0 or len(keys) < 2:
        return set()
    n_val = min(len(keys) - 1, max(1, math.ceil(val_fraction * len(keys))))
    return set(sorted(keys, key=lambda k: (zlib.crc32(k.encode()), k))[:n_val])


def index_samples(shards: list[Path], data: DataConfig, n_stacks: int, scale: int
                  ) -> tuple[list[SampleRef], list[SampleRef]]:
    """(train, val) samples: every frame whose stacks fit inside its sequence's events."""
    half = n_stacks // 2
    span = stack_span_ns(data.stacks)
    samples: dict[str, list[SampleRef]] = {}
    warned: set = set()
    for path in shards:
        with ShardReader(path) as reader:
            layout = reader.frame_layout()
            if data.stacks.method == "sbn" and layout is not None and layout.mode == "events" \
                    and (layout.every_events, layout.tail_events) not in warned:
                warned.add((layout.every_events, layout.tail_events))
                # against the configured size (the active rule's are at most that)
                for problem in stack_fit_warnings(layout.every_events, layout.tail_events,
                                                  data.stacks.events_per_stack, n_stacks,
                                                  data.stacks.overlap):
                    log.warning("%s: %s", path, problem)
            for seq in reader.sequences():
                cams = reader.frame_names(seq)
                if hr_camera(scale) not in cams:
                    raise ValueError(f"{path}/{seq}: no {hr_camera(scale)} frames (it has "
                                     f"{', '.join(cams)}); generate with --scale {scale}")
                for camera in ("lr", hr_camera(scale)):
                    reader.check_frames(seq, camera)
                total = reader.num_events(seq)
                idx = reader.frame_event_idx(seq)
                t = reader.frame_times_ns(seq)
                stacks = sequence_stacks(reader, seq, data)
                per_stack = stacks.events_per_stack
                before = per_stack + half * (per_stack - stacks.overlap)
                after = half * (per_stack - stacks.overlap)
                if data.stacks.method == "sbn":
                    fits = [k > 0 and a - before >= 0 and a + after <= total
                            for k, a in enumerate(idx)]
                else:  # by time: the stacks' time span must lie inside the recording
                    t_last = reader.last_event_ns(seq)
                    fits = [k > 0 and t[k] - (half + 1) * span >= 0 and
                            t[k] + half * span <= t_last for k in range(len(idx))]
                samples[f"{path.name}/{seq}"] = [
                    SampleRef(str(path), seq, k, int(a), int(t[k]), stacks.events_per_channel)
                    for k, a in enumerate(idx) if fits[k]]
    val_keys = split_sequences(sorted(samples), data.val_fraction)
    train = [s for k in sorted(samples) if k not in val_keys for s in samples[k]]
    val = [s for k in sorted(samples) if k in val_keys for s in samples[k]]
    return train, val


_FLIP_X = np.array([-1.0, 1.0], np.float32)[:, None, None]  # negate dx on a left-right flip
_FLIP_Y = np.array([1.0, -1.0], np.float32)[:, None, None]  # negate dy on an up-down flip


class ShardSamples(Dataset):
    """``dataset[i]`` -> dict of tensors: ``stacks`` (n, c, h, w) in [-1, 1], ``flows``
    (n, 2, h, w) pixels, ``lr`` (1, h, w) and ``hr`` (1, s h, s w) linear intensity,
    and ``index``. Shard files are opened lazily, once per process."""

    def __init__(self, refs: list[SampleRef], data: DataConfig, n_stacks: int, scale: int,
                 train: bool, seed: int = 0, cache: InputCache | None = None) -> None:
        self.refs, self.data, self.n_stacks, self.scale = refs, data, n_stacks, scale
        self.train, self.seed, self.epoch, self.cache = train, seed, 0, cache
        self._readers: dict[str, ShardReader] = {}
        self._pid = None

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.refs)

    def _reader(self, path: str) -> ShardReader:
        if self._pid != os.getpid():  # a DataLoader worker: handles are not inherited
            self._readers, self._pid = {}, os.getpid()
        if path not in self._readers:
            self._readers[path] = ShardReader(path)
        return self._readers[path]

    def _stacks(self, reader: ShardReader, ref: SampleRef):
        """(events read, stacks) around the sample's frame, by number or by time."""
        cfg, half, t = ref.stacks(self.data.stacks), self.n_stacks // 2, ref.t_ns
        if cfg.method == "sbn":
            lo = max(0, ref.anchor - (half + 1) * cfg.events_per_stack)
            hi = min(reader.num_events(ref.sequence), ref.anchor + half * cfg.events_per_stack)
        else:
            span = stack_span_ns(cfg)
            lo = reader.event_index_at(ref.sequence, t - (half + 1) * span)
            hi = reader.event_index_at(ref.sequence, t + half * span)
        events = reader.events(ref.sequence, lo, hi)
        return events, stacks_around(events, cfg, self.n_stacks, ref.anchor - lo, t)

    def _exact_flows(self, reader: ShardReader, ref: SampleRef, events, built) -> np.ndarray:
        """float32[n, 2, H, W]: the plane's true flow from the central stack's end time to
        each stack's end time (LR pixels)."""
        traj = reader.trajectory(ref.sequence)
        cam = reader.cameras(ref.sequence)["lr"]

        def pose_at(stack) -> Pose:
            k = max(stack.end - 1, 0)
            t = events.t_ns[k] * 1e-9 if len(events) else 0.0
            return traj.pose(min(max(t, 0.0), traj.duration_s))

        mid = self.n_stacks // 2
        centre = pose_at(built[mid])
        flows = np.stack([planar_flow(cam, centre, pose_at(st)).transpose(2, 0, 1)
                          for st in built]).astype(np.float32)
        flows[mid] = 0.0  # by definition (the projection round trip leaves ~1e-14)
        return flows

    def _inputs(self, ref: SampleRef):
        """(stacks uint8[n, c, H, W], whole-frame flows float32[n, 2, H, W] or None to
        compute them after cropping, lr, hr)."""
        if self.cache is not None:
            return self.cache.sample(ref)
        reader = self._reader(ref.path)
        events, built = self._stacks(reader, ref)
        stacks = np.stack([st.image for st in built])
        lr = reader.frame(ref.sequence, "lr", ref.frame)
        hr = reader.frame(ref.sequence, hr_camera(self.scale), ref.frame)
        given = self._exact_flows(reader, ref, events, built) \
            if self.data.flow == "exact" else None
        return stacks, given, lr, hr

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        """Sample ``i``'s tensors, cropped and flipped as this epoch draws them."""
        ref, cfg, s = self.refs[i], self.data, self.scale
        stacks, given, lr, hr = self._inputs(ref)
        if self.train:
            rng = np.random.default_rng([self.seed, self.epoch, i])
            if cfg.crop is not None:
                h, w = lr.shape
                if cfg.crop > min(h, w):
                    raise ValueError(f"{ref.path}: crop {cfg.crop} exceeds the {w}x{h} frames")
                y0 = int(rng.integers(0, h - cfg.crop + 1))
                x0 = int(rng.integers(0, w - cfg.crop + 1))
                win = (slice(y0, y0 + cfg.crop), slice(x0, x0 + cfg.crop))
                stacks, lr = stacks[(..., *win)], lr[win]
                hr = hr[s * y0:s * (y0 + cfg.crop), s * x0:s * (x0 + cfg.crop)]
                given = None if given is None else given[(..., *win)]
            if cfg.flips and rng.random() < 0.5:
                stacks, lr, hr = stacks[..., ::-1], lr[:, ::-1], hr[:, ::-1]
                given = None if given is None else given[..., ::-1] * _FLIP_X
            if cfg.flips and rng.random() < 0.5:
                stacks, lr, hr = stacks[..., ::-1, :], lr[::-1], hr[::-1]
                given = None if given is None else given[..., ::-1, :] * _FLIP_Y
        stacks = np.ascontiguousarray(stacks)
        n, _, h, w = stacks.shape
        if given is not None:  # exact, or cached whole-frame flow: cropped/flipped above
            flows = np.ascontiguousarray(given, np.float32)
        elif cfg.flow in ("dis", "farneback"):
            flows = stack_flows(stacks, cfg.flow)
        else:
            flows = np.zeros((n, 2, h, w), np.float32)
        return {"stacks": torch.from_numpy(stack_to_input(stacks)),
                "flows": torch.from_numpy(flows),
                "lr": torch.from_numpy(np.ascontiguousarray(lr))[None],
                "hr": torch.from_numpy(np.ascontiguousarray(hr))[None],
                "index": torch.tensor(i)}
