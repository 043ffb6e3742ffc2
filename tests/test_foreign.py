"""The foreign-capture set: every capture parameter outside the training ranges, deterministic, a prefix."""
from __future__ import annotations

import hashlib
import json
import math

import pytest
import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.data import foreign as F
from mi_svbrdf.data.parameter_split import is_held_out
from mi_svbrdf.data.photo_setups import capture_config
from mi_svbrdf.data.simulator import SimulatorConfig
from mi_svbrdf.nets.train import RECIPES, load_config

TRAIN = F.training_ranges()


def test_foreign_ranges_are_disjoint_from_the_training_ranges() -> None:
    assert set(F.FOREIGN_RANGES) == set(TRAIN)
    for name, r in F.FOREIGN_RANGES.items():
        assert not F.overlaps(r, TRAIN[name]), (name, r, TRAIN[name])
    # the documented training figures (module docstring) are what the presets give
    assert TRAIN["fov"] == (30.0, 55.0) and TRAIN["extra_lights"] == (0, 1, 3) and TRAIN["jpeg_quality"] == ()
    assert TRAIN["light_distance"][0] == pytest.approx(1.921, abs=1e-3)
    assert TRAIN["flash_rgb"] == pytest.approx((1.599, 116.5), abs=1e-2)
    # the foreign material parameters are outside every training class's range
    for name, (param, r, train) in F.MATERIAL_RANGES.items():
        assert not any(F.overlaps(r, t) for t in train), name


# (the large-scale recipes train on ambient photos of procedural surfaces, mi_svbrdf.data.large_scale, not on captures)
@pytest.mark.parametrize("recipe", sorted(r for r in RECIPES if RECIPES[r].get("kind") != "large"))
def test_every_training_recipe_stays_outside_the_foreign_ranges(recipe: str) -> None:
    """A recipe may broaden the simulator (captures, reliefs, scales) but never into the foreign set."""
    sim = SimulatorConfig.from_dict({"holdout": "train", **load_config(recipe).simulator})
    train = F.training_ranges(configs=[sim.capture_config])
    overlapping = {k: (train[k], F.FOREIGN_RANGES[k]) for k in F.FOREIGN_RANGES if F.overlaps(F.FOREIGN_RANGES[k], train[k])}
    assert not overlapping, f"{recipe}: {overlapping}"
    slope = F.MATERIAL_RANGES["embossed_leather"][1]
    assert not F.overlaps(slope, tuple(sim.normal_strength)), f"{recipe}: normal_strength {sim.normal_strength}"
    lo, hi = sim.specular_scale
    for cls in ("glazed_tiles", "anodised_metal"):  # the classes' specular ranges, scaled
        scaled = [(a * lo, min(1.0, b * hi)) for a, b in F.MATERIAL_RANGES[cls][2]]
        assert not any(F.overlaps(F.MATERIAL_RANGES[cls][1], r) for r in scaled), f"{recipe}: {cls} {scaled}"
    weave = F.MATERIAL_RANGES["micro_weave"][1]
    assert not F.overlaps(weave, tuple(sim.scale)), f"{recipe}: scale {sim.scale}"


def test_training_ranges_include_given_configs() -> None:
    wide = capture_config("multiview", ambient_min_elevation=5.0)
    assert F.overlaps(F.FOREIGN_RANGES["extra_elevation"], F.training_ranges(configs=[wide])["extra_elevation"])


def test_overlaps_reads_intervals_unions_and_sets() -> None:
    assert F.overlaps((0.0, 1.0), (1.0, 2.0)) and not F.overlaps((0.0, 1.0), (1.01, 2.0))
    assert F.overlaps(((0.0, 0.1), (0.9, 1.0)), (0.95, 2.0)) and not F.overlaps(((0.0, 0.1), (0.9, 1.0)), (0.2, 0.8))
    assert not F.overlaps((2,), (0, 1, 3)) and F.overlaps((1,), (0, 1, 3)) and not F.overlaps((40, 75), ())


def _outside(value: float, name: str) -> None:
    assert F.within(value, F.FOREIGN_RANGES[name]), (name, value, F.FOREIGN_RANGES[name])
    assert not F.within(value, TRAIN[name]), (name, value, TRAIN[name])


