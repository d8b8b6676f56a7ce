"""Column sweep for particles: the broad phase and the Verlet narrow phase.

About the algorithm
-------------------
Particles are points with a per-particle half range ``rad``; pair ``(a, b)``
is in range iff ``d <= rad[a] + rad[b] + skin`` (float64, one ``sqrt``).

*Coordinates.*  Everything is binned in fractional coordinates ``s = x H^-1``
of the cell matrix ``H`` (rows are cell vectors; the identity for open
boundaries).  Along a periodic axis ``s`` is wrapped to ``t = s - floor(s)``
and the Cartesian position to ``w = x - floor(s) H`` (cell vectors subtracted
one at a time).  Two points at distance ``d`` differ by at most ``d / w_c`` in
fractional coordinate ``c``, ``w_c`` the perpendicular width of the cell
across axis ``c`` (volume over the area of the opposite face), so a bin of
fractional width ``B / w_c`` holds every partner within ``B`` in itself and
its two neighbours, in triclinic cells too.

*Columns.*  Axes 0 and 1 are cut into ``nb0 x nb1`` columns at least the
pair range (plus the Verlet margin) wide; axis 2 is the sweep axis.
Particles are stored column by column, sorted along ``t2`` inside each column
(a stable counting sort by column over the previous build's order, then an
insertion sort inside each column, which temporal coherence keeps close to
linear; a fresh order falls back to a merge sort per column).  Positions,
ranges and labels are gathered into that order, so the sweep streams through
contiguous memory.  This is the multi-SaP of Tracy, Buss and Woods (2009) and
Terdiman (2007): a Sweep and Prune (Algorithm 1's sweep, one axis) inside each
cell of a spatial subdivision.

*Sweep* (``_sweep_chunk``).  The stencil is half of the ``(2 L0 + 1) x (2 L1
+ 1)`` neighbourhood (offsets lexicographically positive) plus the column
itself, where a particle looks only forward in sorted order; so each
unordered pair, and each periodic image of it, is reported by exactly one
particle and nothing is de-duplicated afterwards.  For each stencil column
two pointers walk it while ``p`` walks its own column: the window of ``p``
along axis 2 is ``|t2_b - t2_a| <= (rad[a] + max(rad) + skin + margin) /
w_2``.  Periodic axes wrap the stencil (column offset -> column and lattice
shift) and the window (``t2 + k`` for integer ``k``); a cell narrower than
the range simply gives a stencil of more than one layer, so every image
within range is found (the ASE convention) when self-images are asked for.
Between the pointers lie runs of one lattice shift, each tested by a counted
loop with no branch in its body.

*Records.*  Pass 1 keeps, for every run of up to 64 candidates holding a
pair, a record: the 64-bit mask of its pairs, the particle, the first
candidate and the lattice shift ``S`` (three 10-bit fields of one int32).  A
frame without a Verlet margin writes the pairs of its records at once
(``direct_fill``).  With a margin the records are the Verlet list (the pairs
within range plus ``margin``): while no particle has moved more than
``margin / 2`` since the build, every pair in range is in the list, and a
frame only re-tests it (``records_narrow``) with the shift corrected by the
image jumps ``m`` of the two particles since the build: ``S' = S - m_b +
m_a``.

*Levels.*  Widely spread radii may be split into small and large: columns
are then sized for the small ones and the large ones walk a wider full
stencil, pairing with everything (a large-large pair is kept by its lower
end).

*Arithmetic.*  The separation is ``(w_b - w_a) + S0 a + S1 b + S2 c``, the
order of MDAnalysis's triclinic minimum image; negating it term by term
gives the same squared norm bit for bit, so the distance of a pair does not
depend on which end found it, and a Verlet frame reproduces a fresh build
exactly.  (Coordinates whose squares would overflow or underflow are scaled
by a power of two before they get here: see ``search.py``.)

Cost: O(n) for wrapping, sorting and gathering, O(candidates) for the
sweep; candidates per pair found are about ``(3 B)^2 2 B / (2 (4/3) pi R^3)``
for uniform points (4.3 for columns one range wide).  Parallel work is split
into chunks of whole columns whose boundaries depend only on the input, never
on the thread count; each chunk writes its records and its pairs into its own
region, so no two threads share an output slot.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numba
import numpy as np

from .._numba import hjit, ijit, jit, pjit, serial_twin
from .bits import ctpop, cttz
from .common import (  # noqa: F401 (re-exported)
    OFF,
    ZERO,
    decode,
    encode,
    lower_bound,
    separation_between,
    stable_argsort,
)
from .common import hit as _hit
from .common import zbucket as _zbucket
from .radixsort import scatter_offsets

#: fractional coordinates at or beyond this magnitude cannot be wrapped
#: meaningfully (the wrapped value keeps no significant bits)
WRAP_LIMIT = 2.0 ** 52


@ijit
def _separation(w, a, b, cell, s0, s1, s2):
    """``separation_between`` of two rows of one array."""
    return separation_between(w, a, w, b, cell, s0, s1, s2)


# ------------------------------------------------------- the one arithmetic
#
# Every answer follows the positions as given, ``x``, and the integer shift
# ``S`` of a pair relative to them (docs/cells.md, "Arithmetic"):
#
#     D_c = (x[j, c] - x[i, c]) + S0 cell[0, c] + S1 cell[1, c] + S2 cell[2, c]
#
# added in that order, ``d2 = D_0^2 + D_1^2 + D_2^2``, ``d = sqrt(d2)``, in if
# ``d <= thr`` (``<`` when strict).  The sweep reads the wrapped positions ``w =
# x - k @ cell`` (``k`` the wrap shifts, ``_wrap_one``) through the shift ``s = S
# + k_j - k_i`` (so ``S = s - k_j + k_i``, the shifts the outputs report).  When
# every ``k`` is 0, ``w`` is ``x`` bit for bit (nothing is subtracted) and the
# sweep's sum is the agreed one operation for operation: the frame is *exact*.
# Otherwise the two differ by rounding: the test on ``w`` decides only the pairs
# clearly inside or outside, and those within a band around the threshold are
# re-tested with the agreed arithmetic on ``x`` (``_reference_hit``).
#
# The band (``band``).  u = 2**-53; every operation rounds with |error| <= u |result|
# + eta, eta = 2**-1074 (subnormal results).  Let K = max |k|, W = max |w| (as
# computed), C = max |cell entry| of the periodic rows, s* a bound on |s_c| over
# every candidate any path tests (``frame_band``), A = W + 6 K C (>= |x| + 3 K C
# up to rounding: it bounds |x|, |w| and every partial sum of the wrap) and B =
# 3 s* C.  With D* the exact (real) separation:
#   wrap:      w_c = x_c - sum_r k_r cell[r, c] + e,  |e| <= 6 u A  (6 operations);
#   sweep:     7 operations on terms summing to <= 2A + B, plus both wrap errors:
#              |D_w - D*|_c <= u (26 A + 7 B);
#   reference: |S_r| <= s* + 2K, terms summing to <= 2A + B: |D_r - D*|_c <= 7 u (2A + B).
# So the two computed vectors are within sqrt(3) u (40 A + 14 B) of each other;
# ``delta = u (128 A + 64 B) + 64 eta`` covers that with room for gamma_n = n u
# / (1 - n u) and for the rounding of these very formulas.  A sum of three
# squares adds a relative error below gamma_3 < 4u, a square root one of u, so:
#   one threshold (d2 <= x2, T = sqrt(x2)), g = 16 u:
#     d2_w <= lo2 = ((1 - g) T - delta)^2 (1 - g)  implies  d2_r <= x2  (clearly in),
#     d2_w >  hi2 = ((1 + g) T + delta)^2 (1 + g)  implies  d2_r >  x2  (clearly out);
#   a threshold per pair thr <= tmax, with dtol = 4 delta + 16 u tmax:
#     d_w < thr - dtol implies in, d_w > thr + dtol implies out
#     (|d_w - d_r| <= 1.01 delta + 6.1 u thr near the threshold).
# A pair in by the agreed arithmetic has |D_w| <= thr + delta, so ``dtol`` also
# widens every superset pairs are drawn from (column windows, the superset
# tests of the sweep, Verlet lists, the cubes of the paper's sweep).  An exact
# frame has no band: lo2 = hi2 = x2, dtol = 0.

#: unit roundoff of float64 and the largest absolute error of a subnormal result
_U = 2.0 ** -53
_ETA = 5e-324


@ijit
def band(wmax, kmax, cmax, smax, tmax, x2):
    """(lo2, hi2, dtol, exact) of a frame: its largest wrapped coordinate
    ``wmax``, largest wrap shift ``kmax``, largest periodic cell entry ``cmax``,
    bound ``smax`` on the image shifts tested, largest threshold ``tmax`` and
    the squared bound ``x2`` of a uniform threshold (see above)."""
    if kmax == 0:
        return x2, x2, 0.0, True
    a = wmax + 6.0 * kmax * cmax
    b = 3.0 * smax * cmax
    delta = _U * (128.0 * a + 64.0 * b) + 64.0 * _ETA
    dtol = 4.0 * delta + 16.0 * _U * tmax + 64.0 * _ETA
    if not x2 >= 0.0:  # nothing is in range
        return x2, x2, dtol, False
    g = 16.0 * _U
    t = math.sqrt(x2)
    lo = (1.0 - g) * t - delta
    lo2 = lo * lo * (1.0 - g) - 16.0 * _ETA if lo > 0.0 else -1.0
    hi = (1.0 + g) * t + delta
    hi2 = hi * hi * (1.0 + g) + 16.0 * _ETA
    return lo2, hi2, dtol, False


@ijit
def frame_band(wmax, kmax, cell, pbc, widths, reach, tmax, x2):
    """``band`` of a frame from its cell: ``reach`` bounds the separation of every
    candidate a path tests, up to a factor 2 (the interaction range plus the
    Verlet margin), so no tested image shift exceeds ``6 + 2 reach / w`` cell
    vectors along an axis of perpendicular width ``w`` (the stencil's and the
    windows' layers, the ghosts' and the image jumps of a Verlet frame)."""
    cmax = 0.0
    wmin = math.inf
    for r in range(3):
        if pbc[r]:
            wmin = min(wmin, widths[r])
            for c in range(3):
                cmax = max(cmax, abs(cell[r, c]))
    smax = 6.0 + math.ceil(2.0 * reach / wmin) if wmin < math.inf else 0.0
    return band(wmax, kmax, cmax, smax, tmax, x2)


@ijit
def _given_shift(kp, p, q, s0, s1, s2):
    """Shift relative to the given positions of the image ``s`` of ``p`` to ``q``
    between wrapped positions (``kp`` the wrap shifts in column order)."""
    return s0 - kp[q, 0] + kp[p, 0], s1 - kp[q, 1] + kp[p, 1], s2 - kp[q, 2] + kp[p, 2]


@ijit
def _unwrapped(kp, p):
    """Whether ``p`` (column order) was not wrapped: its wrapped position is its
    given one bit for bit (``_wrap_one`` subtracts nothing), so a pair of two
    such particles is summed on ``w`` exactly as the agreed arithmetic sums it
    on ``x``, with the same shift."""
    return (kp[p, 0] == 0) & (kp[p, 1] == 0) & (kp[p, 2] == 0)


@ijit
def _reference_hit(xg, perm, kp, p, q, cell, s0, s1, s2, thr, strict, uniform, x2):
    """The agreed test of ``p`` to ``q`` through the wrapped-frame shift ``s``: on
    the given positions ``xg`` (input order) and the shift relative to them."""
    g0, g1, g2 = _given_shift(kp, p, q, s0, s1, s2)
    dx, dy, dz = _separation(xg, perm[p], perm[q], cell, g0, g1, g2)
    return _hit(dx * dx + dy * dy + dz * dz, thr, strict, uniform, x2)


@ijit
def _decide(d2, thr, strict, uniform, x2, lo2, hi2, dtol, xg, perm, kp, p, q, cell, s0, s1,
            s2):
    """The agreed test from the squared wrapped separation ``d2``: clearly in or
    out by the band of ``band``, else re-tested on the given positions.

    The clear cases take one well-predicted branch and return the test's value
    (about half the candidates are in, in no order a branch could learn)."""
    if uniform:
        clear_in = d2 <= lo2
        if clear_in | (not d2 <= hi2):
            return clear_in
    else:
        d = math.sqrt(d2)
        clear_in = d < thr - dtol
        if clear_in | (not d <= thr + dtol):
            return clear_in
        if dtol == 0.0:  # an exact frame: d == thr
            return not strict
    return _reference_hit(xg, perm, kp, p, q, cell, s0, s1, s2, thr, strict, uniform, x2)


# ----------------------------------------------------------------- wrapping


@ijit
def _wrap_one(x, i, hinv, cell, diag, pbc, t, k, w, j):
    """Fractional ``t[j]``, wrap shift ``k[j]`` and wrapped ``w[j]`` of ``x[i]``.

    Returns False when a periodic fractional coordinate is too large to wrap.
    """
    ok = True
    for c in range(3):
        if diag:
            s = x[i, c] / cell[c, c]
        else:
            s = x[i, 0] * hinv[0, c] + x[i, 1] * hinv[1, c] + x[i, 2] * hinv[2, c]
        if pbc[c]:
            if not abs(s) < WRAP_LIMIT:
                ok = False
                s = 0.0
            f = math.floor(s)
            t[j, c] = s - f
            k[j, c] = np.int64(f)
        else:
            t[j, c] = s
            k[j, c] = 0
    wx = x[i, 0]
    wy = x[i, 1]
    wz = x[i, 2]
    for c in range(3):
        kc = k[j, c]
        if kc != 0:
            wx -= kc * cell[c, 0]
            wy -= kc * cell[c, 1]
            wz -= kc * cell[c, 2]
    w[j, 0] = wx
    w[j, 1] = wy
    w[j, 2] = wz
    return ok


@pjit
def wrap(x, hinv, cell, diag, pbc, t, k, w, n_chunks):
    """Wrap every particle (input order); returns (first bad row or -1, largest
    absolute wrapped coordinate, largest absolute wrap shift)."""
    n = x.shape[0]
    bad = np.full(n_chunks, -1, np.int64)
    ext = np.zeros(n_chunks)
    kext = np.zeros(n_chunks, np.int64)
    for ch in numba.prange(n_chunks):
        lo = ch * n // n_chunks
        hi = (ch + 1) * n // n_chunks
        mx = 0.0
        km = np.int64(0)
        for i in range(lo, hi):
            if not _wrap_one(x, i, hinv, cell, diag, pbc, t, k, w, i):
                if bad[ch] < 0:
                    bad[ch] = i
            for c in range(3):
                a = abs(w[i, c])
                # a NaN is caught by the caller's finiteness check of the input
                mx = a if a > mx else mx
                kc = abs(k[i, c])
                km = kc if kc > km else km
        ext[ch] = mx
        kext[ch] = km
    extent = 0.0
    kmax = np.int64(0)
    for ch in range(n_chunks):
        if bad[ch] >= 0:
            return bad[ch], extent, kmax
        extent = max(extent, ext[ch])
        kmax = max(kmax, kext[ch])
    return -1, extent, kmax


@pjit
def wrap_sorted(x, perm, hinv, cell, diag, pbc, t_build, n_chunks, t, k, w, m, disp2):
    """Wrap particles into column order and measure their motion since the build.

    ``m[p]`` is the image jump of particle ``perm[p]`` since the build (packed
    like a shift code, minus the zero code) and ``disp2[chunk]`` the largest
    squared displacement (minimum image along periodic axes, Cartesian through
    ``cell``).
    Returns (the first bad input row or -1, largest absolute wrapped coordinate,
    largest absolute wrap shift).
    """
    n = x.shape[0]
    bad = np.full(n_chunks, -1, np.int64)
    ext = np.zeros(n_chunks)
    kext = np.zeros(n_chunks, np.int64)
    for ch in numba.prange(n_chunks):
        lo = ch * n // n_chunks
        hi = (ch + 1) * n // n_chunks
        mx = 0.0
        wm = 0.0
        km = np.int64(0)
        for p in range(lo, hi):
            i = perm[p]
            if not _wrap_one(x, i, hinv, cell, diag, pbc, t, k, w, p):
                if bad[ch] < 0:
                    bad[ch] = i
            for c in range(3):
                a = abs(w[p, c])
                wm = a if a > wm else wm
                kc = abs(k[p, c])
                km = kc if kc > km else km
            f0 = t[p, 0] - t_build[p, 0]
            f1 = t[p, 1] - t_build[p, 1]
            f2 = t[p, 2] - t_build[p, 2]
            m0 = 0
            m1 = 0
            m2 = 0
            if pbc[0]:
                m0 = np.int64(math.floor(f0 + 0.5))
                f0 -= m0
            if pbc[1]:
                m1 = np.int64(math.floor(f1 + 0.5))
                f1 -= m1
            if pbc[2]:
                m2 = np.int64(math.floor(f2 + 0.5))
                f2 -= m2
            m[p] = encode(m0, m1, m2) - ZERO
            dx = f0 * cell[0, 0] + f1 * cell[1, 0] + f2 * cell[2, 0]
            dy = f0 * cell[0, 1] + f1 * cell[1, 1] + f2 * cell[2, 1]
            dz = f0 * cell[0, 2] + f1 * cell[1, 2] + f2 * cell[2, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if not d2 <= mx:  # also catches nan
                mx = d2 if d2 == d2 else np.inf
        disp2[ch] = mx
        ext[ch] = wm
        kext[ch] = km
    extent = 0.0
    kmax = np.int64(0)
    for ch in range(n_chunks):
        if bad[ch] >= 0:
            return bad[ch], extent, kmax
        extent = max(extent, ext[ch])
        kmax = max(kmax, kext[ch])
    return -1, extent, kmax


# ------------------------------------------------------------------ sorting


@pjit
def columns_of(t, lo, inv_f, nb0, nb1, col):
    """Column index of every particle from its fractional coordinates."""
    n = t.shape[0]
    for i in numba.prange(n):
        b0 = int(math.floor((t[i, 0] - lo[0]) * inv_f[0]))
        b1 = int(math.floor((t[i, 1] - lo[1]) * inv_f[1]))
        b0 = min(max(b0, 0), nb0 - 1)
        b1 = min(max(b1, 0), nb1 - 1)
        col[i] = b0 * nb1 + b1


@pjit
def counting_sort(col, prev, ncol, start, perm, hist):
    """Stable counting sort of ``prev``'s order by column into ``perm``; ``start``
    (ncol + 1) gets each column's first slot.  ``hist`` (segments, ncol) is
    scratch: ``prev`` is cut into that many consecutive segments, counted and
    scattered at once, one histogram row each; the segments keep their order,
    so the sort stays stable."""
    n = prev.shape[0]
    n_seg = hist.shape[0]
    for g in numba.prange(n_seg):
        for c in range(ncol):
            hist[g, c] = 0
        for r in range(g * n // n_seg, (g + 1) * n // n_seg):
            hist[g, col[prev[r]]] += 1
    scatter_offsets(hist, start, n_seg, ncol)
    for g in numba.prange(n_seg):
        for r in range(g * n // n_seg, (g + 1) * n // n_seg):
            i = prev[r]
            c = col[i]
            perm[hist[g, c]] = i
            hist[g, c] += 1


@pjit
def sort_columns(start, ncol, perm, t, axis, fresh):
    """Sort every column of ``perm`` by ``t[:, axis]`` (insertion sort; merge sort
    if fresh or if the insertion sort would move too much)."""
    for c in numba.prange(ncol):
        lo = start[c]
        hi = start[c + 1]
        m = hi - lo
        if m < 2:
            continue
        done = False
        if not fresh:
            budget = 8 * m + 64
            moves = 0
            done = True
            for p in range(lo + 1, hi):
                v = perm[p]
                kv = t[v, axis]
                q = p - 1
                while q >= lo and t[perm[q], axis] > kv:
                    perm[q + 1] = perm[q]
                    q -= 1
                    moves += 1
                perm[q + 1] = v
                if moves > budget:
                    done = False
                    break
        if not done:
            seg = perm[lo:hi].copy()
            vals = np.empty(m, np.float64)
            for p in range(m):
                vals[p] = t[seg[p], axis]
            order = stable_argsort(vals)
            for p in range(m):
                perm[lo + p] = seg[order[p]]


@pjit
def gather(perm, t, w, rad, label, ts, ws, rs, ls, use_label):
    """Gather fractional and wrapped positions, ranges and labels in column order."""
    n = perm.shape[0]
    for p in numba.prange(n):
        i = perm[p]
        for c in range(3):
            ts[p, c] = t[i, c]
            ws[p, c] = w[i, c]
        rs[p] = rad[i]
        if use_label:
            ls[p] = label[i]


@pjit
def gather_columns(perm, t, w, rad, label, tz, xs, ys, zs, rs, ls, use_label):
    """:func:`gather` for a direct frame: the sweep coordinate and the wrapped
    positions as separate contiguous arrays, the layout the column sweep reads."""
    n = perm.shape[0]
    for p in numba.prange(n):
        i = perm[p]
        tz[p] = t[i, 2]
        xs[p] = w[i, 0]
        ys[p] = w[i, 1]
        zs[p] = w[i, 2]
        rs[p] = rad[i]
        if use_label:
            ls[p] = label[i]


# -------------------------------------------------------------------- build


@ijit
def _step(q, k, kf, lo, hi, wrap):
    """Next element of a column read as a periodic sequence: past the end it wraps
    to the start one period up, or (``wrap`` False) stops at ``hi``."""
    q += 1
    if q == hi and wrap:
        return lo, k + 1, kf + 1.0
    return q, k, kf


@ijit
def _pair_test(q, p, xs, ys, zs, ls, use_label, diag, ax, ay, az, bx, by, bz, cx, cy, cz,
               xp, yp, zp, lp, self_images):
    """Separation of ``p`` to ``q`` seen through one lattice shift (``ax..cz`` its
    terms, added in ``_separation``'s order) and whether the pair may be one (not
    a particle with itself unless ``self_images``, not one label); (ok, d2, dx,
    dy, dz).  The caller applies the threshold (``_decide``).  (At most 30
    arguments: CPython passes more as a tuple, which numba cannot inline.)"""
    if diag:  # the other terms of _separation's sum are zeros: no square changes
        dx = (xs[q] - xp) + ax
        dy = (ys[q] - yp) + by
        dz = (zs[q] - zp) + cz
    else:
        dx = (((xs[q] - xp) + ax) + bx) + cx
        dy = (((ys[q] - yp) + ay) + by) + cy
        dz = (((zs[q] - zp) + az) + bz) + cz
    d2 = dx * dx + dy * dy + dz * dz
    ok = (p != q) | self_images
    if use_label:
        ok = ok & (lp != ls[q])
    return ok, d2, dx, dy, dz


@hjit
def _sweep_chunk(c_lo, c_hi, start, nb0, nb1, pbc, tz, xs, ys, zs, rs, ls, use_label,
                 cell, diag, stencil, rmax, reach, inv_w2, self_images, skin, strict, uniform,
                 x2, in2, out2, dtol, exact, xg, perm, kp, words, rec_p, rec_q, rec_s, wbase,
                 wcap, levels, big, r_small, stencil_big, verlet, fast, tri):
    """Pass 1 of a direct frame: test every candidate of the columns
    ``[c_lo, c_hi)`` and keep the outcome as records (``records_fill`` reads
    them): a 64-bit mask of the pairs found among up to 64 consecutive
    candidates, with the particle, the first candidate and the lattice shift.
    Records with no pair are not kept.  Writes at most ``wcap`` records from
    ``wbase``; returns (pairs, candidates, records needed).  ``verlet``: the
    records are a Verlet list instead, the pairs within ``rs[p] + rs[q] +
    skin`` (the caller's skin holding the margin) by the squared test a hair
    wide (a superset), re-tested every frame by ``records_narrow``.

    The test is the agreed arithmetic on the given positions (see "the one
    arithmetic" above): ``in2``, ``out2``, ``dtol`` and ``exact`` are the
    frame's ``band`` (its ``lo2``, ``hi2``, ...); a pair within it is re-tested
    on ``xg`` (input order) through ``perm`` and the wrap shifts ``kp`` (column
    order).  A Verlet build passes an exact band (its superset holds the band
    in ``skin``).

    For each column of the stencil, two pointers walk it while ``p`` walks its
    own sorted column (Algorithm 1's sweep of one sorted list against another):
    ``(q, k)`` is the first element of the periodic sequence ``tz + k`` at or
    above ``tz[p] - dmax`` and ``(qh, kh)`` the first above the upper end of
    ``p``'s window; both only grow with ``p`` (the upper one is searched per
    ``p`` when ranges differ).  Between them lie runs of one lattice shift,
    each a counted loop over contiguous arrays without a branch in its body.

    Two levels (``levels``): columns are sized for the pairs of particles no
    larger than ``r_small``; the first walk pairs those among themselves
    (windows from ``r_small``), the second walks only the large ones
    (``big``) over the wider full stencil ``stencil_big`` and pairs them with
    everything, a pair of two large ones being kept by its lower end.  So a
    few large spheres widen neither the columns nor the windows of the rest
    (the hierarchical grids of polydisperse packings).

    ``fast`` and ``tri`` (``loop_mode``, each True or None) name the candidate
    loop: the vectorised one of an orthorhombic cell with one threshold, no
    labels and one level (``fast``), else the superset loop of an orthorhombic
    or (``tri``) a triclinic cell.  numba types a None apart and drops the
    branches it rules out before typing, so a frame compiles only its loop.
    """
    cnt = 0
    tested = 0
    w = 0
    loose = 1.0 + 1e-12
    skin_sup = skin + dtol  # the supersets hold the band
    p2 = pbc[2]
    for col in range(c_lo, c_hi):
      lo_c = start[col]
      hi_c = start[col + 1]
      if lo_c == hi_c:
          continue
      b0 = col // nb1
      b1 = col - b0 * nb1
      for walk in range(2 if levels else 1):
        second = walk == 1
        st = stencil_big if second else stencil
        n_st = st.shape[0]
        r_win = rmax if (second or not levels) else r_small
        dmax = (2.0 * r_win + reach) * inv_w2
        for o_st in range(0 if second else -1, n_st):
            own = o_st < 0  # the column itself: forward in sorted order
            s0 = 0
            s1 = 0
            if own:
                col2 = col
            else:
                c0 = b0 + st[o_st, 0]
                c1 = b1 + st[o_st, 1]
                if pbc[0]:
                    s0 = c0 // nb0
                    c0 -= s0 * nb0
                elif c0 < 0 or c0 >= nb0:
                    continue
                if pbc[1]:
                    s1 = c1 // nb1
                    c1 -= s1 * nb1
                elif c1 < 0 or c1 >= nb1:
                    continue
                col2 = c0 * nb1 + c1
            lo2 = start[col2]
            hi2 = start[col2 + 1]
            if lo2 == hi2:
                continue
            ax = s0 * cell[0, 0]
            ay = s0 * cell[0, 1]
            az = s0 * cell[0, 2]
            bx = s1 * cell[1, 0]
            by = s1 * cell[1, 1]
            bz = s1 * cell[1, 2]
            q = lo2
            k = 0
            kf = 0.0
            if not own:
                first = tz[lo_c] - dmax
                k = int(math.floor(first)) - 1 if p2 else 0
                q = lower_bound(tz, lo2, hi2, first - k)
                if q == hi2:
                    if not p2:
                        continue
                    q = lo2
                    k += 1
                kf = float(k)
            qh = q
            kh = k
            khf = kf
            for p in range(lo_c, hi_c):
                if levels and (big[p] != second):
                    continue
                tp = tz[p]
                # the window's upper end from the largest range, so that it only
                # grows with p (one pointer, no search per particle)
                hi_v = tp + dmax
                if own:
                    q = p + 1
                    k = 0
                    kf = 0.0
                    if q == hi_c:
                        if not p2:
                            continue
                        q = lo_c
                        k = 1
                        kf = 1.0
                else:
                    if q >= hi2:  # open sweep axis: exhausted
                        break
                    lo_v = tp - dmax
                    while tz[q] + kf < lo_v:
                        q, k, kf = _step(q, k, kf, lo2, hi2, p2)
                        if q == hi2:
                            break
                    if q >= hi2:
                        break
                # the upper end of p's window: never behind the lower one
                if kh < k or (kh == k and qh < q):
                    qh = q
                    kh = k
                    khf = kf
                while qh < hi2 and tz[qh] + khf <= hi_v:
                    qh, kh, khf = _step(qh, kh, khf, lo2, hi2, p2)
                xp = xs[p]
                yp = ys[p]
                zp = zs[p]
                rp = rs[p]
                lp = ls[p] if use_label else 0
                # runs of one shift: (q, k) .. (hi2, k), (lo2, k + 1) .. , .. (qh, kh)
                qa = q
                ka = k
                while ka < kh or (ka == kh and qa < qh):
                    qb = hi2 if ka < kh else qh
                    cx = ka * cell[2, 0]
                    cy = ka * cell[2, 1]
                    cz = ka * cell[2, 2]
                    tested += qb - qa
                    for base in range(qa, qb, 64):
                        top = min(base + 64, qb)
                        word = np.uint64(0)
                        # unsigned indices need no wraparound fix (so the loops
                        # vectorise) and, unlike slices, no reference counting
                        ub = np.uint64(base)
                        if fast is not None and exact:
                            # the common case written out, so that it vectorises
                            pt = p - base
                            for t in range(top - base):
                                u = ub + np.uint64(t)
                                dx = (xs[u] - xp) + ax
                                dy = (ys[u] - yp) + by
                                dz = (zs[u] - zp) + cz
                                ok = ((dx * dx + dy * dy + dz * dz <= x2)
                                      & ((pt != t) | self_images))
                                word |= np.uint64(ok) << np.uint64(t)
                        elif fast is not None:
                            # the same with the band: ``word`` the pairs up to out2,
                            # ``inner`` those clearly in; the rest is re-tested
                            pt = p - base
                            inner = np.uint64(0)
                            for t in range(top - base):
                                u = ub + np.uint64(t)
                                dx = (xs[u] - xp) + ax
                                dy = (ys[u] - yp) + by
                                dz = (zs[u] - zp) + cz
                                d2 = dx * dx + dy * dy + dz * dz
                                ok = (d2 <= out2) & ((pt != t) | self_images)
                                word |= np.uint64(ok) << np.uint64(t)
                                inner |= np.uint64(d2 <= in2) << np.uint64(t)
                            bits = word & ~inner
                            while bits:
                                t = cttz(bits)
                                bits &= bits - np.uint64(1)
                                if not _reference_hit(xg, perm, kp, p, base + np.int64(t),
                                                      cell, s0, s1, ka, 0.0, strict, True,
                                                      x2):
                                    word &= ~(np.uint64(1) << t)
                        else:
                            # a vectorised superset first (squared, a relative hair
                            # wide), then the exact test on the few bits it sets
                            # levels: the first walk pairs small with small, the
                            # second large with small, and large with large from
                            # the lower end
                            pt = p - base
                            if tri is None:
                                for t in range(top - base):
                                    u = ub + np.uint64(t)
                                    dx = (xs[u] - xp) + ax
                                    dy = (ys[u] - yp) + by
                                    dz = (zs[u] - zp) + cz
                                    thr = rp + rs[u] + skin_sup
                                    ok = dx * dx + dy * dy + dz * dz <= thr * thr * loose
                                    if levels:
                                        ok = ok & ((big[u] == 0) | (second & (pt < t)))
                                    word |= np.uint64(ok) << np.uint64(t)
                            else:
                                for t in range(top - base):
                                    u = ub + np.uint64(t)
                                    dx = (((xs[u] - xp) + ax) + bx) + cx
                                    dy = (((ys[u] - yp) + ay) + by) + cy
                                    dz = (((zs[u] - zp) + az) + bz) + cz
                                    thr = rp + rs[u] + skin_sup
                                    ok = dx * dx + dy * dy + dz * dz <= thr * thr * loose
                                    if levels:
                                        ok = ok & ((big[u] == 0) | (second & (pt < t)))
                                    word |= np.uint64(ok) << np.uint64(t)
                            bits = word
                            while bits:
                                t = cttz(bits)
                                bits &= bits - np.uint64(1)
                                q2 = base + np.int64(t)
                                if verlet:  # a superset is what the list needs
                                    ok = (p != q2) | self_images
                                    if use_label:
                                        ok = ok & (lp != ls[q2])
                                else:
                                    ok, d2, dx, dy, dz = _pair_test(
                                        q2, p, xs, ys, zs, ls, use_label, diag, ax, ay, az,
                                        bx, by, bz, cx, cy, cz, xp, yp, zp, lp, self_images)
                                    ok = ok and _decide(d2, rp + rs[q2] + skin, strict,
                                                        uniform, x2, in2, out2, dtol, xg,
                                                        perm, kp, p, q2, cell, s0, s1, ka)
                                if not ok:
                                    word &= ~(np.uint64(1) << t)
                        if word:
                            if w < wcap:
                                r = wbase + w
                                words[r] = word
                                rec_p[r] = p
                                rec_q[r] = base
                                rec_s[r] = encode(s0, s1, ka)
                            w += 1
                            cnt += np.int64(ctpop(word))
                    qa = lo2
                    ka += 1
    return cnt, tested, w

@hjit
def _records_fill(r_lo, r_hi, o, words, rec_p, rec_q, rec_s, xs, ys, zs, rs, ls, use_label,
                  cell, diag, self_images, skin, strict, uniform, x2, perm, kw, xg, exact,
                  want_d, want_vec, want_shift, out_p, out_d, out_v, out_s):
    """Pass 2 of a direct frame: write the pairs of records ``[r_lo, r_hi)`` from
    slot ``o`` (rows as ``narrow_fill``'s).  Distances and vectors are the agreed
    arithmetic's: the sweep's own sum in an ``exact`` frame and for pairs of
    two particles not wrapped (``_unwrapped``), else the sum on the given
    positions ``xg`` with the shift relative to them."""
    uo = np.uint64(o)
    for r in range(r_lo, r_hi):
        p = np.int64(rec_p[r])
        base = np.int64(rec_q[r])
        s0, s1, s2 = decode(rec_s[r])
        ax = s0 * cell[0, 0]
        ay = s0 * cell[0, 1]
        az = s0 * cell[0, 2]
        bx = s1 * cell[1, 0]
        by = s1 * cell[1, 1]
        bz = s1 * cell[1, 2]
        cx = s2 * cell[2, 0]
        cy = s2 * cell[2, 1]
        cz = s2 * cell[2, 2]
        xp = xs[p]
        yp = ys[p]
        zp = zs[p]
        ip = perm[p]
        # only pairs with a wrapped end need the sum on the given positions
        plain = exact or _unwrapped(kw, p)
        word = words[r]
        ubase = np.uint64(base)
        while word:
            # unsigned indices: no negative-index fix on every access
            q = ubase + cttz(word)
            word &= word - np.uint64(1)
            iq = perm[q]
            g0 = s0
            g1 = s1
            g2 = s2
            if want_shift or not exact:  # (kw is read only then)
                g0, g1, g2 = _given_shift(kw, p, q, s0, s1, s2)
            # a pair of pass 1: only its separation is needed (_pair_test's sum)
            if not exact and not (plain and _unwrapped(kw, q)):
                dx, dy, dz = _separation(xg, ip, iq, cell, g0, g1, g2)
            elif diag:
                dx = (xs[q] - xp) + ax
                dy = (ys[q] - yp) + by
                dz = (zs[q] - zp) + cz
            else:
                dx = (((xs[q] - xp) + ax) + bx) + cx
                dy = (((ys[q] - yp) + ay) + by) + cy
                dz = (((zs[q] - zp) + az) + bz) + cz
            d2 = dx * dx + dy * dy + dz * dz
            flip = iq < ip
            out_p[uo, 0] = min(ip, iq)
            out_p[uo, 1] = max(ip, iq)
            if want_d:
                out_d[uo] = math.sqrt(d2)
            if want_vec:
                _store3(out_v, uo, dx, dy, dz, flip)
            if want_shift:
                _store3(out_s, uo, g0, g1, g2, flip)
            uo += np.uint64(1)
    return np.int64(uo)


@pjit
def direct_count(chunk_cols, start, nb0, nb1, pbc, tz, xs, ys, zs, rs, ls, use_label, cell,
                 diag, stencil, rmax, reach, inv_w2, self_images, skin, strict, uniform, x2,
                 lo2, hi2, dtol, exact, xg, perm, kp, words, rec_p, rec_q, rec_s, wstart,
                 wcap, counts, tested, wneed, todo, levels, big, r_small, stencil_big, verlet,
                 fast, tri):
    """Pass 1 of a direct frame (no Verlet list) for every chunk marked in
    ``todo``: its pairs into ``counts``, its records into ``wneed`` (kept when
    they fit its ``wcap``); ``fast`` and ``tri`` are ``loop_mode`` of the frame."""
    n_chunks = chunk_cols.shape[0] - 1
    for c in numba.prange(n_chunks):
        if not todo[c]:
            continue
        counts[c], tested[c], wneed[c] = _sweep_chunk(
            chunk_cols[c], chunk_cols[c + 1], start, nb0, nb1, pbc, tz, xs, ys, zs, rs, ls,
            use_label, cell, diag, stencil, rmax, reach, inv_w2, self_images, skin, strict,
            uniform, x2, lo2, hi2, dtol, exact, xg, perm, kp, words, rec_p, rec_q, rec_s,
            wstart[c], wcap[c], levels, big, r_small, stencil_big, verlet, fast, tri)


@pjit
def direct_fill(wstart, wneed, offsets, words, rec_p, rec_q, rec_s, xs, ys, zs, rs, ls,
                use_label, cell, diag, self_images, skin, strict, uniform, x2, perm, kw,
                xg, exact, want_d, want_vec, want_shift, out_p, out_d, out_v, out_s):
    """Pass 2 of a direct frame: chunk ``c``'s pairs from ``offsets[c]``."""
    for c in numba.prange(wstart.shape[0]):
        _records_fill(wstart[c], wstart[c] + wneed[c], offsets[c], words, rec_p, rec_q,
                      rec_s, xs, ys, zs, rs, ls, use_label, cell, diag, self_images, skin,
                      strict, uniform, x2, perm, kw, xg, exact, want_d, want_vec,
                      want_shift, out_p, out_d, out_v, out_s)


@pjit
def records_narrow(fill, wstart, wneed, offsets, counts, words, rec_p, rec_q, rec_s, ws, m,
                   rs, skin, cell, diag, strict, uniform, x2, lo2, hi2, dtol, exact, xg, perm,
                   kw, want_d, want_vec, want_shift, out_p, out_d, out_v, out_s, out_e):
    """A Verlet frame on a list of records: pass 1 (``fill`` False) counts each
    chunk's pairs in range into ``counts``, pass 2 writes them from
    ``offsets[c]`` (rows as ``narrow_fill``'s; ``out_e``, unless empty, the
    entry of each row, ``64 * record + bit``, increasing).  Each entry's shift is corrected
    by the image jumps of its two particles since the build, as ``_entry`` does
    (the record's shift, with ``p``'s jump, serves every partner that jumped as
    ``p`` did, usually all); ``uniform`` and ``x2`` as for ``_hit``, ``diag`` a
    diagonal cell.  The test and the outputs follow the agreed arithmetic:
    the count pass decides by the frame's ``band`` (``lo2``, ``hi2``, ``dtol``,
    ``exact``), re-testing the band on the given positions ``xg`` with the wrap
    shifts ``kw``; the fill pass of a frame that is not exact computes every
    pair with a wrapped end on ``xg`` (``_unwrapped``: the others' sum on ``ws``
    is the same one; the same decisions, so the counts hold).  The fill pass
    leaves in ``counts[c]`` the number of rows it wrote: given room for every
    entry of a chunk (``counts[c]`` its entries), it is the whole frame in one
    pass (``VerletList.retest`` on one chunk)."""
    incl = not strict
    want_e = out_e.shape[0] > 0
    for c in numba.prange(wstart.shape[0]):
        o = offsets[c] if fill else 0
        end = o + counts[c] if fill else 0
        cnt = 0
        for r in range(wstart[c], wstart[c] + wneed[c]):
            p = np.int64(rec_p[r])
            base = np.int64(rec_q[r])
            mp = m[p]
            code = rec_s[r] + mp
            t0, t1, t2 = decode(code)
            # the record's shift terms, added in _separation's order
            ax = t0 * cell[0, 0]
            ay = t0 * cell[0, 1]
            az = t0 * cell[0, 2]
            bx = t1 * cell[1, 0]
            by = t1 * cell[1, 1]
            bz = t1 * cell[1, 2]
            cx = t2 * cell[2, 0]
            cy = t2 * cell[2, 1]
            cz = t2 * cell[2, 2]
            xp = ws[p, 0]
            yp = ws[p, 1]
            zp = ws[p, 2]
            rp = rs[p]
            ip = perm[p]
            # only pairs with a wrapped end need the sum on the given positions
            plain = exact or _unwrapped(kw, p)
            word = words[r]
            ubase = np.uint64(base)
            while word:
                q = ubase + cttz(word)  # unsigned: no negative-index fix
                word &= word - np.uint64(1)
                mq = m[q]
                s0, s1, s2 = t0, t1, t2
                if mq != 0:
                    s0, s1, s2 = decode(code - mq)
                if fill and not exact and not (plain and _unwrapped(kw, q)):
                    # the agreed arithmetic itself, for the outputs
                    g0, g1, g2 = _given_shift(kw, p, q, s0, s1, s2)
                    dx, dy, dz = _separation(xg, ip, perm[q], cell, g0, g1, g2)
                elif mq == 0:
                    if diag:
                        dx = (ws[q, 0] - xp) + ax
                        dy = (ws[q, 1] - yp) + by
                        dz = (ws[q, 2] - zp) + cz
                    else:
                        dx = (((ws[q, 0] - xp) + ax) + bx) + cx
                        dy = (((ws[q, 1] - yp) + ay) + by) + cy
                        dz = (((ws[q, 2] - zp) + az) + bz) + cz
                else:
                    dx, dy, dz = _separation(ws, p, q, cell, s0, s1, s2)
                d2 = dx * dx + dy * dy + dz * dz
                if not fill:
                    if exact:  # no band: the plain test, without a branch
                        cnt += np.int64(_hit(d2, rp + rs[q] + skin, strict, uniform, x2))
                    else:
                        cnt += np.int64(_decide(d2, rp + rs[q] + skin, strict, uniform, x2,
                                                lo2, hi2, dtol, xg, perm, kw, p, q, cell, s0,
                                                s1, s2))
                    continue
                if o >= end:
                    break
                d = math.sqrt(d2)
                thr = rp + rs[q] + skin
                ok = (d < thr) | (incl & (d == thr))
                iq = perm[q]
                flip = iq < ip
                out_p[o, 0] = min(ip, iq)
                out_p[o, 1] = max(ip, iq)
                if want_d:
                    out_d[o] = d
                if want_vec:
                    _store3(out_v, o, dx, dy, dz, flip)
                if want_shift:
                    g0, g1, g2 = _given_shift(kw, p, q, s0, s1, s2)
                    _store3(out_s, o, g0, g1, g2, flip)
                if want_e:
                    out_e[o] = 64 * r + np.int64(q - ubase)
                o += np.int64(ok)
        # pass 2 leaves the number it wrote: with room for every entry of the
        # chunk (``counts[c]`` its entries), one pass is the frame
        counts[c] = (o - offsets[c]) if fill else cnt

# ------------------------------------------------------------ Verlet frames


@ijit
def _entry(code, m, p, q):
    """Shift of a Verlet entry now: ``S - m_q + m_p`` on the packed codes (the
    biased 10-bit fields never borrow), decoded."""
    return decode(code - m[q] + m[p])


@pjit
def narrow_count(chunk_rows, vstart, vstop, vb, vs, ws, m, rs, skin, cell, strict, uniform,
                 x2, lo2, hi2, dtol, xg, perm, kw, counts):
    """Pairs in range per chunk of rows (pass 1 of a frame), decided by the
    frame's band as ``records_narrow``'s count pass."""
    n_chunks = chunk_rows.shape[0] - 1
    for c in numba.prange(n_chunks):
        cnt = 0
        for p in range(chunk_rows[c], chunk_rows[c + 1]):
            for e in range(vstart[p], vstop[p]):
                q = vb[e]
                s0, s1, s2 = _entry(vs[e], m, p, q)
                dx, dy, dz = _separation(ws, p, q, cell, s0, s1, s2)
                d2 = dx * dx + dy * dy + dz * dz
                if dtol == 0.0:  # an exact frame (no band): the plain test
                    cnt += np.int64(_hit(d2, rs[p] + rs[q] + skin, strict, uniform, x2))
                else:
                    cnt += np.int64(_decide(d2, rs[p] + rs[q] + skin, strict, uniform, x2,
                                            lo2, hi2, dtol, xg, perm, kw, p, q, cell, s0, s1,
                                            s2))
        counts[c] = cnt


@ijit
def _store3(out, o, a, b, c, flip):
    """Row ``o`` of ``out`` is ``(a, b, c)``, negated if ``flip`` (from ``j`` to ``i``
    into from ``i`` to ``j``)."""
    if flip:
        a = -a
        b = -b
        c = -c
    out[o, 0] = a
    out[o, 1] = b
    out[o, 2] = c


@pjit
def narrow_fill(chunk_rows, offsets, counts, vstart, vstop, vb, vs, ws, m, rs, skin,
                cell, strict, exact, xg, perm, kw, want_d, want_vec, want_shift, out_p, out_d,
                out_v, out_s, out_e):
    """Write each chunk's pairs from ``offsets[c]`` (pass 2 of a frame).

    Rows are ``(i, j)`` original indices with ``i < j``; the vector and shift
    are from ``i`` to ``j``, the shift in terms of the caller's positions
    (``D = x[j] - x[i] + S @ cell``; ``kw`` is the current wrap shift).  Every
    candidate is written to the next free slot and the slot is kept only if
    the pair is in range (no unpredictable branch); a chunk never writes past
    its own ``counts[c]`` slots.  ``out_e``, unless empty, gets the entry of
    each row (its index in ``vb``).  Outside an ``exact`` frame every pair with
    a wrapped end is computed on the given positions ``xg`` (the agreed
    arithmetic; ``_unwrapped``).
    """
    n_chunks = chunk_rows.shape[0] - 1
    incl = not strict
    want_e = out_e.shape[0] > 0
    for c in numba.prange(n_chunks):
        o = offsets[c]
        end = o + counts[c]
        for p in range(chunk_rows[c], chunk_rows[c + 1]):
            if o >= end:
                break
            ip = perm[p]
            plain = exact or _unwrapped(kw, p)
            for e in range(vstart[p], vstop[p]):
                q = vb[e]
                s0, s1, s2 = _entry(vs[e], m, p, q)
                iq = perm[q]
                if exact or (plain and _unwrapped(kw, q)):
                    dx, dy, dz = _separation(ws, p, q, cell, s0, s1, s2)
                else:
                    g0, g1, g2 = _given_shift(kw, p, q, s0, s1, s2)
                    dx, dy, dz = _separation(xg, ip, iq, cell, g0, g1, g2)
                d = math.sqrt(dx * dx + dy * dy + dz * dz)
                thr = rs[p] + rs[q] + skin
                ok = (d < thr) | (incl & (d == thr))
                if o >= end:
                    break
                flip = iq < ip
                out_p[o, 0] = min(ip, iq)
                out_p[o, 1] = max(ip, iq)
                if want_d:
                    out_d[o] = d
                if want_vec:
                    _store3(out_v, o, dx, dy, dz, flip)
                if want_shift:
                    # w = x - k @ cell:  D = x_q - x_p + (S - k_q + k_p) @ cell
                    g0, g1, g2 = _given_shift(kw, p, q, s0, s1, s2)
                    _store3(out_s, o, g0, g1, g2, flip)
                if want_e:
                    out_e[o] = e
                o += np.int64(ok)


@jit
def csr_from_pairs(n, pairs, dist, want_d, offsets, col, cd):
    """Half list by row: ``offsets`` (n + 1), partners ``col`` and distances ``cd``
    of each ``i`` (rows in increasing ``i``, partners in pair order)."""
    k = pairs.shape[0]
    for i in range(n + 1):
        offsets[i] = 0
    for t in range(k):
        offsets[pairs[t, 0] + 1] += 1
    for i in range(n):
        offsets[i + 1] += offsets[i]
    fill = offsets[:-1].copy()
    for t in range(k):
        i = pairs[t, 0]
        o = fill[i]
        col[o] = pairs[t, 1]
        if want_d:
            cd[o] = dist[t]
        fill[i] = o + 1


# ------------------------------------------------------------ small frames
#
# A frame of a few thousand particles without a Verlet margin is done in two
# serial calls, with no array work in Python between them: ``small_count``
# wraps, plans the columns, sorts, gathers and runs pass 1 of the sweep over
# every column (``_sweep_chunk``, one chunk); ``small_fill`` runs pass 2
# (``_records_fill``) into the outputs.  They are the general path's own
# kernels on one chunk, so the records, the pairs, their order and their
# distances are those of the general path bit for bit.


@hjit
def _small_sweep(ncol, start, nb0, nb1, pbc, tz, xs, ys, zs, rs, ls, use_label, cell, diag,
                 stencil, rmax, reach, inv_w2, skin, strict, uniform, x2, in2, out2, dtol,
                 exact, xg, perm, kp, words, rec_p, rec_q, rec_s, wcap, levels, big, r_small,
                 stencil_big, zidx, nz, zlo, inv_bz, ts0, ts1, lo0, lo1, f0, f1, inv_w0,
                 inv_w1, guard, fast, tri):
    """``_sweep_chunk`` over every column of a small frame (no self-images, no
    Verlet list) with a window per particle.

    The pairs of every (column, walk, stencil column, particle) are those of
    ``_sweep_chunk``, in the same order (lattice shift along the sweep axis,
    then candidate), so the records hold the same pairs in the same order;
    only the candidates tested differ.  The window of ``p`` is its own range
    ``(rs[p] + r_win + reach) / w_2`` (``r_win`` bounds the partners' radii
    in this walk) instead of the largest one, and it is found without a
    pointer walk: ``zidx[col * (nz + 1) + b]`` is the first particle of
    column ``col`` in sweep bucket ``b`` or later (``_zbucket``), so the
    candidates of a shift ``k`` are those of the buckets from ``lo - k`` to
    ``hi - k``, a superset of the window (the exact test decides).  A stencil
    column farther from ``p`` across axis 0 or 1 than that range (``ts0``,
    ``ts1`` the fractional coordinates in column order, columns ``f0``, ``f1``
    wide from ``lo0``, ``lo1``) holds no partner and is not visited.

    ``fast`` and ``tri`` (``loop_mode``, each True or None) name the one
    candidate loop the frame takes: the vectorised loop of an orthorhombic
    cell with one threshold, no labels and one level (``fast``), else the
    superset loop of an orthorhombic or (``tri``) a triclinic cell.  A None is
    a type of its own to numba, which drops the branches it rules out before
    typing: a first frame compiles only the loop it takes."""
    cnt = 0
    tested = 0
    w = 0
    loose = 1.0 + 1e-12
    skin_sup = skin + dtol  # the supersets hold the band
    p2 = pbc[2]
    ztop = float(nz - 1)
    zstride = nz + 1
    for col in range(ncol):
      lo_c = start[col]
      hi_c = start[col + 1]
      if lo_c == hi_c:
          continue
      b0 = col // nb1
      b1 = col - b0 * nb1
      for walk in range(2 if levels else 1):
        second = walk == 1
        st = stencil_big if second else stencil
        n_st = st.shape[0]
        r_win = rmax if (second or not levels) else r_small
        rw = r_win + reach
        # the range across axes 0 and 1, a guard more for the rounding of the
        # column edges
        rg = rw + guard
        for o_st in range(0 if second else -1, n_st):
            own = o_st < 0  # the column itself: forward in sorted order
            s0 = 0
            s1 = 0
            # the gap of p to the stencil column across axis c: g_c (e_c - t_c),
            # nothing along an axis of no offset
            g0 = 0.0
            g1 = 0.0
            e0 = 0.0
            e1 = 0.0
            if own:
                col2 = col
            else:
                o0 = st[o_st, 0]
                o1 = st[o_st, 1]
                if o0 > 0:
                    g0 = 1.0
                    e0 = lo0 + (b0 + o0) * f0
                elif o0 < 0:
                    g0 = -1.0
                    e0 = lo0 + (b0 + o0 + 1) * f0
                if o1 > 0:
                    g1 = 1.0
                    e1 = lo1 + (b1 + o1) * f1
                elif o1 < 0:
                    g1 = -1.0
                    e1 = lo1 + (b1 + o1 + 1) * f1
                c0 = b0 + st[o_st, 0]
                c1 = b1 + st[o_st, 1]
                if pbc[0]:
                    s0 = c0 // nb0
                    c0 -= s0 * nb0
                elif c0 < 0 or c0 >= nb0:
                    continue
                if pbc[1]:
                    s1 = c1 // nb1
                    c1 -= s1 * nb1
                elif c1 < 0 or c1 >= nb1:
                    continue
                col2 = c0 * nb1 + c1
            lo2 = start[col2]
            hi2 = start[col2 + 1]
            if lo2 == hi2:
                continue
            zrow = col2 * zstride
            ax = s0 * cell[0, 0]
            ay = s0 * cell[0, 1]
            az = s0 * cell[0, 2]
            bx = s1 * cell[1, 0]
            by = s1 * cell[1, 1]
            bz = s1 * cell[1, 2]
            for p in range(lo_c, hi_c):
                if levels and (big[p] != second):
                    continue
                rp = rs[p]
                if not own:
                    reach_p = rp + rg
                    if ((g0 * (e0 - ts0[p]) > reach_p * inv_w0)
                            | (g1 * (e1 - ts1[p]) > reach_p * inv_w1)):
                        continue
                tp = tz[p]
                dp = (rp + rw) * inv_w2
                lo_v = tp - dp
                hi_v = tp + dp
                xp = xs[p]
                yp = ys[p]
                zp = zs[p]
                lp = ls[p] if use_label else 0
                # the shifts along the sweep axis whose images can meet the window
                # (t in [0, 1] on a periodic axis): k + 1 >= lo_v and k <= hi_v
                k_lo = 0
                k_hi = 0
                if p2 and not (lo_v > 0.0 and hi_v < 1.0):
                    # (a window inside the cell meets the images of shift 0 only)
                    if not own:
                        k_lo = np.int64(math.ceil(lo_v)) - 1
                    k_hi = np.int64(math.floor(hi_v))
                for ka in range(k_lo, k_hi + 1):
                    kf = float(ka)
                    qa = zidx[zrow + _zbucket(lo_v - kf, zlo, inv_bz, ztop)]
                    qb = zidx[zrow + _zbucket(hi_v - kf, zlo, inv_bz, ztop) + 1]
                    if own and ka == 0:
                        qa = max(qa, p + 1)
                    if qa >= qb:
                        continue
                    cx = ka * cell[2, 0]
                    cy = ka * cell[2, 1]
                    cz = ka * cell[2, 2]
                    tested += qb - qa
                    for base in range(qa, qb, 64):
                        top = min(base + 64, qb)
                        word = np.uint64(0)
                        ub = np.uint64(base)
                        if fast is not None and exact:
                            pt = p - base
                            for t in range(top - base):
                                u = ub + np.uint64(t)
                                dx = (xs[u] - xp) + ax
                                dy = (ys[u] - yp) + by
                                dz = (zs[u] - zp) + cz
                                ok = (dx * dx + dy * dy + dz * dz <= x2) & (pt != t)
                                word |= np.uint64(ok) << np.uint64(t)
                        elif fast is not None:
                            pt = p - base
                            inner = np.uint64(0)
                            for t in range(top - base):
                                u = ub + np.uint64(t)
                                dx = (xs[u] - xp) + ax
                                dy = (ys[u] - yp) + by
                                dz = (zs[u] - zp) + cz
                                d2 = dx * dx + dy * dy + dz * dz
                                ok = (d2 <= out2) & (pt != t)
                                word |= np.uint64(ok) << np.uint64(t)
                                inner |= np.uint64(d2 <= in2) << np.uint64(t)
                            bits = word & ~inner
                            while bits:
                                t = cttz(bits)
                                bits &= bits - np.uint64(1)
                                if not _reference_hit(xg, perm, kp, p, base + np.int64(t),
                                                      cell, s0, s1, ka, 0.0, strict, True,
                                                      x2):
                                    word &= ~(np.uint64(1) << t)
                        else:
                            pt = p - base
                            if tri is None and not levels:
                                # (few hits among the candidates: a branch taken
                                # rarely costs less than the mask of every one)
                                for t in range(top - base):
                                    u = ub + np.uint64(t)
                                    dx = (xs[u] - xp) + ax
                                    dy = (ys[u] - yp) + by
                                    dz = (zs[u] - zp) + cz
                                    thr = rp + rs[u] + skin_sup
                                    if dx * dx + dy * dy + dz * dz <= thr * thr * loose:
                                        word |= np.uint64(1) << np.uint64(t)
                            elif tri is None:
                                for t in range(top - base):
                                    u = ub + np.uint64(t)
                                    dx = (xs[u] - xp) + ax
                                    dy = (ys[u] - yp) + by
                                    dz = (zs[u] - zp) + cz
                                    thr = rp + rs[u] + skin_sup
                                    ok = dx * dx + dy * dy + dz * dz <= thr * thr * loose
                                    ok = ok & ((big[u] == 0) | (second & (pt < t)))
                                    word |= np.uint64(ok) << np.uint64(t)
                            else:
                                for t in range(top - base):
                                    u = ub + np.uint64(t)
                                    dx = (((xs[u] - xp) + ax) + bx) + cx
                                    dy = (((ys[u] - yp) + ay) + by) + cy
                                    dz = (((zs[u] - zp) + az) + bz) + cz
                                    thr = rp + rs[u] + skin_sup
                                    ok = dx * dx + dy * dy + dz * dz <= thr * thr * loose
                                    if levels:
                                        ok = ok & ((big[u] == 0) | (second & (pt < t)))
                                    word |= np.uint64(ok) << np.uint64(t)
                            bits = word
                            while bits:
                                t = cttz(bits)
                                bits &= bits - np.uint64(1)
                                q2 = base + np.int64(t)
                                ok, d2, dx, dy, dz = _pair_test(
                                    q2, p, xs, ys, zs, ls, use_label, diag, ax, ay, az,
                                    bx, by, bz, cx, cy, cz, xp, yp, zp, lp, False)
                                ok = ok and _decide(d2, rp + rs[q2] + skin, strict,
                                                    uniform, x2, in2, out2, dtol, xg,
                                                    perm, kp, p, q2, cell, s0, s1, ka)
                                if not ok:
                                    word &= ~(np.uint64(1) << t)
                        if word:
                            if w < wcap:
                                words[w] = word
                                rec_p[w] = p
                                rec_q[w] = base
                                rec_s[w] = encode(s0, s1, ka)
                            w += 1
                            cnt += np.int64(ctpop(word))
    return cnt, tested, w


@ijit
def _small_zindex(ncol, start, tz, zidx, nz, zlo, inv_bz):
    """``zidx`` of ``_small_sweep``: for every column its first particle in each
    sweep bucket or later, then the column's end."""
    ztop = float(nz - 1)
    stride = nz + 1
    for c in range(ncol):
        row = c * stride
        hi = start[c + 1]
        b = 0
        for q in range(start[c], hi):
            # (sorted along the sweep axis: the buckets up to q's start at q)
            bq = _zbucket(tz[q], zlo, inv_bz, ztop)
            while b <= bq:
                zidx[row + b] = q
                b += 1
        while b <= nz:
            zidx[row + b] = hi
            b += 1


def loop_mode(diag, uniform, use_label, levels):
    """``(fast, tri)`` of ``_sweep_chunk`` and ``_small_sweep`` for a frame, each
    True or None: the vectorised loop of the common case, or the superset loop
    of an orthorhombic or a triclinic cell."""
    fast = diag and uniform and not use_label and not levels
    return (True if fast else None), (True if not fast and not diag else None)


#: a sparse frame's columns are widened, up to MAX_WIDEN times, until a window
#: holds about WINDOW_TARGET candidates (``search.plan.wide_columns``), in
#: frames of up to WIDE_MAX particles: those this kernel takes on any thread
#: count (fewer than two chunks of parallel work, ``search.plan.CHUNK``), so
#: that the general path, which plans them alike, stays as fast on larger ones
WINDOW_TARGET = 25.0
MAX_WIDEN = 3.0
WIDE_MAX = 4095


@ijit
def wide_columns(nb0, nb1, n, delta2, span2):
    """Columns ``(nb0, nb1)`` widened for a sparse frame (``search.plan.wide_columns``
    says why): the expected candidates of a window, ``n / (nb0 nb1)`` particles per
    column times the window's share ``delta2 / span2`` of the sweep axis, below
    ``WINDOW_TARGET`` widen the columns by ``sqrt(WINDOW_TARGET / that)``, at most
    ``MAX_WIDEN`` times.  One compiled function for the small-frame kernel and the
    general path's plan, so that both take the same columns bit for bit."""
    per_window = n / (nb0 * nb1)
    if span2 > 0:
        along = delta2 / span2
        per_window *= along if along < 1.0 else 1.0
    if not per_window < WINDOW_TARGET:
        return nb0, nb1
    f = MAX_WIDEN
    if per_window > 0.0:
        f = min(MAX_WIDEN, math.sqrt(WINDOW_TARGET / per_window))
    return max(1, int(math.floor(nb0 / f))), max(1, int(math.floor(nb1 / f)))


@hjit
def _small_plan(x, rad, label, use_label, cell, hinv, diag, pbc, widths, skin, x2,
                guard_rel, r_small, fresh, prev, t, k, w, col, perm, start, cursor, tz, xs,
                ys, zs, rs, ls, big, stencil, kp, zidx, ts0, ts1):
    """Wrap, plan, sort and gather one frame for ``_small_sweep``: the steps of
    ``search._build`` on one chunk, and the sweep buckets of the windows.
    Returns (first bad input row, -1, or -2 for a stencil larger than
    ``stencil`` or sweep buckets too crowded for the windows: the general
    path; nb0, nb1, then what ``_small_sweep`` takes: the band (``lo2``,
    ``hi2``, ``dtol``, ``exact``), the stencils, the largest radius, the reach
    and guard, the buckets and the column edges)."""
    n = x.shape[0]
    bad = -1
    extent = 0.0
    rmax = 0.0
    kmax = np.int64(0)
    for i in range(n):
        if not _wrap_one(x, i, hinv, cell, diag, pbc, t, k, w, i):
            if bad < 0:
                bad = i
        for c in range(3):
            a = abs(w[i, c])
            extent = a if a > extent else extent
            kc = abs(k[i, c])
            kmax = kc if kc > kmax else kmax
        rmax = rad[i] if rad[i] > rmax else rmax
    none = np.empty((0, 2), np.int64)
    if bad >= 0 or n == 0:
        return (bad, 1, 1, x2, x2, 0.0, True, 0, none, 0.0, 0.0, 0.0, 1, 0.0, 0.0, 0.0, 0.0,
                0.0, 0.0)
    lo2, hi2, dtol, exact = frame_band(extent, kmax, cell, pbc, widths, 2.0 * rmax + skin,
                                       2.0 * rmax + skin, x2)
    extent = extent + 2.0 * rmax + skin
    guard = guard_rel * extent + 2.2250738585072014e-308
    reach = skin + guard + dtol
    lo0 = 0.0
    lo1 = 0.0
    span0 = 1.0
    span1 = 1.0
    span2 = 1.0
    for c in range(3):
        if not pbc[c]:
            mn = t[0, c]
            mx = t[0, c]
            for i in range(1, n):
                v = t[i, c]
                mn = v if v < mn else mn
                mx = v if v > mx else mx
            if c == 0:
                lo0 = mn
                span0 = mx - mn
            elif c == 1:
                lo1 = mn
                span1 = mx - mn
            else:
                span2 = mx - mn
    levels = r_small > 0.0
    bin_range = 2.0 * (r_small if levels else rmax) + reach + guard
    big_range = 2.0 * rmax + reach + guard
    # the column plan of search._build (columns one range wide)
    nb0 = 1
    nb1 = 1
    d0 = bin_range / widths[0]
    d1 = bin_range / widths[1]
    if span0 > 0:
        nb0 = int(max(1.0, math.floor(min(span0 / d0 if d0 > 0 else math.inf, 65536.0))))
    if span1 > 0:
        nb1 = int(max(1.0, math.floor(min(span1 / d1 if d1 > 0 else math.inf, 65536.0))))
    while nb0 * nb1 > max(1, n) and max(nb0, nb1) > 1:
        if nb0 >= nb1:
            nb0 = max(1, nb0 // 2)
        else:
            nb1 = max(1, nb1 // 2)
    crowded = 32.0  # (a bucket of a column one range wide; wider ones hold more)
    if not levels and n <= WIDE_MAX:  # as the general path's plan_columns
        wide0, wide1 = wide_columns(nb0, nb1, n, bin_range / widths[2], span2)
        crowded *= (nb0 * nb1) / (wide0 * wide1)
        nb0 = wide0
        nb1 = wide1
    inv0 = nb0 / span0 if span0 > 0 else 0.0
    inv1 = nb1 / span1 if span1 > 0 else 0.0
    f0 = span0 / nb0
    f1 = span1 / nb1
    if not math.isfinite(inv0):
        nb0 = 1
        inv0 = 0.0
        f0 = 0.0
    if not math.isfinite(inv1):
        nb1 = 1
        inv1 = 0.0
        f1 = 0.0
    L0 = 1 if (f0 >= d0 or f0 == 0) else int(math.ceil(d0 / f0))
    L1 = 1 if (f1 >= d1 or f1 == 0) else int(math.ceil(d1 / f1))
    db0 = big_range / widths[0]
    db1 = big_range / widths[1]
    B0 = 1 if (f0 >= db0 or f0 == 0) else int(math.ceil(db0 / f0))
    B1 = 1 if (f1 >= db1 or f1 == 0) else int(math.ceil(db1 / f1))
    if not pbc[0]:
        L0 = min(L0, nb0 - 1)
        B0 = min(B0, nb0 - 1)
    if not pbc[1]:
        L1 = min(L1, nb1 - 1)
        B1 = min(B1, nb1 - 1)
    n_st = 0
    for o0 in range(-L0, L0 + 1):
        for o1 in range(-L1, L1 + 1):
            if o0 > 0 or (o0 == 0 and o1 > 0):
                if n_st < stencil.shape[0]:
                    stencil[n_st, 0] = o0
                    stencil[n_st, 1] = o1
                n_st += 1
    if n_st > stencil.shape[0]:
        # columns a rounding narrower than the range can need two layers: the
        # caller has room for those; anything wider goes to the general path
        return (-2, nb0, nb1, lo2, hi2, dtol, exact, 0, none, rmax, reach, guard, 1, 0.0,
                0.0, lo0, lo1, f0, f1)
    stencil_big = np.empty(((2 * B0 + 1) * (2 * B1 + 1) if levels else 0, 2), np.int64)
    if levels:
        j = 0
        for o0 in range(-B0, B0 + 1):
            for o1 in range(-B1, B1 + 1):
                stencil_big[j, 0] = o0
                stencil_big[j, 1] = o1
                j += 1
    ncol = nb0 * nb1
    # a stable counting sort of the previous order by column, then t2 in columns
    for c in range(ncol + 1):
        start[c] = 0
    for i in range(n):
        b0 = int(math.floor((t[i, 0] - lo0) * inv0))
        b1 = int(math.floor((t[i, 1] - lo1) * inv1))
        b0 = min(max(b0, 0), nb0 - 1)
        b1 = min(max(b1, 0), nb1 - 1)
        col[i] = b0 * nb1 + b1
        start[col[i] + 1] += 1
    for c in range(ncol):
        start[c + 1] += start[c]
        cursor[c] = start[c]
    for r in range(n):
        i = r if fresh else prev[r]
        c = col[i]
        perm[cursor[c]] = i
        cursor[c] += 1
    for c in range(ncol):
        lo_c = start[c]
        hi_c = start[c + 1]
        budget = 8 * (hi_c - lo_c) + 64
        moves = 0
        for p in range(lo_c + 1, hi_c):
            v = perm[p]
            kv = t[v, 2]
            q = p - 1
            while q >= lo_c and t[perm[q], 2] > kv:
                perm[q + 1] = perm[q]
                q -= 1
                moves += 1
            perm[q + 1] = v
            if moves > budget:
                break
        if moves > budget:
            m = hi_c - lo_c
            seg = perm[lo_c:hi_c].copy()
            vals = np.empty(m, np.float64)
            for p in range(m):
                vals[p] = t[seg[p], 2]
            order = stable_argsort(vals)
            for p in range(m):
                perm[lo_c + p] = seg[order[p]]
    keep01 = ts0.shape[0] >= n and ts1.shape[0] >= n
    for p in range(n):
        i = perm[p]
        if keep01:
            ts0[p] = t[i, 0]
            ts1[p] = t[i, 1]
        tz[p] = t[i, 2]
        xs[p] = w[i, 0]
        ys[p] = w[i, 1]
        zs[p] = w[i, 2]
        rs[p] = rad[i]
        if use_label:
            ls[p] = label[i]
        if levels:
            big[p] = np.uint8(rs[p] > r_small)
        kp[p, 0] = k[i, 0]
        kp[p, 1] = k[i, 1]
        kp[p, 2] = k[i, 2]
    chunk_start = start[:ncol + 1]
    inv_w2 = 1.0 / widths[2]
    # buckets of the sweep axis for the windows of _small_sweep: an eighth of the
    # widest window's half width (sixteen to a window), at most two per particle
    # of a column
    zlo = 0.0
    span = 1.0
    if not pbc[2]:
        zlo = tz[0]
        zhi = tz[0]
        for p in range(1, n):
            v = tz[p]
            zlo = v if v < zlo else zlo
            zhi = v if v > zhi else zhi
        span = zhi - zlo
    bw = 0.125 * (2.0 * (r_small if levels else rmax) + reach) * inv_w2
    cap_nz = 2 * ((n + ncol - 1) // ncol) + 1
    nzf = span / bw if bw > 0.0 else math.inf
    nz = max(1, int(math.ceil(nzf))) if nzf < cap_nz else cap_nz
    inv_bz = nz / span if span > 0.0 else 0.0
    if not math.isfinite(inv_bz):
        nz = 1
        inv_bz = 0.0
    use_z = keep01 and ncol * (nz + 1) <= zidx.shape[0]
    if use_z:
        _small_zindex(ncol, chunk_start, tz, zidx, nz, zlo, inv_bz)
        # crowded buckets (positions clustered along an open sweep axis) would
        # make the windows long: the pointer walk of _sweep_chunk then
        # (the general path).  Widened columns hold as many more per bucket
        # as they are larger (a settled pile's layers, one to a bucket)
        fullest = 0
        for c in range(ncol):
            row = c * (nz + 1)
            for b in range(nz):
                fullest = max(fullest, zidx[row + b + 1] - zidx[row + b])
        use_z = fullest <= crowded
    if not use_z:
        # the general path's pointer walk (search._build), whose kernels compile
        # only for the frames that need them, not in every first small frame
        bad = -2
    return (bad, nb0, nb1, lo2, hi2, dtol, exact, n_st, stencil_big, rmax, reach, guard, nz,
            zlo, inv_bz, lo0, lo1, f0, f1)


@jit
def small_frame(x, rad, label, use_label, cell, hinv, diag, pbc, widths, skin, strict,
                uniform, x2, guard_rel, r_small, fresh, prev, t, k, w, col, perm, start,
                cursor, tz, xs, ys, zs, rs, ls, big, stencil, words, rec_p, rec_q, rec_s, kp,
                zidx, ts0, ts1, want_d, want_vec, want_shift, out_p, out_d, out_v, out_s,
                fast, tri, fill):
    """One small frame (serial, minimum image, no Verlet list) in one call: wrap,
    plan, sort and gather (``_small_plan``, the steps of ``search._build`` on
    one chunk), sweep (``_small_sweep``, pass 1 of ``direct_count``) and, when
    the records and the pairs fit ``words`` and the outputs, write the pairs
    (``_records_fill``).  ``r_small > 0`` asks for two column levels split at
    that radius; ``fast`` and ``tri`` are ``loop_mode`` of the frame (each
    True or None: the one candidate loop compiled).  ``fill = (need, exact)``
    with ``need >= 0`` only writes the pairs of the records of the call before
    (into outputs grown since).

    Returns (first bad input row, -1, or -2 for a stencil larger than
    ``stencil`` or sweep buckets too crowded for the windows: the general
    path, -3 for ``fast`` and ``tri`` not the frame's; pairs, candidates
    tested, records needed, nb0, nb1, whether the frame is exact, whether the
    outputs were written).  The wrap shifts in column order go to ``kp``; the
    pair test is the agreed arithmetic on ``x`` (the frame's ``band``)."""
    need, exact = fill
    zero = np.int64(0)  # (typed values, not literals: one compiled _records_fill for
    no_self = np.bool_(False)  # this kernel and direct_fill)
    if need >= 0:
        total = _records_fill(zero, need, zero, words, rec_p, rec_q, rec_s, xs, ys, zs, rs, ls,
                              use_label, cell, diag, no_self, skin, strict, uniform, x2, perm,
                              kp, x, exact, want_d, want_vec, want_shift, out_p, out_d, out_v,
                              out_s)
        return -1, total, 0, need, 0, 0, exact, True
    (bad, nb0, nb1, lo2, hi2, dtol, exact, n_st, stencil_big, rmax, reach, guard, nz, zlo,
     inv_bz, lo0, lo1, f0, f1) = _small_plan(
        x, rad, label, use_label, cell, hinv, diag, pbc, widths, skin, x2, guard_rel, r_small,
        fresh, prev, t, k, w, col, perm, start, cursor, tz, xs, ys, zs, rs, ls, big, stencil,
        kp, zidx, ts0, ts1)
    if bad != -1 or x.shape[0] == 0:
        return bad, 0, 0, 0, nb0, nb1, exact, bad == -1
    want = diag and uniform and not use_label and not r_small > 0.0  # loop_mode
    if (fast is not None) != want or (tri is not None) != (not want and not diag):
        return -3, 0, 0, 0, nb0, nb1, exact, False  # the caller's error
    ncol = nb0 * nb1
    total, tested, need = _small_sweep(
        ncol, start[:ncol + 1], nb0, nb1, pbc, tz, xs, ys, zs, rs, ls, use_label, cell, diag,
        stencil[:n_st], rmax, reach, 1.0 / widths[2], skin, strict, uniform, x2, lo2, hi2,
        dtol, exact, x, perm, kp, words, rec_p, rec_q, rec_s, words.shape[0], r_small > 0.0,
        big, r_small, stencil_big, zidx, nz, zlo, inv_bz, ts0, ts1, lo0, lo1, f0, f1,
        1.0 / widths[0], 1.0 / widths[1], guard, fast, tri)
    done = (need <= words.shape[0] and total <= out_p.shape[0]
            and (total <= out_d.shape[0] or not want_d)
            and (total <= out_v.shape[0] or not want_vec)
            and (total <= out_s.shape[0] or not want_shift))
    if done:
        _records_fill(zero, need, zero, words, rec_p, rec_q, rec_s, xs, ys, zs, rs, ls,
                      use_label, cell, diag, no_self, skin, strict, uniform, x2, perm, kp, x, exact,
                      want_d, want_vec, want_shift, out_p, out_d, out_v, out_s)
    return -1, total, tested, need, nb0, nb1, exact, done


# ------------------------------------------------------------ serial twins


#: the parallel kernels of this module, compiled serially (same names)
serial = SimpleNamespace(**{name: serial_twin(globals()[name]) for name in (
    "wrap", "wrap_sorted", "columns_of", "counting_sort", "sort_columns", "gather",
    "gather_columns", "direct_count",
    "direct_fill", "records_narrow", "narrow_count", "narrow_fill")})
