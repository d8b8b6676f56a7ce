"""Small kernels both engines use: the packed lattice shift of a pair and the
bounds search in a sorted run."""

from __future__ import annotations

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
