#!/usr/bin/env bash
# Set up shinysim in ./.venv: Python packages (with the renderer and test
# tools) at the versions of requirements/constraints.txt (the lock; refreshed by
# scripts/lock.sh) and, where possible, the LLVM library Mitsuba's fast CPU
# variants need.
set -euo pipefail
cd "$(dirname "$0")/.."

PY="${PYTHON:-python3.11}"
command -v "$PY" >/dev/null || PY=python3

# Mitsuba's llvm_* variants need an LLVM that drjit 1.5 accepts; on Debian 12
# that is the libllvm19 package (libLLVM 14/15 do not work).
have_llvm19() { ldconfig -p 2>/dev/null | grep -q 'libLLVM\.so\.19\|libLLVM-19'; }
if ! have_llvm19; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "setup: installing Debian's libllvm19 for Mitsuba's LLVM variants"
        if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19; } >/dev/null 2>&1; then
            echo "setup: libllvm19 could not be installed; Mitsuba will fall back to its scalar variants (slow), and tests that need a JIT variant will skip"
        fi
    else
        echo "setup: libllvm19 not found and cannot be installed here (needs root and apt);"
        echo "setup: Mitsuba will use its scalar variants (slow) unless an LLVM that drjit accepts is present"
    fi
fi

if [ ! -x .venv/bin/python ]; then
    "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e '.[all]' -c requirements/constraints.txt
.venv/bin/python - <<'PY'
try:
    from shinysim.sim.variants import choose_variant
    print("setup:", choose_variant()[1])
except Exception as exc:  # the reconstruction half works without a renderer
    print("setup: renderer not usable:", exc)
PY
