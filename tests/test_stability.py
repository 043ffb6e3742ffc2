"""Stability: every failure case through every method, finite and in range; noise, permutations,
recoveries, the stability table, and the degradation from the clean case with its chart."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from mi_svbrdf.core import maps as M
from mi_svbrdf.core.metrics import eval_lights
from mi_svbrdf.eval import failure_cases as F
from mi_svbrdf.eval import report, runner
from mi_svbrdf.eval import stability as S
from mi_svbrdf.eval.baseline import BASELINE_SPECULAR
from mi_svbrdf.eval.harness import case_datasets
from mi_svbrdf.eval.methods import Method, make_method
from mi_svbrdf.optim.fit import frontality
from tests.conftest import export_tiny_net
from tests.test_failure_cases import all_cases

SIZE, N = 32, 3
#: A short optimiser run: one start, 0.3 s or 10 steps.
BUDGET, OPT = 0.3, {"iterations": 10, "roughness_starts": (0.5,)}
#: An optimiser made to recover at every step after its first window of 5: with max_recoveries
#: = 3 it stops after exactly 3 recoveries (rise_factor 0: every loss counts as rising).
# one fit's recovery guard (a validated fit, 2 <= N <= 3, runs two fits, each with its own guard)
#: A coarse light search for the uncalibrated refinement (2 x 2 x 4 lights, 8^2 texels): fast on tiny photos.
SEARCH = {"search_size": 8, "distances": (1.4, 2.8), "elevations": (30.0, 60.0), "azimuths": 4,
          "camera_elevations": (60.0,)}
RECOVERING = {"iterations": 1000, "roughness_starts": (0.5,), "window": 5, "rise_factor": 0.0, "max_recoveries": 3,
              "validate_photo": False}


def _export(folder: Path, kind: str) -> None:
    export_tiny_net(folder, kind, SIZE)


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread(one_torch_thread):
    """Every test here runs with one torch thread (see tests/conftest.py)."""

@pytest.fixture(scope="module")
def weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("weights")
    _export(folder, "single")
    _export(folder, "multi")
    return folder


@pytest.fixture(scope="module")
def methods(weights: Path) -> dict[str, Method]:
    return {"trivial": make_method("trivial"), "single": make_method("single", weights_dir=weights),
            "multi": make_method("multi", weights_dir=weights),
            "optimize": make_method("optimize", budget_s=BUDGET, optimizer=OPT),
            "uncalibrated": make_method("uncalibrated", weights_dir=weights, budget_s=BUDGET, optimizer=OPT,
                                        refine_options=SEARCH)}


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
    rest = (M.diffuse(good), M.roughness(good), M.specular(good))
    assert not S.finite_and_in_range(M.make_maps(M.normal(good) * 1.01, *rest))  # not unit
    assert not S.finite_and_in_range(M.make_maps(M.normal(good) * -1, *rest))  # facing into the surface
    assert not S.finite_and_in_range(good[:, :9])


def test_every_case_through_every_method_is_finite_and_in_range(methods, cases) -> None:
    for name, case in cases.items():
        for method_name, method in methods.items():
            out = method(case.inputs, case.captures)
            assert out.shape == (1, 10, SIZE, SIZE), (name, method_name)
            assert S.finite_and_in_range(out), (name, method_name)


def test_optimizer_reports_its_run_and_ends_finite(methods, cases) -> None:
    method = methods["optimize"]
    for name in ("saturated_highlight", "near_mirror", "wrong_gamma"):
        maps = method(cases[name].inputs, cases[name].captures)
        assert S.finite_and_in_range(maps) and method.info["losses_finite"] is True, name
        assert method.info["stop_reason"] in ("converged", "budget", "iterations", "recoveries"), name
        assert 1 <= method.info["steps"] <= OPT["iterations"], name


def test_uncalibrated_refinement_reports_its_run_and_ends_finite(methods, cases) -> None:
    """Photos it cannot use are dropped (counted), a sample whose flash photo is unusable keeps the net's maps."""
    method = methods["uncalibrated"]
    for name in ("saturated_highlight", "dark_material", "noisy"):
        maps = method(cases[name].inputs, cases[name].captures)
        info = method.info
        assert S.finite_and_in_range(maps) and info["losses_finite"] is True, name
        assert 0 <= info["dropped"] <= N and info["net"] == "multi", name
        if info["unfitted"]:  # the net's maps as they are, no step
            assert info["stop_reason"] == "unfitted" and info["steps"] == 0, name
            assert torch.equal(maps, methods["multi"](cases[name].inputs, cases[name].captures)), name
        else:
            assert info["stop_reason"] in ("converged", "budget", "iterations", "recoveries"), name
            assert 1 <= info["steps"] <= OPT["iterations"], name


def test_uncalibrated_refinement_in_the_stability_table(weights: Path, cases, tmp_path: Path) -> None:
    """Capped at 10 steps (not by its budget) its fit is deterministic: a repeat changes nothing; reversing the
    photos changes its flash photo, so the maps move; 1/255 noise moves them less than the photos' reversal."""
    data = case_datasets([cases["cast_shadows"]])[0]
    rows = S.run_stability([("uncalibrated", 60.0)], data, N, tmp_path, weights_dir=weights, trials=1,
                           method_options={"optimizer": OPT, "refine_options": SEARCH})
    (row,) = rows
    assert row["method"] == "uncalibrated" and row["budget_s"] == 60.0 and row["finite"] is True
    assert row["repeat_max"] == 0.0 and row["permutation_max"] > 1e-4 and row["recoveries"] == 0
    assert 0 < row["noise_mean_all"] <= row["noise_max_all"] and math.isfinite(row["rmse_render"])
    (line,) = [ln for ln in S.stability_table(S.read_stability(tmp_path)) if ln.startswith("| uncalibrated 60 s |")]
    assert line.split(" | ")[1] == "0.0000"


