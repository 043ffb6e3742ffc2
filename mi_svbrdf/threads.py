"""CPU thread pools on a machine that other programs share: OpenMP's waiting threads sleep.

mi_svbrdf's CPU work runs in two thread pools, each sized to the whole machine: PyTorch's intra-op pool
(OpenMP, libgomp in PyTorch's Linux wheels: every parallel region ends on a barrier) and Dr.Jit's LLVM
pool (nanothread: a kernel's blocks go to whichever worker is free). By default libgomp's threads
*spin* at a barrier and between regions (``OMP_WAIT_POLICY`` unset: an active wait of about 300 000
iterations before they sleep). Beside Dr.Jit's workers, and worse beside other busy processes, the
spinning threads take the cores the work needs, and a region waits for a thread the scheduler parked:
the optimiser's step, a Dr.Jit kernel between many small PyTorch operations, ran many times slower
beside busy processes than a fair share of the CPU would make it (``benchmarks/bench_contention.py``;
the figures in ``docs/benchmarks/contention.md``).

The rule (:func:`set_wait_policy`, run first thing by ``import mi_svbrdf``, hence by every ``mi-svbrdf``
command and worker process): unless the environment already says how OpenMP waits (``OMP_WAIT_POLICY`` or
libgomp's ``GOMP_SPINCOUNT``), waiting OpenMP threads sleep (``OMP_WAIT_POLICY=PASSIVE``). OpenMP reads the
variable when its library loads, i.e. when torch is first imported: a process that imported torch
before mi_svbrdf keeps the active wait (:func:`wait_policy` says which applies; set the variable before
Python starts to be sure). Thread counts are left as they are (``OMP_NUM_THREADS`` or
``torch.set_num_threads`` size PyTorch's pool, ``drjit.set_thread_count`` Dr.Jit's: ``docs/install.md``),
except in that case, torch imported first with nothing said about OpenMP: then the spinning pool and
Dr.Jit's would both fill the cores, so :func:`share_cores` splits them (PyTorch half, Dr.Jit the rest;
a PyTorch pool already smaller than the cores is kept, and Dr.Jit gets the cores it leaves).

This module imports nothing heavy at import time (no torch, no Mitsuba): it must run before they load.

Examples:
    >>> env = {}
    >>> set_wait_policy(env, torch_loaded=False)
    'PASSIVE'
    >>> env
    {'OMP_WAIT_POLICY': 'PASSIVE'}
    >>> set_wait_policy({"OMP_WAIT_POLICY": "active"}, torch_loaded=False)  # the user's choice stays
    'active'
"""
from __future__ import annotations

import os
import sys
from collections.abc import MutableMapping

__all__ = ["MIN_DRJIT_THREADS", "OWN_SETTINGS", "THREAD_SETTINGS", "WAIT_POLICY", "cpu_count", "set_wait_policy", "share_cores",
           "split_cores", "wait_policy"]

#: The wait policy set for OpenMP's threads when the environment names none.
WAIT_POLICY = "PASSIVE"
#: Variables by which a user says how OpenMP waits; when one is set, mi_svbrdf sets nothing.
OWN_SETTINGS = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")
#: Variables by which a user sizes PyTorch's pool; when one is set, :func:`share_cores` changes nothing.
THREAD_SETTINGS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")
#: The fewest threads :func:`share_cores` leaves Dr.Jit: with a pool of one, Mitsuba's scene loading
#: (``mi.load_file``, whose parallel parsing waits on tasks of the same pool) never returns.
MIN_DRJIT_THREADS = 2
#: What this module did in this process: the policy :func:`set_wait_policy` set, or None (the user's, or too
#: late); the ``(torch, drjit)`` thread counts :func:`share_cores` set, or None.
_SET: dict[str, object] = {"policy": None, "shared": None}


