"""Evaluation metrics against hand-computed cases: RMSE of known maps, SSIM of identical images,
scale-invariant albedo error, re-rendering under a known light, the flat table dict."""
from __future__ import annotations

import math
from collections.abc import Callable

import pytest
import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.core import metrics


def test_map_rmse_of_known_constant_maps() -> None:
    gt = torch.cat([M.constant_maps(1, 8, 8, diffuse=0.5, roughness=0.5, specular=0.04),
                    M.constant_maps(1, 8, 8, diffuse=0.5, roughness=0.5, specular=0.04)])
    pred = torch.cat([M.constant_maps(1, 8, 8, normal=(1, 0, 0), diffuse=0.3, roughness=0.2, specular=0.1),
                      M.constant_maps(1, 8, 8, diffuse=(0.5, 0.5, 0.2), roughness=0.5, specular=0.04)])
    r = metrics.map_rmse(pred, gt)
    # normals as (n + 1) / 2: (1, .5, .5) vs (.5, .5, 1) -> sqrt((.25 + 0 + .25) / 3)
    assert r["normal"].tolist() == pytest.approx([math.sqrt(1 / 6), 0.0], abs=1e-6)
    assert r["diffuse"].tolist() == pytest.approx([0.2, math.sqrt(0.09 / 3)], abs=1e-6)
    assert r["roughness"].tolist() == pytest.approx([0.3, 0.0], abs=1e-6)
    assert r["specular"].tolist() == pytest.approx([0.06, 0.0], abs=1e-6)


def test_map_rmse_identical_is_zero_and_symmetric(maps_factory: Callable[..., torch.Tensor]) -> None:
    a, b = maps_factory(3, 16, 16, seed=1), maps_factory(3, 16, 16, seed=2)
    for v in metrics.map_rmse(a, a).values():
        assert torch.equal(v, torch.zeros(3))
    ab, ba = metrics.map_rmse(a, b), metrics.map_rmse(b, a)
    for k in M.MAP_NAMES:
        assert torch.allclose(ab[k], ba[k]) and bool((ab[k] > 0.05).all())


def test_scaled_albedo_rmse(maps_factory: Callable[..., torch.Tensor]) -> None:
    gt = maps_factory(2, 16, 16, seed=3)
    scaled = gt.clone()
    scaled[:, 3:6] *= torch.tensor([0.5, 1.7]).view(2, 1, 1, 1)
    scaled[:, 7:10] *= 0.3
    r = metrics.scaled_albedo_rmse(scaled, gt)
    assert r["diffuse"].tolist() == pytest.approx([0.0, 0.0], abs=1e-6)
    assert r["specular"].tolist() == pytest.approx([0.0, 0.0], abs=1e-6)
    assert float(metrics.map_rmse(scaled, gt)["diffuse"][0]) > 0.1  # the plain RMSE sees the scale
    # By hand: gt 0.5 everywhere, pred half 0.2 / half 0.4 -> k = <p, g> / <p, p> = 0.15 / 0.1 = 1.5,
    # k p = 0.3 / 0.6, errors 0.2 / 0.1 -> sqrt((0.04 + 0.01) / 2)
    g = M.constant_maps(1, 8, 8, diffuse=0.5)
    p = g.clone()
    p[:, 3:6, :4], p[:, 3:6, 4:] = 0.2, 0.4
    assert float(metrics.scaled_albedo_rmse(p, g)["diffuse"][0]) == pytest.approx(0.025**0.5, abs=1e-6)
    # A black prediction keeps the whole error (scale 0).
    p[:, 3:6] = 0.0
    assert float(metrics.scaled_albedo_rmse(p, g)["diffuse"][0]) == pytest.approx(0.5, abs=1e-6)


def test_rerender_rmse_scaled_forgives_an_exposure_only(maps_factory: Callable[..., torch.Tensor]) -> None:
    lights = metrics.eval_lights()
    gt = maps_factory(2, 16, 16, seed=6)
    same = metrics.rerender_rmse_scaled(gt, gt, lights, backend="torch")
    assert same.tolist() == pytest.approx([0.0, 0.0], abs=1e-6)
    # Both albedos of a dielectric scaled per channel (what an unknown exposure and white balance
    # leave): the plain error sees it, the scaled one all but forgives it (Fresnel's grazing term,
    # (1 - F0) of it, does not scale).
    gt[:, 7:10] = 0.04
    dim = gt.clone()
    factor = torch.tensor([0.2, 0.4, 0.3]).view(1, 3, 1, 1)
    dim[:, 3:6] *= factor
    dim[:, 7:10] *= factor
    plain = metrics.rerender_rmse(dim, gt, lights, backend="torch")
    scaled = metrics.rerender_rmse_scaled(dim, gt, lights, backend="torch")
    assert bool((plain > 0.1).all()) and bool((scaled < 0.1 * plain).all())
    # A wrong material is not forgiven.
    other = maps_factory(2, 16, 16, seed=7)
    assert bool((metrics.rerender_rmse_scaled(other, gt, lights, backend="torch") > 0.03).all())


