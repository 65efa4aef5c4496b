"""Start a network from another one's weights: an x4 run from a trained x2 model.

Only the scale, the lift's ending (``lift``: the parameter-free anti-grid filter) and the
context branch (``context``: added to a network without one, its tensors fresh and its
residual starting at zero, so the network computes exactly what it did) may differ between
the two networks. Every tensor whose name and shape agree is copied. In the LR-state variant
the one scale-dependent layer is the sub-pixel lift (``mix.1``: ``scale^2 x hr_channels``
output channels before the pixel shuffle); when the new scale is a multiple ``k`` of the old
one, each of its sub-pixel channels is copied from the old sub-pixel it falls in, so the
lifted features start as the old ones repeated over ``k x k`` pixels (nearest upsampling)
instead of random. Anything else that differs in shape (the HR-state variant's
deconvolutions) keeps its fresh initialisation and is named in the log.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import torch

from model import checkpoint
from model.archs.e2sri_arch import E2SRI, NetConfig

log = logging.getLogger(__name__)

LIFT = "mix.1"  # the sub-pixel convolution of the LR-state variant
FREE = ("scale", "lift", "context")
"""What a warm start may change: no tensor, or new ones whose residual starts at zero."""


@dataclasses.dataclass(frozen=True)
class WarmStart:
    """What ``warm_start`` did: tensors copied as they were, lifted, and left fresh."""

    copied: tuple[str, ...]
    lifted: tuple[str, ...]
    fresh: tuple[str, ...]


def lift_index(old_scale: int, new_scale: int, channels: int) -> torch.Tensor:
    """For each output channel of the new lift, the old lift's channel it copies.

    A pixel shuffle by ``r`` maps channel ``c r^2 + i r + j`` to sub-pixel ``(i, j)`` of
    feature ``c``; new sub-pixel ``(i, j)`` lies in old sub-pixel ``(i // k, j // k)``.
    """
    r_old, r_new = old_scale, new_scale
    k = r_new // r_old
    c, i, j = torch.meshgrid(torch.arange(channels), torch.arange(r_new), torch.arange(r_new),
                             indexing="ij")
    return (c * r_old * r_old + (i // k) * r_old + (j // k)).reshape(-1)


def check_compatible(old: NetConfig, new: NetConfig, source: str | Path) -> None:
    """Refuse a warm start from ``old`` into ``new`` that would change more than
    :data:`FREE`, lose the context branch, or divide the scale."""
    if dataclasses.replace(old, scale=new.scale, lift=new.lift, context=new.context) != new:
        differ = [f.name for f in dataclasses.fields(NetConfig) if f.name not in FREE
                  and getattr(old, f.name) != getattr(new, f.name)]
        raise ValueError(f"{source}: its network differs in {', '.join(differ)}; a warm start "
                         f"may change only the scale, the lift filter and the context branch")
    if old.context and new.context != old.context:
        raise ValueError(f"{source}: its context branch (width {old.context}) would be lost "
                         f"or left fresh (model.context: {new.context})")
    if new.scale % old.scale:
        raise ValueError(f"{source}: an x{old.scale} model cannot start an x{new.scale} one "
                         f"(the new scale must be a multiple of the old)")


def warm_start(net: E2SRI, source: str | Path) -> WarmStart:
    """Copy the weights of the checkpoint or shipped model ``source`` into ``net``.

    Raises:
        ValueError: ``source`` is not a network checkpoint, its network differs from
            ``net``'s in more than the scale, the lift or an added context branch, or the
            new scale is not a multiple of its scale.
    """
    ckpt = checkpoint.load(source)
    old, new = checkpoint.net_config(ckpt, str(source)), net.config
    check_compatible(old, new, source)
    saved = {k: v.float() if v.is_floating_point() else v for k, v in ckpt["model"].items()}
    copied, lifted, fresh = [], [], []
    with torch.no_grad():
        for name, tensor in net.state_dict().items():
            value = saved.get(name)
            if value is not None and value.shape == tensor.shape:
                tensor.copy_(value)
                copied.append(name)
            elif value is not None and new.state == "lr" and name.startswith(LIFT + "."):
                tensor.copy_(value[lift_index(old.scale, new.scale, new.hr_channels)])
                lifted.append(name)
            else:
                fresh.append(name)
    if not copied:
        raise ValueError(f"{source}: no tensor matches the network")
    log.info("warm start from %s (x%d -> x%d): %d tensors copied, %d lifted, %d fresh%s",
             source, old.scale, new.scale, len(copied), len(lifted), len(fresh),
             f" ({', '.join(fresh)})" if fresh else "")
    return WarmStart(tuple(copied), tuple(lifted), tuple(fresh))
