#!/usr/bin/env bash
# Set up gibench in .venv/ at the repository root (idempotent; quick when done).
#  - on Debian, installs libllvm19 when no libLLVM >= 17 is present: Mitsuba's
#    LLVM variant needs it (Dr.Jit aborts with libLLVM 14/15/16); without it the
#    references fall back to the slow scalar_rgb variant, with a warning;
#  - on Debian, installs Mesa's EGL (libegl1) when no libEGL is present: `gibench view`
#    draws off screen through VTK's EGL window (no X server needed);
#  - on Debian, installs Chromium when no chromium is on PATH, so tests/test_browser.py
#    (the report and its image viewer in a real browser) runs instead of skipping;
#    GIBENCH_NO_CHROMIUM=1 skips it;
#  - creates .venv with Python 3.11 and installs gibench with its test extras;
#  - compiles the numba kernels the default, ci and hard suites need and the tracers'
#    kernel variants (`gibench warmup`), so a fresh clone's first render loads them from
#    .numba_cache/ instead of compiling;
#    GIBENCH_SKIP_WARMUP=1 skips it.
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

# Debian packages installed with apt-get when root (or sudo) is there; a warning otherwise.
apt_install() {   # apt_install WHAT PACKAGE...
    local what=$1; shift
    command -v apt-get >/dev/null 2>&1 || { echo "setup: warning: $what missing and no apt-get" >&2; return 0; }
    local SUDO=""
    [ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO="sudo"
    if [ "$(id -u)" -ne 0 ] && [ -z "$SUDO" ]; then
        echo "setup: warning: $what missing and no root to install $*" >&2; return 0
    fi
    echo "setup: installing Debian's $* ($what)"
    [ -n "${APT_UPDATED:-}" ] || { $SUDO apt-get update -qq; APT_UPDATED=1; }
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$@" >/dev/null \
        || echo "setup: warning: could not install $*" >&2
}

if ! ldconfig -p 2>/dev/null | grep -q 'libEGL\.so\.1'; then
    apt_install "EGL for off-screen 3D views" libegl1 libegl-mesa0 libgl1-mesa-dri
fi
if [ -z "${GIBENCH_NO_CHROMIUM:-}" ] && ! command -v chromium >/dev/null 2>&1 \
        && ! command -v chromium-browser >/dev/null 2>&1; then
    apt_install "a headless browser for tests/test_browser.py" chromium
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
if [ -z "${GIBENCH_SKIP_WARMUP:-}" ]; then
    echo "setup: compiling the numba kernels of the default, ci and hard suites (gibench warmup)"
    .venv/bin/python -m gibench.cli warmup default ci hard --jobs 2 | tail -1 \
        || echo "setup: warning: warm-up failed; the first renders will compile instead" >&2
fi
echo "setup: ready (.venv/bin/gibench)"
