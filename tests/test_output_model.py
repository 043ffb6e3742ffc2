"""Another output BRDF model (issue 17 §3, thesis ch. 6.1.1): the loss's target_distribution on both backends,
the optimiser's and the nets' output model, material folders recording it, and the held-out comparison."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
import torch

import mi_svbrdf as ms
from mi_svbrdf.core import maps as M
from mi_svbrdf.core.configurations import sample_configurations
from mi_svbrdf.core.loss import map_l1, rendering_ms_ssim_loss
from mi_svbrdf.core.metrics import evaluate_maps
from mi_svbrdf.data import procedural
from mi_svbrdf.data.photo_setups import capture_config, render_captures, sample_captures
from mi_svbrdf.io import material_io
from mi_svbrdf.io.calibrated_photos import capture_from_simulator, save_capture
from mi_svbrdf.optim import OptimizeConfig, initial_maps
from mi_svbrdf.optim.forward import TexelForward, forward_for
from mi_svbrdf.optim.loop import rerender_loss, target_bounds
from mi_svbrdf.optim.params import from_maps, to_maps
from tests.conftest import random_maps

pytestmark = pytest.mark.usefixtures("one_thread", "cpu_scene_variant")  # mi.Float below: the CPU's variant

PAIRS = [("beckmann", "ggx"), ("ggx", "beckmann")]


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _hand_loss(pred, target, cfg, distribution: str, target_distribution: str, intensity: float = 1.0,
               eps: float = 0.01) -> torch.Tensor:
    """Float64 reference: each side rendered with its own model by the torch renderer (conventions.md's light)."""
    kw = dict(intensity=intensity, light_z_division=True, distance_falloff=False, backend="torch")
    r_p = ms.render(pred.double(), cfg.light.double(), cfg.view.double(), distribution=distribution, **kw)
    r_t = ms.render(target.double(), cfg.light.double(), cfg.view.double(), distribution=target_distribution, **kw)
    return (torch.log(r_t + eps) - torch.log(r_p + eps)).abs().mean()


# ----------------------------------------------------------------------------------------------
# The loss
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("distribution, target_distribution", PAIRS)
def test_cross_model_loss_backends_agree_on_value_and_gradient(distribution, target_distribution):
    pred = random_maps(2, 16, 16, seed=1, rough_range=(0.05, 1.0))
    target = random_maps(2, 16, 16, seed=2, rough_range=(0.05, 1.0))
    cfg = sample_configurations(2, generator=_gen(3))
    ref = _hand_loss(pred, target, cfg, distribution, target_distribution)
    values, grads = {}, {}
    for backend, m in (("mitsuba", pred), ("torch", pred.double())):
        m = m.clone().requires_grad_()
        loss = ms.rendering_loss(m, target.to(m.dtype), configurations=cfg, distribution=distribution,
                                 target_distribution=target_distribution, backend=backend)
        loss.backward()
        values[backend], grads[backend] = loss.item(), m.grad
    assert values["mitsuba"] == pytest.approx(float(ref), rel=1e-5)
    assert values["torch"] == pytest.approx(float(ref), rel=1e-9)
    for name, sl in M.SLICES.items():
        g_mi, g_ref = grads["mitsuba"][:, sl].double(), grads["torch"][:, sl]
        err = (g_mi - g_ref).abs() / (g_ref.abs() + 1e-3 * g_ref.abs().max() + 1e-12)
        assert torch.quantile(err.flatten(), 0.99) < 1e-3, name
        assert g_ref.abs().sum() > 0, name
    # the target's model matters: the same call with the pred's model for both sides differs
    same = ms.rendering_loss(pred, target, configurations=cfg, distribution=distribution)
    assert abs(float(same) - values["mitsuba"]) > 1e-3 * values["mitsuba"]


@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_loss_is_zero_only_when_the_models_match(backend):
    maps = random_maps(2, 16, 16, seed=4, rough_range=(0.1, 0.9))
    cfg = sample_configurations(2, generator=_gen(5))

    def loss(d: str, t: str | None) -> float:
        return float(ms.rendering_loss(maps, maps.clone(), configurations=cfg, distribution=d,
                                       target_distribution=t, backend=backend))

    assert loss("beckmann", "beckmann") == 0.0 and loss("beckmann", None) == 0.0 and loss("ggx", "ggx") == 0.0
    # the same maps, another model: the lobes differ, so the loss does not vanish
    assert loss("beckmann", "ggx") > 0.02 and loss("ggx", "beckmann") > 0.02


def test_mixed_loss_ms_ssim_and_modules_pass_the_target_model_on():
    pred, target = random_maps(2, 32, 32, seed=6, rough_range=(0.1, 0.9)), random_maps(2, 32, 32, seed=7)
    cfg = sample_configurations(2, generator=_gen(8))
    kw = dict(distribution="beckmann", target_distribution="ggx")
    render19 = ms.rendering_loss(pred, target, preset="2019", configurations=cfg, **kw)
    mixed = ms.mixed_loss(pred, target, configurations=cfg, **kw)
    assert float(mixed) == pytest.approx(float(render19) + 0.1 * float(map_l1(pred, target)), rel=1e-6)
    assert float(mixed) != pytest.approx(float(ms.mixed_loss(pred, target, configurations=cfg,
                                                             distribution="beckmann")), rel=1e-3)
    module = ms.MixedLoss(seed=9, **kw)
    expect = ms.mixed_loss(pred, target, generator=_gen(9), **kw)
    assert float(module(pred, target)) == pytest.approx(float(expect), rel=1e-6)
    module = ms.RenderingLoss(seed=9, **kw)
    expect = ms.rendering_loss(pred, target, generator=_gen(9), **kw)
    assert float(module(pred, target)) == pytest.approx(float(expect), rel=1e-6)
    # MS-SSIM of the renderings: 1 - 1 = 0 for the same maps and model, > 0 across models
    assert float(rendering_ms_ssim_loss(pred, pred, cfg, distribution="beckmann")) == pytest.approx(0.0, abs=1e-6)
    assert float(rendering_ms_ssim_loss(pred, pred, cfg, **kw)) > 1e-4


def test_bad_target_distribution_names_the_argument():
    maps = random_maps(1, 8, 8, seed=10)
    cfg = sample_configurations(1, generator=_gen(0))
    for call in (lambda: ms.rendering_loss(maps, maps, configurations=cfg, target_distribution="phong"),
                 lambda: ms.mixed_loss(maps, maps, configurations=cfg, target_distribution="phong"),
                 lambda: rendering_ms_ssim_loss(maps, maps, cfg, target_distribution="phong"),
                 lambda: ms.RenderingLoss(target_distribution="phong"),
                 lambda: ms.MixedLoss(target_distribution="phong")):
        with pytest.raises(ValueError, match="target_distribution: expected None or one of"):
            call()
    with pytest.raises(ValueError, match="^distribution: expected one of"):
        ms.rendering_loss(maps, maps, configurations=cfg, distribution="phong", target_distribution="ggx")


def test_evaluate_maps_renders_each_side_with_its_model():
    maps = random_maps(1, 16, 16, seed=11, rough_range=(0.1, 0.9))
    same = evaluate_maps(maps, maps, distribution="beckmann", gt_distribution="beckmann")
    cross = evaluate_maps(maps, maps, distribution="beckmann", gt_distribution="ggx")
    assert same["rmse_render"] == 0.0 and cross["rmse_render"] > 1e-3
    assert cross["rmse_roughness"] == 0.0  # the maps are the same; only the re-rendering differs


# ----------------------------------------------------------------------------------------------
# The equal-width roughness conversion
# ----------------------------------------------------------------------------------------------

def _half_width(distribution: str, roughness: float) -> float:
    """tan(theta_h) where D cos^4 falls to half its peak, found numerically with the plugin's D."""
    from mi_svbrdf.plugins.model import distribution_d

    t = np.linspace(0.0, 3.0, 200_001)
    c = 1.0 / np.sqrt(1.0 + t * t)
    d = np.asarray(distribution_d(mi.Float(c), mi.Float(roughness ** 2), distribution)) * c ** 4
    dr.eval()
    return float(np.interp(0.5, (d / d[0])[::-1], t[::-1]))


@pytest.mark.parametrize("r", [0.2, 0.45, 0.7])
def test_equivalent_roughness_matches_the_lobes_half_width(r):
    from mi_svbrdf.eval.studies.output_model import equivalent_roughness

    rb = float(equivalent_roughness(torch.tensor(r), "ggx", "beckmann"))
    assert rb == pytest.approx(0.8792 * r, rel=1e-3)
    assert _half_width("beckmann", rb) == pytest.approx(_half_width("ggx", r), rel=1e-3)
    assert abs(_half_width("beckmann", r) - _half_width("ggx", r)) > 0.05 * _half_width("ggx", r)  # not identity
    back = equivalent_roughness(torch.tensor(rb), "beckmann", "ggx")
    assert float(back) == pytest.approx(r, rel=1e-6)
    with pytest.raises(ValueError, match="target: expected one of"):
        equivalent_roughness(torch.tensor(r), "ggx", "phong")


# ----------------------------------------------------------------------------------------------
# Material folders
# ----------------------------------------------------------------------------------------------

def test_material_folder_records_the_model_and_defaults_to_ggx(tmp_path: Path):
    maps = M.constant_maps(1, 4, 4, roughness=0.4)
    meta = material_io.write_material(tmp_path / "b", maps, fmt="exr", distribution="beckmann")
    assert meta["distribution"] == "beckmann"
    assert json.loads((tmp_path / "b" / "material.json").read_text())["distribution"] == "beckmann"
    assert material_io.read_distribution(tmp_path / "b") == "beckmann"
    assert torch.allclose(material_io.read_material(tmp_path / "b"), maps, atol=1e-6)
    material_io.write_material(tmp_path / "g", maps)
    assert material_io.read_distribution(tmp_path / "g") == "ggx"
    # an old folder (material.json without the key) and a folder without material.json are GGX
    path = tmp_path / "g" / "material.json"
    old = json.loads(path.read_text())
    del old["distribution"]
    path.write_text(json.dumps(old))
    assert material_io.read_distribution(tmp_path / "g") == "ggx"
    path.unlink()
    assert material_io.read_distribution(tmp_path / "g") == "ggx"
    (tmp_path / "b" / "material.json").write_text(json.dumps({**meta, "distribution": "phong"}))
    with pytest.raises(ValueError, match="material.json: expected 'distribution'"):
        material_io.read_distribution(tmp_path / "b")
    with pytest.raises(ValueError, match="distribution: expected one of"):
        material_io.write_material(tmp_path / "x", maps, distribution="phong")


def test_render_cli_honours_the_folders_model(tmp_path: Path):
    from mi_svbrdf.cli.render import main as render_main

    maps = M.constant_maps(1, 32, 32, diffuse=0.3, specular=0.3, roughness=0.3)
    material_io.write_material(tmp_path / "m", maps, fmt="exr", distribution="beckmann")
    assert render_main(["render", "--material", str(tmp_path / "m"), "--spp", "4", "-o", str(tmp_path / "out")]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["distribution"] == "beckmann" and summary["scene_parameters"]["distribution"] == "beckmann"
    assert material_io.read_distribution(tmp_path / "out" / "material") == "beckmann"
    # the scene and the texel renderer both used Beckmann: they agree far better than the two models do
    # (flash_capture's defaults: flash and camera at z = 2.1445069, intensity 14.4479 = pi * I)
    z = torch.tensor([[[0.0, 0.0, 2.1445069]]])
    ggx, beck = (ms.render(maps, z, z, intensity=14.4479 / math.pi, distance_falloff=True, distribution=d)
                 for d in ("ggx", "beckmann"))
    assert float((ggx - beck).abs().mean()) > 0.08
    assert summary["texel_vs_mitsuba_mean_abs_diff"] < 0.03


def test_calibrate_averages_a_beckmann_material_as_beckmann():
    from mi_svbrdf.eval import measured_comparison as C

    maps = M.constant_maps(1, 4, 4, diffuse=0.2, specular=0.3, roughness=0.35)
    wi = torch.tensor([[0.3, 0.0, 0.954]], dtype=torch.float64)
    wo = torch.tensor([[-0.3, 0.05, 0.952]], dtype=torch.float64)
    ggx = C.average_material(maps).brdf(wi, wo)
    beck = C.average_material(maps, distribution="beckmann").brdf(wi, wo)
    assert torch.allclose(beck, C.model_brdf(maps[0].permute(1, 2, 0).reshape(-1, 10)[:1], wi, wo,
                                             distribution="beckmann"), rtol=1e-5)
    assert float((beck - ggx).abs().max()) > 1e-2 * float(ggx.abs().max())
    with pytest.raises(ValueError, match="distribution: expected one of"):
        C.average_material(maps, distribution="phong")


# ----------------------------------------------------------------------------------------------
# The optimiser
# ----------------------------------------------------------------------------------------------

def _ggx_capture(size: int, n: int, seed: int = 0):
    """A calibrated 8-bit capture of a glossy procedural material rendered with GGX (the simulator's model)."""
    gt = procedural.generate("tiles", 1, size)[None]
    cfg = capture_config(ambient=False, noise=False, intensity_jitter=False, intensity=4.0)
    cap = sample_captures(1, n, cfg, _gen(seed))
    spec, images = capture_from_simulator(cap, 0, render_captures(gt, cap, backend="torch"), encoding="srgb8")
    return gt, spec, images


def test_fused_objective_uses_the_output_model():
    _, spec, images = _ggx_capture(16, 3)
    lo, hi = target_bounds(images, torch.ones(3, 1, 16, 16, dtype=torch.bool), ["srgb8"] * 3)
    x = from_maps(initial_maps(spec, images)) + 0.2 * torch.randn(1, 9, 16, 16, generator=_gen(1))
    values = {}
    for model in ("ggx", "beckmann"):
        ref = rerender_loss(TexelForward(spec, 16, "torch", model)(to_maps(x)), lo, hi)
        got = TexelForward(spec, 16, "mitsuba", model).fused_objective(lo, hi, "log_l1", 0.0)(x)
        assert float(got) == pytest.approx(float(ref), rel=1e-5), model
        values[model] = float(ref)
    assert abs(values["ggx"] - values["beckmann"]) > 1e-3 * values["ggx"]
    assert forward_for(spec, 16, "texel", "torch", "beckmann").distribution == "beckmann"
    with pytest.raises(ValueError, match="OptimizeConfig.distribution: expected one of"):
        OptimizeConfig(distribution="phong")
    with pytest.raises(ValueError, match="distribution: expected one of"):
        TexelForward(spec, 16, "torch", "phong")


def test_beckmann_fit_of_ggx_photos_lowers_its_loss_and_records_the_model(tmp_path: Path):
    from mi_svbrdf.cli.optimize import main as cli_main

    _, spec, images = _ggx_capture(32, 4)
    save_capture(tmp_path / "cap" / "capture.json", spec, images)
    out = tmp_path / "out"
    code = cli_main(["--capture", str(tmp_path / "cap"), "-o", str(out), "--iterations", "120", "--no-progress",
                     "--distribution", "beckmann", "--select", "full", "--early-stop", "off"])  # 120 steps, all photos
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["distribution"] == "beckmann"
    assert json.loads((out / "material" / "material.json").read_text())["distribution"] == "beckmann"
    assert material_io.read_distribution(out / "material") == "beckmann"
    losses = [float(line.split(",")[2]) for line in (out / "history.csv").read_text().splitlines()[1:]]
    assert losses[-1] < 0.6 * losses[0]
    # the maps were fitted for Beckmann: re-rendered with Beckmann they explain the photos better than as GGX
    fit = material_io.read_material(out / "material")
    lo, hi = target_bounds(images, torch.ones(4, 1, 32, 32, dtype=torch.bool), ["srgb8"] * 4)
    own = float(rerender_loss(TexelForward(spec, 32, "torch", "beckmann")(fit), lo, hi))
    other = float(rerender_loss(TexelForward(spec, 32, "torch", "ggx")(fit), lo, hi))
    assert own < 0.9 * other


# ----------------------------------------------------------------------------------------------
# The nets
# ----------------------------------------------------------------------------------------------

TINY_NET = {"encoder_features": [8, 16, 16], "last_features": 8, "resolution": 32}


def test_beckmann_training_runs_records_the_model_and_captures_write_it(tmp_path: Path):
    from mi_svbrdf.cli.capture import write_capture
    from mi_svbrdf.nets import weights as W
    from mi_svbrdf.nets.inference import predict_details
    from mi_svbrdf.nets.train import RECIPES, TrainConfig, load_config, train, training_loss

    base = {"name": "run", "out": str(tmp_path), "net": TINY_NET, "batch_size": 2, "sizes": [[0, 32]], "steps": 2,
            "warmup": 1, "validate_every": 0, "log_every": 1, "checkpoint_every_s": 1e9, "bf16": False,
            "simulator": {"preset": "single_flash", "pool_size": 4}}
    cfg = TrainConfig.from_dict({**base, "distribution": "beckmann"})
    with pytest.raises(ValueError, match="TrainConfig.distribution: expected one of"):
        TrainConfig.from_dict({**base, "distribution": "phong"})
    # the loss renders the prediction with Beckmann and the (GGX) ground truth with GGX
    pred, truth = random_maps(2, 16, 16, seed=20, rough_range=(0.1, 0.9)), random_maps(2, 16, 16, seed=21)
    got = training_loss(cfg, pred, truth, _gen(22))
    expect = ms.rendering_loss(pred, truth, generator=_gen(22), distribution="beckmann", target_distribution="ggx")
    assert float(got) == pytest.approx(float(expect), rel=1e-6)
    assert abs(float(training_loss(dataclasses.replace(cfg, distribution="ggx"), pred, truth, _gen(22)))
               - float(got)) > 1e-3 * float(got)
    run = train(cfg, progress=False)
    state = torch.load(run / "checkpoint.pt", weights_only=False)
    assert state["step"] == 2 and state["config"]["distribution"] == "beckmann"
    assert all(math.isfinite(r["loss"]) for r in state["log"])
    # bundled: the manifest entry records it, inference passes it on, a capture folder writes it
    folder = tmp_path / "weights"
    entry = W.export_weights(run / "checkpoint.pt", folder=folder)
    assert entry["distribution"] == "beckmann" and W.entry_distribution({}) == "ggx"
    photos = torch.rand(1, 1, 3, 64, 64, generator=_gen(23))  # the smallest photo predict takes
    result = predict_details(photos, kind="single", weights_dir=folder)
    assert result.distribution == "beckmann"
    summary = write_capture(tmp_path / "capture", result, frames=0)
    assert summary["distribution"] == "beckmann"
    assert material_io.read_distribution(tmp_path / "capture") == "beckmann"
    assert material_io.read_distribution(tmp_path / "capture" / "exr") == "beckmann"
    # the held-out comparison scores the net with its own model
    from mi_svbrdf.eval.studies.output_model import OutputModelConfig, compare_nets

    nets = compare_nets({"tiny beckmann": run / "checkpoint.pt"}, OutputModelConfig(materials=1, size=64, cache=False))
    assert [(r["label"], r["model"], r["n_images"]) for r in nets.rows] == [("tiny beckmann", "beckmann", 1)]
    assert math.isfinite(nets.rows[0]["rmse_render"])
    # the lead's fine-tune recipe
    recipe = load_config("single-beckmann")
    assert recipe.distribution == "beckmann" and recipe.init == "bundled:single" and recipe.kind == "single"
    assert RECIPES["single-beckmann"]["sizes"] == [[0, 128]] and recipe.steps <= 1000


# ----------------------------------------------------------------------------------------------
# The held-out comparison
# ----------------------------------------------------------------------------------------------

def test_score_renders_each_output_with_its_own_model():
    from mi_svbrdf.eval.studies.output_model import score

    truth = random_maps(1, 16, 16, seed=30, rough_range=(0.1, 0.9))
    as_ggx = score(truth, truth, "ggx")
    as_beck = score(truth, truth, "beckmann")
    assert as_ggx["rmse_render"] == 0.0 and as_ggx["rmse_roughness_equiv"] == 0.0
    assert as_beck["rmse_render"] > 1e-3 and as_beck["rmse_render_as_ggx"] == 0.0
    assert as_beck["rmse_roughness"] == 0.0 and as_beck["rmse_roughness_equiv"] > 0.01


def test_compare_optimizer_on_a_tiny_held_out_set(tmp_path: Path):
    from mi_svbrdf.eval.harness import load_heldout
    from mi_svbrdf.eval.studies.output_model import OutputModelConfig, compare_optimizer, output_model_table, plot_comparison

    cfg = OutputModelConfig(materials=1, size=16, n_images=2, iterations=8, cache=False,
                            optimizer={"start_iterations": 3})
    comparison = compare_optimizer(cfg, load_heldout(cfg.heldout(), progress=False))
    assert [r["label"] for r in comparison.rows] == ["optimize ggx", "optimize beckmann"]
    steps = [r["steps"] for r in comparison.rows]
    assert steps[0] == steps[1] > 0  # equal iterations
    for row in comparison.rows:
        assert all(math.isfinite(row[k]) and row[k] >= 0 for k in ("rmse_render", "rmse_roughness_equiv"))
    assert comparison.settings["roughness_ratio"] is not None
    table = output_model_table(comparison)
    assert "| optimize beckmann | beckmann |" in table
    plot_comparison(comparison, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(ValueError, match="OutputModelConfig.models"):
        OutputModelConfig(models=("ggx", "phong"))
    with pytest.raises(ValueError, match="OutputModelConfig.optimizer"):
        OutputModelConfig(optimizer={"distribution": "ggx"})


def test_doctests():
    import doctest

    from mi_svbrdf.core import loss
    from mi_svbrdf.eval.studies import output_model

    for module in (loss, material_io, output_model):
        assert doctest.testmod(module).failed == 0, module.__name__
