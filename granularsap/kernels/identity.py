"""Contact identity between two calls: which row of the previous result each
row of this result continues.

Particle pairs (``match_pairs``)
--------------------------------
Both pair lists come from the same search, which writes the pairs of one
particle (the "source" of a sweep over one stencil column) one after another,
in an order that moves little between calls.  Each list is cut into *groups*:
maximal runs of consecutive pairs that share one particle, the group's *hub*
(a new group takes as hub the particle it shares with the next pair, else its
first; ``group_pairs``, or the matching pass of the call before for its own
list).  The previous list's groups are also sorted by hub (``hub_index``, a
counting sort over particles), so that every particle's groups are one range
of ``hub_groups`` (each entry the group and its first and last rows plus one, on
one cache line).

A pair of this call is mapped to the previous call's rows of its two
particles (``m``, from the ids).  When a group of this list starts, its hub
is looked for among the next few previous groups after the last one used
(the two lists follow one order); inside a group, each pair is looked for
from where the last pair was found, then in the whole group.  A pair not
found there (its partner moved to another column, the search chose the other
source, or the pair is new) scans the other previous groups of its hub, and
the order is followed from where it was found, then the groups of its other
particle.  Continuing pairs in step with the previous list cost a few
sequential reads each; a pair that changed group or is new costs the scan of
its two particles' groups (random accesses).  O(pairs + particles) per call.
The answer does not depend on how the list is split between threads: every
pair has at most one previous row.

With every periodic image (``with_shift``), a pair is the same when its two
particles and its lattice shift are: the current shift, corrected by the
whole cell vectors each particle jumped between the two calls (``jumps``),
equals the previous one (negated when the two particles come in the other
order, either sign for a particle's own image).

Two calls on one kept list (``match_entries``)
---------------------------------------------
A Verlet frame re-tests the list its search kept at the last rebuild, in the
list's order, and each pair of its result carries its entry in that list
(increasing along the result).  When the previous call re-tested the same
list, with the same particles in the same rows, a pair continues exactly
when its entry was in the previous result: a merge of two increasing
sequences, O(pairs) streaming reads, no lookup by particle.

Keys (``key_table``, ``match_keys``)
-----------------------------------
Contacts given by integer keys (any number of int64 columns) are matched
with an open-addressing hash table of the previous call's keys (multiplicative
hashing, linear probing), built once per call in O(rows) and probed by every
row of this call.
"""

from __future__ import annotations

from types import SimpleNamespace

import numba
import numpy as np

from .._numba import ijit, jit, pjit, serial_twin

_MIX = np.uint64(0x9E3779B97F4A7C15)


# ------------------------------------------------------------------ ids

@jit
def map_ids_dense(prev_ids, ids, lo, table, m):
    """``m[a]`` = row of ``ids[a]`` in ``prev_ids`` or -1, through a table indexed by
    ``id - lo``.  Returns ``(first, second)`` rows of a repeated id of ``ids``, or
    ``(-1, -1)``."""
    table[:] = -1
    for a in range(ids.shape[0]):
        k = ids[a] - lo
        if table[k] != -1:
            return table[k], a
        table[k] = a
    for a in range(ids.shape[0]):
        m[a] = -1
    for r in range(prev_ids.shape[0]):
        k = prev_ids[r] - lo
        if 0 <= k < table.shape[0]:
            a = table[k]
            if a >= 0:
                m[a] = r
    return -1, -1


@ijit
def _slot(key, mask, shift):
    return np.int64((np.uint64(key) * _MIX) >> shift) & mask


@jit
def map_ids_hashed(prev_ids, ids, shift, keys, vals, m):
    """As ``map_ids_dense`` for ids spread too widely for a table: an open-addressing
    hash table of ``len(keys)`` (a power of two, ``64 - shift`` bits) slots."""
    mask = np.int64(keys.shape[0] - 1)
    ushift = np.uint64(shift)
    vals[:] = -1
    for a in range(ids.shape[0]):
        key = ids[a]
        s = _slot(key, mask, ushift)
        while vals[s] >= 0 and keys[s] != key:
            s = (s + 1) & mask
        if vals[s] >= 0:
            return vals[s], a
        keys[s] = key
        vals[s] = a
    for a in range(ids.shape[0]):
        m[a] = -1
    for r in range(prev_ids.shape[0]):
        key = prev_ids[r]
        s = _slot(key, mask, ushift)
        while vals[s] >= 0:
            if keys[s] == key:
                m[vals[s]] = r
                break
            s = (s + 1) & mask
    return -1, -1


# --------------------------------------------------------- pair groups

