"""Stateful neighbour and contact searches for particles over a sequence of frames.

:class:`NeighborSearch` (pairs with ``d <= cutoff``) and :class:`ContactSearch`
(pairs with ``d <= r_i + r_j + skin``, optional rigid-clump labels) are the
engine every particle function of granularsap goes through: the one-shot
functions (``neighbor_pairs``, ``sphere_contacts``, ``clump_contacts``), the
MDAnalysis and ASE drop-ins, the trajectory pipeline and the benchmark are
conveniences over them.

Between calls a search keeps what the frames allow (see ``kernels/grid.py``
for the algorithm):

* every buffer: wrapped positions, the column order, the Verlet list and the
  output arrays are allocated once and reused while the particle count and
  the output size allow;
* the column order of the last build: the next build sorts from it, so a
  frame whose particles moved a little sorts in close to linear time;
* a Verlet list: the pairs within the range plus ``rebuild_margin``.  While
  no particle has moved more than ``rebuild_margin / 2`` since the list was
  built (and the cell, the particle count, the radii and the labels are the
  same), a frame only re-tests the list.  This is the "skin" of LAMMPS's
  ``neighbor`` command and of ASE's ``NeighborList``; it is called
  ``rebuild_margin`` here because ``skin`` already means the contact
  distance added to ``r_i + r_j``.

Every frame's answer equals a fresh one-shot call exactly: the same pair set
and the same float64 distances, bit for bit, whether the frame rebuilt or not
and whatever the thread count.

The engine is in named parts, one module each (docs/architecture.md):
``frame`` (the scan, scale and range checks of a frame), ``plan`` (the column
plan), ``chooser`` (the candidate path), ``columns`` (the column sweep as a
candidate builder), ``verlet`` (the kept Verlet list), ``outputs`` (the
alternating output buffers), ``cross`` (the cross-set query's kept grid) and
``engine`` (``SearchEngine``, which runs a frame through them).
"""

from __future__ import annotations

import math

import numpy as np

from .._validate import as_coords, as_scalar
from .engine import SearchEngine
from .frame import as_labels, as_radii

__all__ = ["ContactSearch", "NeighborSearch", "as_labels", "as_radii"]


