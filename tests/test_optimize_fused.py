"""Tests of the fused optimisation objective, coarse-to-fine and the ``mi_svbrdf.optimize`` export."""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

import mi_svbrdf
from mi_svbrdf.core.maps import normal
from mi_svbrdf.data import procedural
from mi_svbrdf.data.photo_setups import capture_config, render_captures, sample_captures
from mi_svbrdf.io.calibrated_photos import capture_from_simulator
from mi_svbrdf.io.material_io import srgb_decode, srgb_encode
from mi_svbrdf.optim import OptimizeConfig, initial_maps
from mi_svbrdf.optim.forward import TexelForward
from mi_svbrdf.optim.loop import LoopConfig, rerender_loss, run, target_bounds
from mi_svbrdf.optim.params import from_maps, to_maps, total_variation


def capture(size: int, n: int, *, intensity: float = 4.0, seed: int = 0, name: str = "tiles"):
    """A calibrated rectified capture (flash with cone) of a procedural material."""
    gt = procedural.generate(name, 1, size)[None]
    cfg = capture_config(ambient=False, noise=False, intensity_jitter=False, intensity=intensity)
    cap = sample_captures(1, n, cfg, torch.Generator().manual_seed(seed))
    spec, images = capture_from_simulator(cap, 0, render_captures(gt, cap, backend="torch"), encoding="srgb8")
    return gt, spec, images


def test_bounds_are_each_codes_interval_and_the_kernel_reads_them_in_place():
    """The intervals of 8-bit codes (the sRGB curve on tensors, as the colour library draws it for files), a
    linear photo's own values, inf where clipped; the fused objective reads the caller's bounds without a copy
    (at 2048^2 a copy is 50 MB a photo, twice)."""
    _, spec, images = capture(16, 3)
    images[0, :, 0, 0] = 1.0  # the top code: a clipped channel
    valid = torch.ones(3, 1, 16, 16, dtype=torch.bool)
    valid[1, :, 3, 3] = False
    lo, hi = target_bounds(images, valid, ["srgb8", "srgb8", "linear_exr"])
    half = 0.5 / 255.0
    code = srgb_encode(images[:2].numpy())
    assert torch.equal(lo[:2], torch.from_numpy(srgb_decode(np.clip(code - half, 0.0, 1.0))))
    up = torch.from_numpy(srgb_decode(np.clip(code + half, 0.0, 1.0)))
    top = torch.from_numpy(code >= 1.0 - half)
    open_ = top | ~valid[:2].expand_as(top)  # the top code or a pixel marked saturated: no upper bound
    assert bool(top[0, :, 0, 0].all()) and bool(open_[1, :, 3, 3].all())
    assert torch.equal(hi[:2][~open_], up[~open_]) and bool(torch.isinf(hi[:2][open_]).all())
    assert torch.equal(lo[2], images[2]) and torch.equal(hi[2], images[2])
    fused = TexelForward(spec, 16, "mitsuba").fused_objective(lo, hi, "log_l1", 0.0)
    assert fused.lo.data_ptr() == lo.data_ptr() and fused.hi.data_ptr() == hi.data_ptr()


@pytest.mark.parametrize("kind, tv, ambient", [("log_l1", 0.0, False), ("log_l1", 0.05, False), ("l2", 0.02, False),
                                               ("log_l1", 0.05, True), ("l2", 0.0, True),
                                               ("l2_display", 0.0, False), ("l2_display", 0.02, True)])
def test_fused_objective_equals_unfused(kind, tv, ambient):
    """Value and gradient of the one-kernel objective equal residual + TV through autograd
    (with ambient lights too: the held-out captures have one per photo)."""
    gt, spec, images = capture(24, 4, intensity=10.0)
    if ambient:  # the multiview simulator's ambient point light on every photo, photo 1 given a second
        cap = sample_captures(1, 4, "multiview", torch.Generator().manual_seed(3))
        amb, _ = capture_from_simulator(cap, 0, images)
        extra = [list(im.extra_lights) for im in amb.images]
        extra[1] = extra[1] + extra[2]
        assert all(len(e) for e in extra)
        spec = dataclasses.replace(spec, images=[dataclasses.replace(im, extra_lights=tuple(e))
                                                 for im, e in zip(spec.images, extra)])
        images = TexelForward(spec, 24, "torch")(gt).clamp(0.0, 1.0)
    valid = images.amax(dim=1, keepdim=True) < 0.99  # bright flash: some saturated pixels (hi = inf)
    assert 0 < float((~valid).float().mean()) < 0.9
    lo, hi = target_bounds(images, valid, ["srgb8"] * 4)
    fwd = TexelForward(spec, 24, "mitsuba")
    x = (from_maps(initial_maps(spec, images)) + 0.3 * torch.randn(1, 9, 24, 24,
                                                                   generator=torch.Generator().manual_seed(1)))
    x.requires_grad_(True)
    maps = to_maps(x)
    ref = rerender_loss(fwd(maps), lo, hi, kind) + tv * total_variation(maps)
    (g_ref,) = torch.autograd.grad(ref, x)
    fused = fwd.fused_objective(lo, hi, kind, tv)
    got = fused(x)
    (g_got,) = torch.autograd.grad(got, x)
    assert abs(float(got.detach()) - float(ref.detach())) < 1e-5 * float(ref.detach())
    assert float((g_got - g_ref).abs().max()) < 1e-4 * float(g_ref.abs().max())
    assert float(g_ref.abs().max()) > 0
    if ambient:  # the ambient light matters: without it the objective differs
        plain = TexelForward(dataclasses.replace(spec, images=[dataclasses.replace(im, extra_lights=())
                                                               for im in spec.images]), 24, "mitsuba")
        other = float(plain.fused_objective(lo, hi, kind, tv)(x).detach())
        assert abs(other - float(ref.detach())) > 1e-3 * float(ref.detach())