@ijit
def _has(pairs, r, x):
    return pairs[r, 0] == x or pairs[r, 1] == x


@pjit
def group_pairs(pairs, bounds, gpos, ghub, counts):
    """Cut ``pairs`` into groups sharing one particle (module docstring): chunk
    ``c`` of rows ``bounds[c]:bounds[c + 1]`` writes its groups' first rows and
    hubs from ``gpos[bounds[c]]``, ``ghub[bounds[c]]`` and their number to
    ``counts[c]``."""
    for c in numba.prange(bounds.shape[0] - 1):
        lo = bounds[c]
        end = bounds[c + 1]
        g = lo
        h = np.int64(-1)
        for r in range(lo, end):
            x = pairs[r, 0]
            y = pairs[r, 1]
            if x == h or y == h:
                continue
            h = x
            if r + 1 < end and not _has(pairs, r + 1, x) and _has(pairs, r + 1, y):
                h = y
            gpos[g] = r
            ghub[g] = h
            g += 1
        counts[c] = g - lo


@jit
def hub_index(bounds, counts, gpos, ghub, k, n_rows, hub_start, hub_groups):
    """Compact the chunks' groups into ``gpos`` (their first rows, then ``k``) and sort
    them by hub: the groups of particle ``h`` are
    ``hub_groups[hub_start[h]:hub_start[h + 1]]``, rows ``(group, first row, end
    row)``.  Returns the group count."""
    g = 0
    for c in range(counts.shape[0]):
        lo = bounds[c]
        for t in range(counts[c]):
            gpos[g] = gpos[lo + t]
            ghub[g] = ghub[lo + t]
            g += 1
    gpos[g] = k
    hub_start[:] = 0
    for t in range(g):
        hub_start[ghub[t] + 1] += 1
    for h in range(n_rows):
        hub_start[h + 1] += hub_start[h]
    for t in range(g):
        h = ghub[t]
        u = hub_start[h]
        hub_groups[u, 0] = t
        hub_groups[u, 1] = gpos[t]
        hub_groups[u, 2] = gpos[t + 1]
        hub_start[h] += 1
    for h in range(n_rows, 0, -1):
        hub_start[h] = hub_start[h - 1]
    hub_start[0] = 0
    return g


# ------------------------------------------------------------- matching

@ijit
def _same(prev_pairs, prev_shifts, q, pa, pb, with_shift, s0, s1, s2):
    """Whether previous row ``q`` is the pair ``(pa, pb)`` with shift ``s`` (from
    ``pa`` to ``pb``)."""
    p0 = prev_pairs[q, 0]
    p1 = prev_pairs[q, 1]
    if not with_shift:
        return (p0 == pa and p1 == pb) or (p0 == pb and p1 == pa)
    t0 = prev_shifts[q, 0]
    t1 = prev_shifts[q, 1]
    t2 = prev_shifts[q, 2]
    if p0 == pa and p1 == pb and t0 == s0 and t1 == s1 and t2 == s2:
        return True
    return p0 == pb and p1 == pa and t0 == -s0 and t1 == -s1 and t2 == -s2


@ijit
def _scan(hub, skip, pa, pb, prev_pairs, prev_shifts, gpos, hub_start, hub_groups,
          with_shift, s0, s1, s2):
    """``(row, group)`` of ``(pa, pb, s)`` among the previous groups of ``hub`` but
    ``skip``, or ``(-1, -1)``."""
    for t in range(hub_start[hub], hub_start[hub + 1]):
        g = hub_groups[t, 0]
        if g == skip:
            continue
        for q in range(hub_groups[t, 1], hub_groups[t, 2]):
            if _same(prev_pairs, prev_shifts, q, pa, pb, with_shift, s0, s1, s2):
                return q, g
    return np.int64(-1), np.int64(-1)


@ijit
def _apart(x, rad, lengths, pa, pb, slack):
    """Whether previous rows ``pa``, ``pb`` were farther apart than
    ``rad[pa] + rad[pb] + slack`` (minimum image over the axes of length > 0)."""
    d2 = 0.0
    for c in range(3):
        d = x[pb, c] - x[pa, c]
        if lengths[c] > 0:
            d -= lengths[c] * np.rint(d / lengths[c])
        d2 += d * d
    reach = rad[pa] + rad[pb] + slack
    return d2 > reach * reach


#: entries of the previous group tried from where the last pair was found
_WINDOW = 4
#: previous groups tried after the last one used when a group starts
_LOOKAHEAD = 4