def test_ssim_identical_is_one_and_different_less(maps_factory: Callable[..., torch.Tensor]) -> None:
    a, b = maps_factory(2, 32, 32, seed=4), maps_factory(2, 32, 32, seed=5)
    for v in metrics.map_ssim(a, a).values():
        assert v.tolist() == pytest.approx([1.0, 1.0], abs=1e-4)
    for v in metrics.map_ssim(a, b).values():
        assert bool((v < 0.5).all())
    lights = metrics.eval_lights(3)
    assert metrics.rerender_ssim(a, a, lights).tolist() == pytest.approx([1.0, 1.0], abs=1e-4)
    assert bool((metrics.rerender_ssim(a, b, lights) < 0.9).all())


def test_rerender_rmse_under_a_known_light() -> None:
    # A far light straight above with I = d^2: unit irradiance on every texel, so a flat
    # Lambertian texel (s = 0) radiates its albedo d and is displayed as d^(1/2.2).
    far = metrics.EvalLights(light=torch.tensor([[0.0, 0.0, 1e3]]), view=torch.tensor([[0.0, 0.0, 2.75]]),
                             intensity=torch.full((1, 3), 1e6))
    gt = M.constant_maps(1, 16, 16, diffuse=0.5, specular=0.0, roughness=1.0)
    pred = M.constant_maps(1, 16, 16, diffuse=0.2, specular=0.0, roughness=1.0)
    img = metrics.rerender(gt, far)
    assert tuple(img.shape) == (1, 1, 3, 16, 16)
    assert torch.allclose(img, torch.full_like(img, 0.5), atol=1e-3)
    expected = 0.5 ** (1 / 2.2) - 0.2 ** (1 / 2.2)
    assert float(metrics.rerender_rmse(pred, gt, far)[0]) == pytest.approx(expected, abs=1e-3)
    assert float(metrics.rerender_rmse(gt, gt, far)[0]) == 0.0
    # Display clips: a radiance above 1 shows as 1.
    assert float(metrics.display(torch.tensor(3.0))) == 1.0


def test_eval_lights_fixed_and_above_the_plane() -> None:
    a, b = metrics.eval_lights(9), metrics.eval_lights(9)
    assert torch.equal(a.light, b.light) and torch.equal(a.view, b.view)
    small = metrics.eval_lights(4)
    assert torch.equal(small.light, a.light[:4]) and torch.equal(small.view, a.view[:4])
    other = metrics.eval_lights(9, seed=1)
    assert not torch.allclose(other.light, a.light)
    elevation = torch.rad2deg(torch.asin(a.light[:, 2] / a.light.norm(dim=-1)))
    assert bool((elevation >= 15.0 - 1e-4).all())
    assert torch.allclose(a.intensity[:, 0], a.light.square().sum(dim=-1))
    with pytest.raises(ValueError, match="count"):
        metrics.eval_lights(0)


def test_evaluate_maps_flat_dict(maps_factory: Callable[..., torch.Tensor]) -> None:
    gt = maps_factory(3, 16, 16, seed=6)
    same = metrics.evaluate_maps(gt, gt, metrics.eval_lights(2), chunk=2)
    assert tuple(same) == metrics.METRIC_KEYS
    assert all(isinstance(v, float) for v in same.values())
    for k, v in same.items():
        assert v == pytest.approx(0.0 if k.startswith("rmse") else 1.0, abs=1e-4), k
    pred = maps_factory(3, 16, 16, seed=7)
    diff = metrics.evaluate_maps(pred, gt, metrics.eval_lights(2), chunk=2)
    rmse = metrics.map_rmse(pred, gt)
    assert diff["rmse_diffuse"] == pytest.approx(float(rmse["diffuse"].mean()), rel=1e-5)
    assert diff["rmse_render"] == pytest.approx(float(metrics.rerender_rmse(pred, gt, metrics.eval_lights(2)).mean()),
                                                rel=1e-5)
    assert diff["rmse_diffuse_scaled"] <= diff["rmse_diffuse"] + 1e-7


def test_bad_input_names_the_argument(maps_factory: Callable[..., torch.Tensor]) -> None:
    gt = maps_factory(1, 8, 8)
    with pytest.raises(ValueError, match="pred: expected the shape"):
        metrics.map_rmse(maps_factory(1, 16, 16), gt)
    with pytest.raises(ValueError, match="gt"):
        metrics.map_rmse(gt, gt[:, :9])
