"""Convolutional building blocks shared by the networks (RBPN/DBPN style: conv + PReLU)."""

from __future__ import annotations

from torch import nn

#: (kernel, stride, padding) of the back-projection up/down sampling for each scale.
PROJECTION = {2: (6, 2, 2), 4: (8, 4, 2), 8: (12, 8, 2)}  # kernel, stride, padding per scale


def conv(c_in: int, c_out: int, k: int = 3, s: int = 1, p: int = 1, act: bool = True
         ) -> nn.Sequential:
    """Conv2d (+ PReLU). ``(B, c_in, H, W) -> (B, c_out, H', W')``."""
    layers: list[nn.Module] = [nn.Conv2d(c_in, c_out, k, s, p)]
    if act:
        layers.append(nn.PReLU(c_out))
    return nn.Sequential(*layers)


def deconv(c_in: int, c_out: int, scale: int) -> nn.Sequential:
    """Transposed conv upsampling by ``scale`` with the back-projection kernel, + PReLU."""
    k, s, p = PROJECTION[scale]
    return nn.Sequential(nn.ConvTranspose2d(c_in, c_out, k, s, p), nn.PReLU(c_out))


def down(c_in: int, c_out: int, scale: int) -> nn.Sequential:
    """Strided conv downsampling by ``scale`` with the back-projection kernel, + PReLU."""
    k, s, p = PROJECTION[scale]
    return conv(c_in, c_out, k, s, p)


class ResBlock(nn.Module):
    """``x + conv(prelu(conv(x)))``: a residual block at constant width and size."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(channels, channels, 3, 1, 1), nn.PReLU(channels),
                                  nn.Conv2d(channels, channels, 3, 1, 1))

    def forward(self, x):
        return x + self.body(x)


def res_stack(channels: int, n: int) -> nn.Sequential:
    return nn.Sequential(*[ResBlock(channels) for _ in range(n)])
