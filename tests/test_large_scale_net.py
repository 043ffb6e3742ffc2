"""The by-example large-scale network (thesis ch. 5.1.2) and its training: exemplar pooling, the
no-exemplar baseline, the once-per-photo pyramid, gradients, bad inputs, warm start, resume."""
from __future__ import annotations

import itertools
from pathlib import Path

import pytest
import torch

from mi_svbrdf.core.maps import check_maps
from mi_svbrdf.nets.large_scale import LargeScaleNet, exemplar_input
from mi_svbrdf.nets.network import (
    SVBRDFNet,
    build_network,
    config_from_dict,
    network_config,
    parameter_count,
)
from mi_svbrdf.nets.train import TrainConfig, load_config, train, warm_start

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = {"encoder_features": (8, 16, 16), "last_features": 8, "exemplar_features": (4, 8, 8), "resolution": 32,
        "exemplar_size": 16}


def _net(seed: int = 0, **kw: object) -> LargeScaleNet:
    torch.manual_seed(seed)
    return build_network(network_config("compact", "large", **{**TINY, **kw})).eval()


def _exemplars(batch: int, count: int, size: int = 16, seed: int = 0) -> torch.Tensor:
    from conftest import random_maps

    maps = random_maps(batch * count, size, size, seed=seed, max_tilt=0.6).view(batch, count, 10, size, size)
    return exemplar_input(maps, generator=torch.Generator().manual_seed(seed))


def test_shapes_and_valid_maps_for_any_tile_size() -> None:
    net = _net()
    assert isinstance(net, LargeScaleNet) and net.config.kind == "large"
    for h, w in ((32, 32), (40, 56), (17, 33)):  # padded to a multiple of 2**depth and cropped back
        with torch.no_grad():
            maps = net(torch.rand(2, 3, h, w), _exemplars(2, 2))
        assert maps.shape == (2, 10, h, w)
        check_maps(maps)
        assert torch.allclose(maps[:, :3].norm(dim=1), torch.ones(2, h, w), atol=1e-5)
        assert 0 <= float(maps[:, 3:].min()) and float(maps[:, 3:].max()) <= 1


def test_exemplars_are_max_pooled_in_any_number_and_order() -> None:
    net = _net()
    photo = torch.rand(1, 3, 32, 32)
    ex = _exemplars(1, 4)
    f_all = net.exemplar_features(ex)
    assert [tuple(f.shape) for f in f_all] == [(1, 4, 8, 8), (1, 8, 4, 4), (1, 8, 2, 2)]
    # max over exemplars, level by level: the pyramid of {a, b, c, d} is the max of theirs
    singles = [net.exemplar_features(ex[:, i:i + 1]) for i in range(4)]
    for level, f in enumerate(f_all):
        assert torch.allclose(f, torch.stack([s[level] for s in singles]).amax(dim=0), atol=1e-6)
    ref = net(photo, ex)
    for order in ([3, 1, 0, 2], [2, 3, 1, 0]):
        assert torch.allclose(net(photo, ex[:, order]), ref, atol=1e-5)
    assert torch.allclose(net(photo, ex[:, [0, 0, 1]]), net(photo, ex[:, [0, 1]]), atol=1e-5)  # a repeat adds nothing
    outs = [net(photo, ex[:, :e]) for e in (1, 2, 3, 4)]  # any E; each exemplar changes the result here
    assert all(not torch.allclose(a, b, atol=1e-4) for a, b in itertools.pairwise(outs))


def test_no_exemplar_is_the_zero_feature_baseline() -> None:
    net = _net()
    photo = torch.rand(2, 3, 32, 32)
    base = net(photo)
    assert net.exemplar_features(None) is None and net.exemplar_features(_exemplars(2, 0)) is None
    assert torch.equal(net(photo, _exemplars(2, 0)), base)
    assert not torch.allclose(net(photo, _exemplars(2, 1)), base, atol=1e-4)
    # E = 0 is what zero exemplar features give
    zeros = [torch.zeros(2, c, 16 >> (level + 1), 16 >> (level + 1)) for level, c in enumerate((4, 8, 8))]
    assert torch.allclose(net(photo, features=zeros), base, atol=1e-6)


