"""Tests of the refinement of a net's maps against uncalibrated photos (mi_svbrdf.optim.refine)."""
from __future__ import annotations

import math

import pytest
import torch

from mi_svbrdf.core import brdf_torch
from mi_svbrdf.core.metrics import angle_deg
from mi_svbrdf.core.render import point, texel_positions
from mi_svbrdf.data import procedural
from mi_svbrdf.optim.refine import RefineConfig, estimate_lights, refine


def photograph(maps: torch.Tensor, cameras: list[list[float]], lights: list[list[float]],
               gains: list[list[float]]) -> torch.Tensor:
    """``(N, 3, H, W)`` linear rectified photos of ``maps`` under isotropic point lights with fall-off."""
    h, w = maps.shape[-2:]
    with torch.no_grad():
        r = brdf_torch.render(maps, texel_positions(h, w), point(torch.tensor([lights])),
                              point(torch.tensor([cameras])), torch.tensor([gains]), None, None,
                              distance_falloff=True, light_z_division=False, include_diffuse=True,
                              normalize_normals=True, distribution="ggx")[0]
    return r.clamp(0.0, 1.0)


def on_hemisphere(elevation: float, azimuth: float, distance: float) -> list[float]:
    e, a = math.radians(elevation), math.radians(azimuth)
    return [distance * math.cos(e) * math.cos(a), distance * math.cos(e) * math.sin(a), distance * math.sin(e)]


CAMERAS = [[0.2, -0.1, 2.0], [0.0, 0.0, 2.0], on_hemisphere(70, 200, 2.0)]
LIGHTS = [[0.2, -0.1, 2.0], on_hemisphere(40, 60, 2.0), on_hemisphere(55, 300, 1.4)]
GAINS = [[1.5, 1.4, 1.3], [3.0, 3.0, 3.3], [1.2, 1.2, 1.2]]


@pytest.fixture(scope="module")
def scene() -> tuple[torch.Tensor, torch.Tensor]:
    maps = procedural.generate("tiles", 3, 64)[None]
    return maps, photograph(maps, CAMERAS, LIGHTS, GAINS)


def test_search_finds_each_photos_light_under_the_true_maps(scene):
    """With the true maps, the grid search puts photo 0's flash and the others' lights within about a grid step
    (the ambient fill, free here, trades a little with the flash's position)."""
    maps, photos = scene
    est = estimate_lights(photos, maps, RefineConfig())
    assert angle_deg(est[0]["camera"], CAMERAS[0]) < 10 and est[0]["light"] == est[0]["camera"]
    for k in (1, 2):
        assert angle_deg(est[k]["light"], LIGHTS[k]) < 15, (k, est[k]["light"], LIGHTS[k])
    for e in est:
        assert e["search_error"] < 0.2


def test_refine_improves_a_blurred_start_and_reports_errors_before_and_after(scene):
    """The net's maps stand-in (the truth, blurred and with a flattened roughness) get closer to the
    truth, and every photo's re-rendering error falls."""
    maps, photos = scene
    start = maps.clone()
    start[:, 6:7] = 0.5 * start[:, 6:7] + 0.25
    start = torch.nn.functional.avg_pool2d(start, 5, stride=1, padding=2, count_include_pad=False)
    res = refine(photos, start, config=RefineConfig(budget_s=20.0, progress=False,
                                                    optimizer={"validate_photo": False}))
    assert res.fit is not None and res.steps > 50
    assert all(a < b for a, b in zip(res.error_after, res.error_before)), (res.error_before, res.error_after)
    err = lambda m: float((m[:, 6:7] - maps[:, 6:7]).abs().mean())  # noqa: E731 - roughness error
    assert err(res.maps) < err(start)
    summary = res.summary()
    assert len(summary["lights"]) == 3 and summary["lights"][0]["used"] and summary["calibration"] is not None
    assert set(summary["lights"][1]) >= {"camera", "light", "gain", "search_error", "used"}


def test_a_black_photo_is_dropped_with_a_note_and_a_black_flash_photo_keeps_the_net(scene):
    maps, photos = scene
    dark = photos.clone()
    dark[2] = 0.0
    res = refine(dark, maps, config=RefineConfig(budget_s=3.0, progress=False))
    assert not res.lights[2]["used"] and res.error_after[2] is None
    assert any("photo 2" in n and "black" in n and "dropped" in n for n in res.notes)
    flash_dark = photos.clone()
    flash_dark[0] = 0.0
    kept = refine(flash_dark, maps, config=RefineConfig(budget_s=3.0, progress=False))
    assert kept.fit is None and torch.equal(kept.maps, maps) and any("photo 0" in n for n in kept.notes)


def test_search_without_the_ambient_fill_finds_the_lights(scene):
    """``ambient=False``: each hypothesis is scored by its light alone (its gain by least squares)."""
    maps, photos = scene
    est = estimate_lights(photos, maps, RefineConfig(ambient=False))
    assert all(e["ambient"] == [0.0, 0.0, 0.0] and math.isfinite(e["search_error"]) for e in est)
    for k in (1, 2):
        assert angle_deg(est[k]["light"], LIGHTS[k]) < 15, (k, est[k]["light"], LIGHTS[k])


def test_validation_at_every_n_keeps_the_net_where_the_fitted_photos_mislead(scene):
    """Four photos (more than the optimiser validates by default): photos 1 and 2 are of another material,
    the last one, held out, of the net's (here the truth). The blend chosen on it stays near the net's maps;
    without the validation the fit follows the misleading photos."""
    maps, photos = scene
    other = procedural.generate("fabric", 5, 64)[None]
    odd = photograph(other, CAMERAS[1:], LIGHTS[1:], GAINS[1:])
    four = torch.cat([photos[:1], odd, photos[1:2]])
    cfg = {"budget_s": 8.0, "progress": False, "max_search_error": 1.0}
    res = refine(four, maps, config=RefineConfig(**cfg))
    assert all(e["used"] for e in res.lights) and res.fit is not None
    assert set(res.fit.validation) == {0.0, 0.25, 0.5, 0.75, 1.0} and res.summary()["blend"] == res.fit.shrink
    assert res.fit.shrink <= 0.25, res.fit.validation
    unvalidated = refine(four, maps, config=RefineConfig(**cfg, validate=False))
    assert unvalidated.fit.shrink is None
    err = lambda m: float((m - maps).abs().mean())  # noqa: E731
    assert err(res.maps) < 0.5 * err(unvalidated.maps), (err(res.maps), err(unvalidated.maps))


def test_refine_rejects_bad_inputs(scene):
    maps, photos = scene
    with pytest.raises(ValueError, match=r"photos: expected shape \(N, 3, H, W\)"):
        refine(photos[:, :2], maps)
    bad = photos.clone()
    bad[0, 0, 0, 0] = math.nan
    with pytest.raises(ValueError, match="photos: expected finite values"):
        refine(bad, maps)
    with pytest.raises(ValueError, match="maps"):
        refine(photos, maps[:, :9])
    with pytest.raises(ValueError, match="RefineConfig.budget_s: expected seconds > 0"):
        RefineConfig(budget_s=0)
    with pytest.raises(ValueError, match="unknown"):
        RefineConfig.from_dict({"budget": 3})
