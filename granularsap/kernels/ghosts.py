"""Ghost images and the Verlet layout for the box sweep of particles.

The particle engine's candidate list can be built by the column sweep
(``grid.py``) or by the paper's bi-dimensional Sweep and Prune over bounding
cubes.  The second needs two things this module provides:

*Ghosts.*  Along a periodic axis the sweep sees the images of the particles
near the faces as extra boxes.  Only images with a lattice shift ``S`` that is
lexicographically positive (first non-zero component > 0) are made: the image
``(p, q, S)`` is then found as the box of particle ``p`` against the ghost
``q + S`` when ``S > 0``, and as ``q`` against the ghost ``p - S`` when
``S < 0``; the zero shift is a pair of real boxes.  So every image is found
exactly once, and nothing is de-duplicated afterwards (pairs of two ghosts are
dropped: the same image is a real-ghost pair).

*Which ghosts.*  Boxes of half-widths ``h_p`` and ``h_q`` overlap only when
every Cartesian component of the separation is at most ``h_p + h_q``; the
fractional separation along axis ``c`` is then at most
``(h_p + h_q) * sum_k |Hinv[k, c]|`` (the L1 norm of column ``c`` of the
inverse cell matrix; ``1 / L_c`` in an orthorhombic cell, up to ``sqrt(3) /
w_c`` in a triclinic one).  A ghost of ``q`` with shift ``S`` is made when
``t_q + S`` is within that reach (with ``max(h)`` for ``h_p``) of the span of
the real particles' fractional coordinates on every periodic axis.  The range
of ``S_c`` is an integer interval per axis (``ceil`` / ``floor``), so several
layers of images appear by themselves when the reach exceeds the cell.

*Verlet layout.*  Entries are grouped by row ``p`` (``vstart[p]`` to
``vstop[p]``): partner ``vb`` (int32) and shift ``vs`` packed like
``grid.py``'s codes, three biased 10-bit fields.  Inside a row, entries are
sorted by (partner, code) so the layout does not depend on the sweep's pair
order (or on the thread count).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .._numba import ijit, pjit
from .common import OFF, ZERO, encode

#: largest |S_c| a code holds (a field is 10 bits, biased by 512; one is left
#: so that a negated shift is still a code)
MAX_SHIFT = OFF - 1


@ijit
def _image_range(t, q, c, pbc, lo, hi, reach, l1, slack):
    """Shifts ``[a, b]`` along axis ``c`` that bring ``t[q, c]`` within the reach
    of the real span ``[lo[c], hi[c]]`` (``0, 0`` on an open axis)."""
    if not pbc[c]:
        return 0, 0
    hc = reach * l1[c] * (1.0 + 1e-9) + slack[c]
    a = math.ceil(lo[c] - hc - t[q, c])
    b = math.floor(hi[c] + hc - t[q, c])
    return np.int64(a), np.int64(b)


@ijit
def _positives(a, b):
    """Integers above zero in ``[a, b]``."""
    return max(np.int64(0), b - max(a, np.int64(1)) + 1)


@pjit
def count_ghosts(t, half, extra, pbc, lo, hi, l1, slack, counts):
    """Ghosts of every particle: lexicographically positive shifts in its ranges."""
    n = t.shape[0]
    for q in numba.prange(n):
        r = half[q] + extra
        a0, b0 = _image_range(t, q, 0, pbc, lo, hi, r, l1, slack)
        a1, b1 = _image_range(t, q, 1, pbc, lo, hi, r, l1, slack)
        a2, b2 = _image_range(t, q, 2, pbc, lo, hi, r, l1, slack)
        n0 = max(np.int64(0), b0 - a0 + 1)
        n1 = max(np.int64(0), b1 - a1 + 1)
        n2 = max(np.int64(0), b2 - a2 + 1)
        cnt = _positives(a0, b0) * n1 * n2
        if a0 <= 0 <= b0:
            cnt += _positives(a1, b1) * n2
            if a1 <= 0 <= b1:
                cnt += _positives(a2, b2)
        counts[q] = cnt if n0 > 0 else 0


@pjit
def fill_ghosts(ws, t, half, extra, pbc, lo, hi, l1, slack, cell, offsets, owner, code,
                gpos):
    """Owner, shift code and Cartesian position of every ghost (from ``offsets[q]``).

    The position is ``ws[q] + s0 cell[0] + s1 cell[1] + s2 cell[2]``, summed in
    that order (the order of ``grid.py``'s separation)."""
    n = t.shape[0]
    for q in numba.prange(n):
        r = half[q] + extra
        a0, b0 = _image_range(t, q, 0, pbc, lo, hi, r, l1, slack)
        a1, b1 = _image_range(t, q, 1, pbc, lo, hi, r, l1, slack)
        a2, b2 = _image_range(t, q, 2, pbc, lo, hi, r, l1, slack)
        o = offsets[q]
        for s0 in range(max(a0, np.int64(0)), b0 + 1):
            for s1 in range(a1 if s0 > 0 else max(a1, np.int64(0)), b1 + 1):
                first2 = a2 if (s0 > 0 or s1 > 0) else max(a2, np.int64(1))
                for s2 in range(first2, b2 + 1):
                    x = ws[q, 0]
                    y = ws[q, 1]
                    z = ws[q, 2]
                    x += s0 * cell[0, 0]
                    y += s0 * cell[0, 1]
                    z += s0 * cell[0, 2]
                    x += s1 * cell[1, 0]
                    y += s1 * cell[1, 1]
                    z += s1 * cell[1, 2]
                    x += s2 * cell[2, 0]
                    y += s2 * cell[2, 1]
                    z += s2 * cell[2, 2]
                    gpos[o, 0] = x
                    gpos[o, 1] = y
                    gpos[o, 2] = z
                    owner[o] = q
                    code[o] = encode(s0, s1, s2)
                    o += 1


@pjit
def boxes(ws, half, gpos, owner, guard, lower, upper):
    """Real boxes (rows ``0..n-1``) then ghost boxes, each widened by ``guard``."""
    n = ws.shape[0]
    g = gpos.shape[0]
    for i in numba.prange(n + g):
        if i < n:
            h = half[i] + guard
            for c in range(3):
                lower[i, c] = ws[i, c] - h
                upper[i, c] = ws[i, c] + h
        else:
            k = i - n
            h = half[owner[k]] + guard
            for c in range(3):
                lower[i, c] = gpos[k, c] - h
                upper[i, c] = gpos[k, c] + h


@ijit
def _image(pairs, t, n, owner, gcode, self_images, spheres, ws, gpos, half, guard2, labels,
           use_labels):
    """Row, partner and code of box pair ``t`` (row -1: not reported).

    With ``spheres``, only pairs whose spheres of radius ``half`` (plus the
    guard ``guard2``, twice the cube guard) touch are reported; with
    ``use_labels``, only pairs of different ``labels``."""
    i = pairs[t, 0]
    j = pairs[t, 1]
    if i >= n:  # two ghosts: the same image is a real-ghost pair
        return np.int64(-1), np.int64(0), np.int64(0)
    if j < n:  # two real boxes (i < j)
        q = j
        c = np.int64(ZERO)
        dx = ws[j, 0] - ws[i, 0]
        dy = ws[j, 1] - ws[i, 1]
        dz = ws[j, 2] - ws[i, 2]
    else:
        k = j - n
        q = owner[k]
        if q == i and not self_images:
            return np.int64(-1), np.int64(0), np.int64(0)
        c = np.int64(gcode[k])
        dx = gpos[k, 0] - ws[i, 0]
        dy = gpos[k, 1] - ws[i, 1]
        dz = gpos[k, 2] - ws[i, 2]
    if use_labels and labels[i] == labels[q]:
        return np.int64(-1), np.int64(0), np.int64(0)
    if spheres:
        thr = half[i] + half[q] + guard2
        if not dx * dx + dy * dy + dz * dz <= thr * thr * (1.0 + 1e-12):
            return np.int64(-1), np.int64(0), np.int64(0)
    return i, q, c


@ijit
def _chunk(k, n_chunks, ch):
    return ch * k // n_chunks, (ch + 1) * k // n_chunks


@pjit
def image_counts(pairs, n, owner, gcode, self_images, spheres, ws, gpos, half, guard2, labels,
                 use_labels, cnt, by_partner):
    """``cnt[ch, x]``: images among chunk ``ch`` of the box pairs with row
    ``x`` (or, with ``by_partner``, partner ``x``)."""
    n_chunks = cnt.shape[0]
    k = pairs.shape[0]
    for ch in numba.prange(n_chunks):
        for x in range(n):
            cnt[ch, x] = 0
        lo, hi = _chunk(k, n_chunks, ch)
        for t in range(lo, hi):
            p, q, c = _image(pairs, t, n, owner, gcode, self_images, spheres, ws, gpos, half,
                             guard2, labels, use_labels)
            if p >= 0:
                cnt[ch, q if by_partner else p] += 1


@pjit
def offsets(cnt, start, stop):
    """CSR rows from the chunk counts (``stop[x] == start[x + 1]``); turns
    ``cnt[ch, x]`` into chunk ``ch``'s first slot in row ``x``.  Returns the
    entry count."""
    n_chunks, n = cnt.shape
    for x in numba.prange(n):
        m = np.int64(0)
        for ch in range(n_chunks):
            m += cnt[ch, x]
        stop[x] = m
    total = np.int64(0)
    for x in range(n):
        m = stop[x]
        start[x] = total
        total += m
        stop[x] = total
    for x in numba.prange(n):
        o = start[x]
        for ch in range(n_chunks):
            m = cnt[ch, x]
            cnt[ch, x] = o
            o += m
    return total


@pjit
def scatter_by_partner(pairs, n, owner, gcode, self_images, spheres, ws, gpos, half, guard2,
                       labels, use_labels, cnt, key):
    """Every image into the bucket of its partner ``q``, as ``p << 32 | code``."""
    n_chunks = cnt.shape[0]
    k = pairs.shape[0]
    for ch in numba.prange(n_chunks):
        lo, hi = _chunk(k, n_chunks, ch)
        for t in range(lo, hi):
            p, q, c = _image(pairs, t, n, owner, gcode, self_images, spheres, ws, gpos, half,
                             guard2, labels, use_labels)
            if p >= 0:
                e = cnt[ch, q]
                key[e] = (p << 32) | c
                cnt[ch, q] = e + 1


@ijit
def _partner_chunk(n, n_chunks, ch):
    return ch * n // n_chunks, (ch + 1) * n // n_chunks


@pjit
def row_counts(qstart, qstop, key, cnt):
    """``cnt[ch, p]``: entries of row ``p`` whose partner lies in chunk ``ch`` of
    the partners (chunks of consecutive partners, in order)."""
    n_chunks, n = cnt.shape
    for ch in numba.prange(n_chunks):
        for p in range(n):
            cnt[ch, p] = 0
        lo, hi = _partner_chunk(n, n_chunks, ch)
        if hi > lo:
            for e in range(qstart[lo], qstop[hi - 1]):
                cnt[ch, key[e] >> 32] += 1


@pjit
def scatter_rows(qstart, qstop, key, cnt, vb, vs):
    """Rows from the partner buckets, walked in increasing partner order: every
    row comes out sorted by partner."""
    n_chunks, n = cnt.shape
    for ch in numba.prange(n_chunks):
        lo, hi = _partner_chunk(n, n_chunks, ch)
        for q in range(lo, hi):
            for e in range(qstart[q], qstop[q]):
                v = key[e]
                p = v >> 32
                o = cnt[ch, p]
                vb[o] = np.int32(q)
                vs[o] = np.int32(v & 0xFFFFFFFF)
                cnt[ch, p] = o + 1


@pjit
def sort_ties(vstart, vstop, vb, vs):
    """Rows sorted by partner: order the codes of equal partners (insertion sort,
    linear on such rows)."""
    n = vstart.shape[0]
    for p in numba.prange(n):
        lo = vstart[p]
        hi = vstop[p]
        for e in range(lo + 1, hi):
            b = vb[e]
            s = vs[e]
            f = e - 1
            while f >= lo and (vb[f] > b or (vb[f] == b and vs[f] > s)):
                vb[f + 1] = vb[f]
                vs[f + 1] = vs[f]
                f -= 1
            vb[f + 1] = b
            vs[f + 1] = s
