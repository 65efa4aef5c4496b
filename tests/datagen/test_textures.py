"""Texture sources: built-in, folders and zip/pk3 archives, with unreadable files skipped."""

from __future__ import annotations

import logging
import zipfile

import cv2
import numpy as np
import pytest

from datagen.textures import (
    PROCEDURAL,
    PROCEDURAL_KINDS,
    ImageLibrary,
    TextureConfig,
    TextureSampler,
    procedural,
)


def write_png(path, rng, hw=(60, 90)):
    cv2.imwrite(str(path), (rng.random(hw) * 255).astype(np.uint8))


def test_builtin_library_needs_no_download():
    lib = ImageLibrary("builtin")
    assert len(lib) >= 15
    assert all(lib.read(i) is not None for i in range(len(lib)))


def test_folder_and_archives_with_broken_files(tmp_path, caplog):
    rng = np.random.default_rng(0)
    (tmp_path / "sub").mkdir()
    write_png(tmp_path / "a.png", rng)
    write_png(tmp_path / "sub" / "b.jpg", rng)
    (tmp_path / "broken.png").write_bytes(b"not an image")
    (tmp_path / "notes.txt").write_text("ignored")
    with zipfile.ZipFile(tmp_path / "pack.pk3", "w") as zf:
        ok, buf = cv2.imencode(".png", (rng.random((40, 50)) * 255).astype(np.uint8))
        zf.writestr("textures/c.png", buf.tobytes())
        zf.writestr("textures/d.tga", b"garbage")
    (tmp_path / "bad.zip").write_bytes(b"PK not really")
    lib = ImageLibrary(tmp_path)
    assert len(lib) == 5  # a.png, b.jpg, broken.png, c.png, d.tga
    assert lib.skipped == 1  # bad.zip
    with caplog.at_level(logging.WARNING):
        images = [lib.read(i) for i in range(len(lib))]
    assert sum(img is None for img in images) == 2
    assert lib.skipped == 3
    assert "broken.png: skipped texture" in caplog.text
    sampler = TextureSampler(TextureConfig(source=str(tmp_path), procedural_fraction=0.0))
    tex, name = sampler.sample(np.random.default_rng(1), 1.5, 300)
    assert "broken" not in name and tex.shape == (200, 300)


def test_missing_and_empty_sources_are_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope: texture path does not exist"):
        ImageLibrary(tmp_path / "nope")
    with pytest.raises(FileNotFoundError, match="no readable images"):
        ImageLibrary(tmp_path)


@pytest.mark.parametrize("kind", PROCEDURAL_KINDS)
def test_procedural_textures(kind):
    img = procedural(kind, 128, np.random.default_rng(3))
    assert img.shape == (128, 128) and img.dtype == np.float32
    assert img.min() == 0.0 and img.max() == pytest.approx(1.0) and img.std() > 0.05


def flat_share(img: np.ndarray, radius: int = 8) -> float:
    """Share of pixels whose (2 radius + 1)^2 neighbourhood is constant."""
    k = np.ones((2 * radius + 1,) * 2, np.uint8)
    spread = cv2.dilate(img, k) - cv2.erode(img, k)
    return float((spread < 1e-6).mean())


def test_posters_are_mostly_flat_with_edges_of_both_polarities():
    grounds_above = []
    for seed in range(12):
        img = procedural("poster", 512, np.random.default_rng(seed))
        assert flat_share(img) > 0.5  # large event-free regions, unlike the other kinds
        levels, counts = np.unique(img.round(3), return_counts=True)
        ground = levels[counts.argmax()]
        grounds_above.append(ground > np.median(img[np.abs(img - ground) > 0.05]))
    assert 0 < sum(grounds_above) < len(grounds_above)  # light and dark grounds both occur
    for kind in PROCEDURAL:  # the default kinds are busy
        if kind != "shapes":
            assert flat_share(procedural(kind, 512, np.random.default_rng(0))) < 0.5


def test_procedural_kinds_are_chosen_and_checked():
    sampler = TextureSampler(TextureConfig(procedural_fraction=1.0, procedural_kinds=("poster",)))
    rng = np.random.default_rng(0)
    assert {sampler.sample(rng, 1.0, 256)[1] for _ in range(4)} == {"procedural:poster"}
    with pytest.raises(ValueError, match="unknown: dots"):
        TextureConfig(procedural_kinds=("poster", "dots"))
    with pytest.raises(ValueError, match="procedural_kinds must name"):
        TextureConfig(procedural_kinds=())
    # the default draws exactly as before the option existed: same kinds, same order
    assert TextureConfig().procedural_kinds == ("noise", "shapes", "grating", "checker")


