"""Input checks fused into one pass without temporaries (the API raises)."""

from __future__ import annotations

import numpy as np

from .._numba import jit

OK = 0
NONFINITE_LOWER = 1
NONFINITE_UPPER = 2
INVERTED = 3


@jit
def check_boxes(lower, upper):
    """Return ``(status, row, axis)`` of the first bad entry, or ``(OK, -1, -1)``."""
    n = lower.shape[0]
    for i in range(n):
        for a in range(3):
            lo = lower[i, a]
            hi = upper[i, a]
            if not np.isfinite(lo):
                return NONFINITE_LOWER, i, a
            if not np.isfinite(hi):
                return NONFINITE_UPPER, i, a
            if lo > hi:
                return INVERTED, i, a
    return OK, -1, -1
