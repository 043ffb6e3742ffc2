"""Tests of the map models (tied and fixed maps) and of the per-capture selection (``optimize --select``)."""
from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
from pathlib import Path

import pytest
import torch

from mi_svbrdf.cli.optimize import main as cli_main
from mi_svbrdf.core import maps as M
from mi_svbrdf.optim import OptimizeConfig, optimize
from mi_svbrdf.optim.params import MODELS, from_maps, tie_gradient, tie_variables, to_maps
from mi_svbrdf.optim.select import (LADDER, SELECT_MODES, SelectConfig, candidate_config, fold_photos, fold_spread,
                                    held_out_rmse, select_and_fit)

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_select", ROOT / "benchmarks" / "bench_select.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


BENCH = _bench()


def test_tie_gradient_is_the_shared_parameters_gradient():
    """A tied channel's gradient is the mean of the per-texel gradients: the gradient of one shared value / texels."""
    torch.manual_seed(0)
    target = torch.rand(1, 9, 6, 6)
    x = torch.randn(1, 9, 6, 6).requires_grad_()
    ((x - target) ** 2).sum().backward()
    g = x.grad.clone()
    tie_gradient(x.grad, "uniform")
    shared = torch.zeros(1, 4, 1, 1, requires_grad=True)  # one value added to every texel of each tied channel
    y = torch.cat([x.detach()[:, :5], x.detach()[:, 5:] + shared], 1)
    ((y - target) ** 2).sum().backward()
    assert torch.allclose(x.grad[:, 5:], (shared.grad / 36.0).expand(1, 4, 6, 6), atol=1e-6)
    assert torch.equal(x.grad[:, :5], g[:, :5])  # untied channels untouched
    x.grad = g.clone()
    tie_gradient(x.grad, "lambertian")
    assert float(x.grad[:, 5:].abs().max()) == 0.0 and torch.equal(x.grad[:, :5], g[:, :5])
    with pytest.raises(ValueError, match="model: expected one of"):
        tie_gradient(g, "phong")


def test_tie_variables_per_model():
    v = torch.randn(2, 9, 5, 5)
    for model in MODELS:
        t = tie_variables(v, model)
        assert torch.equal(t[:, :5], v[:, :5])
    assert float(tie_variables(v, "uniform")[:, 5:].std(dim=(2, 3)).max()) < 1e-6
    us = tie_variables(v, "uniform_specular")
    assert torch.equal(us[:, 5], v[:, 5]) and float(us[:, 6:].std(dim=(2, 3)).max()) < 1e-6
    lam = to_maps(tie_variables(v, "lambertian"))
    assert float(M.specular(lam).max()) < 2e-4


@pytest.fixture(scope="module")
def uniform_capture():
    gt = BENCH.material("uniform", 1, 24)
    return (gt, *BENCH.simulated_capture(gt, 5, 1))


@pytest.mark.parametrize("model", ["lambertian", "uniform", "uniform_specular"])
def test_fits_of_a_model_keep_its_tied_maps(uniform_capture, model):
    """Every step (multi-start, the cosine schedule, priors, recoveries) keeps tied maps uniform and fixed maps fixed."""
    _, spec, images, valid = uniform_capture
    res = optimize(spec, images, valid, config=OptimizeConfig(iterations=60, model=model, progress=False))
    maps = res.maps
    spec_std = float(M.specular(maps).std(dim=(2, 3)).max())
    if model == "lambertian":
        assert float(M.specular(maps).max()) < 2e-4
    else:
        assert spec_std < 1e-5
    if model == "uniform":
        assert float(M.roughness(maps).std()) < 1e-5
    if model == "uniform_specular":
        assert float(M.roughness(maps).std()) > 1e-3  # roughness stays free per texel


def test_config_rejects_an_unknown_model():
    with pytest.raises(ValueError, match="model: expected one of"):
        OptimizeConfig(model="phong")


def test_fold_photos_spread_over_the_capture():
    assert fold_photos(7, 3) == [0, 3, 6]
    assert fold_photos(3, 3) == [0, 1, 2]
    assert fold_photos(10, 4) == [0, 3, 6, 9]
    assert fold_photos(2, 3) == [0, 1]


