#!/bin/bash
# Issue 17's checks on a machine with an NVIDIA GPU (run through the device tool; see
# bench/gpu/README.md). Expects in .gpu/: `spsr` and `spsr-tests` (built here with the cargo
# feature `gpu`: the release binary and the library's stripped unit-test binary) and the
# ground-truth mesh `bunny.ply` (../shared/data/gt). Writes its logs and table to $OUT.
#   bash bench/gpu/device_check.sh [POINTS] [DEPTH]
set -u
POINTS=${1:-20000000}
DEPTH=${2:-12}
OUT=${OUT:-/tmp/spsr-gpu-out}
mkdir -p "$OUT"
B=$(pwd)/.gpu
W=$(mktemp -d /tmp/spsr-gpu.XXXX)
export PYTHONUNBUFFERED=1

echo "== machine"
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv
echo "cores: $(nproc)"; free -g | head -2
# NVRTC: the CUDA toolkit's, or the pip package's.
NV=$(python3 -c 'import nvidia; print(list(nvidia.__path__)[0])' 2>/dev/null)
export LD_LIBRARY_PATH=/usr/local/cuda/lib64:/usr/local/cuda/targets/x86_64-linux/lib:$NV/cu13/lib:$NV/cuda_nvrtc/lib:${LD_LIBRARY_PATH:-}
ls /usr/local/cuda/lib64/libnvrtc.so* $NV/cu13/lib/libnvrtc.so* 2>/dev/null | head -3

echo "== unit tests (GPU sweeps against the CPU's, bit for bit)"
"$B/spsr-tests" --test-threads 1 --nocapture gpu 2>&1 | tail -15 | tee "$OUT/unit.txt"

echo "== sampling $POINTS points from bunny.ply"
python3 - "$B/bunny.ply" "$W/cloud.ply" "$POINTS" <<'PY'
import sys, time
sys.path.insert(0, "bench")
from run import sample_gt
import os, shutil
t = time.time()
p = sample_gt("cloud", sys.argv[1], int(sys.argv[3]), os.path.dirname(sys.argv[2]))
print(p, os.path.getsize(p) >> 20, "MiB in", round(time.time() - t, 1), "s")
PY

run() {  # name, flags...
    local name=$1; shift
    timeout 240 /usr/bin/time -f "%e s wall, %M KiB peak" "$B/spsr" reconstruct "$W/cloud.ply" \
        -o "$W/$name.ply" --depth "$DEPTH" -v "$@" 2> "$OUT/$name.log"
    echo "$name: exit $? $(tail -1 "$OUT/$name.log")"
}
echo "== reconstructions at depth $DEPTH, all cores"
run cpu1
run gpu1 --gpu
run gpu2 --gpu
echo "== same bytes?"
cmp "$W/cpu1.ply" "$W/gpu1.ply" && echo "gpu1 == cpu1"
cmp "$W/gpu1.ply" "$W/gpu2.ply" && echo "gpu2 == gpu1"
run cpu2
cmp "$W/cpu1.ply" "$W/cpu2.ply" && echo "cpu2 == cpu1"
echo "== Chamfer to the ground truth"
timeout 90 "$B/spsr" eval "$W/gpu1.ply" --reference "$B/bunny.ply" 2>&1 | tail -8 | tee "$OUT/eval.txt"
rm -rf "$W"
