"""Slow, readable reference implementations the engine is checked against.

Nothing here is clever: every function is the definition written as loops
over all pairs (vectorised per row with numpy), so it can be trusted on small
inputs.
"""

from __future__ import annotations

import numpy as np


def _as_pair_array(pairs):
    if len(pairs) == 0:
        return np.empty((0, 2), dtype=np.int64)
    return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)


def sort_pairs(pairs):
    """Return ``pairs`` (k, 2) in lexicographic row order, as int64."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order]


def brute_box_overlaps(lower, upper):
    """All pairs ``i < j`` of closed boxes that overlap on every axis."""
    lower = np.asarray(lower, dtype=np.float64)
    upper = np.asarray(upper, dtype=np.float64)
    n = len(lower)
    out = []
    for i in range(n):
        j = np.arange(i + 1, n)
        ok = np.all((lower[i] <= upper[j]) & (lower[j] <= upper[i]), axis=1)
        out.extend((i, int(jj)) for jj in j[ok])
    return _as_pair_array(out)


def _image_ranges(pos, cell, pbc, reach_max):
    """Integer image ranges per cell vector that hold every image within
    ``reach_max`` of any point (generously: the points' span is added)."""
    span = np.ptp(pos, axis=0).max() if len(pos) else 0.0
    reps = []
    for k in range(3):
        if not pbc[k]:
            reps.append(range(0, 1))
            continue
        # the spacing of the lattice planes across vector k: its part normal to the
        # other periodic vectors (an open axis's vector may be zero: an ASE slab)
        others = np.array([cell[j] for j in range(3) if j != k and pbc[j]]).reshape(-1, 3)
        v = cell[k]
        if len(others):
            v = v - others.T @ np.linalg.lstsq(others.T, v, rcond=None)[0]
        width = np.linalg.norm(v)
        m = int(np.ceil((reach_max + 2 * span) / width)) + 1
        reps.append(range(-m, m + 1))
    return reps


def brute_image_pairs(positions, cutoff, cell=None, pbc=(True, True, True), radii=None):
    """Pairs ``i < j`` with some periodic image of ``j`` within reach of ``i``.

    Reach is ``cutoff`` or, with ``radii``, ``r_i + r_j + cutoff``; the test is
    ``d <= reach`` in float64.  ``cell`` is a (3, 3) matrix of cell vectors (rows),
    ``None`` for open boundaries.  Every image combination that could matter is
    enumerated (no minimum-image shortcut), so any cutoff and any tilt work.
    Returns ``(pairs, distances)`` with the smallest qualifying distance.
    """
    pos = np.asarray(positions, dtype=np.float64)
    n = len(pos)
    rad = np.zeros(n) if radii is None else np.asarray(radii, dtype=np.float64)
    reach_max = cutoff + (2 * rad.max() if n else 0.0)
    shifts = [np.zeros(3)]
    if cell is not None:
        cell = np.asarray(cell, dtype=np.float64)
        reps = _image_ranges(pos, cell, pbc, reach_max)
        shifts = [a * cell[0] + b * cell[1] + c * cell[2]
                  for a in reps[0] for b in reps[1] for c in reps[2]]
    shifts = np.array(shifts)
    out, dist = [], []
    for i in range(n):
        for j in range(i + 1, n):
            d = np.sqrt((((pos[j] + shifts) - pos[i]) ** 2).sum(axis=1)).min()
            if d <= rad[i] + rad[j] + cutoff:
                out.append((i, j))
                dist.append(d)
    return _as_pair_array(out), np.asarray(dist, dtype=np.float64)


def brute_full_image_list(positions, cutoff, cell=None, pbc=(True, True, True), radii=None,
                          self_interaction=False):
    """Every ``(i, j, S)`` with ``|pos[j] - pos[i] + S @ cell| < reach`` (ASE semantics).

    Full list (both directions), strict ``<``; ``reach`` is ``cutoff`` or, with
    ``radii``, ``r_i + r_j`` (ASE per-atom cutoffs; ``cutoff`` ignored).  Positions
    are used as given (not wrapped), like ASE's ``D``.  ``(i, i, 0)`` is listed
    only with ``self_interaction``.  Returns ``(i, j, S, d)`` sorted by
    ``(i, j, S)``.
    """
    pos = np.asarray(positions, dtype=np.float64)
    n = len(pos)
    rad = None if radii is None else np.asarray(radii, dtype=np.float64)
    reach_max = cutoff if rad is None else (2 * rad.max() if n else 0.0)
    reps = [range(0, 1)] * 3
    if cell is not None:
        cell = np.asarray(cell, dtype=np.float64)
        reps = _image_ranges(pos, cell, pbc, reach_max)
    shifts = np.array([(a, b, c) for a in reps[0] for b in reps[1] for c in reps[2]],
                      dtype=np.int64)
    vecs = shifts @ (cell if cell is not None else np.zeros((3, 3)))
    ii, jj, ss, dd = [], [], [], []
    for i in range(n):
        for j in range(n):
            D = pos[j] - pos[i] + vecs
            d = np.sqrt((D * D).sum(axis=1))
            reach = cutoff if rad is None else rad[i] + rad[j]
            ok = d < reach
            if i == j:
                zero = (shifts == 0).all(axis=1)
                ok &= ~zero
                if self_interaction:
                    ok |= zero
            for k in np.flatnonzero(ok):
                ii.append(i)
                jj.append(j)
                ss.append(shifts[k])
                dd.append(d[k])
    i_ = np.asarray(ii, dtype=np.int64)
    j_ = np.asarray(jj, dtype=np.int64)
    s_ = np.asarray(ss, dtype=np.int64).reshape(-1, 3)
    d_ = np.asarray(dd, dtype=np.float64)
    order = np.lexsort((s_[:, 2], s_[:, 1], s_[:, 0], j_, i_))
    return i_[order], j_[order], s_[order], d_[order]
