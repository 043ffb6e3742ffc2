"""SSIM and MS-SSIM: identities, symmetry, monotonicity in noise, hand-checkable values, gradients."""
from __future__ import annotations

import pytest
import torch

from mi_svbrdf.core.ssim import MS_SSIM_WEIGHTS, ms_ssim, ssim


def _images(shape=(2, 3, 32, 32), seed=0, dtype=torch.float64) -> torch.Tensor:
    """Smooth-ish random images in [0, 1] (a blurred noise field, so SSIM has structure to compare)."""
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(shape, generator=g, dtype=dtype)
    x = torch.nn.functional.avg_pool2d(torch.nn.functional.pad(x, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
    return x.clamp(0, 1)


def _noisy(x: torch.Tensor, std: float, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (x + std * torch.randn(x.shape, generator=g, dtype=x.dtype)).clamp(0, 1)


def test_identity_is_one():
    for dtype, tol in ((torch.float64, 1e-12), (torch.float32, 1e-5)):
        x = _images(dtype=dtype)
        s, m = ssim(x, x), ms_ssim(x, x)
        assert tuple(s.shape) == (2,) and tuple(m.shape) == (2,)
        assert s.tolist() == pytest.approx([1.0, 1.0], abs=tol)
        assert m.tolist() == pytest.approx([1.0, 1.0], abs=tol)
    big = _images((1, 1, 96, 96), seed=1)  # 4 scales with the 11-px window
    assert float(ms_ssim(big, big)) == pytest.approx(1.0, abs=1e-12)


def test_symmetric():
    x, y = _images(seed=2), _images(seed=3)
    assert torch.allclose(ssim(x, y), ssim(y, x), rtol=0, atol=1e-14)
    assert torch.allclose(ms_ssim(x, y), ms_ssim(y, x), rtol=0, atol=1e-14)
    assert (ssim(x, y) < 0.9).all()


def test_lower_for_noisier_images():
    x = _images((2, 3, 64, 64), seed=4)
    stds = (0.01, 0.05, 0.15, 0.4)
    s = [ssim(x, _noisy(x, std, seed=5)) for std in stds]
    m = [ms_ssim(x, _noisy(x, std, seed=5)) for std in stds]
    for a, b in zip(s, s[1:]):
        assert (b < a).all()
    for a, b in zip(m, m[1:]):
        assert (b < a).all()
    assert (s[0] > 0.95).all() and (s[-1] < 0.5).all()


def test_constant_images_hand_checked():
    """Constant images: every variance and covariance is 0, so cs = C2/C2 = 1 and SSIM is the luminance term."""
    mx, my = 0.3, 0.6
    x = torch.full((1, 3, 32, 32), mx, dtype=torch.float64)
    y = torch.full((1, 3, 32, 32), my, dtype=torch.float64)
    c1 = 0.01**2
    lum = (2 * mx * my + c1) / (mx * mx + my * my + c1)
    assert lum == pytest.approx(0.3601 / 0.4501)
    assert float(ssim(x, y)) == pytest.approx(lum, rel=1e-12)
    # data_range L enters C1 = (0.01 L)^2.
    c1 = (0.01 * 2.0) ** 2
    lum2 = (2 * mx * my + c1) / (mx * mx + my * my + c1)
    assert float(ssim(x, y, data_range=2.0)) == pytest.approx(lum2, rel=1e-12)
    # MS-SSIM of 32 px with the 11-px window has 2 scales (32, 16; 8 < 11): the contrast terms
    # are 1 and the coarsest scale contributes lum ** (w2 / (w1 + w2)).
    w1, w2 = MS_SSIM_WEIGHTS[:2]
    assert float(ms_ssim(x, y)) == pytest.approx(lum ** (w2 / (w1 + w2)), rel=1e-12)
    # 96 px: 4 scales (96, 48, 24, 12; 6 < 11), renormalised weights.
    x96, y96 = torch.full((1, 1, 96, 96), mx, dtype=torch.float64), torch.full((1, 1, 96, 96), my, dtype=torch.float64)
    w = MS_SSIM_WEIGHTS[:4]
    assert float(ms_ssim(x96, y96)) == pytest.approx(((2 * mx * my + 1e-4) / (mx**2 + my**2 + 1e-4)) ** (w[3] / sum(w)),
                                                      rel=1e-12)


def test_single_scale_ms_ssim_equals_ssim():
    """Below 22 px (2 x the window) MS-SSIM has one scale and is plain SSIM."""
    x, y = _images((2, 3, 20, 20), seed=6), _images((2, 3, 20, 20), seed=7)
    assert torch.allclose(ms_ssim(x, y), ssim(x, y).clamp_min(1e-6), atol=1e-14)
    # With more scales it is not.
    x, y = _images((2, 3, 32, 32), seed=6), _images((2, 3, 32, 32), seed=7)
    assert not torch.allclose(ms_ssim(x, y), ssim(x, y), atol=1e-3)


def test_structure_term_by_hand():
    """SSIM of x and 1 - x over one full-window patch: hand-computed from the Gaussian moments."""
    g = torch.Generator().manual_seed(8)
    x = torch.rand(1, 1, 11, 11, generator=g, dtype=torch.float64)
    y = 1.0 - x
    coords = torch.arange(11, dtype=torch.float64) - 5.0
    w1 = torch.exp(-coords**2 / (2 * 1.5**2))
    w = (w1[:, None] * w1[None, :]) / (w1.sum() ** 2)
    mu_x, mu_y = (w * x).sum(), (w * y).sum()
    vx = (w * (x - mu_x) ** 2).sum()
    vy = (w * (y - mu_y) ** 2).sum()
    cxy = (w * (x - mu_x) * (y - mu_y)).sum()
    c1, c2 = 1e-4, 9e-4
    expect = (2 * mu_x * mu_y + c1) * (2 * cxy + c2) / ((mu_x**2 + mu_y**2 + c1) * (vx + vy + c2))
    assert float(expect) < 0  # anti-correlated
    assert float(ssim(x, y)) == pytest.approx(float(expect), rel=1e-10)


def test_gradcheck():
    # Full Jacobian on tiny inputs: SSIM with the 11-px window on 11 px (one window position) and
    # MS-SSIM with a 3-px window on 8 px (2 scales: 8, 4; 2 < 3).
    x = _images((1, 1, 11, 11), seed=9).requires_grad_()
    y = _images((1, 1, 11, 11), seed=10).requires_grad_()
    assert torch.autograd.gradcheck(lambda a, b: ssim(a, b), (x, y), eps=1e-6, atol=1e-7)
    x8 = _images((1, 1, 8, 8), seed=9).requires_grad_()
    y8 = _images((1, 1, 8, 8), seed=10).requires_grad_()
    assert torch.autograd.gradcheck(lambda a, b: ms_ssim(a, b, window=3), (x8, y8), eps=1e-6, atol=1e-7)
    # Random Jacobian projections (fast mode) on larger inputs: 2 channels, several window
    # positions; MS-SSIM with 2 scales (window 5 on 12 px) and 3 scales (window 3 on 16 px).
    x = _images((1, 2, 12, 12), seed=9).requires_grad_()
    y = _images((1, 2, 12, 12), seed=10).requires_grad_()
    assert torch.autograd.gradcheck(lambda a, b: ssim(a, b, window=7), (x, y), eps=1e-6, atol=1e-7, fast_mode=True)
    assert torch.autograd.gradcheck(lambda a, b: ms_ssim(a, b, window=5), (x, y), eps=1e-6, atol=1e-7, fast_mode=True)
    x16 = _images((1, 1, 16, 16), seed=11).requires_grad_()
    y16 = _noisy(x16.detach(), 0.1, seed=12).requires_grad_()
    assert torch.autograd.gradcheck(lambda a, b: ms_ssim(a, b, window=3), (x16, y16), eps=1e-6, atol=1e-7,
                                    fast_mode=True)


def test_gradient_towards_target():
    """A gradient step on 1 - SSIM raises SSIM."""
    x, y = _images((1, 3, 24, 24), seed=13), _images((1, 3, 24, 24), seed=14)
    for fn in (ssim, ms_ssim):
        xg = x.clone().requires_grad_()
        (1 - fn(xg, y)).sum().backward()
        assert float(fn(x - 0.5 * xg.grad, y)) > float(fn(x, y))


@pytest.mark.parametrize("a, b", [
    ((1, 3, 16, 16), (1, 3, 16, 15)),
    ((1, 3, 16, 16), (2, 3, 16, 16)),
    ((1, 3, 16, 16), (1, 1, 16, 16)),
    ((3, 16, 16), (3, 16, 16)),
])
def test_shape_mismatch(a, b):
    for fn in (ssim, ms_ssim):
        with pytest.raises(ValueError, match=r"same shape \(B, C, H, W\)"):
            fn(torch.rand(a), torch.rand(b))
