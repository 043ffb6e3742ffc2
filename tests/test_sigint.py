"""Ctrl-C at any instant of a command: exit code 130, one line, no traceback, nothing half-written, never exit 0.

The windows where a library takes the interrupt (:mod:`mi_svbrdf.cli.interrupt`): Dr.Jit loses it in a torch
tensor's conversion and turns it into a ``RuntimeError`` in a kernel recording; the command's handler raises a
lost one again and :func:`mi_svbrdf.cli.common.run` answers an error around one as the interrupt. The tests here
check each mechanism in a small process, then send SIGINT at seeded instants to real runs of ``optimize``,
``capture example:multi`` and ``scan example`` (``benchmarks/bench_sigint.py``: a few instants of short runs in the
fast suite, its whole sweep as a slow test).
"""
from __future__ import annotations

import doctest
import importlib.util
import signal
import subprocess
import sys
import textwrap
from pathlib import Path
from types import ModuleType

import pytest
import torch

from mi_svbrdf.cli import interrupt
from mi_svbrdf.core.device import to_jit

ROOT = Path(__file__).resolve().parent.parent


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_sigint", ROOT / "benchmarks" / "bench_sigint.py")
    module = sys.modules[spec.name] = importlib.util.module_from_spec(spec)  # its dataclasses look it up there
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


BENCH = _bench()

#: A command ``work`` whose function the test defines, in a script named ``mi-svbrdf``: the process starts as the
#: console script's does (:func:`mi_svbrdf.started_as_command`: Ctrl-C guarded from the first import, torch and
#: Mitsuba not imported); exits with :func:`mi_svbrdf.cli.common.run`'s code.
COMMAND = """\
import argparse, os, signal, sys, time
from mi_svbrdf.cli import common
{work}
parser = argparse.ArgumentParser(prog="mi-svbrdf")
parser.add_subparsers(dest="command").add_parser("work").set_defaults(func=work)
sys.exit(common.run(parser, ["work"]))
"""
#: The line of a command without an output folder stopped by Ctrl-C.
LINE = "mi-svbrdf work: interrupted; completed files are whole (each is written atomically)\n"


def _command(work: str, folder: Path, timeout: float = 60.0) -> subprocess.CompletedProcess:
    script = folder / "mi-svbrdf"
    script.write_text(COMMAND.format(work=textwrap.dedent(work)))
    return subprocess.run([sys.executable, str(script)], cwd=folder, capture_output=True, text=True, timeout=timeout)


def test_an_interrupt_a_library_loses_ends_the_command_with_130(tmp_path: Path) -> None:
    """Ctrl-C lands in ``Tensor.__dlpack__`` while Dr.Jit converts a torch tensor (``TensorXf(tensor)``, as
    ``dr.wrap`` does): Dr.Jit clears the ``KeyboardInterrupt`` and converts another way, and the command works on;
    the watchdog raises it again within about :data:`~mi_svbrdf.cli.interrupt.RETRY_S`."""
    res = _command("""
        import torch
        from drjit.llvm.ad import TensorXf

        def work(args):
            dlpack = torch.Tensor.__dlpack__

            def interrupted_dlpack(self, *a, **k):
                os.kill(os.getpid(), signal.SIGINT)  # its handler runs in this Python frame, inside Dr.Jit's call
                return dlpack(self, *a, **k)

            torch.Tensor.__dlpack__ = interrupted_dlpack
            converted = TensorXf(torch.arange(4.0))
            torch.Tensor.__dlpack__ = dlpack
            lost = time.monotonic()
            print(f"converted {converted.array}", flush=True)
            try:
                while time.monotonic() - lost < 20:
                    sum(range(1000))
            finally:
                print(f"stopped {time.monotonic() - lost:.2f} s after", flush=True)
            return 0
    """, tmp_path)
    assert res.returncode == 130 and res.stderr == LINE, (res.returncode, res.stderr)
    converted, stopped = res.stdout.splitlines()
    assert converted == "converted [0, 1, 2, 3]"  # Dr.Jit went on: the interrupt was lost there
    assert float(stopped.split()[1]) < interrupt.RETRY_S + 1.0, res.stdout


def test_a_command_that_outruns_a_lost_interrupt_does_not_exit_0(tmp_path: Path) -> None:
    """The interrupt is lost and the command ends before the watchdog raises it again: exit code 130 all the
    same (its outcome is not success), one line."""
    res = _command("""
        def work(args):
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(5)
            except KeyboardInterrupt:
                pass  # lost, and the command ends at once
            print("done")
            return 0
    """, tmp_path)
    assert res.returncode == 130 and res.stderr == LINE and res.stdout == "done\n", (res.returncode, res.stderr)


def test_an_interrupt_in_a_kernel_recording_is_one_line_not_a_runtime_error(tmp_path: Path) -> None:
    """Dr.Jit raises ``RuntimeError: record(): error encountered while recording ...`` from a ``KeyboardInterrupt``
    inside a frozen function: the command still ends with one line and exit code 130."""
    res = _command("""
        import drjit as dr
        from drjit.llvm.ad import Float

        @dr.freeze
        def kernel(x):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(10**6):  # the handler runs here, inside the recording
                pass
            return x * 2

        def work(args):
            kernel(Float([1.0, 2.0]))
            return 0
    """, tmp_path)
    assert res.returncode == 130 and res.stderr == LINE, (res.returncode, res.stderr)


