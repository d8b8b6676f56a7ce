"""Drop-in replacement for ``ase.neighborlist.NeighborList`` on the stateful engine.

Swap the import and nothing else changes::

    # from ase.neighborlist import NeighborList
    from granularsap.ase import NeighborList

    nl = NeighborList(cutoffs, skin=0.3, self_interaction=False, bothways=True)
    nl.update(atoms)            # True: the list was (re)built
    indices, offsets = nl.get_neighbors(0)

Semantics follow ASE's own source (``ase/neighborlist.py``, ASE 3.29):

* each atom's cutoff is widened by ``skin``: atoms ``a`` and ``b`` are listed
  when ``d < (cutoffs[a] + skin) + (cutoffs[b] + skin)`` (strict, as in ASE), in
  every periodic image in range (cutoffs larger than the cell give several
  images, each with its offset);
* :meth:`NeighborList.update` rebuilds the list (and returns True) on the first
  call, when ``atoms.pbc`` or the cell changed, or when some atom has moved more
  than ``skin`` since the last build (``((p0 - p) ** 2).sum(1).max() > skin **
  2``, ASE's expression); otherwise it returns False and the list of the last
  build is kept as it is, not re-filtered, exactly like ASE;
* ``self_interaction=True`` lists every atom as its own neighbour at offset 0;
* ``bothways=False`` gives a half list: every pair appears once, oriented as the
  chosen ASE primitive orients it.  ``PrimitiveNeighborList`` (ASE's default)
  keeps the image whose shift in its Minkowski-reduced cell is
  lexicographically non-negative, ``NewPrimitiveNeighborList`` the one whose
  offset is; the ``primitive`` argument picks which.

The list is computed by :class:`granularsap.ContactSearch` (every image, strict
comparison, radii ``cutoffs + skin``); the engine runs only when ASE would
rebuild.  ``get_neighbors(a)`` returns the neighbours of ``a`` sorted by index,
then by offset (lexicographically); that is ASE's ``sorted=True`` order, and the
order does not depend on ``sorted`` or on the thread count.  Pairs are decided in
float64 with the engine's wrapped coordinates; a pair whose distance is within a
few units in the last place of its range can be decided differently from ASE
(whose distances round differently), nothing else.

Stricter than ASE: ``cutoffs`` must have one non-negative entry per atom of
every ``atoms`` given to :meth:`update` (a different count raises a
``ValueError`` naming both counts; ASE fails later or not at all).  An atom
count that changes between calls is the same error.  See
docs/stateful-dropins.md.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..search import ContactSearch

__all__ = ["NeighborList"]

_PRIMITIVES = ("PrimitiveNeighborList", "NewPrimitiveNeighborList")


def _primitive_name(primitive):
    if primitive is None:
        return "PrimitiveNeighborList"
    if isinstance(primitive, str):
        name = primitive
    elif isinstance(primitive, type):
        name = primitive.__name__
    else:
        raise TypeError("primitive must be ase.neighborlist.PrimitiveNeighborList or "
                        "NewPrimitiveNeighborList (the class) or its name, got "
                        f"{type(primitive).__name__}")
    if name not in _PRIMITIVES:
        raise ValueError(f"primitive must be one of {', '.join(_PRIMITIVES)} (the ASE class "
                         f"or its name), got {name!r}")
    return name


def _lex_positive(v):
    """Rows of the integer ``(k, 3)`` array ``v`` that are lexicographically > 0."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    return (x > 0) | ((x == 0) & ((y > 0) | ((y == 0) & (z > 0))))


