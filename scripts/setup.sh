#!/usr/bin/env bash
# Create (or update) the project's virtual environment in .venv and install the package
# with its test and detector extras. Safe to run again: pip skips what is satisfied.
# --test: also the cluster extra (Ray, for the cluster tests) and Debian's Chromium for the
# teleop page's browser test.
set -euo pipefail
cd "$(dirname "$0")/.."

pick_python() {
    for py in python3.11 python3.12 python3.13 python3; do
        if command -v "$py" >/dev/null 2>&1 &&
           "$py" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' 2>/dev/null; then
            echo "$py"; return 0
        fi
    done
    echo "rosmeery setup: Python >= 3.11 is required and none was found on PATH" >&2
    return 1
}

if [ ! -x .venv/bin/python ]; then
    "$(pick_python)" -m venv .venv
fi
extras="test,detector"
if [ "${1:-}" = "--test" ]; then extras="$extras,cluster"; fi
stamp=".venv/.rosmeery-installed-${extras//,/-}"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
    .venv/bin/python -m pip install --quiet --upgrade pip
    # torch pinned here too, so no resolver path can reach a newer, CUDA-laden build.
    # --no-compile: Python compiles the modules it imports when first imported, instead of
    # pip compiling every file of every package up front (65 s instead of 99 s here).
    .venv/bin/python -m pip install --quiet --no-compile -e ".[$extras]" "torch==2.13.0"
    if [ -n "${PYTHONDONTWRITEBYTECODE:-}" ]; then
        # Python writes no bytecode here, so every process would compile again from source
        # the modules it imports (the command line: 17.6 s instead of 5.5 s on a 2-core
        # Xeon): those of a session, of training and of the tests compiled once, now
        # (about 40 s; compileall writes bytecode whatever the variable says). Only a
        # speed-up: a failure here stops nothing.
        .venv/bin/python -c 'import os, sys, pytest, hypothesis, rosmeery_jax.apps.cli, rosmeery_jax.session.runner
import rosmeery_jax.detector.yolo, rosmeery_jax.detector.runtime, rosmeery_jax.rl.ppo
files = (getattr(m, "__file__", None) or "" for m in list(sys.modules.values()))
print("\n".join(sorted(f for f in files if os.path.isabs(f) and f.endswith(".py"))))' |
            .venv/bin/python -m compileall -q -j 0 -i - >/dev/null 2>&1 || true
    fi
    touch "$stamp"
fi

if [ "${1:-}" = "--test" ] && ! command -v chromium >/dev/null 2>&1; then
    # Playwright drives the system Chromium (its own browser download is not reachable).
    if [ "$(id -u)" = "0" ]; then sudo=""; elif command -v sudo >/dev/null 2>&1; then sudo="sudo -n"; else sudo="none"; fi
    if [ "$sudo" != "none" ] && command -v apt-get >/dev/null 2>&1 &&
       { $sudo apt-get install -y -qq chromium >/dev/null 2>&1 ||
         { $sudo apt-get update -qq >/dev/null 2>&1 && $sudo apt-get install -y -qq chromium >/dev/null 2>&1; }; }; then
        echo "rosmeery setup: installed Chromium for the browser test"
    else
        echo "rosmeery setup: WARNING: could not install Chromium (apt-get as root); the teleop browser test will be skipped" >&2
    fi
fi
