"""The cell of one frame as the engine sees it: validated once, then handed down.

A box reaches the engine in any of the forms :meth:`granularsap.Cell.coerce`
accepts (a Cell, a matrix, LAMMPS or MDAnalysis dimensions, an ``ase.Atoms``).
:meth:`FrameCell.of` validates it, once per distinct box, and resolves it into
the one value every part of a search reads: the full matrix (open axes
completed), its inverse, the perpendicular widths, the volume and the rounding
figures.  Nothing below this module turns a matrix back into a Cell.

Open axes of a partly periodic box (LAMMPS ``f``/``s``/``m``, ASE
``pbc=False`` on an axis) only set a frame of reference: :func:`open_axes_normal`
replaces their vectors by ones normal to the periodic vectors, so that a tilt
towards an open axis cannot narrow the periodic widths.  The trajectory readers
(``io.pipeline.engine_cell``) and the searches both use it.

Examples
--------
>>> import numpy as np
>>> fc = FrameCell.of(np.diag([4.0, 5.0, 6.0]), [True, True, False])
>>> fc.pbc.tolist(), fc.widths[:2].tolist(), fc.diag
([True, True, False], [4.0, 5.0], True)
>>> fc.scaled(2.0).widths[:2].tolist()
[8.0, 10.0]
>>> FrameCell.of(None, None).cell is None
True
"""

from __future__ import annotations

import math

import numpy as np

from .cell import Cell, widths_of

__all__ = ["FrameCell", "open_axes_normal"]

_OPEN = np.zeros(3, bool)
_OPEN.flags.writeable = False


def open_axes_normal(matrix, pbc):
    """``matrix`` with the rows of open axes set to zero (a fresh float64 array).

    A :class:`Cell` completes zero rows with unit vectors normal to the others
    (``Cell.full_matrix``): given this matrix, the open axes are normal to the
    periodic ones, whatever the box's tilt towards them was.

    >>> open_axes_normal([[4.0, 0, 0], [0, 5.0, 0], [1.0, 2.0, 6.0]], [True, True, False])
    array([[4., 0., 0.],
           [0., 5., 0.],
           [0., 0., 0.]])
    """
    m = np.array(matrix, dtype=np.float64)
    m[~np.asarray(pbc, dtype=bool)] = 0.0
    return m


class FrameCell:
    """A frame's resolved cell: what every part of a search reads.

    Build with :meth:`of` (validates) or :meth:`scaled` (exact, no validation).
    ``cell`` is the full matrix, or None for open boundaries; ``matrix`` is the
    one the kernels take (the identity for open boundaries).
    """

    __slots__ = ("cell", "pbc", "matrix", "diag", "hinv", "widths", "key", "narrowest",
                 "magnitude", "fine", "min_periodic_width", "det", "all_periodic",
                 "any_periodic", "open_lengths")

    def __init__(self, cell, pbc):
        """From a full, valid matrix (or None) and its pbc: use :meth:`of`."""
        # read-only, whatever cell it comes from: a kernel compiles one signature
        # for it (numba types read-only and writable arrays apart)
        if pbc.flags.writeable:
            pbc = pbc.copy()
            pbc.flags.writeable = False
        self.cell, self.pbc = cell, pbc
        self.all_periodic = bool(pbc.all())
        self.any_periodic = bool(pbc.any())
        matrix = cell if cell is not None else np.eye(3)
        self.matrix = matrix
        self.diag = not np.any(matrix - np.diag(np.diag(matrix)))
        #: |matrix[c, c]| of each open axis, 0.0 for a periodic one (Python floats)
        self.open_lengths = tuple(0.0 if pbc[c] else abs(float(matrix[c, c])) for c in range(3))
        self.hinv = np.ascontiguousarray(np.linalg.inv(matrix)) if not self.diag else np.eye(3)
        self.widths = widths_of(matrix)
        self.key = matrix.tobytes() + pbc.tobytes()
        axes = np.flatnonzero(pbc)
        self.narrowest = [int(c) for c in axes[np.argsort(self.widths[axes], kind="stable")][:1]]
        entries = np.abs(cell) if cell is not None else np.zeros(0)
        self.magnitude = float(entries.max()) if cell is not None else 0.0
        # the smallest nonzero |entry| of the cell (inf for open boundaries)
        nonzero = entries[entries > 0]
        self.fine = float(nonzero.min()) if nonzero.size else math.inf
        self.min_periodic_width = float(self.widths[pbc].min()) if pbc.any() else math.inf
        with np.errstate(over="ignore", under="ignore"):
            # a cell beyond 2**340 wide has no finite volume (searches then run on
            # scaled coordinates, whose volume is taken again); it is only a cost figure
            self.det = abs(float(np.linalg.det(matrix)))

    @classmethod
    def of(cls, box, pbc, name="box"):
        """Validate ``box`` (anything :meth:`Cell.coerce` takes, or None) and ``pbc``.

        A box with no periodic axis is open boundaries (``cell`` None).  The
        unit vectors that complete open axes are scaled by a power of two (exact)
        to the size of the periodic ones: fractional coordinates of a cell 1e100
        wide must not mix with real coordinates along the open axes.
        """
        if box is None:
            if pbc is not None and Cell(np.eye(3), pbc).any_periodic:
                raise ValueError(f"pbc asks for periodic axes but {name} is None; give the "
                                 "cell")
            return cls(None, _OPEN)
        cell = Cell.coerce(box, pbc=pbc, name=name)
        if cell is None or not cell.any_periodic:
            return cls(None, _OPEN)
        open_axes = ~cell.pbc
        if open_axes.any() and cell.matrix[open_axes].any():
            cell = Cell(open_axes_normal(cell.matrix, cell.pbc), cell.pbc)
        full = np.array(cell.full_matrix, dtype=np.float64)
        if open_axes.any():
            size = np.abs(full[~open_axes]).max()
            full[open_axes] = np.ldexp(full[open_axes], int(np.frexp(size)[1]))
        return cls(full, np.array(cell.pbc, dtype=bool))

    def scaled(self, scale):
        """This cell times ``scale``, a power of two (exact): no validation."""
        return type(self)(None if self.cell is None else self.cell * scale, self.pbc)