def test_sampled_textures_have_the_requested_shape_and_range():
    cfg = TextureConfig(low_range=(0.05, 0.1), high_range=(0.7, 0.9), max_texels=500)
    sampler = TextureSampler(cfg)
    rng = np.random.default_rng(0)
    for _ in range(8):
        tex, _ = sampler.sample(rng, 0.75, 800)  # capped at 500 on the longest side
        assert tex.shape == (500, 375) and tex.dtype == np.float32
        assert 0.05 <= tex.min() and tex.max() <= 0.9
        assert tex.max() - tex.min() > 0.5


def test_flat_photos_are_redrawn_and_an_all_flat_source_is_an_error(tmp_path):
    rng = np.random.default_rng(0)
    write_png(tmp_path / "detailed.png", rng, (200, 200))
    yy, xx = np.mgrid[0:200, 0:200]
    cv2.imwrite(str(tmp_path / "flat.png"), (xx / 200 * 255).astype(np.uint8))  # a ramp
    sampler = TextureSampler(TextureConfig(source=str(tmp_path), procedural_fraction=0.0))
    names = {sampler.sample(np.random.default_rng(i), 1.0, 64)[1] for i in range(12)}
    assert all("detailed" in n for n in names)
    assert sampler.flat > 0
    (tmp_path / "detailed.png").unlink()
    with pytest.raises(ValueError, match="flatter than min_detail"):
        TextureSampler(TextureConfig(source=str(tmp_path), procedural_fraction=0.0)).sample(
            np.random.default_rng(0), 1.0, 64)


def test_train_and_test_parts_are_disjoint_and_fixed_by_name(tmp_path):
    rng = np.random.default_rng(0)
    for i in range(40):
        write_png(tmp_path / f"img_{i:02d}.png", rng)
    train = set(ImageLibrary(tmp_path, split="train", test_fraction=0.25).keys())
    test = set(ImageLibrary(tmp_path, split="test", test_fraction=0.25).keys())
    assert train.isdisjoint(test) and len(train | test) == 40
    assert 3 <= len(test) <= 20  # about a quarter
    # adding images to the source never moves an existing image to the other part
    for i in range(40, 60):
        write_png(tmp_path / f"img_{i:02d}.png", rng)
    grown = set(ImageLibrary(tmp_path, split="test", test_fraction=0.25).keys())
    assert test <= grown and not (grown & train)
    # a sampler over the test part only ever draws test images
    sampler = TextureSampler(TextureConfig(source=str(tmp_path), split="test",
                                           test_fraction=0.25, procedural_fraction=0.0,
                                           min_detail=0.0))
    names = {sampler.sample(np.random.default_rng(s), 1.0, 64)[1] for s in range(30)}
    assert {n.rsplit("/", 1)[-1] for n in names} <= grown


def test_material_maps_are_excluded_and_sources_are_drawn_by_weight(tmp_path):
    rng = np.random.default_rng(1)
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    with zipfile.ZipFile(a / "pack.pk3", "w") as zf:
        for name in ("wall.png", "wall_nm.png", "wall_sm.png", "wall_gm.png", "floor.jpg"):
            ok, buf = cv2.imencode(name[-4:], (rng.random((40, 50)) * 255).astype(np.uint8))
            zf.writestr(f"textures/{name}", buf.tobytes())
    assert sorted(ImageLibrary(a).keys()) == ["textures/floor.jpg", "textures/wall.png"]
    assert len(ImageLibrary(a, exclude=())) == 5
    write_png(b / "photo.png", rng)
    cfg = TextureConfig(source=(str(a), str(b)), source_weights=(0.0, 1.0),
                        procedural_fraction=0.0, min_detail=0.0)
    names = {TextureSampler(cfg).sample(np.random.default_rng(s), 1.0, 64)[1]
             for s in range(20)}
    assert names == {str(b / "photo.png")}
    with pytest.raises(ValueError, match="source_weights must be 2"):
        TextureConfig(source=(str(a), str(b)), source_weights=(1.0,))



def test_held_out_photographs_stay_out_of_every_training_recipe():
    from pathlib import Path

    import yaml

    from datagen.config import DatagenConfig
    from esim_lite.core.dataconf import load_config

    configs = Path(__file__).resolve().parents[2] / "configs"
    held = load_config(DatagenConfig, [configs / "datagen_test.yaml",
                                       configs / "textures_heldout.yaml"]).textures
    assert all(str(s).startswith("data/heldout/") for s in held.source)
    assert held.procedural_fraction == 0 and held.split == "all"
    # no other config's values (comments aside) name the held-out folder or a reserved package
    for path in configs.rglob("*.yaml"):
        if path.name == "textures_heldout.yaml":
            continue
        values = str(yaml.safe_load(path.read_text()))
        for reserved in ("heldout", "opencv", "mate-backgrounds", "plasma-workspace",
                         "/usr/share/backgrounds", "/usr/share/wallpapers"):
            assert reserved not in values, f"{path.name} names {reserved}"
