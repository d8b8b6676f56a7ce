"""Column sweep for axis-aligned boxes: the second path of ``SweepAndPrune``.

About the algorithm
-------------------
Boxes are closed: ``i`` and ``j`` overlap iff ``lower_i <= upper_j`` and
``lower_j <= upper_i`` on all three axes.

*Sizes.*  One pass (``measure``) finds, per chunk of boxes, the span of the
box centres on every axis and a histogram of ``r = `` the largest side of each
box by binary exponent (``frexp``), with the largest side per axis of every
exponent bucket.  The API picks from it a size limit (a power of two): boxes
at or above it are *big* (at most a sixteenth of them, and only boxes at least
twice the median size), the others *small*.  Big boxes go to a separate list,
so a few large boxes do not fatten every column.

*Columns.*  Two axes ``c0, c1`` are cut into ``nb0 x nb1`` columns of width
``w_a >= `` the largest side ``E_a`` of any small box on that axis (the API
takes twice that, with a relative margin that covers rounding), and small
boxes are binned by their centre.  Two small boxes that overlap have centres
at most ``(e_i + e_j) / 2 <= E_a`` apart on axis ``a``, so they lie in the same
column or in neighbouring ones (3 x 3 stencil); the third axis ``z`` is the
sweep axis.  Binning clamps to the grid, which keeps neighbouring columns
neighbours, so boxes outside the binned range are still exact.  Boxes are stored
column by column, sorted inside each column by ``(lower_z, id)``, as a
structure of arrays (``xl, xu, yl, yu, zl, zu, ids``: the column axes, then
the sweep axis), so the sweep streams through contiguous memory.  The order
is built by a stable counting sort by column over the previous frame's order,
then an insertion sort inside each column, which temporal coherence keeps
close to linear (a fresh order, or one that moved too much, falls back to a
merge sort per column).  This is the multi-SaP of Tracy, Buss and Woods (2009)
and Terdiman (2007): a one-axis Sweep and Prune inside each cell of a grid.

*Sweep.*  Each pair is reported by the box that comes first in the total
order ``(lower_z, id)``: box ``p`` scans, in its own column and in each
neighbouring column that can hold the centre of a small box meeting it (its
extent widened by ``E_a / 2``: one to nine columns), the boxes ``q`` after it
in that order whose ``lower_z <= upper_z(p)`` (every such ``q`` overlaps
``p`` on ``z``) and tests the two column axes.  Each unordered pair is found
exactly once and nothing is de-duplicated.  A pointer per neighbouring column
keeps the first box after the last ``p`` that visited it (it only moves
forward as ``p`` walks its sorted column), so the window costs no search.
With that forward rule the window is ``p``'s own side, so a wide spread of
sizes does not lengthen every window.  When sizes are close (the largest small
side on ``z`` at most twice the mean) the half stencil is cheaper: ``p`` visits
only the 4 neighbours ``(0, +1), (+1, -1), (+1, 0), (+1, +1)`` of its range,
with windows ``lower_z in [lower_z(p) - max side, upper_z(p)]`` (the cross-
column pair belongs to the box in the earlier column): half the visits for
windows longer by the largest side (0.14 against 0.18 core-s for the sweep of
2^20 paper boxes).

*Big boxes.*  Each big box tests the small boxes of every column its
footprint can reach (its extent plus one column) whose ``lower_z`` lies in
``[lower_z(b) - max small side on z, upper_z(b)]`` (binary search, then a
scan), with the full three-axis test; pairs of two big boxes are left to the
caller (the API runs the paper's sweep on them).

Cost: O(n) for measuring, binning, sorting and gathering; O(candidates) for
the sweep, about ``(e_0 + E_0 + w_0) (e_1 + E_1 + w_1) rho e_z`` per box of
sides ``e`` for uniform density ``rho`` (7.6 candidates per pair found for the
paper's boxes at density 0.35).
Parallel work is cut into chunks of whole columns (or of big boxes) whose
boundaries depend only on the input, never on the thread count; each chunk
writes into its own region of the output (sized from the previous frame, and
re-run alone when it overflows), so results do not depend on the thread count.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numba
import numpy as np

from .._numba import hjit, ijit, jit, pjit, serial_twin
from .common import lower_bound, stable_argsort

#: exponent buckets of the size histogram: 0 holds zero-size boxes, ``b``
#: holds sides with ``frexp`` exponent ``b - OFFSET`` (``2**(e-1) <= r < 2**e``),
#: the last one non-finite sides
OFFSET = 1100
NBUCKETS = 2 * OFFSET + 2


@ijit
def _bucket(r):
    if r == 0.0:
        return 0
    if not r < np.inf:
        return NBUCKETS - 1
    e = math.frexp(r)[1]
    b = e + OFFSET
    if b < 1:
        return 1
    if b > NBUCKETS - 2:
        return NBUCKETS - 2
    return b


@ijit
def _side(lower, upper, i):
    return max(upper[i, 0] - lower[i, 0], max(upper[i, 1] - lower[i, 1],
                                              upper[i, 2] - lower[i, 2]))


@pjit
def measure(lower, upper, cmin, cmax, ssum, hist, hext):
    """Per chunk ``c`` of boxes: centre span ``cmin[c], cmax[c]`` (3,), the sum
    of the sides per axis ``ssum[c]``, the histogram ``hist[c]`` of size
    buckets and ``hext[c, b]`` the largest side per axis of the boxes in bucket
    ``b``.  Chunk ``c`` covers boxes ``[c n / m, (c + 1) n / m)`` for
    ``m = len(cmin)``."""
    n = lower.shape[0]
    m = cmin.shape[0]
    for c in numba.prange(m):
        lo = c * n // m
        hi = (c + 1) * n // m
        for b in range(NBUCKETS):
            hist[c, b] = 0
            for a in range(3):
                hext[c, b, a] = 0.0
        mn0 = np.inf
        mn1 = np.inf
        mn2 = np.inf
        mx0 = -np.inf
        mx1 = -np.inf
        mx2 = -np.inf
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for i in range(lo, hi):
            x = 0.5 * lower[i, 0] + 0.5 * upper[i, 0]
            y = 0.5 * lower[i, 1] + 0.5 * upper[i, 1]
            z = 0.5 * lower[i, 2] + 0.5 * upper[i, 2]
            mn0 = min(mn0, x)
            mn1 = min(mn1, y)
            mn2 = min(mn2, z)
            mx0 = max(mx0, x)
            mx1 = max(mx1, y)
            mx2 = max(mx2, z)
            e0 = upper[i, 0] - lower[i, 0]
            e1 = upper[i, 1] - lower[i, 1]
            e2 = upper[i, 2] - lower[i, 2]
            s0 += e0
            s1 += e1
            s2 += e2
            b = _bucket(max(e0, max(e1, e2)))
            hist[c, b] += 1
            hext[c, b, 0] = max(hext[c, b, 0], e0)
            hext[c, b, 1] = max(hext[c, b, 1], e1)
            hext[c, b, 2] = max(hext[c, b, 2], e2)
        cmin[c, 0] = mn0
        cmin[c, 1] = mn1
        cmin[c, 2] = mn2
        cmax[c, 0] = mx0
        cmax[c, 1] = mx1
        cmax[c, 2] = mx2
        ssum[c, 0] = s0
        ssum[c, 1] = s1
        ssum[c, 2] = s2


@ijit
def _cell(v, o, inv_w, nb):
    """Column coordinate of centre coordinate ``v``, clamped to ``[0, nb)``
    (clamping keeps neighbours neighbours; NaN from inf - inf goes to 0)."""
    t = (v - o) * inv_w
    if not t >= 0.0:
        return 0
    if t >= nb:
        return nb - 1
    return min(np.int64(t), nb - 1)


@pjit
def bin_boxes(lower, upper, c0, c1, o0, o1, inv0, inv1, nb0, nb1, big_bucket, n_chunks,
              col):
    """Column of every box, ``nb0 * nb1`` for a big box (bucket >= ``big_bucket``)."""
    n = lower.shape[0]
    ncol = nb0 * nb1
    for c in numba.prange(n_chunks):
        for i in range(c * n // n_chunks, (c + 1) * n // n_chunks):
            if _bucket(_side(lower, upper, i)) >= big_bucket:
                col[i] = ncol
                continue
            x = 0.5 * lower[i, c0] + 0.5 * upper[i, c0]
            y = 0.5 * lower[i, c1] + 0.5 * upper[i, c1]
            col[i] = _cell(x, o0, inv0, nb0) * nb1 + _cell(y, o1, inv1, nb1)


@jit
def column_chunks(start, ncol, target, out):
    """Cut columns ``[0, ncol)`` into chunks of about ``target`` boxes; writes the
    boundaries into ``out`` and returns how many chunks there are.  Depends on
    ``start`` only (never on the thread count)."""
    k = 0
    out[0] = 0
    base = start[0]
    for c in range(ncol):
        if start[c + 1] - base >= target:
            k += 1
            out[k] = c + 1
            base = start[c + 1]
    if out[k] < ncol:
        k += 1
        out[k] = ncol
    return k


@ijit
def _before(ka, ia, kb, ib):
    """``(ka, ia) < (kb, ib)``: the sweep's total order (lower_z, then id)."""
    return ka < kb or (ka == kb and ia < ib)


