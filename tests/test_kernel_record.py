"""The record behind ``--kernel-tests`` (tests/conftest.py): which tests' processes launch a Dr.Jit kernel or ask
Mitsuba for its variant, and the pass that runs only those (``.ci/run``'s variant pass)."""
from __future__ import annotations

from pathlib import Path

import pytest

from tests import conftest

pytest_plugins = ["pytester"]

INNER_TESTS = '''
import drjit as dr
import mitsuba as mi
import torch


def test_kernel():
    x = dr.llvm.Float([1.0, 2.0]) * 2.0
    dr.eval(x)


def test_reads_and_stops_the_history_itself():
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    x = dr.llvm.Float([1.0, 2.0]) * 3.0
    dr.eval(x)
    assert dr.kernel_history()  # clears it
    dr.set_flag(dr.JitFlag.KernelHistory, False)


def test_variant():
    assert mi.variant()


def test_active_variants_float():
    x = dr.opaque(mi.Float, 2.0) * 2.0  # a kernel under llvm_ad_rgb, a Python float under scalar_rgb
    dr.eval(x)


def test_torch_only():
    assert float(torch.ones(3).sum()) == 3.0
'''


def test_kernel_tests_record_and_select(pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch) -> None:
    """A first run records the kernel and variant tests, not the torch-only one; ``--kernel-tests`` then runs
    only those; without a record it is a usage error; a run under another variant, or without pytest's cache,
    records nothing."""
    monkeypatch.delenv("MI_SVBRDF_TEST_VARIANT", raising=False)
    pytester.makeconftest(Path(conftest.__file__).read_text())
    pytester.makepyfile(test_inner=INNER_TESTS)
    refused = pytester.runpytest_subprocess("--kernel-tests")
    assert refused.ret == pytest.ExitCode.USAGE_ERROR
    refused.stderr.fnmatch_lines(["*--kernel-tests: expected a record of an earlier run*"])

    without_cache = pytester.runpytest_subprocess("-p", "no:cacheprovider")  # records nowhere, and says nothing
    without_cache.assert_outcomes(passed=5)
    assert without_cache.ret == pytest.ExitCode.OK
    pytester.runpytest_subprocess().assert_outcomes(passed=5)
    record = pytester.runpytest_subprocess("--kernel-tests", "-v")
    record.assert_outcomes(passed=4, deselected=1)
    record.stdout.fnmatch_lines(["*test_kernel PASSED*", "*test_reads_and_stops_the_history_itself PASSED*",
                                 "*test_variant PASSED*", "*test_active_variants_float PASSED*"])
    assert "test_torch_only" not in record.stdout.str()

    # under scalar_rgb (where mi.Float launches nothing) the record is kept as the default run made it
    monkeypatch.setenv("MI_SVBRDF_TEST_VARIANT", "scalar_rgb")
    pytester.runpytest_subprocess().assert_outcomes(passed=5)
    pytester.runpytest_subprocess("--kernel-tests").assert_outcomes(passed=4, deselected=1)
