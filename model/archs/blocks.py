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

    The shipped x2 network's convolutions see about +-18 LR pixels around each output
    pixel (measured: the farthest input pixel with a non-zero gradient), so a flat,
    event-free region wider than that is filled with a constant prior rather than the level
    its bounding edges imply (the halos of docs/notes/halos.md). Each path averages the
    features over ``f x f`` cells (:func:`cell_means`), runs two 3x3 convolutions there
    (each seeing ``3 f`` pixels), and is brought back by bilinear interpolation; a 1x1
    convolution mixes the paths into a residual. With factors (4, 16) an output pixel sees
    about +-63 LR pixels (measured on the x2 CPU variant) for little compute.
    That last convolution starts at zero, so a network warm-started from one without the
    branch computes exactly what it did until training moves it.

    ``far="dilated"`` reaches as far with a finer grain: the far path runs on the 4x4
    cells (not 16x16) through a 3x3 convolution and three more dilated by 2, 4 and 8 (+-15
    cells, +-60 LR pixels), so what it adds can change every 4 LR pixels instead of being a
    bilinear blend of 16-pixel cells, which spreads anything it carries over +-16 pixels
    (the cloud around moving objects on a static background that
    ``bench/context_ablation.py`` traced to the 16x16 path). The near path is the 4x4 one.
    Trained (run L, docs/models.md), it learned the same cloud: the grain was not the cause.

    ``far="none"`` keeps the near (4x4) path alone: what ``bench/context_ablation.py``
    calls ``no-far``, as a network of its own, for a network that carries its state across
    outputs (``model.memory``) and may fill what its edges swept from that instead.

    ``global_path`` adds a path that sees the whole frame: the mean over all pixels of a 1x1
    projection of the features (after a ReLU), concatenated to every pixel's features, a
    1x1 convolution and a ReLU, then its own zero-initialised 1x1 residual (``g_out``), so a
    branch without it warm-starts one with it exactly. The cells reach +-63 LR pixels; a
    never-fired background wider than that was filled with the level its nearest edges imply
    near them and a prior beyond (the cloud of run M, docs/models.md): with the frame mean
    every pixel can take the level the frame's edges imply.

    ``support`` adds a path that averages only where events fired (normalised convolution,
    Knutsson and Westin 1993, filled coarse to fine as push-pull does): a 1x1 projection of
    the features (after a ReLU) is averaged over the fired pixels of each ``f x f`` cell
    (``f`` the branch's largest factor) and of the whole frame (:func:`support_means`);
    a cell where few pixels fired takes the frame's fired mean in proportion
    (:func:`push_pull`). That map, brought back bilinearly, and the fired shares of the cell
    and of the frame are concatenated to every pixel's features, mixed by a 1x1 convolution
    and a ReLU, and added through their own zero-initialised 1x1 residual (``s_out``).
    Every other path averages all pixels, fired or not, so over a static background that
    never fired the cells far from a moving object hold nothing, and the network fills
    them with a constant prior while the cells beside the object carry its level (the cloud
    of runs K to N, docs/models.md); this path gives the far cells what the fired pixels
    say, however few and wherever they are. ``forward`` then needs the support map.
    """

    def __init__(self, channels: int, width: int, factors: tuple[int, ...] = (4, 16),
                 far: str = "cells", global_path: bool = False, support: bool = False) -> None:
        super().__init__()
        if far not in ("cells", "dilated", "none"):
            raise ValueError(f"far must be cells, dilated or none, got {far!r}")
        self.far_kind = far
        if far == "none":  # the near path alone (a memory across outputs may carry the rest)
            factors = tuple(factors[:1])
        if far == "dilated":
            factors = (FAR_CELL,)
            self.far = nn.Sequential(conv(channels, width),
                                     *(conv(width, width, p=d, d=d) for d in FAR_DILATIONS))
        self.factors = tuple(factors)
        self.paths = nn.ModuleList(nn.Sequential(conv(channels, width), conv(width, width))
                                   for _ in self.factors)
        n_paths = len(self.factors) + (far == "dilated")
        self.out = nn.Conv2d(width * n_paths, channels, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        self.global_path = global_path
        if global_path:
            self.g_in = nn.Conv2d(channels, width, 1)
            self.g_mix = nn.Conv2d(channels + width, width, 1)
            self.g_out = nn.Conv2d(width, channels, 1)
            nn.init.zeros_(self.g_out.weight)
            nn.init.zeros_(self.g_out.bias)
        self.support = support
        if support:
            self.s_in = nn.Conv2d(channels, width, 1)
            self.s_mix = nn.Conv2d(channels + width + 2, width, 1)
            self.s_out = nn.Conv2d(width, channels, 1)
            nn.init.zeros_(self.s_out.weight)
            nn.init.zeros_(self.s_out.bias)

    def forward(self, x: torch.Tensor, support: torch.Tensor | None = None,
                gate: torch.Tensor | None = None) -> torch.Tensor:
        """``x``: ``(B, C, H, W)`` features; ``support``: ``(B, 1, H, W)``, 1 where an event
        fired in any stack, 0 elsewhere (needed, and read, only by the support path);
        ``gate``: ``(B, 1, H, W)`` in [0, 1], the weight of the far path's share of the
        residual at each pixel (:func:`history_gate`; None: 1 everywhere)."""
        h, w = x.shape[-2:]
        parts = [F.interpolate(path(cell_means(x, f)), scale_factor=f, mode="bilinear",
                               align_corners=False)[..., :h, :w]
                 for f, path in zip(self.factors, self.paths)]
        if self.far_kind == "dilated":
            parts.append(F.interpolate(self.far(cell_means(x, FAR_CELL)), scale_factor=FAR_CELL,
                                       mode="bilinear", align_corners=False)[..., :h, :w])
        if gate is None:
            y = x + self.out(torch.cat(parts, dim=1))
        else:  # the far path's columns of the residual come last (as context_ablation reads)
            width = parts[-1].shape[1]
            wt = self.out.weight
            near = F.conv2d(torch.cat(parts[:-1], dim=1), wt[:, :-width], self.out.bias)
            y = x + near + gate * F.conv2d(parts[-1], wt[:, -width:])
        if self.global_path:
            g = F.relu(self.g_in(x)).mean(dim=(-2, -1), keepdim=True)
            z = F.relu(self.g_mix(torch.cat([x, g.expand(-1, -1, h, w)], dim=1)))
            y = y + self.g_out(z)
        if self.support:
            if support is None or support.shape != (x.shape[0], 1, h, w):
                raise ValueError(f"the support path needs a (B, 1, {h}, {w}) support map, got "
                                 f"{None if support is None else tuple(support.shape)}")
            f = max(self.factors)
            p = F.relu(self.s_in(x))
            cells, share, frame, frame_share = support_means(p, support, f)
            filled = F.interpolate(push_pull(cells, share, frame), scale_factor=f,
                                   mode="bilinear", align_corners=False)[..., :h, :w]
            share = F.interpolate(share, scale_factor=f, mode="bilinear",
                                  align_corners=False)[..., :h, :w]
            z = F.relu(self.s_mix(torch.cat([x, filled, share,
                                             frame_share.expand(-1, -1, h, w)], dim=1)))
            y = y + self.s_out(z)
        return y


GATE_CELL = 4
"""The grain of :func:`history_gate`: the near path's cells, so an isolated pixel that fired
(a noise event) opens the far path over its cell at 1/16 of its weight, not fully."""


def history_gate(recent: torch.Tensor) -> torch.Tensor:
    """The far path's weight per pixel from the event history: ``recent`` is one history
    channel, ``(B, 1, H, W)``, ``exp(-age / tau)`` (1 for a pixel that fired last, 0 for one
    that never fired; :mod:`model.data.history`), averaged over :data:`GATE_CELL` cells and
    brought back bilinearly. A region swept by events within about ``tau`` stacks (the
    inside of an object whose edges crossed it) keeps the far path's fill; a background
    that has not fired for many times ``tau`` (a static camera's street) gets none of it."""
    h, w = recent.shape[-2:]
    return F.interpolate(cell_means(recent, GATE_CELL), scale_factor=GATE_CELL,
                         mode="bilinear", align_corners=False)[..., :h, :w].clamp(0, 1)


PUSH_PULL_FULL = 1 / 16
"""The share of fired pixels at which a cell's own fired mean is trusted fully in
:func:`push_pull` (16 of a 16x16 cell's 256 pixels); below it the frame's fills in."""


def support_means(p: torch.Tensor, support: torch.Tensor, f: int
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Means of ``p`` over the fired pixels (``support`` 1) of each ``f x f`` cell and of the
    whole frame, with the fired shares: ``(cell means, cell shares, frame mean, frame
    share)``, the cells ``(B, C, ceil(H/f), ceil(W/f))``, the frame ``(B, C, 1, 1)``. A
    cell or frame where nothing fired has mean 0. Pixels that did not fire do not count,
    whatever ``p`` holds there."""
    share = cell_means(support, f)
    cells = cell_means(p * support, f) / share.clamp_min(SUPPORT_EPS)
    frame_share = support.mean(dim=(-2, -1), keepdim=True)
    frame = (p * support).mean(dim=(-2, -1), keepdim=True) / frame_share.clamp_min(SUPPORT_EPS)
    return cells, share, frame, frame_share


SUPPORT_EPS = 1e-6
"""Floor of a fired share before dividing (where nothing fired the sum is 0 too)."""


def push_pull(cells: torch.Tensor, share: torch.Tensor, frame: torch.Tensor
              ) -> torch.Tensor:
    """Each cell's fired mean where enough fired, the frame's where none did, and in
    proportion between: weight ``min(1, share / PUSH_PULL_FULL)`` on the cell's own."""
    trust = (share / PUSH_PULL_FULL).clamp(max=1.0)
    return trust * cells + (1.0 - trust) * frame


FAR_CELL = 4
"""Cell size of the dilated far path (and of the near path beside it)."""
FAR_DILATIONS = (2, 4, 8)
"""Dilations of the far path's convolutions after its first (undilated) one."""


def cell_means(x: torch.Tensor, f: int) -> torch.Tensor:
    """Means of ``x`` over ``f x f`` cells, ``(..., H, W) -> (..., ceil(H/f), ceil(W/f))``;
    cells cut by the border average the pixels they hold. (Zero padding to a multiple of
    ``f``, divided by the same pooling of ones: graph engines refuse a pooling window
    larger than its input, which ``ceil_mode`` would need on small inputs.)"""
    h, w = x.shape[-2:]
    pad = (0, -w % f, 0, -h % f)
    held = F.avg_pool2d(F.pad(torch.ones_like(x[:, :1]), pad), f)
    return F.avg_pool2d(F.pad(x, pad), f) / held
