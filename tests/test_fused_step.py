"""Tests of the fused objective's step-level contract: its gradient against finite differences (priors, TV and a
cone light together), its NaN where the variables are not finite (the loop reads no variables to test them), and
the rendering loss's value and gradient against the float64 PyTorch reference at several sizes in one process."""
from __future__ import annotations

import math

import pytest
import torch

import mi_svbrdf
from mi_svbrdf.data import procedural
from mi_svbrdf.data.photo_setups import capture_config, render_captures, sample_captures
from mi_svbrdf.io.calibrated_photos import capture_from_simulator
from mi_svbrdf.optim import initial_maps
from mi_svbrdf.optim.forward import TexelForward
from mi_svbrdf.optim.loop import LoopConfig, Prior, _objective, target_bounds
from mi_svbrdf.optim.params import from_maps


def _setup(size: int = 16, n: int = 3, smooth: float = 0.0):
    """A flash capture with a cone of a procedural material, its bounds, the objective with TV and a prior, and
    variables near its start."""
    gt = procedural.generate("tiles", 1, size)[None]
    cap = sample_captures(1, n, capture_config(ambient=False, noise=False, intensity_jitter=False, intensity=10.0),
                          torch.Generator().manual_seed(0))
    spec, images = capture_from_simulator(cap, 0, render_captures(gt, cap, backend="torch"), encoding="srgb8")
    valid = images.amax(dim=1, keepdim=True) < 0.99
    lo, hi = target_bounds(images, valid, ["srgb8"] * n)
    fwd = TexelForward(spec, size, "mitsuba")
    gen = torch.Generator().manual_seed(2)
    prior = Prior(anchor=torch.randn(1, 9, size, size, generator=gen), anchor_weight=0.05, chroma_weight=0.3,
                  smooth_weight=smooth)
    objective = _objective(fwd, lo, hi, LoopConfig(tv_weight=0.02), prior)
    x = from_maps(initial_maps(spec, images)) + 0.3 * torch.randn(1, 9, size, size, generator=gen)
    return objective, x


def test_fused_gradient_matches_finite_differences() -> None:
    """The kernel's hand-assembled gradient (per photo with respect to the maps, then the maps' chain rule) against
    central differences of its own value along random directions."""
    objective, x = _setup()
    v = x.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(objective(v), v)
    gen = torch.Generator().manual_seed(5)
    for _ in range(3):
        d = torch.randn(x.shape, generator=gen)
        d /= d.norm()
        h = 3e-3
        with torch.no_grad():
            fd = (float(objective(x + h * d)) - float(objective(x - h * d))) / (2 * h)
        assert float((grad * d).sum()) == pytest.approx(fd, rel=2e-2, abs=1e-5)


@pytest.mark.parametrize("smooth", [0.0, 0.1])
def test_objective_is_nan_where_variables_are_not_finite(smooth: float) -> None:
    """A variable at inf, -inf or NaN makes the objective NaN (with and without gradients, the smoothness term
    added in PyTorch or not), and the objective says so (``checks_finite``): the loop then skips its own test."""
    objective, x = _setup(smooth=smooth)
    assert getattr(objective, "checks_finite", False)
    assert math.isfinite(float(objective(x)))
    for bad in (math.inf, -math.inf, math.nan):
        y = x.clone()
        y[0, 5, 3, 7] = bad
        assert math.isnan(float(objective(y)))
        v = y.clone().requires_grad_(True)
        assert math.isnan(float(objective(v).detach()))


@pytest.mark.parametrize("batch, size", [(2, 16), (3, 24), (1, 8)])
def test_rendering_loss_matches_the_float64_reference(batch: int, size: int) -> None:
    """The fused rendering loss (the target rendered in the prediction's launches, one logarithm per residual)
    against the float64 PyTorch backend, at sizes replayed from one recording."""
    gen = torch.Generator().manual_seed(batch * 100 + size)

    def maps() -> torch.Tensor:
        m = torch.rand(batch, 10, size, size, generator=gen)
        m[:, 2] += 0.5
        return mi_svbrdf.core.maps.normalize_normals(m)

    pred, target = maps(), maps()
    p = pred.clone().requires_grad_(True)
    got = mi_svbrdf.rendering_loss(p, target, generator=torch.Generator().manual_seed(1))
    got.backward()
    r = pred.double().requires_grad_(True)
    ref = mi_svbrdf.rendering_loss(r, target.double(), generator=torch.Generator().manual_seed(1), backend="torch")
    ref.backward()
    assert float(got.detach()) == pytest.approx(float(ref.detach()), rel=1e-5)
    torch.testing.assert_close(p.grad.double(), r.grad, rtol=1e-3, atol=1e-4 * float(r.grad.abs().max()))
