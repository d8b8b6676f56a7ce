"""The periodic cell: one immutable, validated value for every ``box=`` argument.

A :class:`Cell` is a ``(3, 3)`` matrix whose *rows* are the cell vectors ``a,
b, c`` (ASE form, so Cartesian positions are ``x = origin + s @ matrix`` for
fractional coordinates ``s``), a per-axis periodicity ``pbc`` and an
``origin`` (the lower corner: LAMMPS ``boxlo``, ASE ``celldisp``).  It is
built once from any of the forms the neighbouring codes use (MDAnalysis
``dimensions``, a matrix, an ``ase.Atoms``, a LAMMPS dump header), validated
at construction, and read-only afterwards.

Wrapping costs the same for every finite coordinate: the integer shift along
a periodic axis is ``floor(s)`` of the fractional coordinate, never a loop
over images.  A coordinate whose fractional part cannot be represented after
wrapping (``|s| >= 2**52`` cell lengths away, where one float64 ulp is a
whole cell) is refused with a ``ValueError`` naming ``positions``.
"""

from __future__ import annotations

import numpy as np

from ._validate import as_coords

__all__ = ["MAX_FRACTIONAL", "Cell"]

#: Largest |fractional coordinate| along a periodic axis that can be wrapped:
#: beyond it one float64 ulp of the coordinate is a whole cell length.
MAX_FRACTIONAL = float(2**52)

_LAMMPS_OPEN = {"f", "s", "m"}


def as_pbc(pbc, name="pbc"):
    """``pbc`` as three bools: one bool (or 0/1) for every axis, or one per axis.

    Examples
    --------
    >>> as_pbc([1, 0, 1]).tolist()
    [True, False, True]
    """
    arr = np.asarray(pbc)
    if arr.dtype.kind not in "biu":
        raise TypeError(f"{name} must be a bool or three bools, got dtype {arr.dtype}")
    if arr.ndim == 0:
        arr = np.broadcast_to(arr, (3,))
    if arr.shape != (3,):
        raise ValueError(f"{name} must be a bool or three bools, got shape {arr.shape}")
    return np.array(arr, dtype=bool)



def as_open_axes(axes, name="open_axes"):
    """``axes`` as a sorted tuple of distinct axis numbers 0, 1, 2 (the axes to take
    as open whatever a file's boundaries say), or ValueError naming ``name``.

    Examples
    --------
    >>> as_open_axes([2, 0]), as_open_axes(())
    ((0, 2), ())
    """
    try:
        got = tuple(axes)
    except TypeError:
        got = (None,)
    if (any(isinstance(a, (bool, np.bool_)) or not isinstance(a, (int, np.integer))
            or not 0 <= a <= 2 for a in got) or len(set(got)) != len(got)):
        raise ValueError(f"{name} must be distinct axis numbers 0, 1, 2, got {axes!r}")
    return tuple(sorted(int(a) for a in got))

def open_directions(periodic):
    """Orthonormal directions normal to the periodic cell vectors ``periodic`` (rows,
    zero to three of them, independent): one per open axis, for a box that needs a
    vector along each (LAMMPS's, or a fully periodic stand-in).

    Examples
    --------
    >>> open_directions(np.array([[2.0, 0.0, 0.0], [1.0, 3.0, 0.0]])).tolist()
    [[0.0, 0.0, 1.0]]
    >>> len(open_directions(np.zeros((0, 3))))
    3
    """
    vecs = np.asarray(periodic, dtype=np.float64).reshape(-1, 3)
    if len(vecs) == 0:
        return np.eye(3)
    if len(vecs) == 1:
        a = vecs[0] / np.linalg.norm(vecs[0])
        e = np.eye(3)[int(np.argmin(np.abs(a)))]
        u1 = e - (e @ a) * a
        u1 /= np.linalg.norm(u1)
        return np.array([u1, np.cross(a, u1)])
    if len(vecs) == 2:
        u = np.cross(vecs[0], vecs[1])
        return (u / np.linalg.norm(u))[None, :]
    return np.zeros((0, 3))