@pjit
def match_pairs(pairs, m, mapped, n_prev, with_shift, shifts, jumps, prev_pairs, prev_shifts,
                gpos, ghub, hub_start, hub_groups, far_x, far_r, far_len, far_slack, bounds,
                prev_rows, matched, cur_gpos, cur_ghub, cur_counts):
    """``prev_rows[r]``: the previous row of pair ``r`` or -1, and ``matched[q] = 1``
    for every previous row found (module docstring).  ``m`` maps rows to previous
    rows when ``mapped``, else a row is its own previous row below ``n_prev``.
    Chunk ``c`` takes rows ``bounds[c]:bounds[c + 1]``, and cuts them into groups
    for the next call as ``group_pairs`` does (``cur_gpos``, ``cur_ghub``,
    ``cur_counts``).  With previous positions ``far_x`` (else empty), a pair
    not in step whose particles were farther apart than their radii ``far_r``
    plus ``far_slack`` (``_apart``) is new without a scan: the previous list
    held every pair within that range."""
    n_groups = ghub.shape[0]
    far = far_x.shape[0] > 0
    for c in numba.prange(bounds.shape[0] - 1):
        lo = bounds[c]
        end = bounds[c + 1]
        cg = lo
        ch = np.int64(-1)
        h = np.int64(-1)  # hub of the current group (a previous row)
        pg = np.int64(-1)  # the previous group of h in use, or -1
        j = np.int64(0)  # where in it the last pair was found, plus one
        nxt = np.int64(0)  # the previous group the next current group likely has
        for r in range(lo, end):
            a = pairs[r, 0]
            b = pairs[r, 1]
            if a != ch and b != ch:  # this list's groups, for the next call
                ch = a
                if r + 1 < end and not _has(pairs, r + 1, a) and _has(pairs, r + 1, b):
                    ch = b
                cur_gpos[cg] = r
                cur_ghub[cg] = ch
                cg += 1
            if mapped:
                pa = m[a]
                pb = m[b]
            else:
                pa = a if a < n_prev else np.int64(-1)
                pb = b if b < n_prev else np.int64(-1)
            prev_rows[r] = -1
            if pa < 0 or pb < 0:
                continue
            s0 = s1 = s2 = np.int64(0)
            if with_shift:
                s0 = shifts[r, 0] + jumps[b, 0] - jumps[a, 0]
                s1 = shifts[r, 1] + jumps[b, 1] - jumps[a, 1]
                s2 = shifts[r, 2] + jumps[b, 2] - jumps[a, 2]
            if pa == h:
                t = pb
            elif pb == h:
                t = pa
            else:  # a new group: its hub, then its hub's previous group
                h = pa
                if r + 1 < end:
                    na = pairs[r + 1, 0]
                    nb = pairs[r + 1, 1]
                    if mapped:
                        na = m[na]
                        nb = m[nb]
                    elif na >= n_prev or nb >= n_prev:
                        na = nb = np.int64(-1)
                    if na != pa and nb != pa and (na == pb or nb == pb):
                        h = pb
                t = pb if h == pa else pa
                # the group after the last one used (the two lists usually
                # follow one order), else the one found below
                pg = -1
                for u in range(nxt, min(nxt + _LOOKAHEAD, n_groups)):
                    if ghub[u] == h:
                        pg = u
                        break
                if pg >= 0:
                    j = gpos[pg]
                    nxt = pg + 1
            q = np.int64(-1)
            if pg >= 0:
                gs = gpos[pg]
                ge = gpos[pg + 1]
                for u in range(j, min(j + _WINDOW, ge)):
                    if _same(prev_pairs, prev_shifts, u, pa, pb, with_shift, s0, s1, s2):
                        q = u
                        break
                if q < 0:
                    for u in range(gs, ge):
                        if _same(prev_pairs, prev_shifts, u, pa, pb, with_shift, s0, s1,
                                 s2):
                            q = u
                            break
                if q >= 0:
                    j = q + 1
            if q < 0 and far and _apart(far_x, far_r, far_len, pa, pb, far_slack):
                continue  # out of range in the previous call: new
            if q < 0 and hub_start[h + 1] - hub_start[h] > (1 if pg >= 0 else 0):
                q, g = _scan(h, pg, pa, pb, prev_pairs, prev_shifts, gpos, hub_start,
                             hub_groups, with_shift, s0, s1, s2)
                if q >= 0:  # follow the order of the previous list from there
                    pg = g
                    j = q + 1
                    nxt = g + 1
            if q < 0 and t != h:
                q, g = _scan(t, -1, pa, pb, prev_pairs, prev_shifts, gpos, hub_start,
                             hub_groups, with_shift, s0, s1, s2)
            if q >= 0:
                prev_rows[r] = q
                matched[q] = 1
        cur_counts[c] = cg - lo


