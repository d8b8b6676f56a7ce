"""Cross-set box overlaps: every box of set A against every box of set B.

Two exact methods, chosen per box by the API (``boxes._cross_overlaps``):

*Grid* (most boxes).  Overlaps can only occur inside the region ``R`` where
the two sets' spans meet.  ``R`` is cut into a uniform grid of cells about
as wide as the boxes; every box of B is listed in each cell it overlaps (a
counting sort by cell), and every box of A visits the cells it overlaps and
tests the B boxes listed there.  A pair found in several cells is reported
in one only: the cell holding the lower corner of the two boxes'
intersection, ``max(lower_a, lower_b)`` per axis.  That corner lies in both
boxes, and cell indices are a monotone function of the coordinate (floor,
then clamped to the grid), so its cell is one both boxes are binned to: each
pair is found exactly once, without de-duplication.  Cost ``O(n + m +
cells + candidates)``.

*Sweep* (boxes spanning many cells: a floor made of two big triangles, one
sphere much bigger than the rest).  The one-axis Sweep and Prune of
Algorithm 1 of Capannini & Larsson over both sets with set labels.  Both
sets are sorted by their lower bound along the sweep axis; a pair
overlapping on that axis is found exactly once, by the box that starts
later, inside the interval of the one that starts first:

* pass A, for every ``a``: the ``b`` with ``lower_a <= lower_b <= upper_a``;
* pass B, for every ``b``: the ``a`` with ``lower_b < lower_a <= upper_b``
  (strict on the left: a tie of lower bounds belongs to pass A),

then tested on the two other axes.  Cost ``O((n + m) log(n + m) +
candidates)``.

Every pass runs twice, count then fill, in parallel over rows: each row
writes its own count, then its own slice of the output (offsets from a
prefix sum), so the result does not depend on the thread count.  Boxes are
closed (touching counts) on both paths.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numba
import numpy as np

from .._numba import ijit, jit, pjit, serial_twin

# ----------------------------------------------------------------- the grid


@ijit
def _cell(x, lo, inv, dim):
    """Cell index of coordinate ``x`` along one axis (monotone in ``x``)."""
    if inv == 0.0:
        return np.int64(0)
    c = np.floor((x - lo) * inv)
    if c < 0.0:
        return np.int64(0)
    if c >= dim - 1:
        return np.int64(dim - 1)
    return np.int64(c)


@ijit
def _cell_range(lower, upper, b, lo, inv, dims):
    """First and last grid cell of box ``b`` along each axis."""
    return (_cell(lower[b, 0], lo[0], inv[0], dims[0]), _cell(upper[b, 0], lo[0], inv[0], dims[0]),
            _cell(lower[b, 1], lo[1], inv[1], dims[1]), _cell(upper[b, 1], lo[1], inv[1], dims[1]),
            _cell(lower[b, 2], lo[2], inv[2], dims[2]), _cell(upper[b, 2], lo[2], inv[2], dims[2]))


@ijit
def _axis_extent(lower, upper, ax):
    """Lowest lower corner, highest upper corner and mean side of the boxes along
    axis ``ax``."""
    lo = np.inf
    hi = -np.inf
    side = 0.0
    for b in range(lower.shape[0]):
        lo = min(lo, lower[b, ax])
        hi = max(hi, upper[b, ax])
        side += upper[b, ax] - lower[b, ax]
    return lo, hi, side / max(lower.shape[0], 1)


@jit
def extent(lower, upper, lo, hi, side):
    """Lowest lower corner, highest upper corner and mean side per axis."""
    for ax in range(3):
        lo[ax], hi[ax], side[ax] = _axis_extent(lower, upper, ax)


@ijit
def _span(lower, upper, b, lo, inv, dims):
    """Cells of the grid box ``b`` overlaps."""
    c = np.int64(1)
    for ax in range(3):
        c *= (_cell(upper[b, ax], lo[ax], inv[ax], dims[ax])
              - _cell(lower[b, ax], lo[ax], inv[ax], dims[ax]) + 1)
    return c


@pjit
def spans(lower, upper, lo, inv, dims, out):
    """Cells of the grid each box overlaps (as :func:`bin_boxes` bins them)."""
    for b in numba.prange(lower.shape[0]):
        out[b] = _span(lower, upper, b, lo, inv, dims)


@jit
def bin_boxes(lower, upper, rows, lo, inv, dims, start, members):
    """Counting sort of the boxes ``rows`` of B into every cell they overlap.

    ``start`` (cells + 1,) zeroed on entry: CSR offsets on return; ``members``
    (insertions,): the rows, by cell.  Serial (a sort by cell; the query is
    the parallel part).
    """
    n0, n1 = dims[1], dims[2]
    for k in range(rows.shape[0]):
        b = rows[k]
        i0, i1, j0, j1, k0, k1 = _cell_range(lower, upper, b, lo, inv, dims)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for q in range(k0, k1 + 1):
                    start[(i * n0 + j) * n1 + q + 1] += 1
    for c in range(start.shape[0] - 1):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    for k in range(rows.shape[0]):
        b = rows[k]
        i0, i1, j0, j1, k0, k1 = _cell_range(lower, upper, b, lo, inv, dims)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for q in range(k0, k1 + 1):
                    c = (i * n0 + j) * n1 + q
                    members[fill[c]] = b
                    fill[c] += 1


@ijit
def _grid_row(la, ua, lb, ub, a, lo, hi, inv, dims, start, members, out, w, write):
    """Pairs of box ``a`` of A with the B boxes of the grid (count, or write at w)."""
    c = np.int64(0)
    n0, n1 = dims[1], dims[2]
    i0 = _cell(la[a, 0], lo[0], inv[0], dims[0])
    i1 = _cell(ua[a, 0], lo[0], inv[0], dims[0])
    j0 = _cell(la[a, 1], lo[1], inv[1], dims[1])
    j1 = _cell(ua[a, 1], lo[1], inv[1], dims[1])
    k0 = _cell(la[a, 2], lo[2], inv[2], dims[2])
    k1 = _cell(ua[a, 2], lo[2], inv[2], dims[2])
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            for q in range(k0, k1 + 1):
                cell = (i * n0 + j) * n1 + q
                for s in range(start[cell], start[cell + 1]):
                    b = members[s]
                    if not (la[a, 0] <= ub[b, 0] and lb[b, 0] <= ua[a, 0]
                            and la[a, 1] <= ub[b, 1] and lb[b, 1] <= ua[a, 1]
                            and la[a, 2] <= ub[b, 2] and lb[b, 2] <= ua[a, 2]):
                        continue
                    # report in the cell of the intersection's lower corner only
                    if _cell(max(la[a, 0], lb[b, 0]), lo[0], inv[0], dims[0]) != i:
                        continue
                    if _cell(max(la[a, 1], lb[b, 1]), lo[1], inv[1], dims[1]) != j:
                        continue
                    if _cell(max(la[a, 2], lb[b, 2]), lo[2], inv[2], dims[2]) != q:
                        continue
                    if write:
                        out[w + c, 0] = a
                        out[w + c, 1] = b
                    c += 1
    return c


@pjit
def grid_count(la, ua, lb, ub, rows, lo, hi, inv, dims, start, members, cnt):
    """Pairs of each box ``rows[k]`` of A with the binned boxes of B."""
    dummy = np.empty((0, 2), np.int64)
    lo0, lo1, lo2, hi0, hi1, hi2 = lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
    for k in numba.prange(rows.shape[0]):
        # the region test written out ahead of the call: most boxes of A miss the
        # region, and a call with array arguments (inlined or not) takes and drops
        # a reference per array, which costs more than the test
        a = rows[k]
        if (ua[a, 0] < lo0 or la[a, 0] > hi0 or ua[a, 1] < lo1 or la[a, 1] > hi1
                or ua[a, 2] < lo2 or la[a, 2] > hi2):
            cnt[k] = 0
        else:
            cnt[k] = _grid_row(la, ua, lb, ub, a, lo, hi, inv, dims, start, members, dummy, 0,
                               False)


@pjit
def grid_fill(la, ua, lb, ub, rows, lo, hi, inv, dims, start, members, off, out):
    """Write the pairs counted by :func:`grid_count` at the rows' offsets."""
    for k in numba.prange(rows.shape[0]):  # rows that found pairs only
        _grid_row(la, ua, lb, ub, rows[k], lo, hi, inv, dims, start, members, out, off[k], True)


