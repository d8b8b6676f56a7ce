"""Periodic cells: parsing, wrapping and perpendicular widths (functions over :class:`Cell`).

Conventions
-----------
A cell is a ``(3, 3)`` float64 matrix whose *rows* are the cell vectors
``a, b, c`` (ASE form), so Cartesian positions are ``x = s @ cell`` for
fractional coordinates ``s``.  The MDAnalysis form ``[lx, ly, lz, alpha, beta,
gamma]`` (degrees) is converted with the same formula as
``MDAnalysis.lib.mdamath.triclinic_vectors`` (``a`` along x, ``b`` in the xy
plane, exact zeros for right angles), so both libraries see the same matrix.

Periodic searches never require wrapped input.  Positions are wrapped into the
cell along periodic axes (``s - floor(s)``).  A point is within distance ``r``
of the slab ``0 <= s_c <= 1`` iff its fractional coordinate lies in
``[-r / w_c, 1 + r / w_c]``, where ``w_c`` is the perpendicular width of the
cell across axis ``c`` (volume / area of the opposite face): for a triclinic
cell this width, not the vector length, bounds the periodic images in range.
"""

from __future__ import annotations

import numpy as np

from .cell import Cell, translate

__all__ = [
    "as_cell",
    "as_pbc",
    "cell_from_dimensions",
    "fractional",
    "perpendicular_widths",
    "translate",
    "wrap",
]

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


