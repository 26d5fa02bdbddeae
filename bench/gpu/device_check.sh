#!/bin/bash
# Issue 17's checks on a machine with an NVIDIA GPU (run through the device tool; docs/gpu.md).
# Expects in .gpu/: `spsr` and `spsr-tests` (built with the cargo feature `gpu`: the release
# binary and the library's stripped unit-test binary), the ground-truth mesh `bunny.ply`
# (../shared/data/gt) and, for the reference's column, `PoissonRecon` (PoissonRecon 18.74's
# command line, built from the sources pypoisson2 vendors; bench/gpu/README.md). Writes its
# logs to $OUT.
#   [THREADS="1 4 16"] [BIG=0] [SMALL_V=1] [UNIT=0] [PR=0] [SMALL="POINTS DEPTH"] [RUN_TIMEOUT=300] \
#       bash bench/gpu/device_check.sh [POINTS] [DEPTH]
# (UNIT=0 skips step 1, PR=0 skips PoissonRecon, SMALL sets the small cloud.)
# 1. the GPU unit tests (right-hand sides, sweeps and solves against the CPU's, bit for bit);
#    on a failure it stops there, to leave device time for a fix;
# 2. a small cloud (POINTS/10, DEPTH-2) on the CPU and twice on the GPU: the same bytes? Then
#    PoissonRecon on every core, on the same cloud and depth;
#    With THREADS, the small cloud also on the CPU with each of those thread counts (-v, for
#    the stages' speed-ups); with SMALL_V=1 the small runs print their profiles (-v);
# 3. unless BIG=0: POINTS points at DEPTH: the CPU on every core, then --gpu, then PoissonRecon on every
#    core (each -v); the CPU's and the GPU's meshes compared byte for byte.
set -u
POINTS=${1:-20000000}
DEPTH=${2:-12}
OUT=${OUT:-/tmp/spsr-gpu-out}
mkdir -p "$OUT"
B=$(pwd)/.gpu
W=$(mktemp -d /tmp/spsr-gpu.XXXX)
export PYTHONUNBUFFERED=1
T0=$(date +%s)
stamp() { echo "[$(($(date +%s) - T0)) s] $*"; }

stamp "== machine"
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv
echo "cores: $(nproc)"
# NVRTC: the CUDA toolkit's, or the pip package's.
NV=$(python3 -c 'import nvidia, os; print(os.pathsep.join(os.path.join(p, d, "lib") for p in nvidia.__path__ for d in ("cu13", "cuda_nvrtc")))' 2>/dev/null)
export LD_LIBRARY_PATH=/usr/local/cuda/lib64:${NV}:${LD_LIBRARY_PATH:-}

SMALL_POINTS=$((POINTS / 10))
SMALL_DEPTH=$((DEPTH - 2))
[ -n "${SMALL:-}" ] && read -r SMALL_POINTS SMALL_DEPTH <<< "$SMALL"
PRBIN=$B/PoissonRecon
[ "${PR:-1}" = 0 ] && PRBIN=/nonexistent
if [ "${UNIT:-1}" = 1 ]; then
stamp "== unit tests"
"$B/spsr-tests" --test-threads 1 --nocapture the_gpu_gives the_kernels_compile copies_through_the_staging > "$OUT/unit.txt" 2>&1
rc=$?
tail -15 "$OUT/unit.txt"
if [ $rc -ne 0 ] || grep -q skipped "$OUT/unit.txt"; then
    stamp "unit tests failed or were skipped: stopping"
    exit 1
fi
fi

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
    timeout "${RUN_TIMEOUT:-300}" /usr/bin/time -f "%e s wall, %M KiB peak" "$B/spsr" reconstruct "$cloud" \
        -o "$W/$name.ply" --depth "$depth" "$@" 2> "$OUT/$name.log"
    stamp "$name: exit $? $(tail -1 "$OUT/$name.log")"
}

stamp "== small: $SMALL_POINTS points at depth $SMALL_DEPTH"
sample $SMALL_POINTS "$W/small.ply"
V=$([ "${SMALL_V:-0}" = 1 ] && echo -v)
run "$W/small.ply" $SMALL_DEPTH small-cpu $V
run "$W/small.ply" $SMALL_DEPTH small-gpu --gpu $V
run "$W/small.ply" $SMALL_DEPTH small-gpu2 --gpu
cmp "$W/small-cpu.ply" "$W/small-gpu.ply" && echo "small: GPU bytes == CPU bytes"
cmp "$W/small-gpu.ply" "$W/small-gpu2.ply" && echo "small: GPU bytes == GPU bytes"
sha256sum "$W"/small-*.ply | sed "s|$W/||"
if [ -x "$PRBIN" ]; then
    OMP_NUM_THREADS=$(nproc) timeout 90 /usr/bin/time -f "%e s wall, %M KiB peak" \
        "$PRBIN" --in "$W/small.ply" --out "$W/small-pr.ply" --depth $SMALL_DEPTH \
        > "$OUT/small-pr.log" 2>&1
    stamp "small-pr: exit $? $(tail -1 "$OUT/small-pr.log")"
fi

for t in ${THREADS:-}; do
    run "$W/small.ply" $SMALL_DEPTH "small-cpu-t$t" --threads "$t" -v
    rm -f "$W/small-cpu-t$t.ply"
done
if [ "${BIG:-1}" = 0 ]; then
    rm -rf "$W"
    exit 0
fi

stamp "== big: $POINTS points at depth $DEPTH"
sample "$POINTS" "$W/big.ply"
run "$W/big.ply" "$DEPTH" big-cpu -v
run "$W/big.ply" "$DEPTH" big-gpu --gpu -v
cmp "$W/big-cpu.ply" "$W/big-gpu.ply" && echo "big: GPU bytes == CPU bytes"
rm -f "$W/big-cpu.ply" "$W/big-gpu.ply"
# The reference gets what is left of a 10-minute call (it is the last step).
LEFT=$((575 - $(date +%s) + T0))
if [ -x "$PRBIN" ] && [ $LEFT -gt 30 ]; then
    stamp "PoissonRecon, at most $LEFT s"
    OMP_NUM_THREADS=$(nproc) timeout $LEFT /usr/bin/time -f "%e s wall, %M KiB peak" \
        "$PRBIN" --in "$W/big.ply" --out "$W/big-pr.ply" --depth "$DEPTH" \
        --verbose > "$OUT/big-pr.log" 2>&1
    stamp "big-pr: exit $? $(tail -1 "$OUT/big-pr.log")"
fi
stamp "== summary"
for n in big-cpu big-gpu; do
    echo "-- $n"
    sed -n '/^gpu /,/^iso-value/p; /^timings:/,$p' "$OUT/$n.log" | cut -c1-80
done
rm -rf "$W"
