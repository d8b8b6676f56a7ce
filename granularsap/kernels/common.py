"""Small kernels both engines use: the packed lattice shift of a pair, the bounds
search in a sorted run, a stable index sort; and what the particles' column sweep
and the cross-set query share: the agreed separation and threshold test, the
sweep-axis bucket."""

from __future__ import annotations

import math

import numpy as np

from .._numba import ijit, jit

OFF = 512  # bias of one 10-bit shift field
ZERO = (OFF << 20) | (OFF << 10) | OFF  # the code of a zero shift


@ijit
def encode(s0, s1, s2):
    """Packed int32 code of the lattice shift ``(s0, s1, s2)``: three 10-bit fields
    biased by ``OFF``."""
    return ((s0 + OFF) << 20) | ((s1 + OFF) << 10) | (s2 + OFF)


@ijit
def decode(code):
    """``(s0, s1, s2)`` of a packed shift code."""
    return (code >> 20) - OFF, ((code >> 10) & 1023) - OFF, (code & 1023) - OFF


@ijit
def separation_between(wa, a, wb, b, cell, s0, s1, s2):
    """``D = (wb[b] - wa[a]) + s0 cell[0] + s1 cell[1] + s2 cell[2]``, added in this
    order (the agreed arithmetic, docs/cells.md; ``wa`` and ``wb`` may be one
    array)."""
    dx = wb[b, 0] - wa[a, 0]
    dy = wb[b, 1] - wa[a, 1]
    dz = wb[b, 2] - wa[a, 2]
    # added unconditionally (no unpredictable branch): a zero shift adds +-0.0,
    # which changes no distance
    dx += s0 * cell[0, 0]
    dy += s0 * cell[0, 1]
    dz += s0 * cell[0, 2]
    dx += s1 * cell[1, 0]
    dy += s1 * cell[1, 1]
    dz += s1 * cell[1, 2]
    dx += s2 * cell[2, 0]
    dy += s2 * cell[2, 1]
    dz += s2 * cell[2, 2]
    return dx, dy, dz


@ijit
def hit(d2, thr, strict, uniform, x2):
    """The exact test ``d <= thr`` (``d < thr`` if strict) with ``d = sqrt(d2)``;
    with one threshold for every pair (``uniform``) it is ``d2 <= x2``, ``x2`` the
    largest double whose rounded square root passes (the same answer, no sqrt)."""
    if uniform:
        return d2 <= x2
    d = math.sqrt(d2)
    return (d < thr) | ((not strict) & (d == thr))


@ijit
def zbucket(v, zlo, inv_bz, top):
    """Bucket of sweep coordinate ``v`` on a grid of the sweep axis: ``floor((v -
    zlo) * inv_bz)`` clamped to ``[0, top]`` (monotone in ``v``)."""
    f = (v - zlo) * inv_bz
    f = min(max(f, 0.0), top)
    return np.int64(f)


@jit
def lower_bound(arr, lo, hi, v):
    """First index in ``[lo, hi)`` of the sorted ``arr`` with ``arr[i] >= v``."""
    while lo < hi:
        mid = (lo + hi) >> 1
        if arr[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@ijit
def stable_argsort(vals):
    """Indices that sort the finite ``vals`` ascending, equal values in index order
    (``np.argsort(vals, kind="stable")`` for finite values): a bottom-up merge
    sort, which compiles in a fraction of the time numba's own takes."""
    m = vals.shape[0]
    order = np.arange(m)
    tmp = np.empty(m, np.int64)
    width = 1
    while width < m:
        for lo in range(0, m, 2 * width):
            mid = min(lo + width, m)
            hi = min(lo + 2 * width, m)
            a, b, k = lo, mid, lo
            while a < mid and b < hi:
                if vals[order[b]] < vals[order[a]]:  # strictly less: ties keep the left
                    tmp[k] = order[b]
                    b += 1
                else:
                    tmp[k] = order[a]
                    a += 1
                k += 1
            while a < mid:
                tmp[k] = order[a]
                a += 1
                k += 1
            while b < hi:
                tmp[k] = order[b]
                b += 1
                k += 1
        order, tmp = tmp, order
        width *= 2
    return order
