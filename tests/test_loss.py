"""Rendering loss: configuration sampler, presets, hand-written reference, backends, gradients, errors.

The reference values come from ``/work/shared/conventions.md`` (the authors' code), written here
by hand: presets (I, eps, r1_max) = (1.0, 0.01, 0.95) for 2018 and (1.5, 0.1, 0.90) for 2019, the
loss light model ``L = f pi I c(n.wl) / max(wl.z, 1e-3)`` (no fall-off) and
``mean |log(R_gt + eps) - log(R_pred + eps)|``.
"""
from __future__ import annotations

import math

import pytest
import torch

import mi_svbrdf as ms
from mi_svbrdf.core.configurations import Configurations, sample_configurations
from mi_svbrdf.core.loss import PRESETS, LossPreset, map_l1, rendering_ms_ssim_loss, resolve_preset
from tests.conftest import random_maps

#: conventions.md: preset -> (intensity, eps, r1_max); 3 diffuse + 6 specular, diffuse term on.
HAND_PRESETS = {"2018": (1.0, 0.01, 0.95), "2019": (1.5, 0.1, 0.90)}


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _rel_err(x: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """The criterion of test_render.py: |x - ref| / (|ref| + 1e-3 max|ref|)."""
    return ((x.double() - ref).abs() / (ref.abs() + 1e-3 * ref.abs().max() + 1e-12)).flatten()


def _hand_loss(pred, target, cfg: Configurations, intensity: float, eps: float, include_diffuse: bool = True,
               distribution: str = "ggx") -> torch.Tensor:
    """Float64 loss written from conventions.md on top of the torch reference renderer."""
    kw = dict(intensity=intensity, light_z_division=True, distance_falloff=False, include_diffuse=include_diffuse,
              distribution=distribution, backend="torch")
    r_p = ms.render(pred.double(), cfg.light.double(), cfg.view.double(), **kw)
    r_t = ms.render(target.double(), cfg.light.double(), cfg.view.double(), **kw)
    return (torch.log(r_t + eps) - torch.log(r_p + eps)).abs().mean()


# ----------------------------------------------------------------------------------------------
# The configuration sampler
# ----------------------------------------------------------------------------------------------

def test_configuration_shapes_and_homogeneous_w():
    cfg = sample_configurations(3, generator=_gen(0))
    assert cfg.count == 9
    assert tuple(cfg.light.shape) == (3, 9, 4) and tuple(cfg.view.shape) == (3, 9, 4)
    for t in (cfg.light, cfg.view):
        assert (t[:, :3, 3] == 0).all()  # 3 diffuse (far field) first
        assert (t[:, 3:, 3] == 1).all()  # then 6 specular (near field)
    cfg = sample_configurations(2, 2, 5, generator=_gen(0))
    assert tuple(cfg.light.shape) == (2, 7, 4)
    assert cfg.light[:, :2, 3].eq(0).all() and cfg.light[:, 2:, 3].eq(1).all()
    only_diffuse = sample_configurations(1, 4, 0, generator=_gen(0))
    assert only_diffuse.count == 4 and (only_diffuse.view[..., 3] == 0).all()


def test_configurations_reproducible_with_a_seed():
    a = sample_configurations(4, generator=_gen(123))
    b = sample_configurations(4, generator=_gen(123))
    c = sample_configurations(4, generator=_gen(124))
    assert torch.equal(a.light, b.light) and torch.equal(a.view, b.view)
    assert not torch.equal(a.light, c.light) and not torch.equal(a.view, c.view)
    # Consecutive draws from one generator differ (fresh configurations per step).
    g = _gen(5)
    first, second = sample_configurations(2, generator=g), sample_configurations(2, generator=g)
    assert not torch.equal(first.light, second.light)


def _recover_specular(cfg: Configurations, n_diffuse: int, shift_z: float = 1e-4):
    """Shift, view direction and distances of the specular configurations (float64).

    With L - S = a (-v.x, -v.y, v.z) and V - S = b v, S.xy lies on the segment L.xy-V.xy at the
    ratio a : b = (L.z - S.z) : (V.z - S.z); the mirror relation then holds by construction, so
    what is tested is that such a shift exists with S.z = shift_z and S.xy in [-1, 1]^2, and the
    recovered directions and distances.
    """
    light = cfg.light[:, n_diffuse:, :3].double()
    view = cfg.view[:, n_diffuse:, :3].double()
    a, b = light[..., 2:] - shift_z, view[..., 2:] - shift_z
    shift_xy = (b * light[..., :2] + a * view[..., :2]) / (a + b)
    shift = torch.cat([shift_xy, torch.full_like(a, shift_z)], dim=-1)
    lv, vv = light - shift, view - shift
    l_dist, v_dist = lv.norm(dim=-1), vv.norm(dim=-1)
    return shift, lv / l_dist[..., None], vv / v_dist[..., None], l_dist, v_dist


@pytest.mark.parametrize("r1_max", [0.95, 0.90])
def test_sampler_distribution(r1_max):
    n_d, n_s = 3, 6
    cfg = sample_configurations(4000, n_d, n_s, r1_max=r1_max, generator=_gen(7))
    z_lo, z_hi = math.sqrt(1.0 - r1_max), math.sqrt(0.999)

    def check_directions(w: torch.Tensor) -> None:
        assert torch.allclose(w.norm(dim=-1), torch.ones(()).double(), atol=1e-5)
        z = w[..., 2]
        assert z.min() >= z_lo - 1e-5 and z.max() <= z_hi + 1e-5
        assert z.min() < z_lo + 0.01 and z.max() > z_hi - 0.01  # the range is used up to its ends
        r1 = 1.0 - z * z  # r1 ~ U(0.001, r1_max): cosine-weighted
        assert float(r1.mean()) == pytest.approx((0.001 + r1_max) / 2, abs=0.01)
        assert float(r1.std()) == pytest.approx((r1_max - 0.001) / math.sqrt(12.0), abs=0.01)
        phi = torch.atan2(w[..., 1], w[..., 0])  # phi ~ U(-pi, pi)
        assert float(phi.mean()) == pytest.approx(0.0, abs=0.05)
        assert float(phi.std()) == pytest.approx(math.pi / math.sqrt(3.0), abs=0.03)

    # Diffuse: far-field unit directions, light and view drawn independently.
    ld, vd = cfg.light[:, :n_d, :3].double(), cfg.view[:, :n_d, :3].double()
    check_directions(ld)
    check_directions(vd)
    corr = torch.corrcoef(torch.stack([ld[..., 0].flatten(), vd[..., 0].flatten()]))[0, 1]
    assert abs(float(corr)) < 0.05

    # Specular: mirrored directions around a shift on the plane, log-normal distances.
    shift, l_dir, v_dir, l_dist, v_dist = _recover_specular(cfg, n_d)
    assert shift[..., :2].abs().max() <= 1.0 + 1e-5
    assert shift[..., :2].abs().max() > 0.99  # U(-1, 1), not a narrower range
    assert float(shift[..., :2].std()) == pytest.approx(1.0 / math.sqrt(3.0), abs=0.02)
    assert torch.allclose(l_dir, v_dir * torch.tensor([-1.0, -1.0, 1.0], dtype=torch.float64), atol=1e-5)
    check_directions(v_dir)
    log_d = torch.cat([l_dist.log().flatten(), v_dist.log().flatten()])
    assert float(log_d.mean()) == pytest.approx(0.5, abs=0.02)  # 48000 samples: std error 0.0034
    assert float(log_d.std()) == pytest.approx(0.75, abs=0.02)
    corr = torch.corrcoef(torch.stack([l_dist.log().flatten(), v_dist.log().flatten()]))[0, 1]
    assert abs(float(corr)) < 0.05  # independent distances for view and light


def test_specular_shift_z_is_1e_minus_4(monkeypatch):
    """With the normal draws zeroed, both distances are exp(0.5) and the shift is identified exactly.

    L - S = a (-v.x, -v.y, v.z), V - S = a v with a = e^0.5: S.xy = (L.xy + V.xy)/2 and
    S.z = V.z - sqrt(a^2 - |V.xy - S.xy|^2).
    """
    calls = []
    real_zeros = torch.zeros

    def no_noise(size, *args, generator=None, dtype=None, device=None, **kwargs):
        calls.append(size)
        return real_zeros(size, dtype=dtype or torch.float32, device=device)

    monkeypatch.setattr(torch, "randn", no_noise)
    cfg = sample_configurations(500, 3, 6, generator=_gen(11))
    monkeypatch.undo()
    assert calls, "the sampler no longer draws its distances with torch.randn: update this test"
    a = math.exp(0.5)
    light, view = cfg.light[:, 3:, :3].double(), cfg.view[:, 3:, :3].double()
    assert torch.allclose(light[..., 2], view[..., 2], atol=1e-6)  # equal distances, mirrored directions
    s_xy = (light[..., :2] + view[..., :2]) / 2
    s_z = view[..., 2] - torch.sqrt(a * a - (view[..., :2] - s_xy).square().sum(-1))
    assert torch.allclose(s_z, torch.full_like(s_z, 1e-4), atol=2e-6)
    assert s_xy.abs().max() <= 1.0 and s_xy.abs().max() > 0.95
    assert torch.allclose((light - torch.cat([s_xy, s_z[..., None]], -1)).norm(dim=-1),
                          torch.full_like(s_z, a), atol=1e-5)


@pytest.mark.parametrize("kwargs, match", [
    (dict(batch=0), "batch"),
    (dict(batch=1, n_diffuse=0, n_specular=0), "at least one configuration"),
    (dict(batch=1, r1_max=0.0), "r1_max"),
    (dict(batch=1, r1_max=1.5), "r1_max"),
])
def test_sampler_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        sample_configurations(**kwargs)


def test_configurations_shape_check():
    with pytest.raises(ValueError, match=r"\(B, K, 4\)"):
        Configurations(light=torch.zeros(1, 3, 3), view=torch.zeros(1, 3, 3))
    with pytest.raises(ValueError, match=r"\(B, K, 4\)"):
        Configurations(light=torch.zeros(1, 3, 4), view=torch.zeros(1, 2, 4))


# ----------------------------------------------------------------------------------------------
# Presets
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["2018", "2019"])
def test_presets_match_conventions(name):
    intensity, eps, r1_max = HAND_PRESETS[name]
    p = PRESETS[name]
    assert (p.intensity, p.eps, p.r1_max) == (intensity, eps, r1_max)
    assert (p.n_diffuse, p.n_specular, p.include_diffuse) == (3, 6, True)
    assert resolve_preset(name) == p
    assert resolve_preset(name, eps=0.5, intensity=None) == LossPreset(intensity, 0.5, r1_max, 3, 6, True)


