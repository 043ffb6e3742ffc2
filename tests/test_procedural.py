"""Procedural SVBRDF library: registry, parameters, determinism, validity, class properties."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mi_svbrdf.data import procedural as P
from mi_svbrdf.data.procedural import noise
from mi_svbrdf.data.procedural.surface import Surface, finish, hsv, srgb_to_linear

NAMES = ("paint", "plastic", "leather", "metal", "wood", "fabric", "stone", "tiles", "ground")
SIZE = 40  # small (even) maps keep the suite fast; odd sizes are tested for batch equality


def random_params(name: str, count: int, seed: int, spread: float = 1.0) -> list[dict[str, float]]:
    gen = torch.Generator().manual_seed(seed)
    return [P.sample_parameters(name, gen, spread) for _ in range(count)]


def extremes(name: str) -> list[dict[str, float]]:
    """All parameters at their low end, all at their high end."""
    params = P.CLASSES[name].params
    return [{k: p.low for k, p in params.items()}, {k: p.high for k, p in params.items()}]


def luminance(rgb: torch.Tensor) -> torch.Tensor:
    return rgb[..., 0, :, :] * 0.2126 + rgb[..., 1, :, :] * 0.7152 + rgb[..., 2, :, :] * 0.0722


def corr(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.flatten().double(), b.flatten().double()
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / (a.norm() * b.norm() + 1e-30))


# --- registry and parameters -------------------------------------------------------------------

def test_registry_has_the_nine_documented_classes():
    assert tuple(P.CLASSES) == NAMES
    for name, cls in P.CLASSES.items():
        assert cls.name == name and len(cls.doc) > 80 and cls.params
        assert cls.metal == (name == "metal")
        assert set(cls.ranges) == {"diffuse", "roughness", "specular"}
        for key, p in cls.params.items():
            assert p.low <= p.default <= p.high and p.low < p.high, (name, key)
            assert p.doc, (name, key)
            if p.integer:
                assert all(float(v).is_integer() for v in (p.low, p.default, p.high)), (name, key)
    assert {n for n, c in P.CLASSES.items() if c.decorrelated} == {"paint", "plastic"}
    # The parameters the issue names exist, each with a range.
    named = {("tiles", "tile_count"), ("tiles", "grout_width"), ("wood", "ring_frequency"), ("wood", "grain"),
             ("ground", "crack_density"), ("ground", "pebble_size"), ("metal", "scratch_density"),
             ("fabric", "weave_frequency"), ("metal", "palette")}
    assert all(key in P.CLASSES[name].params for name, key in named)


def test_validate_parameters_fills_defaults_and_rejects_bad_input():
    full = P.validate_parameters("tiles", {"tile_count": 6})
    assert full["tile_count"] == 6.0 and full["grout_width"] == P.CLASSES["tiles"].params["grout_width"].default
    assert set(full) == set(P.CLASSES["tiles"].params)
    assert P.validate_parameters("wood", None) == {k: p.default for k, p in P.CLASSES["wood"].params.items()}
    with pytest.raises(ValueError, match=r"name: expected one of .*'wood'.*got 'marble'"):
        P.validate_parameters("marble", {})
    with pytest.raises(ValueError, match=r"unknown parameter 'tiles_count' of class 'tiles'"):
        P.validate_parameters("tiles", {"tiles_count": 3})
    with pytest.raises(ValueError, match=r"tiles\.tile_count: expected a value in \[1, 16\].*got 40"):
        P.validate_parameters("tiles", {"tile_count": 40})
    with pytest.raises(ValueError, match=r"tiles\.tile_count: expected an integer in \[1, 16\].*got 4\.5"):
        P.validate_parameters("tiles", {"tile_count": 4.5})
    with pytest.raises(ValueError, match=r"wood\.grain: expected a value in \[0, 1\].*got nan"):
        P.validate_parameters("wood", {"grain": float("nan")})
    with pytest.raises(ValueError, match=r"wood\.grain: expected a number"):
        P.validate_parameters("wood", {"grain": "high"})
    with pytest.raises(ValueError, match=r"unknown parameter"):
        P.generate("stone", 0, 16, pebble_size=0.1)


def test_sample_parameters_spread_and_determinism():
    for name, cls in P.CLASSES.items():
        defaults = {k: p.default for k, p in cls.params.items()}
        assert P.sample_parameters(name, torch.Generator().manual_seed(0), spread=0.0) == defaults
        a = P.sample_parameters(name, torch.Generator().manual_seed(3), spread=1.0)
        assert a == P.sample_parameters(name, torch.Generator().manual_seed(3), spread=1.0)
        assert P.validate_parameters(name, a) == a
        half = P.sample_parameters(name, torch.Generator().manual_seed(3), spread=0.5)
        for key, p in cls.params.items():  # spread 0.5 lies halfway between the default and the full draw
            if not p.integer:
                assert half[key] == pytest.approx(0.5 * (p.default + a[key]), abs=1e-9)
    # spread = 1 covers each range (and integers stay whole numbers).
    gen = torch.Generator().manual_seed(1)
    draws = [P.sample_parameters("tiles", gen) for _ in range(400)]
    counts = [d["tile_count"] for d in draws]
    assert min(counts) == 1 and max(counts) == 16 and all(c.is_integer() for c in counts)
    grout = [d["grout_width"] for d in draws]
    assert min(grout) < 0.01 and max(grout) > 0.19
    with pytest.raises(ValueError, match=r"spread: expected a value in \[0, 1\]"):
        P.sample_parameters("wood", torch.Generator(), spread=1.5)


# --- determinism ------------------------------------------------------------------------------

def test_same_seed_identical_different_seeds_and_classes_differ():
    for name in NAMES:
        a = P.generate(name, 7, SIZE)
        assert a.shape == (10, SIZE, SIZE) and a.dtype == torch.float32
        assert torch.equal(a, P.generate(name, 7, SIZE))
        assert not torch.equal(a, P.generate(name, 8, SIZE))
    # The same seed in two classes does not give related noise (the class is mixed into the seed).
    assert P._element_seed("wood", 3) != P._element_seed("stone", 3)


@pytest.mark.parametrize("size", [37])
def test_batch_element_equals_single_generation(size):
    for name in NAMES:
        params = random_params(name, 3, seed=size)
        seeds = [11, 5, 2**40 + 3]
        batch = P.generate_batch(name, seeds, size, params)
        assert batch.shape == (3, 10, size, size)
        for i in range(3):
            assert torch.equal(batch[i], P.generate(name, seeds[i], size, **params[i])), (name, size, i)
        assert torch.equal(batch[1:], P.generate_batch(name, seeds[1:], size, params[1:])), name


def test_batches_larger_than_a_chunk():
    seeds = list(range(P.CHUNK + 2))
    batch = P.generate_batch("fabric", seeds, 24)
    assert torch.equal(batch[-1], P.generate("fabric", seeds[-1], 24))
    assert torch.equal(batch[:3], P.generate_batch("fabric", seeds[:3], 24))


def test_request_validation():
    with pytest.raises(ValueError, match=r"size: expected an integer >= 8, got 4"):
        P.generate("wood", 0, 4)
    with pytest.raises(ValueError, match=r"seeds: expected integers in \[0, 2\^63\), got -1"):
        P.generate("wood", -1, 16)
    with pytest.raises(ValueError, match=r"seeds: expected a non-empty sequence"):
        P.generate_batch("wood", [], 16)
    with pytest.raises(ValueError, match=r"params: expected a sequence of 2 dicts"):
        P.generate_batch("wood", [0, 1], 16, [{}])


# --- validity ---------------------------------------------------------------------------------

def check_valid(name: str, maps: torch.Tensor) -> None:
    cls = P.CLASSES[name]
    assert torch.isfinite(maps).all(), name
    n = maps[:, 0:3]
    assert (n.norm(dim=1) - 1.0).abs().max() < 1e-5, name
    assert n[:, 2].min() > 0.0, name
    for key, sl in (("diffuse", slice(3, 6)), ("roughness", slice(6, 7)), ("specular", slice(7, 10))):
        lo, hi = cls.ranges[key]
        values = maps[:, sl]
        assert 0.0 <= lo and hi <= 1.0
        assert values.min() >= lo - 1e-6 and values.max() <= hi + 1e-6, (name, key, float(values.min()),
                                                                          float(values.max()))


@pytest.mark.parametrize("name", NAMES)
def test_outputs_inside_documented_ranges(name):
    params = [{}] + random_params(name, 4, seed=2) + extremes(name)
    maps = P.generate_batch(name, list(range(len(params))), SIZE, params)
    check_valid(name, maps)
    # Not a constant: at defaults and random parameters every class has texture in its albedo or
    # normals (the extremes may switch every variation off).
    assert maps[:5, 0:6].flatten(2).std(dim=2).amax(dim=1).min() > 1e-3


def test_metals_have_coloured_specular_and_dielectrics_grey_specular():
    metal = P.generate_batch("metal", list(range(8)), SIZE, random_params("metal", 8, seed=4))
    assert metal[:, 3:6].max() <= 0.05 and metal[:, 7:10].mean() > 0.3
    gold = P.generate("metal", 0, SIZE, palette=list(P.metal.PALETTE).index("gold"), tarnish=0.0)
    red, blue = gold[7].mean(), gold[9].mean()
    assert red > 0.8 and blue < 0.4  # coloured: F0 of gold
    steel = P.generate("metal", 0, SIZE, palette=0)
    assert (steel[7:10].mean(dim=(1, 2)) - steel[7:10].mean()).abs().max() < 0.02  # steel is nearly grey
    for name in NAMES:
        if name == "metal":
            continue
        maps = P.generate_batch(name, [0, 1, 2], SIZE, [{}] + random_params(name, 2, seed=5))
        spec = maps[:, 7:10]
        assert torch.equal(spec[:, 0], spec[:, 1]) and torch.equal(spec[:, 0], spec[:, 2]), name  # grey
        assert spec.min() >= 0.02 and spec.max() <= 0.08, name
        assert maps[:, 3:6].max() > 0.1, name  # a dielectric has a visible diffuse albedo


# --- parameters act as documented ---------------------------------------------------------------

#: Parameters that only act when another one is on.
ENABLE = {("metal", "dent_size"): {"hammered": 1.0}}


@pytest.mark.parametrize("name", NAMES)
def test_every_parameter_changes_the_output(name):
    for key, p in P.CLASSES[name].params.items():
        base = ENABLE.get((name, key), {})
        mid = 0.5 * (p.low + p.high)
        values = (p.low, float(math.floor(mid)) if p.integer else mid, p.high)
        outs = [P.generate(name, 0, 24, **{**base, key: v}) for v in values]
        assert not (torch.equal(outs[0], outs[1]) and torch.equal(outs[1], outs[2])), (name, key)


def dominant_frequency(profile: torch.Tensor) -> int:
    spectrum = torch.fft.rfft(profile - profile.mean()).abs()
    return int(spectrum[1:].argmax()) + 1


def test_tile_count_sets_the_tile_period():
    for count in (3, 5, 8):
        maps = P.generate("tiles", 1, 128, tile_count=count, tilt=0.0, wear=0.0, color_variation=0.0)
        assert dominant_frequency(maps[6].mean(dim=0)) == count  # grout lines across the roughness map
        assert dominant_frequency(maps[6].mean(dim=1)) == count  # square tiles: the same down the rows
    brick = P.generate("tiles", 1, 128, tile_count=4, aspect=2.0, tilt=0.0, wear=0.0, color_variation=0.0)
    assert dominant_frequency(brick[6].mean(dim=1)) == 8  # aspect 2: twice as many rows


def test_weave_frequency_sets_the_thread_period():
    for freq in (16, 24):
        maps = P.generate("fabric", 1, 128, weave_frequency=freq, fuzz=0.0)
        assert dominant_frequency(luminance(maps[3:6]).mean(dim=0)) == freq


def test_decorrelated_classes_decorrelate_albedo_and_relief():
    def mean_abs_corr(name: str) -> float:
        """Mean |corr(albedo luminance, |grad h|)| over 8 materials (4 default, 4 random)."""
        params = [{}] * 4 + random_params(name, 4, seed=6)
        maps, height = P.generate_surface(name, list(range(len(params))), 64, params)
        gy, gx = torch.gradient(height[:, 0], dim=(1, 2))
        slope = torch.sqrt(gx * gx + gy * gy)[:, 1:-1, 1:-1]
        return sum(abs(corr(luminance(maps[i, 3:6]), slope[i])) for i in range(len(params))) / len(params)

    # Independent fields still correlate by chance over a few blobs: ~0.04 on average.
    for name in ("paint", "plastic"):
        assert mean_abs_corr(name) < 0.06, name
    for name in ("tiles", "wood"):  # correlated classes
        assert mean_abs_corr(name) > 0.15, name


def test_normals_are_the_height_gradient():
    for name in NAMES:
        maps, height = P.generate_surface(name, [3], 48, random_params(name, 1, seed=7))
        assert height.shape == (1, 1, 50, 50)
        h = height[0, 0].double().numpy()
        spacing = 2.0 / 48  # plane units per texel; rows go down (-y)
        d_row, d_col = np.gradient(h, spacing)
        dhdx, dhdy = d_col[1:-1, 1:-1], -d_row[1:-1, 1:-1]
        n = np.stack([-dhdx, -dhdy, np.ones_like(dhdx)])
        n /= np.linalg.norm(n, axis=0)
        assert np.abs(n - maps[0, 0:3].double().numpy()).max() < 1e-5, name
        assert np.abs(dhdx).max() > 1e-3 or np.abs(dhdy).max() > 1e-3, name  # some relief


def test_finish_orientation_x_right_y_up():
    x, y = noise.plane_grid(8)
    for field, expected in ((x, (-1.0, 0.0)), (y, (0.0, -1.0))):  # h = x rises to the right, h = y upwards
        surface = Surface(height=field.expand(1, 1, -1, -1).clone(), diffuse=torch.zeros(1, 3, 10, 10),
                          roughness=torch.zeros(1, 1, 10, 10), specular=torch.zeros(1, 1, 10, 10))
        n = finish(surface, 8)[0, 0:3]
        want = torch.tensor([expected[0], expected[1], 1.0]) / math.sqrt(2.0)
        assert torch.allclose(n, want.view(3, 1, 1).expand_as(n), atol=1e-6)


# --- noise primitives -------------------------------------------------------------------------

def test_voronoi_on_a_regular_grid_is_exact():
    gens = [torch.Generator().manual_seed(0)]
    x, y = noise.plane_grid(64)
    cells = noise.voronoi(gens, x, y, 4.0, jitter=0.0, values=2)
    u, v = (x + 1.0) * 2.0, (y + 1.0) * 2.0  # 4 cells across
    fu, fv = u - torch.floor(u), v - torch.floor(v)
    assert torch.allclose(cells.f1, torch.sqrt((fu - 0.5) ** 2 + (fv - 0.5) ** 2), atol=1e-5)
    border = torch.minimum(torch.minimum(fu, 1 - fu), torch.minimum(fv, 1 - fv))
    assert torch.allclose(cells.edge, border, atol=1e-5)
    cell_id = torch.floor(u) * 100 + torch.floor(v)
    for cid in cell_id.unique():  # one set of random values per cell
        vals = cells.values[0][:, (cell_id[0, 0] == cid)]
        assert (vals.amax(dim=1) - vals.amin(dim=1)).max() == 0
    # Random cells: a texel farther than a texel diagonal from the border has its 4 neighbours in
    # its own cell; a texel with a neighbour in another cell is within a texel of the border.
    x, y = noise.plane_grid(128, margin=0)
    cells = noise.voronoi([torch.Generator().manual_seed(3)], x, y, 6.0, jitter=1.0)
    texel = 6.0 / 128  # in cell units
    v = cells.values[0, 0]
    same = torch.ones_like(v, dtype=torch.bool)[1:-1, 1:-1]
    for di, dj in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        same &= v[1 + dj:127 + dj, 1 + di:127 + di] == v[1:-1, 1:-1]
    edge = cells.edge[0, 0, 1:-1, 1:-1]
    assert edge.min() >= 0.0 and (~same).sum() > 100
    assert bool(same[edge > 1.5 * texel].all()) and bool((edge[~same] < 1.01 * texel).all())


def test_value_noise_is_periodic_and_fbm_is_centred():
    gens = [torch.Generator().manual_seed(1)]
    x, y = noise.plane_grid(32)
    period, freq = 16, 4.0
    a = noise.value_noise(gens, x, y, freq, period=period)
    gens = [torch.Generator().manual_seed(1)]
    b = noise.value_noise(gens, x + period * 2.0 / freq, y, freq, period=period)
    assert torch.allclose(a, b, atol=1e-4)
    f = noise.fbm([torch.Generator().manual_seed(s) for s in range(4)], *noise.plane_grid(64), 6.0, octaves=4)
    assert abs(float(f.mean()) - 0.5) < 0.05 and f.min() > -0.2 and f.max() < 1.2


def test_colour_helpers():
    red = hsv(0.0, 1.0, 1.0).view(3)
    assert torch.allclose(red, torch.tensor([1.0, 0.0, 0.0]))
    assert torch.allclose(hsv(1.0 / 3.0, 1.0, 0.5).view(3), torch.tensor([0.0, 0.5, 0.0]), atol=1e-6)
    assert torch.allclose(srgb_to_linear(torch.tensor([0.0, 0.5, 1.0])), torch.tensor([0.0, 0.21404, 1.0]), atol=1e-5)


def test_docstring_examples():
    import doctest

    from mi_svbrdf.data.procedural import noise as noise_module

    for module in (P, noise_module):
        result = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
        assert result.attempted > 0 and result.failed == 0, module.__name__
