"""Convolutional building blocks shared by the networks (RBPN/DBPN style: conv + PReLU)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

#: (kernel, stride, padding) of the back-projection up/down sampling for each scale.
PROJECTION = {2: (6, 2, 2), 4: (8, 4, 2), 8: (12, 8, 2)}  # kernel, stride, padding per scale


def conv(c_in: int, c_out: int, k: int = 3, s: int = 1, p: int = 1, act: bool = True,
         d: int = 1) -> nn.Sequential:
    """Conv2d (+ PReLU), dilation ``d``. ``(B, c_in, H, W) -> (B, c_out, H', W')``."""
    layers: list[nn.Module] = [nn.Conv2d(c_in, c_out, k, s, p, dilation=d)]
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


class SubPixelLift(nn.Module):
    """Pixel shuffle by ``scale``, optionally followed by a fixed anti-grid filter.

    A sub-pixel convolution computes each of the ``scale^2`` output phases with its own
    weights, so even a constant input comes out with a period-``scale`` pattern: the grid
    of the checkerboard-artifact literature (Sugawara et al., "Super-resolution using
    convolutional neural networks without any checkerboard artifacts", ICIP 2018). With
    ``smooth``, every channel is then convolved with the separable kernel
    ``box(scale) * box(2)`` (length ``scale + 1``, symmetric, so no shift), whose frequency
    response is zero at every multiple of ``2 pi / scale``: a period-``scale`` pattern
    leaves only its mean, so a constant input gives a constant output whatever the weights.
    The filter has no parameters and adds nothing to the state dict.
    """

    def __init__(self, scale: int, smooth: bool = False, channels: int = 1) -> None:
        super().__init__()
        self.scale, self.smooth = scale, smooth and scale > 1
        self.shuffle = nn.PixelShuffle(scale)
        if self.smooth:  # fixed depthwise kernels of known shape (graph exports need it);
            taps = anti_grid_taps(scale)  # not persistent: the state dict stays as it was
            k = len(taps)
            self.register_buffer("kernel_x", taps.view(1, 1, 1, k).repeat(channels, 1, 1, 1),
                                 persistent=False)
            self.register_buffer("kernel_y", taps.view(1, 1, k, 1).repeat(channels, 1, 1, 1),
                                 persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.shuffle(x)
        if not self.smooth:
            return y
        c = self.kernel_x.shape[0]
        y = F.pad(y, (self.scale // 2,) * 4, mode="replicate")
        y = F.conv2d(y, self.kernel_x.to(y.dtype), groups=c)
        return F.conv2d(y, self.kernel_y.to(y.dtype), groups=c)


def anti_grid_taps(scale: int) -> torch.Tensor:
    """``box(scale) * box(2)``, normalised: ``scale + 1`` taps, e.g. [1, 2, 1] / 4 for 2 and
    [1, 2, 2, 2, 1] / 8 for 4 (even scales). Its DTFT vanishes at ``2 pi k / scale`` for
    k = 1 .. scale - 1."""
    if scale < 2 or scale % 2:
        raise ValueError(f"the anti-grid filter needs an even scale, got {scale}")
    taps = torch.full((scale + 1,), 1.0, dtype=torch.float64)
    taps[0] = taps[-1] = 0.5
    return (taps / taps.sum()).float()


class ContextBranch(nn.Module):
    """Coarse context added to LR features: ``x + out(cat_f up(path_f(avgpool_f(x))))``.

    The CPU variant's convolutions see about +-18 LR pixels around each output pixel
    (measured: the farthest input pixel with a non-zero gradient), so a flat, event-free
    region wider than that is filled with a constant prior rather than the level its
    bounding edges imply. Each path averages the features over ``f x f`` cells
    (:func:`cell_means`), runs two 3x3 convolutions there (each seeing ``3 f`` pixels), and
    is brought back by bilinear interpolation; a 1x1 convolution mixes the paths into a
    residual. With factors (4, 16) an output pixel sees about +-63 LR pixels for little
    compute. That last convolution starts at zero, so a network warm-started from one
    without the branch computes exactly what it did until training moves it.
    (Variants tried and not shipped, a dilated far path, a whole-frame path, a path over
    the fired pixels and a gate from the event history, are in docs/notes/experiments.md.)
    """

    def __init__(self, channels: int, width: int, factors: tuple[int, ...] = (4, 16)) -> None:
        super().__init__()
        self.factors = tuple(factors)
        self.paths = nn.ModuleList(nn.Sequential(conv(channels, width), conv(width, width))
                                   for _ in self.factors)
        self.out = nn.Conv2d(width * len(self.factors), channels, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x``: ``(B, C, H, W)`` features; returns the same shape."""
        h, w = x.shape[-2:]
        parts = [F.interpolate(path(cell_means(x, f)), scale_factor=f, mode="bilinear",
                               align_corners=False)[..., :h, :w]
                 for f, path in zip(self.factors, self.paths)]
        return x + self.out(torch.cat(parts, dim=1))


def cell_means(x: torch.Tensor, f: int) -> torch.Tensor:
    """Means of ``x`` over ``f x f`` cells, ``(..., H, W) -> (..., ceil(H/f), ceil(W/f))``;
    cells cut by the border average the pixels they hold. (Zero padding to a multiple of
    ``f``, divided by the same pooling of ones: graph engines refuse a pooling window
    larger than its input, which ``ceil_mode`` would need on small inputs. The ones are
    ``x * 0 + 1``, not ``ones_like``: OpenVINO's CPU plugin has no bfloat16 pooling of the
    constant that ``ones_like`` exports to, and refuses to compile the graph in bfloat16.)"""
    h, w = x.shape[-2:]
    pad = (0, -w % f, 0, -h % f)
    held = F.avg_pool2d(F.pad(x[:, :1] * 0 + 1, pad), f)
    return F.avg_pool2d(F.pad(x, pad), f) / held
