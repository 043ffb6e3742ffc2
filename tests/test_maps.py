"""The canonical SVBRDF tensor: accessors, construction, validation, network layouts."""
from __future__ import annotations

import math

import pytest
import torch

from mi_svbrdf.core import maps as M
from tests.conftest import random_maps


def _distinct(batch=2, h=3, w=4) -> torch.Tensor:
    """(B, 10, H, W) whose channel c holds 100 c + texel index (every value tells where it came from)."""
    c = torch.arange(10, dtype=torch.float32)[None, :, None, None] * 100
    t = torch.arange(h * w, dtype=torch.float32).view(1, 1, h, w)
    b = torch.arange(batch, dtype=torch.float32)[:, None, None, None] * 1000
    return c + t + b


def test_layout_constants():
    assert M.NUM_CHANNELS == 10
    assert M.MAP_NAMES == ("normal", "diffuse", "roughness", "specular")
    assert M.SLICES == {"normal": slice(0, 3), "diffuse": slice(3, 6), "roughness": slice(6, 7),
                        "specular": slice(7, 10)}
    assert M.MAP_CHANNELS == {"normal": 3, "diffuse": 3, "roughness": 1, "specular": 3}


def test_accessors_and_split():
    m = _distinct()
    assert torch.equal(M.normal(m), m[:, 0:3])
    assert torch.equal(M.diffuse(m), m[:, 3:6])
    assert torch.equal(M.roughness(m), m[:, 6:7])
    assert torch.equal(M.specular(m), m[:, 7:10])
    assert M.roughness(m).shape == (2, 1, 3, 4)
    assert float(M.specular(m)[1, 2, 0, 1]) == 1000 + 900 + 1
    parts = M.split(m)
    assert list(parts) == ["normal", "diffuse", "roughness", "specular"]
    for name, part in parts.items():
        assert torch.equal(part, m[:, M.SLICES[name]])
    # Views, not copies.
    parts["roughness"][0, 0, 0, 0] = -7.0
    M.diffuse(m)[1, 0, 2, 3] = -8.0
    assert float(m[0, 6, 0, 0]) == -7.0 and float(m[1, 3, 2, 3]) == -8.0


def test_make_maps_round_trip_and_roughness_averaging():
    m = random_maps(2, 5, 6, seed=0)
    assert torch.equal(M.make_maps(M.normal(m), M.diffuse(m), M.roughness(m), M.specular(m)), m)
    r3 = torch.stack([torch.full((2, 5, 6), 0.1), torch.full((2, 5, 6), 0.2), torch.full((2, 5, 6), 0.6)], dim=1)
    out = M.make_maps(M.normal(m), M.diffuse(m), r3, M.specular(m))
    assert out.shape == (2, 10, 5, 6)
    assert torch.allclose(M.roughness(out), torch.full((2, 1, 5, 6), 0.3))
    assert torch.equal(M.specular(out), M.specular(m)) and torch.equal(M.diffuse(out), M.diffuse(m))


@pytest.mark.parametrize("key, bad, match", [
    ("normal", torch.zeros(2, 2, 5, 6), "normal: expected 3 channels, got 2"),
    ("diffuse", torch.zeros(2, 4, 5, 6), "diffuse: expected 3 channels, got 4"),
    ("roughness", torch.zeros(2, 2, 5, 6), "roughness: expected 1 channels, got 2"),
    ("specular", torch.zeros(2, 3, 5), r"specular: expected shape \(B, C, H, W\)"),
    ("diffuse", torch.zeros(2, 3, 5, 7), r"diffuse: expected batch and size \(B, H, W\) = \(2, 5, 6\)"),
    ("roughness", torch.zeros(1, 1, 5, 6), "roughness: expected batch and size"),
    ("specular", torch.zeros(2, 3, 4, 6), "specular: expected batch and size"),
])
def test_make_maps_errors_name_the_map(key, bad, match):
    m = random_maps(2, 5, 6)
    parts = M.split(m)
    parts[key] = bad
    with pytest.raises(ValueError, match=match):
        M.make_maps(**parts)


