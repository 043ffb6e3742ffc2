"""Stability (issue 6 §2): every failure case through every method, finite and in range; noise and permutations."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from mi_svbrdf.eval import failure_cases as F, stability as S
from mi_svbrdf.core import maps as M
from mi_svbrdf.eval.baseline import BASELINE_SPECULAR, frontality
from mi_svbrdf.optim import OptimizeConfig
from tests.conftest import export_tiny_net
from tests.test_failure_cases import all_cases

SIZE, N = 32, 3
#: A short optimiser run: one start, 0.3 s or 10 steps.
OPT = OptimizeConfig(iterations=10, budget_s=0.3, roughness_starts=(0.5,), progress=False)


def _export(folder: Path, kind: str) -> None:
    export_tiny_net(folder, kind, SIZE)


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread(one_torch_thread):
    """Every test here runs with one torch thread (see tests/conftest.py)."""

@pytest.fixture(scope="module")
def methods(tmp_path_factory: pytest.TempPathFactory) -> dict[str, S.Method]:
    folder = tmp_path_factory.mktemp("weights")
    _export(folder, "single")
    _export(folder, "multi")
    return S.standard_methods(folder, OPT)


@pytest.fixture(scope="module")
def cases() -> dict[str, F.Case]:
    return all_cases(SIZE, N)  # shared with tests/test_failure_cases.py (generated once per session)


def test_finite_and_in_range_definition() -> None:
    good = M.constant_maps(1, 4, 4, normal=(0.3, -0.2, 1.0), diffuse=1.0, roughness=0.0, specular=0.0)
    assert S.finite_and_in_range(good)
    for channel, value in ((3, math.nan), (7, math.inf), (6, 1.01), (4, -0.01)):
        bad = good.clone()
        bad[0, channel, 1, 2] = value
        assert not S.finite_and_in_range(bad), (channel, value)
    assert not S.finite_and_in_range(torch.cat([good[:, :3] * 1.01, good[:, 3:]], 1))  # not unit
    assert not S.finite_and_in_range(torch.cat([good[:, :3] * -1, good[:, 3:]], 1))  # facing into the surface
    assert not S.finite_and_in_range(good[:, :9])


def test_every_case_through_every_method_is_finite_and_in_range(methods, cases) -> None:
    for name, case in cases.items():
        for method_name, method in methods.items():
            out = method(case.inputs, case.captures)
            assert out.shape == (1, 10, SIZE, SIZE), (name, method_name)
            assert S.finite_and_in_range(out), (name, method_name)


def test_optimizer_reports_recoveries_and_ends_finite(cases) -> None:
    for name in ("saturated_highlight", "near_mirror", "wrong_gamma"):
        report = S.run_optimizer(cases[name].inputs, cases[name].captures, OPT)
        assert report.finite and S.finite_and_in_range(report.maps), name
        assert len(report.recoveries) == 1 and report.recoveries[0] >= 0
        assert report.stop_reasons[0] in ("converged", "budget", "iterations", "recoveries")
        assert report.steps[0] >= 1


def test_multi_net_is_permutation_invariant_and_single_net_is_not(methods, cases) -> None:
    for name in ("cast_shadows", "noisy"):
        case = cases[name]
        assert S.permutation_invariance(methods["multi"], case.inputs, case.captures) < 1e-5
        assert S.permutation_invariance(methods["multi"], case.inputs, case.captures, torch.tensor([1, 2, 0])) < 1e-5
    # The single net sees image 0 only: moving another photo first changes its output.
    assert S.permutation_invariance(methods["single"], case.inputs, case.captures) > 1e-3
    with pytest.raises(ValueError, match="permutation: expected"):
        S.permutation_invariance(methods["multi"], case.inputs, case.captures, torch.tensor([0, 0, 1]))


def test_baseline_sensitivity_is_bounded_by_the_hand_computed_amount(cases) -> None:
    """diffuse = clip(photo / ((1 - s) E)): a photo change of at most 1/255 moves it by at most 1/255 / ((1 - s) E)."""
    case = cases["jpeg"]
    cap = case.captures
    noise = 1 / 255
    result = S.perturbation_sensitivity(S.baseline_method(), case.inputs, cap, noise=noise, trials=2)
    assert result["normal"]["max"] == result["roughness"]["max"] == result["specular"]["max"] == 0.0
    # E by hand: the most frontal photo's flash irradiance of a flat white texel (cone, 1/d^2) + the ambient light.
    k = int(frontality(cap.light, cap.view)[0].argmax())
    centres = -1.0 + (2.0 * torch.arange(SIZE) + 1.0) / SIZE
    y, x = torch.meshgrid(-centres, centres, indexing="ij")
    p = torch.stack([x, y, torch.zeros_like(x)])
    to_light = cap.light[0, k].view(3, 1, 1) - p
    d2 = to_light.square().sum(0)
    wl = to_light / d2.sqrt()
    axis = (cap.light[0, k] - cap.cone_target[0, k]) / (cap.light[0, k] - cap.cone_target[0, k]).norm()
    cone = (wl * axis.view(3, 1, 1)).sum(0).clamp_min(0) ** cap.cone_exponent[0, k]
    irr = cap.intensity[0, k].view(3, 1, 1) * wl[2] / d2 * cone
    for a in range(cap.ambient_light.shape[1]):
        amb = cap.ambient_light[0, a].view(3, 1, 1) - p
        irr = irr + cap.ambient_intensity[0, a].view(3, 1, 1) * (amb[2] / amb.norm(dim=0))
    bound = noise / ((1 - BASELINE_SPECULAR) * irr.min())
    assert 0.3 * bound < result["diffuse"]["max"] <= bound * 1.001
    assert 0 < result["diffuse"]["mean"] < result["diffuse"]["max"]
    assert result["all"]["max"] == result["diffuse"]["max"]


def test_network_sensitivity_is_reported_per_map(methods, cases) -> None:
    case = cases["clear_coat_print"]
    result = S.perturbation_sensitivity(methods["multi"], case.inputs, case.captures, trials=2)
    assert set(result) == {"normal", "diffuse", "roughness", "specular", "all"}
    for key, values in result.items():
        assert 0 <= values["mean"] <= values["max"] < 1, key
    assert result["all"]["max"] > 0  # a net is not blind to its input
    silent = S.perturbation_sensitivity(methods["multi"], case.inputs, case.captures, noise=0.0, trials=1)
    assert silent["all"]["max"] == 0.0


def test_degradation_and_its_chart(methods, cases, tmp_path: Path) -> None:
    results = {name: {"baseline": S.degradation(methods["baseline"], cases[name])} for name in ("dark_material", "noisy")}
    dark = results["dark_material"]["baseline"]
    assert dark["finite"] == dark["finite_clean"] == 1.0
    assert dark["rmse_diffuse_delta"] == pytest.approx(dark["rmse_diffuse"] - dark["rmse_diffuse_clean"])
    # The baseline's flat normal and constant roughness do not depend on the photos: no degradation there.
    assert dark["rmse_normal_delta"] == pytest.approx(0.0, abs=1e-7)
    assert results["noisy"]["baseline"]["rmse_diffuse_delta"] > 0  # noise hurts the photo-derived albedo
    S.plot_degradation(results, tmp_path / "degradation.png")
    assert (tmp_path / "degradation.png").stat().st_size > 5000
    with pytest.raises(ValueError, match="clean twin"):
        S.degradation(methods["baseline"], cases["noisy"].clean)