def test_unknown_preset_and_backend():
    p, t = random_maps(1, 4, 4, seed=0), random_maps(1, 4, 4, seed=1)
    with pytest.raises(ValueError, match="preset"):
        ms.rendering_loss(p, t, preset="2020")
    with pytest.raises(ValueError, match="preset"):
        ms.mixed_loss(p, t, preset="2017")
    with pytest.raises(ValueError, match="preset"):
        ms.RenderingLoss("thesis")
    with pytest.raises(ValueError, match="preset"):
        ms.MixedLoss("thesis")
    for backend in ("numpy", "cuda"):
        with pytest.raises(ValueError, match="backend"):
            ms.rendering_loss(p, t, backend=backend)
        with pytest.raises(ValueError, match="backend"):
            ms.mixed_loss(p, t, backend=backend)
    for backend in ("mitsuba", "torch"):  # both backends reject an unknown distribution alike
        with pytest.raises(ValueError, match="distribution"):
            ms.rendering_loss(p, t, distribution="phong", backend=backend)


# ----------------------------------------------------------------------------------------------
# Values against the hand-written reference
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("preset", ["2018", "2019"])
def test_loss_equals_hand_written_reference(preset):
    intensity, eps, r1_max = HAND_PRESETS[preset]
    pred, target = random_maps(2, 16, 16, seed=1), random_maps(2, 16, 16, seed=2)
    cfg = sample_configurations(2, 3, 6, r1_max=r1_max, generator=_gen(3))
    ref = _hand_loss(pred, target, cfg, intensity, eps)
    assert float(ref) > 0.05
    got64 = ms.rendering_loss(pred.double(), target.double(), preset=preset, generator=_gen(3), backend="torch")
    assert got64.dtype == torch.float64
    assert float(got64) == pytest.approx(float(ref), rel=1e-12)
    for backend in ("torch", "mitsuba"):
        got = ms.rendering_loss(pred, target, preset=preset, generator=_gen(3), backend=backend)
        assert got.dim() == 0
        assert float(got) == pytest.approx(float(ref), rel=1e-5), backend
    # The preset matters: the other one gives another value under the same configurations.
    other = "2019" if preset == "2018" else "2018"
    assert float(ms.rendering_loss(pred, target, preset=other, configurations=cfg)) != pytest.approx(
        float(ref), rel=1e-3)


