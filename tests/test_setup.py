"""The set-up: the README's two commands, ``.ci/run`` and ``.ci/setup.sh`` (its venv checks, what each command
installs), ``constraints.txt``, ``.gitignore``, the cache.

The installing path of ``.ci/setup.sh`` (creating ``.venv``, apt, pip) takes minutes and is what CI runs
(``.ci/run`` on a fresh clone); these tests cover what can be checked in seconds: that CI runs the README's
test command as written, that the script refuses, before installing anything, an environment or an argument it
must not take, what each command would install (``--dry-run``: the main job's command no test tools, the test
command all of them, both pinned by ``constraints.txt``), and that the pins cover what the install pulls in.
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
CONSTRAINTS = ROOT / "constraints.txt"
#: The README's two commands: the main job's set-up installs what it needs; the test command's also the test tools.
MAIN_PREFIX = "bash .ci/setup.sh && . .venv/bin/activate && "
TEST_COMMAND = "bash .ci/setup.sh --tests && . .venv/bin/activate && python -m pytest -q"
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
    assert commands[0].startswith(MAIN_PREFIX), f"README: the main job's set-up has no --tests: {commands[0]}"
    assert commands[0].removeprefix(MAIN_PREFIX).startswith("mi-svbrdf capture example"), commands[0]
    assert commands[1] == TEST_COMMAND, f"README: the test command installs the test tools first: {commands[1]}"
    run = _ci_lines()
    assert run[-8] == commands[1], ".ci/run must run the README's test command as written"
    assert run[-7] == ". .venv/bin/activate && python -m pytest -q -m slow", "then the slow tests"
    assert run[-6] == ". .venv/bin/activate && MI_SVBRDF_TEST_VARIANT=scalar_rgb python -m pytest -q --kernel-tests", \
        "then the default suite's kernel tests (recorded by the first run) with another Mitsuba variant active"
    # the venv the README enters is the one the script installs into by default
    assert 'venv="${MI_SVBRDF_VENV:-.venv}"' in SETUP.read_text()


def _ci_lines() -> list[str]:
    """``.ci/run``'s lines that are not comments, stripped."""
    lines = (line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines())
    return [line for line in lines if line and not line.startswith("#")]


def test_ci_runs_the_optimiser_loss_and_selfcal_tests_at_every_llvm_width() -> None:
    """After its three passes ``.ci/run`` runs the optimiser's, the loss's and self-calibration's tests at each of
    Dr.Jit's LLVM vector widths the suite offers (``MI_SVBRDF_TEST_LLVM_WIDTH``, tests/conftest.py), saying in its
    log which width each pass runs at; the width check itself first."""
    from tests import conftest

    run = _ci_lines()
    assert run[-5].startswith("width_tests=(") and run[-5].endswith(")"), run[-5]
    tests = run[-5].removeprefix("width_tests=(").removesuffix(")").split()
    assert tests[0].startswith("tests/test_llvm_width.py::"), tests
    files = [t.split("::")[0] for t in tests]
    assert all((ROOT / f).is_file() for f in files), files
    for test in tests:  # a named test is in its file
        if "::" in test:
            assert f"def {test.split('::')[1]}(" in (ROOT / test.split("::")[0]).read_text(), test
    names = [Path(f).name for f in files]
    assert any(n.startswith("test_optimize") for n in names) and "test_loss.py" in names \
        and "test_selfcal.py" in names, names
    assert run[-4] == f"for width in {' '.join(map(str, conftest.LLVM_WIDTHS))}; do", run[-4]
    assert run[-3].startswith("echo ") and "$width" in run[-3], "each pass says its width in CI's log"
    assert run[-2] == '. .venv/bin/activate && MI_SVBRDF_TEST_LLVM_WIDTH="$width" python -m pytest -q ' \
        '"${width_tests[@]}"', run[-2]
    assert run[-1] == "done"


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


def test_setup_refuses_an_unknown_argument(tmp_path: Path) -> None:
    res = _run_setup_args(tmp_path, ["--test"])  # a typo of --tests
    assert res.returncode == 2, res.stdout + res.stderr
    assert "unknown argument '--test'" in res.stderr and "--tests" in res.stderr, res.stderr
    assert not STARTED.search(res.stdout), res.stdout


def _run_setup_args(tmp_path: Path, args: list[str], **env: str) -> subprocess.CompletedProcess[str]:
    """``bash .ci/setup.sh ARGS`` with ``env`` added, from ``tmp_path`` (at most 60 s)."""
    drop = ("MI_SVBRDF_VENV", "MI_SVBRDF_PYTHON", "MI_SVBRDF_TEST_TOOLS")
    full = {k: v for k, v in os.environ.items() if k not in drop}
    return subprocess.run(["bash", str(SETUP), *args], check=False, cwd=tmp_path, env={**full, **env},
                          capture_output=True, text=True, timeout=60)


