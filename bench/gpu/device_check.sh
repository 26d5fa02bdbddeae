#!/bin/bash
# Issue 17's checks on a machine with an NVIDIA GPU (run through the device tool; docs/gpu.md).
# Expects in .gpu/: `spsr` and `spsr-tests` (built with the cargo feature `gpu`: the release
# binary and the library's stripped unit-test binary) and the ground-truth mesh `bunny.ply`
# (../shared/data/gt). Writes its logs to $OUT.
#   bash bench/gpu/device_check.sh [POINTS] [DEPTH] [BIG_CPU]
# 1. the GPU unit tests (sweeps and solves against the CPU's, bit for bit);
# 2. a small cloud (POINTS/10, DEPTH-2) on the CPU and twice on the GPU: the same bytes?
# 3. POINTS points at DEPTH with --gpu -v (and on the CPU too when BIG_CPU is 1).
set -u
POINTS=${1:-20000000}
DEPTH=${2:-12}
BIG_CPU=${3:-0}
OUT=${OUT:-/tmp/spsr-gpu-out}
mkdir -p "$OUT"
B=$(pwd)/.gpu
W=$(mktemp -d /tmp/spsr-gpu.XXXX)
export PYTHONUNBUFFERED=1

echo "== machine"
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv
echo "cores: $(nproc)"
# NVRTC: the CUDA toolkit's, or the pip package's.
NV=$(python3 -c 'import nvidia; print(list(nvidia.__path__)[0])' 2>/dev/null)
export LD_LIBRARY_PATH=/usr/local/cuda/lib64:$NV/cu13/lib:${LD_LIBRARY_PATH:-}

echo "== unit tests"
"$B/spsr-tests" --test-threads 1 --nocapture gpu 2>&1 | tail -12 | tee "$OUT/unit.txt"

sample() {  # count, path
    python3 - "$B/bunny.ply" "$2" "$1" <<'PY'
import os, sys, time
sys.path.insert(0, "bench")
from run import sample_gt
t = time.time()
p = sample_gt(os.path.basename(sys.argv[2])[:-4], sys.argv[1], int(sys.argv[3]), os.path.dirname(sys.argv[2]))
print(p, os.path.getsize(p) >> 20, "MiB in", round(time.time() - t, 1), "s")
PY
}
run() {  # cloud, depth, name, flags...
    local cloud=$1 depth=$2 name=$3; shift 3
    timeout 240 /usr/bin/time -f "%e s wall, %M KiB peak" "$B/spsr" reconstruct "$cloud" \
        -o "$W/$name.ply" --depth "$depth" "$@" 2> "$OUT/$name.log"
    echo "$name: exit $? $(tail -1 "$OUT/$name.log")"
}

echo "== small: $((POINTS / 10)) points at depth $((DEPTH - 2))"
sample $((POINTS / 10)) "$W/small.ply"
run "$W/small.ply" $((DEPTH - 2)) small-cpu
run "$W/small.ply" $((DEPTH - 2)) small-gpu --gpu
run "$W/small.ply" $((DEPTH - 2)) small-gpu2 --gpu
cmp "$W/small-cpu.ply" "$W/small-gpu.ply" && echo "small: GPU bytes == CPU bytes"
cmp "$W/small-gpu.ply" "$W/small-gpu2.ply" && echo "small: GPU bytes == GPU bytes"
sha256sum "$W"/small-*.ply | sed "s|$W/||"

echo "== big: $POINTS points at depth $DEPTH"
sample "$POINTS" "$W/big.ply"
run "$W/big.ply" "$DEPTH" big-gpu --gpu -v
sed -n '/^gpu /,/^iso-value/p; /^timings:/,$p' "$OUT/big-gpu.log"
[ "$BIG_CPU" = 1 ] && run "$W/big.ply" "$DEPTH" big-cpu -v
rm -rf "$W"
