#!/usr/bin/env bash
# The Aravis camera backend against Aravis's fake GigE Vision camera on
# loopback. Installs Debian's Aravis 0.8 (libaravis-dev, libusb-1.0-0-dev for
# aravis-0.8.pc, aravis-tools for the fake camera) if missing, starts the fake
# camera, runs the feature-gated test, stops the camera.
set -euo pipefail
cd "$(dirname "$0")/../.."

need=()
pkg-config --exists aravis-0.8 2>/dev/null || need+=(libaravis-dev libusb-1.0-0-dev)
command -v arv-fake-gv-camera-0.8 >/dev/null || need+=(aravis-tools)
if ((${#need[@]})); then
    sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${need[@]}"
fi
echo "Aravis $(pkg-config --modversion aravis-0.8)"

# Build first, so the camera does not wait through the compile.
cargo test -p qhm-acquire --features aravis --test aravis_fake --no-run

arv-fake-gv-camera-0.8 -i 127.0.0.1 &
fake=$!
trap 'kill "$fake" 2>/dev/null || true; wait "$fake" 2>/dev/null || true' EXIT
sleep 1
kill -0 "$fake" || { echo "the fake camera did not start"; exit 1; }

QHM_ARAVIS_FAKE=running cargo test -p qhm-acquire --features aravis --test aravis_fake -- --ignored --nocapture
