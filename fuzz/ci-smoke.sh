#!/usr/bin/env bash
# Short fuzz runs for CI: each cargo-fuzz target for N seconds (default 30).
# Needs rustup's nightly and cargo-fuzz (`cargo install cargo-fuzz`). Any
# crash fails the script; libFuzzer leaves the reproducer in
# fuzz/artifacts/<target>/ (replay: cargo +nightly fuzz run <target> <file>).
set -euo pipefail
cd "$(dirname "$0")"
seconds="${1:-30}"
case "$seconds" in
    '' | *[!0-9]*) echo "usage: $0 [seconds per target]" >&2; exit 2 ;;
esac
targets=(frame_decoder controller)
cargo +nightly fuzz build
log=$(mktemp)
trap 'rm -f "$log"' EXIT
for t in "${targets[@]}"; do
    echo "fuzzing $t for ${seconds}s"
    # -rss_limit_mb: generous, the controller harness keeps ~300 MB of corpus
    status=0
    cargo +nightly fuzz run "$t" -- -max_total_time="$seconds" -rss_limit_mb=4096 \
        -print_final_stats=1 >"$log" 2>&1 || status=$?
    grep -E '^stat::(number_of_executed_units|new_units_added)|^Done|ERROR|panicked|SUMMARY' "$log" || true
    if [ "$status" -ne 0 ]; then
        tail -n 40 "$log" >&2
        echo "fuzz target $t failed (exit $status)" >&2
        exit 1
    fi
done
echo "fuzz smoke passed: ${targets[*]} (${seconds}s each)"
