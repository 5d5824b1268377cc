#!/usr/bin/env bash
# One-time set-up on a fresh machine: a virtual environment with ppd and its dependencies,
# the system tools the tests use, and LPIPS weights converted into the user's cache.
# Re-running is cheap: each step is skipped when already done.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${PPD_VENV:-.venv}
PYTHON=${PYTHON:-$(command -v python3.11 || command -v python3)}

if [ ! -x "$VENV/bin/python" ]; then
    "$PYTHON" -m venv "$VENV"
fi

stamp="$VENV/.ppd-installed"
want=$( (cat pyproject.toml setup.py poisoner/_jpeg_entropy.c poisoner/_scene_filter.c scripts/setup.sh; echo "bench=${PPD_SETUP_BENCH:-0}") | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
    "$VENV/bin/python" -m pip install -q --upgrade pip
    # The build backend in the venv itself: scripts/wheel_smoke.sh builds the wheel without
    # isolation (no download in CI); >= 77 reads pyproject's SPDX `license`.
    "$VENV/bin/python" -m pip install -q "setuptools>=77"
    # The CPU wheel first and pinned: an unpinned torch pulls gigabytes of CUDA packages.
    "$VENV/bin/python" -m pip install -q torch==2.13.0
    extras=dev
    [ "${PPD_SETUP_BENCH:-0}" = 1 ] && extras=dev,bench
    "$VENV/bin/python" -m pip install -q -e ".[$extras]"
    echo "$want" > "$stamp"
fi

# System tools, installed only when missing and only when we may (root, apt):
# - jpegtran (libjpeg-turbo-progs): the lossless JPEG splice that leaves every DCT block outside
#   the patch untouched; without it ppd falls back to a same-tables re-encode and says so.
# - systemd-analyze: the tests verify the user unit with it.
# - ImageMagick's composite: only the benchmarks compare against it (PPD_SETUP_BENCH=1).
need=()
command -v jpegtran >/dev/null 2>&1 || need+=(libjpeg-turbo-progs)
# libturbojpeg: the in-process coefficient pass (poisoner/jpeg_turbo.py); without it, jpegtran's path.
ldconfig -p 2>/dev/null | grep -q 'libturbojpeg\.so\.0' || need+=(libturbojpeg0)
command -v systemd-analyze >/dev/null 2>&1 || need+=(systemd)
if [ "${PPD_SETUP_BENCH:-0}" = 1 ]; then
    [ -x /usr/bin/composite ] || need+=(imagemagick)
fi
if [ ${#need[@]} -gt 0 ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}") >/dev/null \
        || echo "setup: could not install ${need[*]} (tests that need them will skip)" >&2
fi

# Optional post-install steps registered by the package (e.g. LPIPS weights); each is idempotent.
for step in scripts/setup.d/*.sh; do
    [ -e "$step" ] && VENV="$VENV" bash "$step"
done
exit 0
