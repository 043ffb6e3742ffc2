"""The realistic captures (mi_svbrdf.data.realistic): deterministic and cached, two different splits, the
injected errors within their ranges, the clean twin exact, the photos decoded as load_capture decodes them,
the held-out error."""
from __future__ import annotations

import dataclasses
import doctest
import json
import math

import numpy as np
import pytest
import torch

from mi_svbrdf.data import realistic
from mi_svbrdf.data.realistic import (ERROR_FIELDS, MM_PER_UNIT, RANGES, RealisticCapture, RealisticSet,
                                      vignetting_factor)
from mi_svbrdf.io.calibrated_photos import camera_frame, load_capture
from mi_svbrdf.io.material_io import srgb_encode
from mi_svbrdf.optim.forward import TexelForward

SIZE = 48
N = 4


def _set(**kw) -> RealisticSet:  # the tune split's metal (saturated highlights) and glossy wood
    return RealisticSet(**{"split": "tune", "size": SIZE, "materials": 2, "n_images": (N,), "cache": False, **kw})


@pytest.fixture(scope="module")
def real() -> list[RealisticCapture]:
    return _set().captures(progress=False)


@pytest.fixture(scope="module")
def clean() -> list[RealisticCapture]:
    return _set(realism="clean").captures(progress=False)


def _positions(spec, what: str) -> torch.Tensor:
    return torch.tensor([getattr(im, what).position for im in spec.images], dtype=torch.float64)


def _same(a: RealisticCapture, b: RealisticCapture) -> bool:
    return (torch.equal(a.maps, b.maps) and torch.equal(a.images, b.images) and torch.equal(a.valid, b.valid)
            and a.stated == b.stated and a.true == b.true and a.errors == b.errors and a.info == b.info
            and all(torch.equal(getattr(a.heldout, f), getattr(b.heldout, f)) for f in ("light", "view", "intensity")))


def _rmse(render: torch.Tensor, cap: RealisticCapture) -> float:
    ok = cap.valid.expand_as(render)
    return float((render.clamp(0.0, 1.0) - cap.images)[ok].square().mean().sqrt())


def test_deterministic_cached_and_splits_differ(real, tmp_path) -> None:
    again = _set().captures(progress=False)
    assert [c.material for c in real] == [3, 13] and [c.cls for c in real] == ["metal", "wood"]
    assert all(_same(a, b) for a, b in zip(real, again))
    cached = _set(cache=True, cache_dir=str(tmp_path))
    first = cached.capture(3, N)
    assert cached.path(3, N).is_file() and _same(first, real[0]) and _same(cached.capture(3, N), real[0])
    test = RealisticSet(split="test", size=SIZE, materials=1, n_images=(N,), cache=False).capture(3, N)
    assert test.cls == "metal" and not torch.equal(test.maps, real[0].maps)
    assert not torch.allclose(_positions(test.true, "camera"), _positions(real[0].true, "camera"))
    assert RealisticSet(split="test").material_indices() != RealisticSet(split="tune").material_indices()


def test_gains_pinned_to_a_geometric_mean_of_one_within_their_ranges(real) -> None:
    for cap in real:
        gains = torch.tensor(cap.errors["gains"], dtype=torch.float64)
        assert gains.shape == (N, 3)
        assert torch.allclose(gains.log().mean(dim=0).exp(), torch.ones(3, dtype=torch.float64), atol=1e-5)
        stops = torch.tensor(cap.errors["exposure_stops"], dtype=torch.float64)
        balance = torch.tensor(cap.errors["white_balance"], dtype=torch.float64)
        assert bool((stops.abs() <= 0.7).all()) and bool(((balance >= 0.9) & (balance <= 1.1)).all())
        raw = stops.exp2()[:, None] * balance
        assert torch.allclose(gains, raw / raw.log().mean(dim=0).exp(), rtol=1e-9)  # the draws, normalised
        ratio = gains.amax(dim=0) / gains.amin(dim=0)
        assert bool((ratio <= 2 ** 1.4 * 1.1 / 0.9 + 1e-9).all()) and float(ratio.max()) > 1.05
        true_i = torch.tensor([im.light.intensity for im in cap.true.images], dtype=torch.float64)
        stated_i = torch.tensor([im.light.intensity for im in cap.stated.images], dtype=torch.float64)
        assert torch.allclose(true_i / stated_i, gains, rtol=1e-9)
        assert torch.allclose(stated_i, stated_i[:1].expand_as(stated_i))  # one stated intensity
        assert stated_i[0, 0] == pytest.approx(0.8 * float(_positions(cap.stated, "camera")[0].square().sum()))


