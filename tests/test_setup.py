"""The set-up: the README's two commands, ``.ci/run`` and ``.ci/setup.sh`` (its venv checks), ``.gitignore``, the cache.

The installing path of ``.ci/setup.sh`` (creating ``.venv``, apt, pip) takes minutes and is what CI runs
(``.ci/run`` on a fresh clone); these tests cover what can be checked in seconds: that CI runs the README's
test command as written, and that the script refuses, before installing anything, an environment it must not
touch.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SETUP = ROOT / ".ci" / "setup.sh"
#: What both README commands start with: install into the project venv, then enter it.
PREFIX = "bash .ci/setup.sh && . .venv/bin/activate && "
#: What the script prints when it starts apt, creates the venv or runs pip.
STARTED = re.compile(r"^\[setup\] (installing|creating|using)", flags=re.MULTILINE)


def _setup_commands() -> list[str]:
    """The command lines of the README's "Set-up" code block."""
    section = (ROOT / "README.md").read_text(encoding="utf-8").split("## Set-up", 1)[1]
    block = re.search(r"```bash\n(.*?)```", section, flags=re.DOTALL)
    assert block, "README: no bash block in the Set-up section"
    return [line for line in block.group(1).splitlines() if line.strip() and not line.startswith("#")]


def _run_setup(tmp_path: Path, **env: str) -> subprocess.CompletedProcess[str]:
    """``bash .ci/setup.sh`` with ``env`` added (from ``tmp_path``; at most 60 s: these runs must stop early)."""
    full = {k: v for k, v in os.environ.items() if k not in ("MI_SVBRDF_VENV", "MI_SVBRDF_PYTHON")}
    return subprocess.run(["bash", str(SETUP)], check=False, cwd=tmp_path, env={**full, **env}, capture_output=True, text=True,
                          timeout=60)


def test_readme_commands_install_into_the_venv_and_ci_runs_the_test_command() -> None:
    commands = _setup_commands()
    assert len(commands) == 2, commands
    assert all(c.startswith(PREFIX) for c in commands), commands
    assert commands[0].removeprefix(PREFIX).startswith("mi-svbrdf capture example"), commands[0]
    assert commands[1].removeprefix(PREFIX) == "python -m pytest -q", commands[1]
    run = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if line and not line.startswith("#")]
    assert run[-3] == commands[1], ".ci/run must run the README's test command as written"
    assert run[-2] == ". .venv/bin/activate && python -m pytest -q -m slow", "then the slow tests"
    assert run[-1] == ". .venv/bin/activate && MI_SVBRDF_TEST_VARIANT=scalar_rgb python -m pytest -q", \
        "then the default suite with another Mitsuba variant active"
    # the venv the README enters is the one the script installs into by default
    assert 'venv="${MI_SVBRDF_VENV:-.venv}"' in SETUP.read_text()


def test_scripts_are_valid_bash() -> None:
    for script in (SETUP, ROOT / ".ci" / "run"):
        res = subprocess.run(["bash", "-n", str(script)], check=False, capture_output=True, text=True)
        assert res.returncode == 0, f"{script}: {res.stderr}"


def test_setup_refuses_a_folder_that_is_not_a_venv(tmp_path: Path) -> None:
    target = tmp_path / "not_a_venv"
    target.mkdir()
    (target / "keep.txt").write_text("a user's folder")
    res = _run_setup(tmp_path, MI_SVBRDF_VENV="not_a_venv")  # relative to the current folder
    assert res.returncode == 2, res.stdout + res.stderr
    assert "not a Python virtual environment" in res.stderr and str(target) in res.stderr
    assert "MI_SVBRDF_VENV=" in res.stderr  # says what to run instead
    assert not STARTED.search(res.stdout), res.stdout  # refused before apt and pip
    assert sorted(p.name for p in target.iterdir()) == ["keep.txt"]


