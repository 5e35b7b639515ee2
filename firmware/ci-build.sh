#!/usr/bin/env bash
# Cross-build the board binary for the Nucleo-F446RE and print its flash and
# RAM use. Follows shared/toolchain/firmware-cross-build.md: Debian's Rust
# (with library sources) builds `core` from source for thumbv7em-none-eabihf,
# since rustup cannot fetch the target on these machines. Idempotent: installs
# the packages and links the toolchain only if missing.
set -euo pipefail
cd "$(dirname "$0")/.."

TARGET=thumbv7em-none-eabihf
PKGS=(rustc-web cargo-web rust-web-src lld-22 llvm-22)

missing=()
for p in "${PKGS[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
    SUDO=""
    [ "$(id -u)" = 0 ] || SUDO="sudo"
    echo "installing ${missing[*]}"
    $SUDO apt-get update -q
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q "${missing[@]}"
fi
if ! rustup toolchain list | grep -q '^debian-web'; then
    rustup toolchain link debian-web /usr
fi

export RUSTC_BOOTSTRAP=1
export CARGO_UNSTABLE_BUILD_STD=core,alloc
export CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER=ld.lld-22
cargo +debian-web build -p firmware --release --target "$TARGET" --features stm32

elf="${CARGO_TARGET_DIR:-target}/$TARGET/release/firmware"
size_tool=$(command -v llvm-size-22 || command -v llvm-size || true)
if [ -z "$size_tool" ]; then
    echo "llvm-size not found; built $elf" >&2
    exit 0
fi
"$size_tool" "$elf"
# Flash: everything loaded into flash; RAM: static data (stack comes on top).
"$size_tool" -A "$elf" | awk '
    $1 ~ /^\.(vector_table|text|rodata)$/ { flash += $2 }
    $1 == ".data" { flash += $2; ram += $2 }
    $1 ~ /^\.(bss|uninit)$/ { ram += $2 }
    END {
        printf "firmware flash: %d bytes (%.1f%% of 512 KiB)\n", flash, 100 * flash / 524288
        printf "firmware RAM:   %d bytes static (%.1f%% of 128 KiB)\n", ram, 100 * ram / 131072
    }'