def test_candidates_are_named_configurations():
    assert [c.name for c in LADDER][:5] == ["plain", "lambertian", "uniform", "uniform_specular", "full"]
    plain = candidate_config("plain")
    assert (plain.loss, plain.tv_weight, plain.schedule, plain.roughness_starts, plain.start_prior_weight) == (
        "l2_display", 0.0, "constant", (0.5,), 0.0)
    assert SELECT_MODES[:2] == ("auto", "off")
    for c in LADDER:
        candidate_config(c.name)  # every override is a valid OptimizeConfig field and value
    cfg = candidate_config("full_slow", OptimizeConfig(budget_s=12.0))
    assert (cfg.lr, cfg.tol, cfg.budget_s) == (0.03, 0.0, 12.0)
    with pytest.raises(ValueError, match="select: expected one of"):
        candidate_config("best")
    with pytest.raises(ValueError, match="folds: expected an int >= 2"):
        SelectConfig(folds=1)


def test_held_out_rmse_of_the_true_maps_is_the_photos_noise():
    gt = BENCH.material("full", 2, 24)
    spec, images, valid = BENCH.simulated_capture(gt, 4, 2, noise=0.0)
    err, k, renders = held_out_rmse(gt, spec, images, [0, 1, 2], [3])
    assert err < 0.01 and abs(k - 1.0) < 0.02 and renders.shape == (1, 3, 24, 24)
    wrong = gt.clone()
    wrong[:, 6] = 0.9  # rough instead of the material's own roughness
    assert held_out_rmse(wrong, spec, images, [0, 1, 2], [3])[0] > 3 * err


def test_fold_spread():
    m = BENCH.material("full", 3, 16)
    same = fold_spread([m, m.clone(), m.clone()], (16, 16))
    assert all(float(v.abs().max()) < 1e-3 for v in same.values())
    tilted = to_maps(from_maps(m) + torch.tensor([0.5, 0, 0, 0, 0, 0, 0, 0, 0]).view(1, 9, 1, 1))
    spread = fold_spread([m, tilted], (32, 32))
    assert spread["normal_deg"].shape == (1, 1, 32, 32) and float(spread["normal_deg"].mean()) > 5.0
    with pytest.raises(ValueError, match="two or more"):
        fold_spread([m], (16, 16))


QUICK = SelectConfig(size=24, steps=40)


def test_selection_recovers_a_matte_material():
    """A matte material selects the Lambertian candidate (the recovery rates of every kind over 10 seeds at 64²:
    benchmarks/bench_select.py, docs/benchmarks/select.md)."""
    spec, images, valid = BENCH.simulated_capture(BENCH.material("lambertian", 0, 24), 6, 0)
    fit = select_and_fit(spec, images, valid, config=OptimizeConfig(progress=False), settings=QUICK)
    assert fit.choice == "lambertian", fit.selection["why"]


def test_selection_records_every_candidate_and_the_uncertainty():
    gt = BENCH.material("full", 4, 24)
    spec, images, valid = BENCH.simulated_capture(gt, 6, 4)
    fit = select_and_fit(spec, images, valid, config=OptimizeConfig(progress=False), settings=QUICK)
    sel = fit.selection
    assert sel["folds"] == [0, 2, 5] and {c["name"] for c in sel["candidates"]} == {c.name for c in LADDER}
    survivors = [c for c in sel["candidates"] if not c["eliminated"]]
    assert len(survivors) == max(2, math.ceil(SelectConfig().keep * len(LADDER)))
    assert all(len(c["fold_errors"]) == 3 for c in survivors)
    assert all(len(c["fold_errors"]) == 1 for c in sel["candidates"] if c["eliminated"])
    best = min(survivors, key=lambda c: c["mean"])
    chosen = next(c for c in survivors if c["name"] == fit.choice)
    assert chosen["mean"] <= best["mean"] + chosen["se"] + 1e-12  # the one-SE rule
    order = [c.name for c in LADDER]
    assert all(order.index(c["name"]) >= order.index(fit.choice) for c in survivors
               if c["mean"] <= best["mean"] + c["se"])  # the simplest such candidate
    assert fit.result.maps.shape == (1, 10, 24, 24) and fit.result.steps > 0
    assert set(fit.uncertainty) == {"normal_deg", "diffuse", "roughness", "specular"}
    assert all(v.shape == (1, 1, 24, 24) for v in fit.uncertainty.values())


def test_uncertainty_is_higher_where_the_photos_say_less():
    """Texels saturated in every photo hold no measurement: their uncertainty is the largest, for every map."""
    gt = BENCH.material("full", 5, 32)
    spec, images, valid = BENCH.simulated_capture(gt, 6, 5)
    images[:, :, :8, :8] = 1.0  # a corner clipped in every photo
    valid[:, :, :8, :8] = False
    fit = select_and_fit(spec, images, valid, config=OptimizeConfig(progress=False),
                         settings=SelectConfig(size=32, steps=40), select="auto")
    for name, u in fit.uncertainty.items():
        assert float(u[0, 0, :8, :8].min()) > float(u[0, 0, 12:, 12:].max()), name


