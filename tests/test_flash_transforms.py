"""Flash input rendering, the 8-bit photo pipeline and the networks' log transform, by hand.

Reference values are computed here from ``/work/shared/conventions.md``: flash at (0, 0, 2.197),
camera at (0, 0, 2.75), cone target (0, 0, 0), e = 5, I = 13,
``L = f I pi / |P_L - P|^2 c(wl . a)^e c(n . wl)`` (no wl.z division); the photo pipeline
clip -> x^(1/2.2) -> trunc(255.5 x)/255 -> x^2.2; the log transform
``(log(x + 0.01) - log 0.01)/(log 1.01 - log 0.01)`` and ``2 y - 1``.
"""
from __future__ import annotations

import math

import pytest
import torch

import mi_svbrdf as ms
from mi_svbrdf.core.flash import FlashSetup, photo_pipeline, render_flash
from mi_svbrdf.core.transforms import log_decode, log_encode, network_input, network_input_inverse
from tests.conftest import random_maps


def _hand_pipeline(x: float) -> float:
    x = min(max(x, 0.0), 1.0) ** (1.0 / 2.2)
    return (math.trunc(255.5 * x) / 255.0) ** 2.2


# ----------------------------------------------------------------------------------------------
# photo_pipeline
# ----------------------------------------------------------------------------------------------

def test_photo_pipeline_hand_values():
    # x:      -0.5  0    0.001         0.18          0.5          1    2
    # 8-bit:   0    0    11            117           186          255  255
    xs = [-0.5, 0.0, 0.001, 0.18, 0.5, 1.0, 2.0]
    expect = [0.0, 0.0, (11 / 255) ** 2.2, (117 / 255) ** 2.2, (186 / 255) ** 2.2, 1.0, 1.0]
    assert [_hand_pipeline(x) for x in xs] == pytest.approx(expect, rel=1e-12)  # the helper itself
    assert expect[4] == pytest.approx(0.4995052766, rel=1e-9)
    for dtype, rel in ((torch.float64, 1e-12), (torch.float32, 1e-6)):
        got = photo_pipeline(torch.tensor(xs, dtype=dtype))
        assert got.dtype == dtype
        assert got.tolist() == pytest.approx(expect, rel=rel, abs=1e-12)


def test_photo_pipeline_ramp_and_quantisation_levels():
    x = torch.linspace(-0.2, 1.2, 1001, dtype=torch.float64)
    got = photo_pipeline(x)
    assert got.tolist() == pytest.approx([_hand_pipeline(v) for v in x.tolist()], rel=1e-12, abs=1e-15)
    codes = got ** (1.0 / 2.2) * 255.0  # every output is one of the 256 8-bit levels
    assert torch.allclose(codes, codes.round(), atol=1e-9)
    assert codes.min() == 0 and codes.max() == 255
    assert (got[1:] >= got[:-1]).all()  # monotone


def test_photo_pipeline_options():
    x = torch.tensor([[-0.1, 0.0, 0.3, 0.77, 1.0, 1.5]], dtype=torch.float64)
    # Without quantisation it is only the clip (x^(1/2.2))^2.2 = x, differentiably.
    xg = x.clone().requires_grad_()
    smooth = photo_pipeline(xg, quantize=False)
    assert smooth.tolist()[0] == pytest.approx([0.0, 0.0, 0.3, 0.77, 1.0, 1.0], rel=1e-12)
    smooth.sum().backward()
    grad = xg.grad[0]
    assert torch.isfinite(grad).all()  # also at x = 0 (a black pixel), where x^(1/2.2) has an infinite slope
    assert grad[[0, 5]].tolist() == [0.0, 0.0] and grad[[2, 3]].tolist() == pytest.approx([1.0, 1.0], abs=1e-9)
    # The quantised pipeline has a zero gradient, finite at black pixels too.
    xg = x.clone().requires_grad_()
    photo_pipeline(xg).sum().backward()
    assert xg.grad.tolist()[0] == [0.0] * 6
    # Noise: seeded and reproducible, zero std changes nothing, and it actually perturbs.
    y = torch.full((1, 3, 16, 16), 0.4)
    a = photo_pipeline(y, noise_std=0.05, generator=torch.Generator().manual_seed(1))
    b = photo_pipeline(y, noise_std=0.05, generator=torch.Generator().manual_seed(1))
    assert torch.equal(a, b)
    assert not torch.equal(a, photo_pipeline(y))
    assert float((a - photo_pipeline(y)).abs().mean()) > 0.01
    assert torch.equal(photo_pipeline(y, noise_std=0.0), photo_pipeline(y))
    # Per-element std as a tensor: zero where the std is zero.
    std = torch.zeros(1, 3, 16, 16)
    std[:, 0] = 0.05
    c = photo_pipeline(y, noise_std=std, generator=torch.Generator().manual_seed(2))
    assert torch.equal(c[:, 1:], photo_pipeline(y)[:, 1:]) and not torch.equal(c[:, 0], photo_pipeline(y)[:, 0])


