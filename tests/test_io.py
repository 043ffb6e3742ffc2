"""Material IO: image files, material folders, the thesis strip format, and bad inputs.

Quantisation bounds asserted (maximum absolute error per value, + 1e-6 for float32 arithmetic):

- linear PNG: half a code, 0.5 / 255 (8-bit) and 0.5 / 65535 (16-bit);
- sRGB PNG: half a code times the steepest slope of sRGB decoding, 2.4 / 1.055 (at 1), i.e.
  about 4.46e-3 (8-bit) and 1.74e-5 (16-bit);
- half EXR: 2^-12 (half the spacing of halves in [0.5, 1]); float EXR: exact;
- normals, stored as (n + 1) / 2: each component of n is off by at most twice the stored error
  e, so the angle to the true normal is at most asin(sqrt(3) * 2 e).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.io import image_io
from mi_svbrdf.io.image_io import read_image, select_channels, write_image
from mi_svbrdf.io.material_io import read_material, srgb_encode, write_material
from mi_svbrdf.io.strip import read_strip, write_strip

SRGB_MAX_SLOPE = 2.4 / 1.055
HALF_ERROR = 2.0 ** -12


def stored_error(fmt: str, bits: int) -> float:
    """Largest error of one stored value in [0, 1]."""
    if fmt == "png":
        return 0.5 / (2 ** bits - 1)
    return HALF_ERROR if bits == 16 else 0.0


def value_bound(fmt: str, bits: int, encoding: str) -> float:
    return stored_error(fmt, bits) * (SRGB_MAX_SLOPE if encoding == "srgb" else 1.0) + 1e-6


def normal_angle_bound(fmt: str, bits: int) -> float:
    return math.asin(math.sqrt(3.0) * 2.0 * stored_error(fmt, bits)) + 1e-5


def random_maps(size: int = 16, seed: int = 0) -> torch.Tensor:
    """``(1, 10, S, S)`` maps with random unit normals (z > 0.2) and values that include 0 and 1."""
    g = torch.Generator().manual_seed(seed)
    n = torch.rand(1, 3, size, size, generator=g) * 2.0 - 1.0
    n[:, 2] = n[:, 2].abs() + 0.2
    rest = torch.rand(1, 7, size, size, generator=g)
    rest[..., 0, 0], rest[..., 0, 1] = 0.0, 1.0
    return M.normalize_normals(torch.cat([n, rest], dim=1))


def max_angle(a: torch.Tensor, b: torch.Tensor) -> float:
    """Largest angle (radians) between normals ``(B, 3, H, W)``, computed in float64."""
    a, b = a.double(), b.double()
    cross = torch.linalg.cross(a, b, dim=1).norm(dim=1)
    return float(torch.atan2(cross, (a * b).sum(dim=1)).max())


def assert_maps_close(got: torch.Tensor, want: torch.Tensor, fmt: str, bits: int, encoding: str) -> None:
    assert got.shape == want.shape and got.dtype == torch.float32
    assert max_angle(M.normal(got), M.normal(want)) <= normal_angle_bound(fmt, bits)
    torch.testing.assert_close(M.normal(got).norm(dim=1), torch.ones_like(got[:, 0]), atol=1e-5, rtol=0)
    for name in ("diffuse", "specular"):
        err = (M.split(got)[name] - M.split(want)[name]).abs().max()
        assert err <= value_bound(fmt, bits, encoding), (name, float(err))
    assert (M.roughness(got) - M.roughness(want)).abs().max() <= value_bound(fmt, bits, "linear")


def write_raw_exr(path: Path, channels: dict[str, np.ndarray]) -> None:
    """Write an EXR directly (write_image refuses NaN, as it should)."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    data = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}
    with OpenEXR.File(header, data) as f:
        f.write(str(path))


# ----------------------------------------------------------------------------- image files
@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("channels", [1, 2, 3, 4])
def test_png_round_trips_code_values(tmp_path: Path, bits: int, channels: int) -> None:
    top = 2 ** bits - 1
    codes = np.random.default_rng(channels).integers(0, top + 1, size=(5, 7, channels))
    codes[0, 0], codes[0, 1] = 0, top
    path = tmp_path / "x.png"
    write_image(path, (codes / top).astype(np.float32), bit_depth=bits)
    image, info = read_image(path)
    assert image.dtype == np.float32 and image.shape == (5, 7, channels)
    np.testing.assert_array_equal(np.rint(image * top), codes)  # raw codes: no sRGB linearisation
    assert (info.format, info.bit_depth, len(info.channel_names)) == ("png", bits, channels)
    assert [p.name for p in tmp_path.iterdir()] == ["x.png"]  # no temporary file left behind


