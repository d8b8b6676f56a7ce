"""Narrow phase: exact distance tests on the broad phase's candidate pairs.

The broad phase (``box_overlaps``) runs on the boxes of the ``n_own`` owned
particles followed by their ghost images (periodic cells).  A candidate is a
pair of box indices ``p < q``:

* ``q < n_own``: two owned particles, kept as ``(p, q)``.
* ``p < n_own <= q``: owned ``a = p`` against the image of ``b = owner[q]``
  shifted by the lattice vector ``T``.  The same unordered image pair is also
  seen from ``b``'s side as ``(b, image of a shifted by -T)``; it is kept only
  where ``a < b`` (and, for a particle against its own image, only for the
  lexicographically positive ``T``), so each image pair is kept once.
* both ghosts: dropped (every such pair is found again from an owned side).

The distance vector is ``(pos[b] - pos[a]) + S0 a + S1 b + S2 c`` with
``S = T - nshift[b] + nshift[a]`` (just ``T`` if ``nshift`` is empty) added one
cell vector at a time (the order
MDAnalysis's triclinic minimum image uses), squared norm summed x, y, z, then
one ``sqrt``; a pair is kept iff ``d <= rad[a] + rad[b] + skin`` (or ``<`` for
ASE semantics).  Cost O(k) for k candidates in two passes over contiguous
chunks: pass 1 flags, counts and stores the distance per candidate (the only
pass that reads positions, in candidate order), pass 2 writes each chunk's kept
pairs from its prefix-sum offset, so no two threads write the same slot and the
output order does not depend on the thread count.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .._numba import ijit, jit, pjit

#: candidates below which the serial kernels run (thread start-up dominates)
PARALLEL_MIN = 16384


@jit
def _flag_range(t_lo, t_hi, cand, n_own, owner, gshift, pos, nshift, cell, rad, skin,
                strict, self_images, split, keep, dist):
    """Pass 1: ``keep[t]`` (and ``dist[t]`` if kept) for ``t_lo <= t < t_hi``; returns how many.

    ``split > 0`` keeps only pairs across the split (``a < split <= b``): the
    two point sets of ``capped_distance``.
    """
    count = 0
    use_nshift = nshift.shape[0] > 0
    for t in range(t_lo, t_hi):
        keep[t] = False
        # resolution and separation written out: as function calls they made this
        # loop several times slower
        p = cand[t, 0]
        q = cand[t, 1]
        if p > q:
            p, q = q, p
        if p >= n_own:
            continue
        a = p
        b = q
        s0 = 0
        s1 = 0
        s2 = 0
        if q >= n_own:
            g = q - n_own
            b = owner[g]
            if a > b:
                continue
            s0 = gshift[g, 0]
            s1 = gshift[g, 1]
            s2 = gshift[g, 2]
            if a == b:
                if not self_images:
                    continue
                if not (s0 > 0 or (s0 == 0 and (s1 > 0 or (s1 == 0 and s2 > 0)))):
                    continue
        if split > 0 and (a < split) == (b < split):
            continue
        if use_nshift:
            s0 = s0 - nshift[b, 0] + nshift[a, 0]
            s1 = s1 - nshift[b, 1] + nshift[a, 1]
            s2 = s2 - nshift[b, 2] + nshift[a, 2]
        dx = pos[b, 0] - pos[a, 0]
        dy = pos[b, 1] - pos[a, 1]
        dz = pos[b, 2] - pos[a, 2]
        if s0 != 0 or s1 != 0 or s2 != 0:
            dx += s0 * cell[0, 0]
            dy += s0 * cell[0, 1]
            dz += s0 * cell[0, 2]
            dx += s1 * cell[1, 0]
            dy += s1 * cell[1, 1]
            dz += s1 * cell[1, 2]
            dx += s2 * cell[2, 0]
            dy += s2 * cell[2, 1]
            dz += s2 * cell[2, 2]
        d = math.sqrt(dx * dx + dy * dy + dz * dz)
        thr = rad[a] + rad[b] + skin
        if d < thr or (d == thr and not strict):
            keep[t] = True
            dist[t] = d
            count += 1
    return count


@jit
def _fill_range(t_lo, t_hi, o, cand, n_own, owner, gshift, nshift, keep, dist,
                want_shift, out_a, out_b, out_s, out_d):
    """Pass 2: write the kept candidates of ``[t_lo, t_hi)`` from output row ``o`` on.

    Reads the candidates and distances in order; positions are not touched again.
    """
    use_nshift = nshift.shape[0] > 0
    for t in range(t_lo, t_hi):
        if not keep[t]:
            continue
        p = cand[t, 0]
        q = cand[t, 1]
        if p > q:
            p, q = q, p
        a = p
        b = q
        s0 = 0
        s1 = 0
        s2 = 0
        if q >= n_own:
            g = q - n_own
            b = owner[g]
            s0 = gshift[g, 0]
            s1 = gshift[g, 1]
            s2 = gshift[g, 2]
        out_a[o] = a
        out_b[o] = b
        out_d[o] = dist[t]
        if want_shift:
            if use_nshift:
                s0 = s0 - nshift[b, 0] + nshift[a, 0]
                s1 = s1 - nshift[b, 1] + nshift[a, 1]
                s2 = s2 - nshift[b, 2] + nshift[a, 2]
            out_s[o, 0] = s0
            out_s[o, 1] = s1
            out_s[o, 2] = s2
        o += 1


@pjit
def _flag_parallel(n_chunks, cand, n_own, owner, gshift, pos, nshift, cell, rad, skin,
                   strict, self_images, split, keep, dist, counts):
    """``_flag_range`` over ``n_chunks`` contiguous chunks; ``counts[c]`` per chunk."""
    k = cand.shape[0]
    for c in numba.prange(n_chunks):
        counts[c] = _flag_range(c * k // n_chunks, (c + 1) * k // n_chunks, cand, n_own,
                                owner, gshift, pos, nshift, cell, rad, skin, strict,
                                self_images, split, keep, dist)


@pjit
def _fill_parallel(n_chunks, offsets, cand, n_own, owner, gshift, nshift, keep, dist,
                   want_shift, out_a, out_b, out_s, out_d):
    """``_fill_range`` per chunk, chunk ``c`` writing from ``offsets[c]``."""
    k = cand.shape[0]
    for c in numba.prange(n_chunks):
        _fill_range(c * k // n_chunks, (c + 1) * k // n_chunks, offsets[c], cand, n_own,
                    owner, gshift, nshift, keep, dist, want_shift, out_a, out_b, out_s, out_d)


@ijit
def _clump_distance(u, i, j, cell, shifted, t0, t1, t2):
    """Distance from sphere ``i`` to sphere ``j`` shifted by cell image ``t``."""
    dx = u[j, 0] - u[i, 0]
    dy = u[j, 1] - u[i, 1]
    dz = u[j, 2] - u[i, 2]
    if shifted:
        dx += t0 * cell[0, 0] + t1 * cell[1, 0] + t2 * cell[2, 0]
        dy += t0 * cell[0, 1] + t1 * cell[1, 1] + t2 * cell[2, 1]
        dz += t0 * cell[0, 2] + t1 * cell[1, 2] + t2 * cell[2, 2]
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@jit
def _clump_count_range(t_lo, t_hi, ca, cb, ct, start, members, u, cell, radii, skin, counts):
    """Number of sphere contacts for each candidate clump pair (image ``ct``)."""
    for t in range(t_lo, t_hi):
        a = ca[t]
        b = cb[t]
        t0 = ct[t, 0]
        t1 = ct[t, 1]
        t2 = ct[t, 2]
        shifted = t0 != 0 or t1 != 0 or t2 != 0
        c = 0
        for x in range(start[a], start[a + 1]):
            i = members[x]
            for y in range(start[b], start[b + 1]):
                j = members[y]
                d = _clump_distance(u, i, j, cell, shifted, t0, t1, t2)
                if d <= radii[i] + radii[j] + skin:
                    c += 1
        counts[t] = c


@jit
def _clump_fill_range(t_lo, t_hi, ca, cb, ct, start, members, u, cell, radii, skin, offsets,
                      out_pairs, out_dist):
    """Write the sphere contacts counted by ``_clump_count_range`` at ``offsets``."""
    for t in range(t_lo, t_hi):
        a = ca[t]
        b = cb[t]
        t0 = ct[t, 0]
        t1 = ct[t, 1]
        t2 = ct[t, 2]
        shifted = t0 != 0 or t1 != 0 or t2 != 0
        o = offsets[t]
        for x in range(start[a], start[a + 1]):
            i = members[x]
            for y in range(start[b], start[b + 1]):
                j = members[y]
                d = _clump_distance(u, i, j, cell, shifted, t0, t1, t2)
                if d <= radii[i] + radii[j] + skin:
                    if i < j:
                        out_pairs[o, 0] = i
                        out_pairs[o, 1] = j
                    else:
                        out_pairs[o, 0] = j
                        out_pairs[o, 1] = i
                    out_dist[o] = d
                    o += 1


@pjit
def _clump_count_parallel(n_chunks, ca, cb, ct, start, members, u, cell, radii, skin, counts):
    k = ca.shape[0]
    for c in numba.prange(n_chunks):
        _clump_count_range(c * k // n_chunks, (c + 1) * k // n_chunks, ca, cb, ct, start,
                           members, u, cell, radii, skin, counts)


@pjit
def _clump_fill_parallel(n_chunks, ca, cb, ct, start, members, u, cell, radii, skin, offsets,
                         out_pairs, out_dist):
    k = ca.shape[0]
    for c in numba.prange(n_chunks):
        _clump_fill_range(c * k // n_chunks, (c + 1) * k // n_chunks, ca, cb, ct, start,
                          members, u, cell, radii, skin, offsets, out_pairs, out_dist)


def _chunks(k, n_threads):
    """Number of parallel chunks, or 0 for the serial kernel."""
    if k < PARALLEL_MIN or n_threads <= 1:
        return 0
    return int(min(8 * n_threads, max(1, k // 4096)))


def narrow_candidates(cand, n_own, owner, gshift, pos, nshift, cell, rad, skin,
                      strict=False, self_images=False, want_shift=False, split=0,
                      n_threads=1):
    """Exact test of every candidate; returns ``(a, b, shift, dist)`` of the kept ones.

    ``a <= b`` are owned indices, ``shift`` the ``(m, 3)`` lattice shifts (``None``
    unless ``want_shift``) and ``dist`` the float64 distances.  Two passes: flag,
    count and store the distance per candidate (9 bytes per candidate), then
    write each chunk's kept pairs at its prefix-sum offset.
    """
    k = len(cand)
    keep = np.empty(k, dtype=np.bool_)
    dist = np.empty(k, dtype=np.float64)
    chunks = _chunks(k, n_threads)
    flag_args = (cand, np.int64(n_own), owner, gshift, pos, nshift, cell, rad, float(skin),
                 bool(strict), bool(self_images), np.int64(split), keep, dist)
    if chunks:
        counts = np.zeros(chunks, dtype=np.int64)
        _flag_parallel(chunks, *flag_args, counts)
    else:
        chunks = 1
        counts = np.array([_flag_range(0, k, *flag_args) if k else 0], dtype=np.int64)
    offsets = np.zeros(chunks + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    m = int(offsets[-1])
    out_a = np.empty(m, dtype=np.int64)
    out_b = np.empty(m, dtype=np.int64)
    out_s = np.empty((m if want_shift else 0, 3), dtype=np.int64)
    out_d = np.empty(m, dtype=np.float64)
    fill_args = (cand, np.int64(n_own), owner, gshift, nshift, keep, dist, bool(want_shift),
                 out_a, out_b, out_s, out_d)
    if m:
        if chunks > 1:
            _fill_parallel(chunks, offsets, *fill_args)
        else:
            _fill_range(0, k, 0, *fill_args)
    return out_a, out_b, (out_s if want_shift else None), out_d


def clump_pairs(ca, cb, ct, start, members, u, cell, radii, skin, n_threads=1):
    """Sphere contacts of candidate clump pairs; returns ``(counts, pairs, distances)``."""
    k = len(ca)
    counts = np.zeros(k, dtype=np.int64)
    args = (ca, cb, ct, start, members, u, cell, radii, float(skin))
    chunks = _chunks(k, n_threads)
    if chunks:
        _clump_count_parallel(chunks, *args, counts)
    elif k:
        _clump_count_range(0, k, *args, counts)
    offsets = np.zeros(k + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    total = int(offsets[-1])
    pairs = np.empty((total, 2), dtype=np.int64)
    dist = np.empty(total, dtype=np.float64)
    if total:
        if chunks:
            _clump_fill_parallel(chunks, *args, offsets, pairs, dist)
        else:
            _clump_fill_range(0, k, *args, offsets, pairs, dist)
    return counts, pairs, dist
