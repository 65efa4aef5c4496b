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
from model.archs.blocks import ContextBranch, SubPixelLift, conv, deconv, down, res_stack
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
        lift: with ``state: lr``, how the sub-pixel lift ends. ``shuffle`` (the first shipped
            models): a plain pixel shuffle, whose per-phase weights leave a faint
            period-``scale`` grid in flat regions. ``smooth`` (the shipped models): the
            shuffle followed by a fixed, parameter-free filter that removes any
            period-``scale`` pattern (:class:`model.archs.blocks.SubPixelLift`); the state
            dict is the same, so a ``shuffle`` model warm-starts a ``smooth`` one.
        context: with ``state: lr``, the width of a coarse context branch on the features
            Mix reads (:class:`model.archs.blocks.ContextBranch`: averages over 4x4 and
            16x16 cells, two convolutions each, a zero-initialised residual), which lets an
            output pixel see about +-63 LR pixels instead of about +-18; 0: none (the first
            shipped models; 16 in the shipped ones). A model without it warm-starts one
            with it exactly.
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
    lift: Literal["shuffle", "smooth"] = "shuffle"
    context: int = 0

    def __post_init__(self) -> None:
        check_scales((self.scale,), "model.scale")
        if self.lift not in ("shuffle", "smooth"):
            raise ValueError(f"model.lift must be shuffle or smooth, got {self.lift!r}")
        if self.context < 0 or (self.context and self.state != "lr"):
            raise ValueError("model.context must be >= 0, and > 0 only with state: lr")
        if self.n_stacks < 3 or self.n_stacks % 2 == 0:
            raise ValueError(f"n_stacks must be odd and >= 3, got {self.n_stacks}")
        if min(self.base_channels, self.hr_channels, self.c_blocks, self.blocks) < 1:
            raise ValueError("channel widths and block counts must be >= 1")

    @property
    def central_channels(self) -> int:
        """Channels of the central input: a stack, or one for the APS frame or first pass."""
        return self.stack_channels if self.central == "stack" else 1


class E2SRI(nn.Module):
    """Events to super-resolved intensity.

    ``forward(stacks, central, flows=None)``:
        stacks: ``(B, n, c, H, W)`` SBN stacks scaled to [-1, 1] (128 -> 0).
        central: ``(B, c_central, H, W)``: the central stack, or an LR intensity in [0, 1].
        flows: ``(B, n, 2, H, W)`` pixel flow from the central input to each stack (the
            central entry is ignored); required when ``config.flow == "given"``.
    Returns ``(B, 1, scale H, scale W)`` intensity (linear, about [0, 1]).
    """

    def __init__(self, config: NetConfig) -> None:
        super().__init__()
        self.config = cfg = config
        b, h, s = cfg.base_channels, cfg.hr_channels, cfg.scale
        self.efr0 = nn.Sequential(conv(cfg.central_channels, b), conv(b, b))
        self.efr = nn.Sequential(conv(cfg.stack_channels + cfg.central_channels + 2, b),
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
            self.mix = nn.Sequential(conv((cfg.n_stacks - 1) * b, b),
                                     nn.Conv2d(b, s * s * h, 3, 1, 1),
                                     SubPixelLift(s, cfg.lift == "smooth", h), nn.PReLU(h),
                                     conv(h, 1, act=False))
            if cfg.context:
                self.context = ContextBranch((cfg.n_stacks - 1) * b, cfg.context)
        self.flow_net = FlowNet(cfg.stack_channels) if cfg.flow == "learned" else None

    def forward(self, stacks: torch.Tensor, central: torch.Tensor,
                flows: torch.Tensor | None = None) -> torch.Tensor:
        cfg = self.config
        n, mid = cfg.n_stacks, cfg.n_stacks // 2
        if stacks.ndim != 5 or stacks.shape[1:3] != (n, cfg.stack_channels):
            raise ValueError(f"stacks must be (B, {n}, {cfg.stack_channels}, H, W), got "
                             f"{tuple(stacks.shape)}")
        if central.shape != (stacks.shape[0], cfg.central_channels) + stacks.shape[-2:]:
            raise ValueError(f"central must be (B, {cfg.central_channels}, H, W) matching the "
                             f"stacks, got {tuple(central.shape)}")
        flows = self._flows(stacks, flows)
        state = self.efr0(central)
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
            features = self.context(features)
        return self.mix(features)

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
                  | None) -> torch.Tensor:
    """The network's central input (see :attr:`NetConfig.central`), (B, c, H, W) or
    (B, 1, H, W): the central stack, the APS frame, or a main model's output brought back
    to the sensor size (Duo-Pass). ``stacks`` (B, n, c, H, W), ``flows`` (B, n, 2, H, W)."""
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
