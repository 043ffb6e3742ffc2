#!/usr/bin/env bash
# Install mi_svbrdf into the project's virtual environment: what the main job needs, or with --tests also what
# the test suite needs.
#
#   bash .ci/setup.sh            the main job (mi-svbrdf capture, optimize, ...): libllvm19 (apt, when missing), the
#                                venv, mi_svbrdf (editable) and its dependencies
#   bash .ci/setup.sh --tests    the same, then what the tests need: the test and dataset extras (pytest, nbclient,
#                                ipykernel, pygltflib; ray, isal), chromium (apt, when missing) and the two real tools
#                                the export tests open their outputs with (4. and 5. below)
#   --dry-run                    print what would be installed (each installing command as "would run: ..."),
#                                install nothing
#   --unpinned                   resolve from pyproject.toml's ranges without constraints.txt (to move the pins:
#                                docs/install.md, "Moving the pins")
#
# Versions: pip installs with -c constraints.txt (beside pyproject.toml), the exact versions the suite last passed
# with, when the venv's Python is the one the pins were made on (its "# python: X.Y" line); another Python resolves
# from pyproject.toml's ranges, with a note. A torch of another version already in the venv is kept: the pins of
# torch and of its own requirements are then left out, with a note.
#
# The environment: `.venv` in the clone (MI_SVBRDF_VENV=DIR: another one, relative to the current
# folder), created with `python3` (MI_SVBRDF_PYTHON=PY: another interpreter, Python >= 3.10) when it
# does not exist, reused when it does (the torch installed in it is kept). Nothing is ever installed
# into a Python that is not a virtual environment: Debian's system Python is externally managed
# (PEP 668) and a global pyenv is shared with other projects. A MI_SVBRDF_VENV that exists but is not
# a venv is refused before anything is installed. Enter the environment with `. .venv/bin/activate`
# (the README's commands do).
#
# With apt (sudo when not root), only what is missing:
# 1. libllvm19: Dr.Jit's LLVM backend needs a recent libLLVM: with Debian's LLVM 14/15 `dr.maximum`
#    aborts ("Cannot select fmaximum"). Dr.Jit dlopen()s libLLVM from the system's library folders
#    (/usr/lib/<arch>/libLLVM*.so.*, or DRJIT_LIBLLVM_PATH), never from Python's, so the venv sees it;
#    the last step prints the version Dr.Jit found and stops on 15 or older.
# 2. chromium (--tests only): the viewer's test draws the page in a real browser (the test skips where it is missing).
# 3. python3 and python3-venv: when there is no python3, or it cannot create a venv (Debian ships
#    venv's ensurepip in python3-venv).
# Test tools (--tests only; MI_SVBRDF_TEST_TOOLS=0 skips both; a failure prints a note and the set-up goes on,
# the tests that need a tool then skip with the reason):
# 4. Blender as a Python module (PyPI's bpy 4.5 LTS, about 950 MB) in its own venv .venv-blender
#    (MI_SVBRDF_BLENDER_VENV=DIR: another one): the Blender export's test runs the exported script in it
#    and renders with Cycles. bpy 4.5 has wheels for Python 3.11 only: created with python3.11
#    (MI_SVBRDF_BLENDER_PYTHON=PY: another interpreter). Kept when bpy already imports in it.
# 5. the Khronos glTF validator (npm's gltf-validator) in .tools/ (npm install --prefix .tools;
#    MI_SVBRDF_TOOLS=DIR: another folder): the glTF export's test validates the written files with it.
# PyTorch: a torch already in the venv is kept. Otherwise, where pip can find a local CPU wheel of the
# pinned torch (constraints.txt: 2.13.0; e.g. through PIP_FIND_LINKS) that one is used; elsewhere pip installs the pinned torch
# from the index (on Linux PyPI's is the CUDA build; GPU users, and CPU users who want the small build,
# install their torch build into the venv first: docs/install.md, "PyTorch").
set -euo pipefail
caller_pwd="$PWD"
cd "$(dirname "$0")/.."
root="$PWD"

say() { echo "[setup] $*"; }
die() { echo "[setup] error: $*" >&2; exit 2; }

# --- the arguments: checked before anything is installed --------------------------------------------
tests=0 dry=0 unpinned=0
for arg in "$@"; do
    case "$arg" in
        --tests) tests=1 ;;
        --dry-run) dry=1 ;;
        --unpinned) unpinned=1 ;;
        -h|--help) sed -n '2,/^set -euo/{/^set -euo/d;s/^# \{0,1\}//;p}' "$root/.ci/$(basename "${BASH_SOURCE[0]}")"; exit 0 ;;
        *) die "unknown argument '$arg': expected none (the main job's set-up), --tests (also what the tests need), --dry-run or --unpinned" ;;
    esac