@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_loss_overrides_equal_hand_written_reference(backend):
    pred, target = random_maps(2, 8, 12, seed=4), random_maps(2, 8, 12, seed=5)
    cfg = sample_configurations(2, 2, 1, r1_max=0.95, generator=_gen(6))
    ref = _hand_loss(pred, target, cfg, 2.5, 0.05, include_diffuse=False)
    got = ms.rendering_loss(pred, target, preset="2018", generator=_gen(6), n_diffuse=2, n_specular=1,
                            eps=0.05, intensity=2.5, include_diffuse=False, backend=backend)
    assert float(got) == pytest.approx(float(ref), rel=1e-5)
    custom = LossPreset(intensity=2.5, eps=0.05, r1_max=0.95, n_diffuse=2, n_specular=1, include_diffuse=False)
    got = ms.rendering_loss(pred, target, preset=custom, generator=_gen(6), backend=backend)
    assert float(got) == pytest.approx(float(ref), rel=1e-5)


def test_explicit_configurations_equal_seeded_draw():
    pred, target = random_maps(2, 16, 16, seed=7), random_maps(2, 16, 16, seed=8)
    for preset, (_, _, r1_max) in HAND_PRESETS.items():
        cfg = sample_configurations(2, 3, 6, r1_max=r1_max, generator=_gen(9))
        for backend in ("mitsuba", "torch"):
            seeded = ms.rendering_loss(pred, target, preset=preset, generator=_gen(9), backend=backend)
            explicit = ms.rendering_loss(pred, target, preset=preset, configurations=cfg, backend=backend)
            assert float(seeded) == float(explicit)
            other = ms.rendering_loss(pred, target, preset=preset, generator=_gen(10), backend=backend)
            assert float(other) != float(seeded)