def test_cameras_flash_offset_and_pose_errors(real) -> None:
    for cap in real:
        cams, lights = _positions(cap.true, "camera"), _positions(cap.true, "light")
        right, up, forward = camera_frame(cams)
        local = torch.stack([((lights - cams) * a).sum(-1) for a in (right, up, forward)], dim=1)  # (N, 3)
        assert torch.allclose(local, local[:1].expand_as(local), atol=1e-9)  # one offset in every photo's frame
        assert torch.allclose(local[0], torch.tensor(cap.errors["flash_offset_units"], dtype=torch.float64))
        assert 5.0 <= float(local[0].norm()) * MM_PER_UNIT <= 25.0
        assert float(local[0, 2]) == pytest.approx(0.0, abs=1e-12)
        stated, stated_light = _positions(cap.stated, "camera"), _positions(cap.stated, "light")
        assert torch.equal(stated, stated_light)  # the user puts the flash at the lens
        error = (stated - cams).norm(dim=1) / cams.norm(dim=1)
        assert bool((error <= 0.03 + 1e-12).all()) and float(error.max()) > 0
        fov = torch.tensor([im.camera.fov_deg for im in cap.true.images], dtype=torch.float64)
        assert bool(((fov >= 45) & (fov <= 65)).all())
        assert torch.allclose(cams[0, 2], 1.0 / torch.tan(torch.deg2rad(fov[0]) / 2))
        assert float(cams[0, :2].abs().max()) <= 0.3
        assert torch.allclose(cams[1:].norm(dim=1), 1.0 / torch.tan(torch.deg2rad(fov[1:]) / 2))
        elevation = torch.rad2deg(torch.asin(cams[1:, 2] / cams[1:].norm(dim=1)))
        assert bool(((elevation >= 45) & (elevation <= 80)).all())


def test_clean_twin_is_its_stated_calibration(real, clean) -> None:
    for cap, twin in zip(clean, real):
        assert cap.stated == cap.true and torch.equal(cap.maps, twin.maps)
        assert torch.equal(_positions(cap.true, "camera"), _positions(twin.true, "camera"))  # the same draws
        assert torch.equal(_positions(cap.true, "light"), _positions(twin.true, "light"))
        assert cap.errors["jpeg_quality"] is None and cap.errors["unmodelled_light"] is None
        with torch.no_grad():
            render = TexelForward(cap.stated, SIZE)(cap.maps)
        assert _rmse(render, cap) < 0.01  # 8 bits and noise only


def test_real_photos_hold_the_nuisances(real) -> None:
    for cap in real:
        with torch.no_grad():
            stated = TexelForward(cap.stated, SIZE)(cap.maps)
            true = TexelForward(cap.true, SIZE)(cap.maps) * cap.vignetting().float()
            unvignetted = TexelForward(cap.rendering_spec(), SIZE)(cap.maps)
        everything = unvignetted * cap.vignetting().float()
        err_stated, err_true, err_all = _rmse(stated, cap), _rmse(true, cap), _rmse(everything, cap)
        assert err_stated > 0.03 and err_true < 0.5 * err_stated
        assert err_all <= err_true and err_all < 0.02  # JPEG and noise remain
        assert _rmse(unvignetted, cap) > err_all  # the vignetting is in the photos
        v = torch.tensor(cap.errors["vignetting"])
        assert bool(((v >= 0) & (v <= 0.3)).all())
        assert all(70 <= q <= 95 for q in cap.errors["jpeg_quality"])
        light = cap.errors["unmodelled_light"]
        elevation = math.degrees(math.asin(light["position"][2] / math.hypot(*light["position"])))
        assert 30 <= elevation <= 70 and 0 <= light["level"] <= 0.03