def test_selection_says_what_it_does_with_too_few_photos():
    spec, images, valid = BENCH.simulated_capture(BENCH.material("full", 6, 16), 2, 6)
    fit = select_and_fit(spec, images, valid, config=OptimizeConfig(iterations=20, progress=False))
    assert fit.choice == "" and "selection needs 3 or more photos" in fit.result.notes[0]
    assert "held-out photo chooses" in fit.selection["why"]
    forced = select_and_fit(spec, images, valid, config=OptimizeConfig(iterations=20, progress=False),
                            select="uniform")
    assert forced.choice == "uniform" and float(M.roughness(forced.result.maps).std()) < 1e-5
    with pytest.raises(ValueError, match="select: expected one of"):
        select_and_fit(spec, images, valid, select="best")


def test_cli_select_writes_the_chart_the_uncertainty_and_the_summary(tmp_path, capsys):
    out = tmp_path / "fit"
    # 60 steps a fit (the folds capped alike): what the command writes, not how well it fits (test_cli_examples)
    assert cli_main(["--capture", "example", "-o", str(out), "--budget-s", "0", "--iterations", "60",
                     "--no-progress"]) == 0
    captured = capsys.readouterr()
    printed = captured.out
    assert "selection.png, uncertainty/" in printed and "no uncertainty/" not in printed, printed
    summary = json.loads((out / "summary.json").read_text())
    sel = summary["selection"]
    assert sel["plan"]["line"] in captured.err  # said before the folds run, and recorded
    assert sel["plan"]["folds"] == sel["folds"] and len(sel["folds"]) == 3 and not sel["plan"]["fallback"]
    assert sel["mode"] == "auto" and sel["choice"] in {c.name for c in LADDER} and sel["why"]
    assert len(sel["candidates"]) == len(LADDER)
    assert (out / "selection.png").stat().st_size > 0
    for name in ("normal_deg", "diffuse", "roughness", "specular"):
        assert (out / "uncertainty" / f"{name}.png").stat().st_size > 0
    assert set(summary["uncertainty"]["mean"]) == {"normal_deg", "diffuse", "roughness", "specular"}
    scales = summary["uncertainty"]["png_top_of_scale"]  # each map on its own scale, which shows its spread
    assert set(scales) == set(summary["uncertainty"]["mean"])
    assert all(0 < summary["uncertainty"]["mean"][k] < scales[k] for k in scales), summary["uncertainty"]
    forced = tmp_path / "forced"
    assert cli_main(["--capture", "example", "-o", str(forced), "--select", "uniform", "--iterations", "30",
                     "--no-progress"]) == 0
    summary = json.loads((forced / "summary.json").read_text())
    assert summary["selection"] == {"mode": "forced", "choice": "uniform"}
    assert not (forced / "selection.png").exists()
    printed = capsys.readouterr().out
    assert "selection.png" not in printed and "no uncertainty/: " in printed and "--select uniform" in printed
    assert summary["uncertainty"]["mean"] is None and "--select uniform" in summary["uncertainty"]["why_none"]


def _selected(folds: int, *, uncertainty: dict[str, torch.Tensor] | None = None):
    """A selection record like select_and_fit's: three candidates, ``folds`` folds (leaving out photos 0, 2, 4)."""
    import types

    left_out = [0, 2, 4][:folds]
    rows = []
    for name, mean, eliminated in (("plain", 0.044, True), ("lambertian", 0.0155, False), ("uniform", 0.0221, False)):
        k = left_out if not eliminated else left_out[:1]
        rows.append({"name": name, "mean": mean, "eliminated": eliminated, "length": 60, "still_improving": True,
                     "se": 0.004 if len(k) > 1 and name != "lambertian" else None,
                     "fold_errors": {str(i): mean for i in k}, "fold_seconds": {str(i): 1.0 for i in k},
                     "fold_curves": {str(i): [[10, mean * 1.2], [30, mean * 1.05], [60, mean]] for i in k}})
    selection = {"mode": "auto", "candidates": rows, "choice": "lambertian", "best": "lambertian", "folds": left_out,
                 "why": "lambertian: the lowest mean held-out error", "fold_size": [64, 64],
                 "runs": [[r["name"], i] for i in left_out for r in rows if str(i) in r["fold_errors"]]}
    return types.SimpleNamespace(selection=selection, uncertainty=uncertainty, choice="lambertian")


