"""The process-wide GPU context: which adapter is in use and what it offers."""

from __future__ import annotations

from evsplat import _core
from evsplat.errors import EvsplatError


def adapter_info() -> dict:
    """Adapter name, type, backend, driver, float32-atomic support and kernel-relevant limits.

    The adapter is chosen once per process from ``EVSPLAT_ADAPTER=auto|cpu|gpu``.
    """
    try:
        return dict(_core.adapter_info())
    except RuntimeError as e:
        raise EvsplatError(str(e)) from None


def adapter_label() -> str:
    """The adapter in one line: name (device type, backend)."""
    a = adapter_info()
    return f"{a['name']} ({a['device_type']}, {a['backend']})"
