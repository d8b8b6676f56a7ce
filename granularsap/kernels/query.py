"""Cross-set queries: reference points against a column grid of configuration points.

About the algorithm
-------------------
A query asks for every pair ``(i, j)`` of a reference point ``i`` and a
configuration point ``j`` with ``d <= r_ref[i] + r_conf[j] + skin`` (one
cutoff is radii 0 and ``skin = cutoff``), each pair once, with the integer
lattice shift ``S`` of the image.  There is no symmetry to use: the pair
``(i, j)`` and the pair ``(j, i)`` of two sets are different questions.

*The grid* is that of the self-search (``kernels/grid.py``): the
configuration is wrapped into the cell (``grid.wrap``), binned into ``nb0 x
nb1`` columns over the fractional coordinates of axes 0 and 1
(``grid.columns_of``, ``grid.counting_sort``), sorted along axis 2 inside
each column (``grid.sort_columns``) and gathered into contiguous arrays
(``grid.gather_columns``).  It depends on the configuration only, so a
search keeps it while the configuration, its radii and the cell come back,
and queries of new reference points cost only their own visits (the
``FastNS(cutoff, coords, box).search(query)`` pattern of MDAnalysis).

*A visit* (``_rows_of``).  Each reference point is wrapped the same way and
binned with the same formula (clamped to the grid, so that a point outside
the configuration's span along an open axis falls into the edge column, whose
neighbours are still its neighbours).  It visits the **full** stencil of
columns around its own, every column whose fractional interval across axes 0
and 1 lies within its range ``(r_i + max r_conf + skin) / w_c`` plus the
rounding guard (``w_c`` the perpendicular width across axis ``c``): two
points at distance ``d`` differ by at most ``d / w_c`` in fractional
coordinate ``c``, in triclinic cells too.  Periodic axes wrap the column
index into a column and a lattice shift; a cell narrower than the range gives
a stencil of several layers and a window of several periods, so every image
within range is found when every image is asked for.  Inside a column the
window ``|t_2 + k - t_2,i| <= range / w_2`` of each shift ``k`` along the
sweep axis is found from buckets of the sweep axis (``zindex``: per column
the first slot of each bucket, about two slots a bucket) and a binary search
inside one bucket (``common.lower_bound``, ``_upper``), then its candidates
are tested in counted loops of up to 64 that build a bit mask of the pairs
(no branch in their body: they vectorise), and only the bits of a superset
are decided one by one.  This is the cell-list query of a kept grid
(MDAnalysis's ``nsgrid``, Hockney and Eastwood's linked cells) on the column
layout of the multi-SaP of Tracy, Buss and Woods (2009): a sweep and prune
inside each cell of a spatial subdivision, here with the sweep's pointer walk
replaced by a bucket lookup, because the reference points are not part of the
sorted lists.

*The arithmetic* is the one of ``grid.py`` (docs/cells.md, "Arithmetic") with
two sets: a pair is in when ``D = (x_conf[j] - x_ref[i]) + S0 a + S1 b + S2
c`` (added in that order), ``d = sqrt(D.D)`` passes the threshold, on the
positions as given.  The visit reads wrapped positions ``w = x - k @ cell``
through the shift ``s = S + k_conf[j] - k_ref[i]``; when no point of either
set was wrapped that sum is the agreed one operation for operation (an
*exact* frame), otherwise a pair within the frame's rounding band
(``grid.band`` of both sets' largest wrapped coordinate and wrap shift) is
re-tested on the given positions (``_given_hit``), and the outputs of a pair
with a wrapped end are computed on them.  Ties at the threshold therefore
give the brute force's answer bit for bit.

*Two passes* over chunks of reference points (``count``, then ``fill``):
the first tests every candidate once and keeps, for every run of up to 64
candidates that holds a pair, a record (the 64-bit mask of its pairs, the
first slot, the reference point, the shift; ``grid._sweep_chunk``'s records),
and counts each reference point's pairs; a prefix sum gives each its first
row, and the second pass writes the pairs of the records there.  Reference
points are visited column by column (the grid's memory in order), in chunks
whose boundaries depend on their number only; each writes its own rows in
the order of its visit, so the rows (grouped by reference index, ascending)
never depend on the thread count.
"""

