#!/usr/bin/env bash
# Runs every fuzz target (built by build-fuzzers.sh) for SECONDS each (default 240), one
# after the other, at the lowest priority. Corpora grow in fuzz/corpus/<target>/ (seeded from
# fuzz/seeds/<target>/), crashing inputs land in fuzz/artifacts/<target>/, logs in fuzz/logs/.
# Usage: fuzz/run-fuzzers.sh [SECONDS] [TARGET...]
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"
secs=${1:-240}
shift || true
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=(ply ply_mesh mesh text las e57 pcd reconstruct)
host=$(rustc -vV | sed -n 's/^host: //p')
bin=target/$host/release
mkdir -p logs
for t in "${targets[@]}"; do
  mkdir -p "corpus/$t" "artifacts/$t"
  [ -d "seeds/$t" ] && cp -n seeds/"$t"/* "corpus/$t/" 2>/dev/null
  echo "== $t: $secs s" >&2
  nice -n 19 "$bin/$t" "corpus/$t" -max_total_time="$secs" -rss_limit_mb=2048 \
    -malloc_limit_mb=2048 -timeout=20 -max_len=65536 -print_final_stats=1 \
    -artifact_prefix="artifacts/$t/" >"logs/$t.log" 2>&1
  echo "exit $? ; $(grep -E '^(stat::number_of_executed_units|stat::new_units_added)' logs/$t.log | tr '\n' ' ')" >&2
  grep -E 'ERROR|panicked|SUMMARY' "logs/$t.log" | head -5 >&2
done