@pjit
def sort_columns(chunk_cols, start, perm, lower, upper, c0, c1, z, fresh, xl, xu, yl, yu, zl,
                 zu):
    """Sort every column of ``perm`` by ``(lower_z, id)`` and gather the boxes
    into column order (``xl, xu``: axis ``c0``; ``yl, yu``: ``c1``; ``zl, zu``:
    the sweep axis ``z``), one column at a time while its rows are in cache.

    Insertion sort over the previous order (temporal coherence); a merge sort
    of the column when ``fresh`` or when the insertion sort would move more
    than a few times the column's length."""
    n_chunks = chunk_cols.shape[0] - 1
    for ch in numba.prange(n_chunks):
        for c in range(chunk_cols[ch], chunk_cols[ch + 1]):
            lo = start[c]
            hi = start[c + 1]
            # gather in the kept order: both rows of a box are read in one step
            for p in range(lo, hi):
                i = perm[p]
                zl[p] = lower[i, z]
                xl[p] = lower[i, c0]
                yl[p] = lower[i, c1]
                xu[p] = upper[i, c0]
                yu[p] = upper[i, c1]
                zu[p] = upper[i, z]
            m = hi - lo
            done = m < 2
            if not fresh and not done:
                budget = 8 * m + 64
                moves = 0
                done = True
                for p in range(lo + 1, hi):
                    v = perm[p]
                    kv = zl[p]
                    if not _before(kv, v, zl[p - 1], perm[p - 1]):
                        continue  # in place already (the steady state)
                    a0 = xl[p]
                    a1 = xu[p]
                    a2 = yl[p]
                    a3 = yu[p]
                    a4 = zu[p]
                    q = p - 1
                    while q >= lo and _before(kv, v, zl[q], perm[q]):
                        perm[q + 1] = perm[q]
                        zl[q + 1] = zl[q]
                        xl[q + 1] = xl[q]
                        xu[q + 1] = xu[q]
                        yl[q + 1] = yl[q]
                        yu[q + 1] = yu[q]
                        zu[q + 1] = zu[q]
                        q -= 1
                        moves += 1
                    perm[q + 1] = v
                    zl[q + 1] = kv
                    xl[q + 1] = a0
                    xu[q + 1] = a1
                    yl[q + 1] = a2
                    yu[q + 1] = a3
                    zu[q + 1] = a4
                    if moves > budget:
                        done = False
                        break
            if not done:
                seg = np.sort(perm[lo:hi])  # ids ascending, then a stable sort by key
                vals = np.empty(m, np.float64)
                for p in range(m):
                    vals[p] = lower[seg[p], z] + 0.0  # -0.0 sorts as +0.0
                order = stable_argsort(vals)
                for p in range(m):
                    i = seg[order[p]]
                    perm[lo + p] = i
                    zl[lo + p] = vals[order[p]]
                    xl[lo + p] = lower[i, c0]
                    yl[lo + p] = lower[i, c1]
                    xu[lo + p] = upper[i, c0]
                    yu[lo + p] = upper[i, c1]
                    zu[lo + p] = upper[i, z]


