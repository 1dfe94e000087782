#!/usr/bin/env bash
# Every test: set-up, Rust tests (GPU kernels on lavapipe or a real GPU), lint, pytest.
set -euo pipefail
start=$(date +%s)
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"

echo "== cargo test"
cargo test --workspace --exclude evsplat-py --release
echo "== lint"
cargo fmt --all -- --check
cargo clippy --workspace --all-targets --release -q -- -D warnings
ruff check python tests
echo "== pytest"
# Exit code 5 (no tests collected) is a failure too: set -e stops on it.
python -m pytest -q -m "not benchmark" --durations=20 "$@"
echo "all tests passed in $(( $(date +%s) - start )) s"