from __future__ import annotations

import math
from collections import namedtuple
from types import SimpleNamespace

import numba
import numpy as np

from .._numba import hjit, ijit, pjit, serial_twin
from .bits import ctpop, cttz
from .common import hit, lower_bound, separation_between, zbucket

#: the configuration's grid as the visits read it (column order unless named):
#: ``start`` (ncol + 1) first slot of every column; ``nb0``, ``nb1`` columns;
#: ``lo0``, ``lo1``, ``inv_f0``, ``inv_f1``, ``f0``, ``f1`` the binning of axes
#: 0 and 1 (lower edge, columns per fractional unit, column width); ``tz`` the
#: fractional sweep coordinate; ``xs``, ``ys``, ``zs`` wrapped positions; ``rs``
#: radii; ``ks`` wrap shifts; ``perm`` input row of every slot; ``xg`` the given
#: positions (input order); ``zidx`` the sweep buckets of every column
#: (``zindex``: ``nz`` buckets from ``zlo``, ``inv_bz`` per fractional unit)
Grid = namedtuple("Grid", ["start", "nb0", "nb1", "lo0", "lo1", "inv_f0", "inv_f1", "f0", "f1",
                           "tz", "xs", "ys", "zs", "rs", "ks", "perm", "xg", "zidx", "nz",
                           "zlo", "inv_bz"])

#: the reference points (input order): ``xg`` given positions, ``t`` fractional
#: (wrapped along periodic axes), ``k`` wrap shifts, ``w`` wrapped positions,
#: ``r`` radii, ``order`` the order they are visited in (chunks of it)
Ref = namedtuple("Ref", ["xg", "t", "k", "w", "r", "order"])

#: the cell and the test: ``cell`` (3, 3) rows, ``pbc``, ``diag`` (orthorhombic),
#: ``inv_w`` 1 / perpendicular widths; the threshold ``(r_i + r_j) + skin``
#: (``d < thr`` if ``strict``), ``uniform`` with ``x2`` its squared bound
#: (``search._square_bound``); the band ``lo2``, ``hi2``, ``dtol``, ``exact``
#: (``grid.band``); ``rmax`` the configuration's largest radius, ``reach`` the
#: skin plus the rounding guard and ``dtol`` (every superset holds the band),
#: ``guard`` the rounding of column edges; ``gap`` (3,) whether a column farther
#: than the range across that axis is skipped (not along open axes of a frame
#: with coordinates far beyond the range, whose column edges carry their rounding)
Test = namedtuple("Test", ["cell", "pbc", "diag", "inv_w", "skin", "strict", "uniform", "x2",
                           "lo2", "hi2", "dtol", "exact", "rmax", "reach", "guard", "gap"])

#: the outputs of the fill pass: pairs, distances, vectors, shifts (each
#: written when its ``want_*`` is True)
Out = namedtuple("Out", ["p", "d", "v", "s", "want_d", "want_v", "want_s"])


#: pass 1's records: for every run of up to 64 candidates of one column and
#: shift that holds a pair, the 64-bit ``word`` of its pairs, the first slot
#: ``base``, the reference point ``ref`` and the packed shift ``shift`` (``_pack``)
Rec = namedtuple("Rec", ["word", "base", "ref", "shift"])

#: bias of one 21-bit field of a packed shift (shifts up to a million cells)
_BIAS = 1 << 20


@ijit
def _pack(s0, s1, s2):
    """int64 code of the lattice shift ``(s0, s1, s2)``: three biased 21-bit fields."""
    return ((s0 + _BIAS) << 42) | ((s1 + _BIAS) << 21) | (s2 + _BIAS)


@ijit
def _unpack(code):
    """``(s0, s1, s2)`` of a packed shift."""
    mask = (1 << 21) - 1
    return (code >> 42) - _BIAS, ((code >> 21) & mask) - _BIAS, (code & mask) - _BIAS


