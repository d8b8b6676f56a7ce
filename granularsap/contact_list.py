"""A neighbour list with a skin for a DEM loop, as LAMMPS and LIGGGHTS keep one.

:class:`ContactList` keeps the sphere pairs within ``(r_i + r_j) + skin +
rebuild_margin`` (the contacts of this step and every pair that can come into
contact before the list is rebuilt) and rebuilds it only when some sphere has
moved more than half of ``rebuild_margin`` since the last build, or the
spheres, their radii, ids, clump labels or the cell changed.  Between builds
an update is one check of the displacements: the list, its rows and so the
contact history arrays carried with it stay as they are.  This is LAMMPS's
``neighbor SKIN bin`` with ``neigh_modify delay 0 every 1 check yes``, and
``fix neigh/history``: the history moves to the new rows at a rebuild only
(:meth:`ContactList.carry`), and the contact law (LAMMPS's ``pair granular``)
computes every listed pair's separation (:meth:`ContactList.separations`)
and treats a pair that does not touch as it does (no force, its history
reset).

The list is built by a :class:`granularsap.ContactSearch` with contact
identity; a rebuild costs what that search's call costs.  ``ContactSearch``
with ``rebuild_margin`` gives the exact contacts of every step instead (a
re-test of its kept list per step); this class leaves the test to the
contact law, which computes the separations anyway.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ._numba import get_threads, num_threads
from ._validate import as_coords, as_scalar, check_n_threads
from .cell import Cell
from .identity import as_ids
from .kernels import listed
from .search import ContactSearch, as_labels, as_radii

__all__ = ["ContactList"]

#: lists of at least this many pairs get their separations on every thread
_PARALLEL_MIN = 32768
#: relative size of the rounding allowance of the displacement test (see
#: ``ContactList._limit2``): about 1e3 times the rounding of the sums involved
_ROUNDING = 1e-12

_NO_ROWS = np.empty(0, np.int64)


class _ListBuilder(ContactSearch):
    """The search that builds the list: its skin holds the margin, and its
    messages say so."""

    _what = "interaction range 2 * max(radii) + skin + rebuild_margin"
    _names = ("the smallest listed distance 2 * min(radii) + skin + rebuild_margin",
              "the interaction range 2 * max(radii) + skin + rebuild_margin",
              "2 * min(radii) + skin + rebuild_margin")


class ContactList:
    """The sphere pairs within reach of contact, kept between rebuilds.

    Parameters
    ----------
    rebuild_margin : float
        The list holds every pair with ``d <= (r_i + r_j) + skin +
        rebuild_margin`` and is rebuilt when a sphere has moved more than
        ``rebuild_margin / 2`` since the last build (LAMMPS's neighbour
        skin).  Positive.
    skin : float, optional
        Contact distance added to ``r_i + r_j`` (as for
        :class:`ContactSearch`); a pair is in contact when ``d <= (r_i + r_j)
        + skin``.
    periodic_images : {"minimum", "all"}, optional
        As for :class:`ContactSearch`.
    n_threads : int, optional
        Threads of the builds and of :meth:`separations` (default: numba's).
    path : {"auto", "columns", "sweep"}, optional
        Candidate path of the builds, as for :class:`ContactSearch`.

    Attributes
    ----------
    rebuilt : bool
        Whether the last :meth:`update` built the list.
    previous_rows : (k,) int64 ndarray
        For every listed pair, its row in the list of the update before
        (``-1`` for a pair new to the list); ``arange(k)`` when the list was
        kept.
    ended_rows : (k_prev,) int64 ndarray
        Rows of the previous list that left it (none when the list was kept).
    stats : dict
        ``rebuilt``, ``reason`` (why it was built: ``"first"``, ``"moved"``,
        ``"radii"``, ``"count"``, ``"ids"``, ``"clump_ids"``, ``"cell"``, or
        ``None`` when kept), ``builds`` (so far), ``pairs`` (listed) and,
        after a build, the building search's ``stats`` under ``"search"``.

    Notes
    -----
    Pairs are matched across builds by ``ids`` when given (LAMMPS atom ids:
    spheres may be inserted, deleted or re-ordered), else by row, and by
    their image shift, as :class:`ContactSearch` does with
    ``identity=True``.  Positions are taken as given: a sphere moved by a
    whole cell vector (wrapped back into the cell by the script) counts as
    moved, and the list is rebuilt, as LAMMPS remaps atoms into the box only
    at its rebuilds.

    The arrays :meth:`update` returns are the list itself: they stay valid
    and unchanged until the second rebuild after the call that returned them
    (so at least until the call after next); :meth:`separations` writes into
    two sets of buffers in turn (valid until the call after next).

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import ContactList
    >>> x = np.array([[0.0, 0, 0], [2.1, 0, 0], [5.0, 0, 0]])
    >>> contacts = ContactList(rebuild_margin=0.4)
    >>> pairs, shifts = contacts.update(x, 1.0)
    >>> pairs.tolist(), contacts.rebuilt       # 2.1 apart: listed, not touching yet
    ([[0, 1]], True)
    >>> d, D = contacts.separations(x)
    >>> (d <= 2.0).tolist()
    [False]
    >>> x[1, 0] = 1.95                         # moved 0.15, less than half the margin
    >>> pairs, shifts = contacts.update(x, 1.0)
    >>> contacts.rebuilt, (contacts.separations(x)[0] <= 2.0).tolist()
    (False, [True])
    """

    def __init__(self, rebuild_margin, *, skin=0.0, periodic_images="minimum", n_threads=None,
                 path="auto"):
        self.rebuild_margin = as_scalar(rebuild_margin, "rebuild_margin", positive=True)
        self.skin = as_scalar(skin, "skin")
        self.n_threads = check_n_threads(n_threads)
        self._search = _ListBuilder(skin=self.skin + self.rebuild_margin, quantities="PS",
                                    periodic_images=periodic_images, n_threads=n_threads,
                                    path=path, identity=True)
        self.periodic_images = periodic_images
        self.rebuilt = False
        self.stats = {"rebuilt": False, "reason": None, "builds": 0, "pairs": 0}
        self._pairs = np.empty((0, 2), np.int64)
        self._shifts = np.empty((0, 3), np.int64)
        self._x = None  # positions, radii, ids, labels and cell of the last build
        self._r = None
        self._ids = None
        self._labels = None
        self._key = None
        self._matrix = np.zeros((3, 3))
        self._limit2 = -1.0
        self._sc = 1.0
        self._kept_rows = _NO_ROWS
        self._previous = _NO_ROWS
        self._ended = _NO_ROWS
        self._sep = [None, None]  # the separations' two buffers (d, D), in turn
        self._turn = 0

    # ------------------------------------------------------------------ update
    def update(self, positions, radii, box=None, *, pbc=None, ids=None, clump_ids=None):
        """The list for this step: rebuilt if needed, else the kept one.

        Parameters
        ----------
        positions : (n, 3) array_like of float
        radii : (n,) array_like of float or float
        box, pbc
            As for :meth:`ContactSearch.update`.
        ids : (n,) array_like of int, optional
            Unique id of every sphere: pairs are followed across rebuilds by
            ids (by row without).
        clump_ids : (n,) array_like of int, optional
            Rigid-body label of every sphere: spheres with equal labels are
            never listed.

        Returns
        -------
        pairs : (k, 2) int64 ndarray
            Listed pairs ``(i, j)``, ``i < j`` for ``periodic_images="minimum"``.
        shifts : (k, 3) int64 ndarray
            Integer image shift ``S`` of every pair: its separation is
            ``x[j] - x[i] + S @ cell`` (:meth:`separations`).
        """
        if self._same_arrays(positions, radii, box, pbc, ids, clump_ids):
            # a DEM step's call (the arrays of the last build's kinds, no cell, no
            # labels): one kernel call tells a kept list, without the checks below
            # (~4 against ~11 us at 2,000 spheres, cold caches after a force loop)
            if not listed.kept_list_state(positions, self._x, radii, self._r,
                                          _NO_ROWS if ids is None else ids,
                                          _NO_ROWS if self._ids is None else self._ids,
                                          self._sc, self._limit2):
                return self._kept()
        positions = as_coords(positions, "positions", check_finite=False)
        n = len(positions)
        if (type(radii) is np.ndarray and radii.dtype == np.float64 and radii.shape == (n,)
                and radii.flags.c_contiguous):
            rad = radii
        else:
            rad = as_radii(radii, n)
        reason = self._why_rebuild(positions, rad, box, pbc, ids, clump_ids)
        if reason is None:
            return self._kept()
        return self._build(positions, rad, box, pbc, ids, clump_ids, reason)

    def _same_arrays(self, positions, radii, box, pbc, ids, clump_ids):
        """Whether this call's arrays are C-contiguous float64 (int64 ids) of the
        shapes of the last build's, without a cell, ids only if the build had
        them, and no clump labels, so that ``kept_list_state`` alone decides."""
        x = self._x
        if (x is None or box is not None or pbc is not None or clump_ids is not None
                or self._labels is not None or self._key != (None, None)
                or type(positions) is not np.ndarray or type(radii) is not np.ndarray
                or positions.dtype != np.float64 or radii.dtype != np.float64
                or positions.shape != x.shape or radii.shape != self._r.shape
                or not positions.flags.c_contiguous or not radii.flags.c_contiguous):
            return False
        if ids is None:
            return self._ids is None
        return (self._ids is not None and type(ids) is np.ndarray and ids.dtype == np.int64
                and ids.shape == self._ids.shape and ids.flags.c_contiguous)

    def _kept(self):
        """The kept list, as this call's result."""
        self.rebuilt = False
        k = len(self._pairs)
        if len(self._kept_rows) != k:
            self._kept_rows = np.arange(k)
        self._previous, self._ended = self._kept_rows, _NO_ROWS
        self.stats = {"rebuilt": False, "reason": None, "builds": self.stats["builds"],
                      "pairs": k}
        return self._pairs, self._shifts

    def _why_rebuild(self, positions, rad, box, pbc, ids, clump_ids):
        """Why the kept list may miss a contact of this step, or None."""
        if self._x is None:
            return "first"
        if len(positions) != len(self._x):
            return "count"
        if self._cell_key(box, pbc) != self._key:
            return "cell"
        if (ids is None) != (self._ids is None):
            return "ids"
        if (clump_ids is None) != (self._labels is None) or (
                clump_ids is not None and not np.array_equal(clump_ids, self._labels)):
            return "clump_ids"
        pos = positions if positions.flags.c_contiguous else np.ascontiguousarray(positions)
        if ids is None:
            ids = _NO_ROWS
        elif not (type(ids) is np.ndarray and ids.dtype == np.int64
                  and ids.shape == self._ids.shape and ids.flags.c_contiguous):
            ids = as_ids(ids, len(positions))
        state = listed.kept_list_state(pos, self._x, rad, self._r, ids,
                                       _NO_ROWS if self._ids is None else self._ids,
                                       self._sc, self._limit2)
        if state == 2:
            return "radii"
        if state == 3:
            return "ids"
        return "moved" if state else None

    @staticmethod
    def _cell_key(box, pbc):
        """What tells this call's cell from the kept one's without resolving it: the
        values of an array (or list) given, a Cell itself, or the resolved Cell of
        anything else (an ase.Atoms)."""
        flags = pbc if pbc is None or isinstance(pbc, (bool, np.bool_)) else tuple(
            np.ravel(pbc).tolist())
        if box is None or isinstance(box, Cell):
            return box, flags
        if isinstance(box, (np.ndarray, list, tuple)):
            arr = np.asarray(box)
            return (arr.shape, arr.dtype.str, arr.tobytes()), flags
        return Cell.coerce(box, pbc), None

    def _build(self, positions, rad, box, pbc, ids, clump_ids, reason):
        t0 = time.perf_counter()
        pairs, shifts = self._search.update(positions, rad, box, pbc=pbc, ids=ids,
                                            clump_ids=clump_ids)
        search = self._search
        self._pairs, self._shifts = pairs, shifts
        self._previous, self._ended = search.previous_rows, search.ended_rows
        # what the next steps compare with (copies into kept arrays: the script may
        # change its own), with the largest coordinate and radius, in one pass
        n = len(positions)
        if self._x is None or self._x.shape != (n, 3):
            self._x, self._r = np.empty((n, 3)), np.empty(n)
        ids = None if ids is None else as_ids(ids, n)
        if ids is None:
            self._ids = None
        elif self._ids is None or self._ids.shape != (n,):
            self._ids = np.empty(n, np.int64)
        pos = positions if positions.flags.c_contiguous else np.ascontiguousarray(positions)
        big, rmax = listed.keep_build(pos, rad, _NO_ROWS if ids is None else ids, self._x,
                                      self._r, _NO_ROWS if ids is None else self._ids)
        self._labels = None if clump_ids is None else np.array(as_labels(clump_ids, n))
        cell = Cell.coerce(box, pbc)
        self._key = self._cell_key(box, pbc)
        self._matrix = np.zeros((3, 3)) if cell is None else np.array(cell.matrix, np.float64)
        # an extreme limit is compared in units of its own power of two (its
        # square in range); between 2**-400 and 2**400 squares need no scaling
        # (a displacement far beyond the limit may overflow to inf: moved; one
        # far below may underflow to 0: not moved, as it is)
        limit = self._limit(big, rmax)
        self._sc = 1.0
        if limit > 0.0 and not 2.0 ** -400 < limit < 2.0 ** 400:
            self._sc = math.ldexp(1.0, min(-math.frexp(limit)[1], 1000))
        self._limit2 = (limit * self._sc) ** 2
        self.rebuilt = True
        self.stats = {"rebuilt": True, "reason": reason, "builds": self.stats["builds"] + 1,
                      "pairs": len(pairs), "search": search.stats,
                      "seconds": time.perf_counter() - t0}
        return pairs, shifts

    def _limit(self, big, rmax):
        """Half the margin, less an allowance for rounding: the largest
        displacement of a sphere the kept list stays exact for.

        A pair listed at the build with separation ``d_b`` has on a later
        step ``|d - d_b| <= |dx_i| + |dx_j|`` in exact arithmetic, so every
        pair with ``d <= (r_i + r_j) + skin`` now was within the list's range
        while no sphere moved more than half the margin.  The computed
        separations, thresholds and displacements each round by a few units
        in the last place of the coordinates, cell sums and ranges involved;
        the allowance is ``_ROUNDING`` (1e-12) times their size, about a
        thousand times that rounding."""
        scale = big + float(np.abs(self._matrix).sum())
        scale = 4.0 * (scale + 2.0 * rmax + self.skin + self.rebuild_margin)
        return max(0.5 * self.rebuild_margin - _ROUNDING * scale, 0.0)

    # --------------------------------------------------------------- contacts
    def separations(self, positions):
        """Distance and vector of every listed pair on ``positions``.

        ``D = x[j] - x[i] + S @ cell`` and ``d = |D|``, in the arithmetic of
        docs/cells.md: the listed pairs with ``d <= (r_i + r_j) + skin`` are
        the contacts :class:`ContactSearch` finds on the same positions, with
        the same ``d`` and ``D`` bit for bit.

        Parameters
        ----------
        positions : (n, 3) array_like of float
            This step's positions (those of the last :meth:`update`).

        Returns
        -------
        d : (k,) float64 ndarray
        D : (k, 3) float64 ndarray
        """
        positions = as_coords(positions, "positions", check_finite=False)
        if self._x is None:
            raise RuntimeError("separations needs a list: call update first")
        if len(positions) != len(self._x):
            raise ValueError(f"positions must have the {len(self._x)} rows of the last "
                             f"update, got {len(positions)}")
        k = len(self._pairs)
        turn = self._sep[self._turn]
        if turn is None or len(turn[0]) < k:
            turn = (np.empty(max(k, 1)), np.empty((max(k, 1), 3)))
            self._sep[self._turn] = turn
        self._turn ^= 1
        d, vec = turn[0][:k], turn[1][:k]
        pos = positions if positions.flags.c_contiguous else np.ascontiguousarray(positions)
        if k < _PARALLEL_MIN or (self.n_threads or get_threads()) == 1:
            listed.separations_serial(pos, self._pairs, self._shifts, self._matrix, d, vec)
        else:
            with num_threads(self.n_threads):
                listed.separations(pos, self._pairs, self._shifts, self._matrix, d, vec)
        return d, vec

    # ---------------------------------------------------------------- history
    @property
    def previous_rows(self):
        return self._previous

    @property
    def ended_rows(self):
        return self._ended

    def carry(self, history, fill=0.0, out=None):
        """A history array of the previous list, moved to this list's rows.

        After a rebuild, ``history[previous_rows]`` with ``fill`` for pairs
        new to the list (:meth:`ContactSearch.carry`); when the list was
        kept, ``history`` itself (or a copy into ``out``).

        Parameters
        ----------
        history : (k_prev, ...) array_like
            One row per pair of the previous update's list.
        fill : scalar or array_like, optional
            Value for pairs new to the list (default 0).
        out : (k, ...) ndarray, optional
            Where to write.
        """
        if self.rebuilt:
            return self._search.carry(history, fill, out)
        history = np.asarray(history)
        k = len(self._pairs)
        if history.ndim == 0 or len(history) != k:
            raise ValueError(f"history must have one row per pair of the previous list "
                             f"({k}), got shape {history.shape}")
        if out is None:
            return history
        out[...] = history
        return out