done
# the pins (constraints.txt beside pyproject.toml)
constraints="$root/constraints.txt"
[ -f "$constraints" ] || die "$constraints is missing: it pins the versions the suite passed with (git checkout constraints.txt)"
pinned_python="$(sed -n 's/^# python: *//p' "$constraints")"
[ -n "$pinned_python" ] || die "$constraints: expected a '# python: X.Y' line (the Python the pins were made on)"
torch_pin="$(sed -n 's/^torch==//p' "$constraints")"
[ -n "$torch_pin" ] || die "$constraints: expected a torch==VERSION line"
# run CMD...: an installing command, or with --dry-run only its line
run() { if [ "$dry" = 1 ]; then say "would run: $*"; else "$@"; fi; }
run_quiet() { if [ "$dry" = 1 ]; then say "would run: $*"; else "$@" >/dev/null 2>&1; fi; }

# --- the environment: checked before anything is installed -----------------------------------------
venv="${MI_SVBRDF_VENV:-.venv}"
case "$venv" in
    /*) ;;
    *) if [ -n "${MI_SVBRDF_VENV:-}" ]; then venv="$caller_pwd/$venv"; else venv="$root/$venv"; fi ;;
esac
venv_python="$venv/bin/python"
real() { if [ -d "$1" ]; then (cd "$1" && pwd -P); else echo "$1"; fi; }
create=0
if [ -e "$venv" ] && [ -n "$(ls -A "$venv" 2>/dev/null)" ]; then
    if [ ! -f "$venv/pyvenv.cfg" ]; then
        die "$venv exists but is not a Python virtual environment (no pyvenv.cfg): refusing to install into it.
  Remove it, or point MI_SVBRDF_VENV at a venv or a new folder:  MI_SVBRDF_VENV=\$HOME/venvs/mi_svbrdf bash .ci/setup.sh"
    fi
    if ! "$venv_python" -c 'import sys; sys.exit(sys.prefix == sys.base_prefix)' >/dev/null 2>&1; then
        die "$venv has a pyvenv.cfg but its bin/python does not run as a venv (was its base Python removed?):
  remove it (rm -rf $venv) and rerun"
    fi
    if ! "$venv_python" -c 'import sys; sys.exit(sys.version_info < (3, 10))' >/dev/null 2>&1; then
        die "$venv has Python $("$venv_python" -c 'import platform; print(platform.python_version())'); mi_svbrdf needs >= 3.10:
  remove it (rm -rf $venv) and rerun with MI_SVBRDF_PYTHON=python3.11 (or another >= 3.10)"
    fi
else
    create=1
fi
if [ -n "${VIRTUAL_ENV:-}" ] && [ "$(real "$VIRTUAL_ENV")" != "$(real "$venv")" ]; then
    say "note: the active environment $VIRTUAL_ENV is left alone; installing into $venv (MI_SVBRDF_VENV=\$VIRTUAL_ENV uses it)"
fi

python="${MI_SVBRDF_PYTHON:-python3}"
if [ "$create" = 1 ] && [ -n "${MI_SVBRDF_PYTHON:-}" ]; then
    command -v "$python" >/dev/null 2>&1 || die "MI_SVBRDF_PYTHON=$python: no such command"
    "$python" -c 'import sys; sys.exit(sys.version_info < (3, 10))' >/dev/null 2>&1 \
        || die "MI_SVBRDF_PYTHON=$python: expected Python >= 3.10, got $("$python" --version 2>&1 || echo 'an interpreter that does not run')"
fi

# --- system packages ----------------------------------------------------------------------------------
APT_PACKAGES=()
# grep reads all of ldconfig's output (no -q): with pipefail an early exit's SIGPIPE to ldconfig read as "missing"
if ! ldconfig -p 2>/dev/null | grep "libLLVM.so.19\|libLLVM-19" >/dev/null; then APT_PACKAGES+=(libllvm19); fi
if [ "$tests" = 1 ] && ! command -v chromium >/dev/null 2>&1; then APT_PACKAGES+=(chromium); fi
if [ "$create" = 1 ]; then
    if ! command -v "$python" >/dev/null 2>&1; then
        APT_PACKAGES+=(python3 python3-venv)
    elif ! "$python" -c 'import ensurepip, venv' >/dev/null 2>&1 \
        && [[ "$(command -v "$python")" == /usr/bin/python3* ]]; then
        APT_PACKAGES+=(python3-venv)
    fi
fi
if [ "${#APT_PACKAGES[@]}" -gt 0 ]; then
    if command -v apt-get >/dev/null 2>&1; then
        SUDO=""
        if [ "$(id -u)" -ne 0 ]; then
            command -v sudo >/dev/null 2>&1 \
                || die "needs ${APT_PACKAGES[*]}: run as root, or first: apt-get install -y ${APT_PACKAGES[*]}"
            SUDO="sudo"
        fi
        say "installing ${APT_PACKAGES[*]} with apt (libllvm19: Dr.Jit's LLVM backend; chromium: the viewer's browser test; python3-venv: the project venv)"
        run $SUDO apt-get update -qq
        run_quiet $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${APT_PACKAGES[@]}"
    else
        say "note: no apt-get: not installing ${APT_PACKAGES[*]} (install the equivalents yourself)"
    fi
fi

# --- the venv -----------------------------------------------------------------------------------------
if [ "$create" = 1 ]; then
    command -v "$python" >/dev/null 2>&1 || die "no $python: install Python >= 3.10 or set MI_SVBRDF_PYTHON"
    "$python" -c 'import sys; sys.exit(sys.version_info < (3, 10))' \
        || die "$python is Python $("$python" -c 'import platform; print(platform.python_version())'); mi_svbrdf needs >= 3.10: set MI_SVBRDF_PYTHON=python3.11 (or another >= 3.10)"
    "$python" -c 'import ensurepip, venv' >/dev/null 2>&1 \
        || die "$python cannot create a virtual environment (no ensurepip): install python3-venv (Debian, Ubuntu) or set MI_SVBRDF_PYTHON to a Python >= 3.10 that can"
    say "creating the virtual environment $venv with $python ($("$python" -c 'import platform; print(platform.python_version())'))"
    run "$python" -m venv "$venv"
fi
pip=("$venv_python" -m pip)
if [ "$tests" = 1 ]; then spec=".[test,dataset]"; what="mi_svbrdf, its dependencies and the test and dataset extras"
else spec="."; what="mi_svbrdf and its dependencies (the main job's; --tests adds what the tests need)"; fi

# --- the pins: constraints.txt where the venv's Python is the one they were made on --------------------
venv_or_base="$venv_python"; [ -x "$venv_python" ] || venv_or_base="$python"
this_python="$("$venv_or_base" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
pin=()
if [ "$unpinned" = 1 ]; then
    say "--unpinned: resolving from pyproject.toml's ranges, without $constraints"
elif [ "$this_python" != "$pinned_python" ]; then
    say "note: $constraints pins the versions tested on Python $pinned_python; $venv has Python $this_python: resolving from pyproject.toml's ranges"
else
    pin=(-c "$constraints")
    pinned_what="versions of constraints.txt"
    if [ -x "$venv_python" ] && "$venv_python" -c "import torch" >/dev/null 2>&1; then
        # a torch of another version in the venv is kept: leave out the pins of torch and of its requirements
        kept="$(mktemp)"
        trap 'rm -f "$kept"' EXIT
        note="$("$venv_python" - "$constraints" "$kept" <<'EOF'
import re, sys
from importlib import metadata

def key(name):
    return re.sub(r"[-_.]+", "-", name).lower()

src, dst = sys.argv[1:3]
lines = open(src, encoding="utf-8").read().splitlines()
pins = {key(line.split("==")[0]): line.split("==")[1] for line in lines if "==" in line and not line.startswith("#")}
have = metadata.version("torch")
if have.split("+")[0] == pins.get("torch"):
    sys.exit(0)
drop = {"torch"} | {key(re.match(r"[A-Za-z0-9._-]+", r).group(0)) for r in metadata.requires("torch") or []}
with open(dst, "w", encoding="utf-8") as out:
    out.write("\n".join(line for line in lines if line.startswith("#") or key(line.split("==")[0]) not in drop) + "\n")
print(f"keeping torch {have} of the venv (constraints.txt pins {pins.get('torch')}): not pinning "
      + ", ".join(sorted(drop & set(pins))))
EOF
)"
        if [ -n "$note" ]; then say "note: $note"; pin=(-c "$kept"); pinned_what="versions of constraints.txt but torch's"; fi
    fi
fi
say "installing $what into $venv with pip${pin:+ ($pinned_what)} (a few minutes the first time)"

if ! "$venv_python" -c "import torch" >/dev/null 2>&1; then
    probe="$(mktemp -d)"
    if "$venv_or_base" -m pip download --no-index --no-deps "torch==$torch_pin" -d "$probe" >/dev/null 2>&1; then
        say "using the local CPU wheel of torch $torch_pin"
        run "${pip[@]}" install -q "${pin[@]}" "torch==$torch_pin"
    fi
    rm -rf "$probe"
fi

run "${pip[@]}" install -q "${pin[@]}" -e "$spec"

# --- what was installed, and the libLLVM Dr.Jit found ---------------------------------------------
[ "$dry" = 1 ] || "$venv_python" - "$venv" <<'EOF'
import platform, sys
import drjit as dr, mitsuba as mi, torch
import mi_svbrdf
llvm = ""
if mi.variant().startswith("llvm"):
    version = dr.detail.llvm_version()
    llvm = f", LLVM {'.'.join(map(str, version))}"
    if version[0] <= 15:
        sys.exit(f"[setup] error: Dr.Jit found LLVM {version[0]}, with which dr.maximum aborts: install "
                 "libllvm19 (apt-get install libllvm19) or set DRJIT_LIBLLVM_PATH to a libLLVM >= 16")
print(f"[setup] mi_svbrdf {mi_svbrdf.__version__} installed in {sys.argv[1]} (Python {platform.python_version()}, "
      f"torch {torch.__version__}, Mitsuba variant {mi.variant()}{llvm})")
EOF
# --- the tests' tools (--tests): Blender (bpy) and the glTF validator; never fail the set-up --------------
abs_path() { case "$1" in /*) echo "$1" ;; *) echo "$caller_pwd/$1" ;; esac; }
if [ "$tests" = 1 ] && [ "${MI_SVBRDF_TEST_TOOLS:-1}" = 0 ]; then
    say "MI_SVBRDF_TEST_TOOLS=0: not installing Blender's bpy nor the glTF validator (their tests skip)"
elif [ "$tests" = 1 ]; then
    blender_venv="$root/.venv-blender"
    if [ -n "${MI_SVBRDF_BLENDER_VENV:-}" ]; then blender_venv="$(abs_path "$MI_SVBRDF_BLENDER_VENV")"; fi
    blender_python="${MI_SVBRDF_BLENDER_PYTHON:-python3.11}"
    if "$blender_venv/bin/python" -c "import bpy" >/dev/null 2>&1; then
        say "Blender: bpy $("$blender_venv/bin/python" -c 'import bpy; print(bpy.app.version_string)' 2>/dev/null) in $blender_venv (kept)"
    elif ! command -v "$blender_python" >/dev/null 2>&1 \
        || ! "$blender_python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1; then
        say "note: no Python 3.11 ($blender_python) for Blender's bpy 4.5: the Blender render test will skip (MI_SVBRDF_BLENDER_PYTHON=PY names one)"
    elif say "installing Blender as a Python module (bpy 4.5, about 950 MB) into $blender_venv for the Blender export's test" \
        && { [ -f "$blender_venv/pyvenv.cfg" ] || run_quiet "$blender_python" -m venv "$blender_venv"; } \
        && run "$blender_venv/bin/python" -m pip install -q "bpy==4.5.*" \
        && { [ "$dry" = 1 ] || "$blender_venv/bin/python" -c "import bpy" >/dev/null 2>&1; }; then
        [ "$dry" = 1 ] || say "Blender: bpy $("$blender_venv/bin/python" -c 'import bpy; print(bpy.app.version_string)' 2>/dev/null) in $blender_venv"
    else
        say "note: could not install bpy 4.5 into $blender_venv: the Blender render test will skip"
    fi
    tools="$root/.tools"
    if [ -n "${MI_SVBRDF_TOOLS:-}" ]; then tools="$(abs_path "$MI_SVBRDF_TOOLS")"; fi
    if [ -f "$tools/node_modules/gltf-validator/package.json" ]; then
        say "glTF validator: $tools/node_modules/gltf-validator (kept)"
    elif ! command -v npm >/dev/null 2>&1 || ! command -v node >/dev/null 2>&1; then
        say "note: no node/npm: the glTF validator test will skip (Debian: apt-get install nodejs npm)"
    elif say "installing the Khronos glTF validator (npm gltf-validator) into $tools" \
        && run_quiet npm install --prefix "$tools" --no-audit --no-fund --silent gltf-validator@2.0.0-dev.3.10; then
        [ "$dry" = 1 ] || say "glTF validator: $tools/node_modules/gltf-validator"
    else
        say "note: npm could not install gltf-validator into $tools: the glTF validator test will skip"
    fi
fi
if [ "$tests" = 0 ]; then
    say "$([ "$dry" = 1 ] && echo "would install" || echo "installed") what the main job needs; what the tests need comes with: bash .ci/setup.sh --tests"
fi
if [ "$dry" = 1 ]; then
    say "--dry-run: nothing was installed"
    exit 0
fi
if [ "$venv" = "$root/.venv" ]; then
    say "enter it with: . .venv/bin/activate"
else
    say "enter it with: . $venv/bin/activate"
fi
