"""The tensors choose Dr.Jit's backend, never the active Mitsuba variant.

mi_svbrdf's kernels (the texel renderer, the rendering loss, the optimiser's fused objective) build their
arrays with the types of their inputs' backend (:mod:`mi_svbrdf.core.device`), so they give the same numbers
whichever variant is active, and they never switch it: switching costs ~0.3 s on a GPU machine and changes
global state other code relies on. Only Mitsuba's scenes need a variant, entered at one boundary
(:func:`mi_svbrdf.variant.scene_variant`).

A machine without a GPU cannot set ``cuda_ad_rgb``, but any variant other than the tensors' one shows the
same defect: here ``scalar_rgb`` stands in for it. The suite's tests that launch a kernel also run with it active
from the start (``MI_SVBRDF_TEST_VARIANT=scalar_rgb ... --kernel-tests``, ``.ci/run``'s last pass).
"""
from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import drjit as dr
import drjit.llvm.ad as llvm
import mitsuba as mi
import numpy as np
import pytest
import torch

from mi_svbrdf import plugins
from mi_svbrdf.core.configurations import sample_configurations
from mi_svbrdf.core.device import check_jit_device, jit_types_of
from mi_svbrdf.core.loss import rendering_loss
from mi_svbrdf.core.render import render
from mi_svbrdf.data import procedural
from mi_svbrdf.data.photo_setups import capture_config, render_captures, sample_captures
from mi_svbrdf.io.calibrated_photos import capture_from_simulator
from mi_svbrdf.nets import train as T
from mi_svbrdf.optim import OptimizeConfig, optimize
from mi_svbrdf.optim.refine import RefineConfig, refine
from mi_svbrdf.variant import scene_variant, variant_context
from tests.conftest import random_maps

#: A variant whose backend is not the CPU tensors' (LLVM): the stand-in for ``cuda_ad_rgb`` with CPU tensors.
OTHER = "scalar_rgb"


@contextlib.contextmanager
def counted_switches(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[str]]:
    """Every ``mi.set_variant`` call made inside the block, by name."""
    calls: list[str] = []
    real = mi.set_variant

    def counting(*names: str) -> None:
        calls.append(names[0])
        real(*names)

    monkeypatch.setattr(mi, "set_variant", counting)
    try:
        yield calls
    finally:
        monkeypatch.setattr(mi, "set_variant", real)


def _capture(size: int = 32, n: int = 3):
    gt = procedural.generate("tiles", 1, size)[None]
    cfg = capture_config(ambient=False, noise=False, intensity_jitter=False, intensity=4.0)
    cap = sample_captures(1, n, cfg, torch.Generator().manual_seed(0))
    spec, images = capture_from_simulator(cap, 0, render_captures(gt, cap, backend="torch"), encoding="srgb8")
    return gt, spec, images


def test_kernels_give_the_same_numbers_under_another_variant() -> None:
    """Loss value and gradient, and a render, are bit-identical with ``scalar_rgb`` active and with ``llvm_ad_rgb``."""
    pred, gt = random_maps(2, 16, 16, seed=1), random_maps(2, 16, 16, seed=2)
    cfg = sample_configurations(2, generator=torch.Generator().manual_seed(0))
    results = []
    for variant in ("llvm_ad_rgb", OTHER):
        with variant_context(variant):
            p = pred.clone().requires_grad_()
            loss = rendering_loss(p, gt, configurations=cfg)
            loss.backward()
            img = render(gt, cfg.light, cfg.view, distance_falloff=True, backend="mitsuba")
            assert mi.variant() == variant  # the call did not switch it
            results.append((loss.detach(), p.grad, img))
    for a, b in zip(*results):
        assert torch.equal(a, b)


