"""IDXSORT and the parallel bucketed sort of Algorithm 2.

Endpoint convention (Capannini & Larsson, Section 4.1): for object ``i`` its
low endpoint on an axis is entry ``i`` and its high endpoint entry ``i + n``
of a ``2n`` array.  The sort returns the entry indices in coordinate order.

Keys.  A float64 coordinate ``x`` becomes an unsigned 64-bit key that orders
like the float: ``x + 0.0`` first (so ``-0.0`` and ``+0.0`` get one key), then
the sign bit set for non-negative values and all bits flipped for negative
ones.  Comparisons of keys are therefore exact comparisons of coordinates.

Ties.  The sort is stable (least-significant-digit radix sort, and a stable
bucket scatter in index order), so at equal coordinates entries keep index
order: every low endpoint (index < n) comes before every high endpoint (index
>= n).  That is what makes the sweep report closed boxes that only touch.

Algorithm 2.  ``m`` buckets are delimited by ``m - 1`` boundary keys ``B``
(line 2: a key goes to the bucket of the boundaries not above it); each
thread counts its chunk per bucket, a prefix sum gives stable scatter offsets
(line 3), and the buckets are radix-sorted independently in parallel (lines
4-5).  ``B`` is then re-read from the sorted order at every ``2n/m``-th
position (lines 6-7), so on the next frame, with temporal coherence, the
buckets come out almost equal.  On the first frame ``B`` divides the span
evenly.  The dispersion ``D`` of the bucket sizes (equation 1, Section 5) is
returned for the axis-swapping heuristic.

IDXSORT inside a bucket subtracts the bucket's smallest key and sorts 11 bits
per pass, only over the bits in which keys differ, skipping passes where all
keys share the digit; segments of up to 32 entries use insertion sort.
"""

from __future__ import annotations

import numba
import numpy as np

from .._numba import hjit, ijit, jit, pjit

SIGN = np.uint64(0x8000000000000000)
RADIX_BITS = 11
RADIX = 1 << RADIX_BITS
#: Passes of one LSD sort at most (64-bit keys); ``count`` scratch holds
#: ``MAX_PASSES * RADIX`` counters.
MAX_PASSES = 6
MASK = np.uint64(RADIX - 1)


@jit
def float_key(x):
    """Order-preserving uint64 key of a float64 (``-0.0`` maps like ``+0.0``)."""
    a = np.empty(1, np.float64)
    a[0] = x + 0.0
    u = a.view(np.uint64)[0]
    if u & SIGN:
        return ~u
    return u | SIGN


@hjit
def _endpoint_keys_chunk(lower, upper, axis, keys, start, stop):
    n = lower.shape[0]
    kv = keys.view(np.float64)
    for e in range(start, stop):
        if e < n:
            kv[e] = lower[e, axis] + 0.0
        else:
            kv[e] = upper[e - n, axis] + 0.0
    for e in range(start, stop):
        u = keys[e]
        if u & SIGN:
            keys[e] = ~u
        else:
            keys[e] = u | SIGN


@hjit
def _bucket_of(key, bounds):
    """Number of boundaries <= key (binary search): the bucket index."""
    lo = 0
    hi = bounds.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if bounds[mid] <= key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@hjit
def _insertion_sort(keys, idx, lo, hi):
    for a in range(lo + 1, hi):
        k = keys[a]
        v = idx[a]
        b = a - 1
        while b >= lo and keys[b] > k:
            keys[b + 1] = keys[b]
            idx[b + 1] = idx[b]
            b -= 1
        keys[b + 1] = k
        idx[b + 1] = v


@hjit
def _lsd_passes(ka, ia, kb, ib, lo, hi, count, kmin, shift, stop):
    """Stable LSD passes over bits ``[shift, stop)`` of ``key - kmin``.

    The digit histograms of all passes (at most ``MAX_PASSES``) are taken in
    one read; each pass is then one scatter.  Passes in which every key has
    the same digit are skipped.  Returns True when the result is in
    ``(ka, ia)``.
    """
    m = hi - lo
    npass = (stop - shift + RADIX_BITS - 1) // RADIX_BITS
    if npass <= 0:
        return True
    hist = count[: npass * RADIX].reshape(npass, RADIX)
    for d in range(npass * RADIX):
        count[d] = 0
    for a in range(lo, hi):
        v = (ka[a] - kmin) >> np.uint64(shift)
        for j in range(npass):
            hist[j, np.intp(v & MASK)] += 1
            v >>= np.uint64(RADIX_BITS)
    in_a = True
    for j in range(npass):
        sh = np.uint64(shift + j * RADIX_BITS)
        h = hist[j]
        skip = False
        for d in range(RADIX):
            if h[d] == m:
                skip = True
                break
            if h[d] != 0:
                break
        if skip:
            continue
        if in_a:
            src_k, src_i, dst_k, dst_i = ka, ia, kb, ib
        else:
            src_k, src_i, dst_k, dst_i = kb, ib, ka, ia
        total = lo
        for d in range(RADIX):
            c = h[d]
            h[d] = total
            total += c
        for a in range(lo, hi):
            k = src_k[a]
            d = np.intp(((k - kmin) >> sh) & MASK)
            p = h[d]
            h[d] = p + 1
            dst_k[p] = k
            dst_i[p] = src_i[a]
        in_a = not in_a
    return in_a


