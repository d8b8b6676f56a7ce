"""Slow, readable reference implementations the engine is checked against.

Nothing here is clever: every function is the definition written as loops
over all pairs (vectorised per row with numpy), so it can be trusted on small
inputs.
"""

from __future__ import annotations

import numpy as np


def _as_pair_array(pairs):
    if len(pairs) == 0:
        return np.empty((0, 2), dtype=np.int64)
    return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)


def sort_pairs(pairs):
    """Return ``pairs`` (k, 2) in lexicographic row order, as int64."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order]


def brute_box_overlaps(lower, upper):
    """All pairs ``i < j`` of closed boxes that overlap on every axis."""
    lower = np.asarray(lower, dtype=np.float64)
    upper = np.asarray(upper, dtype=np.float64)
    n = len(lower)
    out = []
    for i in range(n):
        j = np.arange(i + 1, n)
        ok = np.all((lower[i] <= upper[j]) & (lower[j] <= upper[i]), axis=1)
        out.extend((i, int(jj)) for jj in j[ok])
    return _as_pair_array(out)
