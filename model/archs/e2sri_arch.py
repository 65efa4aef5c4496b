"""The E2SRI network (Mostafavi, Choi, Yoon, CVPR 2020): EFR, recurrent SRNet, Mix.

Data flow for ``n`` stacks with central stack ``c`` (section 3.2 of the paper; the released
code builds on RBPN, Haris et al. 2019, whose projection layout this follows):

    state_0 = EFR_0(central)                                     LR, ``base`` channels
    for each side stack j (in time order):
        RE_j    = EFR(side_j, central, flow_j)                   two conv layers
        C       = RNet-C(RE_j)          residual blocks + transposed conv -> HR features
        A       = RNet-A(state)         transposed conv + residual blocks  (state upsampled)
        e       = C - A
        S       = RNet-B(e) + C         the new HR state
        I_j     = RNet-D(S)             intermediate HR output (features)
        state   = Down(S)               back-projection to LR for the next step
    O = Mix(concat_j I_j)                                        (B, 1, s H, s W)

``central`` is the central SBN stack (main), the LR APS frame (Complementary) or a
downsampled first-pass output (Duo-Pass); the caller chooses, the network only needs its
channel count. The flow to each side stack comes from outside (classical, in the data
pipeline) or from :class:`model.archs.flow.FlowNet` when ``flow == "learned"``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import torch
import torch.nn.functional as F
from torch import nn

from esim_lite.core.scales import check_scales
from model.archs.blocks import (
    ContextBranch,
    SubPixelLift,
    conv,
    deconv,
    down,
    history_gate,
    res_stack,
)
from model.archs.flow import FlowNet


@dataclass(frozen=True)
class NetConfig:
    """Constructor arguments of :class:`E2SRI` (stored in every checkpoint).

    Attributes:
        scale: super-resolution factor (2 or 4; 8 also works).
        n_stacks: stacks per sample (odd: 3 or 7 in the paper).
        stack_channels: channels per SBN stack (the paper: 3).
        central: what the central input is: ``stack`` (main), ``aps`` (Complementary: the
            LR frame) or ``first_pass`` (Duo-Pass: a first pass's output brought to LR).
        flow: ``given`` (computed outside, e.g. OpenCV DIS), ``learned`` (FlowNet inside),
            or ``none`` (the FNet ablation: zeros).
        base_channels: LR feature width (paper: 256).
        hr_channels: HR feature width (paper: 64).
        c_blocks: residual blocks of RNet-C; blocks: of RNet-A, -B and -D (paper: 5).
        state: where the recurrent state lives. ``hr`` (the paper): RNet-C and -A lift to
            HR with transposed convolutions, RNet-B/-D and Mix work at HR, and a strided
            conv brings the state back to LR after every side stack. ``lr`` (the CPU
            variant): the whole recurrence, the intermediate outputs and Mix's first conv
            stay at LR with ``base_channels``; Mix ends in a sub-pixel lift (a conv to
            ``scale^2 x hr_channels`` channels, pixel shuffle) and one HR conv to the image.
        fold: with ``state: lr``, the inputs are first folded space-to-depth by this factor
            (a lossless pixel unshuffle, as FFDNet does: ``fold^2`` times the channels at
            1/fold the size), so the whole network runs on ``fold^2`` times fewer pixels
            with wider convolutions, which CPUs run far more efficiently than narrow ones;
            the final lift is then by ``scale x fold``. Sizes that ``fold`` does not divide
            are zero-padded (no events, no flow) and cropped back.
        lift: with ``state: lr``, how the sub-pixel lift ends. ``shuffle`` (the shipped
            models until the realistic-data retrain): a plain pixel shuffle, whose
            per-phase weights leave a faint period-``scale`` grid in flat regions.
            ``smooth``: the shuffle followed by a fixed, parameter-free filter that removes
            any period-``scale`` pattern (:class:`model.archs.blocks.SubPixelLift`); the
            state dict is the same, so a ``shuffle`` model warm-starts a ``smooth`` one.
        context: with ``state: lr``, the width of a coarse context branch on the features
            Mix reads (:class:`model.archs.blocks.ContextBranch`: averages over 4x4 and
            16x16 cells, two convolutions each, a zero-initialised residual), which lets an
            output pixel see about +-63 LR pixels instead of about +-18 (measured on the x2
            CPU variant); 0 (the shipped
            models): none. A model without it warm-starts one with it exactly.
        context_far: the far path of the context branch. ``cells`` (the default): 16x16
            cells, bilinear back. ``dilated``: dilated convolutions on the 4x4 cells, as
            far with a 4-pixel grain (:class:`model.archs.blocks.ContextBranch`). A
            ``cells`` model warm-starts a ``dilated`` one with the far path fresh and its
            share of the residual at zero: it computes what it did without its 16x16 path.
            ``none``: the near (4x4) path alone; a ``cells`` model warm-starts it as itself
            without its 16x16 path (``bench/context_ablation.py``'s ``no-far``).
        context_global: add the branch's whole-frame path (the frame mean of its features
            beside every pixel, its own zero-initialised residual); a branch without it
            warm-starts one with it exactly.
        context_support: add the branch's support path (:class:`model.archs.blocks.ContextBranch`:
            means over the pixels where an event fired, per 16x16 cell and over the frame,
            a cell with too few filled from the frame's; its own zero-initialised residual),
            so a never-fired region far from every event gets what the fired pixels say
            instead of a constant prior; a branch without it warm-starts one with it exactly.
        context_gate: 0 (the default): none. Otherwise one of ``history``'s time constants
            ``tau``: the far path's share of the branch's residual is weighted per pixel by
            that history channel, averaged over 4x4 cells
            (:func:`model.archs.blocks.history_gate`), so a background that has not fired
            for many times ``tau`` stacks gets no fill carried from the nearest fired edges
            (the cloud around moving objects under a static camera, docs/models.md) while a
            region swept within about ``tau`` stacks (a dark object's inside) keeps it. It
            has no parameters: a model without it warm-starts one with it, all tensors
            copied, and computes what it did wherever every pixel fired recently. Applied
            to the shipped x2 (run P, docs/models.md) it acted as the far path switched off:
            a flat ground under a moving camera never fires either, so the halos came back.
        history: time constants, in stacks, of the event-history input
            (:mod:`model.data.history`: for every pixel ``exp(-age / tau)``, its age the
            events since it last fired, before the output): one channel each, appended to
            the central input, so EFR sees them beside every stack. Empty (the shipped
            models): none. A model without it warm-starts one with it exactly (the new input
            columns start at zero). Needs SBN stacks.
        memory: carry the recurrent state from one output to the next (the memory across
            outputs of recurrent events-to-video networks): the previous output's final LR
            state enters this output's initial state through a zero-initialised 3x3
            convolution, so a region its edges swept outputs ago keeps what they said after
            they left. ``forward(..., memory=, return_state=True)`` takes and returns it;
            without a memory (the first output) the network computes what it would without
            the option, so a model without it warm-starts one with it exactly. Trained on
            clips of consecutive outputs (``data.clip``); CPU variant (``state: lr``) only.
    """

    scale: int = 2
    n_stacks: int = 3
    stack_channels: int = 3
    central: Literal["stack", "aps", "first_pass"] = "stack"
    flow: Literal["given", "learned", "none"] = "given"
    base_channels: int = 256
    hr_channels: int = 64
    c_blocks: int = 5
    blocks: int = 5
    state: Literal["hr", "lr"] = "hr"
    fold: int = 1
    lift: Literal["shuffle", "smooth"] = "shuffle"
    context: int = 0
    context_far: Literal["cells", "dilated", "none"] = "cells"
    context_global: bool = False
    context_support: bool = False
    context_gate: float = 0.0
    history: tuple[float, ...] = ()
    memory: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "history", tuple(float(t) for t in self.history))
        if any(not t > 0 for t in self.history):
            raise ValueError(f"model.history time constants must be > 0, got {self.history}")
        if self.fold < 1 or (self.fold > 1 and self.state != "lr"):
            raise ValueError("fold must be >= 1, and > 1 only with state: lr")
        check_scales((self.scale,), "model.scale")
        if self.lift not in ("shuffle", "smooth"):
            raise ValueError(f"model.lift must be shuffle or smooth, got {self.lift!r}")
        if self.context < 0 or (self.context and self.state != "lr"):
            raise ValueError("model.context must be >= 0, and > 0 only with state: lr")
        if self.context_global and not self.context:
            raise ValueError("model.context_global needs a context branch (model.context > 0)")
        if self.context_support and not self.context:
            raise ValueError("model.context_support needs a context branch (model.context > 0)")
        object.__setattr__(self, "context_gate", float(self.context_gate))
        if self.context_gate and (not self.context or self.context_gate not in self.history
                                  or self.fold != 1):
            raise ValueError(f"model.context_gate ({self.context_gate}) needs a context branch, "
                             f"fold 1 and the same time constant in model.history "
                             f"({list(self.history)})")
        if self.context_gate and self.context_far == "none":
            raise ValueError("model.context_gate gates the far path; context_far: none has none")
        if self.context_far not in ("cells", "dilated", "none"):
            raise ValueError(f"model.context_far must be cells, dilated or none, got "
                             f"{self.context_far!r}")
        if self.memory and self.state != "lr":
            raise ValueError("model.memory needs the CPU variant's LR state (state: lr)")
        if self.n_stacks < 3 or self.n_stacks % 2 == 0:
            raise ValueError(f"n_stacks must be odd and >= 3, got {self.n_stacks}")
        if min(self.base_channels, self.hr_channels, self.c_blocks, self.blocks) < 1:
            raise ValueError("channel widths and block counts must be >= 1")

    @property
    def central_channels(self) -> int:
        """Channels of the central input: the stack, APS or first pass, then the history."""
        return (self.stack_channels if self.central == "stack" else 1) + len(self.history)


class E2SRI(nn.Module):
    """Events to super-resolved intensity.

    ``forward(stacks, central, flows=None)``:
        stacks: ``(B, n, c, H, W)`` SBN stacks scaled to [-1, 1] (128 -> 0).
        central: ``(B, c_central, H, W)``: the central stack, or an LR intensity in [0, 1].
        flows: ``(B, n, 2, H, W)`` pixel flow from the central input to each stack (the
            central entry is ignored); required when ``config.flow == "given"``.
        memory: with ``config.memory``, the state the previous output returned (None for
            the first output of a sequence).
    Returns ``(B, 1, scale H, scale W)`` intensity (linear, about [0, 1]); with
    ``return_state``, ``(image, state)``, the state to pass as the next output's memory.
    """

    def __init__(self, config: NetConfig) -> None:
        super().__init__()
        self.config = cfg = config
        b, h, s = cfg.base_channels, cfg.hr_channels, cfg.scale
        f2 = cfg.fold ** 2
        self.efr0 = nn.Sequential(conv(cfg.central_channels * f2, b), conv(b, b))
        self.efr = nn.Sequential(conv((cfg.stack_channels + cfg.central_channels + 2) * f2, b),
                                 conv(b, b))
        if cfg.state == "hr":
            self.rnet_c = nn.Sequential(res_stack(b, cfg.c_blocks), deconv(b, h, s))
            self.rnet_a = nn.Sequential(deconv(b, h, s), res_stack(h, cfg.blocks))
            self.rnet_b = nn.Sequential(res_stack(h, cfg.blocks), conv(h, h))
            self.rnet_d = nn.Sequential(res_stack(h, cfg.blocks), conv(h, h))
            self.down = down(h, b, s)
            self.mix = nn.Sequential(conv((cfg.n_stacks - 1) * h, h), conv(h, 1, act=False))
        else:  # everything at LR; one sub-pixel lift at the end
            self.rnet_c = res_stack(b, cfg.c_blocks)
            self.rnet_a = res_stack(b, cfg.blocks)
            self.rnet_b = nn.Sequential(res_stack(b, cfg.blocks), conv(b, b))
            self.rnet_d = nn.Sequential(res_stack(b, cfg.blocks), conv(b, b))
            self.down = nn.Identity()
            lift = s * cfg.fold
            self.mix = nn.Sequential(conv((cfg.n_stacks - 1) * b, b),
                                     nn.Conv2d(b, lift * lift * h, 3, 1, 1),
                                     SubPixelLift(lift, cfg.lift == "smooth", h), nn.PReLU(h),
                                     conv(h, 1, act=False))
            if cfg.context:
                self.context = ContextBranch((cfg.n_stacks - 1) * b, cfg.context,
                                             far=cfg.context_far,
                                             global_path=cfg.context_global,
                                             support=cfg.context_support)
        self.flow_net = FlowNet(cfg.stack_channels) if cfg.flow == "learned" else None
        if cfg.memory:
            self.memory_in = nn.Conv2d(b, b, 3, 1, 1, bias=False)
            nn.init.zeros_(self.memory_in.weight)

    def forward(self, stacks: torch.Tensor, central: torch.Tensor,
                flows: torch.Tensor | None = None, memory: torch.Tensor | None = None,
                return_state: bool = False):
        cfg = self.config
        if (memory is not None or return_state) and not cfg.memory:
            raise ValueError("this network carries no memory across outputs (model.memory)")
        n, mid = cfg.n_stacks, cfg.n_stacks // 2
        if stacks.ndim != 5 or stacks.shape[1:3] != (n, cfg.stack_channels):
            raise ValueError(f"stacks must be (B, {n}, {cfg.stack_channels}, H, W), got "
                             f"{tuple(stacks.shape)}")
        if central.shape != (stacks.shape[0], cfg.central_channels) + stacks.shape[-2:]:
            raise ValueError(f"central must be (B, {cfg.central_channels}, H, W) matching the "
                             f"stacks, got {tuple(central.shape)}")
        flows = self._flows(stacks, flows)
        gate = None
        if cfg.context_gate:  # the history's channels end the central input
            k = cfg.central_channels - len(cfg.history) + cfg.history.index(cfg.context_gate)
            gate = history_gate(central[:, k:k + 1])
        f, (hgt, wid) = cfg.fold, stacks.shape[-2:]
        if f > 1:
            stacks, central, flows = (_fold(t, f) for t in (stacks, central, flows))
        state = self.efr0(central)
        if memory is not None:
            if memory.shape != state.shape:
                raise ValueError(f"memory must be {tuple(state.shape)} (the previous "
                                 f"output's state), got {tuple(memory.shape)}")
            state = state + self.memory_in(memory.to(state.dtype))
        outputs = []
        for j in [k for k in range(n) if k != mid]:
            rectified = self.efr(torch.cat([stacks[:, j], central, flows[:, j]], dim=1))
            c = self.rnet_c(rectified)
            e = c - self.rnet_a(state)
            new_state = self.rnet_b(e) + c
            outputs.append(self.rnet_d(new_state))
            state = self.down(new_state)
        features = torch.cat(outputs, dim=1)
        if cfg.context:
            fired = ((stacks != 0).sum(dim=(1, 2)) > 0).to(features.dtype).unsqueeze(1) \
                if cfg.context_support else None
            features = self.context(features, fired, gate)
        out = self.mix(features)
        if f > 1:
            out = out[..., :hgt * cfg.scale, :wid * cfg.scale]
        return (out, state) if return_state else out

    def _flows(self, stacks: torch.Tensor, flows: torch.Tensor | None) -> torch.Tensor:
        cfg = self.config
        b, n, _, h, w = stacks.shape
        if cfg.flow == "none":
            return stacks.new_zeros(b, n, 2, h, w)
        if cfg.flow == "learned":
            mid = n // 2
            out = [self.flow_net(stacks[:, mid], stacks[:, j]) if j != mid
                   else stacks.new_zeros(b, 2, h, w) for j in range(n)]
            return torch.stack(out, dim=1) / FLOW_SCALE
        if flows is None or flows.shape != (b, n, 2, h, w):
            raise ValueError(f"flows must be (B, {n}, 2, H, W) with flow='given', got "
                             f"{None if flows is None else tuple(flows.shape)}")
        return flows / FLOW_SCALE


def _fold(x: torch.Tensor, f: int) -> torch.Tensor:
    """Space-to-depth by ``f`` over the last two axes, zero-padding them to multiples of f:
    ``(..., C, H, W) -> (..., C f^2, ceil(H/f), ceil(W/f))``."""
    h, w = x.shape[-2:]
    x = F.pad(x, (0, -w % f, 0, -h % f))
    lead = x.shape[:-3]
    y = F.pixel_unshuffle(x.reshape(-1, *x.shape[-3:]), f)
    return y.reshape(*lead, *y.shape[-3:])


#: Pixel flows are divided by this before entering the network (keeps inputs near [-1, 1]).
FLOW_SCALE = 4.0

CENTRAL_OF_MODE = {"main": "stack", "complementary": "aps", "duo-pass": "first_pass"}
"""The paper's three models by name (``reconstruct --mode``) and the central input each
network is built for (:attr:`NetConfig.central`)."""


def mode_of(config: NetConfig) -> str:
    """The ``reconstruct --mode`` a network of ``config`` runs in."""
    return next(m for m, c in CENTRAL_OF_MODE.items() if c == config.central)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def central_input(config: NetConfig, stacks: torch.Tensor, flows: torch.Tensor,
                  aps: torch.Tensor | None,
                  first_pass: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]
                  | None, history: torch.Tensor | None = None) -> torch.Tensor:
    """The network's central input (see :attr:`NetConfig.central`), (B, c, H, W) or
    (B, 1, H, W): the central stack, the APS frame, or a main model's output brought back
    to the sensor size (Duo-Pass), followed by the event history ``(B, k, H, W)`` when the
    model reads one (:attr:`NetConfig.history`). ``stacks`` (B, n, c, H, W), ``flows``
    (B, n, 2, H, W)."""
    base = _central_base(config, stacks, flows, aps, first_pass)
    if not config.history:
        return base
    k = len(config.history)
    if history is None or history.shape != (base.shape[0], k) + base.shape[-2:]:
        raise ValueError(f"a model with an event-history input needs it as (B, {k}, H, W) "
                         f"matching the stacks, got "
                         f"{None if history is None else tuple(history.shape)}")
    return torch.cat([base, history.to(base.dtype)], dim=1)


def _central_base(config: NetConfig, stacks: torch.Tensor, flows: torch.Tensor,
                  aps: torch.Tensor | None, first_pass) -> torch.Tensor:
    mid = config.n_stacks // 2
    if config.central == "stack":
        return stacks[:, mid]
    if config.central == "aps":
        if aps is None:
            raise ValueError("a Complementary model needs an APS frame at every output")
        return aps
    if first_pass is None:
        raise ValueError("a Duo-Pass model needs its first-pass (main) model")
    with torch.no_grad():
        first = first_pass(stacks, stacks[:, mid], flows)
    return F.avg_pool2d(first.clamp(0, 1), config.scale)

