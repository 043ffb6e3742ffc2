"""The trivial baseline: constants, albedo recovery under known captures, the frontal photo."""
from __future__ import annotations

import pytest
import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.data import photo_setups as C
from mi_svbrdf.eval import baseline
from mi_svbrdf.optim.fit import frontality

ALBEDO = (0.2, 0.12, 0.08)  # dark enough that the I = 13 flash does not saturate


def flat(specular: float, size: int = 32, batch: int = 2) -> torch.Tensor:
    return M.constant_maps(batch, size, size, diffuse=ALBEDO, specular=specular, roughness=1.0)


@pytest.mark.parametrize("preset", ["multiview", "single_flash"])
def test_recovers_a_flat_lambertian_albedo_under_known_captures(preset: str) -> None:
    gt = flat(0.0)
    cap = C.sample_captures(2, 4, C.capture_config(preset, photo=False, noise=False, intensity_jitter=False), torch.Generator().manual_seed(0))
    img = C.render_captures(gt, cap)
    assert float(img.max()) < 1.0  # away from saturation
    out = baseline.trivial_baseline(img, cap, specular=0.0)
    assert torch.allclose(M.diffuse(out), M.diffuse(gt), atol=1e-3)
    # With its own s = 0.04 the baseline recovers a material of that specular (its highlight aside).
    gt4 = flat(0.04)
    out4 = baseline.trivial_baseline(C.render_captures(gt4, cap), cap)
    assert torch.allclose(M.diffuse(out4), M.diffuse(gt4), atol=0.015)


def test_through_the_photo_pipeline() -> None:
    gt = flat(0.0)
    cap = C.sample_captures(2, 3, C.capture_config("multiview", noise=False, intensity_jitter=False), torch.Generator().manual_seed(1))
    out = baseline.trivial_baseline(C.simulate(gt, cap), cap, specular=0.0)
    assert (M.diffuse(out) - M.diffuse(gt)).abs().max() < 0.01  # 8-bit quantisation


def test_constants_and_default_captures() -> None:
    gt = flat(0.0)
    img = C.render_captures(gt, baseline.default_captures(2))[:, :1]
    out = baseline.trivial_baseline(img.expand(2, 3, 3, 32, 32), specular=0.0)
    assert torch.allclose(M.diffuse(out), M.diffuse(gt), atol=1e-3)
    out = baseline.trivial_baseline(img)
    assert torch.equal(M.normal(out), M.normal(M.constant_maps(2, 32, 32)))
    assert bool((M.roughness(out) == baseline.BASELINE_ROUGHNESS).all())
    assert bool((M.specular(out) == baseline.BASELINE_SPECULAR).all())


def test_uses_the_most_fronto_parallel_photo() -> None:
    gt = flat(0.0, batch=1)
    cap = C.sample_captures(1, 5, C.capture_config("multiview", photo=False, noise=False),
                            torch.Generator().manual_seed(2))
    img = C.render_captures(gt, cap)
    k = int(frontality(cap.light, cap.view).argmax())
    spoiled = torch.rand(img.shape, generator=torch.Generator().manual_seed(0))
    spoiled[:, k] = img[:, k]  # only the frontal photo is a real photo of gt
    out = baseline.trivial_baseline(spoiled, cap, specular=0.0)
    assert torch.allclose(M.diffuse(out), M.diffuse(gt), atol=1e-3)


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="images"):
        baseline.trivial_baseline(torch.zeros(1, 3, 8, 8))
    cap = baseline.default_captures(2)
    with pytest.raises(ValueError, match="captures"):
        baseline.trivial_baseline(torch.zeros(1, 1, 3, 8, 8), cap)
