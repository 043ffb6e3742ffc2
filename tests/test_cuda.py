"""What a GPU user runs, on a CUDA device: the same numbers as on the CPU, whatever Mitsuba variant is active.

Every test is marked ``cuda`` and skipped with the reason where no CUDA device exists (``tests/conftest.py``).
``python -m pytest -q -m cuda tests/test_cuda.py`` runs them on a GPU machine.
"""
from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import pytest
import torch

from mi_svbrdf.assets import EXAMPLE_CAPTURE
from mi_svbrdf.cli import capture as capture_cli
from mi_svbrdf.cli.common import standalone
from mi_svbrdf.core.configurations import Configurations, sample_configurations
from mi_svbrdf.core.loss import rendering_loss
from mi_svbrdf.core.render import render
from mi_svbrdf.data.simulator import CaptureSimulator
from mi_svbrdf.io.calibrated_photos import load_capture
from mi_svbrdf.io.material_io import read_material
from mi_svbrdf.nets import train as T
from mi_svbrdf.optim import OptimizeConfig, optimize
from mi_svbrdf.variant import variant_context
from tests.conftest import export_tiny_net, random_maps

pytestmark = pytest.mark.cuda

CUDA = torch.device("cuda")
#: Variants a GPU user may have active: the import's default, the CPU's, and a scalar one.
VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")


@pytest.mark.parametrize("variant", VARIANTS)
def test_loss_on_cuda_equals_cpu_value_and_gradient(variant: str) -> None:
    pred, gt = random_maps(4, 32, 32, seed=1), random_maps(4, 32, 32, seed=2)
    cfg = sample_configurations(4, generator=torch.Generator().manual_seed(0))
    out = {}
    with variant_context(variant):
        for device in ("cpu", "cuda"):
            p = pred.to(device).requires_grad_()
            on = Configurations(cfg.light.to(device), cfg.view.to(device))
            loss = rendering_loss(p, gt.to(device), configurations=on)
            loss.backward()
            assert loss.device.type == device and p.grad.device.type == device
            out[device] = (loss.detach().cpu(), p.grad.cpu())
        assert mi.variant() == variant
    torch.testing.assert_close(out["cuda"][0], out["cpu"][0], rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(out["cuda"][1], out["cpu"][1], rtol=1e-3, atol=1e-6)


@pytest.mark.parametrize("variant", VARIANTS)
def test_texel_renderer_on_cuda_equals_cpu_value_and_gradient(variant: str) -> None:
    maps = random_maps(2, 32, 32, seed=3)
    cfg = sample_configurations(2, generator=torch.Generator().manual_seed(1))
    out = {}
    with variant_context(variant):
        for device in ("cpu", "cuda"):
            m = maps.to(device).requires_grad_()
            img = render(m, cfg.light.to(device), cfg.view.to(device), intensity=2.0, distance_falloff=True,
                         backend="mitsuba")
            (img * torch.linspace(0.5, 1.5, img.numel(), device=device).view_as(img)).sum().backward()
            out[device] = (img.detach().cpu(), m.grad.cpu())
    torch.testing.assert_close(out["cuda"][0], out["cpu"][0], rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(out["cuda"][1], out["cpu"][1], rtol=1e-3, atol=1e-5)


@pytest.mark.parametrize("variant", ("cuda_ad_rgb", "llvm_ad_rgb"))
def test_optimize_on_cuda_equals_the_cpu_fit(variant: str) -> None:
    """The bundled example capture, the same steps on both devices: maps within the fits' float drift."""
    spec, images, valid = load_capture(EXAMPLE_CAPTURE)
    cfg = dict(iterations=150, budget_s=float("inf"), progress=False)
    with variant_context(variant):
        cpu = optimize(spec, images, valid, config=OptimizeConfig(**cfg, device="cpu"))
        gpu = optimize(spec, images, valid, config=OptimizeConfig(**cfg, device="cuda"))
    assert gpu.maps.device.type == "cuda" and gpu.steps == cpu.steps
    rmse = ((gpu.maps.cpu() - cpu.maps) ** 2).mean().sqrt().item()
    assert rmse < 0.02, rmse


def test_capture_on_cuda_equals_cpu(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    weights = tmp_path / "weights"
    weights.mkdir()
    export_tiny_net(weights, "single", 64)
    maps = {}
    for device in ("cpu", "cuda"):
        out = tmp_path / device
        code = standalone(capture_cli.add_parser, ["capture", "example", "-o", str(out), "--weights", str(weights),
                                                   "--frames", "0", "--device", device])
        assert code == 0, capsys.readouterr()
        maps[device] = read_material(out)
    assert (maps["cuda"] - maps["cpu"]).abs().max().item() < 2e-3


@pytest.mark.parametrize("amp", ("bf16", "fp16"))
def test_training_step_on_cuda_with_amp(tmp_path: Path, amp: str) -> None:
    cfg = T.TrainConfig.from_dict({
        "name": "run", "out": str(tmp_path), "net": {"encoder_features": [8, 16, 16], "last_features": 8,
                                                    "resolution": 32},
        "batch_size": 2, "sizes": [[0, 32]], "steps": 3, "warmup": 1, "validate_every": 0, "log_every": 1,
        "checkpoint_every_s": 1e9, "bf16": True, "cuda_amp": amp, "device": "cuda",
        "simulator": {"preset": "single_flash", "pool_size": 4}})
    scaler = T.grad_scaler(cfg, CUDA)
    assert scaler.is_enabled() == (amp == "fp16")
    net, opt, _, _, _ = T._start(cfg, None, CUDA, scaler)
    batch = T.make_simulator(cfg, 32, CUDA).batch(0)
    assert batch.inputs.device.type == batch.maps.device.type == "cuda"  # never left the device
    before = [p.detach().clone() for p in net.parameters()]
    loss, n = T._train_step(cfg, net, net, opt, batch, 0, 0, tmp_path / "c.pt", CUDA, scaler)
    assert n == 1 and loss > 0 and torch.isfinite(torch.tensor(loss))
    assert any(not torch.equal(a, b) for a, b in zip(before, net.parameters()))
    run = T.train(cfg, progress=False)  # the loop end to end, checkpoint included
    assert T.load_state(run / "checkpoint.pt")["step"] == 3


@pytest.mark.parametrize("preset", ("single_flash", "multiview"))
def test_simulator_on_cuda_draws_the_cpu_batches(preset: str) -> None:
    """The same seed gives the same materials, captures and photos on the GPU as on the CPU."""
    cfg = dict(size=32, batch_size=3, preset=preset, pool_size=4, remap_roughness=True, seed=5)
    cpu, gpu = CaptureSimulator(**cfg).batch(2), CaptureSimulator(device="cuda", **cfg).batch(2)
    assert gpu.inputs.device.type == gpu.maps.device.type == gpu.captures.light.device.type == "cuda"
    assert gpu.materials == cpu.materials
    torch.testing.assert_close(gpu.maps.cpu(), cpu.maps, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(gpu.captures.light.cpu(), cpu.captures.light)
    off = (gpu.inputs.cpu() - cpu.inputs).abs()
    assert off.mean().item() < 1e-3 and (off > 0.02).float().mean().item() < 1e-3  # 8-bit steps flip rarely
