"""Training data of the large-scale network (thesis ch. 5.1.4): determinism, what a sample is made of,
the ambient photo's camera, the exemplar input, the held-out variant, bad settings."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.ambient import Environment, render_environment, sample_environment
from mi_svbrdf.data import augment, procedural
from mi_svbrdf.data.parameter_split import is_held_out
from mi_svbrdf.data.large_scale import (
    DEFAULT_EXEMPLAR_LIGHT,
    LargeScaleConfig,
    LargeScaleData,
    LargeScaleHeldOut,
    camera,
    exemplar_input,
    white_level,
)
from mi_svbrdf.io.material_io import srgb_encode

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = {"size": 32, "material_size": 80, "crop": (32, 64), "exemplar_size": 16, "batch_size": 2, "n_lights": 4,
        "pool_size": 3}


def _data(**kw: object) -> LargeScaleData:
    return LargeScaleData(LargeScaleConfig.from_dict({**TINY, **kw}))


def _equal(a, b) -> bool:
    return all(torch.equal(getattr(a, k), getattr(b, k)) for k in ("photo", "exemplars", "maps", "exemplar_maps"))


def test_batch_i_is_a_pure_function_of_seed_and_i() -> None:
    first = _data()
    seen = [first.batch(i) for i in range(4)]  # fills and slides the material pool
    again = _data().batch(3)  # a fresh stream, straight to batch 3
    assert _equal(seen[3], again) and seen[3].materials == again.materials
    assert not torch.equal(seen[2].photo, seen[3].photo)
    assert not torch.equal(_data(seed=1).batch(3).maps, again.maps)
    assert [first.exemplar_count(i) for i in range(4)] == [b.n_exemplars for b in seen]


def test_shapes_ranges_and_valid_targets() -> None:
    data = _data(no_exemplar=0.0, n_exemplars=(3, 3))
    b = data.batch(0)
    assert b.photo.shape == (2, 3, 32, 32) and b.maps.shape == (2, 10, 32, 32)
    assert b.exemplars.shape == (2, 3, 13, 16, 16) and b.exemplar_maps.shape == (2, 3, 10, 16, 16)
    for maps in (b.maps, b.exemplar_maps.flatten(0, 1), b.exemplars[:, :, :10].flatten(0, 1)):
        M.check_maps(maps)
        assert torch.allclose(M.normal(maps).norm(dim=1), torch.ones(1), atol=1e-5)
        assert 0 <= float(maps[:, 3:].min()) and float(maps[:, 3:].max()) <= 1
    assert 0 <= float(b.photo.min()) and float(b.photo.max()) <= 1 and float(b.photo.mean()) > 0.02
    assert bool((b.exemplars[:, :, 10:] >= 0).all())  # the exemplar renders
    # what E is: 0 with probability no_exemplar, else uniform in n_exemplars
    counts = np.array([LargeScaleData(LargeScaleConfig(no_exemplar=0.2)).exemplar_count(i) for i in range(400)])
    assert set(counts) == {0, 1, 2, 3} and 0.14 < float((counts == 0).mean()) < 0.26
    assert _data(no_exemplar=1.0).batch(0).exemplars.shape == (2, 0, 13, 16, 16)


def test_photo_is_8_bit_srgb() -> None:
    photo = _data().batch(1).photo
    codes = srgb_encode(photo.numpy()) * 255.0
    assert np.abs(codes - np.round(codes)).max() < 2e-3
    assert len(np.unique(np.round(codes))) > 20  # not a constant image


def test_crop_and_exemplars_are_cut_from_one_blended_material() -> None:
    """Rebuild sample 0 from its description: the target is the blend's crop resized, the exemplars
    are the blend at their corners (texel for texel)."""
    data = _data(no_exemplar=0.0, n_exemplars=(2, 2), pool_size=0)
    b = data.make(1, 2, torch.Generator().manual_seed(5))
    info = b.materials[0]
    a, c = (procedural.generate(s["class"], s["seed"], 80, **s["params"])[None] for s in info["materials"])
    blend = augment.mix(a, c, info["alpha"])
    crop = info["crop"]
    window = blend[:, :, crop["top"]:crop["top"] + crop["side"], crop["left"]:crop["left"] + crop["side"]]
    assert torch.allclose(b.maps, augment.transform_maps(window, scale=32 / crop["side"], out_size=32), atol=1e-5)
    for k, corner in enumerate(info["exemplars"]):
        patch = blend[0, :, corner["top"]:corner["top"] + 16, corner["left"]:corner["left"] + 16]
        assert torch.allclose(b.exemplar_maps[0, k], patch, atol=1e-6)
    assert 32 <= crop["side"] <= 64 and 0.1 <= info["alpha"] <= 0.9


def test_camera_white_balances_and_exposes_a_white_sample() -> None:
    """Without noise or white-balance error, a white Lambertian sample comes out grey at the exposure
    level (within 8-bit quantisation), whatever the environment's colour and brightness."""
    env = sample_environment(3, 16, generator=torch.Generator().manual_seed(0))
    white = M.constant_maps(3, 8, 8, diffuse=1.0, specular=0.0, roughness=1.0)
    radiance = render_environment(white, env, backend="torch")
    assert torch.allclose(radiance.mean(dim=(2, 3)), white_level(env), rtol=0.01)  # up to the Fresnel term
    photo, settings = camera(radiance, env, torch.Generator().manual_seed(1), exposure=(0.4, 0.8), white_balance=0.0,
                             noise_median=0.0, noise_log_std=0.3)
    level = photo.mean(dim=(2, 3))
    assert float((level - level.mean(dim=1, keepdim=True)).abs().max()) < 0.01  # grey
    assert bool(((level > 0.39) & (level < 0.81)).all())
    spread = level[:, 0].max() / level[:, 0].min()
    assert spread > 1.01  # three exposures drawn, not one
    assert torch.equal(settings["noise_std"], torch.zeros(3))