def test_features_once_per_photo_equal_the_exemplar_path_and_broadcast_over_tiles() -> None:
    # float64: in float32 a batch of 3 and a batch of 1 may take different convolution kernels (1.4e-6 apart on an
    # AMD EPYC), which is not what this test is about
    net = _net().double()
    ex = _exemplars(1, 3).double()
    pyramid = net.exemplar_features(ex)
    tiles = torch.rand(3, 3, 32, 40, dtype=torch.float64)  # three tiles of one photo reuse one pyramid (batch 1)
    out = net(tiles, features=pyramid)
    for i in range(3):
        assert torch.allclose(out[i:i + 1], net(tiles[i:i + 1], ex), atol=1e-6)
    assert torch.allclose(net(tiles[:1], ex[:, :1], features=pyramid), net(tiles[:1], ex), atol=1e-6)  # features win


def test_gradients_reach_the_exemplar_encoder_and_match_finite_differences() -> None:
    net = _net(encoder_features=(4, 4), last_features=4, exemplar_features=(2, 3), exemplar_size=8).double()
    photo = torch.rand(1, 3, 8, 8, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    ex = _exemplars(1, 2, size=8).double()
    index = torch.randperm(ex.numel(), generator=torch.Generator().manual_seed(2))[:10]
    probe = torch.randn(1, 10, 8, 8, dtype=torch.float64, generator=torch.Generator().manual_seed(3))

    def summary(maps: torch.Tensor) -> torch.Tensor:  # 10 random projections of the maps (10 backward passes)
        return (maps * probe).sum(dim=(2, 3)).flatten()

    def through_exemplars(z: torch.Tensor) -> torch.Tensor:  # 10 exemplar values, the rest fixed
        return summary(net(photo, ex.flatten().index_put((index,), z).view_as(ex)))

    assert torch.autograd.gradcheck(through_exemplars, (ex.flatten()[index].clone().requires_grad_(),), atol=1e-6)
    name = "exemplar_encoder.stages.0.conv.weight"
    params = dict(net.named_parameters())
    w = params[name].detach()

    def through_weights(z: torch.Tensor) -> torch.Tensor:  # 4 weights of the encoder's first convolution
        weight = w.flatten().index_put((torch.arange(4),), z).view_as(w)
        return summary(torch.func.functional_call(net, {name: weight}, (photo, ex)))

    assert torch.autograd.gradcheck(through_weights, (w.flatten()[:4].clone().requires_grad_(),), atol=1e-6)
    net.zero_grad()
    net(photo, ex).square().mean().backward()
    grads = {n: p.grad for n, p in net.named_parameters() if n.startswith("exemplar_encoder.")}
    assert grads and all(g is not None and g.abs().sum() > 0 for g in grads.values())


def test_bad_inputs_name_the_argument() -> None:
    net = _net()
    photo = torch.rand(2, 3, 32, 32)
    cases = [
        (lambda: net(photo, _exemplars(2, 2)[:, :, :10]), "exemplars: expected shape"),  # 10 channels, no render
        (lambda: net(photo, _exemplars(2, 2)[0]), "exemplars: expected shape"),
        (lambda: net(photo, _exemplars(3, 2)), "exemplars: expected the photo's batch 2"),
        (lambda: net(photo, _exemplars(2, 1, size=4)), "exemplars: expected h, w >= 8"),
        (lambda: net(photo, torch.full((2, 1, 13, 16, 16), float("nan"))), "exemplars: expected finite"),
        (lambda: net(torch.rand(2, 4, 32, 32)), "photo: expected shape"),
        (lambda: net(torch.rand(2, 1, 3, 32, 32)), "photo: expected shape"),
        (lambda: net(torch.rand(2, 3, 4, 4)), "photo: expected H, W > 4"),
        (lambda: net(photo, features=net.exemplar_features(_exemplars(2, 1))[:2]), "features: expected a list of 3"),
        (lambda: net(photo, features=[f[:, :2] for f in net.exemplar_features(_exemplars(2, 1))]),
         "features: expected channels"),
        (lambda: network_config("compact", "large", **{**TINY, "exemplar_features": (4, 8)}),
         "NetConfig.exemplar_features"),
        (lambda: network_config("full", "large", exemplar_size=128), "NetConfig.exemplar_size: expected an int >= 256"),
        (lambda: SVBRDFNet(network_config("compact", "large", **TINY)), "config.kind: expected 'single' or 'multi'"),
        (lambda: LargeScaleNet(network_config("compact", "single")), "config.kind: expected 'large'"),
    ]
    for call, message in cases:
        with pytest.raises(ValueError, match=message):
            call()


def test_presets_and_config_round_trip() -> None:
    compact = network_config("compact", "large")
    assert (compact.resolution, compact.exemplar_size) == (128, 64)  # the thesis's 512 and 256, divided by 4
    full = network_config("full", "large")
    assert (full.resolution, full.exemplar_size, full.exemplar_widths) == (512, 256, full.encoder_features)
    assert config_from_dict(compact.to_dict()) == compact
    # the other kinds' dicts have no large-only field: checkpoints and manifests written before still compare equal
    assert "exemplar_size" not in network_config("compact", "single").to_dict()
    # the compact net's trunk is the single-image net's (a warm start copies it) and it stays near its size: the
    # bundled fp16 weights are ~1.84 bytes per parameter (18.3 MB for 9.96 M), so < 10.6 M keeps it < 19.5 MB
    with torch.device("meta"):
        single = parameter_count(build_network(network_config("compact", "single")))
        large = parameter_count(build_network(compact))
        assert parameter_count(build_network(full)) > 80e6
    assert single < large < 10.6e6


def test_warm_start_from_the_single_image_net_makes_it_that_net(tmp_path: Path) -> None:
    """The single-image trunk and head are copied, the exemplar columns of the decoder start at zero:
    whatever the exemplars, the warm-started net gives the single-image net's maps."""
    torch.manual_seed(3)
    single = build_network(network_config("compact", "single", encoder_features=(8, 16, 16), last_features=8,
                                          resolution=32)).eval()
    torch.save({"model": single.state_dict(), "net_config": single.config.to_dict()}, tmp_path / "single.pt")
    large = _net(seed=4)
    copied = warm_start(large, tmp_path / "single.pt")
    assert copied == len(single.state_dict())  # every tensor of the single-image net (trunk and head)
    photo = torch.rand(2, 3, 32, 32)
    for ex in (None, _exemplars(2, 3)):
        assert torch.allclose(large(photo, ex), single(photo[:, None]), atol=1e-5)
    first = large.trunk.decoder[0][0].conv.weight  # bottleneck level: [upsampled | skip | exemplar columns]
    assert not first[:, 32:].any() and torch.equal(first[:, :32], single.trunk.decoder[0][0].conv.weight)


def test_warm_start_from_the_bundled_single_image_net() -> None:
    from mi_svbrdf.nets import weights as pretrained

    if "single" not in pretrained.available():
        pytest.skip("no bundled single-image net in this checkout")
    single = pretrained.load_network("single")
    large = build_network(network_config("compact", "large")).eval()
    assert warm_start(large, "bundled:single") == len(single.state_dict())
    photo = torch.rand(1, 3, 128, 128, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        assert torch.allclose(large(photo, _exemplars(1, 2, size=64)), single(photo[:, None]), atol=1e-5)


def _cfg(tmp: Path, **kw: object) -> TrainConfig:
    base = {"name": "run", "out": str(tmp), "kind": "large", "net": {k: list(v) if isinstance(v, tuple) else v
                                                                      for k, v in TINY.items()},
            "simulator": {"material_size": 80, "crop": [32, 64], "n_lights": 4, "pool_size": 3},
            "batch_size": 2, "sizes": [[0, 32]], "steps": 4, "warmup": 2, "validate_every": 0, "log_every": 1,
            "checkpoint_every_s": 1e9, "bf16": False}
    return TrainConfig.from_dict({**base, **kw})


def test_training_runs_validates_and_resumes_exactly(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MI_SVBRDF_CACHE", str(tmp_path / "cache"))
    straight = train(_cfg(tmp_path / "a", validate_every=4, val_materials=2, val_size=32), progress=False)
    train(_cfg(tmp_path / "b", steps=2), progress=False)  # interrupted after 2 steps, then resumed
    resumed = train(_cfg(tmp_path / "b"), resume=True, progress=False)
    a = torch.load(straight / "checkpoint.pt", weights_only=False)
    b = torch.load(resumed / "checkpoint.pt", weights_only=False)
    assert a["step"] == b["step"] == 4 and a["net_config"]["kind"] == "large"
    for k in a["model"]:
        assert torch.equal(a["model"][k], b["model"][k]), k
    losses = [r["loss"] for r in a["log"] if "loss" in r]
    assert losses == pytest.approx([r["loss"] for r in b["log"]], rel=1e-6)
    assert all(0 <= r["n_exemplars"] <= 3 for r in a["log"] if "loss" in r)
    val = [r for r in a["log"] if "val_rmse_render" in r]
    assert len(val) == 1 and 0 < val[0]["val_rmse_render"] < 1
    with pytest.raises(ValueError, match="trained with"):  # another architecture refuses to resume
        train(_cfg(tmp_path / "b", net={**_cfg(tmp_path).net, "exemplar_features": [4, 8, 4]}), resume=True,
              progress=False)


def test_bundled_weights_load_as_the_large_scale_net(tmp_path: Path) -> None:
    from mi_svbrdf.nets.weights import export_weights, load_network

    net = _net(seed=5)
    torch.save({"net_config": net.config.to_dict(), "model": net.state_dict(), "config": {"preset": "compact"},
                "step": 1, "seconds": 1.0}, tmp_path / "ckpt.pt")
    entry = export_weights(tmp_path / "ckpt.pt", folder=tmp_path / "w")
    assert entry["file"] == "large_compact.pt.zz"
    loaded = load_network("large", folder=tmp_path / "w")
    assert isinstance(loaded, LargeScaleNet) and loaded.config == net.config
    photo, ex = torch.rand(1, 3, 32, 32), _exemplars(1, 2)
    assert torch.allclose(loaded(photo, ex), net(photo, ex), atol=2e-2)  # fp16 weights
    # the tiny nets of other tests (any encoder) get exemplar widths without asking
    assert network_config("compact", "large", encoder_features=(8, 16, 16, 16)).exemplar_widths == (8, 16, 16, 16)


def test_doctests() -> None:
    import doctest

    from mi_svbrdf.nets import large_scale

    assert doctest.testmod(large_scale).failed == 0


def test_large_recipes() -> None:
    cfg = load_config("large")
    assert cfg.kind == "large" and cfg.preset == "compact" and cfg.init == "bundled:single"
    assert cfg.net_config.resolution == cfg.size_at(0) == 128 and cfg.net_config.exemplar_size == 64
    full = load_config("full-large")
    assert full.net_config.resolution == full.size_at(0) == 512 and full.simulator["material_size"] == 2048
    with pytest.raises(ValueError, match="TrainConfig.kind"):
        TrainConfig.from_dict({"kind": "huge"})


def test_one_pixel_exemplar_levels_run_in_float32_under_bf16_autocast() -> None:
    # exemplars of 8 px through 4 levels: 4, 2, 1, 1; the stages over a 1x1 input must leave autocast
    # (a bf16 strided convolution's weight gradient over a 1x1 input came back NaN now and then)
    net = _net(encoder_features=(8, 16, 16, 16), exemplar_features=(4, 8, 8, 8), exemplar_size=8).train()
    ex = _exemplars(2, 2, size=8)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        levels = net.exemplar_encoder(ex.flatten(0, 1))
    assert [tuple(f.shape[-2:]) for f in levels] == [(4, 4), (2, 2), (1, 1), (1, 1)]
    assert levels[-1].dtype == torch.float32 and levels[1].dtype == torch.bfloat16
    with torch.autocast("cpu", dtype=torch.bfloat16):
        net(torch.rand(2, 3, 32, 32), ex).float().sum().backward()
    assert all(torch.isfinite(p.grad).all() for p in net.exemplar_encoder.parameters() if p.grad is not None)
