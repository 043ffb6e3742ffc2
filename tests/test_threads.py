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
