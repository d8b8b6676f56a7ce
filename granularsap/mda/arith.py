"""MDAnalysis's own distance arithmetic, to decide pairs at the cutoff as it does.

MDAnalysis computes from float32 coordinates, and each of its capped-distance
methods wraps coordinates and takes the minimum image in its own way, so the
methods disagree with each other about pairs within float32 rounding of the
cutoff.  The drop-ins in ``granularsap.mda`` find candidates with a slightly
wider cutoff and then decide every candidate with the arithmetic of the method
MDAnalysis would use (``method=None`` chooses like MDAnalysis does):

* ``bruteforce`` (``distance_array`` / ``self_distance_array``): float32
  differences; orthorhombic minimum image ``box * (s - round(s))`` with
  ``s = inverse_box * dx`` and a float32 inverse box; triclinic: coordinates
  wrapped by ``_triclinic_pbc`` (``apply_PBC``), then the 27-image search.
* ``nsgrid``: coordinates wrapped by ``apply_PBC``; float32 differences;
  orthorhombic "lazy" image (one box shift past half a box), triclinic
  27-image search; ``d**2 <= cutoff**2`` with the cutoff and its square in
  double (``FastNS.cutoff`` is a C double in MDAnalysis 2.x: a cutoff that is
  not a float32 number, such as ``sqrt(2)``, is not rounded to float32).
* ``pkdtree`` decides inside scipy's KD-tree; candidates keep granularsap's
  float64 minimum-image decision.

These are ports of MDAnalysis's ``calc_distances.h`` and ``nsgrid.pyx``: the
coordinates are prepared per set with numpy, each candidate is decided in one
compiled pass (``_decide_kernel``, operation for operation in the same
dtypes); they need MDAnalysis only for ``apply_PBC`` and
``triclinic_vectors``.

Cutoffs beyond half the cell
----------------------------
MDAnalysis's answer for any cutoff is one minimum image per pair.  When the
cutoff exceeds half the smallest perpendicular cell width, ``granularsap.mda``
takes every image within range from the engine and keeps one row per pair
(:func:`nearest_images`: a bitmap of the ``n m`` pairs marks the first image
when MDAnalysis's arithmetic decides afterwards, else a counting sort by the
first index keeps the nearest image's distance).  When the cutoff's sphere
exceeds twice the cell's volume, nearly every pair is in range and the list of
every image would be several times the answer, so :func:`min_image_pairs`
tests every pair directly instead (a brute-force kernel): fractional
separation reduced to ``[-0.5, 0.5)``, a pair skipped at once if one
fractional component times its perpendicular width already exceeds the reach
(a lower bound on every image's distance), otherwise the true nearest image
(triclinic cells: the images ``n`` with ``|n_k| <= |r| / w_k + 1/2`` around the
reduced separation ``r``).  Cost O(n m) distance evaluations in two passes
(count, then fill at prefix-sum offsets) over chunks of rows balanced by work,
so memory is the output and no more; the output order does not depend on the
thread count.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .._numba import ijit, jit, pjit, serial_twin

#: Relative widening of the candidate search (float32 rounding is ~6e-8).
WIDEN = 1e-5


def _box_kind(box32):
    from MDAnalysis.lib.mdamath import triclinic_vectors

    if np.all(box32[3:] == 90.0):
        return "ortho", box32[:3].astype(np.float32)
    return "tri", triclinic_vectors(box32).astype(np.float32).ravel()


def choose_method(n_ref, n_conf, max_cutoff, box32, coords, method):
    """The method MDAnalysis's ``_determine_method(_self)`` would pick."""
    if method is not None:
        return str(method).lower()
    if n_conf is None:
        if n_ref < 100:
            return "bruteforce"
    else:
        if n_ref < 10 or n_conf < 10:
            return "bruteforce"
        if n_ref * n_conf >= 1e8:
            return "nsgrid"
    if box32 is None:
        size = coords.max(axis=0) - coords.min(axis=0)
    elif np.all(box32[3:] == 90.0):
        size = box32[:3]
    else:
        from MDAnalysis.lib.mdamath import triclinic_vectors

        tribox = triclinic_vectors(box32)
        size = tribox.max(axis=0) - tribox.min(axis=0)
    if n_conf is None:
        return "pkdtree" if max_cutoff < 0.03 * size.min() else "nsgrid"
    return "bruteforce" if np.any(max_cutoff > 0.3 * size) else "nsgrid"


