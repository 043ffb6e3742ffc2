"""The networks: shapes, the global-features toy task, order invariance, overfitting."""
from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from mi_svbrdf.core.loss import rendering_loss
from mi_svbrdf.core.maps import check_maps, normal
from mi_svbrdf.nets.network import PRESETS, build_network, config_from_dict, network_config, parameter_count

TINY = {"encoder_features": (8, 16, 16), "last_features": 8}


@pytest.mark.parametrize("kind", ["single", "multi"])
def test_presets_forward_shapes(kind: str) -> None:
    # The full thesis architecture (8 levels of 4x4 convolutions) at 1/16 width, run at 256^2.
    full = network_config("full", kind, encoder_features=tuple(f // 16 for f in PRESETS["full"]["encoder_features"]),
                          last_features=8)
    assert full.depth == 8 and full.kernel_size == 4
    net = build_network(full).eval()
    photos = torch.rand(1, 2 if kind == "multi" else 1, 3, 256, 256)
    with torch.no_grad():
        maps = net(photos)
    assert maps.shape == (1, 10, 256, 256)
    check_maps(maps)
    assert torch.allclose(normal(maps).norm(dim=1), torch.ones(1, 256, 256), atol=1e-5)
    compact = build_network(network_config("compact", kind)).eval()
    assert 8e6 < parameter_count(compact) < 1.1e7  # ~10 M: < 20 MB in fp16
    with torch.no_grad():
        assert compact(torch.rand(1, 1, 3, 128, 128)).shape == (1, 10, 128, 128)


def test_full_preset_is_the_thesis_size() -> None:
    net = build_network(network_config("full", "single"))
    assert len(net.trunk.encoder) == 8
    assert [s.conv.out_channels for s in net.trunk.encoder] == [128, 256, 512, 512, 512, 512, 512, 512]
    assert all(s.conv.kernel_size == (4, 4) and s.conv.stride == (2, 2) for s in net.trunk.encoder)


def test_any_size_is_padded_and_cropped() -> None:
    net = build_network(network_config("compact", "single", **TINY)).eval()
    with torch.no_grad():
        assert net(torch.rand(2, 3, 37, 50)).shape == (2, 10, 37, 50)


def test_bad_input_and_config() -> None:
    net = build_network(network_config("compact", "single", **TINY))
    with pytest.raises(ValueError, match="expected shape"):
        net(torch.rand(2, 4, 32, 32))
    with pytest.raises(ValueError, match="N = 1"):
        net(torch.rand(1, 2, 3, 32, 32))
    with pytest.raises(ValueError, match="finite"):
        net(torch.full((1, 1, 3, 32, 32), float("nan")))
    with pytest.raises(ValueError, match="H, W >"):
        net(torch.rand(1, 1, 3, 4, 4))
    with pytest.raises(ValueError, match="unknown keys"):
        config_from_dict({"kind": "single", "widht": 3})
    with pytest.raises(ValueError, match="kind"):
        network_config("compact", "triple")
    with pytest.raises(ValueError, match="preset"):
        network_config("huge")


def test_multi_image_order_invariance_and_any_n() -> None:
    torch.manual_seed(0)
    net = build_network(network_config("compact", "multi", **TINY)).eval()
    photos = torch.rand(2, 4, 3, 32, 32)
    with torch.no_grad():
        out = net(photos)
        perm = net(photos[:, [2, 0, 3, 1]])
        for n in (1, 2, 7):
            assert net(torch.rand(1, n, 3, 32, 32)).shape == (1, 10, 32, 32)
    assert torch.allclose(out, perm, atol=1e-6)
    # and the photos matter: dropping one changes the output
    with torch.no_grad():
        assert (net(photos[:, :3]) - out).abs().max() > 1e-4


def _two_tone(b: int, size: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Images whose left and right parts have random colours; target: the image's mean colour."""
    a, c = torch.rand(b, 3, 1, 1, generator=gen), torch.rand(b, 3, 1, 1, generator=gen)
    split = torch.randint(size // 4, 3 * size // 4, (b, 1, 1, 1), generator=gen)
    cols = torch.arange(size).view(1, 1, 1, size)
    img = torch.where(cols < split, a, c).expand(b, 3, size, size)
    img = (img * (0.8 + 0.4 * torch.rand(b, 1, size, size, generator=gen))).clamp(0, 1)
    return img, img.mean(dim=(2, 3))


def _fit_average_colour(global_track: bool, steps: int = 300, size: int = 16) -> float:
    torch.manual_seed(0)
    net = build_network(network_config("compact", "single", encoder_features=(8, 16, 16), last_features=8,
                                       global_track=global_track, dropout=0.0))
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    gen = torch.Generator().manual_seed(1)
    for _ in range(steps):
        img, mean = _two_tone(8, size, gen)
        out = net.raw(img)[:, 2:5]  # the diffuse channels
        loss = F.mse_loss(out, mean[:, :, None, None].expand_as(out))
        opt.zero_grad()
        loss.backward()
        opt.step()
    img, mean = _two_tone(32, size, torch.Generator().manual_seed(99))
    net.eval()
    with torch.no_grad():
        out = net.raw(img)[:, 2:5]
    return float((out - mean[:, :, None, None]).pow(2).mean().sqrt())


def test_global_track_learns_the_average_colour() -> None:
    """Thesis ch. 3.1.2: instance norm hides each channel's mean from a plain U-Net; the global
    track carries it. Same net, same steps: with the track the mean colour is learned."""
    with_track = _fit_average_colour(True)
    plain = _fit_average_colour(False)
    assert with_track < 0.1, with_track
    assert plain > 1.5 * with_track, (plain, with_track)


def test_overfits_one_sample() -> None:
    from mi_svbrdf.data.simulator import CaptureSimulator, SimulatorConfig

    torch.manual_seed(0)
    batch = CaptureSimulator(SimulatorConfig(size=32, batch_size=1, preset="single_flash", seed=3)).batch(0)
    net = build_network(network_config("compact", "single", **TINY, dropout=0.0))
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    losses = []
    for step in range(120):
        loss = rendering_loss(net(batch.inputs), batch.maps, generator=torch.Generator().manual_seed(step % 4))
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    first, last = sum(losses[:4]) / 4, sum(losses[-4:]) / 4
    assert last < first / 3, (first, last)