def test_constant_maps():
    m = M.constant_maps(2, 3, 4, normal=(1.0, 0.0, 1.0), diffuse=(0.5, 0.4, 0.3), roughness=0.25, specular=0.04)
    assert m.shape == (2, 10, 3, 4) and m.dtype == torch.float32 and m.is_contiguous()
    s = 1 / math.sqrt(2)
    expect = [s, 0.0, s, 0.5, 0.4, 0.3, 0.25, 0.04, 0.04, 0.04]
    for b in range(2):
        for i in range(3):
            for j in range(4):
                assert m[b, :, i, j].tolist() == pytest.approx(expect, rel=1e-6)
    d = M.constant_maps(1, 2, 2)  # defaults: flat, grey 0.5, roughness 0.5, specular 0.04
    assert d[0, :, 1, 1].tolist() == pytest.approx([0, 0, 1, 0.5, 0.5, 0.5, 0.5, 0.04, 0.04, 0.04])
    d64 = M.constant_maps(1, 2, 2, diffuse=1, dtype=torch.float64)
    assert d64.dtype == torch.float64 and d64[0, 3:6].eq(1.0).all()
    # Independent storage per texel (contiguous, not an expanded view).
    m[0, 3, 0, 0] = 9.0
    assert float(m[1, 3, 0, 0]) == 0.5 and float(m[0, 3, 1, 1]) == 0.5


@pytest.mark.parametrize("bad, match", [
    (torch.zeros(1, 9, 4, 4), r"maps: expected shape \(B, 10, H, W\)"),
    (torch.zeros(10, 4, 4), r"maps: expected shape \(B, 10, H, W\)"),
    (torch.zeros(1, 10, 4, 4, 1), r"maps: expected shape \(B, 10, H, W\)"),
    (torch.zeros(1, 10, 4, 4, dtype=torch.int32), "floating-point"),
    (torch.full((1, 10, 4, 4), float("nan")), "NaN or Inf"),
    (torch.full((1, 10, 4, 4), float("inf")), "NaN or Inf"),
])
def test_check_maps_errors(bad, match):
    with pytest.raises(ValueError, match=match):
        M.check_maps(bad)