@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_loss_of_identical_maps_is_zero(backend):
    pred = random_maps(2, 16, 16, seed=11)
    for preset in ("2018", "2019"):
        assert float(ms.rendering_loss(pred, pred.clone(), preset=preset, generator=_gen(0), backend=backend)) == 0.0
    assert float(ms.mixed_loss(pred, pred.clone(), generator=_gen(0), backend=backend)) == 0.0


@pytest.mark.parametrize("preset", ["2018", "2019"])
def test_backends_agree_on_value_and_gradient(preset):
    pred, target = random_maps(2, 16, 16, seed=12), random_maps(2, 16, 16, seed=13)
    cfg = sample_configurations(2, 3, 6, r1_max=HAND_PRESETS[preset][2], generator=_gen(14))
    values, grads = {}, {}
    for name, m, backend in (("mitsuba", pred, "mitsuba"), ("ref", pred.double(), "torch")):
        m = m.clone().requires_grad_()
        loss = ms.rendering_loss(m, target.to(m.dtype), preset=preset, configurations=cfg, backend=backend)
        loss.backward()
        values[name], grads[name] = loss.item(), m.grad
    assert values["mitsuba"] == pytest.approx(values["ref"], rel=1e-5)
    assert grads["mitsuba"].dtype == torch.float32
    for map_name, sl in ms.maps.SLICES.items():
        err = _rel_err(grads["mitsuba"][:, sl], grads["ref"][:, sl])
        assert torch.quantile(err, 0.99) < 1e-3, map_name
        assert grads["ref"][:, sl].abs().sum() > 0, map_name
        assert torch.isfinite(grads["mitsuba"][:, sl]).all(), map_name


