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
pipeline) or from :class:`model.flow.FlowNet` when ``flow == "learned"``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
import torch.nn.functional as F
from torch import nn

from model.blocks import PROJECTION, conv, deconv, down, res_stack
from model.flow import FlowNet


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

    def __post_init__(self) -> None:
        if self.scale not in PROJECTION:
            raise ValueError(f"scale must be one of {sorted(PROJECTION)}, got {self.scale}")
        if self.n_stacks < 3 or self.n_stacks % 2 == 0:
            raise ValueError(f"n_stacks must be odd and >= 3, got {self.n_stacks}")
        if min(self.base_channels, self.hr_channels, self.c_blocks, self.blocks) < 1:
            raise ValueError("channel widths and block counts must be >= 1")

    @property
    def central_channels(self) -> int:
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
        self.rnet_c = nn.Sequential(res_stack(b, cfg.c_blocks), deconv(b, h, s))
        self.rnet_a = nn.Sequential(deconv(b, h, s), res_stack(h, cfg.blocks))
        self.rnet_b = nn.Sequential(res_stack(h, cfg.blocks), conv(h, h))
        self.rnet_d = nn.Sequential(res_stack(h, cfg.blocks), conv(h, h))
        self.down = down(h, b, s)
        self.mix = nn.Sequential(conv((cfg.n_stacks - 1) * h, h), conv(h, 1, act=False))
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
        return self.mix(torch.cat(outputs, dim=1))

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


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def central_input(config: NetConfig, stacks: torch.Tensor, flows: torch.Tensor,
                  aps: torch.Tensor | None, first_pass: E2SRI | None) -> torch.Tensor:
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

