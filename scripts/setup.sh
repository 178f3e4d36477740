#!/usr/bin/env bash
# Idempotent set-up: a shared libLLVM >= 16 for Dr.Jit's CPU backend, then .venv with scratchfab.
# Safe to run again; it only does what is missing. No prompts.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
cd "$here"

# shellcheck source=scripts/llvm.sh
. "$here/scripts/llvm.sh"

if ! have_llvm; then
    echo "setup: no shared libLLVM >= 16 found; installing Debian's libllvm19 (Dr.Jit's CPU backend needs it)"
    if command -v apt-get >/dev/null 2>&1; then
        sudo_cmd=""
        [ "$(id -u)" -eq 0 ] || sudo_cmd="sudo -n"
        $sudo_cmd apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq libllvm19
    else
        echo "setup: apt-get not available; install libLLVM 16+ yourself and set DRJIT_LIBLLVM_PATH" >&2
        exit 1
    fi
fi

py="${PYTHON:-python3}"
stamp=".venv/.scratchfab-installed"
want="$(cat pyproject.toml | sha256sum | cut -c1-16)"
if [ ! -x .venv/bin/python ]; then
    "$py" -m venv .venv
fi
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[dev]"
    echo "$want" > "$stamp"
fi