def test_no_draw_falls_in_a_training_range() -> None:
    """Property test: 400 samples x 5 photos, every parameter and every Captures value."""
    for b in range(400):
        sample = F.draw_sample(F._generator(99, b, 0))
        images = [F.draw_image(F._generator(99, b, 1, k), k == 0) for k in range(5)]
        cap = F.foreign_captures(sample, images)
        _outside(sample["noise_std"], "noise_std")
        _outside(float(cap.noise_std[0]), "noise_std")
        assert cap.ambient_light.shape[1] in F.FOREIGN_RANGES["extra_lights"]
        assert cap.ambient_light.shape[1] not in TRAIN["extra_lights"]
        for a in range(cap.ambient_light.shape[1]):
            pos = cap.ambient_light[0, a]
            _outside(float(pos.norm()), "extra_distance")
            _outside(math.degrees(math.asin(float(pos[2] / pos.norm()))), "extra_elevation")
            for v in cap.ambient_intensity[0, a].tolist():
                _outside(v, "extra_rgb")
        for k, im in enumerate(images):
            _outside(float(cap.fov[0, k]), "fov")
            _outside(float(cap.distance[0, k]), "camera_distance")
            _outside(float(cap.light[0, k].norm()), "light_distance")
            _outside(im["light_angle"], "light_angle")
            view, light = cap.view[0, k], cap.light[0, k]
            angle = math.degrees(math.acos(float((view @ light) / (view.norm() * light.norm()))))
            _outside(angle, "light_angle")
            assert float(light[2]) > 0.1 and float(view[2]) > 0.1
            if k == 0:
                _outside(float(view[:2].abs().max()), "view_offset")
            _outside(im["flash_intensity"], "flash_intensity")
            for w, v in zip(im["white_balance"], cap.intensity[0, k].tolist()):
                _outside(w, "white_balance")
                _outside(v, "flash_rgb")
            _outside(float(cap.cone_exponent[0, k]), "cone_exponent")
            _outside(float(cap.cone_target[0, k, :2].abs().max()), "cone_target")
            assert F.within(im["jpeg_quality"], F.FOREIGN_RANGES["jpeg_quality"])


def test_materials_are_of_held_out_slices_and_foreign_ranges() -> None:
    for i in range(12):
        for cls, base in F.FOREIGN_CLASSES.items():
            maps, info = F.foreign_material(cls, 16, F._generator(7, i, 0))
            assert maps.shape == (1, 10, 16, 16) and bool(torch.isfinite(maps).all())
            assert torch.allclose(M.normal(maps).norm(dim=1), torch.ones(1, 16, 16), atol=1e-4)
            assert info["base"] == base and is_held_out(base, info["params"])
            param, (lo, hi), train = F.MATERIAL_RANGES[cls]
            assert lo <= info[param] <= hi and not any(F.within(info[param], t) for t in train)
            spec = M.specular(maps)
            if cls == "glazed_tiles":
                assert torch.allclose(spec, torch.full_like(spec, info[param]))
            elif cls == "anodised_metal":
                assert float(spec.amax()) == pytest.approx(info[param], rel=1e-5)
                assert float(spec.amin()) > 0.08  # not a dielectric's
                assert float(M.diffuse(maps).amax()) == pytest.approx(info["dye_value"], rel=1e-5)
                assert info["dye_value"] > 0.05  # not a metal's


def test_set_is_deterministic_cached_and_a_prefix(tmp_path: object) -> None:
    big = F.ForeignSet(size=16, materials=3, n_images=3, cache=True, cache_dir=str(tmp_path))
    maps, inputs, cap = big.load(progress=False)
    assert maps.shape == (3, 10, 16, 16) and inputs.shape == (3, 3, 3, 16, 16) and cap.n_images == 3
    assert bool(torch.isfinite(inputs).all()) and 0 <= float(inputs.min()) and float(inputs.max()) <= 1
    assert big.path().is_file()
    again = F.ForeignSet(size=16, materials=3, n_images=3, cache=False)
    m2, i2, c2 = again.load(progress=False)
    assert torch.equal(maps, m2) and torch.equal(inputs, i2) and torch.equal(cap.light, c2.light)
    small = F.ForeignSet(size=16, materials=2, n_images=2, cache=False)
    m3, i3, c3 = small.load(progress=False)
    assert torch.equal(m3, maps[:2]) and torch.equal(i3, inputs[:2, :2])
    assert torch.equal(c3.view, cap.view[:2, :2]) and torch.equal(c3.ambient_light, cap.ambient_light[:2])
    assert [d["class"] for d in big.info(progress=False)] == big.classes() == list(F.FOREIGN_CLASSES)[:3]
    assert big.key() != small.key()


def test_bad_settings_are_named() -> None:
    with pytest.raises(ValueError, match="seed: expected an int >= 1000"):
        F.ForeignSet(seed=3)
    with pytest.raises(ValueError, match="n_images"):
        F.ForeignSet(n_images=0)
    with pytest.raises(ValueError, match="cls: expected one of"):
        F.foreign_material("paint", 16, torch.Generator())


# ----------------------------------------------------------------------------- the "lights" regime
#: ForeignSet().key() before the regimes existed (the key hashes the torch version: checked on this one).
DEFAULT_KEY, DEFAULT_KEY_TORCH = "f9804d4d3dd80432", "2.13.0"


def test_default_regime_keeps_its_cache_key_and_file_name() -> None:
    default = F.ForeignSet()
    assert F.REGIMES == ("flash", "lights") and default.regime == "flash"
    # the key of every setting but the regime, as computed before the regimes existed
    settings = {"size": 256, "materials": 16, "n_images": 10, "seed": F.FOREIGN_SEED, "backend": "mitsuba",
                "version": F.VERSION, "ranges": repr(F.FOREIGN_RANGES), "materials_ranges": repr(F.MATERIAL_RANGES),
                "torch": torch.__version__.split("+")[0]}
    assert default.key() == hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:16]
    if settings["torch"] == DEFAULT_KEY_TORCH:
        assert default.key() == DEFAULT_KEY
    assert default.path().name == f"foreign_256px_16m_10n_{default.key()}.pt"
    lights = F.ForeignSet(regime="lights")
    assert lights.key() != default.key() and lights.path().name == f"foreign_256px_16m_10n_lights_{lights.key()}.pt"