@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_gradients_finite_at_extremes(backend):
    """Roughness 0 and 1, normals exactly at the horizon, steep normals."""
    pred = random_maps(2, 12, 12, seed=15, max_tilt=math.pi / 2)
    pred[:, 6, :, :4] = 0.0
    pred[:, 6, :, 4:8] = 1.0
    pred[:, 0:3, 0, :] = torch.tensor([1.0, 0.0, 0.0])[:, None]  # at the horizon
    pred[:, 0:3, 1, :] = torch.tensor([0.0, -1.0, 0.0])[:, None]
    target = random_maps(2, 12, 12, seed=16)
    target[:, 6, :6] = 0.0
    for preset in ("2018", "2019"):
        for distribution in ("ggx", "beckmann"):
            m = pred.clone().requires_grad_()
            loss = ms.rendering_loss(m, target, preset=preset, generator=_gen(17), distribution=distribution,
                                     backend=backend)
            loss.backward()
            assert torch.isfinite(loss) and loss.item() > 0
            assert torch.isfinite(m.grad).all(), (preset, distribution)
            assert m.grad.abs().sum() > 0


def test_gradcheck_torch_backend_loss():
    """Float64 gradcheck; pred far below target so no |.| kink is crossed, lights well above every texel."""
    pred = random_maps(1, 3, 2, seed=18, rough_range=(0.2, 0.9), max_tilt=0.3, dtype=torch.float64)
    pred[:, 3:6] = pred[:, 3:6] * 0.3
    target = pred.detach().clone()
    target[:, 3:6] = target[:, 3:6] + 0.6  # brighter diffuse: R_gt > R_pred at every texel
    light = torch.tensor([[[0.2, 0.1, 1.0, 0.0], [0.3, 0.2, 2.0, 1.0], [-0.5, 0.4, 1.5, 1.0]]], dtype=torch.float64)
    view = torch.tensor([[[-0.1, 0.3, 1.0, 0.0], [-0.2, -0.1, 2.5, 1.0], [0.6, -0.3, 1.8, 1.0]]], dtype=torch.float64)
    cfg = Configurations(light=light, view=view)
    kw = dict(intensity=1.5, light_z_division=True, backend="torch")
    with torch.no_grad():
        assert (ms.render(target, light, view, **kw) > ms.render(pred, light, view, **kw) + 1e-3).all()
    pred.requires_grad_()
    for preset in ("2018", "2019"):
        assert torch.autograd.gradcheck(
            lambda m: ms.rendering_loss(m, target, preset=preset, configurations=cfg, backend="torch"),
            (pred,), eps=1e-6, atol=1e-6)


# ----------------------------------------------------------------------------------------------
# Mixed loss, MS-SSIM term, module twins
# ----------------------------------------------------------------------------------------------

def test_map_l1_by_hand():
    pred, target = random_maps(2, 4, 6, seed=19), random_maps(2, 4, 6, seed=20)
    d = (pred - target).abs()
    expect = d[:, 0:3].mean() + d[:, 3:6].mean() + d[:, 6:7].mean() + d[:, 7:10].mean()
    assert float(map_l1(pred, target)) == pytest.approx(float(expect), rel=1e-6)
    # Each map weighs the same whatever its channel count: only roughness differs by 0.4.
    t = pred.clone()
    t[:, 6] += 0.4
    assert float(map_l1(pred, t)) == pytest.approx(0.4, rel=1e-6)


