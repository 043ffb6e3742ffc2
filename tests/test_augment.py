"""Augmentation: mixing is a convex combination, transforms rotate normals like the height field."""
from __future__ import annotations

import math

import pytest
import torch

from mi_svbrdf.core import maps as M
from mi_svbrdf.data import augment
from mi_svbrdf.data.examples import normals_from_height


def random_maps(batch: int, size: int, seed: int, max_tilt: float = 1.2) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    theta = torch.rand(batch, 1, size, size, generator=g) * max_tilt
    phi = torch.rand(batch, 1, size, size, generator=g) * 2 * math.pi
    n = torch.cat([theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()], 1)
    return torch.cat([n, torch.rand(batch, 7, size, size, generator=g)], 1)


def angles(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Angles (radians) between normals ``(B, 3, H, W)`` (atan2 of |a x b| and a . b: exact near 0)."""
    a, b = a.double(), b.double()
    return torch.atan2(torch.cross(a, b, dim=1).norm(dim=1), (a * b).sum(1))


def plane_grid(size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Texel-centre plane coordinates ``(H, W)`` each, x right, y up (row 0 at y = +1)."""
    c = (torch.arange(size, dtype=torch.float64) * 2 + 1) / size - 1
    return c.view(1, -1).expand(size, size), -c.view(-1, 1).expand(size, size)


def height_maps(size: int) -> torch.Tensor:
    """``(1, 10, S, S)``: the analytic normals of h(x, y) (plane units), h itself in the roughness channel."""
    x, y = plane_grid(size)
    h = 0.15 * torch.sin(3 * x + 1) + 0.1 * torch.cos(2.5 * y - 0.5) + 0.08 * x * y
    hx = 0.45 * torch.cos(3 * x + 1) + 0.08 * y
    hy = -0.25 * torch.sin(2.5 * y - 0.5) + 0.08 * x
    n = torch.stack([-hx, -hy, torch.ones_like(h)])
    n = n / n.norm(dim=0, keepdim=True)
    rest = torch.full((7, size, size), 0.3, dtype=torch.float64)
    rest[3] = h
    return torch.cat([n, rest]).unsqueeze(0).float()


# ----------------------------------------------------------------------------------------- mixing

def test_mix_is_convex_with_unit_normals() -> None:
    a, b = random_maps(4, 16, seed=1), random_maps(4, 16, seed=2)
    alpha = torch.tensor([0.0, 0.1, 0.55, 1.0])
    m = augment.mix(a, b, alpha)
    w = alpha.view(-1, 1, 1, 1)
    lo, hi = torch.minimum(a[:, 3:], b[:, 3:]), torch.maximum(a[:, 3:], b[:, 3:])
    assert ((m[:, 3:] >= lo - 1e-6) & (m[:, 3:] <= hi + 1e-6)).all()
    torch.testing.assert_close(m[:, 3:], w * a[:, 3:] + (1 - w) * b[:, 3:])
    torch.testing.assert_close(m[:, :3].norm(dim=1), torch.ones(4, 16, 16))
    # Slopes (x/z, y/z) are the same convex combination (all z >= 0.01 here).
    slope = lambda t: t[:, 0:2] / t[:, 2:3]  # noqa: E731
    torch.testing.assert_close(slope(m), w * slope(a) + (1 - w) * slope(b), rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(m[0], b[0])
    torch.testing.assert_close(m[3], a[3])


def test_mix_of_height_fields_normals_is_the_mixed_height_field() -> None:
    size = 32
    g = torch.Generator().manual_seed(3)
    h1, h2 = torch.rand(1, 1, size, size, generator=g), torch.rand(1, 1, size, size, generator=g)
    flat = M.constant_maps(1, size, size)
    a = torch.cat([normals_from_height(h1, 5.0), flat[:, 3:]], 1)
    b = torch.cat([normals_from_height(h2, 5.0), flat[:, 3:]], 1)
    m = augment.mix(a, b, 0.3)
    expected = normals_from_height(0.3 * h1 + 0.7 * h2, 5.0)
    assert angles(m[:, :3], expected).max() < 1e-5


def test_random_mix_is_seeded_and_in_range() -> None:
    a, b = random_maps(8, 8, seed=4), random_maps(8, 8, seed=5)
    m1, w1 = augment.random_mix(a, b, torch.Generator().manual_seed(7))
    m2, w2 = augment.random_mix(a, b, torch.Generator().manual_seed(7))
    assert torch.equal(m1, m2) and torch.equal(w1, w2)
    assert w1.shape == (8,) and (w1 >= 0.1).all() and (w1 <= 0.9).all() and w1.std() > 0.05


def test_mix_rejects_bad_input() -> None:
    a = random_maps(2, 8, seed=0)
    with pytest.raises(ValueError, match="alpha: expected values in"):
        augment.mix(a, a, 1.5)
    with pytest.raises(ValueError, match=r"alpha: expected a number or a tensor of shape \(2,\)"):
        augment.mix(a, a, torch.ones(3))
    with pytest.raises(ValueError, match="b: expected the shape"):
        augment.mix(a, a[:, :, :4], 0.5)


# ------------------------------------------------------------------------------------- transforms

def test_identity_transform_and_exact_crop() -> None:
    maps = M.normalize_normals(random_maps(2, 32, seed=6))
    same = augment.transform_maps(maps, angle=0.0, scale=1.0)
    torch.testing.assert_close(same, maps, rtol=0, atol=1e-5)
    # scale 1, half the size, window centred at (0.5, 0.5): the top-right quadrant, exactly.
    crop = augment.transform_maps(maps, translation=(0.5, 0.5), out_size=16)
    torch.testing.assert_close(crop, maps[:, :, :16, 16:], rtol=0, atol=1e-5)


@pytest.mark.parametrize("angle,scale", [(0.5, 1.3), (-2.2, 0.9), (math.pi / 2, 1.0)])
def test_rotated_normals_match_the_rotated_height_field(angle: float, scale: float) -> None:
    size, out = 128, 64
    maps = height_maps(size)
    t = (0.1, -0.15)
    bound = float(augment.max_translation(angle, scale, out, size)[0])
    assert bound > 0.15, "the window must stay inside the input (no padding) for this test"
    res = augment.transform_maps(maps, angle, scale, t, out)
    half = out / (size * scale)  # window half-width in input-plane units
    # Heights in output-plane units (the surface scaled uniformly), finite-difference normals.
    h_out = res[:, 6:7].double() / half
    recomputed = normals_from_height(h_out, strength=out / 2.0)
    inner = (slice(None), slice(None), slice(1, -1), slice(1, -1))
    err = angles(res[:, :3], recomputed)[:, 1:-1, 1:-1]
    assert err.max() < math.radians(1.0), math.degrees(err.max())
    # Also against the analytic normals at the sampled positions: n = (-R(θ)∇h(q), 1).
    x, y = plane_grid(out)
    c, s = math.cos(angle), math.sin(angle)
    qx, qy = t[0] + half * (c * x + s * y), t[1] + half * (-s * x + c * y)
    hx = 0.45 * torch.cos(3 * qx + 1) + 0.08 * qy
    hy = -0.25 * torch.sin(2.5 * qy - 0.5) + 0.08 * qx
    n = torch.stack([-(c * hx - s * hy), -(s * hx + c * hy), torch.ones_like(hx)]).unsqueeze(0)
    n = n / n.norm(dim=1, keepdim=True)
    assert angles(res[:, :3], n)[inner[1:]].max() < math.radians(0.5)
    # A visible effect: normals really turned (they are not just resampled).
    unrotated = augment.transform_maps(maps, 0.0, scale, t, out)
    assert angles(res[:, :3], unrotated[:, :3]).mean() > math.radians(1.0)


def test_quarter_turn_sign_convention() -> None:
    # A ramp rising towards +x (normal tilted to -x) turned by +90 degrees rises towards +y.
    n = torch.tensor([-0.6, 0.0, 0.8]).view(1, 3, 1, 1).expand(1, 3, 8, 8)
    maps = torch.cat([n, torch.full((1, 7, 8, 8), 0.5)], 1)
    out = augment.transform_maps(maps, angle=math.pi / 2)
    torch.testing.assert_close(out[0, :3, 4, 4], torch.tensor([0.0, -0.6, 0.8]), rtol=0, atol=1e-6)


def test_reflection_padding_mirrors_normals() -> None:
    # Window centred on the right edge: its right half is the mirror image, where a ramp's
    # x slope changes sign.
    size = 16
    x, _ = plane_grid(size)
    n = torch.stack([torch.full_like(x, -0.6), torch.zeros_like(x), torch.full_like(x, 0.8)])
    maps = torch.cat([n.float(), x.float().expand(7, size, size) * 0.25 + 0.5]).unsqueeze(0)
    out = augment.transform_maps(maps, translation=(1.0, 0.0), padding="reflection")
    torch.testing.assert_close(out[0, 0, :, : size // 2], torch.full((size, size // 2), -0.6), atol=1e-6, rtol=0)
    torch.testing.assert_close(out[0, 0, :, size // 2:], torch.full((size, size // 2), 0.6), atol=1e-6, rtol=0)
    # The mirrored values continue without a seam: the left half mirrored is the right half.
    torch.testing.assert_close(out[0, 3:, :, size // 2:], out[0, 3:, :, : size // 2].flip(-1), atol=1e-6, rtol=0)
    wrapped = augment.transform_maps(maps, translation=(1.0, 0.0), padding="wrap")
    torch.testing.assert_close(wrapped[0, 0], torch.full((size, size), -0.6), atol=1e-6, rtol=0)
    torch.testing.assert_close(wrapped[0, 3:, :, size // 2:], maps[0, 3:, :, : size // 2], atol=1e-6, rtol=0)


def test_minification_is_antialiased() -> None:
    # A one-texel checkerboard shrunk 3x: without supersampling every output texel hits one input
    # texel centre (all black or white); with 3 x 3 samples each averages 4/9 or 5/9.
    size = 32
    checker = ((torch.arange(size).view(-1, 1) + torch.arange(size).view(1, -1)) % 2).float()
    maps = M.constant_maps(1, size, size).clone()
    maps[:, 3:6] = checker
    smooth = augment.transform_maps(maps, scale=1 / 3, padding="wrap")
    sharp = augment.transform_maps(maps, scale=1 / 3, padding="wrap", antialias=False)
    assert (smooth[:, 3:6] - 0.5).abs().max() < 1 / 18 + 1e-5
    assert (sharp[:, 3:6] - 0.5).abs().min() > 0.5 - 1e-5


def test_random_transform_is_seeded_and_stays_inside() -> None:
    maps = height_maps(64).expand(3, -1, -1, -1).contiguous()
    r1, p1 = augment.random_transform(maps, torch.Generator().manual_seed(9), scale_range=(1.5, 2.0), out_size=32)
    r2, p2 = augment.random_transform(maps, torch.Generator().manual_seed(9), scale_range=(1.5, 2.0), out_size=32)
    assert torch.equal(r1, r2) and all(torch.equal(p1[k], p2[k]) for k in p1)
    assert r1.shape == (3, 10, 32, 32)
    assert ((p1["scale"] >= 1.5) & (p1["scale"] <= 2.0)).all()
    bound = augment.max_translation(p1["angle"], p1["scale"], 32, 64)
    assert (p1["translation"].abs() <= bound.view(-1, 1)).all() and (bound > 0).all()
    torch.testing.assert_close(augment.transform_maps(maps, **p1, out_size=32), r1)


def test_transform_rejects_bad_input() -> None:
    maps = random_maps(2, 8, seed=0)
    with pytest.raises(ValueError, match="scale: expected values > 0"):
        augment.transform_maps(maps, scale=0.0)
    with pytest.raises(ValueError, match="padding: expected one of"):
        augment.transform_maps(maps, padding="zeros")
    with pytest.raises(ValueError, match="expected square maps"):
        augment.transform_maps(maps[:, :, :4])
    with pytest.raises(ValueError, match="translation: expected"):
        augment.transform_maps(maps, translation=(0.0, 0.0, 0.0))


# ------------------------------------------------------------------------------------- parameters

def test_perturb_parameters_stays_valid_and_near() -> None:
    from mi_svbrdf.data import procedural

    for name, cls in procedural.CLASSES.items():
        base = procedural.sample_parameters(name, torch.Generator().manual_seed(1), spread=0.5)
        assert augment.perturb_parameters(name, base, torch.Generator().manual_seed(2), amount=0.0) == base
        a = augment.perturb_parameters(name, base, torch.Generator().manual_seed(2), amount=0.1)
        b = augment.perturb_parameters(name, base, torch.Generator().manual_seed(2), amount=0.1)
        assert a == b and a != base and procedural.validate_parameters(name, a) == a
        for key, spec in cls.params.items():
            assert spec.low <= a[key] <= spec.high
            assert abs(a[key] - base[key]) <= 0.6 * (spec.high - spec.low) + (1 if spec.integer else 0)
            if spec.integer:
                assert a[key] == round(a[key])
    with pytest.raises(ValueError, match="amount: expected"):
        augment.perturb_parameters("wood", {}, torch.Generator(), amount=-1.0)
