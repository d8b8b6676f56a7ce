"""The only place that decides numba options for granularsap kernels.

Compilation is cached on disk by default (``cache=True``) so that a warm
``import granularsap`` plus the first call stays fast.  Set the environment
variable ``GRANULARSAP_NO_CACHE=1`` to turn the cache off (for example on a
read-only install).  The library never chooses numba's threading layer: that
is the application's call.
"""

from __future__ import annotations

import contextlib
import os

import numba

CACHE = os.environ.get("GRANULARSAP_NO_CACHE", "0").lower() in ("", "0", "false", "no")

_OPTIONS = dict(cache=CACHE, nogil=True, fastmath=False, error_model="numpy")


def jit(func):
    """Decorator for serial kernels."""
    return numba.njit(**_OPTIONS)(func)


def ijit(func):
    """Decorator for small serial helpers of hot loops, inlined into their
    callers at numba's IR level (no call overhead, no argument packing)."""
    return numba.njit(inline="always", **_OPTIONS)(func)


def pjit(func):
    """Decorator for parallel kernels (``numba.prange`` loops)."""
    return numba.njit(parallel=True, **_OPTIONS)(func)


def max_threads() -> int:
    """Largest thread count numba can use in this process."""
    return numba.config.NUMBA_NUM_THREADS


@contextlib.contextmanager
def num_threads(n_threads):
    """Run a block with ``n_threads`` numba threads, restoring the old value after.

    ``None`` keeps numba's current setting.  Yields the number of threads in use.
    The argument must already be validated (see ``_validate.check_n_threads``).
    """
    if n_threads is None:
        yield numba.get_num_threads()
        return
    old = numba.get_num_threads()
    numba.set_num_threads(n_threads)
    try:
        yield n_threads
    finally:
        numba.set_num_threads(old)