def _pins() -> tuple[str, dict[str, str]]:
    """constraints.txt: the Python its pins were made on (``# python: X.Y``) and ``{normalised name: version}``."""
    python, pins = "", {}
    for n, line in enumerate(CONSTRAINTS.read_text(encoding="utf-8").splitlines(), 1):
        if line.startswith("# python:"):
            python = line.split(":", 1)[1].strip()
        elif line and not line.startswith("#"):
            match = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)==([0-9][0-9A-Za-z.!]*)", line)
            assert match, f"constraints.txt:{n}: expected NAME==VERSION (no local label, no marker), got {line!r}"
            key = re.sub(r"[-_.]+", "-", match.group(1)).lower()
            assert key not in pins, f"constraints.txt:{n}: {key} pinned twice"
            pins[key] = match.group(2)
    assert re.fullmatch(r"3\.\d+", python), "constraints.txt: expected a '# python: 3.X' line"
    return python, pins


def _in_pinned_venv() -> str | None:
    """Why the running environment is not one the pins are in force in (None: it is)."""
    from importlib import metadata

    python, pins = _pins()
    if sys.prefix == sys.base_prefix:
        return "not running in a venv (the set-up's venv is checked where the tests run in it, as .ci/run does)"
    if "%d.%d" % sys.version_info[:2] != python:
        return f"Python {'%d.%d' % sys.version_info[:2]}: constraints.txt pins the versions of Python {python}"
    if metadata.version("torch").split("+")[0] != pins["torch"]:
        return f"a torch of the user's own ({metadata.version('torch')}) is kept unpinned"
    return None


def _dry_run(tmp_path: Path, *args: str, **env: str) -> tuple[list[str], str]:
    """``.ci/setup.sh --dry-run ARGS`` on the running venv, the test tools aimed at empty folders in ``tmp_path``
    and stand-ins for python3.11, npm and node (a dry run only asks them whether they exist): the commands it
    would run, and all it printed."""
    stubs = tmp_path / "bin"
    stubs.mkdir(exist_ok=True)
    for name in ("python3.11", "npm", "node"):
        (stubs / name).write_text("#!/bin/sh\nexit 0\n")  # "Python 3.11", as the version check asks
        (stubs / name).chmod(0o755)
    res = _run_setup_args(tmp_path, ["--dry-run", *args], MI_SVBRDF_VENV=sys.prefix,
                          MI_SVBRDF_BLENDER_VENV=str(tmp_path / "blender"), MI_SVBRDF_TOOLS=str(tmp_path / "tools"),
                          MI_SVBRDF_BLENDER_PYTHON=str(stubs / "python3.11"),
                          PATH=f"{stubs}{os.pathsep}{os.environ['PATH']}", **env)
    assert res.returncode == 0, res.stdout + res.stderr
    assert res.stdout.rstrip().endswith("[setup] --dry-run: nothing was installed"), res.stdout
    assert not (tmp_path / "blender").exists() and not (tmp_path / "tools").exists(), "a dry run installed"
    return [line.removeprefix("[setup] would run: ") for line in res.stdout.splitlines()
            if line.startswith("[setup] would run: ")], res.stdout


def _pip_install_of_the_project(commands: list[str]) -> str:
    found = [c for c in commands if " -m pip install " in c and " -e " in c]
    assert len(found) == 1, commands
    return found[0]


