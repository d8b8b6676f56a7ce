"""Drop-in replacement for ``MDAnalysis.lib.nsgrid.FastNS`` on the stateful engine.

Swap the import and nothing else changes::

    # from MDAnalysis.lib.nsgrid import FastNS
    from granularsap.mda import FastNS

    ns = FastNS(cutoff, coords, box=u.dimensions)
    pairs = ns.self_search().get_pairs()               # (k, 2), i < j
    dist = ns.self_search().get_pair_distances()       # (k,), float64
    cross = ns.search(query_coords).get_pairs()        # (query index, coords index)

Semantics follow MDAnalysis's ``nsgrid.pyx`` (MDAnalysis 2.11):

* pairs within ``d <= cutoff`` (inclusive); with ``pbc=True`` the minimum image
  in the cell of ``box`` (MDAnalysis ``[lx, ly, lz, alpha, beta, gamma]``, shape
  ``(6,)``, required even for ``pbc=False``, where MDAnalysis uses it as a
  bounding box);
* ``self_search()`` gives every pair of ``coords`` once; ``search(q)`` gives the
  pairs ``(index in q, index in coords)``;
* results are :class:`NSResults` with ``get_pairs()`` (int64 ``(k, 2)``) and
  ``get_pair_distances()`` (float64 ``(k,)``), plus ``get_indices()`` and
  ``get_distances()`` (per-atom lists, the API of MDAnalysis before 1.0).

Differences, all documented in docs/stateful-dropins.md:

* pairs and distances are decided in float64 on the coordinates as given
  (float32 input is widened exactly, float64 input is accepted, where
  MDAnalysis requires float32 and computes separations in float32 after
  wrapping).  Distances therefore differ from MDAnalysis's by float32 rounding
  (relative 1e-6 or less), and a pair within that distance of ``cutoff`` can be
  decided differently: the float64 answer is the exact one for the given
  numbers;
* ``self_search`` pairs always have ``i < j`` (MDAnalysis orients them by its
  cell lists) and rows are sorted; MDAnalysis's order is unspecified;
* ``pbc=False`` gives true open-boundary distances whatever the box: MDAnalysis
  wraps coordinates outside its bounding box into it (its documentation says the
  result is then wrong) and refuses cutoffs beyond half of it, granularsap needs
  neither;
* with ``pbc=True`` the largest cutoff is half the smallest perpendicular width
  of the cell (MDAnalysis's own limit is computed from lengths and angles and
  can be smaller); the minimum image is the true nearest image even in strongly
  tilted cells.

A ``FastNS`` keeps one engine search for ``self_search`` and one for
``search``, so repeated searches of one object reuse their buffers; ``search``
is the engine's cross-set query (``NeighborSearch.query``), whose grid of
``coords`` is built at the first ``search`` and kept for the next ones, as
MDAnalysis keeps its grid.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_coords, as_scalar
from ..cell import Cell
from ..search import ContactSearch, NeighborSearch

__all__ = ["FastNS", "NSResults"]


class NSResults:
    """Pairs of one search, like ``MDAnalysis.lib.nsgrid.NSResults``.

    Parameters
    ----------
    pairs : (k, 2) ndarray of int64
    distances : (k,) ndarray of float64
    n_rows : int
        Number of query atoms (the first index of every pair ranges over them).
    symmetric : bool
        A self search: :meth:`get_indices` lists each pair from both atoms.
    """

    def __init__(self, pairs, distances, n_rows, symmetric):
        self._pairs = pairs
        self._distances = distances
        self._n_rows = int(n_rows)
        self._symmetric = bool(symmetric)

    def get_pairs(self):
        """``(k, 2)`` int64 pairs within the cutoff (a fresh array).

        For ``self_search``, ``i < j``; for ``search(q)``, ``(index in q, index
        in coords)``.  Rows are sorted.
        """
        return self._pairs.copy()

    def get_pair_distances(self):
        """``(k,)`` float64 distances, row for row with :meth:`get_pairs`."""
        return self._distances.copy()

    def get_indices(self):
        """Neighbours of every query atom: a list of int64 arrays, sorted.

        For ``self_search`` each pair is listed from both atoms.  (The
        MDAnalysis API before version 1.0.)
        """
        return self._per_atom_list(want_second=True)

    def get_distances(self):
        """Distances matching :meth:`get_indices`, one float64 array per atom."""
        return self._per_atom_list(want_second=False)

    def _per_atom_list(self, want_second):
        first, second, vals = self._pairs[:, 0], self._pairs[:, 1], self._distances
        if self._symmetric:
            first, second = np.concatenate([first, second]), np.concatenate([second, first])
            vals = np.concatenate([vals, vals])
            order = np.lexsort((second, first))
            first, second, vals = first[order], second[order], vals[order]
        out = second if want_second else vals
        cuts = np.searchsorted(first, np.arange(self._n_rows + 1))
        return [out[cuts[a]:cuts[a + 1]].copy() for a in range(self._n_rows)]


class FastNS:
    """Grid search of pairs within ``cutoff``, like ``MDAnalysis.lib.nsgrid.FastNS``.

    Parameters
    ----------
    cutoff : float
        Pairs with ``d <= cutoff``.
    coords : (n, 3) array_like of float
        The coordinates searched (float32 as MDAnalysis wants, or float64), or
        an AtomGroup.
    box : (6,) array_like of float
        ``[lx, ly, lz, alpha, beta, gamma]``.  Required (MDAnalysis asks for a
        pseudo box when ``pbc=False``; granularsap then only validates it).
    pbc : bool, optional
        Minimum-image distances in the cell of ``box``.
    n_threads : int, optional
        numba threads for the searches (results do not depend on it).

    Raises
    ------
    ValueError
        A negative cutoff, coordinates or box of the wrong shape, a box length
        that is not positive, or (``pbc=True``) a cutoff beyond half the
        smallest perpendicular width of the cell.

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap.mda import FastNS
    >>> coords = np.array([[0.5, 0, 0], [9.5, 0, 0], [5, 5, 5]], dtype=np.float32)
    >>> ns = FastNS(1.5, coords, box=np.array([10, 10, 10, 90, 90, 90], np.float32))
    >>> res = ns.self_search()
    >>> res.get_pairs().tolist(), res.get_pair_distances().tolist()
    ([[0, 1]], [1.0])
    >>> ns.search(np.array([[5, 5, 6]], np.float32)).get_pairs().tolist()
    [[0, 2]]
    """

    def __init__(self, cutoff, coords, box, pbc=True, *, n_threads=None):
        value = as_scalar(cutoff, "cutoff", nonnegative=False)
        if value < 0:  # MDAnalysis's words first: code and tests match them
            raise ValueError(f"Cutoff must be positive: cutoff must be non-negative, got "
                             f"{value!r}")
        self.cutoff = value
        self._coords = np.array(as_coords(coords, "coords"))  # a copy, as MDAnalysis
        if not isinstance(pbc, (bool, np.bool_)):
            raise TypeError(f"pbc must be True or False, got {pbc!r}")
        self.pbc = bool(pbc)
        arr = np.asarray(box) if box is not None else None
        if arr is None or arr.shape != (6,):
            got = "None" if arr is None else f"shape {arr.shape}"
            raise ValueError("box must be [lx, ly, lz, alpha, beta, gamma] (shape (6,)), got "
                             f"{got}; for pbc=False give a bounding box such as "
                             "[lx, ly, lz, 90, 90, 90]")
        cell = Cell.coerce(arr, name="box")
        self._cell = cell if self.pbc else None
        if self.pbc:
            half = 0.5 * float(np.min(cell.perpendicular_widths))
            if self.cutoff > half:
                # "Cutoff {cutoff} too large for box (max ...)" with the cutoff as given,
                # as MDAnalysis words it
                raise ValueError(f"Cutoff {cutoff} too large for box (max {half!r}): at most "
                                 "half the smallest perpendicular cell width")
        self._self = ContactSearch(skin=self.cutoff, quantities="Pd", n_threads=n_threads)
        self._cross = NeighborSearch(self.cutoff, quantities="Pd", n_threads=n_threads)
        self._self_result = None

    def self_search(self):
        """All pairs of ``coords`` within the cutoff, each once with ``i < j``.

        Returns
        -------
        NSResults
        """
        if self._self_result is None:
            n = len(self._coords)
            pairs, dist = self._self.update(self._coords, np.zeros(n), self._cell)
            order = np.lexsort((pairs[:, 1], pairs[:, 0]))
            self._self_result = NSResults(pairs[order], dist[order], n, symmetric=True)
        return self._self_result

    def search(self, search_coords):
        """Pairs ``(index in search_coords, index in coords)`` within the cutoff.

        Parameters
        ----------
        search_coords : (m, 3) array_like of float
            Query coordinates (an AtomGroup is accepted too).

        Returns
        -------
        NSResults
        """
        query = as_coords(search_coords, "search_coords")
        # the engine's cross-set query: a grid of coords, kept while they are the
        # same, visited by the query points
        pairs, dist = self._cross.query(query, self._coords, self._cell)
        order = np.lexsort((pairs[:, 1], pairs[:, 0]))
        return NSResults(pairs[order], dist[order], len(query), symmetric=False)