def test_png_write_clips_rounds_and_tags_srgb_only_on_request(tmp_path: Path) -> None:
    write_image(tmp_path / "a.png", np.array([[-0.5, 0.5, 1.5]], np.float32))
    image, _ = read_image(tmp_path / "a.png")
    np.testing.assert_array_equal(image[0, :, 0] * 255, [0, 128, 255])
    write_image(tmp_path / "b.png", np.zeros((2, 2, 3), np.float32), srgb=True)
    assert b"sRGB" not in (tmp_path / "a.png").read_bytes()
    assert b"sRGB" in (tmp_path / "b.png").read_bytes()


@pytest.mark.parametrize("bits", [16, 32])
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_exr_round_trips_raw_floats(tmp_path: Path, bits: int, channels: int) -> None:
    values = np.random.default_rng(0).random((6, 4, channels)).astype(np.float32)
    values[0, 0, 0], values[0, 1, 0] = 5.5, -2.0  # EXR keeps values outside [0, 1]
    write_image(tmp_path / "x.exr", values, bit_depth=bits)
    image, info = read_image(tmp_path / "x.exr")
    assert image.dtype == np.float32 and image.shape == values.shape and info.bit_depth == bits
    np.testing.assert_allclose(image, values, atol=HALF_ERROR if bits == 16 else 0.0, rtol=0)


def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "x.png"
    write_image(path, np.full((4, 4, 3), 0.2, np.float32))
    before = path.read_bytes()

    def crash(tmp: Path, *args: object) -> None:
        assert tmp.parent == tmp_path and tmp.name.startswith(".x.tmp") and tmp.suffix == ".png"
        tmp.write_bytes(b"\x89PNG half a file")
        raise OSError("disk full")

    monkeypatch.setattr(image_io, "_write_png", crash)
    with pytest.raises(OSError, match="disk full"):
        write_image(path, np.full((4, 4, 3), 0.9, np.float32))
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["x.png"]


@pytest.mark.parametrize("name, image, bits, match", [
    ("x.png", np.full((2, 2, 3), np.nan, np.float32), None, "expected finite"),
    ("x.png", np.zeros((2, 2, 3), np.uint8), None, "expected a floating-point image, got uint8"),
    ("x.png", np.zeros((2, 2, 5), np.float32), None, r"expected an image of shape .*, got \(2, 2, 5\)"),
    ("x.jpg", np.zeros((2, 2, 3), np.float32), None, "expected a .png or .exr"),
    ("x.png", np.zeros((2, 2, 3), np.float32), 32, r"expected bit_depth in \[8, 16\]"),
    ("x.exr", np.full((2, 2), 1e6, np.float32), 16, "expected values within the half-float range"),
])
def test_write_image_rejects(tmp_path: Path, name: str, image: np.ndarray, bits: int | None,
                             match: str) -> None:
    with pytest.raises(ValueError, match=match) as err:
        write_image(tmp_path / name, image, bits)
    assert name in str(err.value) and list(tmp_path.iterdir()) == []


def test_read_image_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"none\.png: expected an image file"):
        read_image(tmp_path / "none.png")
    (tmp_path / "junk.png").write_bytes(b"not a png at all" * 8)
    (tmp_path / "junk.exr").write_bytes(b"not an exr at all" * 8)
    write_image(tmp_path / "good.png", np.zeros((32, 32, 3), np.float32))
    (tmp_path / "cut.png").write_bytes((tmp_path / "good.png").read_bytes()[:60])
    for name, kind in [("junk.png", "PNG"), ("cut.png", "PNG"), ("junk.exr", "OpenEXR")]:
        with pytest.raises(ValueError, match=rf"{name}: expected a readable {kind} file, got an unreadable"):
            read_image(tmp_path / name)
    write_raw_exr(tmp_path / "rg.exr", {"R": np.zeros((2, 2)), "G": np.zeros((2, 2))})
    with pytest.raises(ValueError, match=r"rg\.exr: expected EXR channels Y, YA, RGB or RGBA, got \['G', 'R'\]"):
        read_image(tmp_path / "rg.exr")
    write_raw_exr(tmp_path / "inf.exr", {"Y": np.array([[np.inf, 0.0]])})
    with pytest.raises(ValueError, match=r"inf\.exr: expected finite values, got 0 NaN and 1 Inf"):
        read_image(tmp_path / "inf.exr")