def nsgrid_refuses(max_cutoff, box32):
    """True if MDAnalysis's ``FastNS`` raises "Cutoff ... too large for box" for
    ``max_cutoff`` in the periodic box ``box32``.

    Its limit (``_prepare_box`` in nsgrid.pyx) is half the smallest of the
    cell's diagonal elements times the sines of the angles, in float32 with
    the C library's ``sinf``; numpy reproduces it to a unit in the last place,
    and a cutoff that close to it is put to MDAnalysis itself (one coordinate:
    the grid of a cutoff that large has a few cells).
    """
    from MDAnalysis.lib.mdamath import triclinic_vectors

    box32 = np.asarray(box32, dtype=np.float32)
    tv = triclinic_vectors(box32).reshape(9).astype(np.float32)
    sines = [np.float32(math.sin(float(np.float32(float(x) * (math.pi / 180.0)))))
             for x in box32[3:6]]
    xx, yy, zz = tv[0], tv[4], tv[8]
    limit = float(min(yy * sines[0], zz * sines[0], xx * sines[1], zz * sines[1],
                      xx * sines[2], yy * sines[2])) / 2.0
    c = float(max_cutoff)
    if abs(c - limit) > 1e-6 * limit:
        return c > limit
    from MDAnalysis.lib.nsgrid import FastNS

    try:
        FastNS(c, np.zeros((1, 3), np.float32), box32)
    except ValueError:
        return True
    return False


def _nsgrid_cutoff2(max_cutoff):
    """``cutoff2`` of nsgrid.pyx: ``self.cutoff * self.cutoff``, both doubles."""
    c = float(max_cutoff)
    return c * c


#: image rules of ``_decide_kernel``
_PLAIN, _ORTHO_LAZY, _ORTHO_ROUND, _TRICLINIC = 0, 1, 2, 3
#: candidates per chunk of the parallel decision (chunks never depend on threads)
_DECIDE_CHUNK = 1 << 14


@ijit
def _c_round1(s):
    """C ``round`` of a double: halves away from zero (numpy rounds them to even)."""
    r = np.trunc(s)
    frac = s - r
    if abs(frac) >= 0.5:
        r += 1.0 if s > 0 else (-1.0 if s < 0 else 0.0)
    return r


@ijit
def _decide_one(P, Q, i, j, rule, box, half, inv, tri, limit2):
    """Squared distance of ``Q[j] - P[i]`` as MDAnalysis computes it: float32
    differences, then the image ``rule`` in double.

    Exact when it is at most ``limit2``; otherwise some value above ``limit2``
    (the 27-image search skips images that cannot come under ``limit2``: only
    the smallest squared length matters, not which image has it).
    """
    # float32 - float32 is a float32 in numba as in numpy
    d0 = np.float64(Q[j, 0] - P[i, 0])
    d1 = np.float64(Q[j, 1] - P[i, 1])
    d2 = np.float64(Q[j, 2] - P[i, 2])
    if rule == _ORTHO_LAZY:
        d0 = d0 - box[0] if d0 > half[0] else (d0 + box[0] if d0 <= -half[0] else d0)
        d1 = d1 - box[1] if d1 > half[1] else (d1 + box[1] if d1 <= -half[1] else d1)
        d2 = d2 - box[2] if d2 > half[2] else (d2 + box[2] if d2 <= -half[2] else d2)
    elif rule == _ORTHO_ROUND:
        s = inv[0] * d0
        d0 = box[0] * (s - _c_round1(s))
        s = inv[1] * d1
        d1 = box[1] * (s - _c_round1(s))
        s = inv[2] * d2
        d2 = box[2] * (s - _c_round1(s))
    elif rule == _TRICLINIC:
        # minimum_image_triclinic of calc_distances.h: the smallest squared length
        # of the 27 images, each summed in MDAnalysis's order; the cell is lower
        # triangular (triclinic_vectors), so rz2 and then (rz1, rz2) bound an
        # image's length from below, and images that cannot beat limit2 are skipped
        best = np.inf
        for iz in range(-1, 2):
            rz2 = d2 + tri[8] * iz
            z2 = rz2 * rz2
            if z2 > limit2:
                continue
            for iy in range(-1, 2):
                ry1 = d1 + tri[4] * iy
                rz1 = ry1 + tri[7] * iz
                if rz1 * rz1 + z2 > limit2:
                    continue
                for ix in range(-1, 2):
                    rx = d0 + tri[0] * ix
                    ry0 = rx + tri[3] * iy
                    rz0 = ry0 + tri[6] * iz
                    dsq = rz0 * rz0 + rz1 * rz1 + rz2 * rz2
                    if dsq < best:
                        best = dsq
        return best
    return (d0 * d0) + (d1 * d1) + (d2 * d2)