def test_exemplar_input_renders_under_a_distant_light() -> None:
    white = M.constant_maps(2, 8, 8, diffuse=1.0, specular=0.0, roughness=1.0)
    tilt = math.radians(60.0)
    x = exemplar_input(white, light=torch.tensor([math.sin(tilt), 0.0, math.cos(tilt)]))
    assert x.shape == (2, 13, 8, 8) and torch.equal(x[:, :10], white)
    assert torch.allclose(x[:, 10:], torch.full_like(x[:, 10:], 0.5), atol=5e-3)  # cos 60 (Fresnel at s=0: ~0.1 %)
    # (B, E) layout, a light per exemplar, the fixed inference light, random lights from a generator
    maps = M.constant_maps(6, 8, 8, diffuse=0.5, roughness=0.4).view(2, 3, 10, 8, 8)
    lights = torch.tensor([0.0, 0.0, 1.0]).expand(2, 3, 3)
    assert exemplar_input(maps, light=lights).shape == (2, 3, 13, 8, 8)
    fixed = exemplar_input(maps)
    assert torch.allclose(fixed, exemplar_input(maps, light=torch.tensor(DEFAULT_EXEMPLAR_LIGHT)))
    r1 = exemplar_input(maps, generator=torch.Generator().manual_seed(0))
    assert torch.equal(r1, exemplar_input(maps, generator=torch.Generator().manual_seed(0)))
    assert not torch.allclose(r1[0, 0, 10:], r1[0, 1, 10:])  # each exemplar its own light
    assert exemplar_input(maps[:, :0]).shape == (2, 0, 13, 8, 8)
    for call, message in [(lambda: exemplar_input(maps[..., :9, :, :]), "maps: expected shape"),
                          (lambda: exemplar_input(maps, light=torch.tensor([0.0, 0.0, -1.0])),
                           "light: expected finite"),
                          (lambda: exemplar_input(maps, light=torch.ones(3, 3)), "light: expected shape")]:
        with pytest.raises(ValueError, match=message):
            call()


def test_held_out_samples_differ_from_training_ones(tmp_path: Path) -> None:
    settings = {k: v for k, v in TINY.items() if k in ("material_size", "crop", "exemplar_size", "n_lights")}
    held = LargeScaleHeldOut(size=32, materials=3, n_exemplars=2, data=settings, cache_dir=str(tmp_path))
    maps, photo, exemplars = held.load(progress=False)
    assert maps.shape == (3, 10, 32, 32) and photo.shape == (3, 3, 32, 32) and exemplars.shape == (3, 2, 13, 16, 16)
    assert held.path().is_file()
    again = held.load(progress=False)  # from the cache, identical
    assert torch.equal(again[1], photo)
    prefix = LargeScaleHeldOut(size=32, materials=2, n_exemplars=2, data=settings, cache=False).load(progress=False)
    assert torch.equal(prefix[0], maps[:2])  # sample m does not depend on the set's size
    held_specs = [s for d in held.info(progress=False) for s in d["materials"]]
    assert all(is_held_out(s["class"], s["params"]) for s in held_specs)  # only the held-out slices
    train_specs = [s for i in range(3) for d in _data().batch(i).materials for s in d["materials"]]
    assert not any(is_held_out(s["class"], s["params"]) for s in train_specs)  # training never draws them
    assert [d["materials"][0]["class"] for d in held.info(progress=False)] == ["paint", "plastic", "leather"]


def test_doctests() -> None:
    import doctest

    from mi_svbrdf.data import large_scale

    assert doctest.testmod(large_scale).failed == 0


def test_bad_settings_name_the_field() -> None:
    cases = [({"crop": (32, 100)}, "LargeScaleConfig.crop"), ({"exemplar_size": 81}, "LargeScaleConfig.exemplar_size"),
             ({"n_exemplars": (0, 3)}, "LargeScaleConfig.n_exemplars"), ({"no_exemplar": 1.5}, "no_exemplar"),
             ({"holdout": "all"}, "LargeScaleConfig.holdout"), ({"classes": ["brick"]}, "LargeScaleConfig.classes"),
             ({"exposure": (0.0, 1.0)}, "LargeScaleConfig.exposure"), ({"sizee": 3}, "unknown keys"),
             ({"ambient": {"white_levle": 1.0}}, "AmbientConfig: unknown keys")]
    for override, message in cases:
        with pytest.raises(ValueError, match=message):
            LargeScaleConfig.from_dict({**TINY, **override})
    with pytest.raises(ValueError, match="LargeScaleHeldOut.data"):
        LargeScaleHeldOut(data={"holdout": "train"})
    with pytest.raises(ValueError, match="LargeScaleHeldOut.seed"):
        LargeScaleHeldOut(seed=3)
    with pytest.raises(ValueError, match="index: expected an int >= 0"):
        _data().batch(-1)
    env = Environment(directions=torch.tensor([[[0.0, 0.0, 1.0]]]), intensities=torch.ones(1, 1, 3))
    assert torch.allclose(white_level(env), torch.ones(1, 3))
