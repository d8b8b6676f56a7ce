"""Sphere contacts, neighbour pairs and rigid clumps: one-shot conveniences.

``neighbor_pairs``, ``sphere_contacts`` and ``clump_contacts`` are one frame of a
fresh :class:`~granularsap.NeighborSearch` / :class:`~granularsap.ContactSearch`
(``granularsap.search``), so they give exactly what a search gives on every
frame of a trajectory.  For more than one frame, keep a search: it reuses its
buffers, its sort order and (with a ``rebuild_margin``) its Verlet list.
"""

from __future__ import annotations

import numpy as np

from ._validate import as_coords
from .search import ContactSearch, NeighborSearch, as_labels

__all__ = ["clump_contacts", "neighbor_pairs", "sphere_contacts"]

_EMPTY_PAIRS = np.empty((0, 2), dtype=np.int64)


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
