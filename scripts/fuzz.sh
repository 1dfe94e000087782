#!/usr/bin/env bash
# Coverage-guided fuzzing of the recording decoders (crates/formats) with libFuzzer: nightly
# Rust, cargo-fuzz's instrumentation flags passed directly (cargo-fuzz itself is not needed),
# plus overflow checks so that arithmetic overflow is a crash. Each target starts from a copy
# of its seed corpus (crates/formats/fuzz/seeds; scripts/fuzz_seeds.py writes it); crashes land
# in crates/formats/fuzz/artifacts/. Usage: scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]
set -euo pipefail
seconds=${1:-60}
shift || true
targets=("${@:-evt2}")
[ $# -eq 0 ] && targets=(evt2 evt3 dat rosbag aedat4 mcap)
cd "$(dirname "${BASH_SOURCE[0]}")/../crates/formats/fuzz"
export CARGO_TARGET_DIR="${FUZZ_TARGET_DIR:-$PWD/target}"
export RUSTFLAGS="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing -Cdebug-assertions -Coverflow-checks"
# With an explicit --target, RUSTFLAGS reach the fuzzed code but not the build scripts.
host=$(rustc +nightly -vV | sed -n 's/^host: //p')
cargo +nightly build --release --bins --target "$host"
mkdir -p artifacts
for target in "${targets[@]}"; do
    corpus=$(mktemp -d)
    cp "seeds/$target"/* "$corpus"/
    echo "== $target: ${seconds} s from $(ls "$corpus" | wc -l) seeds"
    # -timeout=1: an input over a second is a hang; -malloc_limit_mb: one allocation over
    # 64 MB is a failure (a chunk of 2^20 events is 13 MB); both limits can be set lower
    # (MALLOC_LIMIT_MB, RSS_LIMIT_MB), e.g. to check a reader's memory bound.
    "$CARGO_TARGET_DIR/$host/release/$target" -max_total_time="$seconds" -timeout=1 \
        -rss_limit_mb="${RSS_LIMIT_MB:-1024}" -malloc_limit_mb="${MALLOC_LIMIT_MB:-64}" \
        -max_len=65536 -print_final_stats=1 -report_slow_units="${SLOW_UNIT_S:-10}" \
        -artifact_prefix="artifacts/$target-" "$corpus" 2>&1 | grep -E "^(#[0-9]+.*(DONE|pulse)|stat::|==|INFO: (Seed|Loaded)|Slowest unit|SUMMARY)" || true
    rm -rf "$corpus"
done