class NeighborList:
    """Neighbour list of an ``ase.Atoms`` with a Verlet skin, like ASE's own.

    Parameters
    ----------
    cutoffs : (n,) array_like of float
        One radius per atom: atoms whose spheres (widened by ``skin``) overlap
        are neighbours.  ``ase.neighborlist.natural_cutoffs(atoms)`` gives one.
    skin : float, optional
        Added to every cutoff; the list is kept until some atom has moved more
        than ``skin`` since it was built.
    sorted : bool, optional
        Accepted for compatibility: neighbours are always sorted (by index, then
        offset).
    self_interaction : bool, optional
        List every atom as its own neighbour (offset 0).
    bothways : bool, optional
        Full list (each pair from both atoms) instead of a half list.
    primitive : class or str, optional
        ``ase.neighborlist.PrimitiveNeighborList`` (default, as in ASE) or
        ``NewPrimitiveNeighborList`` (the class or its name): decides how a
        half list orients periodic pairs.
    n_threads : int, optional
        numba threads for the search (results do not depend on it).

    Attributes
    ----------
    nupdates : int
        Number of builds so far.
    nl : object
        The list as ASE's primitive list shows it (``neighbors`` and
        ``displacements`` per atom, ``get_neighbors``, ``update(pbc, cell,
        coordinates)``, ``cutoffs``, ``nupdates``, ...), as ASE's ``nl.nl``:
        ``ase.neighborlist.get_connectivity_matrix(nl.nl)`` works.
    search : granularsap.ContactSearch
        The engine (``search.stats`` describes the last build).

    Examples
    --------
    >>> import numpy as np
    >>> from ase import Atoms
    >>> from granularsap.ase import NeighborList
    >>> atoms = Atoms("H3", positions=[[0, 0, 0], [0.9, 0, 0], [3, 0, 0]])
    >>> nl = NeighborList([0.5, 0.5, 0.5], skin=0.1, self_interaction=False)
    >>> nl.update(atoms)
    True
    >>> nl.get_neighbors(0)[0].tolist()
    [1]
    >>> atoms.positions[2, 0] += 0.05
    >>> nl.update(atoms)
    False
    """

    def __init__(self, cutoffs, skin=0.3, sorted=False, self_interaction=True, bothways=False,
                 primitive=None, *, n_threads=None):
        cut = np.asarray(cutoffs, dtype=np.float64) if not isinstance(cutoffs, str) else None
        if cut is None or cut.ndim != 1:
            shape = "a string" if cut is None else f"shape {cut.shape}"
            raise ValueError(f"cutoffs must be a sequence of one float per atom, got {shape}")
        if cut.size and not (np.all(np.isfinite(cut)) and cut.min() >= 0):
            bad = int(np.flatnonzero(~(np.isfinite(cut) & (cut >= 0)))[0])
            raise ValueError(f"cutoffs must be finite and non-negative, got {float(cut[bad])!r} "
                             f"at index {bad}")
        try:
            skin = float(skin)
        except (TypeError, ValueError):
            raise TypeError(f"skin must be a float, got {type(skin).__name__}") from None
        if not (np.isfinite(skin) and skin >= 0):
            raise ValueError(f"skin must be finite and non-negative, got {skin!r}")
        self.cutoffs = cut.copy()
        self.skin = skin
        self.sorted = bool(sorted)
        self.self_interaction = bool(self_interaction)
        self.bothways = bool(bothways)
        self.primitive = _primitive_name(primitive)
        self.nupdates = 0
        # ASE's own arithmetic: every cutoff widened by skin, pair range their sum
        self._radii = np.asarray(cutoffs, dtype=np.float64) + skin
        self.search = ContactSearch(skin=0.0, rebuild_margin=0.0, quantities="ijS",
                                    periodic_images="all", include_cutoff=False,
                                    n_threads=n_threads)
        self.nl = _Primitive(self)

    # ------------------------------------------------------------------ update
    def update(self, atoms):
        """Rebuild the list if ASE would; return whether it did.

        Parameters
        ----------
        atoms : ase.Atoms
            Anything with ``positions``, ``pbc`` and ``get_cell(complete=True)``.

        Returns
        -------
        bool
            True when the list was built from these positions.

        Raises
        ------
        ValueError
            ``atoms`` has a different number of atoms than ``cutoffs``.
        """
        for attr in ("positions", "pbc", "get_cell"):
            if not hasattr(atoms, attr):
                raise TypeError(f"atoms must be an ase.Atoms (missing .{attr}), got "
                                f"{type(atoms).__name__}")
        return self._update(atoms.pbc, atoms.get_cell(complete=True), atoms.positions,
                            "atoms")

    def _update(self, pbc, cell, positions, what):
        positions = np.array(positions, dtype=np.float64)
        pbc = np.array(pbc, dtype=bool).reshape(3)
        cell = np.array(cell, dtype=np.float64).reshape(3, 3)
        if what == "coordinates" and positions.shape != (len(self.cutoffs), 3):
            raise ValueError(f"coordinates must have shape ({len(self.cutoffs)}, 3), one row "
                             f"per cutoff, got {positions.shape}")
        if len(positions) != len(self.cutoffs):
            raise ValueError(f"atoms has {len(positions)} atoms but cutoffs has "
                             f"{len(self.cutoffs)} entries; give one cutoff per atom (a "
                             "changed atom count needs a new NeighborList)")
        if self.nupdates and not ((self._pbc != pbc).any() or (self._cell != cell).any()):
            if len(positions) == 0 or not (
                    ((self._positions - positions) ** 2).sum(1).max() > self.skin ** 2):
                return False
        self._build(pbc, cell, positions)
        return True

    def _build(self, pbc, cell, positions):
        self._pbc, self._cell, self._positions = pbc, cell, positions
        n = len(positions)
        i, j, shift = self.search.update(positions, self._radii, cell, pbc=pbc, copy=True)
        # i <= j: every unordered pair image once (a self image i == j once, as +S or -S)
        if not self.bothways:
            key = shift
            if self.primitive == "PrimitiveNeighborList" and pbc.any() and len(i):
                key = self._reduced_shifts(pbc, cell, positions, i, j, shift)
            zero = ~key.any(axis=1)
            keep = _lex_positive(key) | zero  # zero: i < j already
            first = np.where(keep, i, j)
            second = np.where(keep, j, i)
            offsets = np.where(keep[:, None], shift, -shift)
        else:
            first = np.concatenate([i, j])
            second = np.concatenate([j, i])
            offsets = np.concatenate([shift, -shift])
        if self.self_interaction:
            # ASE tests the self pair like any other, 0 < 2 (cutoff + skin)
            own = np.flatnonzero(self._radii > 0).astype(np.int64)
            first = np.concatenate([first, own])
            second = np.concatenate([second, own])
            offsets = np.concatenate([offsets, np.zeros((len(own), 3), np.int64)])
        order = np.lexsort((offsets[:, 2], offsets[:, 1], offsets[:, 0], second, first))
        self._second = np.ascontiguousarray(second[order], dtype=np.int64)
        self._offsets = np.ascontiguousarray(offsets[order], dtype=np.int64)
        self._first = np.ascontiguousarray(first[order], dtype=np.int64)
        self._start = np.searchsorted(self._first, np.arange(n + 1))
        self.nupdates += 1

    @staticmethod
    def _reduced_shifts(pbc, cell, positions, i, j, shift):
        """The image index of every pair in ASE's Minkowski-reduced cell.

        ``PrimitiveNeighborList`` wraps the positions into its reduced cell
        (``rcell = op @ cell``) and lists pair ``(a, b)`` in image ``n`` of that
        cell with offset ``n @ op + off[b] - off[a]``, for ``n`` in the
        non-negative half space only; inverting this with ASE's own functions
        gives the orientation it chose.
        """
        from ase.cell import Cell
        from ase.geometry import minkowski_reduce, wrap_positions

        rcell, op = minkowski_reduce(Cell(cell), pbc)
        wrapped = wrap_positions(positions, rcell, pbc=pbc, eps=0)
        off = Cell(cell).scaled_positions(wrapped - positions).round().astype(np.int64)
        inv_op = np.rint(np.linalg.inv(np.asarray(op, dtype=np.float64))).astype(np.int64)
        return (shift - off[j] + off[i]) @ inv_op

    # --------------------------------------------------------------- queries
    def _check_built(self):
        if self.nupdates <= 0:
            raise RuntimeError("Must call update(atoms) on your neighborlist first!")

    def get_neighbors(self, a):
        """Neighbours of atom ``a`` and their cell offsets.

        The position of neighbour ``k`` is ``atoms.positions[indices[k]] +
        offsets[k] @ atoms.cell``.  Sorted by index, then offset.

        Returns
        -------
        indices : (m,) ndarray of int64
        offsets : (m, 3) ndarray of int64
            Views of the list: valid until the next rebuild.
        """
        self._check_built()
        n = len(self._start) - 1
        a = int(a)
        if not -n <= a < n:
            raise IndexError(f"atom index {a} is out of range for {n} atoms")
        a %= n
        lo, hi = self._start[a], self._start[a + 1]
        return self._second[lo:hi], self._offsets[lo:hi]

    @property
    def nneighbors(self):
        """Number of neighbour pairs (ASE's deprecated property, same count)."""
        warnings.warn("nneighbors is deprecated in ASE (3.24): count the rows of "
                      "nl.neighbors instead", FutureWarning, stacklevel=2)
        self._check_built()
        count = len(self._second)
        if self.self_interaction:
            count -= len(self._start) - 1
        return count // 2 if self.bothways else count

    @property
    def npbcneighbors(self):
        """Number of neighbour pairs across the periodic boundary (ASE's
        deprecated property, same count)."""
        warnings.warn("npbcneighbors is deprecated in ASE (3.24): count the non-zero "
                      "rows of nl.displacements instead", FutureWarning, stacklevel=2)
        self._check_built()
        count = int(self._offsets.any(axis=1).sum())
        return count // 2 if self.bothways else count

    def get_connectivity_matrix(self, sparse=True):
        """``(n, n)`` int8 matrix with 1 where ``j`` is a neighbour of ``i``.

        As ``ase.neighborlist.get_connectivity_matrix``: symmetric only with
        ``bothways=True``; a ``scipy.sparse.dok_matrix`` when ``sparse``.
        """
        self._check_built()
        n = len(self._start) - 1
        if sparse:
            from scipy import sparse as sp

            key = np.unique(self._first * max(n, 1) + self._second)
            coo = sp.coo_matrix((np.ones(len(key), np.int8), (key // max(n, 1),
                                                             key % max(n, 1))), shape=(n, n))
            matrix = coo.todok()
            return matrix
        matrix = np.zeros((n, n), dtype=np.int8)
        matrix[self._first, self._second] = 1
        return matrix


