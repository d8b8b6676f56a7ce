"""Periodic cells: parsing, wrapping, perpendicular widths and ghost images.

Conventions
-----------
A cell is a ``(3, 3)`` float64 matrix whose *rows* are the cell vectors
``a, b, c`` (ASE form), so Cartesian positions are ``x = s @ cell`` for
fractional coordinates ``s``.  The MDAnalysis form ``[lx, ly, lz, alpha, beta,
gamma]`` (degrees) is converted with the same formula as
``MDAnalysis.lib.mdamath.triclinic_vectors`` (``a`` along x, ``b`` in the xy
plane, exact zeros for right angles), so both libraries see the same matrix.

Periodic searches never require wrapped input.  Positions are wrapped into the
cell along periodic axes (``s - floor(s)``), and every particle whose
interaction range reaches past a face gets *ghost images* shifted by integer
combinations of cell vectors.  The test is done in fractional space: a point
is within distance ``r`` of the slab ``0 <= s_c <= 1`` iff its fractional
coordinate lies in ``[-r / w_c, 1 + r / w_c]``, where ``w_c`` is the
perpendicular width of the cell across axis ``c`` (volume / area of the
opposite face).  For a triclinic cell this width, not the vector length, is
what bounds the number of images.
"""

from __future__ import annotations

import numpy as np

from .cell import Cell, translate

__all__ = [
    "as_cell",
    "as_pbc",
    "cell_from_dimensions",
    "fractional",
    "ghost_images",
    "perpendicular_widths",
    "translate",
    "wrap",
]

#: Most ghost images one call may create (32 bytes each): a reach that needs
#: more is refused rather than exhausting memory.
MAX_GHOSTS = 1 << 28


def cell_from_dimensions(dimensions):
    """Cell matrix (rows are cell vectors) from ``[lx, ly, lz, alpha, beta, gamma]``.

    ``Cell.from_dimensions(dimensions).matrix`` as a fresh writable array:
    the construction of ``MDAnalysis.lib.mdamath.triclinic_vectors`` in
    float64, raising on invalid boxes instead of returning zeros.

    Parameters
    ----------
    dimensions : (6,) array_like of float
        Edge lengths and angles in degrees.

    Returns
    -------
    cell : (3, 3) ndarray of float64

    Raises
    ------
    ValueError
        If a length is not positive, an angle is outside (0, 180) or the
        angles do not form a cell of positive volume.

    Examples
    --------
    >>> cell_from_dimensions([10, 10, 10, 90, 90, 90])
    array([[10.,  0.,  0.],
           [ 0., 10.,  0.],
           [ 0.,  0., 10.]])
    """
    dim = np.asarray(dimensions)
    if dim.shape != (6,):
        raise ValueError(f"box must be [lx, ly, lz, alpha, beta, gamma], got shape {dim.shape}")
    return np.array(Cell.coerce(dim, name="box").matrix)


def as_cell(box, name="box", *, pbc=(True, True, True)):
    """Validate ``box`` and return a ``(3, 3)`` float64 cell matrix, or ``None``.

    ``Cell.coerce(box, pbc, name).full_matrix`` as a fresh writable array.

    Parameters
    ----------
    box : None, Cell, (6,) or (3, 3) array_like of float
        ``None`` for open boundaries, MDAnalysis ``[lx, ly, lz, alpha, beta,
        gamma]``, a matrix whose rows are the cell vectors, or a Cell.
    name : str
        Argument name used in error messages.
    pbc : (3,) sequence of bool
        Axes that are periodic.  Cell vectors of non-periodic axes may be zero
        (as in ASE); they are completed with a unit vector orthogonal to the
        others.

    Raises
    ------
    ValueError
        Wrong shape, non-finite entries, non-positive lengths or a singular
        (zero-volume) cell.
    TypeError
        Non-numeric input.
    """
    if box is None:
        return None
    return np.array(Cell.coerce(box, pbc=pbc, name=name).full_matrix)


def as_pbc(pbc):
    """Return ``pbc`` as a length-3 bool ndarray (a scalar applies to all axes)."""
    return Cell(np.eye(3), pbc).pbc.copy()


def perpendicular_widths(cell):
    """Distances between opposite faces of the cell, ``(3,)`` float64.

    ``w_c = volume / |a_{c+1} x a_{c+2}|``; equal to the edge lengths for an
    orthorhombic cell (``Cell.perpendicular_widths``).
    """
    return Cell(cell, False).perpendicular_widths.copy()


def fractional(positions, cell):
    """Fractional coordinates ``s`` with ``positions = s @ cell`` (``Cell.fractional``)."""
    return Cell(cell, False).fractional(positions)


def wrap(positions, cell, pbc=(True, True, True)):
    """Wrap positions into the cell along periodic axes (``Cell.wrap``).

    Parameters
    ----------
    positions : (n, 3) ndarray of float64
    cell : (3, 3) ndarray of float64
    pbc : (3,) sequence of bool

    Returns
    -------
    wrapped : (n, 3) ndarray of float64
        ``positions - shifts @ cell``; fractional coordinates in ``[0, 1)`` up to
        rounding on periodic axes, unchanged along open axes.
    shifts : (n, 3) ndarray of int64
        Integer cell offsets such that ``positions = wrapped + shifts @ cell``
        (up to rounding).

    Raises
    ------
    ValueError
        A position is ``2**52`` cell lengths or more outside the cell along a
        periodic axis (its wrapped value would carry no digit).
    """
    return Cell(cell, pbc).wrap(positions, return_shifts=True)


