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

from .._numba import hjit, ijit, jit, pjit
from . import succtree as st
from .bits import ALL, cttz

HIGH = np.int64(1) << 62
QUERY = np.int64(1) << 61
OWN = np.int64(1) << 60
RANK_MASK = np.int64(0xFFFFFFFF)


@hjit
def _scan_range(tree, off, lo, hi, base, xlo, xhi, zlo, zhi, br, rinv, me,
                out, cnt, cap):
    """Range query ``S ∩ [lo, hi)`` (Algorithm 1 line 18 / Algorithm 4 line 13)
    with the overlap test of every candidate (line 20 / 15)."""
    return _scan_range_k(tree, off, 1, 0, lo, hi, base, xlo, xhi, zlo, zhi, br, rinv,
                         me, out, cnt, cap)


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
    cnt = np.int64(0)  # (typed: a literal 0 would compile _scan_range twice)
    tested = 0
    for k in range(2 * n):  # line 16
        i = iy[k]
        if i < n:  # line 17
            r = rank[i]
            cnt, t = _scan_range(tree, off, lcand[i], ucand[i], np.int64(0), br[r, 0], br[r, 1],
                                 br[r, 2], br[r, 3], br, rinv, i, out, cnt,
                                 cap)  # lines 18-20
            tested += t
            st.ins(tree, off, r)  # line 21
        else:
            st.delete(tree, off, rank[i - n])  # line 23
    return cnt, tested


