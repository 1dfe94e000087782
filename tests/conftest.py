"""Shared pytest set-up: the GPU adapter is required (lavapipe in CI), never skipped."""

import os

os.environ.setdefault("XDG_RUNTIME_DIR", "/tmp")
os.environ.setdefault("EVSPLAT_QUIET", "1")