def test_setup_refuses_a_python_it_cannot_use(tmp_path: Path) -> None:
    res = _run_setup(tmp_path, MI_SVBRDF_VENV=str(tmp_path / "venv"), MI_SVBRDF_PYTHON=str(tmp_path / "nope"))
    assert res.returncode == 2 and "no such command" in res.stderr, res.stdout + res.stderr
    old = tmp_path / "python3.8"
    old.write_text("#!/bin/sh\n[ \"$1\" = --version ] && echo 'Python 3.8.10' && exit 0\nexit 1\n")  # as 3.8 would
    old.chmod(0o755)
    res = _run_setup(tmp_path, MI_SVBRDF_VENV=str(tmp_path / "venv"), MI_SVBRDF_PYTHON=str(old))
    assert res.returncode == 2 and "expected Python >= 3.10, got Python 3.8.10" in res.stderr, res.stderr
    assert not (tmp_path / "venv").exists() and not STARTED.search(res.stdout), res.stdout


def _readme_outputs() -> set[str]:
    """Relative folders the README's and docs/' commands and examples write into (``-o``/``--out`` in bash
    blocks, the first argument of ``write_material``/``make_bank`` in Python blocks)."""
    text = "\n".join(p.read_text(encoding="utf-8") for p in (ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))))
    outs: set[str] = set()
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.DOTALL):
        outs |= set(re.findall(r"(?:^|\s)(?:-o|--out)[ =]([^\s\]]+)", block, flags=re.MULTILINE))
    for block in re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL):
        outs |= set(re.findall(r"(?:write_material|make_bank)\(\"([^\"]+)\"", block))
    return {o for o in outs if not o.startswith(("/", "~", "$"))}


def test_gitignore_covers_what_the_readme_writes() -> None:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    outputs = _readme_outputs()
    assert {"out/capture", "bank/", "report/"} <= outputs, outputs  # the parser still finds them
    probes = sorted({f"{o.rstrip('/')}/file.png" for o in outputs} | {".venv/bin/python"})
    res = subprocess.run(["git", "check-ignore", "--no-index", *probes], check=False, cwd=ROOT, capture_output=True,
                         text=True)
    ignored = set(res.stdout.split())
    assert ignored == set(probes), f"not in .gitignore: {sorted(set(probes) - ignored)}"


def test_referenced_scripts_exist() -> None:
    """Every ``*.sh`` that pyproject.toml, the README and .ci/ name exists (pyproject named scripts/setup.sh)."""
    for path in (ROOT / "pyproject.toml", ROOT / "README.md", *sorted((ROOT / ".ci").iterdir())):
        for name in re.findall(r"[\w./-]+\.sh\b", path.read_text(encoding="utf-8")):
            assert (ROOT / name).is_file(), f"{path.name} names {name}, which does not exist"


def test_install_guide_documents_the_cache_where_the_code_puts_it(monkeypatch: pytest.MonkeyPatch) -> None:
    from mi_svbrdf.data.cached_set import default_cache_dir

    text = (ROOT / "docs" / "install.md").read_text(encoding="utf-8")
    assert "**Cache and outputs.**" in text and "`MI_SVBRDF_CACHE`" in text and "`~/.cache/mi_svbrdf`" in text
    monkeypatch.delenv("MI_SVBRDF_CACHE", raising=False)
    assert default_cache_dir("heldout") == Path.home() / ".cache" / "mi_svbrdf" / "heldout"
    for kind in ("heldout/", "foreign/", "runs/"):
        assert f"`{kind}`" in text.split("**Cache and outputs.**")[1].split("\n\n")[0], kind


@pytest.mark.skipif(sys.prefix == sys.base_prefix, reason="not running in a venv (the set-up's venv is checked "
                                                          "where the tests run in it, as .ci/run does)")
def test_running_in_a_venv_with_the_package_of_this_clone() -> None:
    """Under .ci/run: the tests run in a venv whose mi_svbrdf is this clone's (the editable install)."""
    import mi_svbrdf

    assert Path(mi_svbrdf.__file__).resolve().is_relative_to(ROOT)
