"""Image quality metrics of the paper: PSNR, SSIM, MSE (and LPIPS from :mod:`model.losses.lpips`).

All take ``(B, 1, H, W)`` tensors with values in [0, 1] and return ``(B,)`` tensors.
SSIM is Wang et al.'s with an 11x11 Gaussian window (sigma 1.5), K1 = 0.01, K2 = 0.03,
averaged over the positions where the window fits (scikit-image's ``gaussian_weights=True,
use_sample_covariance=False`` convention; checked against it in the tests).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F


def _check(x: torch.Tensor, y: torch.Tensor) -> None:
    if x.shape != y.shape or x.ndim != 4:
        raise ValueError(f"metrics need two (B, C, H, W) tensors of one shape, got "
                         f"{tuple(x.shape)} and {tuple(y.shape)}")


def mse(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    _check(x, y)
    return ((x.float() - y.float()) ** 2).mean(dim=(1, 2, 3))


def psnr(x: torch.Tensor, y: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB (inf for identical images)."""
    return 10 * torch.log10(data_range**2 / mse(x, y))


def _gaussian_taps(size: int = 11, sigma: float = 1.5, device=None) -> torch.Tensor:
    """float64[size]: the normalised 1-D Gaussian whose outer product is SSIM's window."""
    r = torch.arange(size, dtype=torch.float64, device=device) - (size - 1) / 2
    g = torch.exp(-(r**2) / (2 * sigma**2))
    return g / g.sum()


def ssim_map(x: torch.Tensor, y: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """Structural similarity at every position where the 11x11 window fits:
    ``(B, C, H - 10, W - 10)`` float64, entry ``[i, j]`` for the window centred on pixel
    ``(i + 5, j + 5)``."""
    _check(x, y)
    if min(x.shape[-2:]) < 11:
        raise ValueError(f"SSIM needs images of at least 11x11, got {tuple(x.shape[-2:])}")
    c = x.shape[1]
    x, y = x.double(), y.double()
    # The 11x11 Gaussian window is separable: two 1-D passes over the five local moments
    # at once (22 instead of 121 multiply-adds per pixel and moment).
    g = _gaussian_taps(device=x.device)
    z = torch.cat([x, y, x * x, y * y, x * y], dim=1)
    z = F.conv2d(z, g.view(1, 1, 11, 1).expand(5 * c, 1, 11, 1), groups=5 * c)
    z = F.conv2d(z, g.view(1, 1, 1, 11).expand(5 * c, 1, 1, 11), groups=5 * c)
    mx, my, xx, yy, xy = z.split(c, dim=1)
    vx, vy, cxy = xx - mx**2, yy - my**2, xy - mx * my
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    return ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2))


def ssim(x: torch.Tensor, y: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """Structural similarity, mean over channels and window positions."""
    return ssim_map(x, y, data_range).mean(dim=(1, 2, 3)).float()


def psnr_from_mse(value: float, data_range: float = 1.0) -> float:
    return math.inf if value == 0 else 10 * math.log10(data_range**2 / value)