def test_select_channels() -> None:
    rgba = np.concatenate([np.random.default_rng(0).random((2, 2, 3)), np.ones((2, 2, 1))], axis=2)
    np.testing.assert_array_equal(select_channels(rgba, 3, "a.png"), rgba[..., :3])
    np.testing.assert_allclose(select_channels(rgba, 1, "a.png", rgb_to_grey=True),
                               rgba[..., :3].mean(2, keepdims=True))
    with pytest.raises(ValueError, match=r"a\.png: expected a grey image \(1 channel\), got 3 channels"):
        select_channels(rgba, 1, "a.png")
    with pytest.raises(ValueError, match=r"a\.png: expected no alpha channel or an opaque one, "
                                         r"got alpha values down to 0.5"):
        select_channels(np.full((2, 2, 2), 0.5), 1, "a.png")


# ----------------------------------------------------------------------------- material folders
@pytest.mark.parametrize("fmt, bits, encoding", [
    ("png", 8, "srgb"), ("png", 16, "srgb"), ("png", 8, "linear"), ("png", 16, "linear"),
    ("exr", 32, "linear"), ("exr", 16, "linear")])
def test_material_round_trip(tmp_path: Path, fmt: str, bits: int, encoding: str) -> None:
    maps = random_maps()
    meta = write_material(tmp_path, maps, fmt=fmt, bit_depth=bits, albedo_encoding=encoding)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["material.json"] + [f"{n}.{fmt}" for n in M.MAP_NAMES])  # and no temporary files
    assert json.loads((tmp_path / "material.json").read_text()) == meta
    assert meta["format_version"] == 1
    assert {k: (v["file"], v["encoding"], v["bit_depth"]) for k, v in meta["maps"].items()} == {
        "normal": (f"normal.{fmt}", "normal_01", bits), "diffuse": (f"diffuse.{fmt}", encoding, bits),
        "roughness": (f"roughness.{fmt}", "linear", bits), "specular": (f"specular.{fmt}", encoding, bits)}
    assert_maps_close(read_material(tmp_path), maps, fmt, bits, encoding)
    write_material(tmp_path / "unbatched", maps[0], fmt=fmt, bit_depth=bits, albedo_encoding=encoding)
    torch.testing.assert_close(read_material(tmp_path / "unbatched"), read_material(tmp_path), atol=0, rtol=0)
    if fmt == "png" and bits == 8 and encoding == "srgb":  # 8-bit sRGB really is coarser than linear
        err = (M.diffuse(read_material(tmp_path)) - M.diffuse(maps)).abs().max()
        assert err > value_bound("png", 8, "linear")


@pytest.mark.parametrize("encoding", ["srgb", "linear"])
def test_files_hold_the_recorded_encodings(tmp_path: Path, encoding: str) -> None:
    maps = random_maps()
    write_material(tmp_path, maps, albedo_encoding=encoding)
    hwc = maps[0].permute(1, 2, 0).numpy()
    diffuse, _ = read_image(tmp_path / "diffuse.png")
    want = srgb_encode(hwc[..., 3:6]) if encoding == "srgb" else hwc[..., 3:6]
    np.testing.assert_allclose(diffuse, want, atol=0.5 / 255 + 1e-6, rtol=0)
    normal, _ = read_image(tmp_path / "normal.png")
    np.testing.assert_allclose(normal, (hwc[..., 0:3] + 1) / 2, atol=0.5 / 255 + 1e-6, rtol=0)
    roughness, info = read_image(tmp_path / "roughness.png")
    assert info.channel_names == ("Y",)
    np.testing.assert_allclose(roughness, hwc[..., 6:7], atol=0.5 / 255 + 1e-6, rtol=0)


def test_material_json_is_honoured_and_defaults_without_it(tmp_path: Path) -> None:
    maps = random_maps()
    write_material(tmp_path, maps)  # PNG, sRGB albedos
    with_json = read_material(tmp_path)
    meta_path = tmp_path / "material.json"
    meta = json.loads(meta_path.read_text())
    meta["maps"]["diffuse"]["encoding"] = "linear"
    meta_path.write_text(json.dumps(meta))
    stored, _ = read_image(tmp_path / "diffuse.png")
    relabelled = read_material(tmp_path)
    torch.testing.assert_close(M.diffuse(relabelled)[0], torch.from_numpy(stored).permute(2, 0, 1))
    assert (M.diffuse(relabelled) - M.diffuse(with_json)).abs().max() > 0.05
    meta_path.unlink()  # without material.json: PNG albedos are sRGB
    torch.testing.assert_close(read_material(tmp_path), with_json, atol=0, rtol=0)

    exr = tmp_path / "exr"
    write_material(exr, maps, fmt="exr")
    (exr / "material.json").unlink()  # without material.json: EXR albedos are linear
    torch.testing.assert_close(read_material(exr), maps, atol=1e-6, rtol=0)


