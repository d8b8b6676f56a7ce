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

import itertools

import numpy as np

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


def cell_from_dimensions(dimensions):
    """Cell matrix (rows are cell vectors) from ``[lx, ly, lz, alpha, beta, gamma]``.

    Same construction as ``MDAnalysis.lib.mdamath.triclinic_vectors`` but kept
    in float64 and raising on invalid boxes instead of returning zeros.

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
    dim = np.asarray(dimensions, dtype=np.float64)
    lx, ly, lz, alpha, beta, gamma = dim
    if not np.all(dim[:3] > 0):
        raise ValueError(f"box lengths must be positive, got {dim[:3].tolist()}")
    if not all(0.0 < ang < 180.0 for ang in (alpha, beta, gamma)):
        raise ValueError(f"box angles must lie strictly between 0 and 180 degrees, "
                         f"got {dim[3:].tolist()}")
    if alpha == beta == gamma == 90.0:
        return np.diag(dim[:3]).astype(np.float64)
    cell = np.zeros((3, 3), dtype=np.float64)
    cell[0, 0] = lx
    cos_alpha = 0.0 if alpha == 90.0 else np.cos(np.deg2rad(alpha))
    cos_beta = 0.0 if beta == 90.0 else np.cos(np.deg2rad(beta))
    if gamma == 90.0:
        cos_gamma, sin_gamma = 0.0, 1.0
    else:
        cos_gamma = np.cos(np.deg2rad(gamma))
        sin_gamma = np.sin(np.deg2rad(gamma))
    cell[1, 0] = ly * cos_gamma
    cell[1, 1] = ly * sin_gamma
    cell[2, 0] = lz * cos_beta
    cell[2, 1] = lz * (cos_alpha - cos_beta * cos_gamma) / sin_gamma
    disc = lz * lz - cell[2, 0] ** 2 - cell[2, 1] ** 2
    if not disc > 0:
        raise ValueError(f"box angles {dim[3:].tolist()} do not form a cell of positive "
                         "volume (each angle must be smaller than the sum of the other two)")
    cell[2, 2] = np.sqrt(disc)
    return cell


def as_cell(box, name="box", *, pbc=(True, True, True)):
    """Validate ``box`` and return a ``(3, 3)`` float64 cell matrix, or ``None``.

    Parameters
    ----------
    box : None, (6,) or (3, 3) array_like of float
        ``None`` for open boundaries, MDAnalysis ``[lx, ly, lz, alpha, beta,
        gamma]`` or a matrix whose rows are the cell vectors.
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
    arr = np.asarray(box)
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"{name} must be an array of real numbers, got dtype {arr.dtype}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    if arr.shape == (6,):
        return cell_from_dimensions(arr)
    if arr.shape != (3, 3):
        raise ValueError(f"{name} must be [lx, ly, lz, alpha, beta, gamma] or a (3, 3) "
                         f"matrix of cell vectors, got shape {arr.shape}")
    cell = np.array(arr, dtype=np.float64, order="C")
    pbc = as_pbc(pbc)
    norms = np.linalg.norm(cell, axis=1)
    for c in range(3):
        if norms[c] == 0 and pbc[c]:
            raise ValueError(f"{name} vector {c} is zero along a periodic axis; "
                             "give a cell of positive volume")
    if (norms == 0).any():
        cell = _complete_cell(cell)
    vol = abs(np.linalg.det(cell))
    if not vol > 1e-12 * max(norms.max(), 1.0) ** 3:
        raise ValueError(f"{name} is degenerate (zero volume): {arr.tolist()}")
    return cell


def _complete_cell(cell):
    """Replace zero rows by unit vectors orthogonal to the non-zero ones (ASE)."""
    cell = cell.copy()
    missing = np.flatnonzero(np.linalg.norm(cell, axis=1) == 0)
    present = [c for c in range(3) if c not in missing]
    if len(missing) == 3:
        return np.eye(3)
    if len(missing) == 2:
        v = cell[present[0]] / np.linalg.norm(cell[present[0]])
        trial = np.eye(3)[np.argmin(np.abs(v))]
        u1 = trial - v * (trial @ v)
        u1 /= np.linalg.norm(u1)
        u2 = np.cross(v, u1)
        cell[missing[0]], cell[missing[1]] = u1, u2
        if np.linalg.det(cell) < 0:
            cell[missing[1]] = -u2
        return cell
    m = missing[0]
    a, b = cell[(m + 1) % 3], cell[(m + 2) % 3]
    n = np.cross(a, b)
    cell[m] = n / np.linalg.norm(n)
    return cell