@pjit
def _decide_kernel(P, Q, a, b, rule, box, half, inv, tri, cutoff, cutoff2, by_square,
                   out_d, keep):
    """Distances and keep-mask of candidates ``(P[a[k]], Q[b[k]])``: ``d2 <= cutoff2``
    (nsgrid) or ``sqrt(d2) <= cutoff`` (bruteforce).  Distances are exact up to
    a relative 1e-3 beyond the cutoff, and some larger value (inf) further out."""
    k_all = a.shape[0]
    n_chunks = (k_all + _DECIDE_CHUNK - 1) // _DECIDE_CHUNK
    limit2 = max(cutoff2, cutoff * cutoff) * (1.0 + 2e-3)
    for ch in numba.prange(n_chunks):
        lo = ch * _DECIDE_CHUNK
        hi = min(k_all, lo + _DECIDE_CHUNK)
        for k in range(lo, hi):
            d2 = _decide_one(P, Q, a[k], b[k], rule, box, half, inv, tri, limit2)
            d = math.sqrt(d2)
            out_d[k] = d
            keep[k] = d2 <= cutoff2 if by_square else d <= cutoff


_decide_serial = serial_twin(_decide_kernel)


def decide(ref32, conf32, a, b, box32, max_cutoff, method):
    """Distances (float64) and a keep-mask for candidates ``(ref[a], conf[b])``
    under MDAnalysis method ``method``; ``None`` if the method is not emulated.

    The coordinates are prepared once per set (wrapped by ``apply_PBC``, or
    shifted into nsgrid's pseudo-box, in MDAnalysis's own dtypes), then one
    compiled pass per candidate reproduces MDAnalysis's arithmetic operation
    for operation (``_decide_one``).
    """
    if method not in ("bruteforce", "nsgrid"):
        return None
    same = conf32 is ref32
    zero3 = np.zeros(3)
    box = half = inv = zero3
    tri = np.zeros(9)
    rule = _PLAIN
    if box32 is None:
        if method == "nsgrid":
            # _nsgrid_capped(_self) shift the coordinates into a pseudo-box first
            if same:
                lmin = ref32.min(axis=0)
                boxsize = (ref32.max(axis=0) - lmin).max()
                shift = lmin - 0.1 * boxsize
            else:
                # max_cutoff as the caller gave it: a numpy float64 makes this shift
                # float64 (NEP 50), a Python float leaves it float32
                shift = np.concatenate([ref32, conf32]).min(axis=0) - 0.1 * max_cutoff
            # MDAnalysis subtracts in place from float32 copies (elementwise: the
            # same per coordinate as per candidate)
            ref32 = (ref32 - shift).astype(np.float32)
            conf32 = ref32 if same else (conf32 - shift).astype(np.float32)
    else:
        from MDAnalysis.lib.distances import apply_PBC

        kind, bx = _box_kind(box32)
        if method == "nsgrid" or kind == "tri":
            # wrapping is per coordinate: wrap each set once, then pick candidates
            ref32 = apply_PBC(ref32, box32).astype(np.float32)
            conf32 = ref32 if same else apply_PBC(conf32, box32).astype(np.float32)
        if kind == "tri":
            rule = _TRICLINIC
            tri = bx.astype(np.float64)
        elif method == "nsgrid":
            rule = _ORTHO_LAZY
            box = bx.astype(np.float64)
            half = (np.float32(0.5) * bx).astype(np.float64)
        else:
            rule = _ORTHO_ROUND
            box = bx.astype(np.float64)
            inv = (1.0 / bx.astype(np.float64)).astype(np.float32).astype(np.float64)
    P = np.ascontiguousarray(ref32, dtype=np.float32)
    Q = P if same else np.ascontiguousarray(conf32, dtype=np.float32)
    a = np.ascontiguousarray(a, dtype=np.int64)
    b = np.ascontiguousarray(b, dtype=np.int64)
    k = len(a)
    out_d = np.empty(k)
    keep = np.empty(k, np.bool_)
    by_square = method == "nsgrid"
    kernel = _decide_kernel if k >= 4 * _DECIDE_CHUNK else _decide_serial
    kernel(P, Q, a, b, rule, box, half, inv, tri, float(max_cutoff),
           _nsgrid_cutoff2(max_cutoff), by_square, out_d, keep)
    return out_d, keep


