"""The fused multi-image net (mi_svbrdf.nets.fusion): exact at initialisation, trained head only, bundled by
reference to the single net; the flash photo's choice (mi_svbrdf.core.highlight) and the path capture reports."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mi_svbrdf.core.flash import FlashSetup, render_flash
from mi_svbrdf.core.highlight import choose_flash_photo, highlight_positions
from mi_svbrdf.core.maps import constant_maps
from mi_svbrdf.nets import weights as pretrained
from mi_svbrdf.nets.fusion import FusionHead, from_fusion_space, to_fusion_space
from mi_svbrdf.nets.network import build_network, network_config
from mi_svbrdf.nets.train import TrainConfig, freeze, make_simulator, train

pytestmark = pytest.mark.usefixtures("one_torch_thread")

TINY = {"encoder_features": (8, 16, 16), "last_features": 8, "resolution": 32}


def _fused(seed: int = 0):
    torch.manual_seed(seed)
    return build_network(network_config("compact", "multi", fusion=True, **TINY)).eval()


def _random_maps(b: int = 2, size: int = 16) -> torch.Tensor:
    g = torch.Generator().manual_seed(3)
    n = torch.randn(b, 3, size, size, generator=g) * 0.4
    n[:, 2] = n[:, 2].abs() + 0.2  # the upper hemisphere, as every net's normals
    n = torch.nn.functional.normalize(n, dim=1)
    return torch.cat([n, torch.rand(b, 7, size, size, generator=g) * 0.98 + 0.01], dim=1)


def test_fusion_space_round_trips_maps() -> None:
    maps = _random_maps()
    assert torch.allclose(from_fusion_space(to_fusion_space(maps)), maps, atol=1e-5)


def test_untrained_fused_net_is_the_single_net_exactly() -> None:
    net = _fused()
    photos = torch.rand(2, 3, 3, 40, 40)  # not a multiple of the depth: padded and cropped back
    with torch.no_grad():
        fused, single = net(photos), net.single(photos[:, :1])
    assert torch.allclose(fused, single, atol=1e-5)


def test_gate_one_gives_the_multi_net_and_gradients_reach_the_head_only() -> None:
    net = _fused()
    photos = torch.rand(1, 2, 3, 32, 32)
    with torch.no_grad():  # gate 1, residual 0: the multi-image branch's own maps
        net.fusion.out.bias[:9] = 1.0
        expected = net.decode(net.raw(photos))
        assert torch.allclose(net(photos), expected, atol=1e-4)
        fused, branch = net.fused_and_branch(photos)  # one pass of each net gives both
        assert torch.equal(branch, expected) and torch.equal(fused, net(photos))
    frozen = freeze(net, ["trunk.", "fuse.", "head."])
    assert frozen > 0 and not net.trunk.training
    net.train()
    assert not net.trunk.training and not net.single.training and net.fusion.training  # frozen parts: no dropout
    net(photos).square().mean().backward()
    grads = {name for name, p in net.named_parameters() if p.grad is not None}
    assert grads and all(name.startswith("fusion.") for name in grads)
    with pytest.raises(ValueError, match="freeze: expected prefixes"):
        freeze(net, ["nothing."])


def test_fusion_head_gradients_match_finite_differences() -> None:
    torch.manual_seed(0)
    head = FusionHead(3, 4, hidden=4).double()
    torch.nn.init.normal_(head.out.weight, std=0.1)
    args = [torch.randn(1, c, 6, 6, dtype=torch.float64, requires_grad=True) for c in (3, 4, 9, 9)]
    assert torch.autograd.gradcheck(head, args)


def test_fused_weights_bundle_without_the_single_branch_and_load_back(tmp_path: Path) -> None:
    single_cfg = network_config("compact", "single", **TINY)
    torch.manual_seed(1)
    single = build_network(single_cfg)
    torch.save({"net_config": single_cfg.to_dict(), "model": single.state_dict(), "config": {"preset": "compact"},
                "step": 0, "seconds": 0.0}, tmp_path / "s.pt")
    pretrained.export_weights(tmp_path / "s.pt", folder=tmp_path)
    bundled_single = pretrained.load_network("single", folder=tmp_path)
    net = _fused()
    net.single.load_state_dict(bundled_single.state_dict())
    with torch.no_grad():
        torch.nn.init.normal_(net.fusion.out.weight, std=0.05)  # a trained head: not the single net any more
    torch.save({"net_config": net.config.to_dict(), "model": net.state_dict(), "config": {"preset": "compact"},
                "step": 0, "seconds": 0.0}, tmp_path / "m.pt")
    entry = pretrained.export_weights(tmp_path / "m.pt", folder=tmp_path)
    assert entry["base"] == {"kind": "single", "sha256": pretrained.manifest_entry("single", tmp_path)["sha256"]}
    stored = pretrained.read_weights(tmp_path / entry["file"])
    assert stored and not any(k.startswith("single.") for k in stored)
    loaded = pretrained.load_network("multi", folder=tmp_path)
    photos = torch.rand(1, 2, 3, 32, 32)
    with torch.no_grad():
        assert torch.allclose(loaded(photos), net.half().float()(photos), atol=1e-4)
    # a replaced single net is not the fused net's branch: refused, naming the checksum
    manifest = pretrained.read_manifest(tmp_path)
    manifest["single"]["sha256"] = "0" * 64
    (tmp_path / "manifest.json").write_text(__import__("json").dumps(manifest))
    with pytest.raises(ValueError, match="expected the bundled single net with sha256"):
        pretrained.load_network("multi", folder=tmp_path)


def test_a_fused_branch_that_is_not_the_bundled_single_net_is_not_bundled(tmp_path: Path) -> None:
    export_single = network_config("compact", "single", **TINY)
    torch.save({"net_config": export_single.to_dict(), "model": build_network(export_single).state_dict(),
                "config": {"preset": "compact"}, "step": 0, "seconds": 0.0}, tmp_path / "s.pt")
    pretrained.export_weights(tmp_path / "s.pt", folder=tmp_path)
    net = _fused(seed=5)  # its own random single branch
    torch.save({"net_config": net.config.to_dict(), "model": net.state_dict(), "config": {"preset": "compact"},
                "step": 0, "seconds": 0.0}, tmp_path / "m.pt")
    with pytest.raises(ValueError, match="differs from the bundled single net"):
        pretrained.export_weights(tmp_path / "m.pt", folder=tmp_path)


def test_fusion_is_only_for_the_multi_image_net() -> None:
    with pytest.raises(ValueError, match="fusion"):
        network_config("compact", "single", fusion=True, **TINY)
    assert "fusion" not in network_config("compact", "multi", **TINY).to_dict()  # older manifests still compare equal


def test_training_alternates_capture_settings_and_trains_the_head_only(tmp_path: Path) -> None:
    cfg = TrainConfig.from_dict({
        "name": "fused", "out": str(tmp_path), "kind": "multi", "net": {**TINY, "fusion": True}, "batch_size": 1,
        "sizes": [[0, 32]], "steps": 2, "warmup": 1, "validate_every": 0, "log_every": 1, "bf16": False,
        "checkpoint_every_s": 1e9, "simulator": {"preset": "multiview", "n_images": [2, 2], "pool_size": 2},
        "alternate": [{}, {"flash_at_camera": True}], "freeze": ["trunk.", "fuse.", "head."]})
    stream = make_simulator(cfg, 32)
    plain = make_simulator(TrainConfig.from_dict({**cfg.__dict__, "alternate": []}), 32)
    phone = make_simulator(TrainConfig.from_dict({**cfg.__dict__, "alternate": [],
                                                  "simulator": {**cfg.simulator,
                                                                "capture": {"flash_at_camera": True}}}), 32)
    assert torch.equal(stream.batch(0).inputs, plain.batch(0).inputs)
    assert torch.equal(stream.batch(1).inputs, phone.batch(1).inputs)
    assert not torch.equal(stream.batch(1).inputs, plain.batch(1).inputs)
    run = train(cfg, progress=False)
    state = torch.load(run / "checkpoint.pt", weights_only=False)
    fresh = _fused()
    changed = {k for k, v in state["model"].items() if not torch.equal(v, fresh.state_dict()[k])}
    assert changed and all(k.startswith("fusion.") for k in changed)
    with pytest.raises(ValueError, match="base"):
        TrainConfig.from_dict({"kind": "multi", "base": "bundled:single"})


def _flash_photo(light: tuple[float, float, float]) -> torch.Tensor:
    maps = constant_maps(1, 64, 64)
    return render_flash(maps, FlashSetup(light=light, camera=(0.0, 0.0, 2.75), cone_target=(0.0, 0.0, 0.0)))[0]


def test_the_flash_photo_is_found_by_where_its_light_peaks() -> None:
    flash = _flash_photo((0.1, -0.1, 2.197))
    side = _flash_photo((3.0, 0.5, 1.0))  # lit from the side: its light peaks outside the frame
    (fx, fy), = highlight_positions(flash[None])  # type: ignore[misc]
    assert abs(fx - 0.1) < 0.25 and abs(fy + 0.1) < 0.25
    choice = choose_flash_photo(torch.stack([side, side, flash]))
    assert choice.index == 2 and "put first" in choice.why and not choice.assumed
    kept = choose_flash_photo(torch.stack([flash, _flash_photo((0.0, 0.2, 2.197))]))
    assert kept.index == 0  # the user's order is trusted when photo 1 peaks in the frame
    assumed = choose_flash_photo(torch.stack([side, side]))
    assert assumed.index == 0 and assumed.assumed and "assumed" in assumed.why
    with pytest.raises(ValueError, match="expected shape"):
        highlight_positions(flash)


def test_predict_puts_the_flash_photo_first_and_says_which(tmp_path: Path) -> None:
    from conftest import export_tiny_net

    from mi_svbrdf.nets.inference import predict_details

    export_tiny_net(tmp_path, "multi", 64)
    flash = _flash_photo((0.1, 0.0, 2.197))
    side = _flash_photo((3.0, 0.0, 1.0))
    photos = torch.stack([side, flash])
    result = predict_details(photos, weights_dir=tmp_path, symmetries=1)
    assert result.path["flash_photo"]["index"] == 1 and torch.equal(result.photos[0, 0], flash)
    assert result.path["net"] == "multi" and "multi-image net" in result.path["why"]
    asked = predict_details(photos, weights_dir=tmp_path, symmetries=1, flash_photo=0)
    assert asked.path["flash_photo"]["index"] == 0 and "as asked" in asked.path["flash_photo"]["why"]
    with pytest.raises(ValueError, match="flash_photo: expected None or a photo index"):
        predict_details(photos, weights_dir=tmp_path, symmetries=1, flash_photo=2)


def test_net_candidates_are_the_single_branch_the_multi_branch_and_the_fused_net() -> None:
    from mi_svbrdf.nets.ensemble import symmetry_ensemble
    from mi_svbrdf.nets.fusion import NET_CANDIDATES, net_candidates

    net = _fused()
    with torch.no_grad():
        torch.nn.init.normal_(net.fusion.out.weight, std=0.05)  # a trained head: fused differs from both branches
    photos = torch.rand(1, 3, 3, 32, 32)
    one = net_candidates(net, photos, 1)
    assert tuple(one) == NET_CANDIDATES
    with torch.no_grad():
        fused, multi = net.fused_and_branch(photos)
        single = net.single(photos[:, :1])
        ensemble = symmetry_ensemble(net, photos, 2)
    assert torch.allclose(one["fused"], fused, atol=1e-6) and torch.allclose(one["multi"], multi, atol=1e-6)
    assert torch.allclose(one["single"], single, atol=1e-6)
    assert (one["fused"] - one["single"]).abs().max() > 1e-4
    two = net_candidates(net, photos, 2)
    assert torch.allclose(two["fused"], ensemble, atol=1e-5)
    with pytest.raises(ValueError, match="expected a fused multi-image net"):
        net_candidates(build_network(network_config("compact", "multi", **TINY)), photos)
    with pytest.raises(ValueError, match="symmetries: expected an int in"):
        net_candidates(net, photos, 9)