@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_mixed_loss_is_rendering_plus_weighted_map_l1(backend):
    pred, target = random_maps(2, 16, 16, seed=21), random_maps(2, 16, 16, seed=22)
    cfg = sample_configurations(2, 3, 6, r1_max=0.90, generator=_gen(23))
    rend = ms.rendering_loss(pred, target, preset="2019", configurations=cfg, backend=backend)
    l1 = map_l1(pred, target)
    mixed = ms.mixed_loss(pred, target, generator=_gen(23), backend=backend)  # preset "2019" by default
    assert float(mixed) == pytest.approx(float(rend) + 0.1 * float(l1), rel=1e-6)
    ref = _hand_loss(pred, target, cfg, 1.5, 0.1) + 0.1 * l1.double()
    assert float(mixed) == pytest.approx(float(ref), rel=1e-5)
    mixed = ms.mixed_loss(pred, target, map_weight=0.5, preset="2018", configurations=cfg, backend=backend)
    rend18 = ms.rendering_loss(pred, target, preset="2018", configurations=cfg, backend=backend)
    assert float(mixed) == pytest.approx(float(rend18) + 0.5 * float(l1), rel=1e-6)
    no_maps = ms.mixed_loss(pred, target, map_weight=0.0, configurations=cfg, backend=backend)
    assert float(no_maps) == pytest.approx(float(rend), rel=1e-7)


@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_mixed_loss_with_ms_ssim(backend):
    pred, target = random_maps(2, 16, 16, seed=24), random_maps(2, 16, 16, seed=25)
    cfg = sample_configurations(2, 3, 6, r1_max=0.90, generator=_gen(26))
    m = pred.clone().requires_grad_()
    loss = ms.mixed_loss(m, target, ms_ssim_weight=0.5, configurations=cfg, backend=backend)
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(m.grad).all()
    for sl in ms.maps.SLICES.values():
        assert m.grad[:, sl].abs().sum() > 0
    base = ms.mixed_loss(pred, target, configurations=cfg, backend=backend)
    term = rendering_ms_ssim_loss(pred, target, cfg, preset="2019", backend=backend)
    assert 0.0 < float(term) <= 2.0
    assert loss.item() == pytest.approx(float(base) + 0.5 * float(term), rel=1e-5)
    assert float(rendering_ms_ssim_loss(pred, pred.clone(), cfg, preset="2019", backend=backend)) == pytest.approx(
        0.0, abs=1e-5)


def test_ms_ssim_term_backends_agree():
    pred, target = random_maps(1, 16, 16, seed=27), random_maps(1, 16, 16, seed=28)
    cfg = sample_configurations(1, generator=_gen(29))
    a = rendering_ms_ssim_loss(pred, target, cfg, backend="mitsuba")
    b = rendering_ms_ssim_loss(pred.double(), target.double(), cfg, backend="torch")
    assert float(a) == pytest.approx(float(b), rel=1e-4)


@pytest.mark.parametrize("backend", ["mitsuba", "torch"])
def test_module_twins_reproduce_functional(backend):
    pred, target = random_maps(2, 16, 16, seed=30), random_maps(2, 16, 16, seed=31)
    for preset in ("2018", "2019"):
        module = ms.RenderingLoss(preset, seed=32, backend=backend)
        assert isinstance(module, torch.nn.Module)
        g = _gen(32)  # the module's generator advances the same way over two calls
        for _ in range(2):
            got = module(pred, target)
            expect = ms.rendering_loss(pred, target, preset=preset, generator=g, backend=backend)
            assert float(got) == float(expect)
    mixed = ms.MixedLoss(seed=33, map_weight=0.2, backend=backend)
    expect = ms.mixed_loss(pred, target, map_weight=0.2, generator=_gen(33), backend=backend)
    assert float(mixed(pred, target)) == float(expect)
    mixed = ms.MixedLoss("2018", seed=34, ms_ssim_weight=0.3, backend=backend)
    expect = ms.mixed_loss(pred, target, preset="2018", ms_ssim_weight=0.3, generator=_gen(34), backend=backend)
    assert float(mixed(pred, target)) == pytest.approx(float(expect), rel=1e-6)
    beck = ms.RenderingLoss(seed=35, distribution="beckmann", backend=backend)
    expect = ms.rendering_loss(pred, target, generator=_gen(35), distribution="beckmann", backend=backend)
    assert float(beck(pred, target)) == float(expect)
    # Gradients flow through the module.
    m = pred.clone().requires_grad_()
    ms.RenderingLoss(seed=0, backend=backend)(m, target).backward()
    assert torch.isfinite(m.grad).all() and m.grad.abs().sum() > 0