def test_decoded_normals_are_renormalised_with_a_zero_guard(tmp_path: Path) -> None:
    write_material(tmp_path, random_maps(4), fmt="exr")
    stored = np.full((4, 4, 3), 0.5, np.float32)  # decodes to the zero vector
    stored[0, 0] = (0.9, 0.5, 0.9)  # decodes to (0.8, 0, 0.8), not unit
    write_image(tmp_path / "normal.exr", stored)
    n = M.normal(read_material(tmp_path))[0]
    torch.testing.assert_close(n[:, 0, 0], torch.tensor([0.5 ** 0.5, 0.0, 0.5 ** 0.5]))
    torch.testing.assert_close(n[:, 1:, :], torch.tensor([0.0, 0.0, 1.0]).view(3, 1, 1).expand(3, 3, 4))
    torch.testing.assert_close(n[:, 0, 1:], torch.tensor([0.0, 0.0, 1.0]).view(3, 1).expand(3, 3))


def test_rgb_roughness_is_averaged_and_opaque_alpha_ignored(tmp_path: Path) -> None:
    maps = random_maps(4)
    write_material(tmp_path, maps, albedo_encoding="linear")
    rgb = np.random.default_rng(1).random((4, 4, 3)).astype(np.float32)
    write_image(tmp_path / "roughness.png", rgb, bit_depth=16)
    stored, _ = read_image(tmp_path / "roughness.png")
    diffuse, _ = read_image(tmp_path / "diffuse.png")
    write_image(tmp_path / "diffuse.png", np.concatenate([diffuse, np.ones((4, 4, 1), np.float32)], axis=2))
    got = read_material(tmp_path)
    torch.testing.assert_close(M.roughness(got)[0, 0], torch.from_numpy(stored.mean(axis=2)))
    torch.testing.assert_close(M.diffuse(got)[0], torch.from_numpy(diffuse).permute(2, 0, 1))


@pytest.mark.parametrize("kwargs, match", [
    (dict(maps=random_maps().expand(2, -1, -1, -1)), r"maps: expected a single material .*got batch size 2"),
    (dict(maps=random_maps()[:, :9]), r"maps: expected shape \(B, 10, H, W\)"),
    (dict(maps=random_maps() * float("nan")), "maps: contains NaN"),
    (dict(fmt="jpg"), "fmt: expected 'png' or 'exr', got 'jpg'"),
    (dict(fmt="exr", albedo_encoding="srgb"), r"albedo_encoding: expected one of \('linear',\) for EXR, got 'srgb'"),
    (dict(fmt="exr", bit_depth=8), r"bit_depth: expected one of \(16, 32\) for EXR, got 8"),
    (dict(albedo_encoding="gamma"), "albedo_encoding: expected one of .*, got 'gamma'"),
])
def test_write_material_rejects(tmp_path: Path, kwargs: dict, match: str) -> None:
    kwargs = {"maps": random_maps(), **kwargs}
    with pytest.raises(ValueError, match=match):
        write_material(tmp_path / "m", **kwargs)
    assert not (tmp_path / "m").exists()


def _grey(path: Path) -> None:
    write_image(path, np.zeros((16, 16), np.float32))


def _set_json(key: str, value: object):
    def damage(folder: Path) -> None:
        meta = json.loads((folder / "material.json").read_text())
        if key == "format_version":
            meta[key] = value
        else:
            meta["maps"]["diffuse"][key] = value
        (folder / "material.json").write_text(json.dumps(meta))
    return damage


