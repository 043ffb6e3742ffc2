"""Loading real photos: EXIF orientation, bit depths, channels, sRGB, crops and the errors."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image, ImageOps

from mi_svbrdf.io import photos as photo
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import srgb_decode


def _rgb8(h: int, w: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(h, w, 3), dtype=np.uint8)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_orient_matches_pillow_exif_transpose_and_png_path(tmp_path: Path, orientation: int) -> None:
    stored = _rgb8(70, 90)
    exif = Image.Exif()
    exif[photo.ORIENTATION_TAG] = orientation
    path = tmp_path / "o.png"
    Image.fromarray(stored).save(path, exif=exif.tobytes())
    with Image.open(path) as img:
        expected = np.asarray(ImageOps.exif_transpose(img))
    assert np.array_equal(photo.orient(stored, orientation), expected)
    loaded = photo.load_photo(path, linear=True)
    assert loaded.original_size == expected.shape[:2]
    np.testing.assert_allclose(loaded.image, photo.square_crop(expected) / 255.0, atol=1e-6)
    assert ("EXIF orientation" in " ".join(loaded.conversions)) == (orientation != 1)


def test_pillow_exif_rotation_is_applied(tmp_path: Path) -> None:
    upright = _rgb8(64, 96)  # H x W
    exif = Image.Exif()
    exif[photo.ORIENTATION_TAG] = 6  # stored rotated 90 degrees counter-clockwise
    Image.fromarray(np.rot90(upright, 1).copy()).save(tmp_path / "r.webp", lossless=True, exact=True,
                                                      exif=exif.tobytes())
    loaded = photo.load_photo(tmp_path / "r.webp", linear=True)
    assert loaded.original_size == (64, 96)
    np.testing.assert_allclose(loaded.image, photo.square_crop(upright) / 255.0, atol=1e-6)


def test_16bit_png_full_precision_and_srgb_decoding(tmp_path: Path) -> None:
    values = (np.arange(64 * 64 * 3, dtype=np.float64).reshape(64, 64, 3) * 7 % 65536 / 65535).astype(np.float32)
    write_image(tmp_path / "d.png", values, 16)
    lin = photo.load_photo(tmp_path / "d.png", linear=True)
    np.testing.assert_allclose(lin.image, values, atol=1e-7)
    assert len(np.unique(np.round(lin.image * 65535))) > 256  # not truncated to 8 bits
    srgb = photo.load_photo(tmp_path / "d.png")
    np.testing.assert_allclose(srgb.image, srgb_decode(values), atol=1e-6)
    assert abs(float(srgb_decode(np.float32([0.5]))[0]) - 0.21404) < 1e-4


def test_grey_replicated_alpha_dropped(tmp_path: Path) -> None:
    grey = _rgb8(64, 64)[:, :, 0]
    Image.fromarray(grey, "L").save(tmp_path / "g.jpg", quality=100)
    g = photo.load_photo(tmp_path / "g.jpg", linear=True)
    assert g.image.shape == (64, 64, 3)
    assert np.array_equal(g.image[:, :, 0], g.image[:, :, 2])
    assert "grey replicated to RGB" in g.conversions
    rgba = np.concatenate([_rgb8(64, 64), np.zeros((64, 64, 1), np.uint8)], axis=2)  # fully transparent
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.webp", lossless=True, exact=True)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    for name in ("a.webp", "a.png"):
        a = photo.load_photo(tmp_path / name, linear=True)
        np.testing.assert_allclose(a.image, rgba[:, :, :3] / 255.0, atol=1e-6)
        assert "alpha dropped" in a.conversions


def test_crop_then_centre_square(tmp_path: Path) -> None:
    img = _rgb8(100, 160)
    Image.fromarray(img).save(tmp_path / "p.png")
    sq = photo.load_photo(tmp_path / "p.png", linear=True)
    np.testing.assert_allclose(sq.image, img[:, 30:130] / 255.0, atol=1e-6)
    cr = photo.load_photo(tmp_path / "p.png", linear=True, crop=(10, 5, 80, 90))
    np.testing.assert_allclose(cr.image, img[5 + 5:5 + 85, 10:90] / 255.0, atol=1e-6)
    with pytest.raises(ValueError, match=r"p\.png.*inside"):
        photo.load_photo(tmp_path / "p.png", crop=(100, 0, 80, 80))
    with pytest.raises(ValueError, match="--crop"):
        photo.parse_crop("1,2,3")


def test_errors_name_the_file(tmp_path: Path) -> None:
    (tmp_path / "notes.jpg").write_text("not an image")
    with pytest.raises(ValueError, match=r"notes\.jpg: expected an image"):
        photo.load_photo(tmp_path / "notes.jpg")
    (tmp_path / "bad.png").write_bytes(b"\x89PNG garbage")
    with pytest.raises(ValueError, match=r"bad\.png"):
        photo.load_photo(tmp_path / "bad.png")
    Image.fromarray(_rgb8(48, 200)).save(tmp_path / "tiny.jpg")
    with pytest.raises(ValueError, match=r"tiny\.jpg.*at least 64 px, got 48"):
        photo.load_photo(tmp_path / "tiny.jpg")
    with pytest.raises(FileNotFoundError, match=r"missing\.jpg"):
        photo.load_photo(tmp_path / "missing.jpg")


def test_consistency_and_resize(tmp_path: Path) -> None:
    Image.fromarray(_rgb8(64, 96)).save(tmp_path / "a.png")
    Image.fromarray(_rgb8(128, 192)).save(tmp_path / "b.png")  # same aspect, twice the size
    Image.fromarray(_rgb8(96, 96)).save(tmp_path / "c.png")
    a, b, c = (photo.load_photo(tmp_path / f"{n}.png") for n in "abc")
    photo.check_consistent([a, b], crop=False, full_resolution=False)
    with pytest.raises(ValueError, match=r"a\.png 96x64 and .*c\.png 96x96"):
        photo.check_consistent([a, c], crop=False, full_resolution=False)
    with pytest.raises(ValueError, match=r"a\.png 64 px and .*b\.png 128 px"):
        photo.check_consistent([a, b], crop=False, full_resolution=True)
    stacked = photo.prepare([a, b], 64)
    assert stacked.shape == (1, 2, 3, 64, 64)
    const = torch.full((1, 3, 200, 200), 0.3)
    assert torch.allclose(photo.resize(const, 64), torch.full((1, 3, 64, 64), 0.3), atol=1e-6)
