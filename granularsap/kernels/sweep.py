"""The bi-dimensional sweeps: Algorithm 1 (sequential), 3 (parallel candidate
generation) and 4 (parallel pairing) of Capannini & Larsson.

Objects are ranked by the order of their low endpoints on the primary axis
(``R[i]``, and its inverse ``Rinv``).  The first sweep, over the primary axis,
gives every object a candidate range of ranks ``[L[i], U[i])``: ``L[i]`` is the
oldest rank still active when ``i`` starts (``S.min()``) and ``U[i]`` the
number of objects started when ``i`` ends.  Any object overlapping ``i`` on
the primary axis has its rank in that range.  The second sweep, over the
secondary axis, keeps the active set ``S`` of ranks; when ``i`` starts, every
rank in ``S`` within ``[L[i], U[i])`` overlaps ``i`` on both sweep axes except
for primary-axis false positives, and one exact test of the primary and the
third axis (``OverlapTest``) decides.  Each pair is found once, by the object
that starts later on the secondary axis.

Closed boxes: the sort puts low endpoints before high endpoints at equal
coordinates, so boxes that only touch are active together and reported.

Boxes are copied in rank order (``br``: primary low/high, third low/high), so
the tests of one range query read consecutive memory.

Costs: each sweep is O(n log_64 n); pairing is O(sum of range-query sizes),
the number of pairs overlapping on both sweep axes plus primary false
positives.
"""

from __future__ import annotations

import numba
import numpy as np

from .._numba import jit, pjit
from . import succtree as st
from .bits import ALL, cttz


@jit
def _scan_range(tree, off, lo, hi, base, xlo, xhi, zlo, zhi, br, rinv, me,
                out, cnt, cap):
    """Range query ``S ∩ [lo, hi)`` (Algorithm 1 line 18 / Algorithm 4 line 13)
    with the overlap test of every candidate (line 20 / 15).

    Writes pairs ``(min, max)`` of object ids into ``out`` while ``cnt < cap``
    and always counts.  Returns ``(cnt, tested)``.
    """
    tested = 0
    r = st.succ(tree, off, lo)
    while r != st.NONE and r < hi:
        w = r >> 6
        word = tree[w] & (ALL << np.uint64(r & 63))
        while word != 0:
            rr = (w << 6) + np.int64(cttz(word))
            if rr >= hi:
                return cnt, tested
            q = rr + base
            tested += 1
            if br[q, 0] <= xhi and xlo <= br[q, 1] and br[q, 2] <= zhi and zlo <= br[q, 3]:
                j = rinv[q]
                if cnt < cap:
                    if j < me:
                        out[2 * cnt] = j
                        out[2 * cnt + 1] = me
                    else:
                        out[2 * cnt] = me
                        out[2 * cnt + 1] = j
                cnt += 1
            word &= word - np.uint64(1)
        r = st.succ(tree, off, (w + 1) << 6)
    return cnt, tested


@jit
def candidates_sequential(ix, n, lower, upper, a0, a2, rank, rinv, lcand, ucand, br,
                          tree, off):
    """Algorithm 1, lines 1-14: ranks and candidate bounds on the primary axis
    (then the boxes copied into rank order)."""
    st.clear(tree, off)
    c = 0
    for k in range(2 * n):  # line 6
        i = ix[k]
        if i < n:  # line 7
            rank[i] = c  # line 8
            rinv[c] = i  # line 9
            c += 1
            if st.is_empty(tree, off):  # line 10
                lcand[i] = c
            else:
                lcand[i] = st.minimum(tree, off)
            st.ins(tree, off, rank[i])  # line 11
        else:
            ucand[i - n] = c  # line 13
            st.delete(tree, off, rank[i - n])  # line 14
    for r in range(n):
        i = rinv[r]
        br[r, 0] = lower[i, a0]
        br[r, 1] = upper[i, a0]
        br[r, 2] = lower[i, a2]
        br[r, 3] = upper[i, a2]


@jit
def pairing_sequential(iy, n, rank, rinv, lcand, ucand, br, tree, off, out):
    """Algorithm 1, lines 16-23: sweep the secondary axis.

    Returns ``(pairs, tested)``; pairs beyond ``out.size // 2`` are counted,
    not stored.
    """
    st.clear(tree, off)
    cap = out.shape[0] // 2
    cnt = 0
    tested = 0
    for k in range(2 * n):  # line 16
        i = iy[k]
        if i < n:  # line 17
            r = rank[i]
            cnt, t = _scan_range(tree, off, lcand[i], ucand[i], 0, br[r, 0], br[r, 1],
                                 br[r, 2], br[r, 3], br, rinv, i, out, cnt,
                                 cap)  # lines 18-20
            tested += t
            st.ins(tree, off, r)  # line 21
        else:
            st.delete(tree, off, rank[i - n])  # line 23
    return cnt, tested