@ijit
def _upper(arr, lo, hi, v):
    """First index in ``[lo, hi)`` of the sorted ``arr`` with ``arr[i] > v``."""
    while lo < hi:
        mid = (lo + hi) >> 1
        if arr[mid] <= v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@pjit
def zindex(start, tz, zidx, nz, zlo, inv_bz):
    """For every column ``c`` and bucket ``b``, ``zidx[c * (nz + 1) + b]``: the first
    slot of the column whose sweep coordinate has bucket ``b`` or more (the
    column's end for ``b = nz``).  A window's end is then looked up in the few
    slots of one bucket instead of the whole column: since the bucket is
    monotone, the first slot with ``tz >= v`` lies in ``[zidx[b(v)], zidx[b(v) +
    1]]``."""
    ncol = start.shape[0] - 1
    top = float(nz - 1)
    stride = nz + 1
    for c in numba.prange(ncol):
        row = c * stride
        hi = start[c + 1]
        b = 0
        for q in range(start[c], hi):
            bq = zbucket(tz[q], zlo, inv_bz, top)
            while b <= bq:
                zidx[row + b] = q
                b += 1
        while b <= nz:
            zidx[row + b] = hi
            b += 1


@ijit
def _given_hit(g, ref, i, q, ts, s0, s1, s2, thr):
    """The agreed test of reference ``i`` and slot ``q`` through the wrapped-frame
    shift ``s``: on the given positions, with the shift relative to them."""
    g0 = s0 - g.ks[q, 0] + ref.k[i, 0]
    g1 = s1 - g.ks[q, 1] + ref.k[i, 1]
    g2 = s2 - g.ks[q, 2] + ref.k[i, 2]
    dx, dy, dz = separation_between(ref.xg, i, g.xg, g.perm[q], ts.cell, g0, g1, g2)
    return hit(dx * dx + dy * dy + dz * dz, thr, ts.strict, ts.uniform, ts.x2)


@ijit
def _decide(d2, thr, g, ref, i, q, ts, s0, s1, s2):
    """The agreed test from the squared wrapped separation ``d2``: clearly in or
    out by the frame's band (``grid._decide``), else re-tested on the given
    positions."""
    if ts.uniform:
        clear_in = d2 <= ts.lo2
        if clear_in | (not d2 <= ts.hi2):
            return clear_in
    else:
        d = math.sqrt(d2)
        clear_in = d < thr - ts.dtol
        if clear_in | (not d <= thr + ts.dtol):
            return clear_in
        if ts.exact:  # no band: d == thr
            return not ts.strict
    return _given_hit(g, ref, i, q, ts, s0, s1, s2, thr)


@ijit
def _column(t, lo, inv_f, nb):
    """Column of fractional coordinate ``t`` (``grid.columns_of``'s formula)."""
    b = int(math.floor((t - lo) * inv_f))
    return min(max(b, 0), nb - 1)


@ijit
def _layers(d, f, nb, periodic):
    """Stencil layers of a window ``d`` (fractional) over columns ``f`` wide: one
    more than the window needs (the gap test of each column decides)."""
    if f == 0.0:
        return 0
    if periodic:
        return int(math.ceil(min(d / f, 2.0 ** 40))) + 1
    return int(min(math.ceil(min(d / f, 2.0 ** 40)) + 1, nb - 1))


_LOOSE = 1.0 + 1e-12