# (format written, damage, exception, file named, message)
BAD_MATERIALS = {
    "missing map": ("png", lambda f: (f / "diffuse.png").unlink(), FileNotFoundError, "diffuse.png",
                    "missing map 'diffuse': expected diffuse.png"),
    "missing map, no json": ("png", lambda f: [(f / "material.json").unlink(), (f / "diffuse.png").unlink()],
                             FileNotFoundError, "diffuse", "expected diffuse.png or diffuse.exr, got neither"),
    "wrong size": ("png", lambda f: write_image(f / "specular.png", np.zeros((8, 16, 3), np.float32)),
                   ValueError, "specular.png", r"expected size 16x16 \(H x W\) like normal.png, got 8x16"),
    "corrupt file": ("png", lambda f: (f / "roughness.png").write_bytes(b"garbage bytes" * 10), ValueError,
                     "roughness.png", "expected a readable PNG file, got an unreadable or corrupt file"),
    "NaN in EXR": ("exr", lambda f: write_raw_exr(f / "roughness.exr", {"Y": np.full((16, 16), np.nan)}),
                   ValueError, "roughness.exr", "expected finite values, got 256 NaN"),
    "EXR out of range": ("exr", lambda f: write_image(f / "diffuse.exr", np.full((16, 16, 3), 1.5, np.float32)),
                         ValueError, "diffuse.exr", r"expected values in \[0, 1\].*got \[1.5, 1.5\]"),
    "grey diffuse": ("png", lambda f: _grey(f / "diffuse.png"), ValueError, "diffuse.png",
                     r"expected an RGB image \(3 channels\), got a grey image \(1 channel\)"),
    "grey normal": ("png", lambda f: _grey(f / "normal.png"), ValueError, "normal.png",
                    r"expected an RGB image \(3 channels\), got a grey image"),
    "2-channel roughness": ("png", lambda f: write_image(f / "roughness.png", np.full((16, 16, 2), 0.5, np.float32)),
                            ValueError, "roughness.png", "expected no alpha channel or an opaque one"),
    "ambiguous, no json": ("png", lambda f: [(f / "material.json").unlink(),
                                             write_image(f / "normal.exr", np.zeros((16, 16, 3), np.float32))],
                           ValueError, "normal", "got both normal.png and normal.exr"),
    "bad encoding": ("png", _set_json("encoding", "gamma"), ValueError, "material.json",
                     r"expected encoding of 'diffuse' in \('srgb', 'linear'\), got 'gamma'"),
    "newer version": ("png", _set_json("format_version", 2), ValueError, "material.json",
                      "expected format_version <= 1, got 2"),
    "broken json": ("png", lambda f: (f / "material.json").write_text("{"), ValueError, "material.json",
                    "expected JSON with 'format_version'"),
}


@pytest.mark.parametrize("case", list(BAD_MATERIALS))
def test_bad_material_errors_name_the_file(tmp_path: Path, case: str) -> None:
    fmt, damage, exc, file, match = BAD_MATERIALS[case]
    write_material(tmp_path, random_maps(), fmt=fmt)
    damage(tmp_path)
    with pytest.raises(exc, match=match) as err:
        read_material(tmp_path)
    assert file in str(err.value)


def test_missing_folder() -> None:
    with pytest.raises(FileNotFoundError, match="no_such_material: expected a material folder"):
        read_material("/nonexistent/no_such_material")


# ----------------------------------------------------------------------------- strips
@pytest.mark.parametrize("num_inputs", [0, 1, 10])
def test_strip_round_trip(tmp_path: Path, num_inputs: int) -> None:
    maps = random_maps(8)
    inputs = torch.rand(num_inputs, 3, 8, 8, generator=torch.Generator().manual_seed(2))
    path = tmp_path / "s.png"
    write_strip(path, maps, inputs if num_inputs else None)
    image, info = read_image(path)
    assert image.shape == (8, 8 * (num_inputs + 4), 3) and info.bit_depth == 8
    got_inputs, got = read_strip(path, crop=8)
    assert got_inputs.shape == (num_inputs, 3, 8, 8) and got_inputs.dtype == torch.float32
    torch.testing.assert_close(got_inputs, inputs, atol=0.5 / 255 + 1e-6, rtol=0)
    assert_maps_close(got, maps, "png", 8, "linear")
    # albedos linear as stored, roughness as 3 equal grey channels
    diffuse = image[:, 8 * (num_inputs + 1):8 * (num_inputs + 2)]
    np.testing.assert_array_equal(diffuse, np.rint(maps[0, 3:6].permute(1, 2, 0).numpy() * 255) / 255)
    rough = image[:, 8 * (num_inputs + 2):8 * (num_inputs + 3)]
    assert (rough == rough[..., :1]).all()


