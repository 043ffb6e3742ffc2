"""Failure cases: every case generated and perturbed as named; the anisotropic plugin; the Mitsuba path."""
from __future__ import annotations

import functools

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
import torch

from mi_svbrdf import plugins, scenes
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.colour import GAMMA
from mi_svbrdf.data.photo_setups import render_captures, sample_captures
from mi_svbrdf.eval import failure_cases as F
from tests.conftest import random_maps

#: Mitsuba objects made in these tests are bound to the active variant: the CPU's (tests/conftest.py).
pytestmark = pytest.mark.usefixtures("cpu_scene_variant")

SIZE, N = 32, 3


@functools.lru_cache(maxsize=1)
def all_cases(size: int = SIZE, n: int = N) -> dict[str, F.Case]:
    """Every case at ``size``, seed 0, generated once per session (tests/test_stability.py uses them too)."""
    return {name: F.make_case(name, size, n, seed=0) for name in F.CASES}


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread(one_torch_thread):
    """Every test here runs with one torch thread (see tests/conftest.py)."""

@pytest.fixture(scope="module")
def cases() -> dict[str, F.Case]:
    return all_cases(SIZE, N)


def test_every_case_has_shapes_finite_photos_and_a_clean_twin(cases: dict[str, F.Case]) -> None:
    assert sorted(cases) == sorted(["saturated_highlight", "dark_material", "near_mirror", "clear_coat_print",
                                    "anisotropic_brushed_metal", "cast_shadows", "non_uniform_ambient", "jpeg",
                                    "noisy", "wrong_gamma"])
    for name, case in cases.items():
        for c in (case, case.clean):
            assert c.name == name
            assert c.maps.shape == (1, 10, SIZE, SIZE) and c.inputs.shape == (1, N, 3, SIZE, SIZE), name
            assert (c.captures.batch_size, c.captures.n_images) == (1, N)
            assert torch.isfinite(c.inputs).all() and torch.isfinite(c.maps).all(), name
            assert c.inputs.min() >= 0 and c.inputs.max() <= 1, name
            n = M.normal(c.maps)
            assert torch.allclose(n.norm(dim=1), torch.ones(1), atol=1e-4), name
            for m in (M.diffuse(c.maps), M.roughness(c.maps), M.specular(c.maps)):
                assert (m >= 0).all() and (m <= 1).all(), name
        assert case.clean.clean is None
        change = (case.inputs - case.clean.inputs).abs().mean()
        assert change > 2e-3, f"{name}: the perturbation does not change the photos ({float(change)})"
        # image 0 is the fronto-parallel flash photo
        assert case.captures.view[0, 0, 2] > 2.0 and case.captures.light[0, 0, 2] > 2.0


def test_each_perturbation_is_what_its_name_says(cases: dict[str, F.Case]) -> None:
    c = cases["saturated_highlight"]
    assert torch.allclose(c.captures.intensity, 8 * c.clean.captures.intensity)
    assert (c.inputs >= 0.999).float().mean() > 2 * (c.clean.inputs >= 0.999).float().mean() + 0.05
    assert M.diffuse(cases["dark_material"].maps).max() <= 0.05 + 1e-6
    assert M.diffuse(cases["dark_material"].clean.maps).max() > 0.2
    r = M.roughness(cases["near_mirror"].maps)
    assert r.min() >= 0.02 - 1e-6 and r.max() <= 0.05 + 1e-6
    cc = cases["clear_coat_print"]
    assert torch.equal(M.normal(cc.maps), M.normal(cc.clean.maps)) and M.diffuse(cc.clean.maps).std(dim=(2, 3)).max() == 0
    for name in ("anisotropic_brushed_metal", "cast_shadows", "non_uniform_ambient", "jpeg", "wrong_gamma"):
        assert torch.equal(cases[name].maps, cases[name].clean.maps), name
    # Studs: normals tilt at their sides; shadows darken some texels well below the flat rendering.
    shadows = cases["cast_shadows"]
    assert (M.normal(shadows.maps)[:, 2] < 0.8).any()
    assert ((shadows.inputs < 0.5 * shadows.clean.inputs) & (shadows.clean.inputs > 0.02)).float().mean() > 0.005
    # The area light only adds light.
    amb = cases["non_uniform_ambient"]
    assert amb.inputs.mean() > amb.clean.inputs.mean() * 1.05
    assert torch.equal(cases["wrong_gamma"].inputs, cases["wrong_gamma"].clean.inputs ** (1.0 / GAMMA))
    assert cases["noisy"].captures.noise_std.item() == pytest.approx(0.05)
    jpeg = cases["jpeg"]
    assert 0 < (jpeg.inputs - jpeg.clean.inputs).abs().mean() < 0.05


