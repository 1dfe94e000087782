"""A stress case, the tally of outcomes, and the check that turns one into the other."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from evsplat.errors import EvsplatError

Arrays = Sequence[np.ndarray | torch.Tensor | float]


@dataclass
class Case:
    """One stress case: ``run()`` returns the arrays that must be finite (and may assert its own
    oracle); ``expect`` is "finite" for valid input, "error" for input that must be refused, or
    "either" for input that may be refused with a clear error."""

    component: str
    label: str
    run: Callable[[], Arrays | None]
    expect: str = "finite"


@dataclass
class Tally:
    """Outcome counts of one component."""

    cases: int = 0
    finite: int = 0
    refused: int = 0  # invalid input refused with a clear error, as expected
    nonfinite: int = 0
    failures: list[str] = field(default_factory=list)

    @property
    def failed(self) -> int:
        return len(self.failures)


def _all_finite(values: Arrays | None) -> bool:
    for v in values or ():
        if isinstance(v, torch.Tensor):
            if v.is_floating_point() and not bool(torch.isfinite(v).all()):
                return False
        elif not np.all(np.isfinite(np.asarray(v, dtype=np.float64))):
            return False
    return True


def _clear(e: BaseException) -> bool:
    msg = str(e)
    return isinstance(e, EvsplatError | ValueError) and bool(msg.strip()) and "\n" not in msg


def check_case(case: Case, tally: Tally) -> None:
    """Run one case and record its outcome in ``tally``."""
    tally.cases += 1
    where = f"{case.component}/{case.label}"
    try:
        out = case.run()
    except Exception as e:  # anything else than a clear error is the bug being hunted
        if case.expect in ("error", "either") and _clear(e):
            tally.refused += 1
        else:
            tally.failures.append(f"{where}: {type(e).__name__}: {str(e)[:200]}")
        return
    if case.expect == "error":
        tally.failures.append(f"{where}: invalid input accepted without an error")
    elif not _all_finite(out):
        tally.nonfinite += 1
        tally.failures.append(f"{where}: NaN/Inf in the outputs or gradients")
    else:
        tally.finite += 1


def grads(*tensors: torch.Tensor) -> list[torch.Tensor]:
    return [t.grad if t.grad is not None else torch.zeros(0) for t in tensors]


def leaf(a: np.ndarray | torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a), dtype=torch.float32).clone().requires_grad_(True)