# ----------------------------------------------------------------------------------------------
# render_flash
# ----------------------------------------------------------------------------------------------

def _hand_brdf(n, wl, wv, d, s, r):
    """f from conventions.md (GGX, diffuse included), plain floats; wl and wv normalised here."""
    def norm(v):
        length = math.sqrt(sum(c * c for c in v))
        return [c / length for c in v]

    def dot(a, b):
        return sum(x * y for x, y in zip(a, b))

    wl, wv = norm(wl), norm(wv)
    h = norm([(a + b) / 2 for a, b in zip(wl, wv)])
    nh, nl, nv, vh = (max(dot(n, h), 0.0), max(dot(n, wl), 0.0), max(dot(n, wv), 0.0), max(dot(wv, h), 0.0))
    alpha = r * r
    dist = alpha**2 / (math.pi * max(1e-3, nh * nh * (alpha**2 - 1) + 1) ** 2)
    k = alpha / 2
    geom = 1 / max(1e-3, nl * (1 - k) + k) / max(1e-3, nv * (1 - k) + k)
    fres = s + (1 - s) * 2 ** ((-5.55473 * vh - 6.98316) * vh)
    return fres * geom * dist / 4 + d * (1 - s) / math.pi


@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_render_flash_centre_texel_hand_computed(backend):
    d, s, r = (0.05, 0.1, 0.02), (0.02, 0.04, 0.01), 0.8
    maps = ms.maps.constant_maps(1, 1, 1, diffuse=d, specular=s, roughness=r)  # the texel is at (0, 0, 0)
    # Normal incidence: wl = wv = n = a = (0, 0, 1), so c(wl.a)^5 = c(n.wl) = 1, G = 1, n.h = v.h = 1.
    alpha = r * r
    expect = []
    for c in range(3):
        f = (s[c] + (1 - s[c]) * 2 ** (-5.55473 - 6.98316)) / (4 * math.pi * alpha**2) + d[c] * (1 - s[c]) / math.pi
        expect.append(f * 13.0 * math.pi / 2.197**2)
    assert expect == pytest.approx([0.16511923, 0.32457545, 0.07003936], rel=1e-7)  # by hand, once
    img = render_flash(maps, pipeline=False, backend=backend)
    assert tuple(img.shape) == (1, 3, 1, 1)
    assert img[0, :, 0, 0].tolist() == pytest.approx(expect, rel=1e-5)
    photo = render_flash(maps, backend=backend)  # the default applies the 8-bit pipeline
    assert photo[0, :, 0, 0].tolist() == pytest.approx([_hand_pipeline(v) for v in expect], rel=1e-5)
    # Brighter material: clipped to 1 by the pipeline, not by the renderer.
    bright = ms.maps.constant_maps(1, 1, 1, diffuse=0.9, specular=0.5, roughness=0.2)
    assert float(render_flash(bright, pipeline=False, backend=backend).min()) > 1.0
    assert render_flash(bright, backend=backend).flatten().tolist() == pytest.approx([1.0] * 3)


@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_render_flash_off_centre_texels_hand_computed(backend):
    """3x3 tilted material: texel centres at (+-2/3, 0), cone factor wl.z^5, fall-off, no wl.z division."""
    n = [0.2, -0.1, 1.0]
    length = math.sqrt(sum(c * c for c in n))
    n = [c / length for c in n]
    d, s, r = 0.3, 0.05, 0.4
    maps = ms.maps.constant_maps(1, 3, 3, normal=n, diffuse=d, specular=s, roughness=r)
    img = render_flash(maps, pipeline=False, backend=backend)
    light, camera = (0.0, 0.0, 2.197), (0.0, 0.0, 2.75)
    for i, j in [(0, 0), (0, 2), (1, 1), (2, 1)]:
        p = (-1 + (2 * j + 1) / 3, 1 - (2 * i + 1) / 3, 0.0)
        wl = [a - b for a, b in zip(light, p)]
        wv = [a - b for a, b in zip(camera, p)]
        dist2 = sum(c * c for c in wl)
        wl_unit = [c / math.sqrt(dist2) for c in wl]
        cone = max(wl_unit[2], 0.0) ** 5  # a = (0, 0, 1): from the cone target (0, 0, 0) to the light
        cos_nl = max(sum(a * b for a, b in zip(n, wl_unit)), 0.0)
        expect = _hand_brdf(n, wl, wv, d, s, r) * 13.0 * math.pi / dist2 * cone * cos_nl
        assert img[0, :, i, j].tolist() == pytest.approx([expect] * 3, rel=1e-5), (i, j)
    # The corners are darker than the centre (fall-off and cone).
    assert img[0, 0, 0, 0] < img[0, 0, 1, 1]