def as_pbc(pbc):
    """Return ``pbc`` as a length-3 bool ndarray (a scalar applies to all axes)."""
    arr = np.asarray(pbc)
    if arr.dtype.kind not in "biu":
        raise TypeError(f"pbc must be booleans, got dtype {arr.dtype}")
    arr = np.broadcast_to(arr.astype(bool), (3,)) if arr.ndim == 0 else arr.astype(bool)
    if arr.shape != (3,):
        raise ValueError(f"pbc must be a bool or three bools, got shape {arr.shape}")
    return np.array(arr, dtype=bool)


def perpendicular_widths(cell):
    """Distances between opposite faces of the cell, ``(3,)`` float64.

    ``w_c = volume / |a_{c+1} x a_{c+2}|``; equal to the edge lengths for an
    orthorhombic cell.
    """
    cell = np.asarray(cell, dtype=np.float64)
    if _is_diagonal(cell):
        return np.abs(np.diag(cell)).copy()
    vol = abs(np.linalg.det(cell))
    areas = np.array([np.linalg.norm(np.cross(cell[(c + 1) % 3], cell[(c + 2) % 3]))
                      for c in range(3)])
    return vol / areas


def _is_diagonal(cell):
    return not np.any(cell - np.diag(np.diag(cell)))


def fractional(positions, cell):
    """Fractional coordinates ``s`` with ``positions = s @ cell``."""
    if _is_diagonal(cell):
        return positions / np.diag(cell)
    return np.linalg.solve(cell.T, positions.T).T


def wrap(positions, cell, pbc=(True, True, True)):
    """Wrap positions into the cell along periodic axes.

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
    """
    pbc = as_pbc(pbc)
    s = fractional(positions, cell)
    shifts = np.floor(s).astype(np.int64)
    shifts[:, ~pbc] = 0
    wrapped = translate(positions, -shifts, cell)
    return wrapped, shifts


def translate(positions, shifts, cell):
    """``positions + shifts @ cell``, adding the cell vectors one at a time.

    Parameters
    ----------
    positions : (n, 3) array_like of float
    shifts : (n, 3) ndarray of int
    cell : (3, 3) ndarray of float64
    """
    out = np.array(positions, dtype=np.float64, copy=True)
    for c in range(3):
        nz = shifts[:, c] != 0
        if nz.any():
            out[nz] += shifts[nz, c, None].astype(np.float64) * cell[c]
    return out


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
    """
    n = len(wrapped)
    if n == 0 or not pbc.any():
        return np.empty(0, np.int64), np.empty((0, 3), np.int64)
    widths = perpendicular_widths(cell)
    s = fractional(wrapped, cell)
    delta = reach[:, None] / widths[None, :]
    layers = np.where(pbc, np.ceil(delta.max(axis=0)).astype(np.int64), 0)
    # only particles near a face of some periodic axis can have images
    near = np.zeros(n, dtype=bool)
    for c in np.flatnonzero(pbc):
        near |= (s[:, c] < delta[:, c]) | (s[:, c] > 1.0 - delta[:, c])
    idx = np.flatnonzero(near)
    s_n, d_n = s[idx], delta[idx]
    owners, shifts = [], []
    ranges = [range(-int(m), int(m) + 1) for m in layers]
    for t in itertools.product(*ranges):
        if t == (0, 0, 0):
            continue
        ok = np.ones(len(idx), dtype=bool)
        for c in range(3):
            if pbc[c]:
                sc = s_n[:, c] + t[c]
                ok &= (sc >= -d_n[:, c]) & (sc <= 1.0 + d_n[:, c])
        sel = idx[ok]
        if len(sel):
            owners.append(sel)
            shifts.append(np.broadcast_to(np.array(t, dtype=np.int64), (len(sel), 3)))
    if not owners:
        return np.empty(0, np.int64), np.empty((0, 3), np.int64)
    return np.concatenate(owners), np.ascontiguousarray(np.concatenate(shifts))
