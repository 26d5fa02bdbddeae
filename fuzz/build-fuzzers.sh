#!/usr/bin/env bash
# Builds the coverage-guided fuzzers with a stable toolchain: libFuzzer (compiled from the
# libfuzzer-sys crate; needs a C++ compiler) and LLVM's SanitizerCoverage instrumentation,
# switched on with stable codegen flags (the ones cargo-fuzz passes, without a sanitizer).
# The binaries land in fuzz/target/x86_64-unknown-linux-gnu/release/<target>.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"
host=$(rustc -vV | sed -n 's/^host: //p')
flags="--cfg fuzzing -Cpasses=sancov-module"
for f in level=4 inline-8bit-counters pc-table trace-compares stack-depth; do
  flags="$flags -Cllvm-args=-sanitizer-coverage-$f"
done
# --target keeps the instrumentation off build scripts and proc macros.
RUSTFLAGS="$flags -Cforce-frame-pointers" cargo build --release --features libfuzzer --target "$host" "$@"
