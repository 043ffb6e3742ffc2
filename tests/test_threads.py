"""OpenMP's waiting threads sleep in mi_svbrdf's processes unless the user says otherwise (mi_svbrdf.threads)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from mi_svbrdf import threads

ROOT = Path(__file__).resolve().parents[1]


def test_the_wait_policy_is_set_only_where_the_user_set_none_and_torch_is_not_loaded() -> None:
    env: dict[str, str] = {}
    assert threads.set_wait_policy(env, torch_loaded=False) == "PASSIVE" and env == {"OMP_WAIT_POLICY": "PASSIVE"}
    env = {"OMP_WAIT_POLICY": "ACTIVE"}
    assert threads.set_wait_policy(env, torch_loaded=False) == "ACTIVE" and env == {"OMP_WAIT_POLICY": "ACTIVE"}
    env = {"GOMP_SPINCOUNT": "10000"}
    assert threads.set_wait_policy(env, torch_loaded=False) is None and env == {"GOMP_SPINCOUNT": "10000"}
    env = {}
    assert threads.set_wait_policy(env, torch_loaded=True) is None and env == {}  # OpenMP read its settings already


@pytest.mark.parametrize("user, expected", [(None, "PASSIVE"), ("ACTIVE", "ACTIVE")])
def test_importing_mi_svbrdf_first_sets_it_before_torch_loads(user: str | None, expected: str) -> None:
    env = {k: v for k, v in os.environ.items() if k not in threads.OWN_SETTINGS}
    if user:
        env["OMP_WAIT_POLICY"] = user
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    code = ("import os\nimport mi_svbrdf, torch\nfrom mi_svbrdf.threads import wait_policy\n"
            "print(os.environ['OMP_WAIT_POLICY'], wait_policy())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    policy, said = out.strip().split(" ", 1)
    assert policy == expected, out
    # "set by mi_svbrdf before torch loaded": set_wait_policy sets nothing once torch is imported
    assert said.startswith(f"OMP_WAIT_POLICY={expected}") and ("set by mi_svbrdf" in said) == (user is None), said


def _run(code: str, **extra: str) -> str:
    env = {k: v for k, v in os.environ.items() if k not in (*threads.OWN_SETTINGS, *threads.THREAD_SETTINGS)}
    env.update(extra)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout


#: Prints PyTorch's and Dr.Jit's thread counts, the cores, and wait_policy(), after the imports of the first line.
COUNTS = ("\nimport drjit, torch\nfrom mi_svbrdf.threads import cpu_count, wait_policy\n"
          "print(torch.get_num_threads(), drjit.thread_count(), cpu_count(), wait_policy(), sep='|')")


def test_torch_first_splits_the_cores_between_the_two_pools() -> None:
    """torch imported before mi_svbrdf: OpenMP's threads spin, so PyTorch's pool and Dr.Jit's together do not exceed
    the cores, and wait_policy() says what was done; mi_svbrdf first, or the user's settings: nothing changes."""
    torch_n, drjit_n, cpus, said = _run("import torch\nimport mi_svbrdf" + COUNTS).strip().split("|")
    assert int(torch_n) + int(drjit_n) <= max(int(cpus), 3) and int(torch_n) >= 1 and int(drjit_n) >= 2
    assert (int(torch_n), int(drjit_n)) == threads.split_cores(int(cpus), int(cpus))
    assert f"gave PyTorch {torch_n} and Dr.Jit {drjit_n} of the {cpus} cores" in said and "import mi_svbrdf first" in said
    alone = _run("import torch, drjit\nprint(torch.get_num_threads(), drjit.thread_count())").split()
    first = _run("import mi_svbrdf\nimport torch" + COUNTS).strip().split("|")
    assert first[:2] == alone and first[3].startswith("OMP_WAIT_POLICY=PASSIVE (set by mi_svbrdf")
    for user in ({"OMP_NUM_THREADS": "1"}, {"OMP_WAIT_POLICY": "ACTIVE"}):
        mine = _run("import torch\nimport mi_svbrdf" + COUNTS, **user).strip().split("|")
        assert "gave PyTorch" not in mine[3] and mine[1] == alone[1], (user, mine)


def test_split_cores_keeps_a_smaller_torch_pool_and_never_exceeds_the_cores() -> None:
    for cpus in range(1, 65):
        for torch_threads in (1, cpus // 2 or 1, cpus, cpus + 4):
            t, d = threads.split_cores(cpus, torch_threads)
            assert t >= 1 and d >= threads.MIN_DRJIT_THREADS and t + d <= max(cpus, 1 + threads.MIN_DRJIT_THREADS)
            assert t == (torch_threads if torch_threads < cpus else max(1, cpus // 2))
