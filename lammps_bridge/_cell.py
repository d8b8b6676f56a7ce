"""Periodic cells and their LAMMPS "restricted triclinic" form.

LAMMPS wants a cell whose first vector lies along +x, second in the xy plane
with positive y and third with positive z, with the origin at ``boxlo`` and
tilt factors no larger than half the box length they refer to.  Any cell can
be brought into that form by an isometry (a rotation, or a rotation and a
reflection for a left-handed cell) followed by a lattice reduction, neither
of which changes a distance or a neighbour.

The mapping from the caller's frame to the LAMMPS frame goes through
fractional coordinates, so that integer lattice shifts found in the LAMMPS
frame can be applied to the caller's own float64 coordinates: the exact
distance test then runs on the caller's numbers, not on rotated ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from granularsap import Cell
from granularsap.cell import open_directions
from granularsap.inputs import as_coords


def cell_from_box(box, pbc=None):
    """Return ``box`` as a ``(3, 3)`` float64 cell matrix (rows are cell vectors).

    ``granularsap.Cell.coerce(box, pbc).matrix`` as a fresh array.

    Parameters
    ----------
    box : (6,) array_like of float, (3, 3) array_like of float or Cell
        MDAnalysis form ``[lx, ly, lz, alpha, beta, gamma]`` (degrees), an
        ASE-style cell matrix or a :class:`granularsap.Cell`.
    pbc : three bools, optional
        Periodic axes (default: those of ``box``, all for an array): a cell
        vector of an open axis may be zero (an ASE slab).

    Raises
    ------
    ValueError
        On a wrong shape, non-finite values, non-positive lengths, impossible
        angles or a degenerate (zero-volume) cell.
    """
    return np.array(Cell.coerce(box, pbc=pbc, name="box").matrix)


def as_pbc(pbc, box):
    """Per-axis periodicity as a tuple of three bools.

    Default: all periodic for an array box, the box's own for a Cell or an
    ``ase.Atoms``.  ``pbc`` given with ``box=None`` must be all False.
    """
    if box is None:
        Cell.coerce(None, pbc=pbc, name="box")  # raises if pbc asks for periodic axes
        return (False, False, False)
    if pbc is None and not isinstance(box, Cell) and not hasattr(box, "get_cell"):
        return (True, True, True)
    # a Cell or an ase.Atoms brings its own pbc unless pbc overrides it
    return tuple(bool(f) for f in Cell.coerce(box, pbc=pbc, name="box").pbc)


def _restricted(v):
    """Lower-triangular LAMMPS form of the rows of ``v`` (same Gram matrix)."""
    xlo, xhi, ylo, yhi, zlo, zhi, xy, xz, yz = Cell(v, False).to_lammps()
    return np.array([[xhi - xlo, 0.0, 0.0], [xy, yhi - ylo, 0.0], [xz, yz, zhi - zlo]])


@dataclass
class LammpsFrame:
    """How the caller's coordinates map onto one LAMMPS box.

    ``vectors`` are the LAMMPS cell vectors written in the caller's frame (the
    periodic ones first, reduced; then one vector per open direction, normal
    to the periodic ones and long enough to hold every particle).  ``h`` is
    the same cell in LAMMPS's lower-triangular form.  ``frac`` are the
    particles' fractional coordinates in ``vectors`` before wrapping.
    """

    vectors: np.ndarray
    h: np.ndarray
    origin: np.ndarray
    n_periodic: int
    frac: np.ndarray

    @property
    def boundary(self):
        return " ".join("p" if k < self.n_periodic else "f" for k in range(3))

    def wrapped_lammps_positions(self):
        """Positions inside the LAMMPS box, in the LAMMPS frame (boxlo = 0)."""
        f = self.frac.copy()
        npd = self.n_periodic
        f[:, :npd] -= np.floor(f[:, :npd])
        f[:, :npd][f[:, :npd] >= 1.0] = 0.0
        return f @ self.h

    def lattice_shifts(self, frac_lammps):
        """Integer shifts K with ``frac = frac_lammps + K`` (zero on open axes)."""
        k = np.rint(self.frac - frac_lammps)
        k[:, self.n_periodic:] = 0.0
        return k


def lammps_frame(positions, cell, pbc, margin):
    """Build the :class:`LammpsFrame` for ``positions`` in ``cell`` with ``pbc``.

    ``margin`` is the free space kept between the particles and an open wall.
    """
    positions = as_coords(positions, "positions")
    periodic = [k for k in range(3) if pbc[k]]
    vecs = [cell[k].copy() for k in periodic]
    origin = np.zeros(3)
    for u in open_directions(np.array(vecs).reshape(-1, 3)):
        s = positions @ u if len(positions) else np.zeros(1)
        lo, hi = float(s.min()) - margin, float(s.max()) + margin
        vecs.append((hi - lo) * u)
        origin += lo * u
    v = np.array(vecs, dtype=np.float64)
    # reduce tilts of the periodic part so that LAMMPS accepts them
    h = _restricted(v)
    npd = len(periodic)
    if npd >= 2:
        m = np.rint(h[1, 0] / h[0, 0])
        v[1] -= m * v[0]
        h = _restricted(v)
    if npd == 3:
        m = np.rint(h[2, 1] / h[1, 1])
        v[2] -= m * v[1]
        h = _restricted(v)
        m = np.rint(h[2, 0] / h[0, 0])
        v[2] -= m * v[0]
        h = _restricted(v)
    frac = np.linalg.solve(v.T, (positions - origin).T).T if len(positions) else \
        np.empty((0, 3))
    return LammpsFrame(vectors=v, h=h, origin=origin, n_periodic=npd, frac=frac)
