"""The column plan: how a frame's particles are cut into columns along two axes
for the column sweep, which pairs of columns meet (the stencil), whether widely
spread radii take two levels of columns, how the columns are cut into chunks of
parallel work, and how many candidates the plan predicts per pair (what the
chooser reads).  Pure functions of the frame: the same frame gets the same plan
in every process, with any thread count."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..kernels import grid

#: particles per chunk of parallel work (chunk boundaries never depend on threads)
CHUNK = 2048
MAX_CHUNKS = 1024
#: columns along one axis at most
MAX_BINS = 1 << 16


class ColumnPlan(NamedTuple):
    """The columns of one build (``plan_columns``)."""

    #: lower corner of the columns along open axes, in cell fractions (0 on
    #: periodic ones), and columns per unit of fraction along axes 0 and 1
    lo: np.ndarray
    inv_f: np.ndarray
    #: columns along axes 0 and 1
    nb0: int
    nb1: int
    #: (s, 2) column offsets a column meets forward (half of the neighbourhood),
    #: and the full neighbourhood of the large particles of two levels
    stencil: np.ndarray
    stencil_big: np.ndarray
    #: column layers the large particles' neighbourhood reaches along axes 0, 1
    layers_big: tuple


def wrap_chunks(n):
    """Chunks of the wrap of ``n`` particles (its largest coordinate and shift
    are reduced per chunk): a function of ``n`` alone."""
    return int(min(MAX_CHUNKS, max(1, n // CHUNK)))


def open_span(t, pbc):
    """(lo, span): the lower corner and the extent of the wrapped fractions ``t``
    along open axes (0 and 1 along periodic ones)."""
    lo = np.zeros(3)
    span = np.ones(3)
    for c in range(3):
        if not pbc[c]:
            lo[c] = t[:, c].min()
            span[c] = t[:, c].max() - lo[c]
    return lo, span


def column_counts(span, delta, n):
    """Columns along axes 0 and 1: one range ``delta`` (in fractions) wide where the
    span allows, halved along the longer side while there are more columns than
    particles (``n``)."""
    nb = [1, 1]
    for c in range(2):
        if span[c] > 0:
            with np.errstate(over="ignore", divide="ignore"):
                ratio = span[c] / delta[c] if delta[c] > 0 else math.inf
            nb[c] = int(max(1.0, math.floor(min(ratio, float(MAX_BINS)))))
    while nb[0] * nb[1] > max(1, n) and max(nb) > 1:
        c = 0 if nb[0] >= nb[1] else 1
        nb[c] = max(1, nb[c] // 2)
    return nb


def wide_columns(nb, span, delta, n):
    """Columns along axes 0 and 1 widened for a sparse frame.

    A particle's window in a stencil column costs a fixed setup (finding it,
    entering and leaving its loops) besides its candidates, so columns one
    range wide pay mostly setups when they hold few particles along the
    window: widely spread radii (the range is set by the largest) or a dilute
    frame.  The expected candidates of a window, ``n / (nb0 nb1)`` particles
    per column times the window's share ``delta[2] / span[2]`` of the sweep
    axis, set how much wider the columns get: by ``sqrt(WINDOW_TARGET /
    that)``, at most ``MAX_WIDEN`` times (polydisperse spheres at volume
    fraction 0.3, radii 0.3 to 3: about 5 per window, columns about twice as
    wide).  Only frames a small-frame kernel may take (``wide`` of
    ``plan_columns``): the per-particle windows of ``grid._small_sweep`` skip
    the stencil columns out of a particle's own reach, the column-pair
    windows of ``grid._sweep_chunk`` do not (on wider columns they test
    several times the candidates).  The arithmetic is ``grid.wide_columns``,
    which ``grid._small_plan`` calls too, so that a small frame gets the
    general path's plan, rows in the same order.

    Examples
    --------
    >>> import numpy as np
    >>> wide_columns([6, 6], np.ones(3), np.full(3, 0.17), 1000)
    [2, 2]
    """
    nb0, nb1 = grid.wide_columns(int(nb[0]), int(nb[1]), int(n), float(delta[2]),
                                 float(span[2]))
    return [nb0, nb1]


def plan_columns(lo, span, pbc, widths, rmax, r_small, reach, guard, far, n, wide=False):
    """The column plan of a frame of ``n`` particles whose wrapped fractions start
    at ``lo`` and extend ``span`` (``open_span``), in a cell of perpendicular
    ``widths`` and periodic axes ``pbc``.  Columns are one range ``2 r + reach +
    guard`` wide, ``r`` the largest radius (``rmax``) or that of the small
    particles (``r_small``, two levels), or, with ``wide``, wider in a sparse
    frame of one level (``wide_columns``); the stencil reaches as many columns as
    the range spans.  ``far``: coordinates far beyond the range along an open
    axis, where a column index may be off by its rounding (the stencil covers
    it)."""
    bin_range = 2.0 * (rmax if r_small is None else r_small) + reach + guard
    delta = bin_range / widths
    delta_big = (2.0 * rmax + reach + guard) / widths
    nb = column_counts(span, delta, n)
    if wide and r_small is None:
        nb = wide_columns(nb, span, delta, n)
    inv_f = np.zeros(3)
    layers = []
    layers_big = []
    for c in range(2):
        f = float(span[c]) / nb[c]
        with np.errstate(over="ignore", divide="ignore"):
            inv_f[c] = nb[c] / span[c] if span[c] > 0 else 0.0
        if not math.isfinite(inv_f[c]):  # a subnormal span: one column
            nb[c], inv_f[c], f = 1, 0.0, 0.0
        # (layers capped: a range beyond 2**62 columns is all of an open axis)
        d_c, db_c = float(delta[c]), float(delta_big[c])
        if far and not pbc[c]:
            # a column index is rounded by at most 2 eps nb: the layers cover it
            pad = 8.0 * np.finfo(np.float64).eps * nb[c] * f
            d_c, db_c = d_c + pad, db_c + pad
        L = 1 if (f >= d_c or f == 0) else math.ceil(min(d_c / f, 2.0 ** 62))
        L_big = 1 if (f >= db_c or f == 0) else math.ceil(min(db_c / f, 2.0 ** 62))
        if not pbc[c]:
            L = min(L, nb[c] - 1)
            L_big = min(L_big, nb[c] - 1)
        layers.append(L)
        layers_big.append(L_big)
    stencil = [(o0, o1) for o0 in range(-layers[0], layers[0] + 1)
               for o1 in range(-layers[1], layers[1] + 1)
               if o0 > 0 or (o0 == 0 and o1 > 0)]
    stencil = np.array(stencil, np.int64).reshape(-1, 2)
    stencil_big = np.array([(o0, o1) for o0 in range(-layers_big[0], layers_big[0] + 1)
                            for o1 in range(-layers_big[1], layers_big[1] + 1)],
                           np.int64).reshape(-1, 2)
    return ColumnPlan(lo, inv_f, nb[0], nb[1], stencil, stencil_big, tuple(layers_big))


def chunk_columns(occ, nb0, nb1, n):
    """Chunks of whole columns with about equal candidate counts, estimated as a
    column's particles (``occ``) times those of its 3 x 3 neighbourhood (uniform
    frames: equal particle counts); the column boundaries of the chunks. They
    depend on the input only, never on the thread count."""
    ncol = nb0 * nb1
    n_chunks = int(min(ncol, max(1, n // CHUNK), MAX_CHUNKS))
    occ = occ.reshape(nb0, nb1).astype(np.float64)
    near = occ.copy()
    for s0 in (-1, 0, 1):
        for s1 in (-1, 0, 1):
            if s0 or s1:
                near += np.roll(occ, (s0, s1), axis=(0, 1))
    weight = np.zeros(ncol + 1)
    np.cumsum((occ * near).ravel(), out=weight[1:])
    targets = np.arange(1, n_chunks) * (weight[-1] / n_chunks)
    cuts = np.searchsorted(weight, targets, side="left")
    return np.unique(np.concatenate([[0], cuts, [ncol]])).astype(np.int64)


def octave16(v):
    """``v`` rounded to the nearest power of two of a sixteenth octave, ``2**(k /
    16)``, for the cost model's volumes (0, inf and NaN as they are)."""
    if not 0.0 < v < math.inf:
        return v
    return 2.0 ** (round(16.0 * math.log2(v)) / 16.0)