@jit
def grid_query(la, ua, lb, ub, lo, hi, inv, dims, start, members, big_b, max_visit, out):
    """The grid and a few big boxes of B for every box of A in one serial pass
    (one thread: the grid's count, fill and the sweep of ``big_b`` without
    their launches, and no sort after): the pairs ``(a, b)`` in ``out``, sorted
    by ``a`` then ``b``, while they fit.  Every ``b`` of ``big_b`` is tested
    against every box of A that meets the region (few of them: boxes of B
    spanning many cells).  Returns the number of pairs (nothing past
    ``len(out)`` written: call again with room), or -1 when a box of A visits
    more than ``max_visit`` cells (the sweep takes it: the general path)."""
    n = la.shape[0]
    cap = out.shape[0]
    lo0, lo1, lo2, hi0, hi1, hi2 = lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
    w = np.int64(0)
    for a in range(n):
        if (ua[a, 0] < lo0 or la[a, 0] > hi0 or ua[a, 1] < lo1 or la[a, 1] > hi1
                or ua[a, 2] < lo2 or la[a, 2] > hi2):
            continue
        if _span(la, ua, a, lo, inv, dims) > max_visit:
            return np.int64(-1)
        c = _grid_row(la, ua, lb, ub, a, lo, hi, inv, dims, start, members, out, 0, False)
        w0 = w
        if c and w + c <= cap:
            _grid_row(la, ua, lb, ub, a, lo, hi, inv, dims, start, members, out, w, True)
        w += c
        for k in range(big_b.shape[0]):
            b = big_b[k]
            if (la[a, 0] <= ub[b, 0] and lb[b, 0] <= ua[a, 0] and la[a, 1] <= ub[b, 1]
                    and lb[b, 1] <= ua[a, 1] and la[a, 2] <= ub[b, 2]
                    and lb[b, 2] <= ua[a, 2]):
                if w < cap:
                    out[w, 0] = a
                    out[w, 1] = b
                w += 1
        if w <= cap:  # this box's partners in order (the grid lists them by cell)
            for i in range(w0 + 1, w):
                v = out[i, 1]
                j = i - 1
                while j >= w0 and out[j, 1] > v:
                    out[j + 1, 1] = out[j, 1]
                    j -= 1
                out[j + 1, 1] = v
    return w