@hjit
def _min_max(keys, lo, hi):
    kmin = keys[lo]
    kmax = keys[lo]
    for a in range(lo + 1, hi):
        k = keys[a]
        if k < kmin:
            kmin = k
        if k > kmax:
            kmax = k
    return kmin, kmax


@hjit
def _nbits(x):
    nbits = 0
    while x != 0:
        x >>= np.uint64(1)
        nbits += 1
    return nbits


@hjit
def _radix_plain(ka, ia, kb, ib, lo, hi, count):
    """Stable LSD radix sort of ``[lo, hi)`` over all bits in which keys differ."""
    if hi - lo <= 32:
        _insertion_sort(ka, ia, lo, hi)
        return True
    kmin, kmax = _min_max(ka, lo, hi)
    return _lsd_passes(ka, ia, kb, ib, lo, hi, count, kmin, np.int64(0), _nbits(kmax - kmin))


#: Leading bits sorted by the LSD passes; ties in them are settled afterwards.
TOP_BITS = 2 * RADIX_BITS


@jit
def radix_segment(ka, ia, kb, ib, lo, hi, count):
    """Stable sort of entries ``[lo, hi)`` of ``(ka, ia)`` by key (IDXSORT).

    ``(kb, ib)`` is scratch of the same size.  Returns True when the sorted
    result is in ``(ka, ia)`` and False when it is in ``(kb, ib)``.

    Only the ``TOP_BITS`` leading bits in which the keys differ get LSD
    passes (three, instead of up to six for float keys); runs of entries that
    agree on those bits (rare: their coordinates agree to about ten
    significant digits relative to the bucket's width) are then sorted on the
    remaining bits, by insertion when short and by plain LSD passes when long.
    Every step is stable, so ties keep index order.
    """
    m = hi - lo
    if m <= 1:
        return True
    if m <= 32:
        _insertion_sort(ka, ia, lo, hi)
        return True
    kmin, kmax = _min_max(ka, lo, hi)
    nbits = _nbits(kmax - kmin)
    if nbits <= TOP_BITS + RADIX_BITS:
        return _lsd_passes(ka, ia, kb, ib, lo, hi, count, kmin, np.int64(0), nbits)
    low = nbits - TOP_BITS
    in_a = _lsd_passes(ka, ia, kb, ib, lo, hi, count, kmin, low, nbits)
    if in_a:
        rk, ri, sk, si = ka, ia, kb, ib
    else:
        rk, ri, sk, si = kb, ib, ka, ia
    shl = np.uint64(low)
    a = lo
    while a < hi:
        top = (rk[a] - kmin) >> shl
        b = a + 1
        while b < hi and ((rk[b] - kmin) >> shl) == top:
            b += 1
        if b - a > 1:
            if not _radix_plain(rk, ri, sk, si, a, b, count):
                for c in range(a, b):
                    rk[c] = sk[c]
                    ri[c] = si[c]
        a = b
    return in_a


@jit
def sort_sequential(lower, upper, axis, keys, keys_tmp, idx, idx_tmp):
    """IDXSORT of one axis in a single thread (Algorithm 1, lines 5 and 15)."""
    n2 = 2 * lower.shape[0]
    _endpoint_keys_chunk(lower, upper, axis, keys, np.int64(0), n2)
    for e in range(n2):
        idx[e] = e
    count = np.empty(MAX_PASSES * RADIX, np.int64)
    if not radix_segment(keys, idx, keys_tmp, idx_tmp, np.int64(0), n2, count):
        for e in range(n2):
            idx[e] = idx_tmp[e]


