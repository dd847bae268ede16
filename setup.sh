#!/usr/bin/env bash
# Set up gibench in .venv/ at the repository root (idempotent; quick when done).
#  - on Debian, installs libllvm19 when no libLLVM >= 17 is present: Mitsuba's
#    LLVM variant needs it (Dr.Jit aborts with libLLVM 14/15/16); without it the
#    references fall back to the slow scalar_rgb variant, with a warning;
#  - creates .venv with Python 3.11 and installs gibench with its test extras.
set -euo pipefail
cd "$(dirname "$0")"

have_llvm17() {
    for f in /usr/lib/*-linux-gnu/libLLVM*.so* /usr/lib/llvm-*/lib/libLLVM*.so* /usr/lib/libLLVM*.so* /usr/local/lib/libLLVM*.so*; do
        [ -e "$f" ] || continue
        v=$(basename "$f" | sed -nE 's/^libLLVM-?([0-9]+).*/\1/p')
        [ -n "$v" ] && [ "$v" -ge 17 ] && return 0
    done
    return 1
}

if ! have_llvm17; then
    if command -v apt-get >/dev/null 2>&1; then
        SUDO=""
        [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
        if [ "$(id -u)" -eq 0 ] || [ -n "$SUDO" ]; then
            echo "setup: installing Debian's libllvm19 for Mitsuba's LLVM variant"
            $SUDO apt-get update -qq
            DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libllvm19 >/dev/null
        else
            echo "setup: warning: no libLLVM >= 17 and no root to install libllvm19; references will use scalar_rgb" >&2
        fi
    else
        echo "setup: warning: no libLLVM >= 17 found (not Debian); references will use scalar_rgb" >&2
    fi
fi

PY=""
for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
        PY="$cand"; break
    fi
done
[ -n "$PY" ] || { echo "setup: error: Python 3.11 is required (python3.11 not found)" >&2; exit 2; }

[ -x .venv/bin/python ] || "$PY" -m venv .venv
stamp=.venv/.gibench-installed
want=$(sha256sum pyproject.toml | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    echo "setup: installing Python packages into .venv"
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[test]"
    echo "$want" > "$stamp"
fi
echo "setup: ready (.venv/bin/gibench)"
