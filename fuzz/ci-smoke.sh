#!/usr/bin/env bash
# Short fuzz runs for CI: each cargo-fuzz target for N seconds (default 30),
# the targets side by side (libFuzzer runs one process per target, one core
# each). Needs rustup's nightly and cargo-fuzz (`cargo install cargo-fuzz`).
# Any crash fails the script; libFuzzer leaves the reproducer in
# fuzz/artifacts/<target>/ (replay: cargo +nightly fuzz run <target> <file>).
set -euo pipefail
cd "$(dirname "$0")"
seconds="${1:-30}"
case "$seconds" in
    '' | *[!0-9]*) echo "usage: $0 [seconds per target]" >&2; exit 2 ;;
esac
targets=(frame_decoder controller)
cargo +nightly fuzz build
logs=$(mktemp -d)
trap 'rm -rf "$logs"' EXIT
pids=()
for t in "${targets[@]}"; do
    echo "fuzzing $t for ${seconds}s"
    # -rss_limit_mb: generous, the controller harness keeps ~300 MB of corpus
    cargo +nightly fuzz run "$t" -- -max_total_time="$seconds" -rss_limit_mb=4096 \
        -print_final_stats=1 >"$logs/$t" 2>&1 &
    pids+=($!)
done
failed=()
for i in "${!targets[@]}"; do
    t=${targets[$i]}
    status=0
    wait "${pids[$i]}" || status=$?
    echo "$t:"
    grep -E '^stat::(number_of_executed_units|new_units_added)|^Done|ERROR|panicked|SUMMARY' "$logs/$t" || true
    if [ "$status" -ne 0 ]; then
        tail -n 40 "$logs/$t" >&2
        echo "fuzz target $t failed (exit $status)" >&2
        failed+=("$t")
    fi
done
((${#failed[@]} == 0)) || exit 1
echo "fuzz smoke passed: ${targets[*]} (${seconds}s each)"