@ijit
def _scan(q, e, top, pxl, pxu, pyl, pyu, ip, xl, xu, yl, yu, zl, perm, out, base, pos, cap):
    """Test ``q, q + 1, ...`` (below ``e``) while ``zl[q] <= top``: the boxes that
    overlap ``p`` on the sweep axis; the column axes decide.  Returns
    ``(pos, tested)``."""
    tested = 0
    while q < e and zl[q] <= top:
        tested += 1
        ok = (xl[q] <= pxu) & (pxl <= xu[q]) & (yl[q] <= pyu) & (pyl <= yu[q])
        if pos < cap:  # written whether kept or not: no unpredictable branch
            iq = perm[q]
            out[base + 2 * pos] = min(ip, iq)
            out[base + 2 * pos + 1] = max(ip, iq)
        pos += np.int64(ok)
        q += 1
    return pos, tested


@ijit
def _scan_z(q, e, top, bot, pxl, pxu, pyl, pyu, ip, xl, xu, yl, yu, zl, zu, perm, out, base,
            pos, cap):
    """``_scan`` for a window that starts before ``p`` on the sweep axis: the
    boxes must also end at or above ``bot``, p's lower end."""
    tested = 0
    while q < e and zl[q] <= top:
        tested += 1
        ok = ((xl[q] <= pxu) & (pxl <= xu[q]) & (yl[q] <= pyu) & (pyl <= yu[q])
              & (bot <= zu[q]))
        if pos < cap:
            iq = perm[q]
            out[base + 2 * pos] = min(ip, iq)
            out[base + 2 * pos + 1] = max(ip, iq)
        pos += np.int64(ok)
        q += 1
    return pos, tested