class NeighborSearch(SearchEngine):
    """Pairs of particles within ``cutoff`` over a sequence of frames.

    Parameters
    ----------
    cutoff : float
        Pairs with (minimum-image) distance ``d <= cutoff`` are returned.
    rebuild_margin : float, optional
        Verlet margin: the kept candidate list holds every pair within
        ``cutoff + rebuild_margin`` and is rebuilt only when some particle has
        moved more than ``rebuild_margin / 2`` since it was built (or the cell,
        the particle count changed).  0 rebuilds every frame, reusing buffers.
    quantities : str, optional
        What :meth:`update` returns, in this order: ``'P'`` pairs ``(k, 2)``
        int64 with ``i < j``; ``'i'``, ``'j'`` their columns; ``'d'`` distances;
        ``'D'`` vectors from ``i`` to ``j``; ``'S'`` integer lattice shifts with
        ``D = positions[j] - positions[i] + S @ cell``.  Default ``'Pd'``.
    layout : {"pairs", "csr"}, optional
        ``"csr"``: :meth:`update` returns the half list by particle instead,
        ``(offsets (n + 1,), neighbors[, distances])``: the partners ``j > i``
        of particle ``i`` are ``neighbors[offsets[i]:offsets[i + 1]]``.
    periodic_images : {"minimum", "all"}, optional
        ``"minimum"``: one image per pair, and ``cutoff`` must not exceed half
        the smallest perpendicular width of the cell.  ``"all"``: every image
        within range, including a particle's own images (the ASE convention;
        ask for ``'S'`` to tell them apart).
    include_cutoff : bool, optional
        True (default): ``d <= cutoff``; False: ``d < cutoff`` (ASE).
    n_threads : int, optional
        numba threads for each call (restored afterwards); results do not
        depend on it.
    path : {"auto", "columns", "sweep"}, optional
        How candidates are found when the list is built.  ``"columns"``: the
        column sweep (a sweep along one axis inside columns over the other
        two); ``"sweep"``: the paper's parallel bi-dimensional Sweep and
        Prune over the particles' bounding cubes, with ghost cubes for
        periodic images.  ``"auto"`` (default) decides from the frame alone:
        the column sweep, unless the column plan predicts very many
        candidates per pair and per particle on a large frame; no timing
        enters, so the same input gets the same path in every process and
        with any thread count.  ``stats["path"]`` and ``stats["path_reason"]``
        say which and why.  Results are the same on every path.

    identity : bool, optional
        Follow pairs across calls: after each :meth:`update`,
        ``previous_rows`` (the row of each pair in the previous call's result,
        -1 for a new pair), ``ended_rows`` and :meth:`carry` (a history array
        moved to the new rows); particles matched by ``ids=`` or by row, with
        every periodic image also by lattice shift (docs/identity.md).  Needs
        ``layout="pairs"``.

    Notes
    -----
    Returned arrays are views of buffers the search owns: they stay valid and
    unchanged until the call after next of the same search (two sets of
    output buffers alternate, so the previous call's result can be read while
    this call's is in hand); pass ``copy=True`` (or copy them) to keep them
    longer.  Indices are int64; inside, particles are held in column order
    with int64 partner indices and int32-packed shifts.

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import NeighborSearch
    >>> search = NeighborSearch(1.5, rebuild_margin=0.2)
    >>> pos = np.array([[0.0, 0, 0], [1.0, 0, 0], [4.0, 0, 0]])
    >>> pairs, d = search.update(pos, box=[5, 5, 5, 90, 90, 90])
    >>> pairs.tolist(), d.tolist()
    ([[0, 1], [0, 2]], [1.0, 1.0])
    >>> pairs, d = search.update(pos + 0.05, box=[5, 5, 5, 90, 90, 90])
    >>> search.stats["rebuilt"]
    False
    """

    _what = "cutoff"
    #: names of the range, the largest range and the smallest threshold in messages
    _names = ("cutoff", "cutoff + rebuild_margin", "cutoff")
    #: the names of ``query``'s messages: the two sets, the range, the largest
    #: range, the smallest threshold
    _query_names = ("reference", "configuration", "cutoff", "cutoff", "cutoff")

    def __init__(self, cutoff, *, rebuild_margin=0.0, quantities="Pd", layout="pairs",
                 periodic_images="minimum", include_cutoff=True, n_threads=None, path="auto",
                 identity=False):
        self.cutoff = as_scalar(cutoff, "cutoff")
        super().__init__(rebuild_margin=rebuild_margin, quantities=quantities, layout=layout,
                         n_threads=n_threads, periodic_images=periodic_images,
                         include_cutoff=include_cutoff, path=path, identity=identity)
        self._half = None
        # the threshold of every pair is (half + half) + rest == cutoff exactly: half
        # is cutoff / 2 rounded down, and rest is 0 unless the cutoff is a subnormal
        # with its lowest bit set (5e-324 / 2 rounds to 0): then the lost bit
        half = 0.5 * self.cutoff
        if half + half > self.cutoff:
            half = math.nextafter(half, 0.0)
        self._half_cutoff = half
        self._rest = self.cutoff - (half + half)

    def update(self, positions, box=None, *, pbc=None, copy=False, ids=None):
        """Pairs of this frame.

        Parameters
        ----------
        positions : (n, 3) array_like of float
            Need not be wrapped into the cell; the count may change between calls.
        box : None, (6,) or (3, 3) array_like of float, or Cell, optional
            MDAnalysis ``[lx, ly, lz, alpha, beta, gamma]``, a matrix of cell
            vectors (rows) or a :class:`granularsap.Cell`; None for open boundaries.
        pbc : bool or (3,) bools, optional
            Periodic axes (default: all, when a box is given).
        copy : bool, optional
            Return copies instead of views of the search's buffers.
        ids : (n,) array_like of int, optional
            Unique id of every particle (``identity=True``): pairs are followed
            across calls by ids, so that particles may be inserted, deleted or
            reordered; by row without ids.

        Returns
        -------
        tuple of arrays (or one array) as chosen by ``quantities`` / ``layout``.
        """
        positions = as_coords(positions, "positions", check_finite=False)
        n = len(positions)
        if self._half is None or len(self._half) != n:
            self._half = np.full(n, self._half_cutoff)
        scan = self._scan_inputs(positions, self._half)
        ids = self._check_ids(ids, n)
        self._scan = scan
        return self._run_tracked(positions, self._half, self._rest, box, pbc, None, copy, ids)

    def query(self, reference, configuration, box=None, *, pbc=None, copy=False):
        """Pairs of a reference point and a configuration point within ``cutoff``.

        A cross-set query: every pair ``(i, j)`` of ``reference[i]`` and
        ``configuration[j]`` with ``d <= cutoff`` (``<`` with
        ``include_cutoff=False``), each pair once (no symmetry: ``(i, j)`` is
        not ``(j, i)``), minimum image or, with ``periodic_images="all"``, every
        image within range.  The search builds a column grid on the
        configuration and keeps it while the same configuration (the same
        values), the same cell and the same frame scale come back: a grid is
        built once and queried many times (MDAnalysis's ``FastNS(cutoff,
        coords, box).search(query)``), a query costing only the visits of its
        own reference points.  ``stats["grid"]`` says ``"built"`` or ``"kept"``.
        A query does not touch what :meth:`update` keeps (its Verlet list,
        identity), and ``rebuild_margin`` plays no part in it.

        Parameters
        ----------
        reference : (n, 3) array_like of float
            Query points; need not be wrapped.
        configuration : (m, 3) array_like of float
            Points the grid is built on; need not be wrapped.
        box, pbc, copy
            As for :meth:`update`.

        Returns
        -------
        tuple of arrays (or one array) as chosen by ``quantities``: ``'P'``
        ``(k, 2)`` int64 pairs ``(reference index, configuration index)``;
        ``'i'``, ``'j'`` their columns; ``'d'`` distances; ``'D'`` vectors from
        ``reference[i]`` to the image of ``configuration[j]``; ``'S'`` integer
        lattice shifts with ``D = configuration[j] - reference[i] + S @ cell``
        (the arithmetic of docs/cells.md, added in that order).  Rows are
        grouped by reference index, ascending; inside a group they come in
        the order the grid was visited, which depends on the input only, never
        on the thread count (sort them if an order by configuration index is
        needed).  ``layout="csr"`` returns
        ``(offsets (n + 1,), configuration indices[, distances])`` instead.
        Views of buffers the search owns, valid until the query after next
        (``copy=True`` for copies).

        Examples
        --------
        >>> import numpy as np
        >>> from granularsap import NeighborSearch
        >>> search = NeighborSearch(1.5)
        >>> conf = np.array([[0.5, 0, 0], [4.5, 0, 0], [2.0, 2.0, 2.0]])
        >>> pairs, d = search.query([[0.0, 0, 0]], conf, box=[5, 5, 5, 90, 90, 90])
        >>> sorted(pairs.tolist()), d.tolist()  # rows of one point: in the order visited
        ([[0, 0], [0, 1]], [0.5, 0.5])
        >>> pairs, d = search.query([[2.0, 2.0, 3.0]], conf, box=[5, 5, 5, 90, 90, 90])
        >>> pairs.tolist(), search.stats["grid"]
        ([[0, 2]], 'kept')
        """
        ref = as_coords(reference, "reference", check_finite=False)
        conf = as_coords(configuration, "configuration", check_finite=False)
        return self._query(ref, np.zeros(len(ref)), conf, np.zeros(len(conf)), self.cutoff,
                           box, pbc, copy, self._query_names)


