#!/usr/bin/env bash
# The real rig's path rehearsed on one machine: the emulated MCU served on a
# pseudo-terminal by a separate `qhm sim --pty` process and reached with
# --port, and real GenICam cameras (Aravis's fake GigE camera, one process per
# arc position on 127.0.0.2..8) fired by software on the MCU's trigger-fired
# events (`--camera N=ADDRESS,trigger=software`).
#
# Checks, failing loudly on the first miss:
#  1. a camera given without trigger=software is refused in one line, and no
#     capture directory is left;
#  2. `qhm capture run --scale ci` is killed with SIGKILL mid-capture, resumed
#     with --resume, and completes: every frame journaled before the kill is
#     byte-identical afterwards, every journaled frame matches its sha256, the
#     frame files are exactly the plan's, and a validating reopen passes;
#  3. `qhm calibrate capture --scale ci` runs through the same path, is killed
#     and resumed the same way, and completes with the journaled frames
#     intact;
#  4. `qhm calibrate compute` on those frames (the fake camera's test
#     pattern, not the targets) stops with one line naming the camera and the
#     target it could not find, without a panic and without writing the
#     calibration file.
# Usage: tests/scripts/rehearsal.sh [QHM_BINARY]  (default: builds qhm with
# --profile test --features aravis). Installs Debian's Aravis if missing.
set -euo pipefail
cd "$(dirname "$0")/../.."
t_start=$(date +%s)

fail() {
    echo "REHEARSAL FAILED: $*" >&2
    exit 1
}

