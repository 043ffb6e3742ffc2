"""``mi-svbrdf capture`` and ``mi_svbrdf.predict`` end to end, with tiny random nets (accuracy not tested)."""
from __future__ import annotations

import json
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from mi_svbrdf.assets import EXAMPLE_FLASH, EXAMPLE_VIEWS
from mi_svbrdf.cli import capture as capture_cli
from mi_svbrdf.cli.common import standalone
from mi_svbrdf.core import maps as M
from mi_svbrdf.io import photos as photo
from mi_svbrdf.io.material_io import read_material
from mi_svbrdf.nets import inference as P
from mi_svbrdf.nets.weights import MANIFEST
from tests.conftest import export_tiny_net

RES = 64


def _export(folder: Path, kind: str) -> None:
    export_tiny_net(folder, kind, RES)


@pytest.fixture(scope="module")
def weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("weights")
    _export(folder, "single")
    _export(folder, "multi")
    return folder


def _only(weights: Path, kind: str, dest: Path) -> Path:
    """A copy of ``weights`` whose manifest lists only ``kind``."""
    shutil.copytree(weights, dest)
    manifest = json.loads((dest / MANIFEST).read_text())
    (dest / MANIFEST).write_text(json.dumps({kind: manifest[kind]}))
    return dest


def _capture(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = standalone(capture_cli.add_parser, ["capture", *argv])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def test_capture_end_to_end_on_bundled_photo(weights: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    code, text = _capture(["example", "-o", str(out), "--weights", str(weights), "--frames", "12"], capsys)
    assert code == 0, text
    for name in M.MAP_NAMES:
        assert (out / f"{name}.png").is_file() and (out / "exr" / f"{name}.exr").is_file()
    maps = read_material(out / "exr")
    assert maps.shape == (1, 10, RES, RES) and torch.isfinite(maps).all()
    assert torch.allclose(M.normal(maps).norm(dim=1), torch.ones(1, RES, RES), atol=1e-4)
    assert maps[:, 3:].min() >= 0.0 and maps[:, 3:].max() <= 1.0
    direct = P.predict(EXAMPLE_FLASH, weights_dir=weights)
    assert torch.allclose(maps, direct, atol=1e-6)  # the EXR maps are the network's output
    with Image.open(out / "relit.gif") as gif:
        assert gif.n_frames == 12 and gif.size == (RES, RES)
        first = np.asarray(gif.convert("RGB"), dtype=np.float32)
        gif.seek(6)
        half = np.asarray(gif.convert("RGB"), dtype=np.float32)
    assert np.abs(first - half).mean() > 1.0  # the light moves
    with Image.open(out / "contact_sheet.png") as sheet:
        assert sheet.size[0] == RES * (1 + 4 + capture_cli.SHEET_LIGHTS) and sheet.size[1] > RES
    summary = json.loads((out / "summary.json").read_text())
    assert summary["net"]["kind"] == "single" and summary["resolution"] == RES
    page = (out / "view.html").read_text(encoding="utf-8")  # the WebGL2 viewer of the maps
    assert "view.html" in summary["outputs"] and page.count("data:image/png;base64,") == 4
    assert summary["inputs"][0]["path"] == str(EXAMPLE_FLASH)
    assert summary["inputs"][0]["conversions"] == ["sRGB decoded to linear"]
    assert summary["seconds"]["network"] > 0


def test_capture_jpeg_with_exif_rotation_equals_upright(weights: Path, tmp_path: Path) -> None:
    with Image.open(EXAMPLE_FLASH) as img:
        upright = np.asarray(img.convert("RGB"))[:, 16:240]  # 256 x 224 (H x W), not square
    Image.fromarray(upright).save(tmp_path / "upright.jpg", quality=100, subsampling=0)
    exif = Image.Exif()
    exif[photo.ORIENTATION_TAG] = 8  # stored turned 90 degrees clockwise; the viewer rotates it back
    Image.fromarray(np.rot90(upright, -1).copy()).save(tmp_path / "rotated.jpg", quality=100, subsampling=0,
                                                       exif=exif.tobytes())
    a = P.predict_details(tmp_path / "upright.jpg", weights_dir=weights)
    b = P.predict_details(tmp_path / "rotated.jpg", weights_dir=weights)
    assert b.inputs[0]["original_size_hw"] == [256, 224]
    assert any("EXIF orientation 8" in c for c in b.inputs[0]["conversions"])
    assert (a.photos - b.photos).abs().max() < 0.02  # JPEG re-encoding of the rotated pixels only
    assert (a.maps - b.maps).abs().mean() < 2e-3
    # Without the EXIF transform the photo (and so the maps) would be very different.
    ignored = torch.from_numpy(photo.square_crop(np.rot90(upright, -1)) / 255.0).float()
    assert (photo.resize(ignored.permute(2, 0, 1), RES) - photo.resize(
        torch.from_numpy(photo.square_crop(upright) / 255.0).float().permute(2, 0, 1), RES)).abs().mean() > 0.05


def test_multi_path_three_photos(weights: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "multi"
    code, text = _capture(["example:multi", "-o", str(out), "--weights", str(weights), "--frames", "4"], capsys)
    assert code == 0, text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["net"]["kind"] == "multi" and len(summary["inputs"]) == 3
    assert [Path(i["path"]).name for i in summary["inputs"]] == [p.name for p in EXAMPLE_VIEWS]
    maps = read_material(out / "exr")
    reordered = P.predict([EXAMPLE_VIEWS[2], EXAMPLE_VIEWS[0], EXAMPLE_VIEWS[1]], weights_dir=weights)
    assert torch.allclose(maps, reordered, atol=1e-5)  # the multi net is order invariant: all 3 were used
    first_only = P.predict([EXAMPLE_VIEWS[0]], kind="multi", weights_dir=weights)
    assert (first_only - maps).abs().max() > 1e-3
    with Image.open(out / "contact_sheet.png") as sheet:
        assert sheet.size[0] == RES * (3 + 4 + capture_cli.SHEET_LIGHTS)


def test_symmetry_ensemble_is_the_default_and_symmetries_1_is_the_net(weights: Path, tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    from mi_svbrdf.nets.ensemble import symmetry_ensemble

    details = P.predict_details(EXAMPLE_FLASH, weights_dir=weights)
    net, _ = P.load("single", weights)
    with torch.no_grad():
        alone = net(details.photos)
        assert details.symmetries == 8
        assert torch.allclose(details.maps, symmetry_ensemble(net, details.photos, 8), atol=1e-6)
    assert torch.allclose(P.predict(EXAMPLE_FLASH, weights_dir=weights, symmetries=1), alone, atol=1e-6)
    assert not torch.allclose(details.maps, alone, atol=1e-3)  # a random net is not symmetric: the mean differs
    out = tmp_path / "one"
    code, text = _capture(["example", "-o", str(out), "--weights", str(weights), "--frames", "0",
                           "--symmetries", "1"], capsys)
    assert code == 0 and "(1 symmetry)" in text, text
    assert json.loads((out / "summary.json").read_text())["options"]["symmetries"] == 1
    assert torch.allclose(read_material(out / "exr"), alone, atol=1e-6)
    for bad in ("0", "9", "two"):
        with pytest.raises(SystemExit) as exit_info:
            _capture(["example", "-o", str(out), "--weights", str(weights), "--symmetries", bad], capsys)
        text = capsys.readouterr().err
        assert exit_info.value.code == 2 and "--symmetries: expected an integer in [1, 8]" in text, text


def test_predict_inputs_fallbacks_and_cache(weights: Path, tmp_path: Path) -> None:
    from_path = P.predict(EXAMPLE_FLASH, weights_dir=weights)
    loaded = torch.from_numpy(photo.load_photo(EXAMPLE_FLASH).image).permute(2, 0, 1)
    assert torch.allclose(P.predict(loaded[None], weights_dir=weights), from_path, atol=1e-6)
    assert torch.allclose(P.predict(loaded[None].numpy(), weights_dir=weights), from_path, atol=1e-6)
    with Image.open(EXAMPLE_FLASH) as img:
        u8 = np.asarray(img.convert("RGB"))
    assert torch.allclose(P.predict([u8], weights_dir=weights), from_path, atol=1e-5)
    before = P._cached_network.cache_info().hits
    P.predict(EXAMPLE_FLASH, weights_dir=weights)
    assert P._cached_network.cache_info().hits == before + 1
    full = P.predict(loaded[None, :, :96, :96], full_resolution=True, weights_dir=weights)
    assert full.shape == (1, 10, 96, 96)

    multi_only = _only(weights, "multi", tmp_path / "m")
    with pytest.warns(UserWarning, match="no single-image weights"):
        d = P.predict_details(EXAMPLE_FLASH, weights_dir=multi_only)
    assert d.kind == "multi"
    single_only = _only(weights, "single", tmp_path / "s")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = P.predict_details(list(EXAMPLE_VIEWS), weights_dir=single_only)
    assert d.kind == "single" and d.photos.shape[1] == 1 and "first photo only" in str(caught[0].message)
    with pytest.raises(ValueError, match="expected 1 photo"):
        P.predict(list(EXAMPLE_VIEWS), kind="single", weights_dir=weights)
    with pytest.raises(ValueError, match="kind: expected one of"):
        P.predict(EXAMPLE_FLASH, kind="multi", weights_dir=single_only)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="expected bundled network weights"):
        P.predict(EXAMPLE_FLASH, weights_dir=tmp_path / "empty")


def test_lazy_package_export(monkeypatch: pytest.MonkeyPatch, weights: Path) -> None:
    import mi_svbrdf

    monkeypatch.setitem(mi_svbrdf._LAZY, "predict", "mi_svbrdf.nets.inference")  # the line the package adds
    monkeypatch.delitem(vars(mi_svbrdf), "predict", raising=False)
    assert mi_svbrdf.predict is P.predict
    assert mi_svbrdf.predict(EXAMPLE_FLASH, weights_dir=weights).shape == (1, 10, RES, RES)


def test_bundled_flash_photo_is_reproducible() -> None:
    from mi_svbrdf.data.example_photos import encode, render_examples
    from mi_svbrdf.io.image_io import read_image

    stored, info = read_image(EXAMPLE_FLASH)
    assert info.bit_depth == 8 and stored.shape == (256, 256, 3)
    fresh = encode(render_examples(which=("flash",))["example_flash.png"])
    assert np.abs(np.round(fresh * 255) - np.round(stored * 255)).max() <= 1
    assert EXAMPLE_FLASH.stat().st_size < 300_000


def test_bad_inputs_name_the_file(weights: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    w = ["--weights", str(weights), "-o", str(tmp_path / "o")]
    code, text = _capture(w, capsys)
    assert code == 2 and "expected at least one photo" in text
    (tmp_path / "readme.jpg").write_text("hello")
    code, text = _capture([str(tmp_path / "readme.jpg"), *w], capsys)
    assert code == 2 and "readme.jpg: expected an image file" in text
    Image.fromarray(np.zeros((40, 40, 3), np.uint8)).save(tmp_path / "small.png")
    code, text = _capture([str(tmp_path / "small.png"), *w], capsys)
    assert code == 2 and "small.png" in text and "at least 64 px" in text
    Image.fromarray(np.zeros((64, 128, 3), np.uint8)).save(tmp_path / "wide.png")
    code, text = _capture([str(EXAMPLE_FLASH), str(tmp_path / "wide.png"), *w], capsys)
    assert code == 2 and "example_flash.png 256x256" in text and "wide.png 128x64" in text
    Image.fromarray(np.zeros((128, 128), np.uint8)).save(tmp_path / "grey.png")
    code, text = _capture([str(EXAMPLE_FLASH), str(tmp_path / "grey.png"), "--full-resolution", *w], capsys)
    assert code == 2 and "grey.png 128 px" in text
    code, text = _capture([str(tmp_path / "nope.jpg"), *w], capsys)
    assert code == 2 and "nope.jpg" in text
    code, text = _capture([str(EXAMPLE_FLASH), "--crop", "0,0,10", *w], capsys)
    assert code == 2 and "--crop" in text
    assert not (tmp_path / "o").exists()  # nothing written on bad input


def test_refine_estimates_each_photos_light_and_reports_errors(weights: Path, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """--refine runs the uncalibrated refinement after the multi net; summary.json records what it estimated."""
    out = tmp_path / "refined"
    code, text = _capture(["example:multi", "-o", str(out), "--weights", str(weights), "--frames", "0", "--refine",
                           "--budget-s", "4", "--no-progress"], capsys)
    assert code == 0, text
    summary = json.loads((out / "summary.json").read_text())
    ref = summary["refine"]
    assert summary["options"]["refine"] and len(ref["lights"]) == 3 and ref["steps"] > 0
    light0, camera0 = torch.tensor(ref["lights"][0]["light"]), torch.tensor(ref["lights"][0]["camera"])
    assert float((light0 - camera0).norm()) < 0.25 * float(camera0.norm())  # photo 0: a flash (beside) the lens
    assert len(ref["rerender_rmse_before"]) == len(ref["rerender_rmse_after"]) == 3
    assert "refined against the photos" in text
    net_only = tmp_path / "net"
    code, text = _capture(["example", "-o", str(net_only), "--weights", str(weights), "--frames", "0", "--refine"],
                          capsys)
    assert code == 0 and "--refine needs 2 photos or more" in text
    assert json.loads((net_only / "summary.json").read_text())["refine"] is None
    plain = tmp_path / "plain"
    code, text = _capture(["example:multi", "-o", str(plain), "--weights", str(weights), "--frames", "0",
                           "--refine", "--no-refine"], capsys)  # the last flag wins
    summary = json.loads((plain / "summary.json").read_text())
    assert code == 0 and summary["refine"] is None and not summary["options"]["refine"]
    assert "refined against the photos" not in text


def test_contact_sheet_says_where_the_lights_are_and_keeps_highlights_below_white() -> None:
    """The relit panels are labelled by where their light is (not "relit 1/2/3") and a panel whose highlights would
    be white (a glossy sample under a grazing light: relit 2 on real photos) is darkened in half stops, said in EV."""
    import doctest

    from mi_svbrdf.cli import capture as capture_cli
    from mi_svbrdf.core.maps import constant_maps
    from mi_svbrdf.core.metrics import eval_lights, rerender

    assert doctest.testmod(capture_cli).failed == 0
    where = eval_lights(3)
    labels = [capture_cli.light_label(where.light[k].tolist(), where.view[k].tolist()) for k in range(3)]
    assert labels == ["upper right 44° flash", "right 17°", "upper right 16°"], labels
    glossy = constant_maps(1, 32, 32, diffuse=0.9, specular=0.6, roughness=0.15)
    for image in rerender(glossy, where)[0]:
        stops = capture_cli.relit_stops(image)
        top = float(torch.quantile(image.amax(0).flatten(), capture_cli.RELIT_QUANTILE))
        assert top * 2 ** stops <= capture_cli.RELIT_WHITE and (stops == 0 or top * 2 ** (stops + 0.5) > 0.9)
    assert capture_cli.relit_stops(rerender(glossy, where)[0, 1]) < 0  # the grazing light: darkened


@pytest.fixture(scope="module")
def fused_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Tiny single and fused multi-image nets (the fused net's branch is the single net, its head trained)."""
    from mi_svbrdf.nets.network import build_network, network_config
    from mi_svbrdf.nets.weights import export_weights, load_network

    folder = tmp_path_factory.mktemp("fused_weights")
    _export(folder, "single")
    torch.manual_seed(5)
    net = build_network(network_config("compact", "multi", fusion=True, encoder_features=(8, 16, 16, 16),
                                       last_features=8, resolution=RES))
    net.single.load_state_dict(load_network("single", folder=folder).state_dict())
    with torch.no_grad():
        torch.nn.init.normal_(net.fusion.out.weight, std=0.05)
    ckpt = folder / "multi_checkpoint.pt"
    torch.save({"net_config": net.config.to_dict(), "model": net.state_dict(), "config": {"preset": "compact"},
                "step": 0, "seconds": 0.0}, ckpt)
    export_weights(ckpt, folder=folder)
    return folder


def test_several_photos_choose_the_maps_by_their_own_evidence(fused_weights: Path, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    from mi_svbrdf.eval.evidence import CANDIDATES
    from mi_svbrdf.nets.fusion import net_candidates

    out = tmp_path / "chosen"
    code, text = _capture(["example:multi", "-o", str(out), "--weights", str(fused_weights), "--frames", "0",
                           "--symmetries", "1"], capsys)
    assert code == 0, text
    summary = json.loads((out / "summary.json").read_text())
    choice = summary["choice"]
    assert summary["path"]["net"] == "fused" and summary["options"]["choose"]
    assert summary["maps"]["kept"] == choice["choice"] and "'choice'" in summary["maps"]["how"]  # not path.net's
    assert choice["choice"] in CANDIDATES[:3] and choice["held_photos"] == [2, 3] and choice["lights"] == "estimated"
    assert set(choice["scores"]) == {"single", "multi", "fused"} and all(v > 0 for v in choice["scores"].values())
    assert set(choice["best_per_photo"]) == {"2", "3"}
    line = next(t for t in text.splitlines() if t.startswith("choice by the photos' own evidence"))
    printed = {c: float(v) for c, v in re.findall(r"(single|multi|fused) (\d\.\d{4})", line)}
    assert f": {choice['choice']} (" in line and printed == pytest.approx(choice["scores"], abs=1e-4)
    assert f"({choice['choice']} maps kept)" in text
    details = P.predict_details(list(EXAMPLE_VIEWS), weights_dir=fused_weights, symmetries=1)
    net, _ = P.load("multi", fused_weights)
    expected = net_candidates(net, details.photos, 1)[choice["choice"]]
    assert torch.allclose(read_material(out / "exr"), expected, atol=2e-3)  # (EXR half floats)
    with Image.open(out / "contact_sheet.png") as sheet:
        assert sheet.size[0] == RES * (3 + 4 + capture_cli.SHEET_LIGHTS)
    # --no-choose: the fused net's maps, as before; one photo: no choice
    plain = tmp_path / "plain"
    code, text = _capture(["example:multi", "-o", str(plain), "--weights", str(fused_weights), "--frames", "0",
                           "--symmetries", "1", "--no-choose"], capsys)
    assert code == 0 and json.loads((plain / "summary.json").read_text())["choice"] is None
    assert json.loads((plain / "summary.json").read_text())["maps"]["kept"] == "fused"
    assert "choice by the photos" not in text
    assert torch.allclose(read_material(plain / "exr"), details.maps, atol=2e-3)
    one = tmp_path / "one"
    code, text = _capture(["example", "-o", str(one), "--weights", str(fused_weights), "--frames", "0",
                           "--symmetries", "1"], capsys)
    assert code == 0 and json.loads((one / "summary.json").read_text())["choice"] is None
    assert json.loads((one / "summary.json").read_text())["maps"]["kept"] == "single"
    assert "choice by the photos" not in text


def test_refine_after_the_choice_is_a_candidate_scored_by_its_validation(fused_weights: Path, tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "refined"
    code, text = _capture(["example:multi", "-o", str(out), "--weights", str(fused_weights), "--frames", "0",
                           "--symmetries", "1", "--refine", "--budget-s", "3", "--no-progress"], capsys)
    assert code == 0, text
    summary = json.loads((out / "summary.json").read_text())
    choice, refined = summary["choice"], summary["refine"]
    assert "refined" in choice["scores"] and choice["notes"] and choice["notes"][0].startswith("refined: ")
    assert refined is not None and "with the refinement: choice by the photos' own evidence" in text
    assert (summary["maps"]["kept"] == "refined") == (choice["choice"] == "refined"), summary["maps"]
    if choice["scores"]["refined"] is not None:  # validated: the base's score times the validation's ratio
        assert refined["blend"] is not None
    maps = read_material(out / "exr")
    assert maps.shape == (1, 10, RES, RES) and torch.isfinite(maps).all()