@ijit
def scatter_offsets(hist, starts, nchunks, m):
    """Turn the counts ``hist[t, q]`` of ``nchunks`` chunks in ``m`` buckets into
    each chunk's first slot per bucket, buckets in order and chunks in order
    within a bucket (a stable scatter); ``starts[q]`` gets each bucket's first
    slot and ``starts[m]`` the total."""
    total = 0
    for q in range(m):
        starts[q] = total
        for t in range(nchunks):
            c = hist[t, q]
            hist[t, q] = total
            total += c
    starts[m] = total


@pjit
def sort_parallel(lower, upper, axis, bounds, keys, keys_tmp, idx, idx_tmp,
                  hist, starts, nchunks):
    """Algorithm 2: bucketed parallel IDXSORT of one axis.

    ``bounds``: ``m - 1`` boundary keys.  ``hist``: (nchunks, m) int64 scratch.
    ``starts``: (m + 1,) receives bucket offsets.  The sorted entry indices end
    in ``idx``.
    """
    n2 = 2 * lower.shape[0]
    m = bounds.shape[0] + 1
    chunk = (n2 + nchunks - 1) // nchunks
    # Lines 1-3, counting: keys and bucket of every endpoint, per-chunk counts.
    for t in numba.prange(nchunks):
        a = min(t * chunk, n2)
        b = min(a + chunk, n2)
        _endpoint_keys_chunk(lower, upper, axis, keys, a, b)
        for q in range(m):
            hist[t, q] = 0
        for e in range(a, b):
            q = _bucket_of(keys[e], bounds)
            idx_tmp[e] = q
            hist[t, q] += 1
    # Prefix sums: stable scatter offsets for (chunk, bucket).
    scatter_offsets(hist, starts, nchunks, m)
    # Line 3, scatter in index order (stable).
    for t in numba.prange(nchunks):
        a = min(t * chunk, n2)
        b = min(a + chunk, n2)
        for e in range(a, b):
            q = idx_tmp[e]
            p = hist[t, q]
            hist[t, q] = p + 1
            keys_tmp[p] = keys[e]
            idx[p] = e
    # Lines 4-5: sort every bucket independently.
    for q in numba.prange(m):
        count = np.empty(MAX_PASSES * RADIX, np.int64)
        lo = starts[q]
        hi = starts[q + 1]
        if not radix_segment(keys_tmp, idx, keys, idx_tmp, lo, hi, count):
            for e in range(lo, hi):
                idx[e] = idx_tmp[e]


@jit
def dispersion(starts):
    """Equation 1: D = sum |x_i - mu| / 2n over the m bucket sizes x_i."""
    m = starts.shape[0] - 1
    n2 = starts[m]
    if n2 == 0:
        return 0.0
    mu = n2 / m
    acc = 0.0
    for q in range(m):
        acc += abs((starts[q + 1] - starts[q]) - mu)
    return acc / n2


@jit
def bounds_from_order(lower, upper, axis, idx, bounds):
    """Algorithm 2, lines 6-7: b_i <- X[I[i * floor(2n/m)]] (as keys)."""
    n = lower.shape[0]
    m = bounds.shape[0] + 1
    step = (2 * n) // m
    for i in range(1, m):
        e = idx[i * step]
        if e < n:
            bounds[i - 1] = float_key(lower[e, axis])
        else:
            bounds[i - 1] = float_key(upper[e - n, axis])


@jit
def bounds_from_span(lower, upper, axis, bounds):
    """First frame (Section 4.1): b_i = min + i * span / m, as keys."""
    n = lower.shape[0]
    m = bounds.shape[0] + 1
    lo = np.inf
    hi = -np.inf
    for i in range(n):
        if lower[i, axis] < lo:
            lo = lower[i, axis]
        if upper[i, axis] > hi:
            hi = upper[i, axis]
    if n == 0:
        lo = 0.0
        hi = 0.0
    span = hi - lo
    for i in range(1, m):
        bounds[i - 1] = float_key(lo + i * (span / m))


@jit
def bucket_sizes_sorted(lower, upper, axis, idx, bounds, starts):
    """Bucket sizes of an already sorted axis (for D on the sequential path).

    ``starts[q]`` = number of endpoints with key < ``bounds[q - 1]``, by binary
    search over the sorted order: O(m log n).
    """
    n = lower.shape[0]
    n2 = 2 * n
    m = bounds.shape[0] + 1
    starts[0] = 0
    starts[m] = n2
    for q in range(1, m):
        b = bounds[q - 1]
        lo = 0
        hi = n2
        while lo < hi:
            mid = (lo + hi) >> 1
            e = idx[mid]
            if e < n:
                k = float_key(lower[e, axis])
            else:
                k = float_key(upper[e - n, axis])
            if k < b:
                lo = mid + 1
            else:
                hi = mid
        starts[q] = lo
