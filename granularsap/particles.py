"""Sphere contacts, neighbour pairs and rigid clumps: one-shot conveniences.

``neighbor_pairs``, ``sphere_contacts`` and ``clump_contacts`` are one frame of a
fresh :class:`~granularsap.NeighborSearch` / :class:`~granularsap.ContactSearch`
(``granularsap.search``), so they give exactly what a search gives on every
frame of a trajectory.  For more than one frame, keep a search: it reuses its
buffers, its sort order and (with a ``rebuild_margin``) its Verlet list.

``_search`` below is the earlier ghost-image pipeline over the box broad phase
(``box_overlaps``); the MDAnalysis and ASE drop-ins still call it while they
move onto the public searches.
"""

from __future__ import annotations

import numpy as np

from . import periodic
from ._numba import num_threads
from ._validate import as_coords
from .api import _sphere_candidates
from .kernels import narrow
from .search import ContactSearch, NeighborSearch, as_labels, as_radii

__all__ = ["clump_contacts", "neighbor_pairs", "sphere_contacts"]

_EMPTY_PAIRS = np.empty((0, 2), dtype=np.int64)

#: relative guard added to box half-widths against rounding in ``x +- h``
_GUARD = 64 * np.finfo(np.float64).eps


def _guard(positions, half):
    scale = (np.abs(positions).max() if len(positions) else 0.0) + (
        half.max() if len(half) else 0.0)
    return _GUARD * scale + np.finfo(np.float64).tiny


def _check_range(reach, cell, pbc, what):
    """Raise if a pair could interact with more than one image of the other."""
    widths = periodic.perpendicular_widths(cell)
    for c in np.flatnonzero(pbc):
        # a relative hair of tolerance for the rounding in the widths; pairs whose
        # two images tie at exactly half a width are deduplicated by _search
        if reach > 0.5 * widths[c] * (1.0 + 1e-12):
            raise ValueError(
                f"{what} {reach:.17g} exceeds half the smallest perpendicular cell width "
                f"{0.5 * widths[c]:.17g} (width {widths[c]:.17g} across cell vector {c}); "
                "several periodic images of a pair would be in range. Use a larger "
                "cell (replicate it) or a smaller cutoff; granularsap.ase.neighbor_list "
                "returns every image with its shift")


