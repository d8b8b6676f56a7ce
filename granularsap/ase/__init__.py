"""Drop-in replacement for ``ase.neighborlist.neighbor_list``.

Swap the import and nothing else changes::

    # from ase.neighborlist import neighbor_list
    from granularsap.ase import neighbor_list

    i, j, d, D, S = neighbor_list("ijdDS", atoms, cutoff=3.0)

Same quantities (``'i'``, ``'j'``, ``'d'``, ``'D'``, ``'S'`` in any order and
combination), cutoff forms (a float; one radius per atom, pairs within
``r_i + r_j``; a dict ``{(el1, el2): cutoff}`` keyed by symbols or atomic
numbers), periodicity per axis from ``atoms.pbc`` and the full list in both
directions.  Rows are sorted by ``i``, then ``j``, then the shift ``S``
(lexicographically), so the order is deterministic and independent of the
thread count (ASE sorts by ``i`` only and leaves the order within an atom to
its binning).  Cutoffs are strict (``d < cutoff``), as in ASE.
Cutoffs larger than the cell are handled like ASE: every periodic image within
range is returned with its shift ``S``, so ``D = positions[j] - positions[i] +
S @ cell``; atoms outside the cell need not be wrapped.  When the cutoff is
several times the cell, the full list (both ways) comes straight from the
engine's cross-set query of the atoms against themselves
(``ContactSearch.query``, every image) instead of a half list mirrored.

Stricter than ASE: a per-atom cutoff list must have exactly one entry per
atom (ASE silently ignores extra entries, for example two cutoffs for a
one-atom crystal in its own ``NewPrimitiveNeighborList`` example), and
unknown quantities, negative cutoffs and degenerate periodic cells raise a
``ValueError`` naming the argument.  See docs/dropins.md.

ASE is needed only to build the ``Atoms`` object (and to map element symbols
in dict cutoffs to atomic numbers).
"""

from __future__ import annotations

import numpy as np

from .. import periodic
from .._validate import as_coords, check_n_threads
from ..search import ContactSearch
from ..search import as_radii as _as_radii

__all__ = ["NeighborList", "neighbor_list", "primitive_neighbor_list"]

_EMPTY = {"i": ((0,), np.int64), "j": ((0,), np.int64), "d": ((0,), np.float64),
          "D": ((0, 3), np.float64), "S": ((0, 3), np.int64)}


def _check_quantities(quantities):
    if not isinstance(quantities, str):
        raise TypeError(f"quantities must be a string such as 'ijdDS', got "
                        f"{type(quantities).__name__}")
    bad = [q for q in quantities if q not in _EMPTY]
    if bad:
        raise ValueError(f"Unsupported quantity specified: {bad[0]!r}; quantities must be "
                         "characters of 'ijdDS'")


# ---------------------------------------------------------------------------
# every image of every pair: cutoffs many times the cell

#: image-box factor prod_k (1 + 2 reach / w_k) above which the full list comes
#: straight from the engine's cross-set query of the atoms against themselves
#: (both ways at once) instead of the half list mirrored: the list of every
#: image is then many times the atoms' count
_IMAGE_FACTOR_MAX = 16.0


def _image_factor(reach, cellm, pbc):
    """``prod_k (1 + 2 reach / w_k)`` over the periodic axes."""
    widths = periodic.perpendicular_widths(cellm)
    return float(np.prod(1.0 + 2.0 * reach / widths[pbc]))


def _pair_cutoff_table(cutoff, numbers):
    """Dense table of dict cutoffs indexed by atomic number (0 where absent)."""
    try:
        from ase.data import atomic_numbers
    except ImportError:  # pragma: no cover - ase is an optional dependency
        atomic_numbers = {}
    zmax = int(numbers.max()) if len(numbers) else 0
    keys = []
    for (e1, e2), c in cutoff.items():
        z1 = atomic_numbers.get(e1, e1)
        z2 = atomic_numbers.get(e2, e2)
        if not isinstance(z1, (int, np.integer)) or not isinstance(z2, (int, np.integer)):
            raise ValueError(f"cutoff dict keys must be element symbols or atomic numbers, "
                             f"got {(e1, e2)!r}")
        c = float(c)
        if not np.isfinite(c) or c < 0:
            raise ValueError(f"cutoff for {(e1, e2)!r} must be finite and non-negative, got {c}")
        keys.append((int(z1), int(z2), c))
        zmax = max(zmax, int(z1), int(z2))
    table = np.zeros((zmax + 1, zmax + 1))
    for z1, z2, c in keys:
        table[z1, z2] = c
        table[z2, z1] = c
    return table