def _real_array(x, name):
    arr = np.asarray(x)
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"{name} must be an array of real numbers, got dtype {arr.dtype}")
    arr = np.array(arr, dtype=np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def _matrix_from_dimensions(dim, name):
    """MDAnalysis ``triclinic_vectors`` in float64, raising on invalid boxes."""
    lx, ly, lz, alpha, beta, gamma = dim
    if not np.all(dim[:3] > 0):
        raise ValueError(f"{name} lengths must be positive, got {dim[:3].tolist()}")
    if not all(0.0 < ang < 180.0 for ang in (alpha, beta, gamma)):
        raise ValueError(f"{name} angles must be in (0, 180) degrees, got {dim[3:].tolist()}")
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
    # scaled by a power of two (the same bits) so that the squares cannot overflow
    e = int(np.frexp(lz)[1])
    c0, c1, lzs = np.ldexp(cell[2, 0], -e), np.ldexp(cell[2, 1], -e), np.ldexp(lz, -e)
    disc = lzs * lzs - c0 ** 2 - c1 ** 2
    if not disc > 0:
        raise ValueError(f"{name} angles {dim[3:].tolist()} do not form a cell of positive "
                         "volume (each angle must be smaller than the sum of the other two)")
    cell[2, 2] = np.ldexp(np.sqrt(disc), e)
    return cell


def _complete(cell):
    """Replace zero rows by unit vectors orthogonal to the non-zero ones (ASE)."""
    cell = cell.copy()
    missing = np.flatnonzero(~cell.any(axis=1))
    present = [c for c in range(3) if c not in missing]
    if len(missing) == 3:
        return np.eye(3)
    if len(missing) == 2:
        v = _pow2_scaled(cell[present[0]])
        v = v / np.linalg.norm(v)
        trial = np.eye(3)[np.argmin(np.abs(v))]
        u1 = trial - v * (trial @ v)
        u1 /= np.linalg.norm(u1)
        u2 = np.cross(v, u1)
        cell[missing[0]], cell[missing[1]] = u1, u2
        if np.linalg.det(cell) < 0:
            cell[missing[1]] = -u2
        return cell
    m = missing[0]
    a, b = _pow2_scaled(cell[(m + 1) % 3]), _pow2_scaled(cell[(m + 2) % 3])
    n = np.cross(a, b)
    cell[m] = n / np.linalg.norm(n)
    return cell


def _pow2_scaled(v):
    """``v`` times the power of two that brings its largest entry into [0.5, 1):
    exact, so directions and norms computed from it keep their bits, and squares
    can neither overflow nor underflow."""
    return np.ldexp(v, -np.frexp(np.abs(v).max(axis=-1))[1][..., None])


def _is_diagonal(m):
    return not np.any(m - np.diag(np.diag(m)))


def widths_of(full):
    """Perpendicular widths ``V / |a_{c+1} x a_{c+2}|`` of a complete, valid (3, 3)
    float64 matrix (:attr:`Cell.perpendicular_widths`, which validates first):
    the diagonal of an orthorhombic one exactly."""
    if _is_diagonal(full):
        return np.abs(np.diag(full)).copy()
    # on the cell scaled by a power of two (exact, the same bits) so that volumes
    # and areas neither overflow nor underflow
    e = int(np.frexp(np.abs(full).max())[1])
    cell = np.ldexp(full, -e)
    vol = abs(np.linalg.det(cell))
    areas = np.array([np.linalg.norm(np.cross(cell[(c + 1) % 3], cell[(c + 2) % 3]))
                      for c in range(3)])
    return np.ldexp(vol / areas, e)


def _readonly(a):
    a = np.array(a, dtype=a.dtype, order="C")
    a.flags.writeable = False
    return a


def _is_atoms(x):
    return hasattr(x, "get_cell") and hasattr(x, "pbc") and hasattr(x, "get_positions")


def lammps_pbc(boundary):
    """(3,) bool periodicity of LAMMPS boundary flags (``"pp pp ff"`` or a sequence
    of three flags): ``pp`` periodic, two of ``f``, ``s``, ``m`` open.

    Raises
    ------
    ValueError
        Not three flags, or a flag of another kind (named).

    Examples
    --------
    >>> lammps_pbc("pp fs pp").tolist()
    [True, False, True]
    """
    flags = boundary.split() if isinstance(boundary, str) else list(boundary)
    if len(flags) != 3 or not all(isinstance(f, str) and len(f) == 2 for f in flags):
        raise ValueError(f"boundary must be three LAMMPS boundary flags such as "
                         f"'pp pp ff', got {boundary!r}")
    pbc = []
    for f in flags:
        if f == "pp":
            pbc.append(True)
        elif set(f) <= _LAMMPS_OPEN:
            pbc.append(False)
        else:
            raise ValueError(f"boundary flag {f!r} in {boundary!r} is not a LAMMPS "
                             "boundary: use 'pp' (periodic) or two of 'f', 's', 'm'")
    return np.array(pbc)


class Cell:
    """An immutable, validated simulation cell with per-axis periodicity.

    Parameters
    ----------
    matrix : (3, 3) array_like of float
        Rows are the cell vectors.  A zero row is allowed on a non-periodic
        axis only (an ASE slab); it is completed internally by a unit vector
        orthogonal to the others (:attr:`full_matrix`).
    pbc : bool or (3,) sequence of bool
        Periodicity along each cell vector (default: all periodic).
    origin : (3,) array_like of float, optional
        Lower corner of the cell (LAMMPS ``boxlo``); zeros by default.

    Raises
    ------
    ValueError
        Wrong shape, non-finite entries, a zero vector on a periodic axis, or
        a degenerate (zero-volume) cell.
    TypeError
        Non-numeric input, or a ``pbc`` that is not booleans.

    Examples
    --------
    >>> from granularsap import Cell
    >>> cell = Cell.from_dimensions([10, 10, 10, 90, 90, 90])
    >>> cell.volume, cell.perpendicular_widths.tolist()
    (1000.0, [10.0, 10.0, 10.0])
    >>> cell.wrap([[12.0, -1.0, 5.0]]).tolist()
    [[2.0, 9.0, 5.0]]
    """

    __slots__ = ("_dimensions", "_full", "_matrix", "_origin", "_pbc", "_volume", "_widths")

    def __init__(self, matrix, pbc=True, *, origin=None):
        self._init(matrix, pbc, origin, "matrix")

    # ------------------------------------------------------------------ build
    @classmethod
    def _new(cls, matrix, pbc, origin, name):
        obj = object.__new__(cls)
        obj._init(matrix, pbc, origin, name)
        return obj

    def _init(self, matrix, pbc, origin, name):
        arr = _real_array(matrix, name)
        if arr.shape != (3, 3):
            raise ValueError(f"{name} must be a (3, 3) matrix of cell vectors, got shape "
                             f"{arr.shape}")
        flags = as_pbc(pbc)
        # the shape test runs on every vector scaled by a power of two (exact) to a
        # largest entry in [0.5, 1): whether a cell is degenerate depends on its
        # angles only, not on its units or on how its edge lengths compare
        unit = _pow2_scaled(arr)
        norms = np.linalg.norm(unit, axis=1)
        for c in range(3):
            if not arr[c].any() and flags[c]:
                raise ValueError(f"{name} vector {c} is zero along a periodic axis; {name} "
                                 "must be a non-degenerate cell of positive volume (or make "
                                 "that axis open: pbc False)")
        full = _complete(arr) if (norms == 0).any() else arr.copy()
        if (norms == 0).any():
            unit = _complete(unit)
        # exact for an orthorhombic cell, where det's LU rounding would show
        with np.errstate(over="ignore", under="ignore"):
            vol = abs(float(np.prod(np.diag(full)))) if _is_diagonal(full) else \
                abs(float(np.linalg.det(full)))
        if not abs(float(np.linalg.det(unit))) > 1e-12 * float(
                np.prod(np.linalg.norm(unit, axis=1))):
            raise ValueError(f"{name} must be a non-degenerate cell with positive volume, got "
                             f"{arr.tolist()}")
        if origin is None:
            org = np.zeros(3)
        else:
            org = _real_array(origin, "origin")
            if org.shape != (3,):
                raise ValueError(f"origin must have shape (3,), got {org.shape}")
        set_ = object.__setattr__
        set_(self, "_matrix", _readonly(arr))
        set_(self, "_full", _readonly(full))
        set_(self, "_pbc", _readonly(flags))
        set_(self, "_origin", _readonly(org + 0.0))
        set_(self, "_volume", float(vol))
        set_(self, "_widths", None)
        set_(self, "_dimensions", None)

    @classmethod
    def from_matrix(cls, m, pbc=True, origin=None):
        """A cell from a ``(3, 3)`` matrix whose rows are the cell vectors."""
        return cls._new(m, pbc, origin, "matrix")

    @classmethod
    def from_dimensions(cls, dimensions, pbc=True):
        """A cell from MDAnalysis ``[lx, ly, lz, alpha, beta, gamma]`` (degrees).

        Same construction as ``MDAnalysis.lib.mdamath.triclinic_vectors`` in
        float64 (``a`` along x, ``b`` in the xy plane, exact zeros for right
        angles), raising on an invalid box instead of returning zeros.
        """
        return cls._from_dimensions(dimensions, pbc, "dimensions")

    @classmethod
    def _from_dimensions(cls, dimensions, pbc, name):
        dim = _real_array(dimensions, name)
        if dim.shape != (6,):
            raise ValueError(f"{name} must be [lx, ly, lz, alpha, beta, gamma], got shape "
                             f"{dim.shape}")
        return cls._new(_matrix_from_dimensions(dim, name), pbc, None, name)

    @classmethod
    def from_ase(cls, atoms):
        """The cell of an ``ase.Atoms``: ``atoms.cell``, ``atoms.pbc`` and ``celldisp``.

        Zero cell vectors are allowed on non-periodic axes (a slab or a
        molecule in vacuum).
        """
        matrix = np.asarray(atoms.get_cell(), dtype=np.float64)
        origin = np.asarray(atoms.get_celldisp(), dtype=np.float64).reshape(3)
        return cls._new(matrix, np.asarray(atoms.pbc, dtype=bool), origin, "atoms.cell")

    @classmethod
    def from_lammps(cls, bounds, tilts=(0.0, 0.0, 0.0), boundary="pp pp pp"):
        """A cell from a LAMMPS dump header.

        Parameters
        ----------
        bounds : (3, 2) array_like of float
            The ``ITEM: BOX BOUNDS`` rows ``xlo_bound xhi_bound``, ``ylo_bound
            yhi_bound``, ``zlo_bound zhi_bound``.  For a triclinic box they
            include the tilt (LAMMPS docs, dump BOX BOUNDS).
        tilts : (3,) array_like of float
            ``xy xz yz`` (the third column of a triclinic header).
        boundary : str or sequence of 3 str
            The header's boundary flags, e.g. ``"pp pp pp"`` or ``"pp ff pp"``:
            ``p`` periodic; ``f``, ``s``, ``m`` open.

        Examples
        --------
        >>> cell = Cell.from_lammps([[0, 10], [0, 10], [-1, 1]], boundary="pp pp ff")
        >>> cell.pbc.tolist(), cell.origin.tolist()
        ([True, True, False], [0.0, 0.0, -1.0])
        """
        b = _real_array(bounds, "bounds")
        if b.shape != (3, 2):
            raise ValueError(f"bounds must be three rows of 'lo_bound hi_bound', got shape "
                             f"{b.shape}")
        t = _real_array(tilts, "tilts")
        if t.shape != (3,):
            raise ValueError(f"tilts must be (xy, xz, yz), got shape {t.shape}")
        pbc = lammps_pbc(boundary)
        (xlob, xhib), (ylob, yhib), (zlob, zhib) = b
        xy, xz, yz = t
        xlo = xlob - min(0.0, xy, xz, xy + xz)
        xhi = xhib - max(0.0, xy, xz, xy + xz)
        ylo = ylob - min(0.0, yz)
        yhi = yhib - max(0.0, yz)
        for axis, lo, hi in (("x", xlo, xhi), ("y", ylo, yhi), ("z", zlob, zhib)):
            if not hi > lo:
                raise ValueError(f"bounds give {axis}hi = {float(hi)!r} <= {axis}lo = "
                                 f"{float(lo)!r}; a LAMMPS box needs hi > lo on every axis")
        matrix = np.array([[xhi - xlo, 0.0, 0.0], [xy, yhi - ylo, 0.0], [xz, yz, zhib - zlob]])
        return cls._new(matrix, pbc, np.array([xlo, ylo, zlob]), "bounds")

    @classmethod
    def coerce(cls, box, pbc=None, name="box"):
        """Any accepted cell form as a :class:`Cell`, or ``None`` for open boundaries.

        Parameters
        ----------
        box : None, Cell, (6,) or (3, 3) array_like of float, or ase.Atoms
            ``None`` (open), a Cell, MDAnalysis ``[lx, ly, lz, alpha, beta,
            gamma]``, a matrix of cell vectors (rows) or an ``ase.Atoms``.
        pbc : bool or (3,) sequence of bool, optional
            Periodicity; ``None`` keeps the box's own (all periodic for an
            array).  Given with ``box=None`` it must be all False.
        name : str
            Argument name used in error messages.
        """
        if box is None:
            if pbc is not None and as_pbc(pbc).any():
                raise ValueError(f"pbc={tuple(bool(p) for p in as_pbc(pbc))} needs a {name}; "
                                 f"got {name}=None (give the cell, or pbc=False)")
            return None
        if isinstance(box, Cell):
            if pbc is None:
                return box
            return cls._new(box.matrix, pbc, box.origin, name)
        if _is_atoms(box):
            cell = cls.from_ase(box)
            return cell if pbc is None else cls._new(cell.matrix, pbc, cell.origin, name)
        arr = np.asarray(box)
        if arr.dtype.kind not in "fiu":
            raise TypeError(f"{name} must be an array of real numbers, a Cell or an ase.Atoms, "
                            f"got {type(box).__name__} of dtype {arr.dtype}")
        flags = True if pbc is None else pbc
        if arr.shape == (6,):
            return cls._from_dimensions(arr, flags, name)
        if arr.shape == (3, 3):
            return cls._new(arr, flags, None, name)
        raise ValueError(f"{name} must be [lx, ly, lz, alpha, beta, gamma] or a (3, 3) "
                         f"matrix of cell vectors, got shape {arr.shape}")

    # ------------------------------------------------------------ immutability
    def __setattr__(self, key, value):
        raise AttributeError(f"Cell is immutable; build a new one instead of setting {key!r}")

    def __delattr__(self, key):
        raise AttributeError("Cell is immutable")

    def __eq__(self, other):
        if not isinstance(other, Cell):
            return NotImplemented
        return (np.array_equal(self._matrix, other._matrix)
                and np.array_equal(self._pbc, other._pbc)
                and np.array_equal(self._origin, other._origin))

    def __hash__(self):
        # + 0.0 folds -0.0 into 0.0, which == already treats as equal
        return hash(((self._matrix + 0.0).tobytes(), self._pbc.tobytes(),
                     (self._origin + 0.0).tobytes()))

    def __repr__(self):
        pbc = tuple(bool(p) for p in self._pbc)
        org = "" if not self._origin.any() else f", origin={self._origin.tolist()}"
        return f"Cell({self._matrix.tolist()}, pbc={pbc}{org})"

    def __reduce__(self):
        return (_rebuild, (self._matrix.copy(), self._pbc.copy(), self._origin.copy()))

    # -------------------------------------------------------------- properties
    @property
    def matrix(self):
        """(3, 3) float64, read-only: the cell vectors as given (rows)."""
        return self._matrix

    @property
    def full_matrix(self):
        """(3, 3) float64, read-only: zero rows completed with orthogonal unit vectors."""
        return self._full

    @property
    def pbc(self):
        """(3,) bool, read-only: periodicity along each cell vector."""
        return self._pbc

    @property
    def origin(self):
        """(3,) float64, read-only: the lower corner of the cell."""
        return self._origin

    @property
    def any_periodic(self):
        """True when at least one axis is periodic."""
        return bool(self._pbc.any())

    @property
    def is_orthorhombic(self):
        """True when the (completed) cell vectors lie along x, y and z."""
        return _is_diagonal(self._full)

    @property
    def volume(self):
        """Volume of :attr:`full_matrix` (for a zero vector, of its unit completion)."""
        return self._volume

    @property
    def perpendicular_widths(self):
        """(3,) float64: distance between opposite faces, ``V / |a_{c+1} x a_{c+2}|``.

        Exactly the diagonal for an orthorhombic cell.
        """
        if self._widths is None:
            w = widths_of(self._full)
            object.__setattr__(self, "_widths", _readonly(w))
        return self._widths

    @property
    def dimensions(self):
        """(6,) float64 MDAnalysis ``[lx, ly, lz, alpha, beta, gamma]``, or None.

        None when a cell vector is zero (MDAnalysis has no form for it).  Same
        arithmetic as ``MDAnalysis.lib.mdamath.triclinic_box``, kept in float64.
        """
        if self._dimensions is None:
            m = self._matrix
            lengths = np.array([np.sqrt(v @ v) for v in m])
            if not np.all(lengths > 0):
                return None

            def angle(u, v, nu, nv):
                return np.rad2deg(np.arccos(np.clip(np.dot(u, v) / (nu * nv), -1.0, 1.0)))

            (a, b, c), (la, lb, lc) = m, lengths
            dim = np.array([la, lb, lc, angle(b, c, lb, lc), angle(a, c, la, lc),
                            angle(a, b, la, lb)], dtype=np.float64)
            object.__setattr__(self, "_dimensions", _readonly(dim))
        return self._dimensions

    # ----------------------------------------------------------------- methods
    def fractional(self, positions):
        """Fractional coordinates ``s`` with ``positions = origin + s @ full_matrix``.

        positions : (n, 3) array_like of float
        """
        return self._fractional(as_coords(positions, "positions"))

    def _fractional(self, positions):
        if self._origin.any():
            positions = positions - self._origin
        cell = self._full
        if _is_diagonal(cell):
            return positions / np.diag(cell)
        return np.linalg.solve(cell.T, positions.T).T

    def wrap(self, positions, *, return_shifts=False):
        """Wrap positions into the cell along periodic axes.

        Parameters
        ----------
        positions : (n, 3) array_like of float
        return_shifts : bool
            Also return the integer cell offsets.

        Returns
        -------
        wrapped : (n, 3) ndarray of float64
            ``positions - shifts @ matrix`` (cell vectors subtracted one at a
            time); fractional coordinates in ``[0, 1)`` up to rounding on
            periodic axes, unchanged along open axes.
        shifts : (n, 3) ndarray of int64
            Only with ``return_shifts``: ``positions = wrapped + shifts @
            matrix`` up to rounding; zero on open axes.

        Raises
        ------
        ValueError
            A position is ``2**52`` cell lengths or more away from the cell
            along a periodic axis: its wrapped value would carry no digit.
        """
        wrapped, shifts = self._wrap(as_coords(positions, "positions"))
        return (wrapped, shifts) if return_shifts else wrapped

    def _wrap(self, positions, name="positions"):
        pbc = self._pbc
        s = self._fractional(positions)
        shifts = np.zeros(s.shape, dtype=np.int64)
        if pbc.any() and len(s):
            sp = s[:, pbc]
            ok = np.abs(sp) < MAX_FRACTIONAL
            if not ok.all():
                row, col = np.argwhere(~ok)[0]
                axis = int(np.flatnonzero(pbc)[col])
                raise ValueError(
                    f"{name} must lie within 2**52 cell lengths of the cell along periodic "
                    f"axes (|fractional coordinate| < {MAX_FRACTIONAL:.4g}) to be wrapped; got "
                    f"fractional coordinate {float(sp[row, col]):.4g} on axis {axis} in row "
                    f"{int(row)} ({name}[{int(row)}] = {positions[row].tolist()})")
            shifts[:, pbc] = np.floor(sp).astype(np.int64)
        return translate(positions, -shifts, self._full), shifts

    def to_lammps(self):
        """The cell in LAMMPS's restricted triclinic form.

        Returns
        -------
        (xlo, xhi, ylo, yhi, zlo, zhi, xy, xz, yz) : tuple of float
            ``a`` along +x, ``b`` in the xy plane with positive y, ``c`` with
            positive z: the same lengths and angles as :attr:`full_matrix`
            (rotated, and reflected if left-handed), with ``xlo ylo zlo`` the
            origin.  Tilts are not reduced.
        """
        a, b, c = self._full
        ax = np.linalg.norm(a)
        bx = b @ a / ax
        by = np.sqrt(max(b @ b - bx * bx, 0.0))
        cx = c @ a / ax
        cy = (b @ c - bx * cx) / by
        cz = np.sqrt(max(c @ c - cx * cx - cy * cy, 0.0))
        xlo, ylo, zlo = (float(v) for v in self._origin)
        return (xlo, float(xlo + ax), ylo, float(ylo + by), zlo, float(zlo + cz),
                float(bx), float(cx), float(cy))


def translate(positions, shifts, cell):
    """``positions + shifts @ cell``, adding the cell vectors one at a time.

    positions : (n, 3) array_like of float; shifts : (n, 3) ndarray of int;
    cell : (3, 3) ndarray of float64.
    """
    out = np.array(positions, dtype=np.float64, copy=True)
    for c in range(3):
        nz = shifts[:, c] != 0
        if nz.any():
            # only rows with a shift are touched (a zero shift must not turn -0.0
            # into 0.0); ``where`` does that without gathering and scattering rows
            step = shifts[:, c, None].astype(np.float64) * cell[c]
            np.add(out, step, out=out, where=nz[:, None])
    return out


def _rebuild(matrix, pbc, origin):
    return Cell(matrix, pbc, origin=origin)
