#!/usr/bin/env bash
# LPIPS v0.1 weights (VGG16, AlexNet) converted once into the user's cache
# ($PPD_CACHE_DIR or platformdirs user_cache_dir("ppd"))/lpips/*.npz. Quick no-op when present.
# Failure is not fatal: LPIPS then reports "n/a" with the reason.
set -euo pipefail
cd "$(dirname "$0")/../.."
VENV=${VENV:-.venv}
"$VENV/bin/python" -m verifier.lpips_weights --install \
    || echo "setup: LPIPS weights not installed (LPIPS will report n/a)" >&2