@ijit
def _run_mask(g, lo, hi, xp, yp, zp, rp, ax, ay, az, bx, by, bz, cx, cy, cz, ts):
    """64-bit mask of a superset of the pairs among the candidates ``[lo, hi)``
    (at most 64) of one column and shift, with a threshold per pair: those a
    hair beyond ``r_i + r_j + skin + dtol``, which the caller decides bit by
    bit.  A counted loop with no branch in its body, which the compiler
    vectorises (``grid._sweep_chunk``'s loops)."""
    word = np.uint64(0)
    ub = np.uint64(lo)
    xs = g.xs
    ys = g.ys
    zs = g.zs
    rs = g.rs
    sup = ts.skin + ts.dtol
    if ts.diag:
        for t in range(hi - lo):
            u = ub + np.uint64(t)
            dx = (xs[u] - xp) + ax
            dy = (ys[u] - yp) + by
            dz = (zs[u] - zp) + cz
            thr = rp + rs[u] + sup
            word |= np.uint64(dx * dx + dy * dy + dz * dz <= thr * thr * _LOOSE) << np.uint64(t)
    else:
        for t in range(hi - lo):
            u = ub + np.uint64(t)
            dx = (((xs[u] - xp) + ax) + bx) + cx
            dy = (((ys[u] - yp) + ay) + by) + cy
            dz = (((zs[u] - zp) + az) + bz) + cz
            thr = rp + rs[u] + sup
            word |= np.uint64(dx * dx + dy * dy + dz * dz <= thr * thr * _LOOSE) << np.uint64(t)
    return word