@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_render_flash_gradients_finite_at_black_texels(backend):
    """Texels facing away from the flash render exactly 0: the photo pipeline must not turn that into NaN."""
    maps = random_maps(1, 6, 6, seed=4)
    maps[:, 0:3, :3] = torch.tensor([0.0, 1.0, 0.0])[:, None, None]  # top rows (y > 0) face away: c(n.wl) = 0
    # Differentiable variant: render, then the pipeline without quantisation.
    m = maps.clone().requires_grad_()
    img = photo_pipeline(render_flash(m, pipeline=False, backend=backend), quantize=False)
    assert (img[:, :, :3] == 0).all() and (img[:, :, 3:] > 0).all()
    img.sum().backward()
    assert torch.isfinite(m.grad).all()
    assert m.grad[:, :, 3:].abs().sum() > 0
    # Default (quantised) pipeline: no gradient through the 8 bits, but no NaN either.
    m = maps.clone().requires_grad_()
    render_flash(m, backend=backend).sum().backward()
    assert torch.isfinite(m.grad).all() and (m.grad == 0).all()


def test_render_flash_setup_and_backends():
    maps = random_maps(2, 8, 8, seed=3)
    a = render_flash(maps, pipeline=False, backend="mitsuba")
    b = render_flash(maps.double(), pipeline=False, backend="torch")
    assert tuple(a.shape) == (2, 3, 8, 8)
    assert torch.allclose(a.double(), b, rtol=1e-4, atol=1e-6)
    # The intensity is linear, the setup is used.
    twice = render_flash(maps, FlashSetup(intensity=26.0), pipeline=False)
    assert torch.allclose(twice, 2 * a, rtol=1e-5, atol=1e-7)
    wide = render_flash(maps, FlashSetup(cone_exponent=0.0), pipeline=False)
    assert (wide >= a - 1e-7).all() and (wide > a).any()


# ----------------------------------------------------------------------------------------------
# Log transform
# ----------------------------------------------------------------------------------------------

def test_log_encode_hand_values_and_endpoints():
    x = torch.tensor([0.0, 0.01, 0.25, 1.0], dtype=torch.float64)
    scale = math.log(1.01) - math.log(0.01)  # = log(101)
    expect = [0.0, math.log(2) / scale, math.log(26) / scale, 1.0]
    assert log_encode(x).tolist() == pytest.approx(expect, rel=1e-12, abs=1e-15)
    assert expect[2] == pytest.approx(0.705961, abs=1e-6)
    assert float(log_encode(torch.tensor(0.0))) == 0.0
    assert float(log_encode(torch.tensor(1.0))) == pytest.approx(1.0, abs=1e-7)
    assert network_input(x).tolist() == pytest.approx([2 * e - 1 for e in expect], rel=1e-12, abs=1e-15)
    assert network_input(torch.tensor([0.0, 1.0])).tolist() == pytest.approx([-1.0, 1.0], abs=1e-6)
    assert float(network_input(torch.tensor(0.0))) == -1.0


def test_log_transform_round_trips():
    x = torch.cat([torch.linspace(0, 1, 101, dtype=torch.float64), torch.tensor([1e-4, 0.003], dtype=torch.float64)])
    assert torch.allclose(log_decode(log_encode(x)), x, atol=1e-12)
    assert torch.allclose(network_input_inverse(network_input(x)), x, atol=1e-12)
    y = torch.linspace(0, 1, 51, dtype=torch.float64)
    assert torch.allclose(log_encode(log_decode(y)), y, atol=1e-12)
    z = torch.linspace(-1, 1, 51, dtype=torch.float64)
    assert torch.allclose(network_input(network_input_inverse(z)), z, atol=1e-12)
    assert network_input_inverse(torch.tensor([-1.0, 1.0], dtype=torch.float64)).tolist() == pytest.approx(
        [0.0, 1.0], abs=1e-12)
    assert (log_encode(x[:101])[1:] > log_encode(x[:101])[:-1]).all()  # strictly increasing
    # The dark range is spread: the darkest tenth of the range takes over half of the code range.
    assert float(log_encode(torch.tensor(0.1))) > 0.5
    # float32 also round-trips.
    x32 = torch.rand(1000, generator=torch.Generator().manual_seed(0))
    assert torch.allclose(network_input_inverse(network_input(x32)), x32, atol=1e-5)
