"""Devices: the training loop and inference on an explicit ``device``, and no hard-coded devices.

Only the CPU exists here, so two traps stand in for a GPU:

* **default-device trap** (:func:`hardcoded_device_trap`): the inputs are CPU tensors while
  ``torch.device("meta")`` is the default device, so any tensor a function creates without
  ``device=`` (``torch.zeros(3)``) lands on "meta" and PyTorch raises as soon as it meets an input
  ("Tensor on device meta is not on the expected device cpu"); an output on "meta" fails too.
  On a GPU the same line would put a CPU tensor into a CUDA computation.
* **meta inputs**: the network and the torch renderer on "meta" tensors catch a hard-coded
  ``device="cpu"`` (a CPU tensor meeting a meta input raises).

The CUDA paths themselves (autocast fp16 + GradScaler, NCCL, ``cuda_ad_rgb``) run in ``tests/test_cuda.py``
where a CUDA device exists.
"""
from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch

from mi_svbrdf.cli import capture as capture_cli
from mi_svbrdf.cli import train as train_cli
from mi_svbrdf.cli.common import standalone
from mi_svbrdf.core import brdf_torch, render_drjit
from mi_svbrdf.core.configurations import sample_configurations
from mi_svbrdf.core.device import made_on
from mi_svbrdf.core.loss import MixedLoss, RenderingLoss, map_l1, mixed_loss, rendering_loss
from mi_svbrdf.core.maps import constant_maps
from mi_svbrdf.core.render import render, texel_positions
from mi_svbrdf.nets import inference as P
from mi_svbrdf.nets import train as T
from mi_svbrdf.nets.network import build_network, network_config
from mi_svbrdf.variant import variant_context
from tests.conftest import export_tiny_net

TINY_NET = {"encoder_features": [8, 16, 16], "last_features": 8, "resolution": 32}
CPU = torch.device("cpu")


def _cfg(tmp: Path, **kw: object) -> T.TrainConfig:
    base = {"name": "run", "out": str(tmp), "net": TINY_NET, "batch_size": 2, "sizes": [[0, 32]], "steps": 3,
            "warmup": 1, "validate_every": 0, "log_every": 1, "checkpoint_every_s": 1e9, "bf16": False,
            "simulator": {"preset": "single_flash", "pool_size": 4}}
    return T.TrainConfig.from_dict({**base, **kw})


@contextlib.contextmanager
def hardcoded_device_trap() -> Iterator[None]:
    """Make "meta" the default device: a tensor created without ``device=`` is not on the inputs' device."""
    with torch.device("meta"):
        yield


def _on_cpu(*tensors: torch.Tensor) -> None:
    for t in tensors:
        assert t.device == CPU, f"expected an output on the inputs' device cpu, got {t.device}"