def test_check_maps_names_and_accepts():
    M.check_maps(random_maps(1, 4, 4))
    M.check_maps(random_maps(2, 3, 5, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"^pred: expected shape \(B, 10, H, W\)"):
        M.check_maps(torch.zeros(1, 3, 4, 4), "pred")
    with pytest.raises(TypeError, match="expected a torch.Tensor"):
        M.check_maps([[0.0] * 10])


def test_normalize_normals():
    m = random_maps(1, 3, 3, seed=1)
    m[:, 0:3] *= torch.linspace(0.5, 3.0, 9).view(1, 1, 3, 3)
    out = M.normalize_normals(m)
    assert torch.allclose(M.normal(out).norm(dim=1), torch.ones(1, 3, 3), atol=1e-6)
    assert torch.equal(out[:, 3:], m[:, 3:])
    assert torch.allclose(M.normal(out) * M.normal(m).norm(dim=1, keepdim=True), M.normal(m), atol=1e-6)
    assert torch.isfinite(M.normalize_normals(torch.zeros(1, 10, 2, 2))).all()


def _output(h=2, w=3, seed=0, activation="tanh") -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(1, 9, h, w, generator=g, dtype=torch.float64)
    return 2 * x - 1 if activation == "tanh" else x


@pytest.mark.parametrize("scale", [1.0, 3.0])
def test_from_network_output_tanh(scale):
    out = _output(activation="tanh")
    m = M.from_network_output(out, normal_scale=scale)
    assert m.shape == (1, 10, 2, 3)
    for i in range(2):
        for j in range(3):
            v = out[0, :, i, j].tolist()
            n = [scale * v[0], scale * v[1], 1.0]
            length = math.sqrt(sum(c * c for c in n))
            # 9 channels: normal xy | diffuse | specular | roughness; canonical: normal | diffuse | roughness | specular.
            expect = ([c / length for c in n] + [(c + 1) / 2 for c in v[2:5]] + [(v[8] + 1) / 2]
                      + [(c + 1) / 2 for c in v[5:8]])
            assert m[0, :, i, j].tolist() == pytest.approx(expect, rel=1e-12, abs=1e-15)


def test_from_network_output_channel_order_and_ranges():
    """Constant per-channel outputs identify where each of the 9 channels lands."""
    vals = torch.tensor([0.0, 0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7], dtype=torch.float64)
    out = vals.view(1, 9, 1, 1).expand(1, 9, 2, 2)
    m = M.from_network_output(out, activation="sigmoid")
    # sigmoid: xy = 2 v - 1 = (-1, -1) -> normalize(-1, -1, 1); the rest taken as is.
    r3 = 1 / math.sqrt(3)
    assert m[0, :, 1, 0].tolist() == pytest.approx([-r3, -r3, r3, 0.1, 0.2, 0.3, 0.7, 0.4, 0.5, 0.6], rel=1e-12)
    m = M.from_network_output(out, activation="tanh")
    # tanh: xy = (0, 0) -> (0, 0, 1); the rest (v + 1) / 2.
    assert m[0, :, 0, 1].tolist() == pytest.approx([0, 0, 1, 0.55, 0.6, 0.65, 0.85, 0.7, 0.75, 0.8], rel=1e-12)
    # The endpoints of each activation map to [0, 1].
    lo, hi = M.from_network_output(-torch.ones(1, 9, 1, 1)), M.from_network_output(torch.ones(1, 9, 1, 1))
    assert lo[0, 3:, 0, 0].tolist() == [0.0] * 7 and hi[0, 3:, 0, 0].tolist() == [1.0] * 7
    lo = M.from_network_output(torch.zeros(1, 9, 1, 1), activation="sigmoid")
    assert lo[0, 3:, 0, 0].tolist() == [0.0] * 7


def test_from_network_output_sigmoid_scale():
    out = _output(activation="sigmoid", seed=3)
    m = M.from_network_output(out, activation="sigmoid", normal_scale=3.0)
    xy = 2 * out[:, 0:2] - 1
    n = torch.cat([3 * xy, torch.ones_like(xy[:, :1])], 1)
    assert torch.allclose(M.normal(m), n / n.norm(dim=1, keepdim=True), atol=1e-12)
    assert torch.allclose(M.normal(m).norm(dim=1), torch.ones(1, 2, 3, dtype=torch.float64), atol=1e-12)
    # 2019's scale 3 tilts normals further than 2018's 1 for the same output.
    m1 = M.from_network_output(out, activation="sigmoid", normal_scale=1.0)
    assert (M.normal(m)[:, 2] <= M.normal(m1)[:, 2] + 1e-12).all()


def test_from_network_output_errors():
    with pytest.raises(ValueError, match=r"output: expected shape \(B, 9, H, W\)"):
        M.from_network_output(torch.zeros(1, 10, 2, 2))
    with pytest.raises(ValueError, match=r"output: expected shape \(B, 9, H, W\)"):
        M.from_network_output(torch.zeros(9, 2, 2))
    with pytest.raises(ValueError, match="activation"):
        M.from_network_output(torch.zeros(1, 9, 2, 2), activation="relu")


def test_to_network_layout_inverts_sigmoid():
    out = _output(h=4, w=5, seed=4, activation="sigmoid")
    m = M.from_network_output(out, activation="sigmoid")
    back = M.to_network_layout(m)
    assert back.shape == (1, 9, 4, 5)
    assert torch.allclose(back, out, atol=1e-12)
    # And the other way round, from maps tilted below 45 degrees (|x/z|, |y/z| < 1: the layout stays in [0, 1]).
    maps = random_maps(2, 4, 4, seed=5, max_tilt=0.7, dtype=torch.float64)
    layout = M.to_network_layout(maps)
    assert layout.min() >= 0 and layout.max() <= 1
    assert torch.allclose(M.from_network_output(layout, activation="sigmoid"), maps, atol=1e-12)
    # The layout: (xy/z + 1)/2 | diffuse | specular | roughness.
    c = M.constant_maps(1, 1, 1, normal=(0.2, -0.4, 1.0), diffuse=(0.1, 0.2, 0.3), roughness=0.7,
                        specular=(0.4, 0.5, 0.6), dtype=torch.float64)
    assert M.to_network_layout(c).flatten().tolist() == pytest.approx([0.6, 0.3, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7],
                                                                     rel=1e-12)
    with pytest.raises(ValueError, match=r"expected shape \(B, 10, H, W\)"):
        M.to_network_layout(torch.zeros(1, 9, 2, 2))


def test_project_valid():
    m = torch.tensor([0.3, 0.4, -0.5, -0.2, 0.5, 1.3, 1.7, 0.04, -0.01, 2.0], dtype=torch.float64).view(1, 10, 1, 1)
    out = M.project_valid(m)
    z = 1e-3  # the normal's z is floored at 1e-3, then the normal is renormalised
    length = math.sqrt(0.3**2 + 0.4**2 + z * z)
    expect = [0.3 / length, 0.4 / length, z / length, 0.0, 0.5, 1.0, 1.0, 0.04, 0.0, 1.0]
    assert out.flatten().tolist() == pytest.approx(expect, rel=1e-12, abs=1e-15)
    M.check_maps(out)
    valid = random_maps(2, 4, 4, seed=6, dtype=torch.float64)
    assert torch.allclose(M.project_valid(valid), valid, atol=1e-12)  # valid maps are left alone
    zero = torch.zeros(1, 10, 1, 1)
    assert M.normal(M.project_valid(zero)).flatten().tolist() == [0.0, 0.0, 1.0]
