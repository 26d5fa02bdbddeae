#!/usr/bin/env bash
# Creates the benchmark's Python environment outside the repository (it is large and slow to
# build): PoissonRecon 18.74 through pypoisson2, which ships as source only and needs cmake
# (Debian package) and about 12 minutes to compile.
set -euo pipefail
VENV="${1:-$HOME/.cache/spsr-bench-venv}"
command -v cmake >/dev/null || { apt-get update -qq && apt-get install -y -qq cmake; }
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/pip" install -q --upgrade pip
"$VENV/bin/pip" install -q numpy pypoisson2
echo "benchmark environment ready: $VENV"
