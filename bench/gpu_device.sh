#!/usr/bin/env bash
# The GPU checks of issue 30, on a lent CUDA machine (this workplace's `device` tool), from the
# repository root. Two steps, because what travels to that machine is capped at 64 MiB:
#   setup: install the carried `.dev/` (pycolmap-cuda12 4.2.1 as tar.xz, the few wheels of ppd's
#          dependencies the machine's image lacks, X11 client libraries pycolmap links) into /tmp/site
#          and check that pycolmap sees the GPU, with a small SIFT run on both devices;
#   main:  with `.devdata/` carried (fountain-P11's four texture photos, lego's first 40 views):
#          the 40 x 24 MP creator set, SIFT GPU vs CPU on 12 of its photos (bench_gpu_sift), then
#          bench_verify_speed on it (one default COLMAP run, `ppd verify --profile all` first and
#          second), each lane saved to $OUT as it ends; lego 40 if time is left.
#   pack:  (here, before both) make `.dev/` and `.devdata/` (both in .git/info/exclude) from the
#          package registry and ../shared.
#   placement: (issue 25) lego 40's COLMAP protection, CPU SIFT, one process per profile and seed.
#   verdicts: the GPU-vs-CPU test (tests/verifier/test_sfm_gpu.py) and lego 40's verification.
# Needs the `run` tool's $OUT. Nothing here is part of the product or of CI.
set -u
mode=${1:?setup or main}
deadline=$(( $(date +%s) + ${2:-540} ))
left() { echo $(( deadline - $(date +%s) )); }
export PYTHONUNBUFFERED=1 PYTHONPATH=/tmp/site:$PWD
views=${PPD_GPU_VIEWS:-40} width=${PPD_GPU_WIDTH:-6000}  # smaller only to try the script out

if [ "$mode" = pack ]; then
    py=${PYTHON:-.venv/bin/python} shared=${PPD_SHARED_DATA:-../shared/datasets}
    get() { "$py" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 "$@"; }
    rm -rf .dev .devdata && mkdir -p .dev/whl .dev/lib .devdata/whl /tmp/ppd-pack
    get -d /tmp/ppd-pack pycolmap-cuda12==4.2.1 || exit 3
    repo=$PWD
    (cd /tmp/ppd-pack && rm -rf x && mkdir x && cd x && unzip -q ../pycolmap_cuda12-*.whl &&
        tar -cf - . | xz -9e -T0 > "$repo/.dev/pycolmap_cuda12.tar.xz") || exit 3
    get -d .dev/whl nvidia-cuda-runtime-cu12==12.9.79 msgspec || exit 3
    # the second call's: what setup does not need (the 64 MiB a call carries is nearly full with .dev)
    get -d .devdata/whl pillow==13.0.0 flip-evaluator pytest pluggy iniconfig packaging pygments \
        watchdog sqlite-utils sqlite-fts4 click-default-group platformdirs tomli-w typer==0.29.2 \
        annotated-doc pydantic pydantic-core annotated-types typing-inspection || exit 3
    for lib in libSM.so.6 libICE.so.6 libX11.so.6 libXext.so.6 libxcb.so.1 libXau.so.6 libXdmcp.so.6; do
        cp -L "/usr/lib/x86_64-linux-gnu/$lib" .dev/lib/
    done
    mkdir -p .devdata/fountain_P11/images .devdata/nerf_synthetic_lego/train
    for i in 1 4 7 9; do cp "$shared/fountain_P11/images/000$i.jpg" .devdata/fountain_P11/images/; done
    for n in $(ls "$shared/fountain_P11/images"); do  # creator_set picks photos 1, 4, 7, 9 by sorted name
        [ -e ".devdata/fountain_P11/images/$n" ] || ln -s 0001.jpg ".devdata/fountain_P11/images/$n"
    done
    cp "$shared/nerf_synthetic_lego/transforms_train.json" .devdata/nerf_synthetic_lego/
    for i in $(seq 0 39); do cp "$shared/nerf_synthetic_lego/train/r_$i.png" .devdata/nerf_synthetic_lego/train/; done
    du -sh .dev .devdata
    exit
fi

