"""Start a network from another one's weights: an x4 run from a trained x2 model.

Only the scale, the lift's ending (``lift``: the parameter-free anti-grid filter), the
context branch (``context``: its tensors are left fresh, its residual starting at zero;
``context_far`` from ``cells`` to ``dilated``: the 16x16 path is dropped, the dilated one left
fresh and its columns of the residual zero; ``context_global`` added: its whole-frame path
fresh, its own residual zero; ``context_support`` added: likewise; ``context_gate``, which has
no parameters) and
the event-history input (``history``, added to a model without one: the first convolutions
of EFR get new input columns, set to zero, so the network computes exactly what it did) may
differ between the two networks. Every tensor whose name and shape agree
is copied. In the LR-state variant the one scale-dependent layer is the sub-pixel lift
(``mix.1``: ``scale^2 x hr_channels`` output channels before the pixel shuffle); when the new
scale is a multiple ``k`` of the old one, each of its sub-pixel channels is copied from the old
sub-pixel it falls in, so the lifted features start as the old ones repeated over ``k x k``
pixels (nearest upsampling) instead of random. Anything else that differs in shape (the
HR-state variant's deconvolutions) keeps its fresh initialisation and is named in the log.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import torch

from esim_lite.core.dataconf import from_mapping
from model import checkpoint
from model.archs.e2sri_arch import E2SRI, NetConfig

log = logging.getLogger(__name__)

LIFT = "mix.1"  # the sub-pixel convolution of the LR-state variant
# what a warm start may change: no tensor, or new ones that start at zero (the context
# branch's residuals, the history's input columns, the memory's input convolution)
FREE = ("scale", "lift", "context", "context_far", "context_global", "context_support",
        "context_gate", "history", "memory")
WIDENED = ("efr0.0.0.weight", "efr.0.0.weight")  # first convolutions that read the central
# input: the history's channels are inserted after the old central channels


@dataclasses.dataclass(frozen=True)
class WarmStart:
    """What ``warm_start`` did: tensors copied as they were, lifted, and left fresh."""

    copied: tuple[str, ...]
    lifted: tuple[str, ...]
    fresh: tuple[str, ...]
    widened: tuple[str, ...] = ()


def widen_columns(old: NetConfig, new: NetConfig, name: str) -> tuple[torch.Tensor, int]:
    """(new input-column index of each old column, new column count) of the first
    convolution ``name`` of :data:`WIDENED` when the history input is added: the old
    central channels keep their places and the history's follow them (each channel spans
    ``fold^2`` columns after the space-to-depth fold)."""
    f2 = new.fold ** 2
    k = len(new.history) * f2
    c_old = old.central_channels * f2
    if name == "efr0.0.0.weight":  # [central]
        return torch.arange(c_old), c_old + k
    s = new.stack_channels * f2  # efr: [stack j, central, flow j]
    cols = torch.cat([torch.arange(s + c_old), torch.arange(s + c_old + k, s + c_old + k + 2 * f2)])
    return cols, s + c_old + k + 2 * f2

def lift_index(old_scale: int, new_scale: int, fold: int, channels: int) -> torch.Tensor:
    """For each output channel of the new lift, the old lift's channel it copies.

    A pixel shuffle by ``r`` maps channel ``c r^2 + i r + j`` to sub-pixel ``(i, j)`` of
    feature ``c``; new sub-pixel ``(i, j)`` lies in old sub-pixel ``(i // k, j // k)``.
    """
    r_old, r_new = old_scale * fold, new_scale * fold
    k = r_new // r_old
    c, i, j = torch.meshgrid(torch.arange(channels), torch.arange(r_new), torch.arange(r_new),
                             indexing="ij")
    return (c * r_old * r_old + (i // k) * r_old + (j // k)).reshape(-1)


def warm_start(net: E2SRI, source: str | Path) -> WarmStart:
    """Copy the weights of the checkpoint or shipped model ``source`` into ``net``.

    Raises:
        ValueError: ``source`` is not a network checkpoint, its network differs from
            ``net``'s in more than the scale, or the new scale is not a multiple of its scale.
    """
    ckpt = checkpoint.load(source)
    old = from_mapping(NetConfig, ckpt["net"], source=str(source))
    new = net.config
    if dataclasses.replace(old, scale=new.scale, lift=new.lift, context=new.context,
                           context_far=new.context_far, context_global=new.context_global,
                           context_support=new.context_support, context_gate=new.context_gate,
                           history=new.history, memory=new.memory) != new:
        differ = [f.name for f in dataclasses.fields(NetConfig) if f.name not in FREE
                  and getattr(old, f.name) != getattr(new, f.name)]
        raise ValueError(f"{source}: its network differs in {', '.join(differ)}; a warm start "
                         f"may change only the scale, the lift filter, the context "
                         f"branch, the event history and the memory")
    if old.context and new.context != old.context:
        raise ValueError(f"{source}: its context branch (width {old.context}) would be lost "
                         f"or left fresh (model.context: {new.context})")
    if old.context_global and not new.context_global:
        raise ValueError(f"{source}: its context branch's whole-frame path would be lost "
                         f"(model.context_global: false)")
    if old.context_support and not new.context_support:
        raise ValueError(f"{source}: its context branch's support path would be lost "
                         f"(model.context_support: false)")
    if old.context and old.context_far != new.context_far and old.context_far == "none":
        raise ValueError(f"{source}: a context branch without a far path cannot start one "
                         f"with a far path (model.context_far: {new.context_far})")
    if old.context and old.context_far != new.context_far and old.context_far != "cells":
        raise ValueError(f"{source}: its context branch's far path ({old.context_far}) "
                         f"would be lost (model.context_far: {new.context_far})")
    if old.history and new.history != old.history:
        raise ValueError(f"{source}: its event history (time constants {old.history}) "
                         f"differs from model.history {new.history}")
    if old.memory and not new.memory:
        raise ValueError(f"{source}: its memory across outputs would be lost "
                         f"(model.memory: false)")
    if new.scale % old.scale:
        raise ValueError(f"{source}: an x{old.scale} model cannot start an x{new.scale} one "
                         f"(the new scale must be a multiple of the old)")
    saved = {k: v.float() if v.is_floating_point() else v for k, v in ckpt["model"].items()}
    target = net.state_dict()
    copied, lifted, fresh, widened = [], [], [], []
    with torch.no_grad():
        for name, tensor in target.items():
            value = saved.get(name)
            if value is not None and value.shape == tensor.shape:
                tensor.copy_(value)
                copied.append(name)
            elif value is not None and name in WIDENED and new.history and not old.history:
                cols, width = widen_columns(old, new, name)
                if tensor.shape[1] != width or value.shape[1] != len(cols):
                    raise ValueError(f"{source}: {name} has {value.shape[1]} input columns, "
                                     f"not the {len(cols)} its network implies")
                tensor.zero_()
                tensor[:, cols] = value
                widened.append(name)
            elif value is not None and new.state == "lr" and name.startswith(LIFT + "."):
                index = lift_index(old.scale, new.scale, new.fold, new.hr_channels)
                tensor.copy_(value[index])
                lifted.append(name)
            else:
                fresh.append(name)
        if old.context and old.context_far != new.context_far and new.context_far == "none":
            # the 16x16 path is dropped with its columns of the residual: the new network
            # computes the old one without it (the near path's columns come first)
            net.context.out.weight.copy_(saved["context.out.weight"][:, :new.context])
            fresh.remove("context.out.weight")
            copied.append("context.out.weight (near columns)")
        elif old.context and old.context_far != new.context_far:
            # the 16x16 path is dropped: its columns of the residual start at zero, so the
            # new network computes the old one without it, the dilated path fresh beside it
            net.context.out.weight[:, new.context * len(net.context.factors):] = 0
            fresh.append("context.out.weight (far columns)")
    if not copied:
        raise ValueError(f"{source}: no tensor matches the network")
    result = WarmStart(tuple(copied), tuple(lifted), tuple(fresh), tuple(widened))
    log.info("warm start from %s (x%d -> x%d): %d tensors copied, %d lifted, %d widened, "
             "%d fresh%s", source, old.scale, new.scale, len(copied), len(lifted),
             len(widened), len(fresh),
             f" ({', '.join(fresh)})" if fresh else "")
    return result
