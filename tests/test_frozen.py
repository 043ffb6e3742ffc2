"""The Dr.Jit kernels are recorded once and replayed (``dr.freeze``): no per-call tracing, and no wrong replay.

A frozen function replays the kernel launches of its first call for later compatible calls. These tests check that
new batch sizes, resolutions and configuration values replay (record and compile nothing new), and that a call whose
Python values differ (gradients needed or not, other flags, another K) never replays another call's recording: the
values and gradients of every call equal the plain PyTorch reference.
"""
from __future__ import annotations

import drjit as dr
import pytest
import torch

import mi_svbrdf as ms
from mi_svbrdf.core import render_drjit
from mi_svbrdf.core.configurations import sample_configurations
from tests.conftest import random_maps


def _loss(pred: torch.Tensor, target: torch.Tensor, seed: int, backend: str = "mitsuba", **kw: object):
    return ms.rendering_loss(pred, target, generator=torch.Generator().manual_seed(seed), backend=backend, **kw)


@pytest.fixture
def kernel_history():
    """Dr.Jit's kernel history on for the test (restored after); yields a function returning the JIT kernels
    launched since its last call."""
    before = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clears it
    yield lambda: [h for h in dr.kernel_history() if h["type"] == dr.KernelType.JIT]
    dr.set_flag(dr.JitFlag.KernelHistory, before)


def test_new_batch_size_resolution_and_configurations_record_and_compile_nothing(kernel_history) -> None:
    def step(batch: int, size: int, seed: int) -> None:
        m = random_maps(batch, size, size, seed=seed).requires_grad_()
        _loss(m, random_maps(batch, size, size, seed=seed + 1), seed).backward()
        with torch.no_grad():
            _loss(m, random_maps(batch, size, size, seed=seed + 2), seed + 3)

    step(2, 16, 0)  # records (or replays an earlier test's recording)
    recordings = render_drjit.frozen_recordings()
    kernel_history()
    step(3, 24, 10)
    step(1, 8, 20)
    assert render_drjit.frozen_recordings() == recordings, "a new size or new configurations were recorded again"
    assert all(h["cache_hit"] for h in kernel_history()), "a kernel was compiled for a new size or configurations"


@pytest.mark.parametrize("first_needs_grad", [False, True])
def test_a_call_never_replays_a_recording_of_other_python_values(first_needs_grad: bool) -> None:
    """Gradients needed or not, both presets (other eps), another K and another BRDF model, in both orders: every
    value and gradient equals the float64 torch reference."""
    pred, target = random_maps(2, 12, 12, seed=30), random_maps(2, 12, 12, seed=31)
    cases = [dict(preset="2018"), dict(preset="2019"), dict(preset="2018", n_diffuse=1, n_specular=2),
             dict(preset="2019", distribution="beckmann")]
    for case in cases:
        for grad in ((first_needs_grad, not first_needs_grad)):
            m = pred.clone().requires_grad_(grad)
            got = _loss(m, target, 5, **case)
            ref_m = pred.double().requires_grad_(grad)
            ref = _loss(ref_m, target.double(), 5, backend="torch", **case)
            assert float(got.detach()) == pytest.approx(float(ref.detach()), rel=1e-5), case
            if grad:
                got.backward()
                ref.backward()
                torch.testing.assert_close(m.grad, ref_m.grad.float(), rtol=2e-3, atol=2e-6)


def test_renderer_and_its_adjoint_replay_what_a_fresh_recording_computes(monkeypatch: pytest.MonkeyPatch) -> None:
    """The texel renderer, its adjoint and the summed renderer (ambient light), replayed after a recording at
    another size, give bit for bit what a recording of the same call gives."""
    def run(batch: int, size: int, seed: int) -> list[torch.Tensor]:
        maps = random_maps(batch, size, size, seed=seed).requires_grad_()
        cfg = sample_configurations(batch, generator=torch.Generator().manual_seed(seed))
        img = ms.render(maps, cfg.light, cfg.view, intensity=2.0, distance_falloff=True)
        flags = render_drjit.Flags(False, False, False, True, True, "ggx")
        table = render_drjit.pack_configurations(cfg.light, cfg.view, torch.ones(batch, cfg.count, 3), None, None)
        summed = render_drjit.render_sum(maps, table, cfg.count, flags)
        weights = torch.linspace(0.5, 1.5, img.numel()).view_as(img)
        ((img * weights).sum() + summed.sum()).backward()
        return [img.detach(), summed.detach(), maps.grad]

    run(2, 8, 0)
    replayed = [run(1, 12, 1), run(3, 10, 2)]
    for (batch, size, seed), want in zip(((1, 12, 1), (3, 10, 2)), replayed):
        monkeypatch.setattr(render_drjit, "_FROZEN", {})  # the call below records afresh
        for a, b in zip(run(batch, size, seed), want):
            assert torch.equal(a, b)
