"""The engine's building blocks against plain Python: SuccTree and IDXSORT."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granularsap.kernels import radixsort as rs
from granularsap.kernels import succtree as S


@pytest.mark.parametrize("size", [1, 5, 64, 65, 4096, 4097, 300_000])
def test_succtree_matches_a_python_set(size):
    rng = np.random.default_rng(size)
    off = S.layout(size)
    bits = np.zeros(off[-1], np.uint64)
    ref = set()
    for _ in range(2000):
        x = int(rng.integers(0, size))
        if x in ref:
            S.delete(bits, off, x)
            ref.discard(x)
        else:
            S.ins(bits, off, x)
            ref.add(x)
        q = int(rng.integers(0, size + 2))
        assert S.succ(bits, off, q) == min((r for r in ref if r >= q), default=S.NONE)
    assert list(S.to_array(bits, off)) == sorted(ref)
    assert S.minimum(bits, off) == (min(ref) if ref else S.NONE)


@pytest.mark.parametrize("k,b", [(1, 0), (8, 0), (8, 7), (64, 33)])
def test_interleaved_trees_are_independent(k, b):
    size = 5000
    rng = np.random.default_rng(k + b)
    off = S.layout(size)
    bits = np.zeros(off[-1] * k, np.uint64)
    other = (b + 1) % k
    ref = set()
    for x in rng.integers(0, size, 800):
        x = int(x)
        S.ins_k(bits, off, k, b, x)
        ref.add(x)
        if k > 1:
            S.ins_k(bits, off, k, other, (x * 7) % size)
    for x in list(ref)[::3]:
        S.delete_k(bits, off, k, b, x)
        ref.discard(x)
    for q in range(0, size, 97):
        assert S.succ_k(bits, off, k, b, q) == min((r for r in ref if r >= q),
                                                    default=S.NONE)


def test_symmetric_difference_and_rebuild():
    size = 10_000
    off = S.layout(size)
    a = np.zeros(off[-1], np.uint64)
    b = np.zeros(off[-1], np.uint64)
    sa = {1, 5, 64, 4095, 9999}
    sb = {5, 63, 64, 7000}
    for x in sa:
        S.toggle(a, off, x)
    for x in sb:
        S.toggle(b, off, x)
    a[:off[1]] ^= b[:off[1]]  # the leaves' symmetric difference, as Algorithm 3 takes it
    S.rebuild(a, off)
    assert list(S.to_array(a, off)) == sorted(sa ^ sb)


def _sort_both_ways(lo, hi, axis=0):
    n = len(lo)
    x = np.concatenate([lo[:, axis], hi[:, axis]]) + 0.0
    want = np.lexsort((np.arange(2 * n), x))
    keys = np.empty(2 * n, np.uint64)
    keys_tmp = np.empty_like(keys)
    idx = np.empty(2 * n, np.int32)
    idx_tmp = np.empty_like(idx)
    rs.sort_sequential(lo, hi, axis, keys, keys_tmp, idx, idx_tmp)
    np.testing.assert_array_equal(idx, want)
    for m, chunks in ((1, 1), (7, 3), (16, 2)):
        bounds = np.empty(m - 1, np.uint64)
        rs.bounds_from_span(lo, hi, axis, bounds)
        hist = np.empty((chunks, m), np.int64)
        starts = np.empty(m + 1, np.int64)
        rs.sort_parallel(lo, hi, axis, bounds, keys, keys_tmp, idx, idx_tmp, hist, starts,
                         chunks)
        np.testing.assert_array_equal(idx, want)
        if n:
            rs.bounds_from_order(lo, hi, axis, idx, bounds)
            rs.sort_parallel(lo, hi, axis, bounds, keys, keys_tmp, idx, idx_tmp, hist,
                             starts, chunks)
            np.testing.assert_array_equal(idx, want)


@given(st.lists(st.sampled_from([-2.0, -0.0, 0.0, 1e-310, 0.5, 1.0, 3.0, 1e300, -1e300]),
                min_size=0, max_size=200),
       st.integers(0, 2 ** 32 - 1))
def test_idxsort_is_stable_and_low_before_high(values, seed):
    rng = np.random.default_rng(seed)
    lo = np.array(values, dtype=np.float64).reshape(-1, 1).repeat(3, axis=1)
    hi = lo + rng.integers(0, 2, lo.shape)
    _sort_both_ways(lo, hi)


@pytest.mark.parametrize("n", [0, 1, 33, 1000, 100_000])
def test_idxsort_random(n):
    rng = np.random.default_rng(n)
    lo = rng.normal(size=(n, 3)) * 10.0
    hi = lo + rng.random((n, 3))
    _sort_both_ways(lo, hi, axis=2)


def test_idxsort_runs_that_agree_on_leading_bits():
    """One far outlier makes a bucket's keys span all bits; the many nearly equal
    keys must still come out exactly ordered (settled after the leading passes)."""
    rng = np.random.default_rng(1)
    n = 5000
    lo = 1.0 + rng.integers(0, 50, (n, 3)) * 1e-15
    lo[0, 0] = 1e6
    lo[1, 0] = -3.0
    hi = lo + rng.integers(0, 2, (n, 3)) * 1e-15
    _sort_both_ways(lo, hi)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.sampled_from([-1.5, -0.0, 0.0, 0.25, 1.0, 3.0, 1e300]), max_size=70)
       | st.lists(st.floats(-1e6, 1e6, allow_nan=False), max_size=70))
def test_stable_argsort_equals_numpy_stable(vals):
    from granularsap.kernels.common import stable_argsort

    v = np.array(vals, dtype=np.float64)
    assert stable_argsort(v).tolist() == np.argsort(v, kind="stable").tolist()
