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
Python starts to be sure). Thread counts are left as they are: ``OMP_NUM_THREADS`` or
``torch.set_num_threads`` size PyTorch's pool, ``drjit.set_thread_count`` Dr.Jit's
(``docs/install.md``).

This module imports nothing heavy (no torch, no Mitsuba): it must run before they load.

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

__all__ = ["OWN_SETTINGS", "WAIT_POLICY", "set_wait_policy", "wait_policy"]

#: The wait policy set for OpenMP's threads when the environment names none.
WAIT_POLICY = "PASSIVE"
#: Variables by which a user says how OpenMP waits; when one is set, mi_svbrdf sets nothing.
OWN_SETTINGS = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")
#: What :func:`set_wait_policy` did in this process: the policy it set, or None (the user's, or too late).
_SET: dict[str, str | None] = {"policy": None}


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


def wait_policy() -> str:
    """How this process's OpenMP threads wait, in words (for reports and benchmarks)."""
    if _SET["policy"]:
        return f"OMP_WAIT_POLICY={_SET['policy']} (set by mi_svbrdf before torch loaded)"
    if "OMP_WAIT_POLICY" in os.environ:
        return f"OMP_WAIT_POLICY={os.environ['OMP_WAIT_POLICY']} (the environment's)"
    if "GOMP_SPINCOUNT" in os.environ:
        return f"GOMP_SPINCOUNT={os.environ['GOMP_SPINCOUNT']} (the environment's)"
    return "OpenMP's default active wait (torch was imported before mi_svbrdf; set OMP_WAIT_POLICY=PASSIVE)"