def test_optimizer_recoveries_are_counted_exactly(cases) -> None:
    """Steps 0-5 are good (the rising-loss test starts after the window); steps 6, 7, 8 each recover."""
    method = make_method("optimize", budget_s=60.0, optimizer=RECOVERING)
    maps = method(cases["near_mirror"].inputs, cases["near_mirror"].captures)
    assert method.info["recoveries"] == 3 and method.info["stop_reason"] == "recoveries"
    assert method.info["steps"] == 8
    assert S.finite_and_in_range(maps) and method.info["losses_finite"] is True


def test_stability_table_counts_every_call(cases, tmp_path: Path) -> None:
    """One material, trials = 1: the table calls the method 5 times (scored, repeat, noise base,
    one noisy, permuted), each with exactly 3 recoveries: 15; the CSV and the Markdown say so."""
    data = case_datasets([cases["cast_shadows"]])[0]
    rows = S.run_stability([("optimize", 60.0)], data, N, tmp_path, trials=1,
                           method_options={"optimizer": RECOVERING})
    assert len(rows) == 1 and rows[0]["recoveries"] == 15 and rows[0]["finite"] is True
    assert rows[0]["n"] == N and math.isfinite(rows[0]["rmse_render"]) and rows[0]["rmse_render"] > 0
    (read,) = S.read_stability(tmp_path)
    assert read["recoveries"] == 15.0 and read["rmse_render"] == pytest.approx(rows[0]["rmse_render"], rel=1e-5)
    line = [ln for ln in S.stability_table([read]) if ln.startswith("| optimize 60 s |")]
    assert len(line) == 1 and line[0].split(" | ")[8] == "15", line
    with pytest.raises(ValueError, match="a permutation needs two"):
        S.run_stability([("trivial", None)], data, 1, tmp_path)


def test_multi_net_is_permutation_invariant_and_single_net_is_not(methods, cases) -> None:
    for name in ("cast_shadows", "noisy"):
        case = cases[name]
        assert S.permutation_invariance(methods["multi"], case.inputs, case.captures) < 1e-5
        assert S.permutation_invariance(methods["multi"], case.inputs, case.captures, torch.tensor([1, 2, 0])) < 1e-5
    # The single net sees image 0 only: moving another photo first changes its output.
    assert S.permutation_invariance(methods["single"], case.inputs, case.captures) > 1e-3
    with pytest.raises(ValueError, match="permutation: expected"):
        S.permutation_invariance(methods["multi"], case.inputs, case.captures, torch.tensor([0, 0, 1]))


def test_baseline_sensitivity_is_bounded_by_the_hand_computed_amount(methods, cases) -> None:
    """diffuse = clip(photo / ((1 - s) E)): a photo change of at most 1/255 moves it by at most 1/255 / ((1 - s) E)."""
    case = cases["jpeg"]
    cap = case.captures
    noise = 1 / 255
    result = S.perturbation_sensitivity(methods["trivial"], case.inputs, cap, noise=noise, trials=2)
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
    """Rows of the trivial baseline on failure cases and their clean twins (the runner's row loop),
    report.degradation of them, and chart (e) of it."""
    lights = eval_lights()
    # jpeg without its clean twin: no degradation can be computed for it
    chosen = [cases["dark_material"], cases["noisy"], dataclasses.replace(cases["jpeg"], clean=None)]
    rows = []
    for data in case_datasets(chosen):
        row, maps = runner.run_row(methods["trivial"], runner.Job("trivial", N, None), data, 0, lights)
        assert S.finite_and_in_range(maps), data.name
        rows.append(row)
    assert [r["dataset"] for r in rows] == ["case:dark_material", "clean:dark_material", "case:noisy",
                                            "clean:noisy", "case:jpeg"]
    diffuse, normal = report.degradation(rows, "rmse_diffuse"), report.degradation(rows, "rmse_normal")
    assert set(diffuse) == set(normal) == {"dark_material", "noisy"}
    assert diffuse["dark_material"]["trivial"] == pytest.approx(rows[0]["rmse_diffuse"] - rows[1]["rmse_diffuse"])
    # The baseline's flat normal and constant roughness do not depend on the photos: no degradation there.
    assert normal["dark_material"]["trivial"] == pytest.approx(0.0, abs=1e-7)
    assert diffuse["noisy"]["trivial"] > 0  # noise hurts the photo-derived albedo
    path = tmp_path / "e_failure_cases.png"
    report.chart_failure_cases(report.degradation(rows), path)
    with Image.open(path) as im:
        assert im.format == "PNG" and im.size == (450, 360)  # 5 x 4 inches at 90 dpi
        pixels = np.asarray(im.convert("RGB")).reshape(-1, 3)
    grey = (np.abs(pixels.astype(int) - 127) <= 2).all(axis=1)  # tab:gray, the trivial baseline's bars
    assert grey.sum() > 200 and len(np.unique(pixels, axis=0)) > 20
