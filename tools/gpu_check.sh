#!/usr/bin/env bash
# The GPU check in one call of the device tool (about 9 minutes), with this tree's own bench:
#   1. here: `bash ../shared/tools/gpu/bundle.sh` (the ignored .dev/: Python 3.12 wheels a bare CUDA machine lacks,
#      gsplat 1.5.3 among them, and gsplat's garden asset);
#   2. the device tool's run: carry [".dev"], command `bash tools/gpu_check.sh`, timeout_s 590; then give_back.
# It registers NVIDIA's OpenCL where no .icd file names it, builds gsplat's CUDA extension in the background
# (~90 s) while two whole built-in runs train, then runs `dc4gs-cl bench --garden .dev/garden.npz --gsplat`
# (every case through gsplat too: ours / gsplat per case, in the report's tables) and the suite with the time left.
# Results under $OUT: log.txt, bench-*.json and .md, pytest.txt. Without a GPU (a dry run on a CPU machine) the same
# steps run on the default device, the bench without --gsplat.
set -u
export PYTHONUNBUFFERED=1 TORCH_CUDA_ARCH_LIST=9.0 MAX_JOBS=10   # the same flags for gsplat's build and its use
PY=${PYTHON:-python3}
R=$(pwd); B=$R/.dev; OUT=${OUT:-/tmp/gpu_check}; mkdir -p "$OUT"; L=$OUT/log.txt; S=$(date +%s)
say() { echo "=== $(( $(date +%s) - S ))s $*" | tee -a "$L"; }
left() { echo $(( $1 - ($(date +%s) - S) )); }
say "commit $(git rev-parse --short HEAD 2>/dev/null)"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv >>"$L" 2>&1
lib=$(find / -xdev \( -path /proc -o -path /sys \) -prune -o -name 'libnvidia-opencl.so.1' -print 2>/dev/null | head -1)
if [ -n "$lib" ]; then
  mkdir -p /tmp/icd && echo "$lib" > /tmp/icd/nvidia.icd && export OCL_ICD_VENDORS=/tmp/icd
fi
echo "NVIDIA OpenCL: ${lib:-not found}" >>"$L"
export PYTHONPATH=$R
if [ -d "$B/whl" ]; then
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site "$B"/whl/*.whl >>"$L" 2>&1 \
    || say "pip failed"
  export PYTHONPATH=$R:/tmp/site
fi
garden=$B/garden.npz; [ -f "$garden" ] || garden=$R/../shared/data/gsplat_test_garden/test_garden.npz
( cd /tmp && timeout 400 $PY -c "import torch; assert torch.cuda.is_available(), 'no CUDA device'
from gsplat.cuda._backend import _C; print('gsplat built', _C)" > /tmp/gsplat_build.txt 2>&1 ) &
GB=$!
timeout 30 $PY -m dc4gs_cl devices >>"$L" 2>&1
for spec in "3dgs:" "absgs:--dc4gs"; do s=${spec%%:*}; dc=${spec#*:}
  t=$(date +%s); timeout 90 $PY -m dc4gs_cl train --no-progress --strategy $s $dc --out /tmp/run-$s$dc --force \
    > /tmp/train.txt 2>&1
  say "train built-in $s $dc rc $? wall $(( $(date +%s) - t )) s: $(grep -E 'test PSNR|Gaussians' /tmp/train.txt \
    | tail -2 | tr '\n' ' ')"
done
say wait-gsplat; wait $GB && gs=--gsplat || gs=; tail -2 /tmp/gsplat_build.txt >>"$L"
say "bench ${gs:-(no gsplat)}"
T=$(left 400); [ "$T" -lt 60 ] && T=60   # never 0: timeout 0 would not limit it
timeout "$T" $PY -m dc4gs_cl bench --garden "$garden" $gs --out "$OUT" >>"$L" 2>&1; say "bench rc $?"
xdist=; $PY -c "import xdist" 2>/dev/null && xdist="-n 8"
T=$(left 560); [ "$T" -lt 30 ] && T=30
say "pytest (timeout $T)"
timeout "$T" $PY -m pytest -q -p no:cacheprovider $xdist tests --ignore=tests/test_viewer.py \
  --ignore=tests/test_sanitizer.py --ignore=tests/test_export.py > "$OUT/pytest.txt" 2>&1
say "pytest rc $?"; tail -3 "$OUT/pytest.txt" >>"$L"
say done