def test_bad_inputs():
    p, t = random_maps(2, 8, 8, seed=0), random_maps(2, 8, 8, seed=1)
    for backend in ("mitsuba", "torch"):
        with pytest.raises(ValueError, match="target: expected the shape of pred"):
            ms.rendering_loss(p, random_maps(3, 8, 8), backend=backend)
        with pytest.raises(ValueError, match="target: expected the shape of pred"):
            ms.rendering_loss(p, random_maps(2, 8, 6), backend=backend)
        with pytest.raises(ValueError, match=r"pred: expected shape \(B, 10, H, W\)"):
            ms.rendering_loss(p[:, :9], t, backend=backend)
        with pytest.raises(ValueError, match=r"target: expected shape \(B, 10, H, W\)"):
            ms.rendering_loss(p, t[0], backend=backend)
        with pytest.raises(ValueError, match="pred: contains NaN"):
            ms.rendering_loss(p * float("nan"), t, backend=backend)
        with pytest.raises(ValueError, match="configurations: expected batch 2"):
            ms.rendering_loss(p, t, configurations=sample_configurations(3), backend=backend)
        cfg = sample_configurations(2, generator=_gen(0))
        nan_light = Configurations(cfg.light.clone(), cfg.view)
        nan_light.light[1, 4, 0] = float("nan")
        with pytest.raises(ValueError, match="configurations: light contains NaN"):
            ms.rendering_loss(p, t, configurations=nan_light, backend=backend)
        bad_w = Configurations(cfg.light, cfg.view.clone())
        bad_w.view[0, 0, 3] = 0.5
        with pytest.raises(ValueError, match="configurations: view's homogeneous w must be 0"):
            ms.rendering_loss(p, t, configurations=bad_w, backend=backend)
        with pytest.raises(ValueError, match="target: expected the shape of pred"):
            ms.mixed_loss(p, random_maps(1, 8, 8), backend=backend)
        with pytest.raises(ValueError, match="target: expected the shape of pred"):
            ms.RenderingLoss(seed=0, backend=backend)(p, random_maps(1, 8, 8))
    with pytest.raises(ValueError, match="target: expected the shape of pred"):
        map_l1(p, t[:1])


# ----------------------------------------------------------------------------------------------
# The Beckmann distribution
# ----------------------------------------------------------------------------------------------

def test_beckmann_loss():
    pred, target = random_maps(2, 16, 16, seed=36, rough_range=(0.1, 0.6)), random_maps(2, 16, 16, seed=37)
    cfg = sample_configurations(2, generator=_gen(38))
    ref = _hand_loss(pred, target, cfg, 1.0, 0.01, distribution="beckmann")
    ggx = float(ms.rendering_loss(pred, target, configurations=cfg))
    for backend in ("mitsuba", "torch"):
        m = pred.clone().requires_grad_()
        beck = ms.rendering_loss(m, target, configurations=cfg, distribution="beckmann", backend=backend)
        beck.backward()
        assert beck.item() == pytest.approx(float(ref), rel=1e-5), backend
        assert abs(beck.item() - ggx) > 1e-3 * ggx, backend
        assert torch.isfinite(m.grad).all() and m.grad[:, 6].abs().sum() > 0
    assert float(ms.rendering_loss(pred, pred.clone(), configurations=cfg, distribution="beckmann")) == 0.0
    # The mixed loss and the modules pass the distribution on.
    l1 = float(map_l1(pred, target))
    for backend in ("mitsuba", "torch"):
        beck19 = ms.rendering_loss(pred, target, preset="2019", configurations=cfg, distribution="beckmann",
                                   backend=backend)
        mixed = ms.mixed_loss(pred, target, configurations=cfg, distribution="beckmann", backend=backend)
        assert float(mixed) == pytest.approx(float(beck19) + 0.1 * l1, rel=1e-6)
        module = ms.MixedLoss(seed=39, distribution="beckmann", backend=backend)
        expect = ms.rendering_loss(pred, target, preset="2019", generator=_gen(39), distribution="beckmann",
                                   backend=backend) + 0.1 * l1
        assert float(module(pred, target)) == pytest.approx(float(expect), rel=1e-6)
