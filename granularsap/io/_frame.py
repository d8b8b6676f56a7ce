"""The :class:`Frame` record every reader yields, and cell conversions.

No physics here: a frame is what the file says, in particle-id order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..cell import Cell

__all__ = ["Frame", "box_to_cell", "cell_to_box"]


def box_to_cell(box):
    """Cell matrix (rows are vectors, ASE form) of an MDAnalysis box.

    ``Cell.from_dimensions(box).matrix`` as a fresh array.

    Parameters
    ----------
    box : (6,) array_like of float
        ``[lx, ly, lz, alpha, beta, gamma]``, angles in degrees.

    Returns
    -------
    cell : (3, 3) ndarray of float64
        ``a`` along x, ``b`` in the xy plane (the LAMMPS/MDAnalysis orientation).

    Raises
    ------
    ValueError
        A length that is not positive or angles that do not form a cell.
    """
    return np.array(Cell.from_dimensions(box).matrix)


def cell_to_box(cell):
    """MDAnalysis box ``[lx, ly, lz, alpha, beta, gamma]`` of a (3, 3) cell matrix.

    ``Cell(cell).dimensions`` as a fresh array.
    """
    return np.array(Cell(cell).dimensions)


@dataclass
class Frame:
    """One trajectory frame, particles in increasing id order.

    Attributes
    ----------
    index : int
        0-based position of the frame in the file.
    positions : (n, 3) ndarray of float64
        Cartesian coordinates as the file gives them (not re-wrapped).
    ids : (n,) ndarray of int64
        Particle ids, strictly increasing (LAMMPS ``id``, MDAnalysis ``ids``,
        ASE ``id`` array or ``0..n-1``).
    cell : (3, 3) ndarray of float64 or None
        Cell vectors as rows (ASE form); None when the file has no box.
    pbc : (3,) ndarray of bool
        Periodicity along each cell vector.
    origin : (3,) ndarray of float64
        Lower corner of the cell (LAMMPS ``xlo ylo zlo``; zeros otherwise).
    step : int or None
        Timestep (LAMMPS ``TIMESTEP``, MDAnalysis ``ts.data['step']``).
    time : float or None
    types : (n,) ndarray or None
    radius : (n,) ndarray of float64 or None
        From a ``radius`` column, or half a ``diameter`` column.
    molecule : (n,) ndarray of int64 or None
        Molecule or rigid-clump id (LAMMPS ``mol``).
    columns : dict of str to (n,) ndarray
        Every per-particle column the file has, by its name in the file.
    source : str
        Path of the file the frame came from.
    ids_given : bool
        False when the file has no particle ids and ``ids`` are row numbers
        (a LAMMPS dump without an ``id`` column, an ASE file without an ``id``
        array): then a particle is only known by its row.
    """

    index: int
    positions: np.ndarray
    ids: np.ndarray
    cell: np.ndarray | None = None
    pbc: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=bool))
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    step: int | None = None
    time: float | None = None
    types: np.ndarray | None = None
    radius: np.ndarray | None = None
    molecule: np.ndarray | None = None
    columns: dict = field(default_factory=dict)
    source: str = ""
    ids_given: bool = True

    @property
    def n_particles(self) -> int:
        return len(self.positions)

    @property
    def box(self):
        """MDAnalysis ``[lx, ly, lz, alpha, beta, gamma]`` of the cell, or None.

        None too when a cell vector is zero (an ASE slab's non-periodic axis).
        """
        if self.cell is None or not np.all(np.linalg.norm(self.cell, axis=1) > 0):
            return None
        return cell_to_box(self.cell)

    @property
    def cell_object(self):
        """The frame's :class:`granularsap.Cell` (cell, pbc and origin), or None.

        None when the file has no box.
        """
        if self.cell is None:
            return None
        return Cell(self.cell, self.pbc, origin=self.origin)

    def column(self, name):
        """A per-particle column by name; ``radius`` falls back to ``diameter / 2``."""
        if name in self.columns:
            return self.columns[name]
        if name == "radius" and self.radius is not None:
            return self.radius
        if name == "diameter" and self.radius is not None:
            return 2.0 * self.radius
        known = ", ".join(sorted(self.columns)) or "none"
        raise KeyError(f"no per-particle column {name!r} in {self.source or 'frame'} "
                       f"frame {self.index}; columns: {known}")

    def sorted_by_id(self) -> Frame:
        """Return this frame with rows in increasing id order (a no-op if already so)."""
        if len(self.ids) < 2 or np.all(self.ids[1:] > self.ids[:-1]):
            return self
        order = np.argsort(self.ids, kind="stable")

        def take(a):
            return None if a is None else a[order]

        self.positions = np.ascontiguousarray(self.positions[order])
        self.ids = self.ids[order]
        self.types = take(self.types)
        self.radius = take(self.radius)
        self.molecule = take(self.molecule)
        self.columns = {k: v[order] for k, v in self.columns.items()}
        return self