def test_fused_objective_only_where_exact():
    """The torch backend falls back to the unfused objective."""
    _, spec, images = capture(8, 2)
    lo = hi = images
    assert TexelForward(spec, 8, "torch").fused_objective(lo, hi, "log_l1", 0.0) is None
    assert TexelForward(spec, 8, "mitsuba").fused_objective(lo, hi, "log_l1", 0.0) is not None


def test_fused_and_unfused_loops_follow_the_same_path():
    _, spec, images = capture(24, 4)
    lo, hi = target_bounds(images, torch.ones(4, 1, 24, 24, dtype=torch.bool), ["srgb8"] * 4)
    fwd = TexelForward(spec, 24, "mitsuba")
    start = from_maps(initial_maps(spec, images))
    cfg = dict(iterations=15, tol=0.0, progress=False)
    a = run(fwd, lo, hi, start, LoopConfig(**cfg, fused=True))
    b = run(fwd, lo, hi, start, LoopConfig(**cfg, fused=False))
    la, lb = [h[2] for h in a.history], [h[2] for h in b.history]
    assert len(la) == len(lb) == 15 and la[-1] < la[0] / 2
    assert max(abs(p - q) / q for p, q in zip(la, lb)) < 1e-3
    diff = (a.variables - b.variables).abs()  # Adam amplifies float noise where a gradient is ~0
    assert float(diff.mean()) < 1e-3 and float(diff.max()) < 0.05


def test_run_copies_its_start_unless_it_is_handed_over():
    """``take``: the fit steps the caller's variables in place (one copy of them at the top level, 150 MB at 2048^2)
    and the same path as from a copy; without it the start is left as it was."""
    _, spec, images = capture(16, 3)
    lo, hi = target_bounds(images, torch.ones(3, 1, 16, 16, dtype=torch.bool), ["srgb8"] * 3)
    fwd = TexelForward(spec, 16, "mitsuba")
    start = from_maps(initial_maps(spec, images))
    kept = start.clone()
    cfg = LoopConfig(iterations=5, tol=0.0, progress=False)
    copied = run(fwd, lo, hi, start, cfg)
    assert torch.equal(start, kept) and not torch.equal(copied.variables, kept)
    handed = run(fwd, lo, hi, start, cfg, take=True)
    assert handed.variables.data_ptr() == start.data_ptr() and torch.equal(handed.variables, copied.variables)


def test_optimize_config_fused_switch(monkeypatch):
    """OptimizeConfig(fused=False) reaches the loop: the forward model's fused objective is never asked for."""
    from mi_svbrdf import optimize
    from mi_svbrdf.optim import OptimizeConfig

    _, spec, images = capture(16, 2)
    asked = []
    original = TexelForward.fused_objective
    monkeypatch.setattr(TexelForward, "fused_objective", lambda self, *a: asked.append(1) or original(self, *a))
    cfg = dict(iterations=4, start_iterations=2, progress=False)
    optimize(spec, images, config=OptimizeConfig(**cfg, fused=False))
    assert asked == []
    optimize(spec, images, config=OptimizeConfig(**cfg))
    assert asked