def _figures(monkeypatch) -> list:
    from mi_svbrdf.cli import optimize as optimize_module

    figures: list = []
    monkeypatch.setattr(optimize_module, "save_figure", lambda fig, path, dpi=90: figures.append(fig))
    return figures


def test_selection_chart_names_the_photos_and_explains_only_what_it_draws(tmp_path, monkeypatch):
    """selection.png: a fold by its left-out photo's file name; the paired standard error explained only where error
    bars are drawn; the value labels start after the bars' caps."""
    from mi_svbrdf.cli.optimize import PAIRED_SE, uncertainty_absence, write_selection

    figures = _figures(monkeypatch)
    photos = [f"{k:03d}.png" for k in range(5)]
    one = _selected(1)
    write_selection(tmp_path, one, None, photos)
    fig = figures[-1]
    words = " ".join(t.get_text() for t in fig.texts)
    assert "paired standard error" not in words and "one fold ran" in words, words
    assert [t.get_text() for t in fig.axes[1].get_legend().get_texts()][0] == "000.png left out"
    assert "2 or more fold fits of the chosen candidate, and lambertian had 1" in uncertainty_absence(one, "auto")
    write_selection(tmp_path, _selected(3), None, photos)
    fig = figures[-1]
    assert PAIRED_SE[:40] in " ".join(t.get_text() for t in fig.texts)
    assert [t.get_text() for t in fig.axes[1].get_legend().get_texts()][:3] == [
        "000.png left out", "002.png left out", "004.png left out"]
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    ax = fig.axes[0]
    caps = [line.get_window_extent(renderer) for line in ax.lines]  # the error bars' caps
    labels = [t.get_window_extent(renderer) for t in ax.texts]
    assert caps and len(labels) == 3
    assert not any(label.overlaps(cap) for label in labels for cap in caps)


def test_uncertainty_maps_are_drawn_on_a_scale_that_shows_them(tmp_path, monkeypatch):
    """Spreads far below any fixed scale fill their own: the colour bar tops at the 99th percentile of the measured
    texels (rounded up), the unmeasured texels drawn apart, off the scale."""
    from mi_svbrdf.cli.optimize import UNMEASURED_COLOUR, uncertainty_images, uncertainty_scales, write_selection

    g = torch.Generator().manual_seed(0)
    spread = {name: torch.rand(1, 1, 16, 16, generator=g) * scale
              for name, scale in (("normal_deg", 3.0), ("diffuse", 0.01), ("roughness", 0.02), ("specular", 0.004))}
    measured = torch.ones(16, 16, dtype=torch.bool)
    measured[:4, :4] = False
    for v in spread.values():
        v[0, 0, :4, :4] = 0.5  # what fold_spread writes where nothing measures the texel
    selected = _selected(3, uncertainty=spread)
    scales = uncertainty_scales(selected, measured)
    assert scales == {"normal_deg": 3.0, "diffuse": 0.01, "roughness": 0.02, "specular": 0.004}, scales
    images = uncertainty_images(selected, scales, measured)
    for name, (image, caption) in images.items():
        assert image.shape == (16, 16, 3) and float(image[4:, 4:].mean()) > 0.25, name  # not almost black
        assert torch.allclose(torch.from_numpy(image[:4, :4]), torch.tensor(UNMEASURED_COLOUR).expand(4, 4, 3))
        assert f"{scales[name]:g}" in caption and "blue" in caption
    figures = _figures(monkeypatch)
    write_selection(tmp_path, selected, images, None, scales, measured)
    assert len(figures) == 5  # selection.png and the four maps
    bar = figures[1].axes[1]  # the colour bar of normal_deg.png
    assert bar.get_ylim()[1] == pytest.approx(3.0)


