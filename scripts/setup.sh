#!/usr/bin/env bash
# Idempotent set-up shared by scripts/demo.sh and scripts/test.sh:
# Vulkan software driver (lavapipe) -> .venv with Python deps (uv) -> native extension (maturin).
# Each step is skipped when already done, so a second run takes seconds.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
VENV="$ROOT/.venv"
# Rust build outputs live outside the repo so clean clones (CI) reuse them.
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$HOME/.cache/evsplat/target}"
# The Vulkan loader warns when this is unset; it is harmless, so give it a value.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp}"
export PATH="$VENV/bin:$PATH"

say() { printf 'evsplat setup: %s\n' "$*" >&2; }
need_root() {
    if [ "$(id -u)" = 0 ]; then
        return 0
    fi
    say "$1 is missing and this is not root; run: sudo apt-get install -y $2"
    return 1
}
apt_install() {
    say "installing $* (apt-get)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}

# 1. System packages: Vulkan loader + lavapipe, and Python's venv module.
if ! ldconfig -p 2>/dev/null | grep -q 'libvulkan.so.1' || ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1; then
    if need_root "the Vulkan software driver (lavapipe)" "mesa-vulkan-drivers libvulkan1"; then
        apt_install mesa-vulkan-drivers libvulkan1
    fi
fi
command -v python3 >/dev/null || { need_root python3 "python3 python3-venv" && apt_install python3 python3-venv; }
if ! command -v cargo >/dev/null; then
    say "cargo (Rust >= 1.85) is required to build the native extension; install it with rustup"
    exit 1
fi

# 2. Virtual environment with uv (fast, cached installs of torch and friends).
if [ ! -x "$VENV/bin/python" ]; then
    if ! python3 -m venv "$VENV" 2>/dev/null; then
        need_root "python3-venv" "python3-venv" && apt_install python3-venv
        python3 -m venv "$VENV"
    fi
fi
if ! command -v uv >/dev/null; then
    say "installing uv into .venv"
    "$VENV/bin/python" -m pip install -q uv
fi
# "bytecode" in the hash: a .venv installed before that step gets it once.
deps_hash=$( (cat pyproject.toml; echo bytecode) | sha256sum | cut -c1-16)
if [ "$(cat "$VENV/.evsplat-deps" 2>/dev/null)" != "$deps_hash" ]; then
    say "installing Python dependencies into .venv"
    uv pip install -q --python "$VENV/bin/python" -r pyproject.toml --extra test --extra ray "maturin>=1.5,<2"
    # uv writes no .pyc files, and where PYTHONDONTWRITEBYTECODE is set no process does either:
    # each Python process (a sweep cell, a test's CLI child) then compiled torch's sources again,
    # ~10 s of CPU on 2 cores. Some files are for a newer Python than this one (torch's test
    # helpers in 3.12 syntax), so compileall's exit status is not a failure of the set-up.
    say "compiling their bytecode (once, a minute or two)"
    site=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_path("purelib"))')
    "$VENV/bin/python" -m compileall -q -j 0 "$site" >/dev/null || true
    echo "$deps_hash" >"$VENV/.evsplat-deps"
fi

# 3. Native extension, rebuilt only when Rust sources, shaders or build files change.
src_hash=$(find crates shaders Cargo.toml Cargo.lock pyproject.toml -type f 2>/dev/null \
    -not -path '*/target/*' | LC_ALL=C sort | xargs sha256sum | sha256sum | cut -c1-16)
if [ "$(cat "$VENV/.evsplat-native" 2>/dev/null)" != "$src_hash" ] \
    || ! ls python/evsplat/_core*.so >/dev/null 2>&1; then
    say "building the native extension (maturin develop --release)"
    maturin develop --release --uv -q 2>&1 | grep -vE '^\s*(Compiling|Building|Finished|Installed)' >&2 || true
    ls python/evsplat/_core*.so >/dev/null 2>&1 || { say "maturin build failed"; exit 1; }
    echo "$src_hash" >"$VENV/.evsplat-native"
fi
