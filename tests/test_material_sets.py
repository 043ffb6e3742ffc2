"""MaterialSet: reads strips and material folders; reports and skips bad entries by name."""
from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
import torch
from torch.utils.data import DataLoader

from mi_svbrdf.core import maps as M
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import write_material
from mi_svbrdf.io.material_sets import MaterialSet, png_size
from mi_svbrdf.io.strip import write_strip

SIZE = 16
LINEAR_8BIT = 0.5 / 255 + 1e-6   # strips store albedos linear in 8 bits
SRGB_8BIT = 0.5 / 255 * 2.4 / 1.055 + 1e-6  # folder PNGs store albedos sRGB-encoded


def material(size: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    n = torch.rand(1, 3, size, size, generator=g) * 2 - 1
    n[:, 2] = n[:, 2].abs() + 0.3
    return M.normalize_normals(torch.cat([n, torch.rand(1, 7, size, size, generator=g)], 1))


def max_normal_angle(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.double(), b.double()
    return float(torch.atan2(torch.cross(a, b, dim=0).norm(dim=0), (a * b).sum(0)).max())


@pytest.fixture
def root(tmp_path: Path) -> tuple[Path, dict[str, torch.Tensor]]:
    """A set with 5 good entries and 6 bad ones (+ files that are not materials)."""
    good = {}
    good["a.png"] = material(SIZE, 1)
    write_strip(tmp_path / "a.png", good["a.png"])
    good["b_with_input.png"] = material(SIZE, 2)
    write_strip(tmp_path / "b_with_input.png", good["b_with_input.png"], inputs=torch.full((3, SIZE, SIZE), 0.7))
    good["big.png"] = material(SIZE + 4, 3)  # 20-px panels: centre-cropped to 16
    write_strip(tmp_path / "big.png", good["big.png"])
    good["folder_png"] = material(SIZE, 4)
    write_material(tmp_path / "folder_png", good["folder_png"], fmt="png")
    (tmp_path / "sub").mkdir()
    good["sub/folder_exr"] = material(SIZE, 5)
    write_material(tmp_path / "sub" / "folder_exr", good["sub/folder_exr"], fmt="exr")
    # Bad entries.
    (tmp_path / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(200)))
    data = (tmp_path / "a.png").read_bytes()
    (tmp_path / "truncated.png").write_bytes(data[: len(data) // 2])
    write_material(tmp_path / "missing_map", material(SIZE, 6), fmt="png")
    (tmp_path / "missing_map" / "roughness.png").unlink()
    (tmp_path / "missing_map" / "material.json").unlink()  # found by file names, one missing
    write_image(tmp_path / "wrong_width.png", np.full((SIZE, 4 * SIZE + 5, 3), 0.5, np.float32))
    write_strip(tmp_path / "too_small.png", material(8, 7))
    write_material(tmp_path / "sub" / "nan_exr", material(SIZE, 8), fmt="exr")
    nan = np.full((SIZE, SIZE), np.nan, np.float32)
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"Y": nan}) as exr:
        exr.write(str(tmp_path / "sub" / "nan_exr" / "roughness.exr"))
    # Not materials: passed over.
    (tmp_path / "notes.txt").write_text("not a material")
    (tmp_path / ".a.tmp0123abcd.png").write_bytes(data[:10])
    (tmp_path / "empty_dir").mkdir()
    return tmp_path, good


def test_reads_strips_and_folders_and_skips_bad_entries(root: tuple[Path, dict[str, torch.Tensor]]) -> None:
    path, good = root
    with pytest.warns(UserWarning, match=r"skipped 5 of 11 entries") as record:
        s = MaterialSet(path, size=SIZE)
    message = str(record[0].message)
    for name in ("corrupt.png", "truncated.png", "missing_map", "wrong_width.png", "too_small.png"):
        assert name in message
    reasons = {p.name: r for p, r in s.skipped}
    assert set(reasons) == {"corrupt.png", "truncated.png", "missing_map", "wrong_width.png", "too_small.png"}
    assert "truncated" in reasons["truncated.png"] and "IEND" in reasons["truncated.png"]
    assert "missing map 'roughness'" in reasons["missing_map"]
    assert "multiple >= 4" in reasons["wrong_width.png"]
    assert "at least 16x16" in reasons["too_small.png"]
    # The NaN EXR passes the header scan (header mode); it is in the items until read.
    names = [e.name for e in s.items]
    assert names == ["a.png", "b_with_input.png", "big.png", "folder_png", "sub/folder_exr", "sub/nan_exr"]
    for i, (name, expected) in enumerate(good.items()):
        got_name, maps = s[i]
        assert got_name == name and maps.shape == (10, SIZE, SIZE) and maps.dtype == torch.float32
        if name == "big.png":
            expected = expected[..., 2:18, 2:18]
        expected = expected[0]
        tol = SRGB_8BIT if name == "folder_png" else (1e-6 if name.endswith("exr") else LINEAR_8BIT)
        assert (maps[3:] - expected[3:]).abs().max() <= tol, name
        assert max_normal_angle(maps[:3], expected[:3]) < (1e-5 if name.endswith("exr") else math.radians(0.5))


def test_entry_failing_on_read_is_reported_and_replaced(root: tuple[Path, dict[str, torch.Tensor]]) -> None:
    path, good = root
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = MaterialSet(path, size=SIZE)
    last = len(s) - 1
    assert s.items[last].name == "sub/nan_exr"
    with pytest.warns(UserWarning, match=r"skipped 1 of 6 entries.*nan_exr"):
        name, maps = s[last]
    assert name == "a.png"  # the next readable entry (wrapping around)
    assert len(s.skipped) == 6 and "NaN" in s.skipped[-1][1]
    strict = MaterialSet.__new__(MaterialSet)
    strict.__dict__.update(s.__dict__, on_error="raise", _unreadable=set())
    with pytest.raises(ValueError, match=r"nan_exr.*roughness\.exr: expected finite values"):
        strict[last]


def test_full_validation_catches_bad_pixel_data(root: tuple[Path, dict[str, torch.Tensor]]) -> None:
    path, _ = root
    # A strip with an intact header and IEND but damaged image data (CRC error).
    data = bytearray((path / "a.png").read_bytes())
    idat = data.index(b"IDAT")
    data[idat + 20: idat + 40] = bytes(20)
    (path / "damaged_data.png").write_bytes(bytes(data))
    assert png_size(path / "damaged_data.png") == (SIZE, 4 * SIZE)  # passes the cheap check
    with pytest.warns(UserWarning, match=r"skipped 7 of 12 entries"):
        s = MaterialSet(path, size=SIZE, validate="full")
    skipped = {p.name for p, _ in s.skipped}
    assert {"damaged_data.png", "nan_exr"} <= skipped
    assert [e.name for e in s.items] == ["a.png", "b_with_input.png", "big.png", "folder_png", "sub/folder_exr"]


def test_sizes_recursion_and_dataloader(root: tuple[Path, dict[str, torch.Tensor]]) -> None:
    path, good = root
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        native = MaterialSet(path, size=None, recursive=False, validate="full")
        resized = MaterialSet(path, size=8, fit="resize")
    assert [e.name for e in native.items] == ["a.png", "b_with_input.png", "big.png", "folder_png", "too_small.png"]
    assert native[2][1].shape == (10, 20, 20) and native[4][1].shape == (10, 8, 8)
    name, small = resized[0]
    expected = torch.nn.functional.avg_pool2d(good["a.png"][:, 3:], 2)[0]
    assert (small[3:] - expected).abs().max() < LINEAR_8BIT
    torch.testing.assert_close(small[:3].norm(dim=0), torch.ones(8, 8))
    loader = DataLoader(torch.utils.data.Subset(resized, range(4)), batch_size=2, num_workers=2)
    batches = list(loader)
    assert [n for b in batches for n in b[0]] == ["a.png", "b_with_input.png", "big.png", "folder_png"]
    torch.testing.assert_close(batches[0][1][0], small)


def test_bank_index_and_bad_arguments(tmp_path: Path) -> None:
    write_strip(tmp_path / "000000_wood.png", material(SIZE, 1))
    write_strip(tmp_path / "unlisted.png", material(SIZE, 2))
    write_image(tmp_path / "contact_sheet.png", np.zeros((10, 50, 3), np.float32))
    index = {"format": "mi_svbrdf material bank", "materials": [{"file": "000000_wood.png"}, {"file": "000001_x.png"}]}
    (tmp_path / "index.json").write_text(json.dumps(index))
    with pytest.warns(UserWarning, match=r"skipped 1 of 2 entries.*000001_x\.png"):
        s = MaterialSet(tmp_path, size=SIZE)
    assert [e.name for e in s.items] == ["000000_wood.png"]
    with pytest.raises(ValueError, match="fit: expected one of"):
        MaterialSet(tmp_path, fit="stretch")
    with pytest.raises(FileNotFoundError, match="root: expected a folder"):
        MaterialSet(tmp_path / "nope")
    (tmp_path / "index.json").write_text("{}")
    with pytest.raises(ValueError, match="index.json: expected a bank index"):
        MaterialSet(tmp_path)
