#!/usr/bin/env bash
# Install mi_svbrdf (editable, with the test and dataset extras) into the active Python environment.
#
# 1. Dr.Jit's LLVM backend needs a recent libLLVM: with Debian's LLVM 14/15 `dr.maximum`
#    aborts ("Cannot select fmaximum"); Debian's libllvm19 works and Dr.Jit picks it up.
# 2. PyTorch: an installed torch is kept. Otherwise, where pip can find a local CPU wheel of
#    torch 2.13.0 (e.g. through PIP_FIND_LINKS) that one is used; elsewhere pip resolves
#    `torch>=2.1` from pyproject.toml as usual (nothing is forced on other machines).
set -euo pipefail
cd "$(dirname "$0")/.."

# 3. The viewer's test draws the page in a real browser: Debian's chromium (skipped where missing).
APT_PACKAGES=()
if ! ldconfig -p 2>/dev/null | grep -q "libLLVM.so.19\|libLLVM-19"; then APT_PACKAGES+=(libllvm19); fi
if ! command -v chromium >/dev/null 2>&1; then APT_PACKAGES+=(chromium); fi
if command -v apt-get >/dev/null 2>&1 && [ "${#APT_PACKAGES[@]}" -gt 0 ]; then
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    echo "[setup] installing ${APT_PACKAGES[*]} (libllvm19: Dr.Jit's LLVM backend; chromium: the viewer's browser test)"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${APT_PACKAGES[@]}" >/dev/null
fi

if ! python -c "import torch" >/dev/null 2>&1; then
    probe="$(mktemp -d)"
    if pip download --no-index --no-deps "torch==2.13.0" -d "$probe" >/dev/null 2>&1; then
        echo "[setup] using the local CPU wheel of torch 2.13.0"
        pip install -q "torch==2.13.0"
    fi
    rm -rf "$probe"
fi

pip install -q -e ".[test,dataset]"
echo "[setup] mi_svbrdf installed: $(python -c 'import mi_svbrdf, mitsuba as mi; print(mi_svbrdf.__version__, mi.variant())')"