@pytest.mark.skipif(sys.prefix == sys.base_prefix, reason="not running in a venv (the dry runs use the running one)")
def test_main_job_setup_installs_no_test_tools_and_the_test_setup_installs_them(tmp_path: Path) -> None:
    main, main_out = _dry_run(tmp_path)
    tests, tests_out = _dry_run(tmp_path, "--tests")
    # the main job's command: mi_svbrdf and its own dependencies, nothing the tests use
    assert _pip_install_of_the_project(main).endswith(" -e ."), main
    for tool in ("[test", "dataset", "bpy", "gltf-validator", "chromium", "npm", "Blender"):
        assert tool not in main_out, f"bash .ci/setup.sh (the main job's set-up) would install {tool}: {main_out}"
    assert "bash .ci/setup.sh --tests" in main_out  # and says where the rest comes from
    # the test command's: the extras, Blender's bpy in its venv, the glTF validator, chromium where missing
    assert _pip_install_of_the_project(tests).endswith(" -e .[test,dataset]"), tests
    blender = tmp_path / "blender"
    assert f"{tmp_path / 'bin' / 'python3.11'} -m venv {blender}" in tests, tests
    assert f"{blender}/bin/python -m pip install -q bpy==4.5.*" in tests, tests
    assert any(c.startswith(f"npm install --prefix {tmp_path / 'tools'} ") and " gltf-validator@" in c
               for c in tests), tests
    assert shutil.which("chromium") or any("apt-get install" in c and "chromium" in c for c in tests), tests
    # MI_SVBRDF_TEST_TOOLS=0: the extras, not the two tools
    no_tools, out = _dry_run(tmp_path, "--tests", MI_SVBRDF_TEST_TOOLS="0")
    assert _pip_install_of_the_project(no_tools).endswith(" -e .[test,dataset]")
    assert not any("bpy" in c or "npm" in c for c in no_tools), no_tools
    assert "MI_SVBRDF_TEST_TOOLS=0" in out
    # both pinned by constraints.txt where the pins are in force; --unpinned resolves from pyproject's ranges
    if _in_pinned_venv() is None:
        for commands in (main, tests):
            assert f" -c {CONSTRAINTS} " in _pip_install_of_the_project(commands), commands
    unpinned, _ = _dry_run(tmp_path, "--unpinned")
    assert " -c " not in _pip_install_of_the_project(unpinned), unpinned


def _key(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def test_constraints_pin_exact_versions_and_pyproject_keeps_ranges() -> None:
    from packaging.requirements import Requirement

    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib

    python, pins = _pins()
    assert "mi-svbrdf" not in pins, "constraints.txt: the project itself is not pinned (pip installs it editable)"
    assert "torch" in pins, "constraints.txt: torch is pinned (unpinned, pip would pull the newest CUDA build)"
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    extras = project["optional-dependencies"]
    for line in [*project["dependencies"], *extras["test"], *extras["dataset"]]:
        req = Requirement(line)
        assert not any(spec.operator in ("==", "===") for spec in req.specifier), \
            f"pyproject.toml: {line!r}: the library's requirements are ranges (the pins live in constraints.txt)"
        if req.marker is None or req.marker.evaluate({"python_version": python, "extra": ""}):
            assert _key(req.name) in pins, (f"constraints.txt: no pin for {req.name}, which pyproject.toml requires: "
                                            "regenerate it (docs/install.md, Moving the pins)")
    # the set-up's local-wheel probe looks for the pinned torch
    assert 'sed -n \'s/^torch==//p\' "$constraints"' in SETUP.read_text()


def test_the_venv_is_at_the_pins_of_everything_the_install_pulls_in() -> None:
    """Every distribution that mi_svbrdf with its test and dataset extras pulls in (transitively) is pinned, and
    installed at its pin: a venv that drifted from constraints.txt, or a new dependency left unpinned, fails."""
    from importlib import metadata

    from packaging.requirements import Requirement

    reason = _in_pinned_venv()
    if reason is not None:
        pytest.skip(reason)
    _, pins = _pins()
    seen: set[tuple[str, frozenset[str]]] = set()  # (distribution, the extras asked of it)
    todo = [(Requirement(r), {"", "test", "dataset"}) for r in metadata.requires("mi_svbrdf") or []]
    drift, unpinned = set(), set()
    while todo:
        req, extras = todo.pop()
        if req.marker is not None and not any(req.marker.evaluate({"extra": e}) for e in extras):
            continue
        key = _key(req.name)
        if (key, frozenset(req.extras)) in seen:
            continue
        seen.add((key, frozenset(req.extras)))
        try:
            have = metadata.version(req.name)
        except metadata.PackageNotFoundError:
            drift.add(f"{req.name} not installed")
            continue
        if key not in pins:
            unpinned.add(f"{req.name} {have}")
        elif have.split("+")[0] != pins[key]:
            drift.add(f"{req.name} {have} (pinned {pins[key]})")
        todo += [(Requirement(r), {"", *req.extras}) for r in metadata.requires(req.name) or []]
    assert len({key for key, _ in seen}) > 30, sorted(seen)
    assert not unpinned, (f"constraints.txt does not pin {', '.join(sorted(unpinned))}, which the install pulls in: "
                          "regenerate it (docs/install.md, Moving the pins)")
    assert not drift, (f"the venv differs from constraints.txt: {', '.join(sorted(drift))}; bash .ci/setup.sh --tests "
                       "moves it to the pins (or move the pins: docs/install.md)")


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
