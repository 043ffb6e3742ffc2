"""The realistic captures (mi_svbrdf.data.realistic): deterministic, split, the injected errors as stated,
the clean twin exact, the photos decoded as load_capture decodes them, the held-out error."""
from __future__ import annotations

import doctest
import math

import numpy as np
import pytest
import torch

from mi_svbrdf.data import realistic
from mi_svbrdf.data.realistic import MM_PER_UNIT, RealisticSet
from mi_svbrdf.io.calibrated_photos import camera_frame, load_capture
from mi_svbrdf.io.material_io import srgb_encode
from mi_svbrdf.optim.forward import TexelForward

SIZE = 48


@pytest.fixture(scope="module")
def real():
    return RealisticSet(split="tune", size=SIZE, materials=2, n_images=(5,), cache=False).captures(progress=False)


@pytest.fixture(scope="module")
def clean():
    return RealisticSet(split="tune", size=SIZE, materials=2, n_images=(5,), realism="clean",
                        cache=False).captures(progress=False)


def test_deterministic_and_splits_differ(real):
    again = RealisticSet(split="tune", size=SIZE, materials=2, n_images=(5,), cache=False).captures(progress=False)
    assert all(torch.equal(a.images, b.images) and a.stated == b.stated for a, b in zip(real, again))
    test = RealisticSet(split="test", size=SIZE, materials=1, n_images=(5,), cache=False).capture(0, 5)
    assert not torch.equal(test.maps, real[0].maps) or test.stated != real[0].stated


def test_gains_pinned_and_within_range(real):
    for cap in real:
        gains = torch.tensor(cap.errors["gains"])
        assert torch.allclose(gains.log().mean(dim=0), torch.zeros(3), atol=1e-6)
        assert float(gains.max() / gains.min()) <= 2 ** 1.4 * 1.1 / 0.9 + 1e-6
        intensities = torch.tensor([im.light.intensity for im in cap.true.images])
        stated = torch.tensor([im.light.intensity for im in cap.stated.images])
        assert torch.allclose(intensities / stated, gains, rtol=1e-5)


def test_flash_offset_shared_in_the_camera_frame_and_poses_within_3_percent(real):
    for cap in real:
        cams = torch.tensor([im.camera.position for im in cap.true.images], dtype=torch.float64)
        lights = torch.tensor([im.light.position for im in cap.true.images], dtype=torch.float64)
        right, up, forward = camera_frame(cams)
        local = torch.stack([((lights - cams) * a).sum(-1) for a in (right, up, forward)], dim=1)
        assert torch.allclose(local, local[:1].expand_as(local), atol=1e-5)  # one offset for every photo
        assert 5.0 - 1e-3 <= float(local[0].norm()) * MM_PER_UNIT <= 25.0 + 1e-3
        said = torch.tensor([im.camera.position for im in cap.stated.images], dtype=torch.float64)
        said_light = torch.tensor([im.light.position for im in cap.stated.images], dtype=torch.float64)
        assert torch.equal(said, said_light)  # the user states the flash at the camera
        assert bool(((said - cams).norm(dim=1) <= 0.03 * cams.norm(dim=1) + 1e-6).all())


def test_clean_twin_is_its_stated_calibration(clean, real):
    for cap, twin in zip(clean, real):
        assert torch.equal(cap.maps, twin.maps)
        assert [im.camera.position for im in cap.true.images] == [im.camera.position for im in twin.true.images]
        with torch.no_grad():
            render = TexelForward(cap.stated, SIZE)(cap.maps).clamp(0, 1)
        ok = cap.valid.expand_as(render)
        assert float((render - cap.images)[ok].square().mean().sqrt()) < 0.01  # 8 bits and noise only


def test_real_photos_disagree_with_their_stated_calibration(real):
    for cap in real:
        with torch.no_grad():
            stated = TexelForward(cap.stated, SIZE)(cap.maps).clamp(0, 1)
            true = TexelForward(cap.true, SIZE)(cap.maps).clamp(0, 1)
        ok = cap.valid.expand_as(stated)
        err_stated = float((stated - cap.images)[ok].square().mean().sqrt())
        err_true = float((true - cap.images)[ok].square().mean().sqrt())
        assert err_true < err_stated and err_stated > 0.01


def test_valid_marks_saturated_channels(real):
    for cap in real:
        codes = np.round(srgb_encode(cap.images.permute(0, 2, 3, 1).double().numpy()) * 255.0)
        expect = torch.from_numpy((codes < 255).all(axis=-1))[:, None]
        assert torch.equal(cap.valid, expect)


def test_save_then_load_capture(real, tmp_path):
    cap = real[0]
    path = cap.save(tmp_path / "cap")
    spec, images, valid = load_capture(path)
    assert spec.images == cap.stated.images
    assert float((images - cap.images).abs().max()) < 1e-6
    assert torch.equal(valid, cap.valid)
    assert (tmp_path / "cap" / "truth.json").is_file()


def test_heldout_error(real):
    cap = real[0]
    assert cap.heldout_error(cap.maps) == 0.0
    worse = cap.maps.clone()
    worse[:, 6:7] = (worse[:, 6:7] + 0.3).clamp(max=1.0)
    assert cap.heldout_error(worse) > 0.005
    assert math.isfinite(cap.heldout_error(worse))


def test_bad_settings():
    with pytest.raises(ValueError, match="split"):
        RealisticSet(split="train")
    with pytest.raises(ValueError, match="realism"):
        RealisticSet(realism="noisy")
    with pytest.raises(ValueError, match="n_images"):
        RealisticSet(n_images=(0,))


def test_doctests():
    assert doctest.testmod(realistic).failed == 0