def test_vignetting_factor_is_one_minus_v_at_the_farthest_corner() -> None:
    camera = torch.tensor([[0.0, 0.0, 2.0], [1.0, 0.5, 1.5]], dtype=torch.float64)
    strength = torch.tensor([0.2, 0.3], dtype=torch.float64)
    f = vignetting_factor(camera, strength, 64)
    assert f.shape == (2, 1, 64, 64) and float(f.max()) <= 1.0
    assert float(f[0].min()) == pytest.approx(0.8, abs=0.01) and float(f[0, 0, 31:33, 31:33].min()) > 0.999
    assert torch.allclose(f[0], f[0].flip(-1)) and torch.allclose(f[0], f[0].flip(-2))  # symmetric above the centre
    assert float(f[1].min()) == pytest.approx(0.7, abs=0.03) and float(f[1].min()) >= 0.7
    # independently: t from the angle between the ray and the axis (towards the origin)
    xs = -1.0 + (2.0 * torch.arange(64, dtype=torch.float64) + 1.0) / 64
    grid = torch.stack([xs[None, :].expand(64, 64), xs.flip(0)[:, None].expand(64, 64), torch.zeros(64, 64)], -1)
    corners = torch.tensor([[x, y, 0.0] for x in (-1.0, 1.0) for y in (-1.0, 1.0)], dtype=torch.float64)
    for k in range(2):
        def tan2(p: torch.Tensor) -> torch.Tensor:
            ray = p - camera[k]
            t = torch.acos((ray @ -camera[k]) / (ray.norm(dim=-1) * camera[k].norm()))
            return torch.tan(t) ** 2

        assert torch.allclose(f[k, 0], 1.0 - strength[k] * tan2(grid) / tan2(corners).max(), atol=1e-9)


def test_valid_is_false_exactly_where_a_channel_is_at_the_top_code(real) -> None:
    for cap in real:
        codes = np.round(srgb_encode(cap.images.permute(0, 2, 3, 1).numpy()) * 255.0)
        assert np.array_equal(codes, np.round(codes)) and codes.max() <= 255
        assert torch.equal(cap.valid, torch.from_numpy(~(codes == 255).any(axis=-1))[:, None])
    assert int((~real[0].valid).sum()) > 0 and bool(real[0].valid.any())  # the metal's highlights clip


def test_save_then_load_capture(real, tmp_path) -> None:
    cap = real[0]
    path = cap.save(tmp_path / "cap")
    spec, images, valid = load_capture(path)
    assert spec == cap.stated
    assert float((images - cap.images).abs().max()) < 1e-6 and torch.equal(valid, cap.valid)
    truth = json.loads((tmp_path / "cap" / "truth.json").read_text())
    assert truth["errors"] == cap.errors and truth["true"] == cap.true.to_dict()
    assert set(cap.errors) == set(ERROR_FIELDS)
    assert (tmp_path / "cap" / "truth" / "material.json").is_file()


def test_heldout_error_measures_the_material(real) -> None:
    cap = real[1]
    assert cap.heldout_error(cap.maps) == 0.0
    worse = cap.maps.clone()
    worse[:, 6:7] = (worse[:, 6:7] + 0.2).clamp(max=1.0)  # roughness
    assert cap.heldout_error(worse) > 0.005
    assert cap.map_errors(worse)["roughness"] > 0.05 and cap.map_errors(worse)["diffuse"] == 0.0
    other = _set(n_images=(2,)).capture(cap.material, 2)
    assert torch.equal(other.heldout.light, cap.heldout.light)  # the same views at every N
    assert cap.heldout.light.shape == (8, 3) and cap.heldout.view.shape == (8, 3)
    for p in (cap.heldout.light, cap.heldout.view):
        elevation = torch.rad2deg(torch.asin(p[:, 2] / p.norm(dim=1)))
        assert bool(((elevation >= 30 - 1e-4) & (elevation <= 80 + 1e-4)).all())
    with pytest.raises(ValueError, match="expected shape"):
        cap.heldout_error(cap.maps[:, :, :8, :8])


def test_bad_settings() -> None:
    for kw, name in (({"split": "train"}, "split"), ({"realism": "noisy"}, "realism"),
                     ({"n_images": (0,)}, "n_images"), ({"materials": 0}, "materials"), ({"size": 4}, "size")):
        with pytest.raises(ValueError, match=f"{name}: expected"):
            RealisticSet(**kw)
    with pytest.raises(ValueError, match="m: expected"):
        RealisticSet(cache=False).capture(-1, 3)
    assert RANGES["jpeg_quality"] == (70, 95) and dataclasses.is_dataclass(RealisticSet)


def test_doctests() -> None:
    assert doctest.testmod(realistic).failed == 0