def ghost_images(wrapped, cell, pbc, reach):
    """Ghost images of particles whose range reaches beyond the cell faces.

    Parameters
    ----------
    wrapped : (n, 3) ndarray of float64
        Positions wrapped into the cell along periodic axes.
    cell : (3, 3) ndarray of float64
    pbc : (3,) ndarray of bool
    reach : (n,) ndarray of float64
        For particle ``i``, the largest distance from the cell at which an
        image of ``i`` can still interact with a particle inside the cell.

    Returns
    -------
    owner : (m,) ndarray of int64
        Particle index of each ghost.
    shift : (m, 3) ndarray of int64
        Lattice shift of each ghost: ghost position ``wrapped[owner] + shift @ cell``.
        Rows are ordered by shift (lexicographically), then by owner.

    Raises
    ------
    ValueError
        ``wrapped`` is not wrapped (a fractional coordinate of ``2**52`` or
        more), or ``reach`` needs more than ``MAX_GHOSTS`` images.

    Notes
    -----
    The images of particle ``i`` along periodic axis ``c`` are the integers
    ``t`` with ``-d <= s_c + t <= 1 + d`` (``d = reach_i / w_c``), found with
    ``ceil`` and ``floor``: the cost is proportional to ``n`` plus the number
    of ghosts, whatever the coordinates, never a loop over candidate images.
    """
    n = len(wrapped)
    empty = np.empty(0, np.int64), np.empty((0, 3), np.int64)
    pbc = np.asarray(pbc, dtype=bool)
    if n == 0 or not pbc.any():
        return empty
    cobj = Cell(cell, pbc)
    widths = cobj.perpendicular_widths
    s = cobj.fractional(wrapped)
    big = ~(np.abs(s[:, pbc]) < 2.0**52)
    if big.any():
        row = int(np.flatnonzero(big.any(axis=1))[0])
        raise ValueError("wrapped positions must lie in the cell along periodic axes (wrap "
                         f"them first), got fractional coordinates {s[row].tolist()} in row "
                         f"{row}")
    delta = reach[:, None] / widths[None, :]
    layers = np.where(pbc, np.ceil(delta.max(axis=0)), 0.0)
    # only particles near a face of some periodic axis can have images
    near = np.zeros(n, dtype=bool)
    for c in np.flatnonzero(pbc):
        near |= (s[:, c] < delta[:, c]) | (s[:, c] > 1.0 - delta[:, c])
    idx = np.flatnonzero(near)
    if len(idx) == 0:
        return empty
    s_n, d_n = s[idx], delta[idx]
    # per particle and axis, the image range lo..hi (within +-layers, as the
    # fractional test asks); open axes keep 0 only
    lo = np.zeros((len(idx), 3))
    hi = np.zeros((len(idx), 3))
    for c in np.flatnonzero(pbc):
        sc, dc = s_n[:, c], d_n[:, c]
        # the bounds, then settled by the test itself (s + t >= -d, s + t <= 1 + d)
        # so that rounding of -d - s cannot move them by one
        a = np.ceil(-dc - sc)
        a = np.where(sc + (a - 1.0) >= -dc, a - 1.0, a)
        a = np.where(sc + a < -dc, a + 1.0, a)
        b = np.floor(1.0 + dc - sc)
        b = np.where(sc + (b + 1.0) <= 1.0 + dc, b + 1.0, b)
        b = np.where(sc + b > 1.0 + dc, b - 1.0, b)
        lo[:, c] = np.maximum(a, -layers[c])
        hi[:, c] = np.minimum(b, layers[c])
    span = np.maximum(hi - lo + 1.0, 0.0)
    count_f = span.prod(axis=1)
    # the zero shift is not a ghost: drop it where it lies inside the ranges
    has_zero = np.all((lo <= 0) & (hi >= 0), axis=1)
    total = float(count_f.sum() - has_zero.sum())
    if total > MAX_GHOSTS:
        raise ValueError(f"reach {float(reach.max())!r} needs {total:.3g} ghost images, more "
                         f"than the supported {MAX_GHOSTS}; use a smaller cutoff or a larger "
                         "cell")
    count = count_f.astype(np.int64)
    keep = count > 0
    idx, lo, span, count = idx[keep], lo[keep].astype(np.int64), span[keep].astype(np.int64), \
        count[keep]
    # enumerate every (particle, image) in mixed radix: k = (t0 * span1 + t1) * span2 + t2
    rep = np.repeat(np.arange(len(idx)), count)
    start = np.cumsum(count) - count
    k = np.arange(int(count.sum()), dtype=np.int64) - start[rep]
    t2 = k % span[rep, 2]
    k //= span[rep, 2]
    t1 = k % span[rep, 1]
    t0 = k // span[rep, 1]
    shift = np.stack([t0, t1, t2], axis=1) + lo[rep]
    owner = idx[rep]
    nonzero = shift.any(axis=1)
    owner, shift = owner[nonzero], shift[nonzero]
    if len(owner) == 0:
        return empty
    order = np.lexsort((owner, shift[:, 2], shift[:, 1], shift[:, 0]))
    return owner[order], np.ascontiguousarray(shift[order])