def test_no_variant_switch_in_a_loss_call_an_optimiser_step_a_refinement_or_a_training_step(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """In the steady state (after a first warm-up call) each of them switches the variant 0 times, with the
    tensors' variant active and with another one active."""
    pred, gt = random_maps(1, 16, 16, seed=3), random_maps(1, 16, 16, seed=4)
    _, spec, images = _capture()
    photos = images[None].clamp(0.0, 1.0)
    train_cfg = T.TrainConfig.from_dict({
        "name": "run", "out": str(tmp_path), "net": {"encoder_features": [8, 16, 16], "last_features": 8,
                                                    "resolution": 32},
        "batch_size": 2, "sizes": [[0, 32]], "steps": 3, "warmup": 1, "validate_every": 0, "log_every": 1,
        "checkpoint_every_s": 1e9, "bf16": False, "simulator": {"preset": "single_flash", "pool_size": 4}})
    cpu = torch.device("cpu")
    net, opt, _, _, _ = T._start(train_cfg, None, cpu, T.grad_scaler(train_cfg, cpu))
    sim = T.make_simulator(train_cfg, 32)

    def loss_call() -> None:
        p = pred.clone().requires_grad_()
        rendering_loss(p, gt, generator=torch.Generator().manual_seed(0)).backward()

    def optimiser_steps() -> None:  # the fused texel objective, 3 Adam steps, no multi-start
        optimize(spec, images, config=OptimizeConfig(iterations=3, roughness_starts=(0.5,), budget_s=float("inf"),
                                                     progress=False))

    def refinement() -> None:
        refine(photos[0], start, config=RefineConfig(budget_s=1.0, progress=False))

    def training_step() -> None:
        batch = sim.batch(0)
        T._train_step(train_cfg, net, net, opt, batch, 0, 0, tmp_path / "c.pt", cpu)

    start = random_maps(1, 32, 32, seed=5)
    for variant in ("llvm_ad_rgb", OTHER):
        with variant_context(variant):
            for name, work in (("loss", loss_call), ("optimiser", optimiser_steps), ("refine", refinement),
                               ("training step", training_step)):
                work()  # warm-up
                with counted_switches(monkeypatch) as switches:
                    work()
                assert switches == [], f"{name} under {variant}: switched the variant to {switches}"
                assert mi.variant() == variant


def test_scene_rendering_enters_its_variant_at_one_boundary_and_restores_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """The Mitsuba forward model (scenes) works with another variant active: the fit enters ``llvm_ad_rgb``
    once for the whole fit (not per step) and restores the caller's variant."""
    _, spec, images = _capture(16, 2)
    cfg = OptimizeConfig(iterations=4, roughness_starts=(0.5,), budget_s=float("inf"), progress=False,
                         path="mitsuba", validate_photo=False)
    with variant_context(OTHER):
        with counted_switches(monkeypatch) as switches:
            res = optimize(spec, images, config=cfg)
        assert mi.variant() == OTHER
    assert res.steps == 4 and bool(torch.isfinite(res.maps).all())
    assert switches == ["llvm_ad_rgb", OTHER], switches


def test_plugins_are_defined_for_each_variant() -> None:
    """A plugin class derives from the ``mi.BSDF`` of the variant it is registered for, whichever variant the
    plugin modules were first imported under."""
    with variant_context(OTHER):
        svbrdf_other, _ = plugins.bsdf_classes()
        assert issubclass(svbrdf_other, mi.BSDF)
    with scene_variant("cpu"):
        svbrdf, aniso = plugins.bsdf_classes()
        assert issubclass(svbrdf, mi.BSDF) and issubclass(aniso, svbrdf)
        bsdf = mi.load_dict({"type": "svbrdf_ggx", "roughness": 0.3})
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(0.0, 0.0, 1.0)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        value = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(0.0, 0.6, 0.8)))
        assert value.size == 3 and (value > 0).all()


def test_device_helpers() -> None:
    assert jit_types_of(llvm.Float([1.0])).__name__ == "drjit.llvm.ad"
    with pytest.raises(ValueError, match="pred: expected tensors on cpu or cuda .* got meta"):
        check_jit_device(pred=torch.zeros(1, device="meta"))
    with pytest.raises(ValueError, match="target: expected a tensor on pred's device cpu, got meta"):
        check_jit_device(pred=torch.zeros(1), target=torch.zeros(1, device="meta"))