def test_strip_decodes_like_the_authors(tmp_path: Path) -> None:
    codes = np.zeros((4, 20, 3))
    codes[:, 4:8] = (191, 128, 255)  # normal = normalize(2 c / 255 - 1)
    codes[:, 8:12] = (10, 20, 30)  # diffuse, linear as stored
    codes[:, 12:16] = (0, 51, 102)  # non-grey roughness: averaged
    codes[:, 16:20] = (200, 100, 0)
    write_image(tmp_path / "s.png", (codes / 255).astype(np.float32))
    inputs, maps = read_strip(tmp_path / "s.png", crop=None)
    n = torch.tensor([191, 128, 255]) * 2 / 255 - 1
    torch.testing.assert_close(M.normal(maps)[0, :, 0, 0], n / n.norm())
    torch.testing.assert_close(M.diffuse(maps)[0, :, 0, 0], torch.tensor([10.0, 20.0, 30.0]) / 255)
    torch.testing.assert_close(M.roughness(maps)[0, 0, 0, 0], torch.tensor(51 / 255))
    torch.testing.assert_close(M.specular(maps)[0, :, 0, 0], torch.tensor([200.0, 100.0, 0.0]) / 255)
    assert inputs.shape == (1, 3, 4, 4) and float(inputs.abs().max()) == 0.0


def test_288_px_panels_are_centre_cropped_to_256(tmp_path: Path) -> None:
    rows, cols = np.mgrid[0:288, 0:288] / 287.0
    panel = np.stack([rows, cols, np.zeros_like(rows)], axis=2)
    write_image(tmp_path / "s.png", np.concatenate([panel] * 5, axis=1).astype(np.float32), bit_depth=16)
    inputs, maps = read_strip(tmp_path / "s.png")
    assert inputs.shape == (1, 3, 256, 256) and maps.shape == (1, 10, 256, 256)
    np.testing.assert_allclose(inputs[0, :2, 0, 0] * 287, [16, 16], atol=0.01)
    np.testing.assert_allclose(M.diffuse(maps)[0, :2, -1, -1] * 287, [271, 271], atol=0.01)
    inputs, _ = read_strip(tmp_path / "s.png", offset=(0, 32))
    np.testing.assert_allclose(inputs[0, :2, 0, 0] * 287, [0, 32], atol=0.01)
    inputs, _ = read_strip(tmp_path / "s.png", panel=288, crop=None)
    assert inputs.shape == (1, 3, 288, 288)


def test_bad_strips(tmp_path: Path) -> None:
    def strip(name: str, shape: tuple[int, ...]) -> Path:
        write_image(tmp_path / name, np.zeros(shape, np.float32))
        return tmp_path / name

    cases = [
        (strip("odd.png", (8, 36, 3)), {}, r"odd\.png: expected a width that is a multiple .* got width 36"),
        (strip("three.png", (8, 24, 3)), {}, r"three\.png: expected a width that is a multiple \(>= 4\)"),
        (strip("grey.png", (8, 32)), {}, r"grey\.png: expected an RGB image \(3 channels\), got a grey image"),
        (strip("ok.png", (8, 32, 3)), {"panel": 16}, r"ok\.png: expected square panels of 16 px .*got height 8"),
        (tmp_path / "ok.png", {}, r"ok\.png: expected crop in 1..8 .*got 256"),
        (tmp_path / "ok.png", {"crop": 4, "offset": (5, 0)}, r"offset: expected \(top, left\) in \[0, 4\]"),
        (tmp_path / "ok.png", {"crop": None, "offset": (0, 0)}, "offset: expected None when crop is None"),
    ]
    for path, kwargs, match in cases:
        with pytest.raises(ValueError, match=match):
            read_strip(path, **kwargs)
    with pytest.raises(FileNotFoundError, match=r"none\.png"):
        read_strip(tmp_path / "none.png")

    maps = random_maps(8)
    for kwargs, match in [
        (dict(maps=maps[..., :4]), r"maps: expected square maps .*got 8x4"),
        (dict(maps=maps.expand(2, -1, -1, -1)), "maps: expected a single material"),
        (dict(maps=maps, inputs=torch.zeros(2, 3, 4, 4)), r"inputs: expected shape \(N, 3, 8, 8\)"),
        (dict(maps=maps, inputs=torch.full((3, 8, 8), float("inf"))), "inputs: expected finite values"),
        (dict(path=tmp_path / "s.exr", maps=maps), r"s\.exr: expected a \.png file name"),
    ]:
        with pytest.raises(ValueError, match=match):
            write_strip(**{"path": tmp_path / "w.png", **kwargs})
    assert not (tmp_path / "w.png").exists()
