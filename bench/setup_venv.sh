#!/usr/bin/env bash
# Creates (or completes) the benchmark's Python environment, outside the repository because it
# is large (about 1.5 GB) and slow to build:
#   numpy, matplotlib          needed by the harness (inputs it generates, plots)
#   scipy                      bench/noise: nearest-neighbour distances of scans without a truth
#   pypoisson2                 PoissonRecon 18.74; ships as source only: needs cmake and a C++
#                              compiler, about 12 minutes to compile on 2 cores
#   open3d                     its own, older copy of PoissonRecon; needs libusb-1.0 at import
#   pymeshlab                  MeshLab's screened Poisson filter
# and, from Debian when missing, GNU time (the harness's memory measurement), cmake (for
# pypoisson2) and libusb-1.0-0 (for open3d).
# Idempotent: what already imports is left alone. A peer that cannot be installed is reported
# and skipped (the harness then records it as failed, with the reason written to
# $VENV/spsr-bench-install.log); only numpy and matplotlib are required.
#
#   bash bench/setup_venv.sh [VENV]        (default: $SPSR_BENCH_VENV or ~/.cache/spsr-bench-venv)
set -uo pipefail
VENV="${1:-${SPSR_BENCH_VENV:-$HOME/.cache/spsr-bench-venv}}"
LOG="$VENV/spsr-bench-install.log"
PIPLOG="$VENV/spsr-bench-pip.log"

# Versions the committed results were made with.
NUMPY="numpy==2.4.6"
MATPLOTLIB="matplotlib==3.11.2"
SCIPY="scipy==1.17.1"
PYPOISSON2="pypoisson2==1.0.0"
OPEN3D="open3d==0.20.0"
PYMESHLAB="pymeshlab==2025.7.post1"

apt_install() {
    # Debian packages, only when missing; needs root (or sudo).
    local sudo=""
    [ "$(id -u)" = 0 ] || sudo="sudo"
    $sudo apt-get update -qq && $sudo apt-get install -y -qq "$@"
}

# The harness measures each run's peak memory through GNU time (Debian: time).
[ -x /usr/bin/time ] || apt_install time || echo "setup_venv: could not install GNU time" >&2

if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV" 2>/dev/null || { apt_install python3-venv && python3 -m venv "$VENV"; } || {
        echo "setup_venv: cannot create a virtual environment at $VENV" >&2
        exit 1
    }
fi
PY="$VENV/bin/python"
mkdir -p "$VENV"
: >"$LOG"
: >"$PIPLOG"

has() { "$PY" -c "import $1" >/dev/null 2>&1; }

install() {
    # install MODULE PIP_SPEC [required]
    local module="$1" spec="$2" required="${3:-}"
    if has "$module"; then
        echo "setup_venv: $module already installed"
        return 0
    fi
    echo "setup_venv: installing $spec"
    if ! "$PY" -m pip install -q "$spec" >>"$PIPLOG" 2>&1 || ! has "$module"; then
        local why
        why="$("$PY" -c "import $module" 2>&1 | tail -n 1)"
        [ -n "$why" ] || why="$(grep -iE 'error' "$PIPLOG" | tail -n 1)"
        echo "$module: $spec: ${why:-install failed}" >>"$LOG"
        echo "setup_venv: $spec failed: ${why:-install failed} (details: $LOG.tmp)" >&2
        [ -z "$required" ] || exit 1
    fi
}

install numpy "$NUMPY" required
install matplotlib "$MATPLOTLIB" required
install scipy "$SCIPY" required

# pypoisson2 builds PoissonRecon with cmake.
if ! has poisson && ! command -v cmake >/dev/null; then
    apt_install cmake || echo "setup_venv: could not install cmake" >&2
fi
install poisson "$PYPOISSON2"

# open3d's wheel links libusb-1.0 (Debian: libusb-1.0-0).
if ! has open3d && ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    apt_install libusb-1.0-0 || echo "setup_venv: could not install libusb-1.0-0" >&2
fi
install open3d "$OPEN3D"
install pymeshlab "$PYMESHLAB"

echo "setup_venv: environment ready: $VENV"
[ -s "$LOG" ] && { echo "setup_venv: peers that failed to install:"; cat "$LOG"; }
exit 0
