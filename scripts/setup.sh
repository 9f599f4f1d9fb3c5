#!/usr/bin/env bash
# Installs everything camval needs on a fresh Debian 12 machine of this kind:
# uv (with pip, if missing), the Debian packages of the renderers and the
# report check, and the locked Python environment.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v uv >/dev/null 2>&1; then
    python3 -m pip install --quiet uv || pip install --quiet uv
fi
need=()
command -v povray >/dev/null 2>&1 || need+=(povray)
[ -e /usr/lib/x86_64-linux-gnu/libOSMesa.so.8 ] || ls /usr/lib/*/libOSMesa.so* >/dev/null 2>&1 || need+=(libosmesa6)
command -v chromium >/dev/null 2>&1 || need+=(chromium)
if [ ${#need[@]} -gt 0 ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "camval setup: installing Debian packages: ${need[*]}" >&2
        (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null) \
            || echo "camval setup: could not install ${need[*]}; the tests of those renderers will skip with the reason" >&2
    else
        echo "camval setup: missing Debian packages ${need[*]} (run as root: apt-get install ${need[*]})" >&2
    fi
fi
# --compile-bytecode: the environment sets PYTHONDONTWRITEBYTECODE, so without .pyc files every
# process (each campaign worker, each test subprocess) would compile numba, scipy... again (~3 s)
uv sync --frozen --quiet --compile-bytecode
# numba's kernels, compiled once as an install step (as --compile-bytecode does for .pyc): into
# numba's cache (__pycache__ beside the sources, or NUMBA_CACHE_DIR), on two cores. A fresh
# clone's first campaign then loads them (~60 CPU s of compilation otherwise, before the workers
# start); when the cache is current this only reads numba's cache index (~3 s).
uv run --frozen camval warm-up campaigns/paper.toml campaigns/quick.toml \
    || echo "camval setup: the numba warm-up failed; campaigns compile their kernels on first use" >&2