@pjit
def candidates_parallel(ix, n, info, rinv, rk, trees, off, counts):
    """Algorithm 3: parallel candidate generation on the primary axis.

    ``trees``: (m, size) private SuccTrees over ``n`` ranks; ``counts``: (m,)
    scratch; ``rk``: (2n,) scratch that receives the rank of every endpoint in
    sorted order, so the sweeps after the first read ranks sequentially.
    Fills ``rinv`` and, per object ``i``, the record ``info[i]`` = (rank
    ``R[i]``, ``L[i]``, ``U[i]``, -): one cache line serves every look-up of
    an object in this phase and the next.
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
    # Lines 10-11: ranks of low endpoints.  This loop must finish before the
    # next one starts: a partition holding a high endpoint reads the rank
    # that another partition assigned at the low endpoint.
    for p in numba.prange(m):
        a = min(p * delta, n2)
        b = min(a + delta, n2)
        c = counts[p]
        for k in range(a, b):
            i = ix[k]
            if i < n:
                info[i, 0] = c
                rinv[c] = i
                rk[k] = c
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
            if i >= n:
                rk[k] = info[i - n, 0]
            st.toggle(tree, off, rk[k])
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
            r = rk[k]
            if i < n:
                c += 1
                if st.is_empty(tree, off):  # line 19
                    info[i, 1] = c
                else:
                    info[i, 1] = st.minimum(tree, off)
                st.ins(tree, off, r)  # line 20
            else:
                info[i - n, 2] = c  # line 22
                st.delete(tree, off, r)  # line 23


@jit
def third_axis_bins(lower, upper, a2, kmax):
    """Bins along the unused axis for the sharded active lists of pairing.

    Returns ``(z0, inv_h, reach, k)``: bin of coordinate ``z`` is
    ``floor((z - z0) * inv_h)`` clamped to ``[0, k)``, with bin width
    ``h >= reach >= `` the largest extent of any box on that axis.  ``reach``
    carries a margin of a few ulps so that ``fl(z_lo - reach)`` is never above
    the exact ``z_lo - extent`` (the query range can only grow, never lose a
    candidate).
    """
    n = lower.shape[0]
    zmin = np.inf
    zmax = -np.inf
    ext = 0.0
    for i in range(n):
        lo = lower[i, a2]
        hi = upper[i, a2]
        if lo < zmin:
            zmin = lo
        if hi > zmax:
            zmax = hi
        if hi - lo > ext:
            ext = hi - lo
    if n == 0:
        return 0.0, 0.0, 0.0, 1
    span = zmax - zmin
    reach = ext + 1e-12 * (max(abs(zmin), abs(zmax)) + ext)
    k = 1
    if not (np.isfinite(span) and np.isfinite(reach)):
        return zmin, 0.0, reach, 1  # coordinates near the float range: no shards
    if reach > 0.0:
        k = int(min(float(kmax), span / reach))
    elif span > 0.0:
        k = kmax
    if k < 3:
        return zmin, 0.0, reach, 1
    return zmin, k / span, reach, k


@ijit
def _bin(z, z0, inv_h, k):
    b = np.int64((z - z0) * inv_h)
    if b < 0:
        return 0
    if b >= k:
        return k - 1
    return b


@ijit
def _route(e, n, info, delta):
    """Partitions an event must reach (Algorithm 4, lines 10, 16 and 18).

    Returns ``(own, qa, qb)``: the partition owning the object's rank (it
    inserts or deletes it) and the range ``[qa, qb]`` of partitions whose
    ranks meet the candidate range ``[L, U)`` (empty when ``qa > qb``; only
    low endpoints query).
    """
    if e < n:
        r = info[e, 0]
        lo = info[e, 1]
        hi = info[e, 2]
        if lo < hi:
            return r // delta, lo // delta, (hi - 1) // delta
        return r // delta, 1, 0
    return info[e - n, 0] // delta, 1, 0


@ijit
def _push(events, reg_start, reg_cap, reg_count, t, p, word, lu):
    """Append one event to region ``(t, p)``; False if it is full (still counted)."""
    c = reg_count[t, p]
    reg_count[t, p] = c + 1
    if c >= reg_cap[t, p]:
        return False
    events[reg_start[t, p] + c, 0] = word
    events[reg_start[t, p] + c, 1] = lu
    return True


@pjit
def gather_parallel(iy, n, lower, upper, a0, a2, info, br, z0, inv_h, k, delta,
                    reg_start, reg_cap, reg_count, events):
    """Route the secondary sweep to the rank partitions of Algorithm 4.

    Every endpoint of the secondary order goes, in order, to the partition
    that owns its object's rank (to insert or delete it) and, for a low
    endpoint, to each partition its candidate range ``[L, U)`` meets (to
    query).  That is Algorithm 4's line-10 test done once per event instead of
    once per event and partition; each partition then reads only its own
    events, in sweep order.

    The secondary order is cut into ``T`` chunks (one per thread).  Chunk
    ``t`` writes the events of partition ``p`` into the region of ``events``
    that starts at ``reg_start[t, p]`` and holds ``reg_cap[t, p]`` events;
    ``reg_count[t, p]`` receives how many there were.  Regions are sized from
    the previous frame (temporal coherence), so one pass normally suffices;
    returns False if a region overflowed (the counts are still exact, and the
    caller resizes and calls again).

    ``events[t] = (word, L << 32 | U)`` with ``word`` = rank (bits 0-31), the
    object's third-axis bin (bits 32-47), and flags HIGH, QUERY, OWN.  Also
    records bins in ``info[:, 3]`` and copies the boxes into rank order
    (``br``), reading the inputs in id order.
    """
    n2 = 2 * n
    nchunks = reg_start.shape[0]
    nparts = reg_start.shape[1]
    chunk = (n2 + nchunks - 1) // nchunks
    for i in numba.prange(n):
        r = info[i, 0]
        zlo = lower[i, a2]
        info[i, 3] = _bin(zlo, z0, inv_h, k)
        br[r, 0] = lower[i, a0]
        br[r, 1] = upper[i, a0]
        br[r, 2] = zlo
        br[r, 3] = upper[i, a2]
    ok = np.ones(nchunks, np.bool_)
    for t in numba.prange(nchunks):
        a = min(t * chunk, n2)
        b = min(a + chunk, n2)
        for p in range(nparts):
            reg_count[t, p] = 0
        for q in range(a, b):
            e = iy[q]
            own, qa, qb = _route(e, n, info, delta)
            if e < n:
                i = e
                flags = np.int64(0)
                lu = (np.int64(info[i, 1]) << 32) | np.int64(info[i, 2])
            else:
                i = e - n
                flags = HIGH
                lu = np.int64(0)
            word = np.int64(info[i, 0]) | (np.int64(info[i, 3]) << 32) | flags | OWN
            if qa <= own and own <= qb:
                word |= QUERY
            fits = _push(events, reg_start, reg_cap, reg_count, t, own, word, lu)
            word = (word & ~OWN) | QUERY
            for p in range(qa, qb + 1):
                if p != own:
                    fits &= _push(events, reg_start, reg_cap, reg_count, t, p, word, lu)
            if not fits:
                ok[t] = False
    for t in range(nchunks):
        if not ok[t]:
            return False
    return True


@ijit
def _overlap(br, q, xlo, xhi, zlo, zhi):
    """OverlapTest of Algorithm 1 on the primary and third axes (the secondary
    axis overlaps by construction of the sweep)."""
    return (br[q, 0] <= xhi) & (xlo <= br[q, 1]) & (br[q, 2] <= zhi) & (zlo <= br[q, 3])


@ijit
def _test_word(word, w, base, xlo, xhi, zlo, zhi, br, rinv, me, out, cnt, cap):
    """Overlap-test every rank set in leaf ``word`` number ``w``."""
    tested = 0
    while word != 0:
        q = (w << 6) + np.int64(cttz(word)) + base
        tested += 1
        if _overlap(br, q, xlo, xhi, zlo, zhi):
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
    return cnt, tested


@ijit
def _scan_summary(trees, k, b, leaf0, sum0, sw, s0, s1, w0, w1, first, last, base,
                  xlo, xhi, zlo, zhi, br, rinv, me, out, cnt, cap):
    """The leaves flagged by summary word ``sw``, clipped to words ``[w0, w1]``."""
    tested = 0
    sword = trees[(sum0 + sw) * k + b]
    if sw == s0:
        sword &= ALL << np.uint64(w0 & 63)
    if sw == s1:
        sword &= ALL >> np.uint64(63 - (w1 & 63))
    while sword != 0:
        w = (sw << 6) + np.int64(cttz(sword))
        word = trees[(leaf0 + w) * k + b]
        if w == w0:
            word &= first
        if w == w1:
            word &= last
        cnt, t = _test_word(word, w, base, xlo, xhi, zlo, zhi, br, rinv, me, out, cnt, cap)
        tested += t
        sword &= sword - np.uint64(1)
    return cnt, tested


@ijit
def _scan_range_k(trees, off, k, b, lo, hi, base, xlo, xhi, zlo, zhi, br, rinv, me,
                  out, cnt, cap):
    """Range query ``S ∩ [lo, hi)`` on tree ``b`` of ``k`` interleaved trees,
    with the overlap test of every rank found (Algorithm 4, lines 13-15).

    Rather than iterating ``succ`` (a climb and a descent per step), it walks
    down from the level-2 words covering ``[lo, hi)`` to the non-empty
    summary words they flag, then to the non-empty leaf words, then to their
    set bits: flat loops, O(range / 262144 + words with hits).  Writes pairs
    ``(min, max)`` of object ids into ``out`` while ``cnt < cap`` and always
    counts.  Returns ``(cnt, tested)``.
    """
    tested = 0
    if hi <= lo:
        return cnt, tested
    w0 = lo >> 6
    w1 = (hi - 1) >> 6
    first = ALL << np.uint64(lo & 63)
    last = ALL >> np.uint64(63 - ((hi - 1) & 63))
    if len(off) == 2:  # a single leaf word
        word = trees[b] & first & last
        return _test_word(word, 0, base, xlo, xhi, zlo, zhi, br, rinv, me, out, cnt, cap)
    leaf0 = off[0]
    sum0 = off[1]
    s0 = w0 >> 6
    s1 = w1 >> 6
    if len(off) == 3:  # leaves and one summary level
        for sw in range(s0, s1 + 1):
            cnt, t = _scan_summary(trees, k, b, leaf0, sum0, sw, s0, s1, w0, w1, first,
                                   last, base, xlo, xhi, zlo, zhi, br, rinv, me, out, cnt,
                                   cap)
            tested += t
        return cnt, tested
    # Deeper trees: level-2 words say which summary words are non-empty, and
    # in sparse shards almost none are.
    top0 = off[2]
    t0 = s0 >> 6
    t1 = s1 >> 6
    for tw in range(t0, t1 + 1):
        tword = trees[(top0 + tw) * k + b]
        if tw == t0:
            tword &= ALL << np.uint64(s0 & 63)
        if tw == t1:
            tword &= ALL >> np.uint64(63 - (s1 & 63))
        while tword != 0:
            sw = (tw << 6) + np.int64(cttz(tword))
            cnt, t = _scan_summary(trees, k, b, leaf0, sum0, sw, s0, s1, w0, w1, first,
                                   last, base, xlo, xhi, zlo, zhi, br, rinv, me, out, cnt,
                                   cap)
            tested += t
            tword &= tword - np.uint64(1)
    return cnt, tested


@pjit
def pairing_parallel(events, reg_start, reg_count, n, br, rinv, trees, off, k, z0,
                     inv_h, reach, out, counts, tested, todo):
    """Algorithm 4: rank-partitioned parallel pairing, without duplicates.

    Partition ``p`` owns ranks ``[beta, eps)`` and keeps only those in its
    active list, so each pair is found by exactly one partition and no
    reduction is needed.  Its events (``gather_parallel``: one region per
    chunk of the sweep, read in chunk order) arrive in sweep order: OWN
    events insert (low, line 16) or delete (high, line 18) its ranks; QUERY
    events run the clipped range query (lines 11-15).

    Extension: the active list of a partition is sharded into ``k`` SuccTrees
    (interleaved in ``trees[p]``) by the bin of the box's low end on the
    unused axis (``third_axis_bins``).  A query visits only the bins that can
    hold a box overlapping it on that axis, at most three, instead of the
    whole list; the exact overlap test still decides every pair.  With
    ``k == 1`` this is the paper's Algorithm 4.  Partitions are sized so that
    their trees stay in cache.

    Partition ``p`` writes at most ``out.shape[1] // 2`` pairs into row ``p``
    of ``out`` and counts all of them in ``counts[p]``; only partitions with
    ``todo[p]`` run.
    """
    m = trees.shape[0]
    cap = out.shape[1] // 2
    delta = (n + m - 1) // m  # line 1
    for p in numba.prange(m):  # line 2
        if not todo[p]:
            continue
        tree = trees[p]
        for w in range(tree.shape[0]):  # line 3
            tree[w] = np.uint64(0)
        beta = min(p * delta, n)  # line 4
        eps = min(beta + delta, n)  # line 5
        buf = out[p]
        cnt = 0
        tst = 0
        for c in range(reg_start.shape[0]):  # line 6: the regions in order
            for t in range(reg_start[c, p], reg_start[c, p] + reg_count[c, p]):
                e = events[t, 0]
                r = e & RANK_MASK
                b = (e >> 32) & 0xFFFF
                if e & HIGH:  # line 17
                    st.delete_k(tree, off, k, b, r - beta)  # line 18
                    continue
                if e & QUERY:  # line 10
                    lu = events[t, 1]
                    lo = max(lu >> 32, beta) - beta  # lines 8, 11
                    hi = min(lu & RANK_MASK, eps) - beta  # lines 9, 12
                    xlo = br[r, 0]
                    xhi = br[r, 1]
                    zlo = br[r, 2]
                    zhi = br[r, 3]
                    b0 = _bin(zlo - reach, z0, inv_h, k)
                    b1 = _bin(zhi, z0, inv_h, k)
                    me = rinv[r]
                    for bb in range(b0, b1 + 1):  # lines 13-15, per shard
                        cnt, tt = _scan_range_k(tree, off, k, bb, lo, hi, beta, xlo,
                                                xhi, zlo, zhi, br, rinv, me, buf, cnt,
                                                cap)
                        tst += tt
                if e & OWN:
                    st.ins_k(tree, off, k, b, r - beta)  # line 16
        counts[p] = cnt
        tested[p] = tst


@pjit
def assemble(out, counts, pairs):
    """Concatenate the per-partition pair buffers into ``pairs`` (k, 2)."""
    m = out.shape[0]
    starts = np.zeros(m + 1, np.int64)
    for p in range(m):
        starts[p + 1] = starts[p] + counts[p]
    for p in numba.prange(m):
        s = starts[p]
        buf = out[p]
        for k in range(counts[p]):
            pairs[s + k, 0] = buf[2 * k]
            pairs[s + k, 1] = buf[2 * k + 1]