if [ "$mode" = setup ]; then
    mkdir -p /tmp/site /tmp/devlib
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
        --target /tmp/site .dev/whl/*.whl || exit 3
    tar -xJf .dev/pycolmap_cuda12.tar.xz -C /tmp/site || exit 3
    for lib in .dev/lib/*; do  # only what the image lacks: its own libraries stay first
        ldconfig -p | grep -q "$(basename "$lib")" || cp "$lib" /tmp/devlib/
    done
    curand=$(dirname "$(find / -xdev -name 'libcurand.so.10*' 2>/dev/null | head -1)")
    echo "export LD_LIBRARY_PATH=/tmp/site/nvidia/cuda_runtime/lib:$curand:/tmp/devlib:\${LD_LIBRARY_PATH:-}" \
        > /tmp/ppd-env.sh
    cat /tmp/ppd-env.sh; ls /tmp/devlib; nvidia-smi -L
    . /tmp/ppd-env.sh
    python3 -c "import pycolmap, PIL, numpy; print('pycolmap', pycolmap.__version__, 'cuda', pycolmap.has_cuda, 'PIL', PIL.__version__, 'numpy', numpy.__version__)" || exit 4
    python3 -c "
from pathlib import Path
from verifier.synthetic import SyntheticOptions, render_scene
render_scene(Path('/tmp/syn6'), SyntheticOptions(num_views=6, width=1200, height=800, focal=1440))"
    timeout "$(left)" python3 -m bench.bench_gpu_sift /tmp/syn6 --out "$OUT/gpu_sift_smoke.json"
    exit
fi

[ -f /tmp/ppd-env.sh ] || { echo "setup has not run on this machine"; exit 5; }
. /tmp/ppd-env.sh
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .devdata/whl/*.whl || exit 3
python3 -m daemon.cli verify --help > /dev/null || exit 4  # the CLI imports here
export PPD_SHARED_DATA=$PWD/.devdata PPD_BENCH_WORK=/tmp/pbw PPD_BENCH_RESULTS=$OUT

if [ "$mode" = sweep ]; then
    # round 4: GPU vs CPU verdicts (the integration test), then the mark's area at 24 MP: the lanes'
    # area cap at 1% (ppd's), 2% and 4% of the frame with 8 px blocks (4 px as SIFT sees them), and the
    # default, on the 12-view creator set, default profile, COLMAP seeds 0 and 1 (bench_protection_24mp).
    set -x
    timeout 170 python3 -m pytest -q -p no:cacheprovider -m integration tests/verifier/test_sfm_gpu.py \
        2>&1 | tail -15 | tee "$OUT/test_sfm_gpu.txt"
    cs=/tmp/pbw/cs$width
    timeout 60 python3 -m testkit.creator_set "$cs" --views 12 --width "$width" --height $(( width * 2 / 3 ))
    B=bench.bench_protection_24mp
    for v in ${PPD_SWEEP:-b15a0096:15:0 b8a04:8:0.04 b8a02:8:0.02 b8a0096:8:0}; do
        IFS=: read -r lab blk area <<< "$v"
        [ "$(left)" -lt 60 ] && { echo "no time for $lab"; continue; }
        timeout 60 python3 -m $B poison "$cs" --label "$lab" --block "$blk" --area "$area" | tail -c 300
        timeout "$(( $(left) - 15 ))" python3 -m $B verify "$cs" --poisoned "$cs/$lab" --label "$lab" \
            --profiles default --seeds 0,1
        cp "$cs/runs.json" "$OUT/sweep_runs.json"
    done
    python3 - "$cs" <<'PY' > "$OUT/sweep_area.txt"
import sys
from pathlib import Path
import numpy as np
from PIL import Image
root = Path(sys.argv[1])
clean = sorted((root / "clean").glob("*.jpg"))[:3]
for d in sorted(p for p in root.iterdir() if p.is_dir() and p.name[:1] == "b"):
    shares = []
    for c in clean:
        a = np.asarray(Image.open(c)); b = np.asarray(Image.open(d / c.name))
        diff = np.abs(a.astype(int) - b).max(axis=2)
        shares.append(f"{(diff > 0).mean():.2%} / {(diff > 8).mean():.2%}")
    print(d.name, "changed area (|diff| > 0 / > 8, first 3 views):", shares)
PY
    echo "done, $(left) s left"
    exit
fi
if [ "$mode" = verdicts ]; then
    # issue 30, what 78c6d69 left unrun on a GPU: the GPU-vs-CPU test on its decisive set (and 320 px
    # photos on the CPU's SIFT), then lego 40's verification, whose 800 px photos now keep the CPU's
    # SIFT (round 5 with GPU SIFT: published and masked inconclusive)
    set -x
    timeout 200 python3 -m pytest -q -p no:cacheprovider -m "integration or not integration" \
        tests/verifier/test_sfm_gpu.py 2>&1 | tail -15 | tee "$OUT/test_sfm_gpu.txt"
    timeout "$(( $(left) - 10 ))" python3 -m bench.bench_verify_speed --set lego --views 40 --second \
        --timeout 240 --label "gpu $(nvidia-smi --query-gpu=name --format=csv,noheader | head -1), \
$(nproc) cores (${PPD_CODE:-tree}), lego on the CPU's SIFT" --sift-device cpu
    echo "done, $(left) s left"
    exit
fi
if [ "$mode" = placement ]; then
    # issue 25 round 5: lego 40's five profiles x seeds with the CPU SIFT this machine's checks use
    # (PPD_SFM_DEVICE=cpu), one process per cell on the lent machine's cores; the clean runs are this
    # machine's (carried in .devdata/lego-clean-runs), each cell's colmap.json saved to $OUT
    export PPD_SFM_DEVICE=${PPD_PLACEMENT_SIFT:-cpu}
    for seed in ${PPD_SEEDS:-0 1}; do for p in ${PPD_PROFILES:-default hardened published masked global}; do
        d=/tmp/pl/$p-$seed && mkdir -p "$d/ppd-bench-placement/sfm/lego/clean-runs"
        cp .devdata/lego-clean-runs/*.json "$d/ppd-bench-placement/sfm/lego/clean-runs/"
        (TMPDIR=$d timeout "$(( $(left) - 15 ))" python3 -m bench.bench_placement colmap --sets lego \
            --profiles "$p" --seeds "$seed" --round 5 > "$OUT/$p-$seed.log" 2>&1
         cp "$d/ppd-bench-placement/colmap.json" "$OUT/colmap-$p-$seed.json" 2>/dev/null) &
    done; done
    wait
    # one file back (the tool returns a few files only): every cell's log, run results and the files' hashes
    for d in /tmp/pl/*; do
        echo "== $d"; tail -c 1500 "$OUT/$(basename "$d").log"; rm -f "$OUT/$(basename "$d").log"
        for f in "$d"/ppd-bench-placement/sfm/lego/per-photo-*-r5/*.json "$d"/ppd-bench-placement/sfm/lego/per-photo-*-r5/*.log; do
            [ -f "$f" ] && { echo "-- $f"; head -c 3000 "$f"; echo; }
        done
    done > "$OUT/placement.txt" 2>&1
    sha256sum /tmp/pl/default-0/ppd-bench-placement/sfm/lego/per-photo-*-r5/images/* >> "$OUT/placement.txt"
    echo "done, $(left) s left"
    exit
fi
label="gpu $(nvidia-smi --query-gpu=name --format=csv,noheader | head -1), $(nproc) cores ($(echo "${PPD_CODE:-$(git rev-parse --short HEAD 2>/dev/null || echo tree)}"))"
set -x
t0=$(date +%s)
timeout "$(left)" python3 -m testkit.creator_set /tmp/pbw/creator-$views-$width --views "$views" --width "$width" --height $(( width * 2 / 3 ))
echo "creator set made in $(( $(date +%s) - t0 )) s" | tee "$OUT/creator_set.txt"
[ "$views" = 40 ] && mkdir -p /tmp/c12 && for f in $(ls /tmp/pbw/creator-$views-$width/poisoned/*.jpg | head -12); do ln -sf "$f" /tmp/c12/; done
[ "$views" = 40 ] && timeout 150 python3 -m bench.bench_gpu_sift /tmp/c12 --out "$OUT/gpu_sift_creator12.json" --timeout 140
timeout "$(( $(left) - 10 ))" python3 -m bench.bench_verify_speed --set creator --views "$views" --width "$width" \
    --second --timeout "${PPD_GPU_LANE_S:-300}" --label "$label" --sift-device cuda
# before/after on one warm machine: the same lane with the code of a carried `git archive` (.devdata/base,
# its commit in PPD_BASE_CODE), its own baseline in the lane
if [ -d .devdata/base ] && [ "$(left)" -gt "${PPD_GPU_BASE_NEEDS_S:-200}" ]; then
    timeout "$(( $(left) - 10 ))" python3 -m bench.bench_verify_speed --set creator --views "$views" \
        --width "$width" --second --timeout "${PPD_GPU_LANE_S:-300}" --tree "$PWD/.devdata/base" \
        --label "${label%(*}(${PPD_BASE_CODE:-base})" --sift-device cuda
fi
if [ "${PPD_GPU_LEGO:-1}" = 1 ] && [ "$(left)" -gt 240 ]; then
    timeout "$(( $(left) - 10 ))" python3 -m bench.bench_verify_speed --set lego --views 40 \
        --second --timeout 200 --label "$label" --sift-device cuda
fi
echo "done, $(left) s left"