def level_split(rad, rmax, reach, n, volume):
    """Radius up to which particles are "small" on a two-level column grid, or None
    for one level.

    Cost model of one frame, per particle: a visit of a stencil column costs
    about as much as ten candidates (setting up the window and leaving its
    loops).  Small particles pair among themselves on columns one range
    ``w = 2 r + reach`` wide (5 visits, about ``4.5 rho w^3`` candidates), each
    large one visits a full stencil of the range ``R = 2 rmax + reach``
    (``(2 ceil(R / w) + 1)^2`` visits, about ``rho (2 R + w)^2 2 R``
    candidates).  The split is the radius quantile of least cost, kept only if
    it saves a quarter.
    """
    if n < 1000 or not volume > 0 or not rmax > 0:
        return None
    rho = n / volume
    big_range = 2.0 * rmax + reach
    visit = 10.0

    def cost(r_c, n_big):
        w = 2.0 * r_c + reach
        small = 4.5 * rho * w ** 3 + 5 * visit
        layers = math.ceil(big_range / w)
        large = rho * (2.0 * big_range + w) ** 2 * 2.0 * big_range + (
            (2 * layers + 1) ** 2 * visit)
        return small * (n - n_big) + large * n_big

    try:  # (a cost figure only: a range whose powers overflow takes one level)
        single = cost(rmax, 0)
    except OverflowError:
        return None
    best, choice = single, None
    sorted_r = np.sort(rad)
    for qtl in (0.5, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99):
        r_c = float(sorted_r[int(qtl * (n - 1))])
        if not 0.0 < r_c < rmax:
            continue
        n_big = n - int(np.searchsorted(sorted_r, r_c, side="right"))
        try:
            c = cost(r_c, n_big)
        except OverflowError:
            continue
        if c < best:
            best, choice = c, r_c
    return choice if best < single * 0.75 else None


