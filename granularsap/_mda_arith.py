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

These are ports of MDAnalysis's ``calc_distances.h`` and ``nsgrid.pyx``
written with numpy; they need MDAnalysis only for ``apply_PBC`` and
``triclinic_vectors``.

Cutoffs beyond half the cell
----------------------------
MDAnalysis's answer for any cutoff is one minimum image per pair.  When the
cutoff exceeds half the smallest perpendicular cell width, a cell-list or
sweep search would have to enumerate several images of every particle, so
:func:`min_image_pairs` tests every pair directly instead (a brute-force
kernel): fractional separation reduced to ``[-0.5, 0.5)``, a pair skipped at
once if one fractional component times its perpendicular width already exceeds
the reach (a lower bound on every image's distance), otherwise the true
nearest image (triclinic cells: the images ``n`` with
``|n_k| <= |r| / w_k + 1/2`` around the reduced separation ``r``).  Cost
O(n m) distance evaluations in two passes (count, then fill at prefix-sum
offsets) over chunks of rows balanced by work, so memory is the output and no
more; the output order does not depend on the thread count.  Beyond half the
width a large share of all pairs is in range anyway (about half of them in a
cube), so the brute force is within a small factor of writing the output.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ._numba import ijit, jit, pjit

#: Relative widening of the candidate search (float32 rounding is ~6e-8).
WIDEN = 1e-5


def _c_round(s):
    """C ``round``: halves away from zero (numpy rounds halves to even)."""
    r = np.trunc(s)
    frac = s - r
    return r + np.where(np.abs(frac) >= 0.5, np.sign(s), 0.0)


def _tri_min_image(dx, box9):
    """``minimum_image_triclinic`` of calc_distances.h, vectorised (double)."""
    b = box9.astype(np.float64)
    best = np.full(len(dx), np.finfo(np.float32).max, dtype=np.float64)
    out = np.zeros_like(dx)
    for ix in (-1, 0, 1):
        rx = dx[:, 0] + b[0] * ix
        for iy in (-1, 0, 1):
            ry0 = rx + b[3] * iy
            ry1 = dx[:, 1] + b[4] * iy
            for iz in (-1, 0, 1):
                rz0 = ry0 + b[6] * iz
                rz1 = ry1 + b[7] * iz
                rz2 = dx[:, 2] + b[8] * iz
                dsq = rz0 * rz0 + rz1 * rz1 + rz2 * rz2
                take = dsq < best
                best = np.where(take, dsq, best)
                out[take, 0] = rz0[take]
                out[take, 1] = rz1[take]
                out[take, 2] = rz2[take]
    return out


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


def decide(ref32, conf32, a, b, box32, max_cutoff, method):
    """Distances (float64) and a keep-mask for candidates ``(ref[a], conf[b])``
    under MDAnalysis method ``method``; ``None`` if the method is not emulated."""
    if method not in ("bruteforce", "nsgrid"):
        return None
    if box32 is None:
        p = ref32[a]
        q = conf32[b]
        if method == "nsgrid":
            # _nsgrid_capped(_self) shift the coordinates into a pseudo-box first
            if conf32 is ref32:
                lmin = ref32.min(axis=0)
                boxsize = (ref32.max(axis=0) - lmin).max()
                shift = lmin - 0.1 * boxsize
            else:
                # max_cutoff as the caller gave it: a numpy float64 makes this shift
                # float64 (NEP 50), a Python float leaves it float32
                shift = np.concatenate([ref32, conf32]).min(axis=0) - 0.1 * max_cutoff
            # MDAnalysis subtracts in place from float32 copies
            p = (p - shift).astype(np.float32)
            q = (q - shift).astype(np.float32)
        dx = (q - p).astype(np.float64)
        d2 = (dx[:, 0] * dx[:, 0]) + (dx[:, 1] * dx[:, 1]) + (dx[:, 2] * dx[:, 2])
        if method == "nsgrid":
            return np.sqrt(d2), d2 <= _nsgrid_cutoff2(max_cutoff)
        d = np.sqrt(d2)
        return d, d <= max_cutoff
    from MDAnalysis.lib.distances import apply_PBC

    kind, bx = _box_kind(box32)
    if method == "nsgrid" or kind == "tri":
        # wrapping is per coordinate: wrap each set once, then pick candidates
        same = conf32 is ref32
        ref32 = apply_PBC(ref32, box32).astype(np.float32)
        conf32 = ref32 if same else apply_PBC(conf32, box32).astype(np.float32)
    p = ref32[a]
    q = conf32[b]
    dx = (q - p).astype(np.float64)
    if kind == "tri":
        dx = _tri_min_image(dx, bx)
    elif method == "nsgrid":
        half = (np.float32(0.5) * bx).astype(np.float64)
        box64 = bx.astype(np.float64)
        dx = np.where(dx > half, dx - box64, np.where(dx <= -half, dx + box64, dx))
    else:
        inv = (1.0 / bx.astype(np.float64)).astype(np.float32).astype(np.float64)
        s = inv * dx
        dx = bx.astype(np.float64) * (s - _c_round(s))
    d2 = (dx[:, 0] * dx[:, 0]) + (dx[:, 1] * dx[:, 1]) + (dx[:, 2] * dx[:, 2])
    if method == "nsgrid":
        return np.sqrt(d2), d2 <= _nsgrid_cutoff2(max_cutoff)
    d = np.sqrt(d2)
    return d, d <= max_cutoff


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
    from . import periodic

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