class _Primitive:
    """``NeighborList.nl``: the list as ASE's ``PrimitiveNeighborList`` shows it, for
    code that reads ``nl.nl`` (``ase.neighborlist.get_connectivity_matrix(nl.nl)``,
    ``nl.nl.neighbors``).  It shares the list of its ``NeighborList``."""

    def __init__(self, owner):
        self._owner = owner

    def __getattr__(self, name):
        if name in ("cutoffs", "skin", "sorted", "self_interaction", "bothways", "nupdates"):
            return getattr(self._owner, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def pbc(self):
        self._owner._check_built()
        return self._owner._pbc

    @property
    def cell(self):
        self._owner._check_built()
        return self._owner._cell

    @property
    def coordinates(self):
        self._owner._check_built()
        return self._owner._positions

    def _per_atom(self, rows):
        """``rows`` of the list cut into one view per atom."""
        nl = self._owner
        nl._check_built()
        start = nl._start
        return [rows[start[a]:start[a + 1]] for a in range(len(start) - 1)]

    @property
    def neighbors(self):
        """Neighbour indices of every atom (a list of arrays)."""
        return self._per_atom(self._owner._second)

    @property
    def displacements(self):
        """Cell offsets of every atom's neighbours (a list of (m, 3) arrays)."""
        return self._per_atom(self._owner._offsets)

    def get_neighbors(self, a):
        return self._owner.get_neighbors(a)

    def update(self, pbc, cell, coordinates):
        """Rebuild from ``pbc``, ``cell`` and ``coordinates`` if ASE would; return
        whether it did (``PrimitiveNeighborList.update``)."""
        return self._owner._update(pbc, cell, coordinates, "coordinates")
