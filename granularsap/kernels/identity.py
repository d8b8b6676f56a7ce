"""Contact identity between two calls: which row of the previous result each
row of this result continues.

Particle pairs (``match_in_step``, ``rest_sort`` and ``rest_merge``)
-------------------------------------------------------------------
Both pair lists come from the same search, which writes them in an order that
moves little between calls (column by column, the pairs of one particle one
after another), so most pairs of this call sit where the previous list had
them, one row after the pair found before.  Each pair is written from its
lower previous row (``_canon``: the two particles mapped to the previous
call's rows by ``m``, the shift negated when they swap), and two passes find
its previous row:

1. ``match_in_step``: a cursor follows the previous list.  A pair is looked
   for at the cursor, then on both sides of it, nearest first, up to
   ``_NEAR`` rows; found, the cursor moves past it.  After ``_LOST`` misses in
   a row the cursor is looked for again ``_RESYNC`` rows around.  Each chunk
   of rows places its cursor by finding one of its first pairs near its
   share of the previous list, so chunks run in parallel.  Pairs in step
   (about 97 % of an md-liquid step) cost one comparison of two sequential
   reads; the others cost at most ``2 _NEAR`` comparisons in cache.
2. ``rest_sort`` and ``rest_merge``: the pairs pass 1 did not find (their
   particles crossed a column, or they are new) against the previous rows it
   did not find: both lists are given one uint64 code per pair (its two
   previous rows, ``_pair_code``), radix-sorted by it (the two lists at once,
   one per thread) and merged.  A continuing pair missed by pass 1 is always
   among those rows (a previous row is the row of one pair only), so the
   answer is exact and does not depend on how the rows were chunked or on
   the thread count.  (On an md-liquid trajectory whose particles move 0.05
   sigma a frame, 1e5 particles, pass 1 leaves about 9 % of the pairs, a
   third of them new; the sort and merge of those take a sixth of the time an
   open-addressing hash table of them took, whose probes miss the cache.)

O(pairs + particles) per call, streaming reads but for the few pairs of
pass 2.

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

from .._numba import hjit, ijit, jit, pjit, serial_twin
from .common import lower_bound
from .radixsort import radix_segment

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


@jit
def same_ids(ids, prev_ids):
    """Whether two id arrays of one length are equal, row for row."""
    for a in range(ids.shape[0]):
        if ids[a] != prev_ids[a]:
            return False
    return True


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


# ------------------------------------------------------------- matching

@ijit
def _canon(a, b, with_shift, s0, s1, s2):
    """``(lo, hi, t0, t1, t2)``: the pair ``(a, b)`` with shift ``s`` (from ``a`` to
    ``b``) written from its lower row (the shift negated when swapped; a row's
    own image by the lexicographically positive of ``+-s``)."""
    if not with_shift:
        if a <= b:
            return a, b, s0, s1, s2
        return b, a, s0, s1, s2
    if a > b or (a == b and (s0 < 0 or (s0 == 0 and (s1 < 0 or (s1 == 0 and s2 < 0))))):
        return b, a, -s0, -s1, -s2
    return a, b, s0, s1, s2


@ijit
def _prev_key(prev_pairs, prev_shifts, with_shift, q):
    t0 = t1 = t2 = np.int64(0)
    if with_shift:
        t0 = prev_shifts[q, 0]
        t1 = prev_shifts[q, 1]
        t2 = prev_shifts[q, 2]
    return _canon(prev_pairs[q, 0], prev_pairs[q, 1], with_shift, t0, t1, t2)


@ijit
def _is(prev_pairs, prev_shifts, with_shift, q, lo, hi, s0, s1, s2):
    """Whether previous row ``q`` is the pair ``(lo, hi, s)`` (canonical)."""
    a = prev_pairs[q, 0]
    b = prev_pairs[q, 1]
    if not with_shift:
        return (a == lo and b == hi) or (a == hi and b == lo)
    p0, p1, t0, t1, t2 = _prev_key(prev_pairs, prev_shifts, with_shift, q)
    return p0 == lo and p1 == hi and t0 == s0 and t1 == s1 and t2 == s2


@ijit
def _key_of(pairs, m, mapped, n_prev, with_shift, shifts, jumps, r):
    """This call's row ``r`` in the previous call's rows, canonical (``_canon``), or
    ``lo = -1`` when a particle is new."""
    a = pairs[r, 0]
    b = pairs[r, 1]
    if mapped:
        pa = m[a]
        pb = m[b]
    else:
        pa = a if a < n_prev else np.int64(-1)
        pb = b if b < n_prev else np.int64(-1)
    s0 = s1 = s2 = np.int64(0)
    if pa < 0 or pb < 0:
        return np.int64(-1), np.int64(-1), s0, s1, s2
    if with_shift:
        s0 = shifts[r, 0] + jumps[b, 0] - jumps[a, 0]
        s1 = shifts[r, 1] + jumps[b, 1] - jumps[a, 1]
        s2 = shifts[r, 2] + jumps[b, 2] - jumps[a, 2]
    return _canon(pa, pb, with_shift, s0, s1, s2)


#: previous rows searched on each side of the cursor, nearest first
_NEAR = 64
#: misses in a row after which the cursor is looked for again, and how far
_LOST = 24
_RESYNC = 1024
#: pairs tried when a chunk looks for its first position in the previous list
_ANCHORS = 8


@hjit
def _find_near(prev_pairs, prev_shifts, with_shift, g, reach, lo, hi, s0, s1, s2):
    """The previous row of ``(lo, hi, s)`` within ``reach`` rows of ``g``, nearest
    first, or -1."""
    k_prev = prev_pairs.shape[0]
    for d in range(reach + 1):
        u = g + d
        if 0 <= u < k_prev and _is(prev_pairs, prev_shifts, with_shift, u, lo, hi, s0, s1,
                                   s2):
            return u
        u = g - d - 1
        if 0 <= u < k_prev and _is(prev_pairs, prev_shifts, with_shift, u, lo, hi, s0, s1,
                                   s2):
            return u
    return np.int64(-1)


@ijit
def _in_step_chunk(c, pairs, m, mapped, n_prev, with_shift, shifts, jumps, prev_pairs,
                   prev_shifts, bounds, reach, prev_rows, matched, todo, todo_counts):
    """Chunk ``c`` of ``match_in_step`` (``mapped`` and ``with_shift`` given as
    constants by each kernel, so that their branches compile away)."""
    k = pairs.shape[0]
    k_prev = prev_pairs.shape[0]
    lo_r = bounds[c]
    end = bounds[c + 1]
    nt = lo_r
    q = np.int64(0)
    if k > 0:
        q = (lo_r * k_prev) // k
    for t in range(min(_ANCHORS, end - lo_r)):
        lo, hi, s0, s1, s2 = _key_of(pairs, m, mapped, n_prev, with_shift, shifts, jumps,
                                     lo_r + t)
        if lo < 0:
            continue
        u = _find_near(prev_pairs, prev_shifts, with_shift, q, reach, lo, hi, s0, s1, s2)
        if u >= 0:
            q = max(u - t, np.int64(0))
            break
    misses = 0
    for r in range(lo_r, end):
        prev_rows[r] = -1
        lo, hi, s0, s1, s2 = _key_of(pairs, m, mapped, n_prev, with_shift, shifts, jumps, r)
        if lo < 0:
            continue
        u = np.int64(-1)
        if q < k_prev and _is(prev_pairs, prev_shifts, with_shift, q, lo, hi, s0, s1, s2):
            u = q  # in step: the pair after the last one found
        else:
            for d in range(1, _NEAR):
                v = q + d
                if v < k_prev and _is(prev_pairs, prev_shifts, with_shift, v, lo, hi, s0, s1,
                                      s2):
                    u = v
                    break
                v = q - d
                if v >= 0 and _is(prev_pairs, prev_shifts, with_shift, v, lo, hi, s0, s1, s2):
                    u = v
                    break
        if u < 0 and misses >= _LOST:
            u = _find_near(prev_pairs, prev_shifts, with_shift, q, np.int64(_RESYNC), lo, hi,
                           s0, s1, s2)
            misses = 0
        if u >= 0:
            prev_rows[r] = u
            matched[u] = 1
            q = u + 1
            misses = 0
        else:
            todo[nt] = r
            nt += 1
            misses += 1
    todo_counts[c] = nt - lo_r


# Each variant's chunk is its own compiled function (``mapped`` and
# ``with_shift`` constants there, so that their branches compile away: as runtime
# flags pass 1 took 37 % longer on an md-liquid step) which the parallel kernel
# and its serial twin both call with an int64 ``c`` (a prange index is unsigned:
# a second signature): the body compiles once per variant.

@hjit
def _chunk(c, pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds, reach,
           prev_rows, matched, todo, todo_counts):
    _in_step_chunk(c, pairs, m, False, n_prev, False, shifts, jumps, prev_pairs, prev_shifts,
                   bounds, reach, prev_rows, matched, todo, todo_counts)


@hjit
def _chunk_ids(c, pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds, reach,
               prev_rows, matched, todo, todo_counts):
    _in_step_chunk(c, pairs, m, True, n_prev, False, shifts, jumps, prev_pairs, prev_shifts,
                   bounds, reach, prev_rows, matched, todo, todo_counts)


@hjit
def _chunk_shifts(c, pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds, reach,
                  prev_rows, matched, todo, todo_counts):
    _in_step_chunk(c, pairs, m, False, n_prev, True, shifts, jumps, prev_pairs, prev_shifts,
                   bounds, reach, prev_rows, matched, todo, todo_counts)


@hjit
def _chunk_ids_shifts(c, pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds, reach,
                      prev_rows, matched, todo, todo_counts):
    _in_step_chunk(c, pairs, m, True, n_prev, True, shifts, jumps, prev_pairs, prev_shifts,
                   bounds, reach, prev_rows, matched, todo, todo_counts)


@pjit
def match_in_step(pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds, reach,
                  prev_rows, matched, todo, todo_counts):
    """Pass 1 of the pair matching (module docstring), particles by row, no shifts:
    the pairs of this call found near a cursor that follows the previous list.
    ``prev_rows[r]`` is the previous row of pair ``r``, or -1; a pair not found
    whose particles both existed is written to ``todo`` (chunk ``c`` from
    ``bounds[c]``, their number to ``todo_counts[c]``) for pass 2
    (``match_rest``); ``matched[q] = 1`` for every previous row found.  Chunk
    ``c`` (rows ``bounds[c]:bounds[c + 1]``) places its cursor by finding one of
    its first pairs within ``reach`` rows of its share of the previous list."""
    for c in numba.prange(bounds.shape[0] - 1):
        _chunk(np.int64(c), pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds,
               reach, prev_rows, matched, todo, todo_counts)


@pjit
def match_in_step_ids(pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds,
                      reach, prev_rows, matched, todo, todo_counts):
    """``match_in_step`` with particles mapped to previous rows by ``m``."""
    for c in numba.prange(bounds.shape[0] - 1):
        _chunk_ids(np.int64(c), pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds,
                   reach, prev_rows, matched, todo, todo_counts)


@pjit
def match_in_step_shifts(pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds,
                         reach, prev_rows, matched, todo, todo_counts):
    """``match_in_step`` by row and lattice shift (corrected by ``jumps``)."""
    for c in numba.prange(bounds.shape[0] - 1):
        _chunk_shifts(np.int64(c), pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds,
                      reach, prev_rows, matched, todo, todo_counts)


@pjit
def match_in_step_ids_shifts(pairs, m, n_prev, shifts, jumps, prev_pairs, prev_shifts, bounds,
                             reach, prev_rows, matched, todo, todo_counts):
    """``match_in_step`` by ``m`` and lattice shift."""
    for c in numba.prange(bounds.shape[0] - 1):
        _chunk_ids_shifts(np.int64(c), pairs, m, n_prev, shifts, jumps, prev_pairs,
                          prev_shifts, bounds, reach, prev_rows, matched, todo, todo_counts)


@ijit
def _pair_code(lo, hi, n_prev):
    """One uint64 of a canonical pair's two previous rows (both below ``n_prev``,
    which is below 2**32): equal codes, equal rows."""
    return np.uint64(lo) * np.uint64(n_prev) + np.uint64(hi)


@hjit
def _rest_left(prev_pairs, prev_shifts, with_shift, n_prev, left, keys, rows):
    """The codes of the previous rows pass 1 left (``left``)."""
    for i in range(left.shape[0]):
        q = left[i]
        lo, hi, t0, t1, t2 = _prev_key(prev_pairs, prev_shifts, with_shift, q)
        keys[i] = _pair_code(lo, hi, n_prev)
        rows[i] = q


@hjit
def _rest_todo(pairs, m, mapped, n_prev, with_shift, shifts, jumps, bounds, todo, todo_counts,
               keys, rows):
    """The codes of this call's rows pass 1 did not find (``todo``, chunk ``c``'s from
    ``bounds[c]``, ``todo_counts[c]`` of them), in chunk order."""
    j = 0
    for c in range(bounds.shape[0] - 1):
        for i in range(bounds[c], bounds[c] + todo_counts[c]):
            r = todo[i]
            lo, hi, s0, s1, s2 = _key_of(pairs, m, mapped, n_prev, with_shift, shifts, jumps,
                                         r)
            keys[j] = _pair_code(lo, hi, n_prev)
            rows[j] = r
            j += 1


@pjit
def rest_sort(pairs, m, mapped, n_prev, with_shift, shifts, jumps, prev_pairs, prev_shifts,
              bounds, todo, todo_counts, n_todo, left, keys, rows, scratch_keys, scratch_rows,
              counts, sorted_in):
    """Pass 2 of the pair matching, its first half: the codes (``_pair_code``) of the
    previous rows pass 1 left (``keys[0]``, ``rows[0]``: ``left``) and of the
    ``n_todo`` rows it did not find (``keys[1]``, ``rows[1]``: ``todo``), each
    sorted by code (a stable radix sort, one list per thread).  ``sorted_in[t]``
    is 1 when list ``t`` came out in ``keys[t]``, 0 when in ``scratch_keys[t]``."""
    n_left = left.shape[0]
    for t in numba.prange(2):
        size = n_left if t == 0 else n_todo
        if t == 0:
            _rest_left(prev_pairs, prev_shifts, with_shift, n_prev, left, keys[0], rows[0])
        else:
            _rest_todo(pairs, m, mapped, n_prev, with_shift, shifts, jumps, bounds, todo,
                       todo_counts, keys[1], rows[1])
        sorted_in[t] = np.uint8(radix_segment(keys[t], rows[t], scratch_keys[t],
                                              scratch_rows[t], np.int64(0), np.int64(size),
                                              counts[t]))


@jit
def rest_merge(pairs, m, mapped, n_prev, with_shift, shifts, jumps, prev_pairs, prev_shifts,
               keys_left, rows_left, keys_todo, rows_todo, prev_rows, matched):
    """Pass 2, its second half: the two lists of ``rest_sort`` merged by code; a row
    of this call and a previous row of equal code are the same pair (with lattice
    shifts, of equal shifts too: the rows of one code are the images of one
    particle pair, compared one by one).  A previous row is the row of one pair
    only, so the answer does not depend on how pass 1 left them."""
    n_left = keys_left.shape[0]
    n_todo = keys_todo.shape[0]
    i = 0
    j = 0
    while i < n_left and j < n_todo:
        a = keys_left[i]
        b = keys_todo[j]
        if a < b:
            i += 1
            continue
        if b < a:
            j += 1
            continue
        i1 = i + 1
        while i1 < n_left and keys_left[i1] == a:
            i1 += 1
        j1 = j + 1
        while j1 < n_todo and keys_todo[j1] == a:
            j1 += 1
        if not with_shift:  # one pair of each code on each side
            q = rows_left[i]
            prev_rows[rows_todo[j]] = q
            matched[q] = 1
            i = i1
            j = j1
            continue
        for jj in range(j, j1):
            r = rows_todo[jj]
            lo, hi, s0, s1, s2 = _key_of(pairs, m, mapped, n_prev, with_shift, shifts, jumps,
                                         r)
            for ii in range(i, i1):
                q = rows_left[ii]
                if matched[q] == 0 and _is(prev_pairs, prev_shifts, with_shift, q, lo, hi, s0,
                                           s1, s2):
                    prev_rows[r] = q
                    matched[q] = 1
                    break
        i = i1
        j = j1


@jit
def rest_ended(left, matched, ended):
    """The rows of ``left`` (ascending) still unmatched after pass 2, into
    ``ended``; returns their number."""
    e = 0
    for i in range(left.shape[0]):
        q = left[i]
        if matched[q] == 0:
            ended[e] = q
            e += 1
    return e


@jit
def rest_one(pairs, m, mapped, n_prev, with_shift, shifts, jumps, prev_pairs, prev_shifts,
             n_todo, prev_rows, flags, todo, left, keys, rows, scratch_keys, scratch_rows,
             counts, ended):
    """What follows pass 1 in a small call, in one serial kernel: the previous rows
    pass 1 left (``unmatched_into``), pass 2 on them and the ``n_todo`` rows of
    ``todo`` it did not find (``rest_sort``'s serial build, ``rest_merge``), and
    the rows that ended (``rest_ended``).  ``flags``: ``matched`` as pass 1 left
    it, padded as ``unmatched_words`` reads it;
    ``left`` has room for every previous row, ``keys`` ... ``scratch_rows`` (2,
    >= both counts) and ``counts`` are ``rest_sort``'s.  Returns (rows ended,
    -1 when pass 2 has work but ``n_prev`` is 2**32 or more, -2 when it has
    work but ``keys`` holds fewer than both counts (nothing written then but
    ``left``: call again with larger buffers); previous rows pass 1 left)."""
    n_left = unmatched_into(flags, left)
    if n_left == 0 or n_todo == 0:
        for i in range(n_left):
            ended[i] = left[i]
        return n_left, n_left
    if n_prev >= np.int64(2) ** 32:
        return np.int64(-1), n_left
    if keys.shape[1] < max(n_left, n_todo):
        return np.int64(-2), n_left
    bounds = np.zeros(2, np.int64)
    bounds[1] = n_todo
    todo_counts = np.full(1, n_todo, np.int64)
    sorted_in = np.zeros(2, np.uint8)
    _rest_sort_serial(pairs, m, mapped, n_prev, with_shift, shifts, jumps, prev_pairs,
                      prev_shifts, bounds, todo, todo_counts, n_todo, left[:n_left], keys, rows,
                      scratch_keys, scratch_rows, counts, sorted_in)
    kl = keys[0, :n_left] if sorted_in[0] else scratch_keys[0, :n_left]
    rl = rows[0, :n_left] if sorted_in[0] else scratch_rows[0, :n_left]
    kt = keys[1, :n_todo] if sorted_in[1] else scratch_keys[1, :n_todo]
    rt = rows[1, :n_todo] if sorted_in[1] else scratch_rows[1, :n_todo]
    rest_merge(pairs, m, mapped, n_prev, with_shift, shifts, jumps, prev_pairs, prev_shifts,
               kl, rl, kt, rt, prev_rows, flags)
    return rest_ended(left[:n_left], flags, ended), n_left


@pjit
def unmatched_words(matched, bounds, counts, out, fill):
    """Rows ``q`` with ``matched[q] == 0`` in increasing order, eight rows (one word)
    at a time: ``matched`` a uint8 array whose length is a multiple of 8 (padding
    rows set to 1), ``bounds`` in rows, each a multiple of 8.  Pass 1 (``fill``
    False) counts chunk ``c``'s into ``counts[c]``, pass 2 writes them from
    ``counts[c]`` (now the chunk's offset) into ``out``."""
    words = matched.view(np.uint64)
    full = np.uint64(0x0101010101010101)
    for c in numba.prange(bounds.shape[0] - 1):
        o = counts[c] if fill else 0
        for w in range(bounds[c] >> 3, bounds[c + 1] >> 3):
            if words[w] == full:
                continue
            for q in range(8 * w, 8 * w + 8):
                if matched[q] == 0:
                    if fill:
                        out[o] = q
                    o += 1
        if not fill:
            counts[c] = o


@pjit
def match_entries(prev_entries, entries, bounds, prev_rows, matched, rising):
    """Two calls on one kept list (module docstring): ``prev_rows[r]`` the row of
    ``prev_entries`` equal to ``entries[r]`` or -1, ``matched[q] = 1`` for every row
    found.  Both increasing: chunk ``c`` of rows ``bounds[c]:bounds[c + 1]`` finds
    its first entry by bisection, then merges.  ``rising[c]`` says whether the
    chunk's entries increase (the caller checks the joins between chunks)."""
    for c in numba.prange(bounds.shape[0] - 1):
        rising[c] = _merge_entries(prev_entries, entries, bounds[c], bounds[c + 1],
                                   prev_rows, matched)


@ijit
def _merge_entries(prev_entries, entries, lo, end, prev_rows, matched):
    """Rows ``lo:end`` of ``match_entries``: the first entry found by bisection,
    then a merge; whether those entries increase."""
    if lo >= end:
        return True
    k_prev = prev_entries.shape[0]
    v = entries[lo]
    q = lower_bound(prev_entries, np.int64(0), np.int64(k_prev), v)
    last = v - 1
    rising = True
    for r in range(lo, end):
        v = entries[r]
        if v <= last:
            rising = False
        last = v
        while q < k_prev and prev_entries[q] < v:
            q += 1
        if q < k_prev and prev_entries[q] == v:
            prev_rows[r] = q
            matched[q] = 1
            q += 1
        else:
            prev_rows[r] = -1
    return rising


@jit
def match_entries_one(prev_entries, entries, prev_rows, flags, ended):
    """``match_entries`` on one chunk, then the previous rows not found into
    ``ended`` (``unmatched_into``), in one serial call (a small Verlet frame's
    whole matching): returns their number, or -1 when ``entries`` does not
    increase (nothing written that counts).  ``flags``: ``matched`` zeroed and
    padded as ``unmatched_words`` reads it."""
    if not _merge_entries(prev_entries, entries, 0, entries.shape[0], prev_rows,
                          flags[:prev_entries.shape[0]]):
        return -1
    return unmatched_into(flags, ended)


@pjit
def entries_rising(entries, bounds, rising):
    """``rising[c]``: whether ``entries[bounds[c]:bounds[c + 1]]`` increases."""
    for c in numba.prange(bounds.shape[0] - 1):
        rising[c] = 1
        for r in range(bounds[c] + 1, bounds[c + 1]):
            if entries[r] <= entries[r - 1]:
                rising[c] = 0
                break


@jit
def unmatched_into(matched, out):
    """``unmatched_words`` in one serial pass: the rows with ``matched[q] == 0``
    written to ``out`` (room for every row); returns their number."""
    words = matched.view(np.uint64)
    full = np.uint64(0x0101010101010101)
    o = 0
    for w in range(words.shape[0]):
        if words[w] == full:
            continue
        for q in range(8 * w, 8 * w + 8):
            if matched[q] == 0:
                out[o] = q
                o += 1
    return o



@jit
def carry_rows(history, prev_rows, fill, out):
    """``out[r] = history[prev_rows[r]]``, ``fill`` where ``prev_rows[r] < 0``: the
    carry of a float64 history of ``(k_prev, w)`` rows in one pass."""
    w = history.shape[1]
    for r in range(prev_rows.shape[0]):
        q = prev_rows[r]
        if q >= 0:
            for c in range(w):
                out[r, c] = history[q, c]
        else:
            for c in range(w):
                out[r, c] = fill

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


@ijit
def _find_key(keys, r, prev_keys, shift, slots):
    """The row of ``prev_keys`` equal to ``keys[r]``, through its table ``slots``
    (``key_table``'s, ``shift`` its hash shift), or -1 (also without a table or
    previous keys)."""
    if slots.shape[0] == 0 or prev_keys.shape[0] == 0:
        return np.int64(-1)
    mask = np.int64(slots.shape[0] - 1)
    s = _key_slot(keys, r, mask, np.uint64(shift))
    while slots[s] >= 0:
        q = slots[s]
        if _rows_equal(keys, r, prev_keys, q):
            return q
        s = (s + 1) & mask
    return np.int64(-1)


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
    for c in numba.prange(bounds.shape[0] - 1):
        for r in range(bounds[c], bounds[c + 1]):
            q = _find_key(keys, r, prev_keys, shift, slots)
            prev_rows[r] = q
            if q >= 0:
                matched[q] = 1


@jit
def match_keys_one(keys, shift, slots, prev_keys, prev_shift, prev_slots, k_prev, prev_rows,
                   flags, ended):
    """A small call of ``ContactIdentity`` in one serial kernel: the table of this
    call's keys (``key_table`` into ``slots``), ``prev_rows`` through the previous
    call's table (``match_keys`` on one chunk; ``flags``, the ``k_prev`` previous
    rows padded to whole words, zeroed and the padding set as ``unmatched_words``
    reads it) and the previous rows not found into ``ended`` (``unmatched_into``).
    Returns ``(first, second, ended count)``: the rows of a repeated key, ``(-1,
    -1)`` when the keys are unique (only then the rest is written)."""
    first, second = key_table(keys, shift, slots)
    if first >= 0:
        return first, second, np.int64(0)
    for q in range(flags.shape[0]):
        flags[q] = 0 if q < k_prev else 1
    for r in range(keys.shape[0]):
        q = _find_key(keys, r, prev_keys, prev_shift, prev_slots)
        prev_rows[r] = q
        if q >= 0:
            flags[q] = 1
    return np.int64(-1), np.int64(-1), unmatched_into(flags, ended)


#: the parallel kernels of this module, compiled serially (same names)
serial = SimpleNamespace(**{name: serial_twin(globals()[name]) for name in (
    "match_in_step", "match_in_step_ids", "match_in_step_shifts",
    "match_in_step_ids_shifts", "match_entries", "entries_rising",
    "unmatched_words", "match_keys", "rest_sort")})

#: ``rest_sort`` on one thread, for ``rest_one`` (a kernel calls it by this name)
_rest_sort_serial = serial.rest_sort
