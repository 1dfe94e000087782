"""The one exception type users see: a one-line message naming the input and the fix."""

from __future__ import annotations

from typing import Callable, TypeVar

R = TypeVar("R")


class EvsplatError(Exception):
    """A user-facing error. The CLI prints its message on one line and exits with status 2."""


def core_call(source: str | None, fn: Callable[..., R], *args: object, **kwargs: object) -> R:
    """Calls the Rust core (``evsplat._core``), whose ValueError is a one-line message about bad
    input, and raises that as an EvsplatError prefixed with ``source`` (the file or argument)
    when given."""
    try:
        return fn(*args, **kwargs)
    except ValueError as e:
        raise EvsplatError(str(e) if source is None else f"{source}: {e}") from None
