#!/usr/bin/env bash
# The demo: set-up, then the main job on the built-in tiny synthetic scene.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
exec evsplat demo "$@"