@pjit
def match_entries(prev_entries, entries, bounds, prev_rows, matched, rising):
    """Two calls on one kept list (module docstring): ``prev_rows[r]`` the row of
    ``prev_entries`` equal to ``entries[r]`` or -1, ``matched[q] = 1`` for every row
    found.  Both increasing: chunk ``c`` of rows ``bounds[c]:bounds[c + 1]`` finds
    its first entry by bisection, then merges.  ``rising[c]`` says whether the
    chunk's entries increase (the caller checks the joins between chunks)."""
    k_prev = prev_entries.shape[0]
    for c in numba.prange(bounds.shape[0] - 1):
        lo = bounds[c]
        end = bounds[c + 1]
        rising[c] = 1
        if lo >= end:
            continue
        v = entries[lo]
        a = np.int64(0)
        b = np.int64(k_prev)
        while a < b:
            mid = (a + b) >> 1
            if prev_entries[mid] < v:
                a = mid + 1
            else:
                b = mid
        q = a
        last = v - 1
        for r in range(lo, end):
            v = entries[r]
            if v <= last:
                rising[c] = 0
            last = v
            while q < k_prev and prev_entries[q] < v:
                q += 1
            if q < k_prev and prev_entries[q] == v:
                prev_rows[r] = q
                matched[q] = 1
                q += 1
            else:
                prev_rows[r] = -1


@pjit
def entries_rising(entries, bounds, rising):
    """``rising[c]``: whether ``entries[bounds[c]:bounds[c + 1]]`` increases."""
    for c in numba.prange(bounds.shape[0] - 1):
        rising[c] = 1
        for r in range(bounds[c] + 1, bounds[c + 1]):
            if entries[r] <= entries[r - 1]:
                rising[c] = 0
                break


@pjit
def unmatched_rows(matched, bounds, counts, out, fill):
    """Rows ``q`` with ``matched[q] == 0`` in increasing order: pass 1 (``fill``
    False) counts chunk ``c``'s into ``counts[c]``, pass 2 writes them from
    ``counts[c]`` (now the chunk's offset) into ``out``."""
    for c in numba.prange(bounds.shape[0] - 1):
        o = counts[c] if fill else 0
        for q in range(bounds[c], bounds[c + 1]):
            if matched[q] == 0:
                if fill:
                    out[o] = q
                o += 1
        if not fill:
            counts[c] = o


# ------------------------------------------------------------------ keys

@ijit
def _key_slot(keys, r, mask, shift):
    h = np.uint64(0)
    for c in range(keys.shape[1]):
        h = (h ^ np.uint64(keys[r, c])) * _MIX
        h ^= h >> np.uint64(29)
    return np.int64((h * _MIX) >> shift) & mask


@ijit
def _rows_equal(a, r, b, q):
    for c in range(a.shape[1]):
        if a[r, c] != b[q, c]:
            return False
    return True


@jit
def key_table(keys, shift, slots):
    """Hash table of the rows of ``keys``: ``slots[s]`` a row or -1.  Returns
    ``(first, second)`` rows of a repeated key, or ``(-1, -1)``."""
    mask = np.int64(slots.shape[0] - 1)
    ushift = np.uint64(shift)
    slots[:] = -1
    for r in range(keys.shape[0]):
        s = _key_slot(keys, r, mask, ushift)
        while slots[s] >= 0:
            if _rows_equal(keys, r, keys, slots[s]):
                return slots[s], r
            s = (s + 1) & mask
        slots[s] = r
    return -1, -1


@pjit
def match_keys(keys, prev_keys, shift, slots, bounds, prev_rows, matched):
    """``prev_rows[r]``: the row of ``prev_keys`` equal to ``keys[r]`` (through its
    table ``slots``) or -1; ``matched[q] = 1`` for every row found."""
    mask = np.int64(slots.shape[0] - 1)
    ushift = np.uint64(shift)
    for c in numba.prange(bounds.shape[0] - 1):
        for r in range(bounds[c], bounds[c + 1]):
            prev_rows[r] = -1
            if slots.shape[0] == 0:
                continue
            s = _key_slot(keys, r, mask, ushift)
            while slots[s] >= 0:
                q = slots[s]
                if _rows_equal(keys, r, prev_keys, q):
                    prev_rows[r] = q
                    matched[q] = 1
                    break
                s = (s + 1) & mask


#: the parallel kernels of this module, compiled serially (same names)
serial = SimpleNamespace(**{name: serial_twin(globals()[name]) for name in (
    "group_pairs", "match_pairs", "match_entries", "entries_rising", "unmatched_rows",
    "match_keys")})
