"""Kernels of :class:`granularsap.ContactList`: whether a kept list still holds
every contact (no sphere moved too far, no radius changed), and the
separations of the listed pairs on the positions of a step.

The separations follow the engine's one arithmetic (docs/cells.md,
"Arithmetic"; ``common.separation_between``): for the pair ``(i, j)`` with
integer image shift ``S``, ``D_c = (x[j, c] - x[i, c]) + S0 cell[0, c] + S1
cell[1, c] + S2 cell[2, c]`` added in that order and ``d = sqrt(D . D)``, so
the listed pairs with ``d <= (r_i + r_j) + skin`` are the contacts a
``ContactSearch`` finds on the same step, with the same ``d`` and ``D`` bit
for bit.
"""

from __future__ import annotations

import math

import numba

from .._numba import ijit, jit, pjit, serial_twin
from .common import separation_between

__all__ = ["keep_build", "kept_list_state", "separations", "separations_serial"]



@jit
def keep_build(x, radii, ids, x_keep, radii_keep, ids_keep):
    """Copy a build's positions, radii and ids (``ids`` may be empty) into the
    kept arrays, in one pass; returns (largest |coordinate|, largest radius),
    0.0 for no rows (what the displacement limit needs of them)."""
    xf = x.reshape(-1)
    kf = x_keep.reshape(-1)
    big = 0.0
    for k in range(xf.shape[0]):
        v = xf[k]
        kf[k] = v
        big = max(big, abs(v))
    rmax = 0.0
    for s in range(radii.shape[0]):
        radii_keep[s] = radii[s]
        rmax = max(rmax, radii[s])
    for s in range(ids.shape[0]):
        ids_keep[s] = ids[s]
    return big, rmax

@jit
def kept_list_state(x, x_built, radii, radii_built, ids, ids_built, sc, limit2):
    """Why a kept list no longer holds every contact: 0 while every row of ``x``
    is within the limit of ``x_built`` (Euclidean: ``|sc (x - x_built)|^2 <=
    limit2``, ``sc`` a power of two that keeps the squares in range; with
    ``limit2 == 0``, not moved at all) and ``radii`` and ``ids`` equal
    ``radii_built`` and ``ids_built``; 1 when a row moved farther (NaN and inf
    count as moved); 2 when a radius differs, 3 when an id does.  Rows alike in
    all (``ids`` may be empty).  No early exit: each loop is one vectorised
    reduction, which reads the rows faster than a branch per row would."""
    changed = 0
    for s in range(radii.shape[0]):
        changed += radii[s] != radii_built[s]
    if changed:
        return 2
    for s in range(ids.shape[0]):
        changed += ids[s] != ids_built[s]
    if changed:
        return 3
    # the rows as one flat array: the loads of three coordinates interleaved,
    # which vectorise where a two-dimensional index does not
    xf = x.reshape(-1)
    bf = x_built.reshape(-1)
    moved = 0
    if limit2 == 0.0:  # no room at all: any change of a coordinate
        for k in range(xf.shape[0]):
            moved += xf[k] != bf[k]
        return 1 if moved else 0
    if sc == 1.0:  # the common case without the scaling (2.4 against 3.1 us at 2,000 rows)
        for s in range(x.shape[0]):
            k = 3 * s
            d0 = xf[k] - bf[k]
            d1 = xf[k + 1] - bf[k + 1]
            d2 = xf[k + 2] - bf[k + 2]
            moved += not d0 * d0 + d1 * d1 + d2 * d2 <= limit2
        return 1 if moved else 0
    for s in range(x.shape[0]):
        k = 3 * s
        d0 = (xf[k] - bf[k]) * sc
        d1 = (xf[k + 1] - bf[k + 1]) * sc
        d2 = (xf[k + 2] - bf[k + 2]) * sc
        moved += not d0 * d0 + d1 * d1 + d2 * d2 <= limit2
    return 1 if moved else 0


#: squared separations between these are exact as computed: no square that
#: matters is subnormal, none overflows
_SMALL_Q = 2.0 ** -900
_LARGE_Q = 2.0 ** 900


@ijit
def _scaled_norm(dx, dy, dz):
    """``|D|`` as float64 with an unbounded exponent would give it: the row scaled
    by the power of two of its largest component (exact), as the searches do
    where squares would underflow or overflow (docs/cells.md, "Magnitudes in one
    frame")."""
    m = max(abs(dx), abs(dy), abs(dz))
    if m == 0.0 or not m < math.inf:
        return m
    e = math.frexp(m)[1]
    u0 = math.ldexp(dx, -e)
    u1 = math.ldexp(dy, -e)
    u2 = math.ldexp(dz, -e)
    return math.ldexp(math.sqrt(u0 * u0 + u1 * u1 + u2 * u2), e)


@pjit
def separations(x, pairs, shifts, cell, d, vec):
    """``d[k]`` and ``vec[k]`` of the listed pair ``pairs[k]`` with image shift
    ``shifts[k]``, on the positions ``x`` (the module's arithmetic)."""
    for k in numba.prange(pairs.shape[0]):
        dx, dy, dz = separation_between(x, pairs[k, 0], x, pairs[k, 1], cell, shifts[k, 0],
                                        shifts[k, 1], shifts[k, 2])
        vec[k, 0] = dx
        vec[k, 1] = dy
        vec[k, 2] = dz
        q = dx * dx + dy * dy + dz * dz
        if _SMALL_Q <= q <= _LARGE_Q:
            d[k] = math.sqrt(q)
        else:
            d[k] = _scaled_norm(dx, dy, dz)


#: the serial build of ``separations``, for lists too short to share out
separations_serial = serial_twin(separations)
