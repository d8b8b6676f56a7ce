"""The frame: one pass over positions and radii, the power-of-two scale that keeps
every square finite and normal (docs/cells.md, supported magnitudes), the
range check of a minimum-image cell, and the squared bound that decides a pair
threshold exactly.  Pure functions of the frame; ``engine.SearchEngine`` calls
them once per call."""

from __future__ import annotations

import math

import numpy as np

from .._numba import jit
from .._validate import as_vector
from ..kernels.grid import WRAP_LIMIT

#: the letters of ``quantities``
QUANTITIES = "Pijd DS".replace(" ", "")
#: relative guard on the Verlet range against rounding (the exact test decides)
GUARD = 64 * np.finfo(np.float64).eps
#: a frame is "far" where the coordinate-relative guard would exceed this fraction
#: of the range (an open axis holds coordinates ~1e11 ranges away or more)
FAR = 2.0 ** -10
#: the power-of-two scale of a frame keeps |coordinates| below 2**POS_EXP, the
#: interaction range below 2**RANGE_EXP and the smallest pair threshold at or
#: above 2**THR_EXP (its square normal, 53 bits), and with a zero threshold every
#: nonzero coordinate difference at or above 2**DIFF_EXP (its square nonzero)
POS_EXP = 1000
RANGE_EXP = 480
THR_EXP = -480
DIFF_EXP = -530
#: scaled distances below this may come from squares that underflowed: they are
#: recomputed row by row (``SearchEngine._exact_small``)
TINY_D = 2.0 ** -480
#: no radii (``scan_frame`` of positions alone)
NO_RADII = np.zeros(0)


def magnitudes(x):
    """(largest |x|, smallest nonzero |x|) of ``(n, 3)`` positions; (0, inf) if none.

    The frame scan's kernel (one compiled signature for both)."""
    scan = scan_frame(np.ascontiguousarray(x, dtype=np.float64), NO_RADII, NO_RADII)
    return scan[1], scan[2]


@jit
def scan_frame(x, rad, kept):
    """One pass over a frame's positions and radii: (first row of ``x`` with a NaN
    or an inf, or -1; ``magnitudes(x)``; whether every radius is finite and
    non-negative; the smallest and the largest radius; whether ``rad`` equals
    ``kept`` value for value; the extent of ``x`` along each axis, the largest
    coordinate less the smallest, or 0 without particles)."""
    n = x.shape[0]
    # every value is compared with accumulators of its own axis: three chains of
    # n compares, not one of 3n (the loop is bound by their latency)
    hi0 = hi1 = hi2 = 0.0  # largest |x|
    sm0 = sm1 = sm2 = np.inf  # smallest nonzero |x|
    lo0 = lo1 = lo2 = np.inf  # extents
    up0 = up1 = up2 = -np.inf
    fin = 0.0  # NaN once a NaN or an inf was seen
    for i in range(n):
        v0 = x[i, 0]
        v1 = x[i, 1]
        v2 = x[i, 2]
        fin += (v0 - v0) + (v1 - v1) + (v2 - v2)
        a0 = abs(v0)
        a1 = abs(v1)
        a2 = abs(v2)
        hi0 = a0 if a0 > hi0 else hi0
        hi1 = a1 if a1 > hi1 else hi1
        hi2 = a2 if a2 > hi2 else hi2
        sm0 = a0 if (a0 > 0.0) & (a0 < sm0) else sm0
        sm1 = a1 if (a1 > 0.0) & (a1 < sm1) else sm1
        sm2 = a2 if (a2 > 0.0) & (a2 < sm2) else sm2
        lo0 = v0 if v0 < lo0 else lo0
        up0 = v0 if v0 > up0 else up0
        lo1 = v1 if v1 < lo1 else lo1
        up1 = v1 if v1 > up1 else up1
        lo2 = v2 if v2 < lo2 else lo2
        up2 = v2 if v2 > up2 else up2
    bad = -1
    if not fin == 0.0:  # the first row with a NaN or an inf
        for i in range(n):
            if not ((abs(x[i, 0]) < np.inf) & (abs(x[i, 1]) < np.inf)
                    & (abs(x[i, 2]) < np.inf)):
                bad = i
                break
    hi = max(hi0, max(hi1, hi2))
    lo = min(sm0, min(sm1, sm2))
    ok = True
    rmin = np.inf
    rmax = -np.inf
    m = rad.shape[0]  # n, or 0 to scan positions only (magnitudes)
    same = kept.shape[0] == m
    for i in range(m):
        r = rad[i]
        ok = ok & (r >= 0.0) & (r < np.inf)
        rmin = r if r < rmin else rmin
        rmax = r if r > rmax else rmax
        if same:
            same = r == kept[i]
    if n == 0:
        return bad, hi, lo, ok, rmin, rmax, same, 0.0, 0.0, 0.0
    return bad, hi, lo, ok, rmin, rmax, same, up0 - lo0, up1 - lo1, up2 - lo2


