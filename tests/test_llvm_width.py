"""The Dr.Jit LLVM vector width the tests run at (``MI_SVBRDF_TEST_LLVM_WIDTH``, tests/conftest.py): the kernels
mi_svbrdf launches are compiled at the width asked for, and a width not offered is refused before any test runs.
``.ci/run``'s width passes run the first test first at each width."""
from __future__ import annotations

import re
from pathlib import Path

import drjit as dr
import pytest
import torch

import mi_svbrdf as ms
from tests import conftest

pytest_plugins = ["pytester"]


def test_the_loss_kernel_is_compiled_at_the_width_asked_for(maps_factory) -> None:
    """The rendering loss's fused kernel (Dr.Jit's LLVM backend) is compiled ``width`` lanes wide: the width
    ``MI_SVBRDF_TEST_LLVM_WIDTH`` asked for, or Dr.Jit's own for this CPU when unset."""
    width = conftest.TEST_LLVM_WIDTH or conftest.llvm_vector_width()
    pred = maps_factory(1, 16, 16, seed=1)
    gt = maps_factory(1, 16, 16, seed=2)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history_clear()
    ms.rendering_loss(pred, gt, preset="2018", backend="mitsuba", generator=torch.Generator().manual_seed(0))
    irs = [launch["ir"].getvalue() for launch in dr.kernel_history()
           if launch["backend"] == dr.JitBackend.LLVM and launch.get("ir") is not None]
    assert irs, "the loss launched no LLVM kernel"
    widths = {int(w) for ir in irs for w in re.findall(r"<(\d+) x float>", ir)}
    assert widths == {width}, (widths, width)


def test_a_width_not_offered_is_refused(pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch) -> None:
    """A width other than 4, 8 or 16 stops the run before any test, with the widths it takes."""
    pytester.makeconftest(Path(conftest.__file__).read_text(encoding="utf-8"))
    pytester.makepyfile(test_inner="def test_nothing():\n    pass\n")
    monkeypatch.setenv("MI_SVBRDF_TEST_LLVM_WIDTH", "5")
    refused = pytester.runpytest_subprocess()
    assert refused.ret != pytest.ExitCode.OK and "test_nothing" not in refused.stdout.str()
    refused.stderr.fnmatch_lines(["*MI_SVBRDF_TEST_LLVM_WIDTH: expected one of 4, 8, 16, got '5'*"])