def _maps(batch: int = 2, size: int = 16, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    maps = constant_maps(batch, size, size, roughness=0.4)
    return (maps + 0.05 * torch.rand(maps.shape, generator=g)).clamp(0.01, 1.0)


# --- the training loop on an explicit device --------------------------------------------------

def test_training_loop_end_to_end_on_explicit_device(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, device="cpu", bf16=True, validate_every=3, val_materials=2, val_size=32)
    run = T.train(cfg, progress=False)
    state = torch.load(run / "checkpoint.pt", map_location="meta", weights_only=False)  # tensors are not read
    assert state["step"] == 3 and state["config"]["device"] == "cpu"
    state = T.load_state(run / "checkpoint.pt")
    assert all(v.device == CPU for v in state["model"].values())
    losses = [r["loss"] for r in state["log"] if "loss" in r]
    assert len(losses) == 3 and all(torch.isfinite(torch.tensor(losses)))
    assert any("val_render" in r or any(k.startswith("val_") for k in r) for r in state["log"])
    # resumed on the device given explicitly: the checkpoint maps onto it (map_location)
    resumed = T.train(_cfg(tmp_path, device="cpu", bf16=True, steps=4), resume=True, progress=False)
    assert T.load_state(resumed / "checkpoint.pt")["step"] == 4


def test_train_step_moves_the_batch_and_follows_the_device(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, device="cpu")
    net, opt, step, _, _ = T._start(cfg, None, CPU, T.grad_scaler(cfg, CPU))
    assert step == 0 and all(p.device == CPU for p in net.parameters())
    assert not T.grad_scaler(cfg, CPU).is_enabled()  # a GradScaler only for fp16 on CUDA
    batch = T.make_simulator(cfg, 32).batch(0)
    loss, n = T._train_step(cfg, net, net, opt, batch, 0, 0, tmp_path / "c.pt", CPU)
    assert n == 1 and loss > 0


def test_device_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError, match="device: expected cpu, cuda or cuda:N, got 'tpu'"):
        _cfg(tmp_path, device="tpu")
    with pytest.raises(ValueError, match="cuda_amp: expected 'bf16' or 'fp16'"):
        _cfg(tmp_path, cuda_amp="fp32")
    assert {"full-single", "full-multi"} <= set(T.RECIPES)
    single, multi = T.load_config("full-single"), T.load_config("full-multi")
    assert (single.batch_size, single.lr, single.steps, single.preset) == (8, 2e-5, 400_000, "full")
    assert (multi.batch_size, multi.lr, multi.steps, multi.betas[0]) == (2, 2e-4, 1_000_000, 0.5)
    assert T.load_config("full-single", {"device": "cuda:1"}).device == "cuda:1"
    if torch.cuda.is_available():
        return
    with pytest.raises(ValueError, match="device: expected cpu"):
        T.train(_cfg(tmp_path, device="cuda"), progress=False)
    for module, argv in ((train_cli, ["train", "single", "--device", "cuda"]),
                         (capture_cli, ["capture", "example", "--device", "cuda:0", "-o", str(tmp_path / "o")])):
        code = standalone(module.add_parser, argv)
        text = capsys.readouterr()
        assert code != 0 and "device: expected cpu" in text.out + text.err


# --- Dr.Jit: the tensors' device chooses the backend ---------------------------------------------

def test_drjit_backend_follows_the_tensors_not_the_variant() -> None:
    """CPU tensors run on Dr.Jit's LLVM backend whatever variant is active (tests/test_variants.py has more)."""
    maps = _maps()
    cfg = sample_configurations(2, generator=torch.Generator().manual_seed(0))
    assert render_drjit.check_device(maps=maps, cfg=cfg.light) == CPU
    with pytest.raises(ValueError, match="cfg: expected a tensor on maps's device cpu, got meta"):
        render_drjit.check_device(maps=maps, cfg=torch.zeros(3, device="meta"))
    with variant_context("scalar_rgb"):  # as another device's variant (cuda_ad_rgb) would be on a GPU machine
        value = rendering_loss(maps, maps * 0.9, configurations=cfg)
        img = render(maps, cfg.light, cfg.view)
    assert torch.equal(value, rendering_loss(maps, maps * 0.9, configurations=cfg))
    assert torch.equal(img, render(maps, cfg.light, cfg.view))
    rendering_loss(maps, maps, configurations=cfg, backend="torch")  # the torch backend needs no variant


# --- no hard-coded devices ----------------------------------------------------------------------

def test_no_hardcoded_devices_in_losses_and_renderers() -> None:
    pred, gt = _maps(seed=1).requires_grad_(), _maps(seed=2)
    gen = torch.Generator().manual_seed(0)
    cfg = sample_configurations(2, generator=gen)
    with hardcoded_device_trap():
        for backend in ("torch", "mitsuba"):
            img = render(pred, cfg.light, cfg.view, intensity=2.0, distance_falloff=True, light_z_division=True,
                         cone_target=torch.zeros(2, 9, 3, device=pred.device), cone_exponent=3.0, backend=backend)
            loss = rendering_loss(pred, gt, generator=torch.Generator().manual_seed(0), backend=backend)
            mixed = mixed_loss(pred, gt, ms_ssim_weight=0.5, generator=torch.Generator().manual_seed(0),
                               backend=backend)
            mods = RenderingLoss(seed=0, backend=backend)(pred, gt) + MixedLoss(seed=0, backend=backend)(pred, gt)
            total = img.mean() + loss + mixed + mods + map_l1(pred, gt)
            total.backward()
            _on_cpu(img, loss, mixed, mods, pred.grad)
            pred.grad = None