def test_coarse_to_fine(forward_sizes):
    """levels=2 fits at half resolution first, then at full resolution, and still recovers the maps."""
    import mi_svbrdf.optim.fit as opt_pkg  # where optimize looks forward_for up

    sizes = forward_sizes
    gt, spec, images = capture(32, 12)
    # Run to convergence, the schedule annealed over the run's 1000 steps. Before it settles the normals' RMSE is
    # that of a few texels still turning (up to 28 degrees off at 160 steps), whose last bits follow Dr.Jit's LLVM
    # vector width (MI_SVBRDF_TEST_LLVM_WIDTH, tests/conftest.py): measured at widths 4 / 8 / 16 vs 0.0177 at the
    # start, 0.0107 / 0.0101 / 0.0153 at 160 steps, 0.0095 / 0.0084 / 0.0075 at 300, 0.0052 / 0.0101 / 0.0061 at
    # 600; from 800 steps on it stays at 0.0043-0.0055 at every width (800, 1000, 1200, 1500 and 2000 steps).
    cfg = OptimizeConfig(iterations=1000, schedule_steps=1000, levels=2, tol=0.0, roughness_starts=(0.3,),
                         progress=False, early_stop="off")
    res = opt_pkg.optimize(spec, images, config=cfg)
    assert sizes == [(16, 16), (32, 32)]
    assert tuple(res.maps.shape) == (1, 10, 32, 32) and torch.isfinite(res.maps).all()
    steps = [h[1] for h in res.history]
    assert steps == sorted(steps) and res.steps == 1000 and len(set(steps)) == len(steps)
    normal_rmse = float((normal(res.maps) - normal(gt)).pow(2).mean().sqrt())
    start_rmse = float((normal(initial_maps(spec, images)) - normal(gt)).pow(2).mean().sqrt())
    # measured 0.0054 / 0.0047 / 0.0050 (widths 4 / 8 / 16) vs 0.0177: at most 0.31 of the start at any width
    assert normal_rmse < 0.5 * start_rmse, (normal_rmse, start_rmse)
    assert res.history[-1][2] < 0.5 * res.history[0][2]  # measured 0.0007-0.0010 vs 0.077 at every width
    # ... and the maps as a whole as well as the single-level fit of the same steps (measured 0.0287 / 0.0286 /
    # 0.0287 vs 0.0434 / 0.0434 / 0.0431 at widths 4 / 8 / 16: 0.66 of it at each)
    flat = opt_pkg.optimize(spec, images, config=dataclasses.replace(cfg, levels=1))
    rmse = float((res.maps - gt).pow(2).mean().sqrt())
    flat_rmse = float((flat.maps - gt).pow(2).mean().sqrt())
    assert rmse < 1.05 * flat_rmse, (rmse, flat_rmse)


def test_package_exports_optimize_lazily():
    assert mi_svbrdf.optimize is mi_svbrdf.optim.optimize
    assert mi_svbrdf.OptimizeConfig is OptimizeConfig
    with pytest.raises(AttributeError, match="no_such_name"):
        mi_svbrdf.no_such_name  # noqa: B018
    code = ("import sys, mi_svbrdf; assert 'mi_svbrdf.optim' not in sys.modules; "
            "assert callable(mi_svbrdf.optimize); assert 'mi_svbrdf.optim' in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, env=os.environ.copy(), timeout=120)


@pytest.mark.parametrize("texel, smooth", [(False, 0.0), (True, 0.0), (True, 0.01)])
def test_prior_folded_into_the_fused_objective_equals_the_pytorch_terms(texel, smooth):
    """The prior's pull and chroma term computed in the fused kernel (Prior.fold_quadratic) give the value and
    gradient of the fused objective plus the prior written plainly in PyTorch (Prior.reference, autograd)."""
    from mi_svbrdf.optim.loop import Prior, _objective

    _, spec, images = capture(16, 3, intensity=10.0)
    lo, hi = target_bounds(images, torch.ones(3, 1, 16, 16, dtype=torch.bool), ["srgb8"] * 3)
    fwd = TexelForward(spec, 16, "mitsuba")
    gen = torch.Generator().manual_seed(2)
    x = (from_maps(initial_maps(spec, images)) + 0.3 * torch.randn(1, 9, 16, 16, generator=gen)).requires_grad_(True)
    prior = Prior(anchor=torch.randn(1, 9, 16, 16, generator=gen), anchor_weight=0.05,
                  map_weights=(1.0, 0.5, 2.0, 1.5), chroma_weight=0.3,
                  chroma_texel=1.0 + torch.rand(1, 1, 16, 16, generator=gen) if texel else None,
                  smooth_weight=smooth)
    cfg = LoopConfig(tv_weight=0.02)
    got = _objective(fwd, lo, hi, cfg, prior)(x)
    (g_got,) = torch.autograd.grad(got, x)
    ref = fwd.fused_objective(lo, hi, cfg.loss, cfg.tv_weight)(x) + prior.reference(x)
    if smooth:
        ref = ref + smooth * total_variation(torch.cat([to_maps(x)[:, 6:7], to_maps(x)[:, 7:10]], 1))
    (g_ref,) = torch.autograd.grad(ref, x)
    assert float(got.detach()) == pytest.approx(float(ref.detach()), rel=1e-5)
    torch.testing.assert_close(g_got, g_ref, rtol=1e-4, atol=1e-4 * float(g_ref.abs().max()))