def primitive_neighbor_list(quantities, pbc, cell, positions, cutoff, numbers=None,
                            self_interaction=False, use_scaled_positions=False,
                            max_nbins=1e6, *, n_threads=None):
    """Neighbour list from raw arrays; drop-in for ASE's ``primitive_neighbor_list``.

    Parameters
    ----------
    quantities : str
        Characters of ``'ijdDS'``.
    pbc : (3,) sequence of bool
    cell : (3, 3) array_like of float
        Rows are the cell vectors (zero vectors allowed along open axes).
    positions : (n, 3) array_like of float
        Cartesian (or fractional with ``use_scaled_positions``).
    cutoff : float, (n,) array_like of float or dict
        Global cutoff, per-atom radii, or element-pair cutoffs (needs ``numbers``).
    numbers : (n,) array_like of int, optional
        Atomic numbers, for dict cutoffs.
    self_interaction : bool, optional
        Include ``(i, i)`` with zero shift.
    max_nbins : float, optional
        Ignored (ASE's binning parameter).
    n_threads : int, optional

    Returns
    -------
    One array per quantity (a single array if one quantity was asked for),
    rows sorted by ``i``, then ``j``, then ``S``.
    """
    _check_quantities(quantities)
    pbc = periodic.as_pbc(pbc)
    positions = as_coords(positions, "positions")
    n = len(positions)
    cell_arr = np.asarray(cell, dtype=np.float64)
    if cell_arr.shape != (3, 3):
        raise ValueError(f"cell must have shape (3, 3), got {cell_arr.shape}")
    if use_scaled_positions:
        positions = positions @ cell_arr
    n_threads = check_n_threads(n_threads)
    if n == 0:
        out = [np.empty(shape, dtype=dt) for shape, dt in (_EMPTY[q] for q in quantities)]
        return out[0] if len(out) == 1 else tuple(out)

    table = None
    if isinstance(cutoff, dict):
        if numbers is None:
            raise ValueError("a dict cutoff needs the atomic numbers (numbers=...)")
        numbers = np.asarray(numbers, dtype=np.int64)
        if numbers.shape != (n,):
            raise ValueError(f"numbers must have shape ({n},), got {numbers.shape}")
        table = _pair_cutoff_table(cutoff, numbers)
        maxc = float(table.max()) if table.size else 0.0
        rad = np.full(n, 0.5 * maxc)
    elif np.ndim(cutoff) == 0:
        c = _as_radii(cutoff, 1, "cutoff")[0]
        rad = np.full(n, 0.5 * c)
    else:
        rad = _as_radii(cutoff, n, "cutoff")

    # a hair of slack so that no candidate is lost to rounding in the kernel; the
    # strict ASE test below decides with ASE's own arithmetic
    slack = 1e-9 * (2.0 * rad.max() + 1e-300) + 1e-300
    if pbc.any():
        cellm = periodic.as_cell(cell_arr, "cell", pbc=pbc)
    else:
        cellm = None
    search = ContactSearch(skin=slack, periodic_images="all", quantities="ijS",
                           n_threads=n_threads)
    full = cellm is not None and _image_factor(2.0 * rad.max() + slack, cellm,
                                               pbc) > _IMAGE_FACTOR_MAX
    if full:
        # a cutoff many times the cell: the full list at once, from the cross-set
        # query of the atoms against themselves (every image of every pair, both
        # ways: no mirror), less each atom with itself at shift 0
        a, b, shift = search.query(positions, rad, positions, rad, cellm, pbc=pbc)
        other = (a != b) | shift.any(axis=1)
        a, b, shift = a[other], b[other], shift[other]
    else:
        a, b, shift = search.update(positions, rad, cellm, pbc=pbc)
    D = positions[b] - positions[a] + shift.dot(cell_arr)
    d = np.sqrt(np.sum(D * D, axis=1))
    if table is not None:
        thr = table[numbers[a], numbers[b]]
        keep = d < thr
    elif np.ndim(cutoff) == 0:
        keep = d < float(cutoff)
    else:
        keep = d < rad[a] + rad[b]
    a, b, shift, D, d = a[keep], b[keep], shift[keep], D[keep], d[keep]

    if full:
        i, j, S = a, b, shift
    else:  # both ways (ASE's arithmetic gives (j, i, -S) exactly -D and d)
        i = np.concatenate([a, b])
        j = np.concatenate([b, a])
        S = np.concatenate([shift, -shift])
        D = np.concatenate([D, -D])
        d = np.concatenate([d, d])
    if self_interaction:
        # ASE tests the self pair like any other, d = 0 < cutoff: an atom whose
        # cutoff with itself is zero is not its own neighbour
        if table is not None:
            own = table[numbers, numbers] > 0
        elif np.ndim(cutoff) == 0:
            own = np.full(n, float(cutoff) > 0)
        else:
            own = rad > 0
        idx = np.flatnonzero(own).astype(np.int64)
        k = len(idx)
        i = np.concatenate([i, idx])
        j = np.concatenate([j, idx])
        S = np.concatenate([S, np.zeros((k, 3), np.int64)])
        D = np.concatenate([D, np.zeros((k, 3))])
        d = np.concatenate([d, np.zeros(k)])
    # deterministic rows: by i, then j, then the shift S (lexicographically)
    order = np.lexsort((S[:, 2], S[:, 1], S[:, 0], j, i))
    values = {"i": i[order], "j": j[order], "S": S[order], "D": D[order], "d": d[order]}
    out = [np.ascontiguousarray(values[q]) for q in quantities]
    return out[0] if len(out) == 1 else tuple(out)


