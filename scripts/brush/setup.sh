#!/usr/bin/env bash
# Fetch Brush (ArthurBrussee/brush) for the side-by-side benchmark, outside evsplat's tree.
# Build-time only: nothing here is part of evsplat's product or wheel.
#
#   BRUSH_GIT    where to clone Brush from (default: https://github.com/ArthurBrussee/brush)
#   BRUSH_REV    the commit benchmarked (default: 8b7f5c6c, 2026-08-17)
#   BRUSH_DIR    where the checkout goes (default: $HOME/.cache/evsplat/brush)
#
# Brush's workspace pins burn's git main branch (b6e27bd) and forks of cubecl and wgpu (wasm
# and Metal fixes, none on the Vulkan path). This rewrites the checkout's workspace manifest so
# that the burn family comes from crates.io at the release that git main is 19 commits past
# (0.22.0-pre.2, with cubecl 0.11.0-pre.2 and cubek 0.3.0-pre.2) and drops the fork patches:
# then the build needs crates.io only. One source line is adapted to that cubecl release
# (below); nothing else in Brush is changed.
set -euo pipefail
BRUSH_GIT=${BRUSH_GIT:-https://github.com/ArthurBrussee/brush}
BRUSH_REV=${BRUSH_REV:-8b7f5c6c0638892204b540d9aced219f62fc2192}
BRUSH_DIR=${BRUSH_DIR:-$HOME/.cache/evsplat/brush}
here=$(cd "$(dirname "$0")" && pwd)

if [ ! -d "$BRUSH_DIR/.git" ]; then
    mkdir -p "$(dirname "$BRUSH_DIR")"
    git clone --no-checkout "$BRUSH_GIT" "$BRUSH_DIR"
fi
cd "$BRUSH_DIR"
git checkout -q -f "$BRUSH_REV" -- crates/brush-render crates/brush-cube crates/brush-sort \
    crates/brush-prefix-sum Cargo.toml
# Workspace manifest: burn from crates.io, no [patch] sections (the forks).
python3 - Cargo.toml <<'PY'
import re
import sys

path = sys.argv[1]
text = open(path).read()
text = re.sub(
    r'git = "https://github.com/tracel-ai/burn", branch = "main"',
    'version = "=0.22.0-pre.2"',
    text,
)
text = text.split("[patch.crates-io]")[0]
open(path, "w").write(text)
PY
# One line of Brush's source: cubecl 0.11.0-pre.2's `Type::new` takes a `StorageType` (the git
# revision Brush builds against took the element type); the released form of the same
# expression, in the host code that asks whether the adapter has float atomic adds.
sed -i 's/Type::new(ElemType::Float(FloatKind::F32))/Type::new(burn_cubecl::cubecl::prelude::StorageType::Scalar(ElemType::Float(FloatKind::F32)))/' \
    crates/brush-render/src/bwd/render_bwd.rs
mkdir -p "$here/../vendor"
ln -sfn "$BRUSH_DIR" "$here/../vendor/brush"
echo "Brush $(git rev-parse --short HEAD) ready at $BRUSH_DIR (linked as scripts/vendor/brush)"