@hjit
def _rows_of(i, g, ref, ts, rec, wbase, wcap, w):
    """Pass 1 of reference point ``i``: its pairs, kept as records (``Rec``) from
    ``wbase + w`` while they fit under ``wcap``.  Returns (pairs, candidates
    tested, records made so far in the chunk)."""
    cell = ts.cell
    pbc = ts.pbc
    xp = ref.w[i, 0]
    yp = ref.w[i, 1]
    zp = ref.w[i, 2]
    tp0 = ref.t[i, 0]
    tp1 = ref.t[i, 1]
    tp2 = ref.t[i, 2]
    rp = ref.r[i]
    rng = rp + ts.rmax + ts.reach
    rgc = rng + ts.guard
    d0 = rgc * ts.inv_w[0]
    d1 = rgc * ts.inv_w[1]
    dz = rng * ts.inv_w[2]
    lo_v = tp2 - dz
    hi_v = tp2 + dz
    if pbc[2]:
        # (fractional coordinates in [0, 1]): the shifts k whose period meets the window
        k_lo = np.int64(math.ceil(lo_v)) - 1
        k_hi = np.int64(math.floor(hi_v))
    else:
        k_lo = np.int64(0)
        k_hi = np.int64(0)
    b0 = _column(tp0, g.lo0, g.inv_f0, g.nb0)
    b1 = _column(tp1, g.lo1, g.inv_f1, g.nb1)
    L0 = _layers(d0, g.f0, g.nb0, pbc[0])
    L1 = _layers(d1, g.f1, g.nb1, pbc[1])
    o_lo0 = -L0 if pbc[0] else max(-L0, -b0)
    o_hi0 = L0 if pbc[0] else min(L0, g.nb0 - 1 - b0)
    o_lo1 = -L1 if pbc[1] else max(-L1, -b1)
    o_hi1 = L1 if pbc[1] else min(L1, g.nb1 - 1 - b1)
    skin = ts.skin
    cnt = 0
    tested = 0
    ztop = float(g.nz - 1)
    # the common case, one threshold, in loops of its own (written out so that
    # they vectorise); orthorhombic or not
    fast = ts.uniform
    hi = ts.x2 if ts.exact else ts.hi2
    lo = ts.x2 if ts.exact else ts.lo2
    diag = ts.diag
    gxs = g.xs
    gys = g.ys
    gzs = g.zs
    for o0 in range(o_lo0, o_hi0 + 1):
        cu0 = b0 + o0
        # the gap of the point to the column's fractional interval across axis 0
        e_lo = g.lo0 + cu0 * g.f0
        e_hi = g.lo0 + (cu0 + 1) * g.f0
        if ts.gap[0] and max(e_lo - tp0, tp0 - e_hi) > d0:
            continue
        s0 = np.int64(0)
        c0 = cu0
        if pbc[0]:
            s0 = cu0 // g.nb0
            c0 = cu0 - s0 * g.nb0
        ax = s0 * cell[0, 0]
        ay = s0 * cell[0, 1]
        az = s0 * cell[0, 2]
        for o1 in range(o_lo1, o_hi1 + 1):
            cu1 = b1 + o1
            e_lo = g.lo1 + cu1 * g.f1
            e_hi = g.lo1 + (cu1 + 1) * g.f1
            if ts.gap[1] and max(e_lo - tp1, tp1 - e_hi) > d1:
                continue
            s1 = np.int64(0)
            c1 = cu1
            if pbc[1]:
                s1 = cu1 // g.nb1
                c1 = cu1 - s1 * g.nb1
            col = c0 * g.nb1 + c1
            if g.start[col] == g.start[col + 1]:
                continue
            row = col * (g.nz + 1)
            bx = s1 * cell[1, 0]
            by = s1 * cell[1, 1]
            bz = s1 * cell[1, 2]
            for k in range(k_lo, k_hi + 1):
                kf = float(k)
                v = lo_v - kf
                b = row + zbucket(v, g.zlo, g.inv_bz, ztop)
                qa = lower_bound(g.tz, g.zidx[b], g.zidx[b + 1], v)
                v = hi_v - kf
                b = row + zbucket(v, g.zlo, g.inv_bz, ztop)
                qb = _upper(g.tz, max(qa, g.zidx[b]), g.zidx[b + 1], v)
                if qa >= qb:
                    continue
                tested += qb - qa
                cx = k * cell[2, 0]
                cy = k * cell[2, 1]
                cz = k * cell[2, 2]
                for base in range(qa, qb, 64):
                    top = min(base + 64, qb)
                    if fast:
                        # one threshold: ``word`` the pairs up to hi, ``inner`` those up
                        # to lo (an exact frame: both x2); the rest is decided below
                        word = np.uint64(0)
                        inner = np.uint64(0)
                        ub = np.uint64(base)
                        if diag:
                            for t in range(top - base):
                                u = ub + np.uint64(t)
                                dx = (gxs[u] - xp) + ax
                                dy = (gys[u] - yp) + by
                                dz = (gzs[u] - zp) + cz
                                d2 = dx * dx + dy * dy + dz * dz
                                word |= np.uint64(d2 <= hi) << np.uint64(t)
                                inner |= np.uint64(d2 <= lo) << np.uint64(t)
                        else:
                            for t in range(top - base):
                                u = ub + np.uint64(t)
                                dx = (((gxs[u] - xp) + ax) + bx) + cx
                                dy = (((gys[u] - yp) + ay) + by) + cy
                                dz = (((gzs[u] - zp) + az) + bz) + cz
                                d2 = dx * dx + dy * dy + dz * dz
                                word |= np.uint64(d2 <= hi) << np.uint64(t)
                                inner |= np.uint64(d2 <= lo) << np.uint64(t)
                        bits = word & ~inner
                    else:
                        # radii: a superset (``_run_mask``), decided bit by bit
                        word = _run_mask(g, base, top, xp, yp, zp, rp, ax, ay, az, bx, by, bz,
                                         cx, cy, cz, ts)
                        bits = word
                    while bits:
                        t = cttz(bits)
                        bits &= bits - np.uint64(1)
                        q = base + np.int64(t)
                        if diag:
                            dx = (g.xs[q] - xp) + ax
                            dy = (g.ys[q] - yp) + by
                            dz2 = (g.zs[q] - zp) + cz
                        else:
                            dx = (((g.xs[q] - xp) + ax) + bx) + cx
                            dy = (((g.ys[q] - yp) + ay) + by) + cy
                            dz2 = (((g.zs[q] - zp) + az) + bz) + cz
                        d2 = dx * dx + dy * dy + dz2 * dz2
                        if not _decide(d2, (rp + g.rs[q]) + skin, g, ref, i, q, ts, s0, s1, k):
                            word &= ~(np.uint64(1) << t)
                    if not word:
                        continue
                    if w < wcap:
                        r = wbase + w
                        rec.word[r] = word
                        rec.base[r] = base
                        rec.ref[r] = i
                        rec.shift[r] = _pack(s0, s1, k)
                    w += 1
                    cnt += np.int64(ctpop(word))
    return cnt, tested, w


