#!/usr/bin/env bash
# The installed ppd, as a user who does not clone gets it (issue 26): build the sdist and, from it,
# the wheel; check both hold every package (scripts/wheel_check.py); install the wheel alone into a
# fresh virtual environment; run ppd's commands from a temporary folder with the checkout nowhere on
# sys.path: --version, poison, preview, status, verify (real COLMAP children started from the
# installed package), report, restore, watch, service install --print, demo.
#
# Cheap on purpose (CI, .ci/run): the third-party dependencies are not downloaded again. The fresh
# venv reads them from the project venv's site-packages through one .pth line (a plain path:
# the .pth files there, such as the checkout's editable install, are not processed), and the
# script fails if ppd itself would import from anywhere but the fresh venv.
set -euo pipefail
cd "$(dirname "$0")/.."
SRC=$PWD
VENV=${PPD_VENV:-.venv}
case $VENV in /*) ;; *) VENV=$SRC/$VENV;; esac
PY=$VENV/bin/python
started=$SECONDS
T=$(mktemp -d "${TMPDIR:-/tmp}/ppd-wheel-smoke.XXXXXX")
trap 'rm -rf "$T"' EXIT
say() { printf 'wheel-smoke [%ds]: %s\n' "$((SECONDS - started))" "$*"; }
fail() { printf 'wheel-smoke: FAILED: %s\n' "$*" >&2; exit 1; }

# 1. sdist, then the wheel built from it (what an index or `pipx install` builds; no stale build/).
"$PY" -c "import sys; from setuptools import build_meta as b; b.build_sdist(sys.argv[1])" "$T/dist" >"$T/build.log" 2>&1 \
    || { cat "$T/build.log" >&2; fail "sdist build"; }
"$PY" -m pip wheel -q --no-deps --no-build-isolation -w "$T/dist" "$T"/dist/patchpoison-*.tar.gz >>"$T/build.log" 2>&1 \
    || { cat "$T/build.log" >&2; fail "wheel build"; }
WHEEL=$(ls "$T"/dist/patchpoison-*.whl)
"$PY" scripts/wheel_check.py "$SRC" "$WHEEL" "$T"/dist/patchpoison-*.tar.gz || fail "the wheel or the sdist lacks a package"

# 2. A fresh venv with only the wheel installed; dependencies read from the project venv.
BASE=$("$PY" -c "import sys; print(sys._base_executable)")
"$BASE" -m venv --without-pip "$T/venv"
SITE=$("$T/venv/bin/python" -c "import sysconfig; print(sysconfig.get_path('purelib'))")
"$PY" -c "import sysconfig; print(sysconfig.get_path('purelib'))" > "$SITE/ppd-smoke-deps.pth"
"$PY" -m pip --python "$T/venv/bin/python" install -q --no-deps --no-index "$WHEEL"

mkdir -p "$T/work" && cd "$T/work"
export PATH="$T/venv/bin:$PATH" PPD_DATA_DIR="$T/data" PPD_CONFIG_DIR="$T/config" PPD_OUTBOX="$T/outbox"
unset PYTHONPATH PPD_SHARED_DATA
# one path a line: a temporary folder may hold spaces
while IFS= read -r f; do
    case $f in "$SITE"/*) ;; *) fail "ppd imported from $f, not from the installed wheel";; esac
done < <(python -c "import daemon, poisoner, verifier; print(*(m.__file__ for m in (daemon, poisoner, verifier)), sep='\n')")
[ "$(command -v ppd)" = "$T/venv/bin/ppd" ] || fail "ppd on PATH is $(command -v ppd)"
version=$(ppd --version)
[ "$version" = "ppd $(python -c 'from importlib.metadata import version; print(version("patchpoison"))')" ] \
    || fail "ppd --version said '$version'"
say "$version from $T/venv (checkout not on sys.path)"
# The compiled module came with the wheel and loads (else JPEGs would quietly take the slower path).
python -c "from poisoner import jpeg_scan; why = jpeg_scan.available(); assert why is None, why" \
    || fail "the bit-level JPEG splice (poisoner/_jpeg_entropy) does not load from the wheel"
python -c "from poisoner import scene; assert scene._compiled_filter() is not None" \
    || fail "the scene hint's filter (poisoner/_scene_filter) does not load from the wheel"

# 3. A small shoot: an object on a plain backdrop (verifier.synthetic, the installed one).
python -c "import sys; from pathlib import Path; from verifier.synthetic import SyntheticOptions, render_scene
render_scene(Path(sys.argv[1]), SyntheticOptions(num_views=8, width=320, height=320, backdrop='plain'))" shoot/kitchen
ppd poison shoot/kitchen
ppd preview shoot/kitchen/"$(ls shoot/kitchen | head -1)" --out preview.png --no-visibility
[ -s preview.png ] || fail "no preview written"
ppd status kitchen
rc=0; (cd shoot && ppd verify kitchen --profile default --json > "$T/verify.json") || rc=$?
[ "$rc" -le 1 ] || fail "ppd verify exited $rc"
verified=$(python - "$T/verify.json" <<'PY'
import json, sys
report = json.load(open(sys.argv[1]))
clean = report["profiles"]["default"]["clean"]
assert clean["outcome"] == "ok", clean  # COLMAP ran in a child process of the installed package
print(f"verify: verdict {report['verdict']}, clean SfM registered {clean['registered']}")
PY
) || fail "ppd verify ran no clean SfM"
say "$verified"
(cd shoot && ppd report kitchen --out "$T/report.html")
(cd shoot/kitchen && ppd restore .)

# 4. The daemon: a file dropped into the outbox comes out patched; SIGTERM ends it cleanly.
ppd watch > "$T/watch.log" 2>&1 &
watcher=$!
mkdir -p "$T/outbox/trip"
cp shoot/kitchen/"$(ls shoot/kitchen | head -1)" "$T/outbox/trip/a.png"
for _ in $(seq 120); do
    ppd status trip --json 2>/dev/null | grep -q '"patched": 1' && break
    sleep 0.5
done
kill -TERM "$watcher"; wait "$watcher" || { cat "$T/watch.log" >&2; fail "ppd watch exited $?"; }
ppd status trip --json | grep -q '"patched": 1' || { cat "$T/watch.log" >&2; fail "ppd watch did not patch"; }
say "watch: the outbox file was patched, SIGTERM exit 0"

# 5. The service unit runs this installation's ppd.
unit=$(ppd service install --print)
exe="$T/venv/bin/ppd"
case $exe in *[[:space:]]*) exe="\"$exe\"";; esac  # systemd quotes a path with spaces (service.quote_word)
grep -qxF "ExecStart=$exe watch" <<<"$unit" || fail "ExecStart is not $exe: $(grep ExecStart <<<"$unit")"
say "service: ExecStart=$T/venv/bin/ppd watch"

# 6. The demo, end to end with its verdict.
say "demo"
ppd demo --workdir "$T/demo" > "$T/demo.log" 2>&1 || { cat "$T/demo.log" >&2; fail "ppd demo"; }
grep -q '^overall' "$T/demo.log" || { cat "$T/demo.log" >&2; fail "ppd demo printed no verdict"; }
sed -n '/^overall/,$p' "$T/demo.log"
say "all commands ran from the installed wheel in $((SECONDS - started)) s"
