"""SuccTree: the succinct active list of the bi-dimensional Sweep and Prune.

Capannini & Larsson, Section 3.  A w-ary tree of bit vectors with w = 64: level
0 holds one bit per leaf (the active set), and bit ``k`` of level ``d + 1`` is
set iff word ``k`` of level ``d`` is non-zero.  The parent of position ``i`` at
level ``d`` is position ``i // 64`` at level ``d + 1``.  ``ins``, ``del``,
``min`` and ``succ`` walk at most two root paths and cost O(log_64 n) word
operations; a range query is ``succ`` iterated, O(l log_64 n) for l results,
and in practice one word scan per 64 ranks.

A tree is a flat ``uint64`` array ``bits`` plus ``off``, the offset of each
level's first word (``off[nlev]`` is the total size).  Several trees of one
size share ``off`` and live in the rows of a 2-D ``bits`` array, which is how
the parallel phases keep one private tree per partition (Algorithms 3 and 4).

The ``*_k`` variants address ``k`` trees interleaved word by word in one
array: word ``w`` of level ``d`` of tree ``b`` is ``bits[(off[d] + w) * k + b]``.
Trees that are queried together at the same position (the third-axis shards
of the pairing phase) then share cache lines.

Algorithm 3 needs the symmetric difference of trees: its kernel
(``sweep.candidates_parallel``) XORs the leaves word by word and rebuilds the
summary levels (``rebuild``), O(n/64).
"""

from __future__ import annotations

import numpy as np

from .._numba import ijit, jit
from .bits import ALL, ONE, cttz

NONE = -1


def layout(size):
    """Level offsets of a SuccTree over ``size`` leaves (pure Python)."""
    size = max(int(size), 1)
    off = [0]
    words = (size + 63) // 64
    while True:
        off.append(off[-1] + words)
        if words == 1:
            break
        words = (words + 63) // 64
    return np.asarray(off, dtype=np.int64)


@jit
def clear(bits, off):
    """Empty the tree (all levels)."""
    for k in range(off[len(off) - 1]):
        bits[k] = np.uint64(0)


@ijit
def ins(bits, off, x):
    """Insert leaf ``x`` (paper: S.ins)."""
    ins_k(bits, off, 1, 0, x)


@ijit
def delete(bits, off, x):
    """Remove leaf ``x`` (paper: S.del)."""
    delete_k(bits, off, 1, 0, x)


@ijit
def toggle(bits, off, x):
    """Flip leaf ``x`` at level 0 only; call ``rebuild`` before any query."""
    w = off[0] + (x >> 6)
    bits[w] ^= ONE << np.uint64(x & 63)


@ijit
def succ(bits, off, x):
    """Smallest leaf ``>= x`` in the tree, or ``NONE`` (paper: succ, from x - 1).

    Climbs until a word holds a set bit at or after the current position (the
    lowest common ancestor), then descends along lowest set bits.
    """
    return succ_k(bits, off, 1, 0, x)


@ijit
def minimum(bits, off):
    """Smallest leaf or ``NONE`` (paper: S.min)."""
    top = off[len(off) - 2]
    if bits[top] == 0:
        return NONE
    return succ(bits, off, 0)


@ijit
def is_empty(bits, off):
    return bits[off[len(off) - 2]] == 0


@jit
def rebuild(bits, off):
    """Recompute summary levels 1.. from level 0."""
    nlev = len(off) - 1
    for lev in range(1, nlev):
        for k in range(off[lev], off[lev + 1]):
            bits[k] = np.uint64(0)
        child0 = off[lev - 1]
        for c in range(off[lev] - off[lev - 1]):
            if bits[child0 + c] != 0:
                bits[off[lev] + (c >> 6)] |= ONE << np.uint64(c & 63)


@jit
def to_array(bits, off):
    """All leaves in increasing order (for tests)."""
    count = 0
    for k in range(off[1]):
        w = bits[k]
        while w != 0:
            w &= w - ONE
            count += 1
    out = np.empty(count, np.int64)
    i = 0
    x = succ(bits, off, 0)
    while x != NONE:
        out[i] = x
        i += 1
        x = succ(bits, off, x + 1)
    return out


# ---------------------------------------------------------------- interleaved


@ijit
def ins_k(bits, off, k, b, x):
    """``ins`` on tree ``b`` of ``k`` interleaved trees."""
    nlev = len(off) - 1
    pos = x
    for lev in range(nlev):
        w = (off[lev] + (pos >> 6)) * k + b
        was = bits[w]
        bits[w] = was | (ONE << np.uint64(pos & 63))
        if was != 0:
            return
        pos >>= 6


@ijit
def delete_k(bits, off, k, b, x):
    """``delete`` on tree ``b`` of ``k`` interleaved trees."""
    nlev = len(off) - 1
    pos = x
    for lev in range(nlev):
        w = (off[lev] + (pos >> 6)) * k + b
        now = bits[w] & ~(ONE << np.uint64(pos & 63))
        bits[w] = now
        if now != 0:
            return
        pos >>= 6


@ijit
def succ_k(bits, off, k, b, x):
    """``succ`` on tree ``b`` of ``k`` interleaved trees."""
    nlev = len(off) - 1
    pos = x
    lev = 0
    while lev < nlev:
        w = pos >> 6
        if off[lev] + w >= off[lev + 1]:
            return NONE
        word = bits[(off[lev] + w) * k + b] & (ALL << np.uint64(pos & 63))
        if word != 0:
            pos = (w << 6) + np.int64(cttz(word))
            while lev > 0:
                lev -= 1
                pos = (pos << 6) + np.int64(cttz(bits[(off[lev] + pos) * k + b]))
            return pos
        pos = w + 1
        lev += 1
    return NONE