def _search(positions, rad, skin, cell, pbc, *, n_threads, strict=False,
            minimum_image=True, pos_for_distance=None,
            what="interaction range 2 * max(radii) + skin", split=0, reach_max=None):
    """Core pair search shared by the public functions and the drop-ins.

    Parameters
    ----------
    positions : (n, 3) float64
        Validated positions (not necessarily wrapped).
    rad : (n,) float64
        Per-particle half range: pair ``(i, j)`` is in range iff
        ``d <= rad[i] + rad[j] + skin`` (``<`` if ``strict``).
    cell : (3, 3) float64 or None
    pbc : (3,) bool
    minimum_image : bool or "reduce"
        True: one image per pair (raises if the range needs more), self images
        dropped.  False: every image pair within range (ASE), returned with shifts.
        "reduce": like True, but a range beyond half the cell width is handled by
        searching every image and keeping the nearest one per pair.
    split : int
        If positive, only pairs ``a < split <= b`` (two point sets).
    reach_max : float, optional
        Largest pair range, if smaller than ``2 * max(rad) + skin``.
    pos_for_distance : None or "original"
        Which coordinates the distance is computed from: the wrapped ones
        (default, MDAnalysis) or the caller's own with integer shifts (ASE).

    Returns
    -------
    a, b : (k,) int64
        Owned indices, ``a <= b`` (``a == b`` only for self images).
    shift : (k, 3) int64 or None
        ``S`` such that the separation is ``pos[b] - pos[a] + S @ cell``
        (``pos`` as chosen by ``pos_for_distance``); only when ``minimum_image``
        is False, else None.
    dist : (k,) float64
    wrapped : (n, 3) float64
        Positions the distances refer to (wrapped, or the input).
    """
    n = len(positions)
    half = rad + 0.5 * skin
    periodic_run = cell is not None and bool(np.any(pbc))
    if periodic_run:
        if reach_max is None:
            reach_max = 2.0 * (rad.max() if n else 0.0) + skin
        if minimum_image == "reduce":
            widths = periodic.perpendicular_widths(cell)
            if reach_max <= 0.5 * widths[pbc].min() * (1.0 + 1e-12):
                minimum_image = True
        elif minimum_image:
            _check_range(reach_max, cell, pbc, what)
        wrapped, nshift = periodic.wrap(positions, cell, pbc)
        guard = _guard(wrapped, half)
        reach = rad + (rad.max() if n else 0.0) + skin + 4 * guard
        widths = periodic.perpendicular_widths(cell)
        # rounding guard in fractional units as well
        reach = reach + 1e-12 * widths.max()
        owner, gshift = periodic.ghost_images(wrapped, cell, pbc, reach)
        ghosts = periodic.translate(wrapped[owner], gshift, cell)
        centres = np.concatenate([wrapped, ghosts]) if len(owner) else wrapped
        half_all = np.concatenate([half, half[owner]]) + guard if len(owner) else half + guard
        if pos_for_distance == "original":
            pos_d = positions
        else:
            pos_d = wrapped
            nshift = np.empty((0, 3), np.int64)
    else:
        wrapped = positions
        guard = _guard(positions, half)
        owner = np.empty(0, np.int64)
        gshift = np.empty((0, 3), np.int64)
        centres = positions
        half_all = half + guard
        nshift = np.empty((0, 3), np.int64)
        pos_d = positions
        cell = np.zeros((3, 3)) if cell is None else cell
    if n == 0:
        return (np.empty(0, np.int64), np.empty(0, np.int64), np.empty((0, 3), np.int64),
                np.empty(0, np.float64), pos_d)
    half_all = half_all[:, None]
    lower = np.ascontiguousarray(centres - half_all)
    upper = np.ascontiguousarray(centres + half_all)
    # cubes around spheres: candidates whose inscribed spheres (nearly) touch
    cand = _sphere_candidates(lower, upper, n_threads=n_threads)
    cand = np.ascontiguousarray(cand, dtype=np.int64)

    with num_threads(n_threads) as threads:
        a, b, shift, dist = narrow.narrow_candidates(
            cand, n, np.ascontiguousarray(owner, dtype=np.int64),
            np.ascontiguousarray(gshift, dtype=np.int64), np.ascontiguousarray(pos_d),
            np.ascontiguousarray(nshift), np.ascontiguousarray(cell, dtype=np.float64),
            np.ascontiguousarray(rad), skin, strict=strict,
            self_images=minimum_image is False, want_shift=minimum_image is False,
            split=split, n_threads=threads)
    if periodic_run and minimum_image is not False and len(a):
        widths = periodic.perpendicular_widths(cell)
        if (minimum_image == "reduce"
                or 2.0 * reach_max >= widths[pbc].min() * (1.0 - 1e-9)):
            # range exactly half a width: both images of a pair may tie
            key = a * n + b
            order = np.lexsort((dist, key))
            first = np.ones(len(order), dtype=bool)
            first[1:] = key[order][1:] != key[order][:-1]
            order = order[first]
            a, b, dist = a[order], b[order], dist[order]
    return a, b, shift, dist, pos_d


_as_radii = as_radii


def _pairs(a, b):
    if len(a) == 0:
        return _EMPTY_PAIRS.copy()
    return np.ascontiguousarray(np.stack([a, b], axis=1), dtype=np.int64)


def sphere_contacts(positions, radii, *, skin=0.0, box=None, pbc=None, n_threads=None,
                    return_distances=False):
    """Pairs of spheres closer than the sum of their radii plus ``skin``.

    One frame of a fresh :class:`~granularsap.ContactSearch`: the exact test
    ``d <= r_i + r_j + skin`` in float64.  Radii may differ by orders of
    magnitude (polydisperse packings).

    Parameters
    ----------
    positions : (n, 3) array_like of float
        Sphere centres; need not be wrapped into a periodic cell.
    radii : (n,) array_like of float or float
        Non-negative radii (a scalar applies to every sphere).
    skin : float, optional
        Extra distance added to every pair's contact distance.
    box : None, (6,) or (3, 3) array_like of float, or Cell, optional
        Periodic cell: MDAnalysis ``[lx, ly, lz, alpha, beta, gamma]``, a matrix
        whose rows are the cell vectors, or a :class:`~granularsap.Cell`.
        ``None`` for open boundaries.
    pbc : bool or (3,) bools, optional
        Periodic axes of ``box`` (default: every axis, or the Cell's own).
    n_threads : int, optional
        numba threads for this call (restored afterwards).
    return_distances : bool, optional
        Also return the centre-centre (minimum image) distances.

    Returns
    -------
    pairs : (k, 2) ndarray of int64
        ``i < j`` in every row, each pair once, row order unspecified.
    distances : (k,) ndarray of float64
        Only if ``return_distances``.

    Raises
    ------
    ValueError
        Wrong shapes, NaN/inf, negative radii or skin, an invalid cell, or
        ``2 * max(radii) + skin`` larger than half the smallest perpendicular
        width of the cell.
    TypeError
        Non-numeric input.

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import sphere_contacts
    >>> pos = np.array([[0.0, 0, 0], [1.5, 0, 0], [5.0, 0, 0]])
    >>> sphere_contacts(pos, [1.0, 0.5, 1.0]).tolist()
    [[0, 1]]
    >>> sorted(sphere_contacts(pos, 1.0, box=[6, 6, 6, 90, 90, 90]).tolist())
    [[0, 1], [0, 2]]
    """
    search = ContactSearch(skin=skin, quantities="Pd" if return_distances else "P",
                           n_threads=n_threads)
    return search.update(positions, radii, box, pbc=pbc)