def test_ctrl_c_while_an_error_is_reported_is_still_130(tmp_path: Path) -> None:
    """Ctrl-C that comes while an exception is being handled is not raised there (it would cut the handling
    short); the command ends with exit code 130 and the interrupt's line, not a traceback."""
    res = _command("""
        def work(args):
            try:
                raise OSError("disk")
            except OSError:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.2)  # a handler's clean-up: not cut short
                print("cleaned up", flush=True)
            time.sleep(5)
            return 0
    """, tmp_path)
    assert res.returncode == 130 and res.stderr == LINE and res.stdout == "cleaned up\n", (res.returncode, res.stderr)


def test_ctrl_c_while_the_outcome_is_reported_makes_it_130(tmp_path: Path) -> None:
    """Ctrl-C after the command's work, while its error line is printed: that line, then the interrupt's."""
    res = _command("""
        flag_terms = common.flag_terms

        def interrupted_flag_terms(*a):
            os.kill(os.getpid(), signal.SIGINT)
            return flag_terms(*a)

        common.flag_terms = interrupted_flag_terms

        def work(args):
            raise ValueError("bad input")
    """, tmp_path)
    assert res.returncode == 130, (res.returncode, res.stderr)
    assert res.stderr == ("mi-svbrdf work: error: bad input\n"
                          "mi-svbrdf work: interrupted as it ended (the lines above say what it did)\n"), res.stderr


def test_ctrl_c_after_the_outcome_ends_the_process_at_once(tmp_path: Path) -> None:
    """Ctrl-C once the command has reported success (the interpreter shuts down): SIGINT's default action, the
    process killed by it (a shell's exit code 130), nothing more printed."""
    script = COMMAND.replace("sys.exit(common.run(parser, [\"work\"]))",
                             "code = common.run(parser, [\"work\"])\nos.kill(os.getpid(), signal.SIGINT)\n"
                             "time.sleep(10)\nsys.exit(code)")
    (tmp_path / "mi-svbrdf").write_text(script.format(work="def work(args):\n    print('done')\n    return 0"))
    res = subprocess.run([sys.executable, str(tmp_path / "mi-svbrdf")], cwd=tmp_path, capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == -signal.SIGINT and res.stdout == "done\n" and res.stderr == "", res


def test_a_cpu_tensor_reaches_dr_jit_without_running_python_code() -> None:
    """Dr.Jit converts a torch tensor by calling its Python ``__dlpack__`` and loses a ``KeyboardInterrupt``
    raised there: :func:`to_jit` hands it a NumPy view instead, whose conversion runs no Python code."""
    t = torch.arange(6.0)
    to_jit(t)  # the backend's first use
    called: list[str] = []

    def profile(frame, event, arg):  # noqa: ANN001, ANN202
        if event == "call":
            called.append(frame.f_code.co_name)

    sys.setprofile(profile)
    try:
        arr = to_jit(t)
    finally:
        sys.setprofile(None)
    assert set(called) <= {"to_jit", "jit_types_for"}, called
    t[0] = 10.0
    assert arr[0] == 10.0  # the array still shares the tensor's memory


#: The fast runs (budget-capped) and the seconds of work each has past its start-up on 2 idle cores: two instants
#: are drawn over that time after the start-up (measured once: :func:`startup`), so that they fall in the
#: command's own work on any machine; a slower one only moves them earlier in it.
FAST = {"optimize": (["optimize", "--capture", "example", "--budget-s", "5"], 6.0),
        "capture": (BENCH.SWEEP["capture"], 5.0),
        "scan": (BENCH.SWEEP["scan"], 7.0)}


@pytest.fixture(scope="module")
def startup(tmp_path_factory: pytest.TempPathFactory) -> float:
    """Seconds an ``mi-svbrdf`` command takes to start on this machine now."""
    return BENCH.startup_seconds(tmp_path_factory.mktemp("startup"))


@pytest.mark.parametrize("command", sorted(FAST))
def test_sigint_at_seeded_instants(command: str, startup: float, tmp_path: Path) -> None:
    """Two seeded instants per command in its work (``benchmarks/bench_sigint.py``'s rules): each run interrupted
    (exit code 130, one line, whole outputs) or, only where the command ended first, exit code 0 with whole
    outputs."""
    argv, work = FAST[command]
    runs = []
    for k, t in enumerate(BENCH.instants(command, 2, startup + work, start=startup)):
        out = tmp_path / f"at{k}"
        runs.append(BENCH.judge(BENCH.interrupt_at(argv, t, out), out))
        print(f"{command}: SIGINT at {t} s (start-up {startup:.1f} s) -> {runs[-1].verdict}, exit code "
              f"{runs[-1].code}, its line {runs[-1].line_latency} s after; {runs[-1].line}")
    assert not [(r.instant, r.problems, r.stderr[-2000:]) for r in runs if r.problems]
    assert runs[0].verdict == "interrupted", (runs[0].instant, runs[0].verdict)


def test_docstring_examples() -> None:
    assert doctest.testmod(interrupt).failed == 0
    assert doctest.testmod(BENCH).failed == 0


@pytest.mark.slow
def test_sigint_sweep(tmp_path: Path) -> None:
    """The whole sweep (``python benchmarks/bench_sigint.py`` writes its table to docs/benchmarks/sigint.md):
    every run judged as the module docstring of the benchmark says."""
    ends, runs = BENCH.sweep(BENCH.SWEEP, BENCH.INSTANTS, tmp_path)
    failed = [(r.command, r.instant, r.problems, r.stderr[-2000:]) for r in [*ends.values(), *runs] if r.problems]
    assert not failed
    assert sum(r.verdict == "interrupted" for r in runs) >= len(runs) // 2