@hjit
def _fill_records(r_lo, r_hi, g, ref, ts, offsets, rec, out):
    """Pass 2: the pairs of records ``[r_lo, r_hi)`` (those of whole reference
    points, in the order pass 1 made them), each reference point's from its
    row ``offsets[i]``.  Distances and vectors are the agreed arithmetic's: the
    visit's own sum (every term) in an exact frame and for pairs of two points
    not wrapped, else the sum on the given positions with the shift relative
    to them."""
    cell = ts.cell
    last = np.int64(-1)
    o = np.int64(0)
    for r in range(r_lo, r_hi):
        i = rec.ref[r]
        if i != last:
            last = i
            o = offsets[i]
        s0, s1, s2 = _unpack(rec.shift[r])
        ax = s0 * cell[0, 0]
        ay = s0 * cell[0, 1]
        az = s0 * cell[0, 2]
        bx = s1 * cell[1, 0]
        by = s1 * cell[1, 1]
        bz = s1 * cell[1, 2]
        cx = s2 * cell[2, 0]
        cy = s2 * cell[2, 1]
        cz = s2 * cell[2, 2]
        xp = ref.w[i, 0]
        yp = ref.w[i, 1]
        zp = ref.w[i, 2]
        ki0 = ref.k[i, 0]
        ki1 = ref.k[i, 1]
        ki2 = ref.k[i, 2]
        plain_i = (ki0 == 0) & (ki1 == 0) & (ki2 == 0)
        word = rec.word[r]
        base = rec.base[r]
        while word:
            t = cttz(word)
            word &= word - np.uint64(1)
            q = base + np.int64(t)
            j = g.perm[q]
            g0 = s0 - g.ks[q, 0] + ki0
            g1 = s1 - g.ks[q, 1] + ki1
            g2 = s2 - g.ks[q, 2] + ki2
            out.p[o, 0] = i
            out.p[o, 1] = j
            if out.want_d or out.want_v:
                if ts.exact or (plain_i & (g.ks[q, 0] == 0) & (g.ks[q, 1] == 0)
                                & (g.ks[q, 2] == 0)):
                    vx = (((g.xs[q] - xp) + ax) + bx) + cx
                    vy = (((g.ys[q] - yp) + ay) + by) + cy
                    vz = (((g.zs[q] - zp) + az) + bz) + cz
                else:
                    vx, vy, vz = separation_between(ref.xg, i, g.xg, j, cell, g0, g1, g2)
                if out.want_d:
                    out.d[o] = math.sqrt(vx * vx + vy * vy + vz * vz)
                if out.want_v:
                    out.v[o, 0] = vx
                    out.v[o, 1] = vy
                    out.v[o, 2] = vz
            if out.want_s:
                out.s[o, 0] = g0
                out.s[o, 1] = g1
                out.s[o, 2] = g2
            o += 1


@pjit
def count(g, ref, ts, chunk, counts, tested, rec, wstart, wcap, wneed, todo):
    """Pass 1 over every chunk of ``chunk`` visited reference points marked in
    ``todo``: the pairs of each point into ``counts`` (input order), the
    candidates of each chunk into ``tested``, its records from ``wstart[c]``
    (kept while they fit its ``wcap[c]``; ``wneed[c]`` says how many it needs:
    a chunk that needs more is run again with more room)."""
    n = ref.order.shape[0]
    for c in numba.prange(tested.shape[0]):
        if not todo[c]:
            continue
        tc = 0
        w = np.int64(0)
        for a in range(c * chunk, min(n, (c + 1) * chunk)):
            i = ref.order[a]
            k, t, w = _rows_of(i, g, ref, ts, rec, wstart[c], wcap[c], w)
            counts[i] = k
            tc += t
        tested[c] = tc
        wneed[c] = w


@pjit
def fill(g, ref, ts, rec, wstart, wneed, offsets, out):
    """Pass 2: every chunk's records into the rows of their reference points."""
    for c in numba.prange(wstart.shape[0]):
        _fill_records(wstart[c], wstart[c] + wneed[c], g, ref, ts, offsets, rec, out)


#: the parallel kernels of this module, compiled serially (same names)
serial = SimpleNamespace(**{name: serial_twin(globals()[name])
                            for name in ("count", "fill", "zindex")})
