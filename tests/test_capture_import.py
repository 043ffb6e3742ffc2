"""Capture folders of other labs (MaterialGAN / svbrdf-diff-renderer layout) read into capture.json.

The two real captures of ``../shared/real/`` (not copied into the project) are read from there;
``MI_SVBRDF_REAL_DIR`` names another folder. Where they are absent those tests skip with the reason.
"""
from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from mi_svbrdf.cli import capture_file
from mi_svbrdf.cli.common import standalone
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.render import point, render
from mi_svbrdf.io.calibrated_photos import CameraSpec, CaptureSpec, ImageSpec, LightSpec, load_capture
from mi_svbrdf.io.capture_import import read_foreign_capture, write_foreign_capture
from mi_svbrdf.io.image_io import write_image
from mi_svbrdf.io.material_io import srgb_encode

REAL = Path(os.environ.get("MI_SVBRDF_REAL_DIR", Path(__file__).resolve().parents[2] / "shared" / "real"))
CAPTURES = {"yellow_box": ("optim.json", 10.88), "bath_tile": ("parameters.json", 9.728)}


def _cli(*argv: str) -> int:
    return standalone(capture_file.add_parser, ["capture-file", *argv])


@pytest.mark.parametrize("name", sorted(CAPTURES))
def test_shared_real_captures_import_and_round_trip(name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = REAL / name
    if not folder.is_dir():
        holds = ", ".join(f"{n}/" for n in sorted(CAPTURES))
        pytest.skip(f"no real capture at {folder}: set MI_SVBRDF_REAL_DIR to the folder that holds {holds} to run it "
                    "(default: shared/real/ beside the clone)")
    file, width = CAPTURES[name]
    raw = json.loads((folder / file).read_text())
    assert _cli("import", str(folder), "--size", "64", "-o", str(tmp_path / "cap")) == 0
    assert f"from {folder / file}" in capsys.readouterr().out
    spec, images, valid = load_capture(tmp_path / "cap")
    assert spec.n_images == len(raw["idx"]) == 9 and images.shape == (9, 3, 64, 64)
    assert images.isfinite().all() and 0.02 < float(images.mean()) < 0.9  # real photos, not black or white
    scale = 2.0 / width
    for k, im in zip(raw["idx"], spec.images):
        assert im.rectified and im.encoding == "srgb8"
        np.testing.assert_allclose(im.camera.position, np.array(raw["camera_pos"][k]) * scale, rtol=1e-12)
        np.testing.assert_allclose(im.light.position, np.array(raw["light_pos"][k]) * scale, rtol=1e-12)
        np.testing.assert_allclose(im.light.intensity, np.array(raw["light_pow"]) * scale**2 / math.pi, rtol=1e-12)
    # the written capture reads back to itself (file names aside)
    again = read_foreign_capture(folder)
    assert [im.light for im in again.spec.images] == [im.light for im in spec.images]


def _constructed(tmp_path: Path, size: int = 64) -> tuple[CaptureSpec, torch.Tensor, float]:
    """A 3-photo capture in project units, its photos rendered by our renderer (white-ish Lambertian)."""
    width_cm = 12.0
    cams = [(0.1, -0.2, 3.5), (-0.6, 0.4, 3.0), (0.9, 0.7, 4.2)]
    flashes = [(0.15, -0.2, 3.5), (-0.6, 0.3, 3.1), (0.8, 0.7, 4.2)]
    intensity = (11.0, 12.0, 13.5)
    spec = CaptureSpec(tuple(ImageSpec(f"{k:03d}.png", "srgb8", True, CameraSpec(c), LightSpec(f, intensity))
                             for k, (c, f) in enumerate(zip(cams, flashes))))
    maps = M.constant_maps(1, size, size, diffuse=0.4, specular=0.04, roughness=0.5)
    light = point(torch.tensor([flashes]))
    view = point(torch.tensor([cams]))
    photos = render(maps, light, view, intensity=torch.tensor(intensity), distance_falloff=True)[0].clamp(0, 1)
    return spec, photos, width_cm


def test_constructed_capture_imports_to_the_positions_and_intensity_it_was_made_with(tmp_path: Path) -> None:
    spec, photos, width_cm = _constructed(tmp_path)
    files = []
    (tmp_path / "ours").mkdir()
    for k in range(spec.n_images):
        files.append(tmp_path / "ours" / f"{k}.png")
        write_image(files[-1], srgb_encode(photos[k].permute(1, 2, 0).numpy()), 8, srgb=True)
    written = write_foreign_capture(spec, files, tmp_path / "theirs", width_cm=width_cm)
    data = json.loads(written.read_text())
    assert data["image_size"] == width_cm and len(data["camera_pos"]) == 3
    back = read_foreign_capture(tmp_path / "theirs")
    for a, b in zip(spec.images, back.spec.images):
        np.testing.assert_allclose(b.camera.position, a.camera.position, rtol=1e-12)
        np.testing.assert_allclose(b.light.position, a.light.position, rtol=1e-12)
        np.testing.assert_allclose(b.light.intensity, a.light.intensity, rtol=1e-12)
    assert _cli("import", str(tmp_path / "theirs"), "-o", str(tmp_path / "cap.json")) == 0
    loaded, images, _ = load_capture(tmp_path / "cap.json")
    assert images.shape == photos.shape
    assert float((images - photos).abs().max()) < 0.01  # 8-bit sRGB round trip of our own renders


def test_intensity_conversion_matches_the_other_labs_formula(tmp_path: Path) -> None:
    """Their texel: albedo (1 - s) / pi * light_pow * cos / d_cm^2 (the flash at the camera); ours renders the imported
    intensity. Compared on a diffuse sample: specular 0 and roughness 1 leave a specular lobe below
    1e-4 of the diffuse term (the Fresnel approximation's 2^-12.5 at v.h = 1 over a flat D = 1/pi)."""
    width_cm, power, size = 10.0, (1500.0, 1200.0, 900.0), 16
    cam_cm = [3.0, -2.0, 25.0]
    folder = tmp_path / "theirs"
    folder.mkdir()
    write_image(folder / "00.png", np.full((size, size, 3), 0.5, np.float32), 8)
    (folder / "parameters.json").write_text(json.dumps({"image_size": width_cm, "camera_pos": [cam_cm],
                                                        "light_pos": [cam_cm], "light_pow": list(power)}))
    im = read_foreign_capture(folder).spec.images[0]
    albedo = 0.3
    maps = M.constant_maps(1, size, size, diffuse=albedo, specular=0.0, roughness=1.0)
    ours = render(maps, point(torch.tensor([[im.light.position]])), point(torch.tensor([[im.camera.position]])),
                  intensity=torch.tensor(im.light.intensity), distance_falloff=True)[0, 0]
    c = (torch.arange(size, dtype=torch.float64) + 0.5) / size * width_cm - width_cm / 2  # texel centres, cm
    x, y = c.view(1, -1), -c.view(-1, 1)  # row 0 at the top (+y)
    d2 = (cam_cm[0] - x) ** 2 + (cam_cm[1] - y) ** 2 + cam_cm[2] ** 2
    cos = cam_cm[2] / d2.sqrt()
    theirs = torch.stack([albedo / math.pi * p * cos / d2 for p in power]).float()
    torch.testing.assert_close(ours, theirs, rtol=2e-4, atol=1e-7)


def _folder(tmp_path: Path, **changes: object) -> Path:
    folder = tmp_path / "cap"
    folder.mkdir(exist_ok=True)
    for k in range(2):
        write_image(folder / f"{k:02d}.png", np.full((16, 16, 3), 0.5, np.float32), 8)
    data: dict[str, object] = {"im_size": 10.0, "camera_pos": [[0, 0, 20], [1, 0, 20]],
                               "light_pos": [[0, 0, 20], [1, 0, 20]], "light_pow": 1500, "idx": [0, 1]}
    for key, value in changes.items():
        if value is None:
            data.pop(key)
        else:
            data[key] = value
    (folder / "optim.json").write_text(json.dumps(data))
    return folder


@pytest.mark.parametrize("changes, message", [
    ({"im_size": None}, r"optim.json: expected the key 'image_size' \(or im_size\), got none"),
    ({"camera_pos": None}, r"optim.json: expected the key 'camera_pos', got none"),
    ({"light_pos": None}, r"optim.json: expected the key 'light_pos', got none"),
    ({"light_pow": None}, r"optim.json: expected the key 'light_pow', got none"),
    ({"im_size": -3}, r"optim.json: im_size: expected a positive finite number, got -3"),
    ({"camera_pos": [[0, 0, 20], [1, 0]]}, r"optim.json: camera_pos\[1\]: expected \[x, y, z\] \(cm\), got \[1, 0\]"),
    ({"light_pos": [[0, 0, 20], [1, 0, -2]]}, r"optim.json: light_pos\[1\]: expected z > 0"),
    ({"light_pos": [[0, 0, 20]]}, r"optim.json: light_pos: expected 2 positions like camera_pos, got 1"),
    ({"light_pow": "bright"}, r"optim.json: light_pow: expected a finite number, got 'bright'"),
    ({"light_pow": [1, 2]}, r"optim.json: light_pow: expected a number or \[r, g, b\], got \[1, 2\]"),
    ({"idx": [0, 5]}, r"optim.json: idx: expected a non-empty list of photo numbers in \[0, 2\), got \[0, 5\]"),
    ({"target_dir": "missing", "camera_pos": [[0, 0, 20], [1, 0, 20], [0, 1, 20]],
      "light_pos": [[0, 0, 20], [1, 0, 20], [0, 1, 20]], "idx": [0, 1, 2]},
     r"optim.json: expected photo 00.png in .*missing \(or all the photos in .*cap\), got no such file"),
])
def test_each_missing_or_malformed_key_is_one_line_naming_file_and_key(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], changes: dict[str, object], message: str) -> None:
    folder = _folder(tmp_path, **changes)
    with pytest.raises(ValueError, match=message):
        read_foreign_capture(folder)
    assert _cli("import", str(folder), "-o", str(tmp_path / "out")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(folder / "optim.json") in err[0], err


def test_text_file_layout(tmp_path: Path) -> None:
    folder = tmp_path / "old"
    folder.mkdir()
    for k in range(2):
        write_image(folder / f"{k:02d}.png", np.full((16, 16, 3), 0.25, np.float32), 8)
    (folder / "camera_pos.txt").write_text("0,0,20\n2,1,22\n")
    (folder / "light_pos.txt").write_text("0,0,20\n2,1,22\n")
    (folder / "image_size.txt").write_text("8.0\n")
    (folder / "light_power.txt").write_text("1000,1100,1200\n")
    spec = read_foreign_capture(folder).spec
    assert spec.images[1].camera.position == (0.5, 0.25, 5.5)
    np.testing.assert_allclose(spec.images[0].light.intensity, np.array([1000, 1100, 1200]) * 0.25**2 / math.pi)
    (folder / "light_pos.txt").write_text("0,0,20\n2,one,22\n")
    with pytest.raises(ValueError, match=r"light_pos.txt: line 2: expected one x,y,z line per photo, got '2,one,22'"):
        read_foreign_capture(folder)
    (folder / "light_pos.txt").write_text("0,0,20\n2,1,22\n")
    (folder / "image_size.txt").unlink()
    with pytest.raises(ValueError, match=r"image_size.txt: expected the file \(one number \(cm\)\), got no such file"):
        read_foreign_capture(folder)


def test_folder_without_a_capture_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _cli("import", str(tmp_path), "-o", str(tmp_path / "out")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "expected parameters.json, optim.json or camera_pos.txt" in err[0]
    shutil.rmtree(tmp_path / "out", ignore_errors=True)


@pytest.mark.parametrize("where", ["target_dir", "beside"])
def test_photos_in_target_dir_first_then_beside_the_json(where: str, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """yellow_box's optim.json (target_dir "target/512") with its photos in target_dir, or beside the JSON as the
    field's data sets are often unpacked: both import, and the command says which folder it used."""
    source = REAL / "yellow_box"
    if not source.is_dir():
        pytest.skip(f"no real capture at {source}: set MI_SVBRDF_REAL_DIR to the folder that holds yellow_box/")
    folder = tmp_path / "yellow_box"
    folder.mkdir()
    shutil.copyfile(source / "optim.json", folder / "optim.json")
    target = json.loads((source / "optim.json").read_text())["target_dir"]
    photos = sorted((source / target).glob("[0-9][0-9].png"))
    into = folder / target if where == "target_dir" else folder
    into.mkdir(parents=True, exist_ok=True)
    for photo in photos:
        shutil.copyfile(photo, into / photo.name)
    read = read_foreign_capture(folder)
    assert read.photo_dir == into and all(p.parent == into for p in read.photos)
    assert _cli("import", str(folder), "--size", "64", "-o", str(tmp_path / "cap")) == 0
    out = capsys.readouterr().out
    said = (f"photos: in target_dir '{target}' ({into})" if where == "target_dir" else
            f"photos: beside optim.json in {into}, not in target_dir '{target}' (no such folder)")
    assert said in out, out
    spec, images, _ = load_capture(tmp_path / "cap")
    assert spec.n_images == len(photos) == 9 and images.shape == (9, 3, 64, 64)
    # beside the JSON, but target_dir exists and lacks a photo: still the ones beside, and the reason says so
    if where == "beside":
        (folder / target).mkdir(parents=True)
        shutil.copyfile(photos[0], folder / target / photos[0].name)
        assert read_foreign_capture(folder).photo_note == (
            f"photos: beside optim.json in {folder}, not in target_dir '{target}' (not all of them there)")