def check_half_width(cs, reach_max, what):
    """Refuse a minimum-image frame whose largest range ``reach_max`` (named
    ``what``) exceeds half the narrowest perpendicular width of the periodic cell
    ``cs`` (a ``FrameCell``): several images of a pair would be in range."""
    widths = cs.widths
    # the narrowest periodic axis (the one the message names as the smallest)
    for c in cs.narrowest:
        if reach_max > 0.5 * widths[c] * (1.0 + 1e-12):
            raise ValueError(
                f"{what} {reach_max:.17g} exceeds half the smallest perpendicular cell "
                f"width {0.5 * widths[c]:.17g} (width {widths[c]:.17g} across cell vector "
                f"{c}); several periodic images of a pair would be in range. Use a larger "
                "cell (replicate it) or a smaller range, or periodic_images='all' to get "
                "every image with its shift")


def far_scale(rng, width):
    """The length a frame's coordinate rounding is compared with to call it "far":
    the range, or without one (a zero cutoff) the narrowest periodic width."""
    return rng if rng > 0 else width


def exp2(v):
    """``e`` with ``2**(e - 1) <= v < 2**e`` (``math.frexp``), for ``v > 0``."""
    return math.frexp(v)[1]


def frame_scale(big, fine, rng, thr_min, what, range_name, thr_name):
    """Binary exponent ``k`` of the frame's scale ``2**k``: 0 where no scaling is
    needed, else the one nearest 0 that keeps every coordinate (at most ``big``)
    finite with room to spare, the squares of in-range distances (up to ``rng``)
    finite and those at the smallest pair threshold ``thr_min`` normal; with a
    zero threshold (``thr_min == 0``) also the square of every nonzero coordinate
    difference nonzero (``fine``: the smallest nonzero coordinate, the grid of
    all of them).  ValueError naming the arguments where no power of two does."""
    k_hi, k_lo = 10 ** 6, -10 ** 6
    if big > 0:
        k_hi = POS_EXP - exp2(big)
    if rng > 0:
        k_hi = min(k_hi, RANGE_EXP - exp2(rng))
    if thr_min > 0:
        k_lo = THR_EXP + 1 - exp2(thr_min)
    elif math.isfinite(fine):
        k_lo = DIFF_EXP - max(exp2(fine) - 53, -1074)
    if k_lo <= 0 <= k_hi:
        return 0
    if k_lo <= k_hi:
        return k_lo if k_lo > 0 else k_hi
    if thr_min > 0 and rng > 0 and RANGE_EXP - exp2(rng) < k_lo:
        raise ValueError(
            f"{range_name} {rng!r} and the smallest pair threshold {thr_min!r} "
            f"({thr_name}) are more than 2**{RANGE_EXP - THR_EXP - 2} apart: no "
            "power-of-two scale of the frame keeps both the squared distances at the "
            "largest range finite and those at the smallest one normal; split the "
            "search by size")
    if thr_min > 0:
        raise ValueError(
            f"positions up to {big!r} in magnitude and {what} {thr_min!r} are more "
            f"than 2**{POS_EXP - THR_EXP - 1} apart: no power-of-two scale of the frame "
            f"keeps the coordinates finite and the squared distances at {what} normal; "
            "move the frame's origin nearer the particles or use a larger range")
    raise ValueError(
        f"with a zero {what} only coincident points pair, but positions up to {big!r} "
        f"in magnitude and nonzero coordinates as small as {fine!r} are too far apart "
        "for any power-of-two scale to keep the coordinates finite and every nonzero "
        "squared separation nonzero")