# ---------------------------------------------------------------------------
# every image within reach, reduced to one per pair


@jit
def _nearest_images(pairs, shift, d, n, m, drop_diagonal, out_a, out_b, out_d):
    """Rows of ``(pairs, d)`` that are the nearest image of their pair (the first
    such row), grouped by ``pairs[:, 0]`` with a counting sort; ``shift`` is
    subtracted from ``pairs[:, 1]``.  Returns how many (written to ``out_*``)."""
    k = pairs.shape[0]
    start = np.zeros(n + 1, np.int64)
    for r in range(k):
        start[pairs[r, 0] + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    order = np.empty(k, np.int64)
    fill = start[:-1].copy()
    for r in range(k):
        i = pairs[r, 0]
        order[fill[i]] = r
        fill[i] += 1
    best = np.full(m, -1, np.int64)
    count = 0
    for i in range(n):
        first = count
        for p in range(start[i], start[i + 1]):
            r = order[p]
            j = pairs[r, 1] - shift
            if drop_diagonal and j == i:
                continue
            q = best[j]
            if q < 0:
                best[j] = count
                out_a[count] = i
                out_b[count] = j
                out_d[count] = d[r]
                count += 1
            elif d[r] < out_d[q]:
                out_d[q] = d[r]
        for q in range(first, count):
            best[out_b[q]] = -1
    return count


@jit
def _first_images(pairs, shift, d, m, drop_diagonal, seen, out_a, out_b, out_d):
    """The first row of every pair, marked in a bitmap of all ``n * m`` pairs (a
    few megabytes at most: the caller checks); returns how many."""
    count = 0
    for r in range(pairs.shape[0]):
        i = pairs[r, 0]
        j = pairs[r, 1] - shift
        if drop_diagonal and j == i:
            continue
        idx = i * m + j
        byte = idx >> 3
        bit = np.uint8(1 << (idx & 7))
        if seen[byte] & bit:
            continue
        seen[byte] |= bit
        out_a[count] = i
        out_b[count] = j
        out_d[count] = d[r]
        count += 1
    return count


#: pairs ``n * m`` up to which a bitmap finds the first image of each pair
_BITMAP_PAIRS = 1 << 27


def nearest_images(pairs, d, n, m, *, shift=0, drop_diagonal=False, any_image=False):
    """One row per pair of an every-image list: the distance of its nearest image.

    Parameters
    ----------
    pairs : (k, 2) ndarray of int64
        ``pairs[:, 0]`` in ``[0, n)``, ``pairs[:, 1] - shift`` in ``[0, m)``; a
        pair appears once per image within range.
    d : (k,) ndarray of float64
        The image's distance.
    shift : int
        Subtracted from ``pairs[:, 1]`` (the second set's offset in a search
        over both sets).
    drop_diagonal : bool
        Leave out a particle with its own images.
    any_image : bool
        Any one image per pair will do (its distance is then that image's, not
        the nearest's): the caller decides pairs by their own arithmetic.

    Returns
    -------
    a, b, d : ndarray
        The order depends only on the input, never on threads.
    """
    k = len(pairs)
    out_a = np.empty(k, np.int64)
    out_b = np.empty(k, np.int64)
    out_d = np.empty(k, np.float64)
    pairs = np.ascontiguousarray(pairs, dtype=np.int64)
    d = np.ascontiguousarray(d, dtype=np.float64)
    if any_image and n * m <= _BITMAP_PAIRS:
        seen = np.zeros((n * m + 7) // 8, np.uint8)
        count = _first_images(pairs, int(shift), d, int(m), bool(drop_diagonal), seen, out_a,
                              out_b, out_d)
    else:
        count = _nearest_images(pairs, int(shift), d, int(n), int(m), bool(drop_diagonal),
                                out_a, out_b, out_d)
    return out_a[:count], out_b[:count], out_d[:count]


# ---------------------------------------------------------------------------
# brute-force minimum image for cutoffs beyond half the cell

#: pair tests below which the serial kernel runs (thread start-up dominates)
_PARALLEL_MIN = 1 << 16


@ijit
def _min_image_d2(fa, fb, i, j, cell, widths, ortho, reach):
    """Squared minimum-image distance of ``fa[i]`` and ``fb[j]`` (fractional
    coordinates), or -1.0 if it certainly exceeds ``reach``."""
    s0 = fb[j, 0] - fa[i, 0]
    s1 = fb[j, 1] - fa[i, 1]
    s2 = fb[j, 2] - fa[i, 2]
    s0 -= math.floor(s0 + 0.5)
    s1 -= math.floor(s1 + 0.5)
    s2 -= math.floor(s2 + 0.5)
    # |s_k| * w_k is the separation's extent across face k: a lower bound
    if abs(s0) * widths[0] > reach or abs(s1) * widths[1] > reach or (
            abs(s2) * widths[2] > reach):
        return -1.0
    x = s0 * cell[0, 0] + s1 * cell[1, 0] + s2 * cell[2, 0]
    y = s0 * cell[0, 1] + s1 * cell[1, 1] + s2 * cell[2, 1]
    z = s0 * cell[0, 2] + s1 * cell[1, 2] + s2 * cell[2, 2]
    d2 = x * x + y * y + z * z
    if ortho:
        return d2
    r = math.sqrt(d2)
    m0 = int(r / widths[0] + 0.5)
    m1 = int(r / widths[1] + 0.5)
    m2 = int(r / widths[2] + 0.5)
    for n0 in range(-m0, m0 + 1):
        t0 = s0 + n0
        for n1 in range(-m1, m1 + 1):
            t1 = s1 + n1
            for n2 in range(-m2, m2 + 1):
                if n0 == 0 and n1 == 0 and n2 == 0:
                    continue
                t2 = s2 + n2
                x = t0 * cell[0, 0] + t1 * cell[1, 0] + t2 * cell[2, 0]
                y = t0 * cell[0, 1] + t1 * cell[1, 1] + t2 * cell[2, 1]
                z = t0 * cell[0, 2] + t1 * cell[1, 2] + t2 * cell[2, 2]
                e2 = x * x + y * y + z * z
                if e2 < d2:
                    d2 = e2
    return d2


@jit
def _min_image_rows(r_lo, r_hi, fa, fb, same, cell, widths, ortho, reach, write, o,
                    out_a, out_b, out_d):
    """Pairs ``(i, j)`` with ``r_lo <= i < r_hi`` (``j > i`` if ``same``) whose
    minimum-image distance is ``<= reach``; written from ``o`` if ``write``.
    Returns how many."""
    reach2 = reach * reach
    count = 0
    m = fb.shape[0]
    for i in range(r_lo, r_hi):
        j0 = i + 1 if same else 0
        for j in range(j0, m):
            d2 = _min_image_d2(fa, fb, i, j, cell, widths, ortho, reach)
            if d2 >= 0.0 and d2 <= reach2:
                if write:
                    out_a[o + count] = i
                    out_b[o + count] = j
                    out_d[o + count] = math.sqrt(d2)
                count += 1
    return count


@pjit
def _min_image_parallel(bounds, fa, fb, same, cell, widths, ortho, reach, write, offsets,
                        counts, out_a, out_b, out_d):
    """``_min_image_rows`` over the row chunks ``bounds[c]:bounds[c + 1]``."""
    for c in numba.prange(bounds.shape[0] - 1):
        counts[c] = _min_image_rows(bounds[c], bounds[c + 1], fa, fb, same, cell, widths,
                                    ortho, reach, write, offsets[c], out_a, out_b, out_d)


def _row_chunks(n, m, same, n_threads):
    """Chunk boundaries over ``n`` rows with about equal pair tests each."""
    chunks = int(min(8 * n_threads, max(1, n)))
    work = np.full(n, m, dtype=np.float64)
    if same:
        work -= np.arange(1, n + 1)
    cum = np.concatenate([[0.0], np.cumsum(work)])
    targets = np.linspace(0.0, cum[-1], chunks + 1)
    bounds = np.searchsorted(cum, targets, side="left").astype(np.int64)
    bounds[0], bounds[-1] = 0, n
    return np.unique(bounds)


def min_image_pairs(ref, conf, cell, reach, n_threads):
    """Every pair within ``reach`` (minimum image), testing all pairs.

    Parameters
    ----------
    ref : (n, 3) ndarray of float64
    conf : (m, 3) ndarray of float64 or None
        None: pairs ``i < j`` within ``ref``.
    cell : (3, 3) ndarray of float64
        Rows are the cell vectors (all three axes periodic).
    reach : float
        Inclusive; ``d <= reach`` up to the rounding of ``reach**2``.
    n_threads : int
        Threads in use (from ``_numba.num_threads``).

    Returns
    -------
    a, b : (k,) ndarray of int64
        Indices into ``ref`` and ``conf`` (``a < b`` if ``conf`` is None).
    d : (k,) ndarray of float64
        Minimum-image distances.
    """
    from .. import periodic

    same = conf is None
    cell = np.ascontiguousarray(cell, dtype=np.float64)
    inv = np.linalg.inv(cell)
    fa = ref @ inv
    fa -= np.floor(fa)
    fb = fa if same else conf @ inv
    if not same:
        fb -= np.floor(fb)
    fa = np.ascontiguousarray(fa)
    fb = np.ascontiguousarray(fb)
    widths = np.ascontiguousarray(periodic.perpendicular_widths(cell), dtype=np.float64)
    ortho = bool(np.all(cell == np.diag(np.diag(cell))))
    n, m = len(fa), len(fb)
    tests = n * (n - 1) // 2 if same else n * m
    reach = float(reach)
    empty_i = np.empty(0, np.int64)
    empty_d = np.empty(0, np.float64)
    if tests < _PARALLEL_MIN or n_threads <= 1:
        k = _min_image_rows(0, n, fa, fb, same, cell, widths, ortho, reach, False, 0,
                            empty_i, empty_i, empty_d)
        a = np.empty(k, np.int64)
        b = np.empty(k, np.int64)
        d = np.empty(k, np.float64)
        if k:
            _min_image_rows(0, n, fa, fb, same, cell, widths, ortho, reach, True, 0, a, b, d)
        return a, b, d
    bounds = _row_chunks(n, m, same, n_threads)
    counts = np.zeros(len(bounds) - 1, dtype=np.int64)
    zero = np.zeros(len(bounds) - 1, dtype=np.int64)
    _min_image_parallel(bounds, fa, fb, same, cell, widths, ortho, reach, False, zero, counts,
                        empty_i, empty_i, empty_d)
    offsets = np.zeros(len(counts), dtype=np.int64)
    np.cumsum(counts[:-1], out=offsets[1:])
    k = int(counts.sum())
    a = np.empty(k, np.int64)
    b = np.empty(k, np.int64)
    d = np.empty(k, np.float64)
    if k:
        _min_image_parallel(bounds, fa, fb, same, cell, widths, ortho, reach, True, offsets,
                            counts, a, b, d)
    return a, b, d
