"""The thread count helpers of ``granularsap._numba``: ``get_threads`` reads what
``numba.get_num_threads`` reads (per calling thread), and ``num_threads`` sets and
restores it."""

from __future__ import annotations

import threading

import numba
import numpy as np
import pytest

import granularsap
from granularsap._numba import get_threads, max_threads, num_threads


@pytest.fixture(autouse=True)
def _pool_running():
    # the pool's C entry points are read only once numba has launched it
    granularsap.neighbor_pairs(np.random.default_rng(0).random((50, 3)), 0.2, n_threads=1)
    old = numba.get_num_threads()
    yield
    numba.set_num_threads(old)


def test_get_threads_reads_numbas_count():
    for n in range(1, max_threads() + 1):
        numba.set_num_threads(n)
        assert get_threads() == numba.get_num_threads() == n


@pytest.mark.parametrize("n", [None, 1, "max"])
def test_num_threads_sets_and_restores(n):
    n = max_threads() if n == "max" else n
    numba.set_num_threads(1)
    before = numba.get_num_threads()
    with num_threads(n) as used:
        assert used == numba.get_num_threads() == get_threads() == (before if n is None else n)
    assert numba.get_num_threads() == before
    # restored when the block raises
    with pytest.raises(KeyError), num_threads(n):
        raise KeyError
    assert numba.get_num_threads() == before


def test_each_thread_has_its_own_count():
    numba.set_num_threads(1)
    seen = {}

    def other():
        seen["start"] = numba.get_num_threads()
        with num_threads(max_threads()):
            seen["inside"] = (get_threads(), numba.get_num_threads())
        seen["after"] = (get_threads(), numba.get_num_threads())

    t = threading.Thread(target=other)
    t.start()
    t.join()
    assert seen["inside"] == (max_threads(), max_threads())
    assert seen["after"] == (seen["start"], seen["start"])
    assert get_threads() == numba.get_num_threads() == 1
