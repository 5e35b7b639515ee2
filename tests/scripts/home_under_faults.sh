#!/usr/bin/env bash
# `qhm rig home both` against `qhm sim --pty` under line faults, N times,
# one rig seed each: prints the runs that failed and the count.
#   tests/scripts/home_under_faults.sh [QHM] [N] [FIRST_SEED]
# QHM defaults to target/release/qhm. The fault mix is docs/link.md's.
set -u
qhm=${1:-target/release/qhm}
n=${2:-20}
first=${3:-1}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
fails=0
for seed in $(seq "$first" $((first + n - 1))); do
    "$qhm" sim --pty --drop 0.01 --corrupt 0.001 --duplicate 0.01 --seed "$seed" \
        >"$tmp/pty" 2>/dev/null &
    sim=$!
    port=""
    for _ in $(seq 50); do
        port=$(head -1 "$tmp/pty" 2>/dev/null)
        [ -n "$port" ] && break
        sleep 0.1
    done
    if ! timeout 120 "$qhm" rig --port "$port" home both >"$tmp/log" 2>&1; then
        fails=$((fails + 1))
        echo "seed $seed failed: $(tail -2 "$tmp/log" | tr '\n' ' ')"
    fi
    kill "$sim" 2>/dev/null
    wait "$sim" 2>/dev/null
done
echo "$fails of $n runs failed"
[ "$fails" -eq 0 ]