need=()
pkg-config --exists aravis-0.8 2>/dev/null || need+=(libaravis-dev libusb-1.0-0-dev)
command -v arv-fake-gv-camera-0.8 >/dev/null || need+=(aravis-tools)
command -v ip >/dev/null || need+=(iproute2)
if ((${#need[@]})); then
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${need[@]}"
fi

work=$(mktemp -d /tmp/qhm-rehearsal.XXXXXX)
if [ $# -ge 1 ]; then
    cp "$1" "$work/qhm"
else
    # The test profile (optimised, target/debug): after the test suite only
    # the crates the feature changes are rebuilt.
    cargo build --profile test -p host --features aravis
    # A private copy: a later build of qhm without the feature cannot swap it mid-run.
    cp target/debug/qhm "$work/qhm"
fi
qhm="$work/qhm"
t_built=$(date +%s)

pids=()
added=()
sudo=""
[ "$(id -u)" -eq 0 ] || sudo="sudo"
cleanup() {
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    for a in "${added[@]}"; do $sudo ip addr del "$a/32" dev lo 2>/dev/null || true; done
}
trap cleanup EXIT

# The fake camera listens on an interface's own address: give loopback
# 127.0.0.2..8 (removed again at the end).
for n in 1 2 3 4 5 6 7; do
    a="127.0.0.$((n + 1))"
    ip -4 addr show dev lo | grep -q "inet $a/" && continue
    $sudo ip addr add "$a/32" dev lo || fail "cannot add $a to the loopback interface"
    added+=("$a")
done

# The emulated MCU: its stdin is held open by a fifo (closing it stops the server).
mkfifo "$work/pty.in"
"$qhm" sim --pty <"$work/pty.in" >"$work/pty.out" 2>"$work/pty.err" &
pids+=($!)
exec 9>"$work/pty.in"
port=""
for _ in $(seq 100); do
    port=$(grep -m1 -o '/dev/[^ ]*' "$work/pty.out" || true)
    [ -n "$port" ] && break
    sleep 0.1
done
[ -n "$port" ] || fail "qhm sim --pty printed no device: $(cat "$work/pty.err")"
echo "emulated MCU on $port"

# One fake camera per arc position the plans use (1..7), serials QHMFAKE1..7.
cams=()
for n in 1 2 3 4 5 6 7; do
    arv-fake-gv-camera-0.8 -i "127.0.0.$((n + 1))" -s "QHMFAKE$n" >"$work/fake$n.log" 2>&1 &
    pids+=($!)
    cams+=(--camera "$n=127.0.0.$((n + 1)),trigger=software")
done
sleep 1
for p in "${pids[@]}"; do kill -0 "$p" || fail "a fake camera or the MCU did not start"; done

# Frames journaled so far: "sha256 path" per line.
# (A line cut short by the kill has no seal yet and does not count.)
journaled() { awk '$1 == "frame" && NF == 8 && $8 ~ /^~/ {print $5, $7}' "$1/journal"; }

# Every journaled frame matches its sha256; with "all", the frame files are
# exactly the journal's (after a kill, the frame being written may be extra).
check_journal() {
    local dir=$1 all=${2:-} n=0
    while read -r sha path; do
        [ -f "$dir/$path" ] || fail "$dir: journaled frame $path is missing"
        [ "$(sha256sum "$dir/$path" | cut -d' ' -f1)" = "$sha" ] || fail "$dir: $path does not match its journal hash"
        n=$((n + 1))
    done < <(journaled "$dir")
    if [ "$all" = all ]; then
        local files
        files=$(find "$dir/frames" -type f | wc -l)
        [ "$files" = "$n" ] || fail "$dir: $files frame files for $n journaled frames"
    fi
    echo "$dir: $n journaled frames, every one matching its hash"
}

# Runs "$@" in the background and kills it with SIGKILL once DIR's journal holds N frames.
kill_after_frames() {
    local dir=$1 n=$2 log=$3
    shift 3
    "$@" >"$log" 2>&1 &
    local pid=$!
    for _ in $(seq 1200); do
        if [ -f "$dir/journal" ] && [ "$(grep -ac '^frame ' "$dir/journal")" -ge "$n" ]; then
            kill -9 "$pid"
            wait "$pid" 2>/dev/null || true
            # A GigE camera keeps a dead host's control privilege until its
            # heartbeat times out (the fake camera: 3 s); only then can it be reopened.
            sleep 4
            echo "killed qhm (SIGKILL) with $(grep -ac '^frame ' "$dir/journal") frames journaled"
            return 0
        fi
        kill -0 "$pid" 2>/dev/null || { cat "$log" >&2; fail "qhm ended before it was killed"; }
        sleep 0.1
    done
    kill -9 "$pid"
    fail "no $n frames within 120 s: $(tail -3 "$log")"
}

# 1. A camera that cannot see the trigger lines must be told so.
cap="$work/capture"
set +e
out=$("$qhm" capture run --port "$port" --camera 3=127.0.0.4 --camera 5=127.0.0.6 --camera 7=127.0.0.8 \
    --scale ci --yes --quiet -o "$cap" 2>&1)
rc=$?
set -e
[ $rc -ne 0 ] || fail "a camera on a trigger line the fake camera lacks was accepted"
grep -q "trigger source Line1" <<<"$out" || fail "unclear refusal: $out"
[ ! -e "$cap" ] || fail "a refused start left $cap"
echo "refused as it should be: $(tail -1 <<<"$out")"

# 2. A short capture, killed and resumed.
run=("$qhm" capture run --port "$port" "${cams[@]}" --scale ci --yes --quiet --frame-timeout 20 -o "$cap")
t0=$(date +%s)
kill_after_frames "$cap" 60 "$work/capture1.log" "${run[@]}"
journaled "$cap" >"$work/capture.before"
check_journal "$cap"
"${run[@]}" --resume >"$work/capture2.log" 2>&1 || { cat "$work/capture2.log" >&2; fail "the resumed capture failed"; }
grep -q "capture complete" "$work/capture2.log" || fail "capture not complete: $(tail -2 "$work/capture2.log")"
t1=$(date +%s)
check_journal "$cap" all
planned=$("$qhm" capture plan --scale ci --json | sed -n 's/^ *"frames": \([0-9]*\),*$/\1/p' | head -1)
[ "$(grep -ac '^frame ' "$cap/journal")" = "$planned" ] || fail "$cap: not the plan's $planned frames"
while read -r sha path; do
    [ "$(sha256sum "$cap/$path" | cut -d' ' -f1)" = "$sha" ] || fail "$path changed across the resume"
done <"$work/capture.before"
echo "the $(wc -l <"$work/capture.before") frames taken before the kill are unchanged"
# A validating reopen (journal replay, every frame's size and hash) of the finished capture.
"${run[@]}" --resume 2>&1 | grep -q "already complete" || fail "$cap does not reopen as a complete capture"
echo "capture run: complete, $planned frames, $((t1 - t0)) s including the kill and the resume"

# 3. The calibration capture through the same path.
cal="$work/calibration-capture"
crun=("$qhm" calibrate capture --port "$port" "${cams[@]}" --scale ci --yes --quiet --frame-timeout 20 -o "$cal")
t0=$(date +%s)
kill_after_frames "$cal" 40 "$work/cal1.log" "${crun[@]}"
journaled "$cal" >"$work/cal.before"
check_journal "$cal"
set +e
"${crun[@]}" --resume >"$work/cal2.log" 2>&1
rc=$?
set -e
t1=$(date +%s)
[ $rc -eq 0 ] || fail "the calibration capture did not complete: $(tail -3 "$work/cal2.log")"
echo "calibration capture complete"
set +e
"$qhm" calibrate compute "$cal" -o "$work/calibration.toml" >"$work/compute.log" 2>&1
rc=$?
set -e
[ $rc -ne 0 ] || fail "calibrate compute accepted the fake camera's test pattern"
grep -q "panicked" "$work/compute.log" && fail "calibrate compute panicked: $(cat "$work/compute.log")"
[ ! -e "$work/calibration.toml" ] || fail "calibrate compute left a calibration file"
refusal=$(tail -1 "$work/compute.log")
grep -qE "camera [0-9]" <<<"$refusal" || fail "calibrate compute's refusal names no camera: $refusal"
grep -qiE "checkerboard|colour|white|two-height|target" <<<"$refusal" ||
    fail "calibrate compute's refusal names no target: $refusal"
echo "calibrate compute refused: $refusal"
check_journal "$cal" all
while read -r sha path; do
    [ "$(sha256sum "$cal/$path" | cut -d' ' -f1)" = "$sha" ] || fail "$path changed across the resume"
done <"$work/cal.before"
echo "calibration capture: $(grep -ac '^frame ' "$cal/journal") frames, the $(wc -l <"$work/cal.before") from before the kill unchanged, $((t1 - t0)) s"

t_end=$(date +%s)
echo "rehearsal passed in $((t_end - t_start)) s ($((t_end - t_built)) s after the build)"
rm -rf "$work"
