"""``python -m evsplat.sweep.child PARENT_PID COMMAND ...``: the evsplat CLI in a process that
is killed with the worker that started it, so a worker killed mid-cell leaves no orphan
training behind to compete with the cell's retry (Linux; elsewhere the child outlives it)."""

from __future__ import annotations

import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>


def main(argv: list[str]) -> int:
    parent = int(argv[0])
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (AttributeError, OSError):
        pass
    if os.getppid() != parent:  # the worker died before the signal was armed
        return 1
    from evsplat.cli import main as cli

    return cli(argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