def test_lights_regime_draws() -> None:
    """Property test (no rendering): 300 samples x 4 photos of both regimes from the same generators."""
    for b in range(300):
        sample = F.draw_sample(F._generator(98, b, 0))
        flash = [F.draw_image(F._generator(98, b, 1, k), k == 0) for k in range(4)]
        lights = [F.draw_image(F._generator(98, b, 1, k), k == 0, regime="lights") for k in range(4)]
        json.dumps(lights)  # JSON-ready
        cap_f, cap_l = F.foreign_captures(sample, flash), F.foreign_captures(sample, lights)
        assert torch.equal(cap_l.light[0, 0], cap_l.view[0, 0])  # photo 0: a flash at the camera
        for field in ("view", "fov", "distance"):  # same cameras
            assert torch.equal(getattr(cap_l, field), getattr(cap_f, field)), field
        assert torch.equal(cap_l.intensity[0, 0], cap_f.intensity[0, 0])
        assert torch.equal(cap_l.cone_exponent[0, 0], cap_f.cone_exponent[0, 0])
        assert torch.equal(cap_l.cone_target[0, 0], cap_f.cone_target[0, 0])
        assert lights[0]["light_distance"] == pytest.approx(float(cap_l.view[0, 0].norm()), rel=1e-6)
        for k, (im_f, im_l) in enumerate(zip(flash, lights)):
            for key in ("fov", "distance", "view", "forward", "flash_intensity", "white_balance", "jpeg_quality"):
                assert im_l[key] == im_f[key], (k, key)
            if k == 0:
                continue
            assert 15.0 <= im_l["light_elevation"] <= 75.0 and 1.0 <= im_l["light_distance"] <= 3.0
            assert 0.0 <= im_l["light_azimuth"] < 2 * math.pi
            light = cap_l.light[0, k]
            assert float(light.norm()) == pytest.approx(im_l["light_distance"], rel=1e-5)
            assert math.degrees(math.asin(float(light[2] / light.norm()))) == pytest.approx(
                im_l["light_elevation"], abs=1e-3)
            assert float(cap_l.cone_exponent[0, k]) == 0.0  # isotropic
            scale = (im_l["light_distance"] / F.LIGHTS_REFERENCE_DISTANCE) ** 2
            assert torch.allclose(cap_l.intensity[0, k], cap_f.intensity[0, k] * scale, rtol=1e-6)


def test_lights_regime_set_shares_the_flash_cameras_and_is_a_prefix() -> None:
    flash = F.ForeignSet(size=16, materials=1, n_images=3, cache=False).material(0)
    small = F.ForeignSet(size=16, materials=1, n_images=3, cache=False, regime="lights").material(0)
    big = F.ForeignSet(size=16, materials=2, n_images=5, cache=False, regime="lights")
    maps, inputs, cap = big.load(progress=False)
    assert inputs.shape == (2, 5, 3, 16, 16) and bool(torch.isfinite(inputs).all())
    assert 0 <= float(inputs.min()) and float(inputs.max()) <= 1 and float(inputs.mean()) > 0.01
    # N = 3 is a prefix of N = 5, material 0 of a set of 2
    assert torch.equal(small["maps"], maps[:1]) and torch.equal(small["inputs"], inputs[:1, :3])
    assert torch.equal(small["captures"].light, cap.light[:1, :3])
    # same material, cameras and noise level as the flash regime, the room's lamps off; other lights, other photos
    c_f, c_l = flash["captures"], small["captures"]
    assert torch.equal(flash["maps"], small["maps"])
    for field in ("view", "fov", "distance", "ambient_light", "noise_std"):
        assert torch.equal(getattr(c_f, field), getattr(c_l, field)), field
    assert float(c_f.ambient_intensity.min()) > 0 and float(c_l.ambient_intensity.abs().max()) == 0
    assert torch.equal(c_l.light[0, 0], c_l.view[0, 0]) and not torch.equal(c_l.light, c_f.light)
    assert not torch.equal(flash["inputs"], small["inputs"])
    photos = small["info"]["capture"]["images"]
    assert all({"light_elevation", "light_azimuth", "light_distance"} <= set(im) for im in photos)
    assert not any("light_elevation" in im for im in flash["info"]["capture"]["images"])


def test_bad_regime_is_named() -> None:
    with pytest.raises(ValueError, match=r"regime: expected one of \('flash', 'lights'\), got 'ambient'"):
        F.ForeignSet(regime="ambient")
    with pytest.raises(ValueError, match="regime: expected one of"):
        F.draw_image(torch.Generator(), True, regime="calibrated")
