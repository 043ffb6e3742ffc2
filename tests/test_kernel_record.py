"""The record behind ``--kernel-tests`` (tests/conftest.py): which tests' processes launch a Dr.Jit kernel or ask
Mitsuba for its variant, and the pass that runs only those (``.ci/run``'s variant pass)."""
from __future__ import annotations

from pathlib import Path

import pytest

from tests import conftest

pytest_plugins = ["pytester"]

INNER_TESTS = '''
import time

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


def test_the_same_kernel_slower():
    time.sleep(0.3)
    x = dr.llvm.Float([1.0, 2.0]) * 2.0  # test_kernel's kernel: the cover runs the faster of the two
    dr.eval(x)


def test_torch_only():
    assert float(torch.ones(3).sum()) == 3.0


def test_a_long_run_is_read_while_it_runs(request):
    x = dr.llvm.Float([1.0, 2.0]) * 7.0 + 1.0  # a kernel of its own
    dr.eval(x)
    recorder = request.config.pluginmanager.get_plugin("mi_svbrdf_kernel_recorder")
    deadline = time.perf_counter() + 10.0
    while not recorder.features and time.perf_counter() < deadline:  # a fit's steps
        y = dr.llvm.Float([1.0, 2.0]) * 2.0
        dr.eval(y)
        time.sleep(0.02)
    assert recorder.features, "the history was not read while the test ran: it piles up"
'''


def test_kernel_tests_record_and_select(pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch) -> None:
    """A first run records the kernel and variant tests, not the torch-only one (a long one's history read while it
    runs); ``--kernel-tests`` then runs only those, and of two tests that launch the same kernel the faster; without a record it is a usage error; a run under another variant, or without pytest's cache,
    records nothing; nor does one at another LLVM vector width (its kernels have other hashes)."""
    monkeypatch.delenv("MI_SVBRDF_TEST_VARIANT", raising=False)
    monkeypatch.delenv("MI_SVBRDF_TEST_LLVM_WIDTH", raising=False)  # the width passes of .ci/run set it
    pytester.makeconftest(Path(conftest.__file__).read_text())
    pytester.makepyfile(test_inner=INNER_TESTS)
    refused = pytester.runpytest_subprocess("--kernel-tests")
    assert refused.ret == pytest.ExitCode.USAGE_ERROR
    refused.stderr.fnmatch_lines(["*--kernel-tests: expected a record of an earlier run*"])

    without_cache = pytester.runpytest_subprocess("-p", "no:cacheprovider")  # records nowhere, and says nothing
    without_cache.assert_outcomes(passed=7)
    assert without_cache.ret == pytest.ExitCode.OK
    pytester.runpytest_subprocess().assert_outcomes(passed=7)
    record = pytester.runpytest_subprocess("--kernel-tests", "-v")
    record.assert_outcomes(passed=5, deselected=2)
    record.stdout.fnmatch_lines(["*test_kernel PASSED*", "*test_reads_and_stops_the_history_itself PASSED*",
                                 "*test_variant PASSED*", "*test_active_variants_float PASSED*",
                                 "*test_a_long_run_is_read_while_it_runs PASSED*"])
    assert "test_torch_only" not in record.stdout.str() and "slower" not in record.stdout.str()

    # at a width asked for the record is kept as the default run made it (a run that records rewrites its seconds)
    cache = pytester.path / ".pytest_cache" / "v" / "mi_svbrdf" / "kernel_tests"
    made = cache.read_text()
    monkeypatch.setenv("MI_SVBRDF_TEST_LLVM_WIDTH", "4")
    pytester.runpytest_subprocess().assert_outcomes(passed=7)
    assert cache.read_text() == made
    monkeypatch.delenv("MI_SVBRDF_TEST_LLVM_WIDTH")

    # under scalar_rgb (where mi.Float launches nothing) the record is kept as the default run made it
    monkeypatch.setenv("MI_SVBRDF_TEST_VARIANT", "scalar_rgb")
    pytester.runpytest_subprocess().assert_outcomes(passed=7)
    pytester.runpytest_subprocess("--kernel-tests").assert_outcomes(passed=5, deselected=2)


def test_the_cover_takes_every_feature_at_the_fewest_seconds() -> None:
    """Every feature is covered; a test whose features others cover more cheaply is left out; a test recorded in
    the former form runs when it launched a kernel."""
    record = {"a": {"features": ["k1", "k2"], "seconds": 1.0}, "b": {"features": ["k1"], "seconds": 0.1},
              "c": {"features": ["k2"], "seconds": 0.1}, "d": {"features": ["k1", "k2", "v"], "seconds": 5.0},
              "e": {"features": ["v"], "seconds": 0.5}, "f": True, "g": False}
    assert conftest.kernel_cover(record) == {"b", "c", "e", "f"}
    assert conftest.kernel_cover({}) == set()