def neighbor_pairs(positions, cutoff, *, box=None, pbc=None, n_threads=None,
                   return_distances=True):
    """All pairs with (minimum image) distance ``d <= cutoff``.

    The same pair set as MDAnalysis
    ``self_capped_distance(positions, max_cutoff=cutoff, box=box)`` (computed in
    float64 rather than MDAnalysis's float32); one frame of a fresh
    :class:`~granularsap.NeighborSearch`.

    Parameters
    ----------
    positions : (n, 3) array_like of float
    cutoff : float
        Non-negative cutoff distance; pairs at exactly ``cutoff`` are included.
    box : None, (6,) or (3, 3) array_like of float, or Cell, optional
        Periodic cell as in :func:`sphere_contacts`.
    pbc : bool or (3,) bools, optional
        Periodic axes of ``box``.
    n_threads : int, optional
    return_distances : bool, optional
        Also return the distances (default True, as MDAnalysis).

    Returns
    -------
    pairs : (k, 2) ndarray of int64
        ``i < j``, each pair once, row order unspecified.
    distances : (k,) ndarray of float64
        Only if ``return_distances``.

    Raises
    ------
    ValueError
        Bad shapes or values, or ``cutoff`` larger than half the smallest
        perpendicular cell width.

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import neighbor_pairs
    >>> pairs, d = neighbor_pairs([[0.0, 0, 0], [1, 0, 0], [3.5, 0, 0]], 2.0)
    >>> pairs.tolist(), d.tolist()
    ([[0, 1]], [1.0])
    """
    search = NeighborSearch(cutoff, quantities="Pd" if return_distances else "P",
                            n_threads=n_threads)
    return search.update(positions, box, pbc=pbc)


def clump_contacts(positions, radii, clump_ids, *, skin=0.0, box=None, pbc=None,
                   n_threads=None):
    """Contacts between rigid clumps (multi-sphere bodies).

    One frame of a fresh :class:`~granularsap.ContactSearch` with clump
    labels: sphere pairs are tested only between different clumps, so
    intra-clump pairs are never returned (and never counted as work).  Each
    sphere pair is taken at its own minimum image, so a clump may straddle
    the cell boundary, its spheres wrapped independently.

    Parameters
    ----------
    positions : (n, 3) array_like of float
        Sphere centres.
    radii : (n,) array_like of float or float
    clump_ids : (n,) array_like of int
        Body label of every sphere (any integers; spheres with equal labels
        form one rigid clump).
    skin : float, optional
    box : None, (6,) or (3, 3) array_like of float, or Cell, optional
    pbc : bool or (3,) bools, optional
    n_threads : int, optional

    Returns
    -------
    sphere_pairs : (k, 2) ndarray of int64
        Sphere index pairs ``i < j`` with ``d <= r_i + r_j + skin`` and
        ``clump_ids[i] != clump_ids[j]``.
    clump_pairs : (m, 2) ndarray of int64
        Pairs of clump labels (values of ``clump_ids``), smaller label first,
        with at least one sphere contact; each once, sorted.

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import clump_contacts
    >>> pos = [[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 0, 0]]
    >>> sp, cp = clump_contacts(pos, 0.5, [7, 7, 8, 9])
    >>> sp.tolist(), cp.tolist()
    ([[1, 2]], [[7, 8]])
    """
    positions = as_coords(positions, "positions")
    ids = as_labels(clump_ids, len(positions))
    sp = ContactSearch(skin=skin, quantities="P", n_threads=n_threads).update(
        positions, radii, box, pbc=pbc, clump_ids=ids)
    if len(sp) == 0:
        return sp, _EMPTY_PAIRS.copy()
    cp = np.sort(np.stack([ids[sp[:, 0]], ids[sp[:, 1]]], axis=1), axis=1)
    return sp, np.unique(cp, axis=0).astype(np.int64)