def neighbor_list(quantities, a, cutoff, self_interaction=False, max_nbins=1e6, *,
                  n_threads=None):
    """Neighbour list of an ``ase.Atoms``; drop-in for ``ase.neighborlist.neighbor_list``.

    Parameters
    ----------
    quantities : str
        Characters of ``'ijdDS'``: first index, second index, distance,
        distance vector, cell shift; returned in that order.
    a : ase.Atoms
        Positions, cell, pbc (and atomic numbers for dict cutoffs).
    cutoff : float, (n,) array_like of float or dict
        ``d < cutoff``; per-atom radii (``d < r_i + r_j``); or
        ``{(el1, el2): cutoff}`` with symbols or atomic numbers.
    self_interaction : bool, optional
        Include every atom as its own neighbour with zero shift.
    max_nbins : float, optional
        Ignored (ASE's binning parameter).
    n_threads : int, optional
        numba threads (granularsap extension).

    Returns
    -------
    One array per requested quantity, in order; a single array if one quantity.
    Rows are sorted by ``i``, then ``j``, then the shift ``S``.

    Raises
    ------
    ValueError
        Unknown quantity, negative cutoff, bad shapes, degenerate periodic cell.

    Examples
    --------
    >>> from ase.build import bulk
    >>> from granularsap.ase import neighbor_list
    >>> i, j = neighbor_list("ij", bulk("Cu", "fcc", a=3.6), 3.0)
    >>> len(i)  # 12 nearest neighbours of the one atom, all periodic images
    12
    """
    for attr in ("positions", "cell", "pbc", "numbers"):
        if not hasattr(a, attr):
            raise TypeError(f"a must be an ase.Atoms (missing .{attr}), got {type(a).__name__}")
    return primitive_neighbor_list(quantities, a.pbc, np.asarray(a.cell), a.positions, cutoff,
                                   numbers=a.numbers, self_interaction=self_interaction,
                                   max_nbins=max_nbins, n_threads=n_threads)


from .neighborlist import NeighborList  # noqa: E402  (stateful drop-in)
