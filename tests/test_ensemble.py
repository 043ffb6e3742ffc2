"""The symmetries of the square on photos and maps, and the symmetry ensemble of a flash net."""
from __future__ import annotations

import pytest
import torch

from mi_svbrdf.core.maps import SYMMETRIES, make_maps, normal, symmetry_image, symmetry_maps
from mi_svbrdf.nets.ensemble import SymmetryEnsemble, symmetry_ensemble
from mi_svbrdf.nets.network import build_network, network_config

TINY = {"encoder_features": (8, 16, 16), "last_features": 8}


def _height_normals(h: torch.Tensor) -> torch.Tensor:
    """Unit normals (x right, y up) of a periodic height field ``(B, 1, H, W)`` (rows top to bottom)."""
    dx = (h.roll(-1, -1) - h.roll(1, -1)) / 2
    dy = -(h.roll(-1, -2) - h.roll(1, -2)) / 2  # y is up: the next row is lower
    n = torch.cat([-dx, -dy, torch.ones_like(dx)], dim=1)
    return n / n.norm(dim=1, keepdim=True)


def _maps_of(h: torch.Tensor, rest: torch.Tensor) -> torch.Tensor:
    return torch.cat([_height_normals(h), rest], dim=1)


@pytest.mark.parametrize("k", range(len(SYMMETRIES)))
def test_symmetry_maps_are_the_maps_of_the_transformed_surface(k: int) -> None:
    """Transforming a relief's maps equals taking the maps of the transformed relief (normals from its heights)."""
    g = torch.Generator().manual_seed(k)
    h = torch.rand(2, 1, 12, 12, generator=g)
    rest = torch.rand(2, 7, 12, 12, generator=g)
    moved = _maps_of(symmetry_image(h, k), symmetry_image(rest, k))
    assert torch.allclose(symmetry_maps(_maps_of(h, rest), k), moved, atol=1e-6)
    assert torch.allclose(symmetry_maps(moved, k, inverse=True), _maps_of(h, rest), atol=1e-6)


def test_symmetries_are_distinct_and_only_the_identity_keeps_an_asymmetric_map() -> None:
    maps = make_maps(torch.nn.functional.normalize(torch.rand(1, 3, 5, 5) + 0.2, dim=1), torch.rand(1, 3, 5, 5),
                     torch.rand(1, 1, 5, 5), torch.rand(1, 3, 5, 5))
    outs = [symmetry_maps(maps, k) for k in range(8)]
    assert torch.equal(outs[0], maps)
    assert all(not torch.allclose(outs[i], outs[j]) for i in range(8) for j in range(i + 1, 8))
    # the normal turns with the texels: a constant tilt to the right (+x) points left after a column flip
    flat = make_maps(torch.tensor([0.6, 0.0, 0.8]).view(1, 3, 1, 1).expand(1, 3, 4, 4),
                     torch.zeros(1, 3, 4, 4), torch.zeros(1, 1, 4, 4), torch.zeros(1, 3, 4, 4))
    assert torch.allclose(normal(symmetry_maps(flat, 1))[:, :, 0, 0], torch.tensor([[-0.6, 0.0, 0.8]]))
    assert torch.allclose(normal(symmetry_maps(flat, 4))[:, :, 0, 0], torch.tensor([[0.0, -0.6, 0.8]]))


def test_symmetry_maps_gradcheck() -> None:
    maps = torch.rand(1, 10, 3, 4, dtype=torch.float64, requires_grad=True)
    for k in (5, 7):
        assert torch.autograd.gradcheck(lambda m, k=k: symmetry_maps(m, k), (maps,))
        assert torch.autograd.gradcheck(lambda m, k=k: symmetry_maps(m, k, inverse=True), (maps,))


@pytest.mark.parametrize("kind, shape", [("single", (2, 1, 3, 24, 24)), ("single", (1, 3, 24, 40)),
                                         ("multi", (1, 3, 3, 24, 24))])
def test_the_ensemble_is_equivariant_where_the_net_is_not(kind: str, shape: tuple[int, ...]) -> None:
    """The ensemble's maps of a transformed photo are its transformed maps (any net), unlike the net's own."""
    torch.manual_seed(0)
    net = build_network(network_config("compact", kind, **TINY)).eval()
    photos = torch.rand(*shape)
    ens = SymmetryEnsemble(net)
    with torch.no_grad():
        base = ens(photos)
        assert tuple(base.shape) == (shape[0], 10, *shape[-2:])
        assert torch.allclose(normal(base).norm(dim=1), torch.ones(()), atol=1e-5)
        for k in range(1, 8):
            assert torch.allclose(ens(symmetry_image(photos, k)), symmetry_maps(base, k), atol=2e-5)
        raw = net(photos)
        gaps = [float((net(symmetry_image(photos, k)) - symmetry_maps(raw, k)).abs().max()) for k in range(1, 8)]
    assert min(gaps) > 1e-3  # the control: a random net is not equivariant


def test_flips_only_are_equivariant_under_flips() -> None:
    torch.manual_seed(1)
    net = build_network(network_config("compact", "single", **TINY)).eval()
    photos = torch.rand(1, 3, 24, 24)
    with torch.no_grad():
        base = symmetry_ensemble(net, photos, symmetries=4)  # identity, column flip, row flip, both
        for k in (1, 2, 3):
            assert torch.allclose(symmetry_ensemble(net, symmetry_image(photos, k), 4), symmetry_maps(base, k),
                                  atol=2e-5)
        assert torch.equal(symmetry_ensemble(net, photos, 1), net(photos))


def test_an_equivariant_net_is_its_own_ensemble() -> None:
    """A per-pixel net (flat normals, albedo from the colour) is equivariant: the ensemble changes nothing."""
    class PerPixel(torch.nn.Module):
        config = network_config("compact", "single")

        def forward(self, photos: torch.Tensor) -> torch.Tensor:
            x = photos[:, 0] if photos.dim() == 5 else photos
            flat = torch.zeros_like(x)
            flat[:, 2] = 1.0
            return make_maps(flat, x.sqrt(), x.mean(1, keepdim=True), x * 0.1)

    photos = torch.rand(2, 1, 3, 9, 7)
    assert torch.allclose(symmetry_ensemble(PerPixel(), photos), PerPixel()(photos), atol=1e-6)


@pytest.mark.parametrize("bad", [0, 9, 2.0, True, "8"])
def test_bad_symmetry_counts_are_refused(bad: object) -> None:
    net = build_network(network_config("compact", "single", **TINY))
    with pytest.raises(ValueError, match=r"symmetries: expected an int in \[1, 8\]"):
        symmetry_ensemble(net, torch.rand(1, 3, 16, 16), bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="k: expected an int in"):
        symmetry_maps(torch.rand(1, 10, 4, 4), 8)
