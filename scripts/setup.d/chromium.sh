#!/usr/bin/env bash
# Headless Chromium for the HTML report test (tests/verifier/test_report.py: the page loads with no console
# error and its screenshot shows the verdict). Debian's `chromium` package; a quick no-op when a
# chromium binary is already on PATH. Not fatal: without it that one test skips and says why.
set -euo pipefail
if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then
    exit 0
fi
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium) >/dev/null \
        || echo "setup: could not install chromium (the report screenshot test will skip)" >&2
else
    echo "setup: chromium missing and cannot apt-get here (the report screenshot test will skip)" >&2
fi
exit 0