def test_loss_chart_lists_only_what_it_draws(tmp_path, monkeypatch):
    """loss.png: a fit or curve of one point is drawn (a marker), an empty one is not in the legend; the early stop's
    left-out photo is named by its file."""
    import types

    from mi_svbrdf.cli.optimize import write_loss_figure

    figures = _figures(monkeypatch)
    result = types.SimpleNamespace(history=[(0.1, 1, 0.127), (0.2, 2, 0.123)],
                                   phases=[("early stop (5 of 6 photos)", 0), ("all 6 photos, continued", 1)],
                                   steps=2, seconds=0.2, recoveries=0,
                                   held_out={"curve": [[0.1, 1, 0.05]], "eligible_from": 10, "photos": [2],
                                             "best_length": 99, "then": "refit"})
    write_loss_figure(tmp_path / "loss.png", result, _selected(1).selection, [f"{k:03d}.png" for k in range(6)])
    fig = figures[-1]
    for ax in fig.axes:
        for line in ax.get_lines():
            if not line.get_label().startswith("_"):
                assert len(line.get_xdata()) >= 2 or line.get_marker() not in ("None", "", None), line.get_label()
    legend = [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
    assert any("002.png left out" in t for t in legend) and not any("photo 3" in t for t in legend), legend
    drawn = {artist.get_label() for ax in fig.axes for artist in [*ax.get_lines(), *ax.patches]}  # bands: patches
    assert set(legend) <= drawn, (legend, drawn)
    result.held_out = {"curve": [], "eligible_from": 10, "photos": [2], "best_length": 0, "then": "refit"}
    write_loss_figure(tmp_path / "loss.png", result, None, [f"{k:03d}.png" for k in range(6)])
    words = " ".join(t.get_text() for t in figures[-1].axes[1].texts)
    assert "left 002.png out, but the fit stopped" in words.replace("\n", " "), words


def test_the_priors_closed_form_equals_autograd_of_its_reference():
    """The pull and the chroma term's value and gradient in one pass equal autograd through their plain formula."""
    from mi_svbrdf.optim.loop import Prior

    torch.manual_seed(1)
    x = torch.randn(1, 9, 7, 5, dtype=torch.float64)
    anchor = torch.randn(1, 9, 7, 5, dtype=torch.float64)
    texel = 1.0 + torch.rand(1, 1, 7, 5, dtype=torch.float64)
    for prior in (Prior(anchor=anchor, anchor_weight=3.0, map_weights=(10.0, 0.1, 1.0, 2.0)),
                  Prior(chroma_weight=0.7), Prior(chroma_weight=0.7, chroma_texel=texel),
                  Prior(anchor=anchor, anchor_weight=0.5, chroma_weight=2.0, chroma_texel=texel)):
        a = x.clone().requires_grad_()
        prior(a).backward()
        b = x.clone().requires_grad_()
        prior.reference(b).backward()
        assert float(prior(x)) == pytest.approx(float(prior.reference(x)), rel=1e-12)
        assert torch.allclose(a.grad, b.grad, rtol=1e-10, atol=1e-14)
        assert torch.autograd.gradcheck(lambda v: prior(v), (x.clone().requires_grad_(),))


def test_viewer_page_toggles_the_uncertainty_maps():
    from mi_svbrdf.io.viewer import viewer_html

    maps = BENCH.material("full", 7, 8)
    plain = viewer_html(maps)
    assert 'id="uncertainty-toggle"' not in plain and plain.count("data:image/png;base64,") == 4
    img = torch.rand(8, 8, 3).numpy()
    page = viewer_html(maps, uncertainty={"normal_deg": (img, "spread of normal: black 0, white 20°"),
                                          "roughness": (img, "spread of roughness")})
    assert 'id="uncertainty-toggle"' in page and page.count("data:image/png;base64,") == 6
    assert '<option value="roughness">' in page and "spread of roughness" in page
    with pytest.raises(ValueError, match="expected an \\(H, W, 3\\) image"):
        viewer_html(maps, uncertainty={"normal_deg": (img[..., 0], "x")})


@pytest.mark.parametrize("seed", range(20))
def test_a_simpler_candidate_is_chosen_only_within_noise_and_the_tie(seed):
    """Whatever the fold means and standard errors, the choice is never worse than the best by more than ``tie``
    nor by more than its own paired standard error, and is the best itself when no simpler one qualifies."""
    from mi_svbrdf.optim.select import choose

    g = torch.Generator().manual_seed(seed)
    names = [c.name for c in LADDER][:5]
    rows = {n: {"mean": 0.05 + 0.02 * float(torch.rand((), generator=g)),
                "se": 0.02 * float(torch.rand((), generator=g))} for n in names}
    choice, best, near = choose(rows, names, 0.02)
    assert best == min(names, key=lambda n: rows[n]["mean"])
    assert rows[choice]["mean"] <= rows[best]["mean"] * 1.02 + 1e-12
    assert rows[choice]["mean"] <= rows[best]["mean"] + rows[choice]["se"] + 1e-12 or choice == best
    assert all(names.index(n) > names.index(choice) or n == best or rows[n]["mean"] > rows[best]["mean"] * 1.02
               or rows[n]["mean"] > rows[best]["mean"] + rows[n]["se"] for n in names if n != choice)
    assert choice not in near and all(abs(rows[n]["mean"] - rows[choice]["mean"]) <= 0.02 * rows[choice]["mean"]
                                      for n in near)


def test_the_selection_is_the_same_on_a_rerun_and_its_record_is_strict_json():
    """Fold fits are capped by steps, not by the clock: two runs make the same fits and the same choice."""
    spec, images, valid = BENCH.simulated_capture(BENCH.material("full", 8, 24), 5, 8)
    runs = [select_and_fit(spec, images, valid, config=OptimizeConfig(progress=False), settings=QUICK)
            for _ in range(2)]
    a, b = (r.selection for r in runs)
    assert a["choice"] == b["choice"] and a["fold_steps"] == b["fold_steps"]
    for ca, cb in zip(a["candidates"], b["candidates"]):
        assert ca["fold_errors"].keys() == cb["fold_errors"].keys()
        assert list(ca["fold_errors"].values()) == pytest.approx(list(cb["fold_errors"].values()), rel=1e-4)
    text = json.dumps(a, allow_nan=False)  # eliminated candidates' standard error: null, never NaN
    assert '"se": null' in text
    chosen = next(c for c in a["candidates"] if c["name"] == a["choice"])
    curves = list(chosen["fold_curves"].values())
    assert chosen["length"] in {k for curve in curves for k, _ in curve}


def test_the_least_squares_start_uses_every_photo():
    from mi_svbrdf.optim.fit import initial_maps

    gt = BENCH.material("lambertian", 1, 32)
    spec, images, _ = BENCH.simulated_capture(gt, 6, 1)
    err = {s: float((M.diffuse(initial_maps(spec, images, 0.5, s)) - M.diffuse(gt)).abs().mean())
           for s in ("frontal", "lstsq")}
    assert err["lstsq"] < 0.8 * err["frontal"], err
    with pytest.raises(ValueError, match="start: expected one of"):
        initial_maps(spec, images, 0.5, "median")


@pytest.mark.parametrize("n, size, budget", [(3, 64, 60.0), (7, 256, 60.0), (9, 256, 60.0), (20, 256, 60.0),
                                             (20, 128, 60.0), (7, 256, 240.0), (5, 48, math.inf)])
def test_the_plan_has_three_folds_and_leaves_the_final_fit_its_share(n, size, budget):
    """Every plan runs every fold (none skipped) within the folds' share at the pace it plans for, so the final fit
    keeps at least the rest; a fold fits every photo but its left-out one, on a window of the photos at their
    resolution (another for each fold), or with ``view="whole"`` on the whole sample downsampled."""
    from mi_svbrdf.optim.select import fit_photos, plan_folds

    sel = SelectConfig()
    plan = plan_folds(n, size, size, budget, sel, sel.steps)
    assert not plan.fallback and len(plan.folds) == 3
    assert plan.seconds <= sel.budget_share * budget
    assert plan.fold_fits == len(plan.candidates) + 2 * plan.keep and plan.keep >= 2
    assert plan.photos == n - 1 and max(plan.size) <= min(sel.size, size)  # every photo but the left-out one
    for k in plan.folds:
        fit = fit_photos(n, k, plan.photos)
        assert fit == [i for i in range(n) if i != k]
    # a window per fold at the photos' resolution, inside them, each at another place
    windows = plan_folds(n, size, size, budget, dataclasses.replace(sel, view="windows"), sel.steps)
    assert windows.view == "windows" and len(windows.windows) == 3
    assert len(set(windows.windows)) == (1 if windows.whole else 3) and windows.seconds <= sel.budget_share * budget
    assert all(win[2:] == windows.size and win[0] + win[2] <= size and win[1] + win[3] <= size
               for win in windows.windows)
    assert json.loads(json.dumps(plan.as_dict(), allow_nan=False))["line"] == plan.line()
    whole = plan_folds(n, size, size, budget, dataclasses.replace(sel, view="whole"), sel.steps)
    assert whole.windows == () and whole.whole and max(whole.size) <= max(32, size // 2)
    assert whole.seconds <= sel.budget_share * budget
    lattice = plan  # the default view
    assert lattice.view == "lattice" and lattice.whole and len(set(lattice.windows)) == 1 and lattice.seconds <= sel.budget_share * budget
    top, left, wh, ww = lattice.windows[0]  # every step-th texel of a centred window that loses less than a step
    assert (wh // lattice.step, ww // lattice.step) == lattice.size and size - wh < lattice.step and top == left


def test_the_plan_is_the_same_on_a_machine_up_to_twice_as_slow():
    """The clock moves the plan only by whole factors of SLOW_PACE over the reference step: a step 2x slower than
    a pace below the reference (one core instead of two, a busy machine) makes the same plan; a much slower machine
    makes a smaller one, and a budget no plan fits says so and fits the measured fallback candidate."""
    from mi_svbrdf.optim.select import SLOW_PACE, plan_folds

    sel = SelectConfig()
    for n, size in ((7, 256), (20, 256), (5, 128)):
        plans = [plan_folds(n, size, size, 60.0, sel, 300, pace) for pace in (None, 0.3, 0.6, 1.2, SLOW_PACE * 0.99)]
        assert len({dataclasses.replace(p, pace=None) for p in plans}) == 1
        slow = plan_folds(n, size, size, 60.0, sel, 300, 3 * SLOW_PACE)
        assert slow.fallback or slow.fold_fits * slow.size[0] * slow.size[1] < (
            plans[0].fold_fits * plans[0].size[0] * plans[0].size[1])
    tiny = plan_folds(7, 256, 256, 2.0, sel, 300)
    assert "full_calibrated was fitted" in tiny.fallback and "selection plan: none" in tiny.line()
    # 20 photos in 45 s: folds of every other photo cost more than half the budget even with the fewest candidates
    assert "9 fold fits of 19 photos" in plan_folds(20, 128, 128, 45.0, sel, 300).fallback


def test_the_same_choice_with_a_step_twice_as_slow(monkeypatch):
    """A finite budget: the plan uses a measured step, yet a machine whose every clock reading is twice as late (a step
    twice as slow) makes the same plan, the same fold fits and the same choice: the clock enters the plan only through
    its coarse rule (whose levels test_the_plan_is_the_same_on_a_machine_up_to_twice_as_slow checks), never the fits."""
    import time as clock

    spec, images, valid = BENCH.simulated_capture(BENCH.material("full", 9, 24), 5, 9)
    settings = SelectConfig(size=24, steps=40)
    budget = 600.0

    def selected() -> dict:
        return select_and_fit(spec, images, valid, config=OptimizeConfig(progress=False, budget_s=budget),
                              settings=settings).selection

    fast = selected()
    real = clock.perf_counter
    origin = real()
    monkeypatch.setattr(clock, "perf_counter", lambda: origin + 2.0 * (real() - origin))
    slow = selected()
    monkeypatch.undo()
    assert fast["plan"]["pace"] is not None and slow["plan"]["pace"] is not None  # measured: the budget is finite
    decided = ("folds", "size", "photos", "steps", "candidates", "keep", "fold_fits", "fallback")
    assert {k: fast["plan"][k] for k in decided} == {k: slow["plan"][k] for k in decided}
    assert fast["choice"] == slow["choice"] and fast["runs"] == slow["runs"]
    for ca, cb in zip(fast["candidates"], slow["candidates"]):
        assert list(ca["fold_errors"].values()) == pytest.approx(list(cb["fold_errors"].values()), rel=1e-4)


def test_folds_fit_windows_of_every_other_photo_at_the_photos_resolution():
    """Windows smaller than the photos: each fold fits its own window of every photo but its left-out one at the photos'
    resolution; no texel has two fold fits, so no uncertainty maps (the record says why) and the final fit starts as
    ``--select NAME`` does."""
    spec, images, valid = BENCH.simulated_capture(BENCH.material("full", 11, 32), 5, 11)
    fit = select_and_fit(spec, images, valid, config=OptimizeConfig(progress=False),
                         settings=SelectConfig(size=16, steps=40, view="windows"))
    sel = fit.selection
    assert sel["fold_view"] == "windows" and sel["fold_size"] == [16, 16] and len(sel["fold_windows"]) == 3
    assert len({tuple(w) for w in sel["fold_windows"]}) == 3  # another part of the sample for each fold
    assert all(sel["fit_photos"][str(k)] == [i for i in range(5) if i != k] for k in sel["folds"])
    assert fit.uncertainty is None and sel["uncertainty"] is None and "windows" in sel["uncertainty_absent"]
    assert sel["final_start"] == "fresh" and fit.result.maps.shape == (1, 10, 32, 32)
    assert json.loads(json.dumps(sel, allow_nan=False))["choice"] == fit.choice
    with pytest.raises(ValueError, match="view: expected one of"):
        SelectConfig(view="tiles")


def test_a_budget_without_folds_fits_the_measured_fallback():
    """A budget no plan fits: no folds run, the candidate :data:`FALLBACK` names is fitted and the record says why."""
    from mi_svbrdf.optim.select import FALLBACK

    spec, images, valid = BENCH.simulated_capture(BENCH.material("full", 13, 24), 5, 13)
    fit = select_and_fit(spec, images, valid, config=OptimizeConfig(progress=False, budget_s=0.5))
    assert fit.choice == FALLBACK == fit.selection["choice"] and "was fitted" in fit.selection["why"]
    assert fit.selection["why"] == fit.result.notes[0] and "candidates" not in fit.selection
    assert fit.result.calibration is not None  # full_calibrated: the calibration ran


def test_lattice_folds_fit_every_kth_texel_of_the_photos():
    """The lattice: every fold fits the same every-k-th texels of the photos (unaveraged), so the chosen candidate's
    fold fits give uncertainty maps over the whole sample; the final fit starts fresh."""
    spec, images, valid = BENCH.simulated_capture(BENCH.material("full", 12, 32), 5, 12)
    fit = select_and_fit(spec, images, valid, config=OptimizeConfig(progress=False),
                         settings=SelectConfig(size=16, steps=40, view="lattice"))
    sel = fit.selection
    assert sel["fold_view"] == "lattice" and sel["fold_size"] == [16, 16] and sel["plan"]["step"] == 2
    assert sel["fold_windows"] == [[0, 0, 32, 32]] * 3 and sel["final_start"] == "fresh"
    assert set(fit.uncertainty) == {"normal_deg", "diffuse", "roughness", "specular"}
    assert all(v.shape == (1, 1, 32, 32) for v in fit.uncertainty.values())
    assert "every 2th texel" not in sel["plan"]["line"] and "every 2nd texel" in sel["plan"]["line"]


def test_the_final_fit_continues_from_the_fold_fits():
    """A multi-start candidate's final fit starts from its fold fits: its first step's loss is below a fresh start's."""
    from mi_svbrdf.optim.select import continues

    assert continues(candidate_config("full")) and continues(candidate_config("full_calibrated"))
    assert not continues(candidate_config("plain")) and not continues(candidate_config("lambertian"))
    spec, images, valid = BENCH.simulated_capture(BENCH.material("full", 10, 24), 6, 10)
    fits = {warm: select_and_fit(spec, images, valid, config=OptimizeConfig(progress=False),
                                 settings=SelectConfig(size=24, steps=40, warm_start=warm, view="whole"))
            for warm in (True, False)}
    assert fits[True].choice == fits[False].choice and fits[False].selection["final_start"] == "fresh"
    if continues(candidate_config(fits[True].choice)):
        assert fits[True].selection["final_start"] == "fold fits"
        assert fits[True].result.history[0][2] < fits[False].result.history[0][2]
    else:
        assert fits[True].selection["final_start"] == "fresh"


def test_an_uncertainty_map_the_model_fixes_says_so(tmp_path, monkeypatch):
    """A map the chosen model fixes (Lambertian: no specular, so no roughness either) has no spread at all: its
    picture says so, on a scale where 0 is the bottom, not on a scale of nothing."""
    from mi_svbrdf.cli.optimize import UNIFORM_TOP, uncertainty_images, uncertainty_scales, write_selection

    spread = {"normal_deg": torch.linspace(0, 4, 64).view(1, 1, 8, 8), "diffuse": torch.full((1, 1, 8, 8), 0.003),
              "roughness": torch.zeros(1, 1, 8, 8), "specular": torch.zeros(1, 1, 8, 8)}
    selected = _selected(3, uncertainty=spread)
    scales = uncertainty_scales(selected)
    assert scales["roughness"] == UNIFORM_TOP["roughness"] and scales["diffuse"] == 0.006, scales
    images = uncertainty_images(selected, scales)
    assert "the chosen model fixes this map" in images["specular"][1]
    assert "at every texel" in images["diffuse"][1] and "at every texel" not in images["normal_deg"][1]
    figures = _figures(monkeypatch)
    write_selection(tmp_path, selected, images, None, scales)
    titles = {fig.axes[0].get_title() for fig in figures[1:]}
    assert sum("the fold fits agree exactly" in t for t in titles) == 2, titles