def test_no_hardcoded_devices_in_networks_training_and_inference(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, bf16=True)
    nets = {kind: build_network(network_config("compact", kind, **TINY_NET)) for kind in ("single", "multi")}
    photos = torch.rand(2, 3, 3, 32, 32)
    photo = torch.rand(1, 1, 3, 64, 64)
    batch = T.make_simulator(cfg, 32).batch(0)
    net = nets["single"]
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    T._train_step(cfg, net, net, opt, batch, 0, 0, tmp_path / "c.pt", CPU)  # Adam's state exists before the trap
    weights = tmp_path / "weights"
    weights.mkdir()
    export_tiny_net(weights, "single", 64)
    P.predict(photo, weights_dir=weights)  # loads (and caches) the net outside the trap
    val = (batch.maps, batch.inputs[:, :1], None)
    with hardcoded_device_trap():
        for kind, n in (("single", 1), ("multi", 3)):
            out = nets[kind](photos[:, :n])
            out.mean().backward()
            _on_cpu(out, *(p.grad for p in nets[kind].parameters()))
        loss, _ = T._train_step(cfg, net, net, opt, batch, 1, 1, tmp_path / "c.pt", CPU)
        metrics = T.validate(net, cfg, val)
        maps = P.predict(photo, weights_dir=weights, device="cpu")
        _on_cpu(maps, *(p for p in net.parameters()))
    assert loss > 0 and metrics and maps.shape == (1, 10, 64, 64)


def test_network_and_torch_renderer_follow_meta_inputs() -> None:
    """On "meta" inputs a hard-coded CPU tensor would raise; the outputs stay on "meta"."""
    meta = torch.device("meta")
    for kind, n in (("single", 1), ("multi", 3)):
        net = build_network(network_config("compact", kind, **TINY_NET)).to(meta)
        out = net(torch.rand(2, n, 3, 32, 32, device=meta))
        out.sum().backward()
        assert out.device == meta and out.shape == (2, 10, 32, 32)
    maps = constant_maps(2, 8, 8).to(meta).requires_grad_()
    cfg = sample_configurations(2, generator=torch.Generator().manual_seed(0), device=meta)
    positions = texel_positions(8, 8, device=meta)
    img = brdf_torch.render(maps, positions, cfg.light, cfg.view, torch.ones(2, 9, 3, device=meta),
                            torch.zeros(2, 9, 3, device=meta), torch.ones(2, 9, device=meta),
                            distance_falloff=True, light_z_division=True, include_diffuse=True,
                            normalize_normals=True, distribution="ggx")
    img.sum().backward()
    assert img.device == meta and maps.grad.device == meta


def test_made_on_makes_tensors_there_and_draws_from_the_cpu_generator() -> None:
    """Factories land on the target; a CPU generator's draws are made on the CPU (the same numbers and
    the same generator state as without the target) and moved; on the CPU nothing is intercepted."""
    meta = torch.device("meta")
    g, ref = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    mean = torch.zeros(3)
    with made_on("meta") as dev:
        made = [torch.rand(2, 3, generator=g), torch.randn(4, generator=g), torch.randint(9, (5,), generator=g),
                torch.randperm(6, generator=g), torch.normal(mean, 1.0, generator=g),
                torch.zeros(2), torch.tensor([1.0, 2.0]), torch.arange(3)]
    assert dev == meta and all(t.device == meta for t in made)
    expected = [torch.rand(2, 3, generator=ref), torch.randn(4, generator=ref), torch.randint(9, (5,), generator=ref),
                torch.randperm(6, generator=ref), torch.normal(mean, 1.0, generator=ref)]
    assert [t.shape for t in made[:5]] == [t.shape for t in expected]
    assert torch.equal(g.get_state(), ref.get_state())  # the draws consumed the CPU generator alike
    with made_on("cpu") as dev:
        x = torch.rand(2, generator=torch.Generator().manual_seed(0))
    assert dev == CPU and x.device == CPU and torch.equal(x, torch.rand(2, generator=torch.Generator().manual_seed(0)))