def predict_cpp(occ, n_stencil, n_stencil_big, widths, span, volume, rad, skin, reach,
                 rmax, r_small):
    """Candidates the column sweep will test per pair it finds, predicted from the
    column plan before the sweep runs (a deterministic function of the frame).

    Candidates: every particle of a column meets the particles of its stencil
    columns (``occ`` of its own column each, the local density) inside a
    window ``2 (2 r + reach) / w_2`` of the sweep axis, its own column forward
    only; with two levels the large ones walk the full wide stencil with the
    largest window.  Pairs: the same local density over the column volume
    times the mean volume of a pair's range sphere, ``4/3 pi E[(a_i + a_j)^3]
    = 4/3 pi (2 m3 + 6 m1 m2)`` from the moments of ``a = r + skin / 2``.
    Returns (candidates per pair, candidates per particle), or (0, 0) without
    particles or volume.
    """
    n = len(rad)
    if n == 0 or not volume > 0:
        return 0.0, 0.0
    s2 = float((occ * occ).sum())

    def window(r):
        return min(1.0, 2.0 * (2.0 * r + reach) / widths[2] / span[2])

    if r_small is None:
        per = (n_stencil + 0.5) * window(rmax)
    else:
        n_big = int(np.count_nonzero(rad > r_small))
        per = ((n - n_big) * (n_stencil + 0.5) * window(r_small)
               + n_big * n_stencil_big * window(rmax)) / n
    cand = s2 * per
    # plain reductions, not BLAS (np.dot): BLAS threads would spin on the
    # cores the parallel kernels are about to use
    a = rad + 0.5 * skin
    a2 = a * a
    m1 = float(a.sum()) / n
    m2 = float(a2.sum()) / n
    m3 = float((a2 * a).sum()) / n
    sphere = 4.0 / 3.0 * math.pi * (2.0 * m3 + 6.0 * m1 * m2)
    pairs = 0.5 * s2 * len(occ) / volume * sphere
    if not pairs > 0:
        return math.inf, cand / n
    return cand / pairs, cand / n