def square_bound(thr, strict):
    """Largest double ``x2`` with ``sqrt(x2) <= thr`` (``< thr`` if strict), rounded
    square roots: ``d2 <= x2`` is then exactly the test on ``d = sqrt(d2)``."""
    def ok(v):
        d = math.sqrt(v)
        return d < thr or (not strict and d == thr)

    if thr < 0 or (strict and thr == 0):
        return -1.0
    x2 = thr * thr
    while not ok(x2):
        x2 = math.nextafter(x2, -math.inf)
    while math.isfinite(up := math.nextafter(x2, math.inf)) and ok(up):
        x2 = up
    return x2


def exact_bound(rad, skin, strict):
    """(uniform, x2): whether every pair has one threshold ``2 r + skin``, and then
    the squared bound that decides it exactly (``square_bound``)."""
    uniform = bool(rad.min() == rad.max())
    if not uniform:
        return False, 0.0
    return True, square_bound(float(rad[0]) + float(rad[0]) + skin, strict)


def as_radii(radii, n, name="radii"):
    """Validated ``(n,)`` float64 radii (a scalar is broadcast); plain-float messages."""
    arr = as_vector(radii, name, n, nonnegative=False)
    if arr.size and arr.min() < 0:
        bad = int(np.argmin(arr))
        raise ValueError(f"{name} must be non-negative, got {float(arr[bad])!r} at index {bad}")
    return arr


def as_labels(clump_ids, n, name="clump_ids"):
    """Validated ``(n,)`` int64 labels."""
    ids = np.asarray(clump_ids)
    if ids.dtype.kind not in "iu":
        if ids.dtype.kind == "f" and ids.size and np.all(np.isfinite(ids)) and np.all(
                ids == np.round(ids)):
            ids = ids.astype(np.int64)
        elif ids.size == 0:
            ids = ids.astype(np.int64)
        else:
            raise TypeError(f"{name} must be integers, got dtype {ids.dtype}")
    if ids.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {ids.shape}")
    if ids.dtype.kind == "u" and ids.dtype.itemsize == 8 and ids.size:
        big = int(np.argmax(ids))
        if ids[big] > np.iinfo(np.int64).max:  # would come back as a negative label
            raise ValueError(f"{name} must be below 2**63 (labels are int64), got "
                             f"{int(ids[big])} at index {big}; renumber the clumps, e.g. with "
                             f"np.unique({name}, return_inverse=True)[1]")
    return np.ascontiguousarray(ids, dtype=np.int64)


def raise_unwrappable(given, bad, name, row=None):
    """The error of row ``bad`` of ``given`` (argument ``name``) too far outside
    the cell to wrap, called ``row`` in the message (default ``bad``: a chunk's
    row names its row in the whole array); nothing when ``bad`` is -1."""
    if bad >= 0:
        raise ValueError(
            f"{name} row {bad if row is None else row} ({given[bad].tolist()}) lies about "
            f"{WRAP_LIMIT:.3g} cell lengths or more outside the cell along a periodic axis: "
            "wrapping it into the cell would keep no significant digit. Give coordinates "
            "within 2**52 cell lengths of the cell")
