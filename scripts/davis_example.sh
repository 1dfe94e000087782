#!/usr/bin/env bash
# The worked example on a real recording (docs/real-data.md, "A DAVIS346 recording, end to
# end"): the DAVIS346 sample that scripts/fetch_samples.sh unpacks (static camera, 2.36 s,
# 78,830 events), converted as a static-camera dataset, checked, trained with 8 held-out 50 ms
# windows, scored on them, rendered to a video (each moving object's pixels too) and exported
# (PLYs, and each moving object's track).
#   scripts/davis_example.sh [OUT]      (default OUT: davis; PRESET=tiny ITERS=2000 by default,
#                                        the settings docs/real-data.md reports)
# Set EVSPLAT to another command (e.g. "python -m evsplat.cli") to run a checkout's code.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="${1:-davis}"
iters="${ITERS:-2000}"
preset="${PRESET:-tiny}"
evsplat=(${EVSPLAT:-evsplat})
sample="$root/tests/data/external/test_data.aedat4"
[ -f "$sample" ] || "$root/scripts/fetch_samples.sh"
rm -rf "$out"
mkdir -p "$out/data"
# No calibration ships with the sample: the focal length is guessed (a loud warning says so).
"${evsplat[@]}" convert "$sample" "$out/data/events.h5" --static-camera
"${evsplat[@]}" check "$out/data"
# 8 windows of 0.0212 of the 2.36 s: 50 ms each, never read by training.
"${evsplat[@]}" train "$out/data" --out "$out/run" --preset "$preset" --iters "$iters" \
    --holdout 8:0.0212 --no-progress
"${evsplat[@]}" eval "$out/run" "$out/data"
"${evsplat[@]}" render "$out/run" --times 0:1:0.01 --out "$out/frames" --video --objects
"${evsplat[@]}" export "$out/run" --tracks "$out/tracks.csv"
"${evsplat[@]}" export "$out/run" --times 0:1:0.25 --ply-dir "$out/plys"