@hjit
def _sweep_chunk(c_lo, c_hi, start, nb0, nb1, o0, o1, inv0, inv1, h0, h1, rz, half, xl, xu,
                 yl, yu, zl, zu, perm, out, base, cap):
    """Pairs of the columns ``[c_lo, c_hi)``; writes at most ``cap`` pairs from
    ``out[base]``; returns ``(pairs, candidates tested)``.

    Box ``p`` visits only the neighbouring columns that can hold the centre of
    a small box meeting it (its extent widened by ``h0``, ``h1``: half the
    largest small side plus the rounding margin), at most the 3 x 3 stencil
    since columns are at least that side wide.  Per neighbouring column a
    pointer keeps the start of p's window; it only moves forward and is moved
    on only when the column is visited.

    ``half`` False: the 8 neighbours, windows of the boxes after ``p`` in the
    order ``(lower_z, id)`` (each pair found by the box that comes first).
    ``half`` True: the half stencil, 4 neighbours ``(0, +1), (+1, -1), (+1, 0),
    (+1, +1)``, windows ``lower_z in [lower_z(p) - rz, upper_z(p)]`` (``rz``:
    the largest small side on the sweep axis with the rounding margin; each
    cross-column pair found by the box in the earlier column).  Half the
    columns visited for windows longer by ``rz``: the better trade when sizes
    are close.
    """
    pos = 0
    tested = 0
    ptr = np.empty(9, np.int64)
    end = np.empty(9, np.int64)
    for col in range(c_lo, c_hi):
        lo_c = start[col]
        hi_c = start[col + 1]
        if lo_c == hi_c:
            continue
        b0 = col // nb1
        b1 = col - b0 * nb1
        for d0 in range(3):
            a0 = b0 + d0 - 1
            for d1 in range(3):
                a1 = b1 + d1 - 1
                k = 3 * d0 + d1
                if a0 < 0 or a0 >= nb0 or a1 < 0 or a1 >= nb1:
                    ptr[k] = 0
                    end[k] = 0
                else:
                    ptr[k] = start[a0 * nb1 + a1]
                    end[k] = start[a0 * nb1 + a1 + 1]
        for p in range(lo_c, hi_c):
            kz = zl[p]
            ip = perm[p]
            top = zu[p]
            pxl = xl[p]
            pxu = xu[p]
            pyl = yl[p]
            pyu = yu[p]
            # own column: everything after p in order, while it starts below p's top
            pos, t = _scan(p + 1, hi_c, top, pxl, pxu, pyl, pyu, ip, xl, xu, yl, yu, zl, perm,
                           out, base, pos, cap)
            tested += t
            r0 = max(_cell(pxl - h0, o0, inv0, nb0) - b0, -1) + 1
            s0 = min(_cell(pxu + h0, o0, inv0, nb0) - b0, 1) + 1
            r1 = max(_cell(pyl - h1, o1, inv1, nb1) - b1, -1) + 1
            s1 = min(_cell(pyu + h1, o1, inv1, nb1) - b1, 1) + 1
            if half:
                zfrom = kz - rz
                for k in range(5, 9):  # offsets (0, +1), (+1, -1), (+1, 0), (+1, +1)
                    d0 = k // 3
                    d1 = k - 3 * d0
                    if d0 > s0 or d1 < r1 or d1 > s1:
                        continue
                    q = ptr[k]
                    e = end[k]
                    while q < e and zl[q] < zfrom:
                        q += 1
                    ptr[k] = q
                    pos, t = _scan_z(q, e, top, kz, pxl, pxu, pyl, pyu, ip, xl, xu, yl, yu, zl,
                                     zu, perm, out, base, pos, cap)
                    tested += t
                continue
            for d0 in range(r0, s0 + 1):
                for d1 in range(r1, s1 + 1):
                    k = 3 * d0 + d1
                    if k == 4:
                        continue
                    q = ptr[k]
                    e = end[k]
                    while q < e and not _before(kz, ip, zl[q], perm[q]):
                        q += 1
                    ptr[k] = q
                    pos, t = _scan(q, e, top, pxl, pxu, pyl, pyu, ip, xl, xu, yl, yu, zl,
                                   perm, out, base, pos, cap)
                    tested += t
    return pos, tested


