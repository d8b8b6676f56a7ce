"""Cross-set box overlaps: every box of set A against every box of set B.

A one-axis Sweep and Prune over the two sets with set labels (the sweep of
Algorithm 1 of Capannini & Larsson, where only pairs of different labels are
kept).  Both sets are sorted by their lower bound along the sweep axis; a
pair ``(a, b)`` overlapping on that axis is found exactly once, by the box
that starts *later* along the axis, inside the interval of the one that starts
first:

* pass A, for every ``a``: the ``b`` with ``lower_a <= lower_b <= upper_a``
  (a range of B's sorted lower bounds, two binary searches);
* pass B, for every ``b``: the ``a`` with ``lower_b < lower_a <= upper_b``
  (strict on the left: a tie of lower bounds belongs to pass A).

Each candidate is then tested on the two other axes (closed boxes).  Cost
``O((n + m) log(n + m) + candidates)``; the candidates are the pairs that
overlap on the sweep axis, so the API picks the axis along which the boxes
are thinnest relative to their spread.

Both passes run twice, count then fill, in parallel over rows: every row
writes its own count and then its own slice of the output (offsets from a
prefix sum), so the result does not depend on the thread count.
"""

from __future__ import annotations

from types import SimpleNamespace

import numba
import numpy as np

from .._numba import ijit, pjit, serial_twin


@ijit
def _overlap(la, ua, lb, ub, i, j, a0, a1):
    """Closed overlap of box ``i`` of A and box ``j`` of B on axes a0 and a1."""
    return (la[i, a0] <= ub[j, a0] and lb[j, a0] <= ua[i, a0]
            and la[i, a1] <= ub[j, a1] and lb[j, a1] <= ua[i, a1])


@pjit
def count(la, ua, lb, ub, axis, key_a, order_a, key_b, order_b, cnt_a, cnt_b):
    """Pairs found by each row of A (pass A) and each row of B (pass B).

    ``key_a``/``key_b``: the lower bounds along ``axis`` sorted ascending;
    ``order_a``/``order_b``: the rows in that order.
    """
    a0 = (axis + 1) % 3
    a1 = (axis + 2) % 3
    n = la.shape[0]
    m = lb.shape[0]
    for i in numba.prange(n):
        lo = np.searchsorted(key_b, la[i, axis], side="left")
        hi = np.searchsorted(key_b, ua[i, axis], side="right")
        c = 0
        for s in range(lo, hi):
            if _overlap(la, ua, lb, ub, i, order_b[s], a0, a1):
                c += 1
        cnt_a[i] = c
    for j in numba.prange(m):
        lo = np.searchsorted(key_a, lb[j, axis], side="right")
        hi = np.searchsorted(key_a, ub[j, axis], side="right")
        c = 0
        for s in range(lo, hi):
            if _overlap(la, ua, lb, ub, order_a[s], j, a0, a1):
                c += 1
        cnt_b[j] = c


@pjit
def fill(la, ua, lb, ub, axis, key_a, order_a, key_b, order_b, off_a, off_b, out):
    """Write the pairs counted by :func:`count` at the rows' offsets."""
    a0 = (axis + 1) % 3
    a1 = (axis + 2) % 3
    n = la.shape[0]
    m = lb.shape[0]
    for i in numba.prange(n):
        lo = np.searchsorted(key_b, la[i, axis], side="left")
        hi = np.searchsorted(key_b, ua[i, axis], side="right")
        w = off_a[i]
        for s in range(lo, hi):
            j = order_b[s]
            if _overlap(la, ua, lb, ub, i, j, a0, a1):
                out[w, 0] = i
                out[w, 1] = j
                w += 1
    for j in numba.prange(m):
        lo = np.searchsorted(key_a, lb[j, axis], side="right")
        hi = np.searchsorted(key_a, ub[j, axis], side="right")
        w = off_b[j]
        for s in range(lo, hi):
            i = order_a[s]
            if _overlap(la, ua, lb, ub, i, j, a0, a1):
                out[w, 0] = i
                out[w, 1] = j
                w += 1


#: the serial builds (no thread-pool launch) for one thread
serial = SimpleNamespace(count=serial_twin(count), fill=serial_twin(fill))