class ContactSearch(SearchEngine):
    """Sphere contacts ``d <= r_i + r_j + skin`` over a sequence of frames.

    Parameters
    ----------
    skin : float, optional
        Contact distance added to every pair's ``r_i + r_j``.
    rebuild_margin, quantities, layout, periodic_images, include_cutoff, n_threads, path, identity
        As for :class:`NeighborSearch` (default quantities ``'P'``).

    Notes
    -----
    As for :class:`NeighborSearch`: results stay valid until the call after
    next.  With ``identity=True`` and ``clump_ids``, the clump pairs in
    contact get their own identity (``clump_pairs``, ``previous_clump_rows``,
    ``ended_clump_rows``, ``carry(h, clumps=True)``).

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import ContactSearch
    >>> search = ContactSearch(rebuild_margin=0.1)
    >>> pos = np.array([[0.0, 0, 0], [1.5, 0, 0], [5.0, 0, 0]])
    >>> search.update(pos, [1.0, 0.5, 1.0]).tolist()
    [[0, 1]]
    >>> search.update(pos, [1.0, 0.5, 1.0], clump_ids=[3, 3, 4]).tolist()
    []

    Contacts followed across calls, particles by id (here reordered):

    >>> search = ContactSearch(identity=True)
    >>> search.update(pos, 1.0, ids=[7, 8, 9]).tolist()
    [[0, 1]]
    >>> search.update(pos[::-1], 1.0, ids=[9, 8, 7]).tolist(), search.previous_rows.tolist()
    ([[1, 2]], [0])
    >>> search.carry(np.array([0.25]), fill=0.0).tolist()
    [0.25]
    """

    _what = "interaction range 2 * max(radii) + skin"
    _names = ("the smallest contact distance 2 * min(radii) + skin",
              "the interaction range 2 * max(radii) + skin + rebuild_margin",
              "2 * min(radii) + skin")
    _query_names = ("reference", "configuration",
                    "the smallest contact distance min(ref_radii) + min(conf_radii) + skin",
                    "the interaction range max(ref_radii) + max(conf_radii) + skin",
                    "min(ref_radii) + min(conf_radii) + skin")

    def __init__(self, *, skin=0.0, rebuild_margin=0.0, quantities="P", layout="pairs",
                 periodic_images="minimum", include_cutoff=True, n_threads=None, path="auto",
                 identity=False):
        self.skin = as_scalar(skin, "skin")
        super().__init__(rebuild_margin=rebuild_margin, quantities=quantities, layout=layout,
                         n_threads=n_threads, periodic_images=periodic_images,
                         include_cutoff=include_cutoff, path=path, identity=identity)

    def update(self, positions, radii, box=None, *, pbc=None, clump_ids=None, copy=False,
               ids=None):
        """Contacts of this frame.

        Parameters
        ----------
        positions : (n, 3) array_like of float
        radii : (n,) array_like of float or float
            Non-negative radii (a scalar applies to every sphere).
        box, pbc, copy, ids
            As for :meth:`NeighborSearch.update`.
        clump_ids : (n,) array_like of int, optional
            Rigid-body label of every sphere: spheres with equal labels are never
            paired.  With ``identity=True`` the clump pairs in contact get their
            own identity, by label (``clump_pairs``, ``previous_clump_rows``,
            ``ended_clump_rows``, ``carry(h, clumps=True)``).

        Returns
        -------
        tuple of arrays (or one array) as chosen by ``quantities`` / ``layout``.
        """
        positions = as_coords(positions, "positions", check_finite=False)
        n = len(positions)
        if (type(radii) is np.ndarray and radii.dtype == np.float64 and radii.shape == (n,)
                and radii.flags.c_contiguous):
            scan = self._scan_inputs(positions, radii)
        else:
            # a scalar, a list or another dtype: made (n,) float64 first, then the
            # same one-pass scan as an array given so
            radii = as_radii(radii, n)
            scan = self._scan_inputs(positions, radii)
        labels = None if clump_ids is None else as_labels(clump_ids, n)
        ids = self._check_ids(ids, n)
        self._scan = scan
        return self._run_tracked(positions, radii, self.skin, box, pbc, labels, copy, ids)

    def query(self, reference, ref_radii, configuration, conf_radii, box=None, *, pbc=None,
              copy=False):
        """Contacts ``d <= ref_radii[i] + conf_radii[j] + skin`` of two sets.

        A cross-set query, as :meth:`NeighborSearch.query`: every pair ``(i,
        j)`` of ``reference[i]`` and ``configuration[j]`` in contact, each once,
        the threshold summed ``(ref_radii[i] + conf_radii[j]) + skin``; the
        configuration's grid is kept while the configuration, its radii, the
        cell and the frame scale come back.  No clump labels.

        Parameters
        ----------
        reference : (n, 3) array_like of float
        ref_radii : (n,) array_like of float or float
            Non-negative radii of the reference spheres (a scalar applies to all).
        configuration : (m, 3) array_like of float
        conf_radii : (m,) array_like of float or float
        box, pbc, copy
            As for :meth:`update`.

        Returns
        -------
        As :meth:`NeighborSearch.query`: pairs ``(reference index,
        configuration index)``, grouped by reference index.

        Examples
        --------
        >>> import numpy as np
        >>> from granularsap import ContactSearch
        >>> search = ContactSearch(skin=0.1, quantities="Pd")
        >>> pairs, d = search.query([[0.0, 0, 0]], 1.0, [[1.5, 0, 0], [3.0, 0, 0]], [0.5, 1.0])
        >>> pairs.tolist(), d.tolist()
        ([[0, 0]], [1.5])
        """
        ref = as_coords(reference, "reference", check_finite=False)
        conf = as_coords(configuration, "configuration", check_finite=False)
        rr = as_radii(ref_radii, len(ref), "ref_radii")
        rc = as_radii(conf_radii, len(conf), "conf_radii")
        return self._query(ref, rr, conf, rc, self.skin, box, pbc, copy, self._query_names)
