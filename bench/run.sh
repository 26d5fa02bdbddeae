#!/usr/bin/env bash
# The benchmark in one command: makes (or completes) the Python environment with the peers,
# then runs bench/run.py in it with the arguments given here (see `bash bench/run.sh --help`).
#
#   bash bench/run.sh                       # full default run; results in bench/results/
#   bash bench/run.sh --inputs bunny_20k --depths 6 7 --reps 1 --name smoke
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="${SPSR_BENCH_VENV:-$HOME/.cache/spsr-bench-venv}"
bash "$HERE/setup_venv.sh" "$VENV"
export SPSR_BENCH_VENV="$VENV"
exec "$VENV/bin/python" "$HERE/run.py" "$@"
