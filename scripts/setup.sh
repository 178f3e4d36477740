#!/usr/bin/env bash
# Idempotent set-up: a shared libLLVM >= 16 for Dr.Jit's CPU backend, then .venv with scratchfab.
# Safe to run again; it only does what is missing. No prompts.
#   PYTHON=/path/to/python3.x   the interpreter for a new .venv (default: the newest of
#                               python3.13 python3.12 python3.11 python3 that is >= 3.11)
#   DRJIT_LIBLLVM_PATH=/path    a libLLVM of your own: the system library check is skipped
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
cd "$here"

# shellcheck source=scripts/llvm.sh
. "$here/scripts/llvm.sh"

llvm_hint="install libllvm19 (Debian/Ubuntu: sudo apt-get install libllvm19) or any shared \
libLLVM >= 16, set DRJIT_LIBLLVM_PATH to it if it is not in /usr/lib, and run this again"

install_llvm() {
    local sudo_cmd=""
    echo "setup: no shared libLLVM >= 16 found; installing Debian's libllvm19 (Dr.Jit's CPU backend needs it)"
    if ! command -v apt-get >/dev/null 2>&1; then
        echo "setup: apt-get is not available here; $llvm_hint" >&2
        return 1
    fi
    if [ "$(id -u)" -ne 0 ]; then
        if ! command -v sudo >/dev/null 2>&1 || ! sudo -n true 2>/dev/null; then
            echo "setup: installing libllvm19 needs root and sudo cannot run without a password; $llvm_hint" >&2
            return 1
        fi
        sudo_cmd="sudo -n"
    fi
    if ! $sudo_cmd apt-get update -qq ||
        ! $sudo_cmd env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 ||
        ! have_llvm; then
        echo "setup: apt-get could not install libllvm19; $llvm_hint" >&2
        return 1
    fi
}

# The first usable interpreter: $PYTHON if set, else the newest python3.x >= 3.11.
pick_python() {
    local cand version found=""
    if [ -n "${PYTHON:-}" ]; then set -- "$PYTHON"; else set -- python3.13 python3.12 python3.11 python3; fi
    for cand in "$@"; do
        command -v "$cand" >/dev/null 2>&1 || continue
        # pyenv shims exist for versions that are not selected and fail when run.
        if ! version="$("$cand" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null)" ||
            ! [[ "$version" =~ ^([0-9]+)\.([0-9]+)$ ]]; then
            found="$found, $cand (does not run)"
        elif [ "${BASH_REMATCH[1]}" -gt 3 ] || { [ "${BASH_REMATCH[1]}" -eq 3 ] && [ "${BASH_REMATCH[2]}" -ge 11 ]; }; then
            echo "$cand"
            return 0
        else
            found="$found, $cand $version"
        fi
    done
    if [ -n "$found" ]; then found="${found#, }"; else found="none of $*"; fi
    echo "setup: scratchfab needs Python >= 3.11; found $found; set PYTHON to a Python 3.11 or newer" >&2
    return 1
}

if [ -n "${DRJIT_LIBLLVM_PATH:-}" ] && [ -f "$DRJIT_LIBLLVM_PATH" ]; then
    :
elif ! have_llvm; then
    install_llvm || exit 1
fi

stamp=".venv/.scratchfab-installed"
# The version is read from scratchfab/__init__.py into the installed metadata.
want="$(cat pyproject.toml scratchfab/__init__.py | sha256sum | cut -c1-16)"
have=""
if [ -f "$stamp" ]; then read -r have <"$stamp" || true; fi
# The stamp lives in .venv and is written only after a good venv took the install.
if [ "$have" = "$want" ] && [ -x .venv/bin/python ]; then
    exit 0
fi
if [ -e .venv ]; then
    if ! .venv/bin/python -c 'import sys, pip; assert sys.version_info >= (3, 11)' 2>/dev/null; then
        echo "setup: .venv has no working Python >= 3.11 with pip; recreating it"
        py="$(pick_python)" || exit 1
        "$py" -m venv --clear .venv
    fi
else
    py="$(pick_python)" || exit 1
    "$py" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[dev]"
echo "$want" >"$stamp"