def test_generation_is_deterministic() -> None:
    a, b = F.make_case("cast_shadows", 16, 2, seed=3), F.make_case("cast_shadows", 16, 2, seed=3)
    assert torch.equal(a.inputs, b.inputs) and torch.equal(a.maps, b.maps)
    assert torch.equal(F.clean_case("cast_shadows", 16, 2, seed=3).inputs, a.clean.inputs)
    assert not torch.equal(F.make_case("cast_shadows", 16, 2, seed=4).inputs, a.inputs)


def test_bad_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="name: expected one of"):
        F.make_case("glitter")
    with pytest.raises(ValueError, match="size: expected"):
        F.make_case("noisy", size=4)


def test_mitsuba_rectified_path_equals_texel_path() -> None:
    maps = random_maps(1, 16, 16, seed=2, rough_range=(0.1, 1.0), max_tilt=0.8)
    cap = sample_captures(1, 3, "multiview", torch.Generator().manual_seed(5))
    mitsuba = F.mitsuba_radiance(F.plane(scenes.material_bsdf(maps, filter_type="nearest")), cap, 16)
    texel = render_captures(maps, cap, backend="torch")
    assert ((mitsuba - texel).abs() / (texel.abs() + 1e-3)).max() < 1e-3
    flipped = mitsuba.flip(-1)
    assert ((flipped - texel).abs() / (texel.abs() + 1e-3)).mean() > 0.05  # orientation matters: the test can fail


def _random_directions(rng: np.random.Generator, n: int) -> mi.Vector3f:
    v = rng.normal(size=(3, n))
    v[2] = np.abs(v[2]) + 0.05
    return mi.Vector3f(v / np.linalg.norm(v, axis=0))


def test_anisotropic_plugin_reduces_to_isotropic_with_equal_roughness() -> None:
    plugins.register()
    rng = np.random.default_rng(0)
    n = 4000
    common = {"diffuse": {"type": "rgb", "value": [0.3, 0.5, 0.2]}, "specular": {"type": "rgb", "value": [0.1, 0.2, 0.05]},
              "normal": {"type": "rgb", "value": [0.62, 0.43, 0.9]}}
    ctx = mi.BSDFContext()
    for r in (0.05, 0.3, 0.8):
        iso = mi.load_dict({"type": "svbrdf_ggx", "roughness": r, **common})
        ani = mi.load_dict({"type": "svbrdf_aniso", "roughness_u": r, "roughness_v": r, **common})
        stretched = mi.load_dict({"type": "svbrdf_aniso", "roughness_u": min(1.0, 2 * r), "roughness_v": r / 2, **common})
        inter = _interaction(rng, n)
        wo = _random_directions(rng, n)
        a, b = np.array(iso.eval(ctx, inter, wo)), np.array(ani.eval(ctx, inter, wo))
        assert np.abs(a).max() > 0.1
        assert np.abs(a - b).max() <= 1e-4 * np.abs(a).max() + 1e-6, r
        c = np.array(stretched.eval(ctx, inter, wo))
        assert np.abs(a - c).max() > 0.05 * np.abs(a).max(), r  # anisotropy changes the value
        # sampling weights are eval / pdf and finite
        bs, weight = stretched.sample(ctx, inter, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
        value, pdf = np.array(stretched.eval(ctx, inter, bs.wo)), np.array(stretched.pdf(ctx, inter, bs.wo))
        ok = np.array(bs.pdf) > 0
        assert ok.mean() > 0.5 and np.isfinite(np.array(weight)).all()
        assert np.allclose(np.array(weight)[:, ok], value[:, ok] / pdf[ok], rtol=1e-3, atol=1e-5)


def _interaction(rng: np.random.Generator, n: int) -> mi.SurfaceInteraction3f:
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = _random_directions(rng, n)
    si.uv = mi.Point2f(0.5, 0.5)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    return si


def test_anisotropic_highlight_is_stretched_across_the_brushing() -> None:
    """r_u > r_v widens the lobe along the tangent (x): tilting h towards x loses less than towards y."""
    plugins.register()
    bsdf = mi.load_dict({"type": "svbrdf_aniso", "roughness_u": 0.6, "roughness_v": 0.2, "specular": {"type": "rgb", "value": 0.5},
                         "diffuse": {"type": "rgb", "value": 0.0}})
    si = dr.zeros(mi.SurfaceInteraction3f, 2)
    si.wi = mi.Vector3f(0.0, 0.0, 1.0)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    t = 0.4
    wo = mi.Vector3f([np.sin(t), 0.0], [0.0, np.sin(t)], [np.cos(t), np.cos(t)])
    value = np.array(bsdf.eval(mi.BSDFContext(), si, wo))[0]
    assert value[0] > 3 * value[1]