@jit
def kept_plan_key(la, ua, lb, ub, out):
    """What the grid of a kept second set depends on, in one pass over each set:
    ``out[0]``, ``out[1]`` the lower and upper corners of B's span, ``out[2]``
    the cell sides (the larger of the two sets' mean box sides per axis, up to
    a power of two).  Returns False when the two spans do not meet (no pair)."""
    for ax in range(3):
        lo_a, hi_a, side_a = _axis_extent(la, ua, ax)
        lo_b, hi_b, side_b = _axis_extent(lb, ub, ax)
        if max(lo_a, lo_b) > min(hi_a, hi_b):
            return False
        side = max(side_a, side_b)
        if side > 0.0 and side < np.inf:
            side = 2.0 ** math.ceil(math.log2(side))
        out[0, ax] = lo_b
        out[1, ax] = hi_b
        out[2, ax] = side
    return True


# ----------------------------------------------------------------- the sweep


@pjit
def sweep_count(sa, key_a, sb, key_b, cnt_a, cnt_b):
    """Pairs found by each sorted row of A (pass A) and of B (pass B).

    ``sa``, ``sb``: the boxes sorted by lower bound on the sweep axis, as rows
    (lower, upper on the sweep axis, then the two other axes' bounds);
    ``key_a``, ``key_b``: their first columns, contiguous (binary searches on
    a column view would take and drop a reference per call).
    """
    n, m = sa.shape[0], sb.shape[0]
    for i in numba.prange(n):
        s = np.searchsorted(key_b, sa[i, 0], side="left")
        c = 0
        while s < m and sb[s, 0] <= sa[i, 1]:
            if (sa[i, 2] <= sb[s, 3] and sb[s, 2] <= sa[i, 3] and sa[i, 4] <= sb[s, 5]
                    and sb[s, 4] <= sa[i, 5]):
                c += 1
            s += 1
        cnt_a[i] = c
    for j in numba.prange(m):
        s = np.searchsorted(key_a, sb[j, 0], side="right")
        c = 0
        while s < n and sa[s, 0] <= sb[j, 1]:
            if (sb[j, 2] <= sa[s, 3] and sa[s, 2] <= sb[j, 3] and sb[j, 4] <= sa[s, 5]
                    and sa[s, 4] <= sb[j, 5]):
                c += 1
            s += 1
        cnt_b[j] = c


@pjit
def sweep_fill(sa, key_a, sb, key_b, rows_a, rows_b, off_a, off_b, out):
    """Write the pairs counted by :func:`sweep_count` (as rows of A and B)."""
    n, m = sa.shape[0], sb.shape[0]
    for i in numba.prange(n):
        s = np.searchsorted(key_b, sa[i, 0], side="left")
        w = off_a[i]
        while s < m and sb[s, 0] <= sa[i, 1]:
            if (sa[i, 2] <= sb[s, 3] and sb[s, 2] <= sa[i, 3] and sa[i, 4] <= sb[s, 5]
                    and sb[s, 4] <= sa[i, 5]):
                out[w, 0] = rows_a[i]
                out[w, 1] = rows_b[s]
                w += 1
            s += 1
    for j in numba.prange(m):
        s = np.searchsorted(key_a, sb[j, 0], side="right")
        w = off_b[j]
        while s < n and sa[s, 0] <= sb[j, 1]:
            if (sb[j, 2] <= sa[s, 3] and sa[s, 2] <= sb[j, 3] and sb[j, 4] <= sa[s, 5]
                    and sa[s, 4] <= sb[j, 5]):
                out[w, 0] = rows_a[s]
                out[w, 1] = rows_b[j]
                w += 1
            s += 1


#: the parallel kernels compiled serially (no thread-pool launch) for one thread
serial = SimpleNamespace(**{name: serial_twin(globals()[name]) for name in (
    "spans", "grid_count", "grid_fill", "sweep_count", "sweep_fill")})