@pjit
def sweep(chunk_cols, start, nb0, nb1, o0, o1, inv0, inv1, h0, h1, rz, half, xl, xu, yl, yu, zl,
          zu, perm, out, reg_start, reg_cap, todo, need, tested):
    """``_sweep_chunk`` for every chunk marked in ``todo``: chunk ``c`` writes pairs
    ``(min id, max id)`` flat into ``out[reg_start[c]:]`` (at most ``reg_cap[c]``
    of them) and ``need[c]`` receives how many it found."""
    n_chunks = chunk_cols.shape[0] - 1
    for c in numba.prange(n_chunks):
        if not todo[c]:
            continue
        need[c], tested[c] = _sweep_chunk(chunk_cols[c], chunk_cols[c + 1], start, nb0, nb1,
                                          o0, o1, inv0, inv1, h0, h1, rz, half, xl, xu, yl,
                                          yu, zl, zu, perm, out, 2 * reg_start[c], reg_cap[c])


@hjit
def _big_chunk(b_lo, b_hi, big0, start, nb0, nb1, o0, o1, inv0, inv1, reach_z, xl, xu, yl,
               yu, zl, zu, perm, out, base, cap):
    """Big boxes ``[b_lo, b_hi)`` (positions ``big0 + k`` of the column order)
    against the small boxes of every column they can reach."""
    pos = 0
    tested = 0
    for k in range(b_lo, b_hi):
        b = big0 + k
        ib = perm[b]
        bxl = xl[b]
        bxu = xu[b]
        byl = yl[b]
        byu = yu[b]
        bzl = zl[b]
        bzu = zu[b]
        # a small box meeting b has its centre within half a column of b's extent
        a0 = max(_cell(bxl, o0, inv0, nb0) - 1, 0)
        a1 = min(_cell(bxu, o0, inv0, nb0) + 1, nb0 - 1)
        s0 = max(_cell(byl, o1, inv1, nb1) - 1, 0)
        s1 = min(_cell(byu, o1, inv1, nb1) + 1, nb1 - 1)
        zfrom = bzl - reach_z
        for c0 in range(a0, a1 + 1):
            for c1 in range(s0, s1 + 1):
                col = c0 * nb1 + c1
                lo = start[col]
                hi = start[col + 1]
                if lo == hi:
                    continue
                q = lower_bound(zl, lo, hi, zfrom)
                while q < hi and zl[q] <= bzu:
                    tested += 1
                    ok = ((xl[q] <= bxu) & (bxl <= xu[q]) & (yl[q] <= byu) & (byl <= yu[q])
                          & (bzl <= zu[q]))
                    if pos < cap:
                        iq = perm[q]
                        out[base + 2 * pos] = min(ib, iq)
                        out[base + 2 * pos + 1] = max(ib, iq)
                    pos += np.int64(ok)
                    q += 1
    return pos, tested


@pjit
def sweep_big(chunk_big, big0, start, nb0, nb1, o0, o1, inv0, inv1, reach_z, xl, xu, yl, yu,
              zl, zu, perm, out, reg_start, reg_cap, todo, need, tested):
    """``_big_chunk`` for every chunk of big boxes marked in ``todo`` (regions as
    in ``sweep``)."""
    n_chunks = chunk_big.shape[0] - 1
    for c in numba.prange(n_chunks):
        if not todo[c]:
            continue
        need[c], tested[c] = _big_chunk(chunk_big[c], chunk_big[c + 1], big0, start, nb0, nb1,
                                        o0, o1, inv0, inv1, reach_z, xl, xu, yl, yu, zl, zu,
                                        perm, out, 2 * reg_start[c], reg_cap[c])


@pjit
def assemble(out, reg_start, need, pairs):
    """Concatenate the regions' pairs into ``pairs`` (k, 2)."""
    m = reg_start.shape[0]
    starts = np.zeros(m + 1, np.int64)
    for c in range(m):
        starts[c + 1] = starts[c] + need[c]
    for c in numba.prange(m):
        s = starts[c]
        b = 2 * reg_start[c]
        for k in range(need[c]):
            pairs[s + k, 0] = out[b + 2 * k]
            pairs[s + k, 1] = out[b + 2 * k + 1]


# ------------------------------------------------------------ serial twins


#: the parallel kernels of this module, compiled serially (same names)
serial = SimpleNamespace(**{name: serial_twin(globals()[name]) for name in (
    "measure", "bin_boxes", "sort_columns", "sweep", "sweep_big", "assemble")})
