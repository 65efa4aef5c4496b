"""Shipping a model: export, checksum on load, the default of reconstruct and evaluate."""

from __future__ import annotations

import json

import pytest
import torch

from model import checkpoint
from model.inference.pretrained import (
    WEIGHTS,
    export,
    file_name,
    manifest,
    sha256,
    shipped_checkpoint,
)
from tests.model.test_arch import inputs


def test_export_round_trip_and_checksum(tiny_checkpoint, tmp_path):
    target = export(tiny_checkpoint, folder=tmp_path, info={"data": "tiny"})
    assert target.name == "e2sr_x2.pt"
    entry = manifest(tmp_path)["e2sr_x2.pt"]
    assert entry["sha256"] == sha256(target) and entry["data"] == "tiny"
    original = checkpoint.load_model(tiny_checkpoint)
    shipped = checkpoint.load_model(shipped_checkpoint(2, tmp_path))
    assert all(v.dtype == torch.float16 for v in torch.load(
        target, weights_only=False)["model"].values() if v.is_floating_point())
    x = inputs(original.config, b=1, h=16, w=16)
    with torch.no_grad():
        a, b = original(*x), shipped(*x)
    assert torch.allclose(a, b, atol=2e-2)  # float16 weights, float32 compute
    # one flipped byte: refused before anything is unpickled
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0xFF
    target.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="SHA-256 .* differs"):
        shipped_checkpoint(2, tmp_path)
    with pytest.raises(FileNotFoundError, match=r"no shipped x4 model \(shipped: x2\)"):
        shipped_checkpoint(4, tmp_path)


@pytest.mark.parametrize("scale", [2, 4])
def test_the_package_ships_a_model_per_scale_that_loads(scale):
    """The weights committed in the package: present, small, matching their manifest, and
    loadable by today's code (later refactors must keep it so)."""
    entries = manifest()
    assert file_name(scale) in entries, f"no shipped x{scale} model in model/weights/"
    path = shipped_checkpoint(scale)
    assert path.stat().st_size < 20e6
    net = checkpoint.load_model(path)
    assert net.config.scale == scale
    with torch.no_grad():
        out = net(*inputs(net.config, b=1, h=32, w=32))
    assert out.shape == (1, 1, 32 * scale, 32 * scale) and torch.isfinite(out).all()
    assert json.loads((WEIGHTS / "manifest.json").read_text())[file_name(scale)]["step"] > 0


@pytest.fixture(scope="module")
def default_sequence(tmp_path_factory):
    """One sequence of the default 128x128 rig (exact renderer, 12 frames): what the shipped
    model was trained on, seconds to simulate."""
    from datagen.cli import main as datagen

    out = tmp_path_factory.mktemp("default_seq")
    assert datagen(["generate", "--n-seq", "1", "--seed", "5", "--out", str(out),
                    "--no-progress", "--workers", "1",
                    "--set", "simulation.render.backend=homography",
                    "--set", "simulation.frames.count=12",
                    "--set", "textures.procedural_fraction=0"]) == 0
    return out


def test_reconstruct_and_evaluate_default_to_the_shipped_model(default_sequence, tmp_path,
                                                               capsys):
    import cv2
    import numpy as np

    from model.cli import evaluate_main, reconstruct_main

    shard = sorted(default_sequence.glob("shard_*.h5"))[0]
    assert reconstruct_main([str(shard), "--out", str(tmp_path / "rec"), "--no-progress"]) == 0
    frames = sorted((tmp_path / "rec").glob("frame_*.png"))
    assert len(frames) >= 8
    img = cv2.imread(str(frames[len(frames) // 2]), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (256, 256) and img.std() > 5  # a picture, not a flat field
    assert evaluate_main(["--data", str(default_sequence), "--split", "all", "--out",
                          str(tmp_path / "eval"), "--no-temporal", "--every", "3"]) == 0
    rows = {(r[1], r[2]): r for r in (line.split(",") for line in
            (tmp_path / "eval" / "metrics.csv").read_text().splitlines()[1:])
            if r[0] == "average"}
    ours, hf = float(rows[("hr", "ours")][4]), float(rows[("hr", "hf")][4])
    assert np.isfinite(ours) and ours > hf  # PSNR: the shipped model beats the filter


def test_reconstruct_scale_4_picks_the_shipped_x4_model(default_sequence, tmp_path):
    """``--scale 4`` without ``--checkpoint``: the x4 model, 512x512 frames of 128x128
    events (the sequence's own HR camera is x2; reconstruction does not need it)."""
    import cv2

    from model.cli import reconstruct_main

    shard = sorted(default_sequence.glob("shard_*.h5"))[0]
    assert reconstruct_main([str(shard), "--scale", "4", "--out", str(tmp_path / "rec"),
                             "--limit", "3", "--no-progress"]) == 0
    frames = sorted((tmp_path / "rec").glob("frame_*.png"))
    assert len(frames) == 3
    img = cv2.imread(str(frames[-1]), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (512, 512) and img.std() > 5