@pjit
def candidates_parallel(ix, n, rank, rinv, lcand, ucand, trees, off, counts):
    """Algorithm 3: parallel candidate generation on the primary axis.

    ``trees``: (m, size) private SuccTrees over ``n`` ranks; ``counts``: (m,)
    scratch.  Fills ``rank``, ``rinv``, ``lcand`` and ``ucand``.
    """
    m = trees.shape[0]
    n2 = 2 * n
    delta = (n2 + m - 1) // m  # line 1 (last partition may be shorter)
    # Lines 4-6: count low endpoints per partition.
    for p in numba.prange(m):
        a = min(p * delta, n2)
        b = min(a + delta, n2)
        c = 0
        for k in range(a, b):
            if ix[k] < n:
                c += 1
        counts[p] = c
    # Line 7: exclusive prefix sum of the counters.
    total = 0
    for p in range(m):
        c = counts[p]
        counts[p] = total
        total += c
    # Lines 10-11: ranks.  This loop must finish before the next one starts:
    # a partition holding a high endpoint reads the rank that another
    # partition assigned at the low endpoint.
    for p in numba.prange(m):
        a = min(p * delta, n2)
        b = min(a + delta, n2)
        c = counts[p]
        for k in range(a, b):
            i = ix[k]
            if i < n:
                rank[i] = c
                rinv[c] = i
                c += 1
    # Lines 12-14: private trees holding the objects with exactly one endpoint
    # in the partition (toggles: insert on low, delete on high).
    for p in numba.prange(m):
        a = min(p * delta, n2)
        b = min(a + delta, n2)
        tree = trees[p]
        st.clear(tree, off)
        for k in range(a, b):
            i = ix[k]
            if i < n:
                st.toggle(tree, off, rank[i])
            else:
                st.toggle(tree, off, rank[i - n])
    # Line 15: exclusive all-prefix symmetric differences, word by word, so
    # that tree p holds the objects active when partition p begins.
    nwords = off[1]
    nblk = (nwords + 1023) // 1024
    for blk in numba.prange(nblk):
        w0 = blk * 1024
        w1 = min(w0 + 1024, nwords)
        for w in range(w0, w1):
            acc = np.uint64(0)
            for p in range(m):
                v = trees[p, w]
                trees[p, w] = acc
                acc ^= v
    # Lines 16-23: sweep each partition from its prefix state.
    for p in numba.prange(m):
        a = min(p * delta, n2)
        b = min(a + delta, n2)
        tree = trees[p]
        st.rebuild(tree, off)
        c = counts[p]
        for k in range(a, b):
            i = ix[k]
            if i < n:
                c += 1
                if st.is_empty(tree, off):
                    lcand[i] = c
                else:
                    lcand[i] = st.minimum(tree, off)
                st.ins(tree, off, rank[i])
            else:
                ucand[i - n] = c
                st.delete(tree, off, rank[i - n])


@pjit
def gather_parallel(iy, n, lower, upper, a0, a2, rank, rinv, lcand, ucand, br, ev, evlu):
    """Copy boxes into rank order and lay the secondary sweep out sequentially.

    ``ev[k]``: rank of the object of the k-th secondary endpoint, ``~rank`` for
    a high endpoint; ``evlu[k]``: its candidate range packed ``L << 32 | U``.
    """
    for r in numba.prange(n):
        i = rinv[r]
        br[r, 0] = lower[i, a0]
        br[r, 1] = upper[i, a0]
        br[r, 2] = lower[i, a2]
        br[r, 3] = upper[i, a2]
    for k in numba.prange(2 * n):
        i = iy[k]
        if i < n:
            ev[k] = rank[i]
            evlu[k] = (np.int64(lcand[i]) << 32) | np.int64(ucand[i])
        else:
            ev[k] = ~rank[i - n]


@pjit
def pairing_parallel(ev, evlu, n, br, rinv, trees, off, out, counts, tested, todo):
    """Algorithm 4: rank-partitioned parallel pairing, without duplicates.

    Partition ``p`` owns ranks ``[beta, eps)``; it sweeps every secondary
    endpoint but keeps only its own ranks in its tree, so each pair is found
    by exactly one partition and no reduction is needed.  Partition ``p``
    writes at most ``out.shape[1] // 2`` pairs into row ``p`` of ``out`` and
    counts all of them in ``counts[p]``; only partitions with ``todo[p]`` run.
    """
    m = trees.shape[0]
    cap = out.shape[1] // 2
    delta = (n + m - 1) // m  # line 1
    for p in numba.prange(m):  # line 2
        if not todo[p]:
            continue
        tree = trees[p]  # line 3
        st.clear(tree, off)
        beta = min(p * delta, n)  # line 4
        eps = min(beta + delta, n)  # line 5
        buf = out[p]
        cnt = 0
        tst = 0
        for k in range(2 * n):  # line 6
            r = ev[k]
            if r >= 0:  # line 7
                lu = evlu[k]
                lo = lu >> 32  # line 8
                hi = lu & 0xFFFFFFFF  # line 9
                if lo < eps and beta < hi:  # line 10
                    lo = max(lo, beta) - beta  # line 11
                    hi = min(hi, eps) - beta  # line 12
                    cnt, t = _scan_range(tree, off, lo, hi, beta, br[r, 0], br[r, 1],
                                         br[r, 2], br[r, 3], br, rinv, rinv[r],
                                         buf, cnt, cap)  # lines 13-15
                    tst += t
                if beta <= r and r < eps:  # line 16
                    st.ins(tree, off, r - beta)
            else:
                r = ~r
                if beta <= r and r < eps:  # line 18
                    st.delete(tree, off, r - beta)
        counts[p] = cnt
        tested[p] = tst


@pjit
def assemble(out, counts, pairs):
    """Concatenate the per-partition pair buffers into ``pairs`` (k, 2)."""
    m = out.shape[0]
    starts = np.zeros(m + 1, np.int64)
    for p in range(m):
        starts[p + 1] = starts[p] + counts[p]
    for p in range(m):
        s = starts[p]
        c = counts[p]
        buf = out[p]
        for k in numba.prange(c):
            pairs[s + k, 0] = buf[2 * k]
            pairs[s + k, 1] = buf[2 * k + 1]