def cpu_count() -> int:
    """The cores this process may run on (its CPU affinity where the system has one, else ``os.cpu_count()``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def split_cores(cpus: int, torch_threads: int) -> tuple[int, int]:
    """``(torch, drjit)`` thread counts that together do not exceed ``cpus``: a PyTorch pool of ``torch_threads``
    already smaller than the cores is kept and Dr.Jit gets the rest; a pool of all the cores is halved. PyTorch
    keeps at least 1 thread and Dr.Jit :data:`MIN_DRJIT_THREADS` (on 1 or 2 cores the sum is then above them).

    Examples:
        >>> split_cores(2, 2), split_cores(16, 16), split_cores(16, 4), split_cores(1, 1)
        ((1, 2), (8, 8), (4, 12), (1, 2))
    """
    torch_threads = max(1, torch_threads if torch_threads < cpus else cpus // 2)
    return torch_threads, max(MIN_DRJIT_THREADS, cpus - torch_threads)


def set_wait_policy(environ: MutableMapping[str, str] | None = None, *, torch_loaded: bool | None = None) -> str | None:
    """Make OpenMP's waiting threads sleep (``OMP_WAIT_POLICY=PASSIVE`` in ``environ``) unless a variable of
    :data:`OWN_SETTINGS` is set there already, or torch (and with it OpenMP) is already loaded.

    Args:
        environ: the environment to change (default: ``os.environ``, which worker processes inherit).
        torch_loaded: whether OpenMP has read its settings already (default: whether ``torch`` is imported).

    Returns:
        The policy that applies: the user's ``OMP_WAIT_POLICY``, the one set here, or None (OpenMP's default
        active wait: ``GOMP_SPINCOUNT`` set by the user, or torch loaded before this ran).
    """
    environ = os.environ if environ is None else environ
    if any(name in environ for name in OWN_SETTINGS):
        return environ.get("OMP_WAIT_POLICY")
    if torch_loaded if torch_loaded is not None else "torch" in sys.modules:
        return None
    environ["OMP_WAIT_POLICY"] = WAIT_POLICY
    if environ is os.environ:
        _SET["policy"] = WAIT_POLICY
    return WAIT_POLICY


def share_cores(environ: MutableMapping[str, str] | None = None) -> tuple[int, int] | None:
    """When torch was imported before mi_svbrdf and the environment says nothing about OpenMP's wait or threads
    (:data:`OWN_SETTINGS`, :data:`THREAD_SETTINGS`): PyTorch's spinning pool and Dr.Jit's would both fill the
    cores, so give them :func:`split_cores` of :func:`cpu_count` (``torch.set_num_threads``,
    ``drjit.set_thread_count``). Called by ``import mi_svbrdf``; the case the wait policy cannot help.

    Returns:
        The ``(torch, drjit)`` thread counts set, or None (nothing changed: torch not loaded, the user's settings).
    """
    environ = os.environ if environ is None else environ
    if "torch" not in sys.modules or any(name in environ for name in (*OWN_SETTINGS, *THREAD_SETTINGS)):
        return None
    import drjit
    import torch

    counts = split_cores(cpu_count(), torch.get_num_threads())
    if counts[0] != torch.get_num_threads():
        torch.set_num_threads(counts[0])
    drjit.set_thread_count(counts[1])
    _SET["shared"] = counts
    return counts


def wait_policy() -> str:
    """How this process's OpenMP threads wait, in words (for reports and benchmarks)."""
    if _SET["shared"]:
        t, d = _SET["shared"]  # type: ignore[misc]
        return (f"OpenMP's default active wait (torch was imported before mi_svbrdf; set OMP_WAIT_POLICY=PASSIVE or "
                f"import mi_svbrdf first): mi_svbrdf gave PyTorch {t} and Dr.Jit {d} of the {cpu_count()} cores")
    if _SET["policy"]:
        return f"OMP_WAIT_POLICY={_SET['policy']} (set by mi_svbrdf before torch loaded)"
    if "OMP_WAIT_POLICY" in os.environ:
        return f"OMP_WAIT_POLICY={os.environ['OMP_WAIT_POLICY']} (the environment's)"
    if "GOMP_SPINCOUNT" in os.environ:
        return f"GOMP_SPINCOUNT={os.environ['GOMP_SPINCOUNT']} (the environment's)"
    return "OpenMP's default active wait (torch was imported before mi_svbrdf; set OMP_WAIT_POLICY=PASSIVE)"
