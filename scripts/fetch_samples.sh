#!/usr/bin/env bash
# Unpacks the real recordings that registry packages ship in their sdists into
# tests/data/external/ (ignored by git), for the tests that skip without them. Only `aedat`
# ships any (see docs/results.md, issue 24): its 6 MB DAVIS346 recording, test_data.aedat4.
# pip prepares the sdist's metadata after downloading it (a maturin build: needs cargo).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
dest="$root/tests/data/external"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$dest"
"${PYTHON:-python}" -m pip download --no-deps --no-binary aedat -d "$tmp" "aedat==2.3.0"
tar -xzf "$tmp"/aedat-2.3.0.tar.gz -C "$tmp"
cp "$tmp"/aedat-2.3.0/tests/data/*.aedat4 "$dest"/
cp "$tmp"/aedat-2.3.0/LICENSE "$dest"/aedat-LICENSE
ls -l "$dest"
