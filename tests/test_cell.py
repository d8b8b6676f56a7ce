"""granularsap.Cell against MDAnalysis, ASE and LAMMPS; wrapping; far coordinates."""

from __future__ import annotations

import pickle
import signal
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import granularsap
from granularsap import Cell
from granularsap import periodic as pc

DATA = Path(__file__).resolve().parent.parent / "data"

DIMS = [
    [10.0, 10.0, 10.0, 90.0, 90.0, 90.0],
    [8.0, 9.0, 10.0, 90.0, 90.0, 60.0],
    [9.0, 10.0, 11.0, 75.0, 80.0, 105.0],
    [12.0, 7.0, 9.5, 100.0, 65.0, 80.0],
]


def _old_wrap(positions, cell, pbc):
    """The arithmetic of periodic.wrap before Cell: floor, then one cell vector at a time."""
    s = np.linalg.solve(cell.T, positions.T).T if np.any(cell - np.diag(np.diag(cell))) \
        else positions / np.diag(cell)
    shifts = np.floor(s).astype(np.int64)
    shifts[:, ~np.asarray(pbc)] = 0
    out = positions.copy()
    for c in range(3):
        nz = shifts[:, c] != 0
        out[nz] += (-shifts[nz, c, None]).astype(np.float64) * cell[c]
    return out, shifts


class _Timeout(Exception):
    pass


def _within(seconds, fn, *args, **kwargs):
    """Run ``fn`` in this process; fail (not hang) if it takes longer than ``seconds``."""

    def handler(signum, frame):
        raise _Timeout(f"{fn.__name__} did not return within {seconds} s")

    old = signal.signal(signal.SIGALRM, handler)
    signal.alarm(seconds)
    try:
        return fn(*args, **kwargs)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


class TestFromDimensions:
    @pytest.mark.parametrize("dims", DIMS)
    def test_matrix_is_mdanalysis_triclinic_vectors(self, dims):
        mdamath = pytest.importorskip("MDAnalysis.lib.mdamath")
        want = mdamath.triclinic_vectors(np.asarray(dims), dtype=np.float64)
        got = Cell.from_dimensions(dims).matrix
        np.testing.assert_allclose(got, want, rtol=1e-15, atol=1e-15)

    @pytest.mark.parametrize("dims", DIMS)
    def test_dimensions_are_mdanalysis_triclinic_box(self, dims):
        mdamath = pytest.importorskip("MDAnalysis.lib.mdamath")
        cell = Cell.from_dimensions(dims)
        want = mdamath.triclinic_box(*cell.matrix)  # float32 in MDAnalysis
        np.testing.assert_allclose(cell.dimensions, want, rtol=1e-6)
        np.testing.assert_allclose(cell.dimensions, dims, rtol=1e-12)

    def test_right_angles_are_exact_zeros(self):
        cell = Cell.from_dimensions([5, 6, 7, 90, 90, 120])
        assert cell.matrix[2, 0] == 0.0 and cell.matrix[2, 1] == 0.0 and cell.matrix[0, 1] == 0.0
        assert Cell.from_dimensions([5, 6, 7, 90, 90, 90]).dimensions.tolist() == \
            [5, 6, 7, 90, 90, 90]

    @pytest.mark.parametrize("dims", DIMS)
    def test_periodic_wrapper_returns_a_writable_copy(self, dims):
        m = pc.cell_from_dimensions(dims)
        assert np.array_equal(m, Cell.from_dimensions(dims).matrix) and m.flags.writeable

    @pytest.mark.parametrize("dims, match", [
        ([0, 1, 1, 90, 90, 90], r"dimensions lengths must be positive, got \[0.0, 1.0, 1.0\]"),
        ([1, 1, 1, 0, 90, 90], r"dimensions angles must be in \(0, 180\) degrees"),
        ([1, 1, 1, 20, 30, 60], r"do not form a cell of positive volume"),
        ([1, 1, 1, 90], r"dimensions must be \[lx, ly, lz, alpha, beta, gamma\], got shape"),
        ([1, 1, np.inf, 90, 90, 90], r"dimensions must be finite"),
    ])
    def test_invalid(self, dims, match):
        with pytest.raises(ValueError, match=match):
            Cell.from_dimensions(dims)


class TestFromMatrixAndAse:
    @pytest.mark.parametrize("dims", DIMS)
    def test_dimensions_are_ase_cellpar(self, dims):
        ase_cell = pytest.importorskip("ase.cell")
        rng = np.random.default_rng(3)
        m = Cell.from_dimensions(dims).matrix @ np.linalg.qr(rng.normal(size=(3, 3)))[0]
        np.testing.assert_allclose(Cell.from_matrix(m).dimensions,
                                   ase_cell.Cell(m).cellpar(), rtol=1e-12)

    @pytest.mark.parametrize("pbc", [(True, True, True), (True, False, True),
                                     (False, False, True), (False, False, False)])
    def test_from_ase_with_zero_vectors_on_open_axes(self, pbc):
        ase = pytest.importorskip("ase")
        m = np.array([[6.0, 0, 0], [1.0, 7.0, 0], [0.5, -1.0, 8.0]])
        m[~np.asarray(pbc)] = 0.0
        atoms = ase.Atoms("H2", positions=[[0, 0, 0], [1, 1, 1]], cell=m, pbc=pbc)
        cell = Cell.from_ase(atoms)
        assert np.array_equal(cell.matrix, m) and cell.pbc.tolist() == list(pbc)
        full = cell.full_matrix
        assert abs(np.linalg.det(full)) > 0
        for k in np.flatnonzero(~np.asarray(pbc)):  # unit vectors normal to the others
            assert np.isclose(np.linalg.norm(full[k]), 1.0)
            for j in range(3):
                if j != k:
                    assert abs(full[k] @ full[j]) < 1e-12
        assert cell.dimensions is None if not all(pbc) else cell.dimensions is not None
        assert Cell.coerce(atoms) == cell

    def test_from_ase_celldisp_is_the_origin(self):
        ase = pytest.importorskip("ase")
        atoms = ase.Atoms("H", positions=[[0, 0, 0]], cell=[5, 5, 5], pbc=True,
                          celldisp=[1.0, -2.0, 0.5])
        assert Cell.from_ase(atoms).origin.tolist() == [1.0, -2.0, 0.5]

    @pytest.mark.parametrize("pbc", [(True, True, True), (True, False, True), (False, True, False)])
    @pytest.mark.parametrize("dims", DIMS)
    def test_wrap_equals_ase_wrap_positions(self, dims, pbc):
        geometry = pytest.importorskip("ase.geometry")
        rng = np.random.default_rng(5)
        cell = Cell.from_dimensions(dims, pbc=pbc)
        pos = rng.uniform(-35, 45, (300, 3))
        want = geometry.wrap_positions(pos, cell.matrix, pbc=pbc, eps=0.0)
        got, shifts = cell.wrap(pos, return_shifts=True)
        s = cell.fractional(got)
        inner = np.all((s[:, list(pbc)] > 1e-9) & (s[:, list(pbc)] < 1 - 1e-9), axis=1)
        np.testing.assert_allclose(got[inner], want[inner], rtol=0, atol=1e-11)
        assert np.all(shifts[:, ~np.asarray(pbc)] == 0)
        assert np.array_equal(got[:, ~np.asarray(pbc)] if not any(pbc) else got, got)

    def test_ase_atoms_wrap(self):
        ase = pytest.importorskip("ase")
        rng = np.random.default_rng(6)
        atoms = ase.Atoms("H50", positions=rng.uniform(-20, 30, (50, 3)),
                          cell=Cell.from_dimensions(DIMS[3]).matrix, pbc=[True, True, False])
        got = Cell.from_ase(atoms).wrap(atoms.positions)
        atoms.wrap(eps=0.0)
        np.testing.assert_allclose(got, atoms.positions, rtol=0, atol=1e-11)


def _header(path):
    """(bounds (3, 2), tilts (3,), boundary) of the first BOX BOUNDS of a dump."""
    lines = Path(path).read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("ITEM: BOX BOUNDS"))
    words = lines[k].split()[3:]
    rows = np.array([[float(v) for v in lines[k + 1 + r].split()] for r in range(3)])
    tilts = rows[:, 2] if "xy" in words else np.zeros(3)
    flags = [w for w in words if w not in ("xy", "xz", "yz")]
    return rows[:, :2], tilts, " ".join(flags)


class TestFromLammps:
    @pytest.mark.lammps
    @pytest.mark.parametrize("boundary, prism", [
        ("p p p", "0 10 0 9 0 8 0 0 0"),
        ("p f p", "-1 9 0.5 8 -2 7 1.5 -0.7 0.9"),
        ("p p p", "0 10 0 9 0 8 -2.5 3.0 -1.25"),
        ("f s m", "2 5 -3 4 0 9 0.3 0.2 0.1"),
    ])
    def test_header_written_by_lammps(self, tmp_path, boundary, prism):
        from lammps_bridge._loader import new_lammps

        lmp = new_lammps()
        dump = tmp_path / "box.dump"
        lmp.commands_string(f"""units lj
boundary {boundary}
region b prism {prism}
create_box 1 b
create_atoms 1 single 3 1 1
mass 1 1
write_dump all atom {dump}
""")
        boxlo, boxhi, xy, yz, xz, periodicity, _ = lmp.extract_box()
        lmp.close()
        cell = Cell.from_lammps(*_header(dump))
        assert cell.pbc.tolist() == [bool(p) for p in periodicity]
        np.testing.assert_allclose(cell.origin, boxlo, rtol=1e-14, atol=1e-14)
        want = np.array([[boxhi[0] - boxlo[0], 0, 0], [xy, boxhi[1] - boxlo[1], 0],
                         [xz, yz, boxhi[2] - boxlo[2]]])
        np.testing.assert_allclose(cell.matrix, want, rtol=1e-14, atol=1e-14)
        xlo, xhi, ylo, yhi, zlo, zhi, t_xy, t_xz, t_yz = cell.to_lammps()
        np.testing.assert_allclose([xlo, ylo, zlo, xhi, yhi, zhi, t_xy, t_xz, t_yz],
                                   [*boxlo, *boxhi, xy, xz, yz], rtol=1e-14, atol=1e-14)

    def test_bundled_triclinic_dump_matches_the_reader(self):
        from granularsap.io import iter_frames

        frame = next(iter(iter_frames(str(DATA / "lj.dump"))))
        cell = Cell.from_lammps(*_header(DATA / "lj.dump"))
        assert np.array_equal(cell.matrix, frame.cell)
        assert np.array_equal(cell.origin, frame.origin)
        assert frame.cell_object == cell and cell.pbc.all()
        assert not cell.is_orthorhombic

    def test_mixed_boundary_flags(self):
        cell = Cell.from_lammps([[0, 10], [0, 10], [-1, 1]], boundary="pp ff pp")
        assert cell.pbc.tolist() == [True, False, True]
        cell = Cell.from_lammps([[0, 10], [0, 10], [-1, 1]], boundary=["fs", "pp", "mm"])
        assert cell.pbc.tolist() == [False, True, False]

    def test_to_lammps_rotates_any_cell_into_the_restricted_form(self):
        rng = np.random.default_rng(8)
        q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        base = Cell.from_dimensions(DIMS[2])
        rotated = Cell(base.matrix @ q, origin=[1.0, 2.0, 3.0])
        xlo, xhi, ylo, yhi, zlo, zhi, xy, xz, yz = rotated.to_lammps()
        h = np.array([[xhi - xlo, 0, 0], [xy, yhi - ylo, 0], [xz, yz, zhi - zlo]])
        np.testing.assert_allclose(h, base.matrix, rtol=1e-12, atol=1e-12)
        assert (xlo, ylo, zlo) == (1.0, 2.0, 3.0)

    @pytest.mark.parametrize("args, match", [
        (([[0, 1], [0, 1]],), r"bounds must be three rows of 'lo_bound hi_bound', got shape"),
        (([[0, 1], [0, 1], [0, 1]], [0, 0]), r"tilts must be \(xy, xz, yz\), got shape \(2,\)"),
        (([[1, 1], [0, 1], [0, 1]],), r"bounds give xhi = 1.0 <= xlo = 1.0"),
        (([[0, 1], [0, 1], [0, 1]], (0, 0, 0), "pp pp"), r"boundary must be three LAMMPS"),
        (([[0, 1], [0, 1], [0, 1]], (0, 0, 0), "pp pf pp"),
         r"boundary flag 'pf' in 'pp pf pp' is not a LAMMPS boundary"),
        (([[0, 1], [0, 1], [0, np.nan]],), r"bounds must be finite"),
    ])
    def test_invalid(self, args, match):
        with pytest.raises(ValueError, match=match):
            Cell.from_lammps(*args)


class TestValueObject:
    def test_immutable(self):
        cell = Cell.from_dimensions(DIMS[1])
        with pytest.raises(AttributeError, match="Cell is immutable"):
            cell.pbc = False
        with pytest.raises(AttributeError, match="Cell is immutable"):
            del cell.matrix
        for arr in (cell.matrix, cell.full_matrix, cell.pbc, cell.origin, cell.dimensions,
                    cell.perpendicular_widths):
            with pytest.raises(ValueError, match="read-only"):
                arr[0] = 1

    def test_input_is_copied(self):
        m = np.diag([3.0, 4.0, 5.0])
        cell = Cell(m)
        m[0, 0] = 99.0
        assert cell.matrix[0, 0] == 3.0

    def test_eq_hash_repr_pickle(self):
        a = Cell([[4.0, 0, 0], [1, 5, 0], [0, 0, 6]], [True, False, True], origin=[1, 2, 3])
        b = Cell(np.array(a.matrix), a.pbc, origin=a.origin)
        assert a == b and hash(a) == hash(b) and len({a, b}) == 1
        assert a != Cell(a.matrix, True, origin=a.origin) and a != Cell(a.matrix, a.pbc)
        assert a != "box"
        neg = Cell([[4.0, -0.0, 0], [1, 5, 0], [0, 0, 6]], [True, False, True], origin=[1, 2, 3])
        assert neg == a and hash(neg) == hash(a)
        assert repr(a) == ("Cell([[4.0, 0.0, 0.0], [1.0, 5.0, 0.0], [0.0, 0.0, 6.0]], "
                           "pbc=(True, False, True), origin=[1.0, 2.0, 3.0])")
        assert pickle.loads(pickle.dumps(a)) == a
        assert eval(repr(a), {"Cell": Cell}) == a

    def test_properties(self):
        cell = Cell(np.diag([3.0, 4.0, 5.0]), [True, True, False])
        assert cell.volume == 60.0
        assert cell.is_orthorhombic and cell.any_periodic
        assert cell.perpendicular_widths.tolist() == [3.0, 4.0, 5.0]
        assert not Cell(np.eye(3), False).any_periodic
        assert Cell(np.diag([3.0, 0.0, 0.0]), [True, False, False]).volume == 3.0

    @pytest.mark.parametrize("dims", DIMS)
    def test_widths_are_face_distances(self, dims):
        cell = Cell.from_dimensions(dims)
        recip = np.linalg.inv(cell.matrix).T
        np.testing.assert_allclose(cell.perpendicular_widths,
                                   1.0 / np.linalg.norm(recip, axis=1), rtol=1e-13)
        assert cell.volume == pytest.approx(abs(np.linalg.det(cell.matrix)), rel=1e-14)

    def test_fractional_relative_to_origin(self):
        rng = np.random.default_rng(9)
        cell = Cell(Cell.from_dimensions(DIMS[3]).matrix, origin=[5.0, -3.0, 2.0])
        s = rng.uniform(-2, 3, (40, 3))
        pos = cell.origin + s @ cell.matrix
        np.testing.assert_allclose(cell.fractional(pos), s, atol=1e-12)

    @pytest.mark.parametrize("args, kwargs, exc, match", [
        (([1, 2, 3],), {}, ValueError, r"matrix must be a \(3, 3\) matrix of cell vectors"),
        ((np.diag([1.0, 0.0, 1.0]),), {}, ValueError,
         r"matrix vector 1 is zero along a periodic axis; matrix must be a non-degenerate"),
        (([[1, 0, 0], [0, 1, 0], [1, 1, 0]],), {}, ValueError,
         r"matrix must be a non-degenerate cell with positive volume"),
        (([["a"] * 3] * 3,), {}, TypeError, r"matrix must be an array of real numbers"),
        ((np.eye(3),), {"origin": [0, 0]}, ValueError, r"origin must have shape \(3,\)"),
        ((np.eye(3),), {"origin": [0, 0, np.nan]}, ValueError, r"origin must be finite"),
        ((np.eye(3), [True, False]), {}, ValueError, r"pbc must be a bool or three bools, got "
                                                     r"shape \(2,\)"),
        ((np.eye(3), "yes"), {}, TypeError, r"pbc must be a bool or three bools, got dtype"),
    ])
    def test_invalid(self, args, kwargs, exc, match):
        with pytest.raises(exc, match=match):
            Cell(*args, **kwargs)


class TestCoerce:
    def test_forms(self):
        ase = pytest.importorskip("ase")
        cell = Cell.from_dimensions(DIMS[2])
        assert Cell.coerce(None) is None and Cell.coerce(None, pbc=False) is None
        assert Cell.coerce(cell) is cell
        assert Cell.coerce(DIMS[2]) == cell
        assert Cell.coerce(cell.matrix) == cell
        atoms = ase.Atoms("H", positions=[[0, 0, 0]], cell=cell.matrix, pbc=[1, 0, 1])
        assert Cell.coerce(atoms).pbc.tolist() == [True, False, True]
        assert Cell.coerce(atoms, pbc=True).pbc.all()

    def test_pbc_overrides_a_cell(self):
        cell = Cell(np.diag([4.0, 5.0, 6.0]), origin=[1, 1, 1])
        other = Cell.coerce(cell, pbc=[True, False, True])
        assert other.pbc.tolist() == [True, False, True] and np.array_equal(other.origin, [1] * 3)
        assert Cell.coerce(cell, pbc=True) == cell

    @pytest.mark.parametrize("box, pbc, exc, match", [
        (None, True, ValueError, r"pbc=\(True, True, True\) needs a cell; got cell=None"),
        ([1, 2], None, ValueError, r"cell must be \[lx, ly, lz, alpha, beta, gamma\] or a "
                                   r"\(3, 3\) matrix of cell vectors, got shape \(2,\)"),
        ("box", None, TypeError, r"cell must be an array of real numbers, a Cell or an "
                                 r"ase.Atoms, got str"),
        ([0, 1, 1, 90, 90, 90], None, ValueError, r"cell lengths must be positive"),
        (np.diag([1.0, 0.0, 1.0]), None, ValueError, r"cell vector 1 is zero along a periodic"),
        (Cell(np.diag([1.0, 0.0, 1.0]), [True, False, True]), True, ValueError,
         r"cell vector 1 is zero along a periodic"),
    ])
    def test_errors_name_the_argument(self, box, pbc, exc, match):
        with pytest.raises(exc, match=match):
            Cell.coerce(box, pbc=pbc, name="cell")

    def test_every_box_argument_takes_a_cell(self):
        rng = np.random.default_rng(10)
        pos = rng.uniform(0, 10, (60, 3))
        radii = rng.uniform(0.3, 0.8, 60)
        cell = Cell.from_dimensions(DIMS[2])
        a = granularsap.neighbor_pairs(pos, 2.0, box=DIMS[2])
        b = granularsap.neighbor_pairs(pos, 2.0, box=cell)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
        a = granularsap.sphere_contacts(pos, radii, box=DIMS[2])
        assert np.array_equal(a, granularsap.sphere_contacts(pos, radii, box=cell))


class TestWrap:
    @pytest.mark.parametrize("pbc", [(True, True, True), (False, True, True), (True, False, False)])
    @pytest.mark.parametrize("dims", DIMS)
    def test_bit_for_bit_the_previous_arithmetic(self, dims, pbc):
        rng = np.random.default_rng(11)
        cell = Cell.from_dimensions(dims, pbc=pbc)
        pos = rng.uniform(-1e4, 1e4, (500, 3))
        want, wshift = _old_wrap(pos, np.array(cell.matrix), pbc)
        got, shifts = cell.wrap(pos, return_shifts=True)
        assert np.array_equal(got, want) and np.array_equal(shifts, wshift)
        assert shifts.dtype == np.int64
        w, s = pc.wrap(pos, np.array(cell.matrix), pbc)
        assert np.array_equal(w, want) and np.array_equal(s, wshift)

    def test_origin_is_the_lower_corner(self):
        cell = Cell(np.diag([10.0, 10.0, 10.0]), origin=[-5.0, 0.0, 100.0])
        assert cell.wrap([[-6.0, 11.0, 99.0], [4.0, 0.0, 110.0]]).tolist() == \
            [[4.0, 1.0, 109.0], [4.0, 0.0, 100.0]]

    def test_far_but_representable_coordinates_wrap_exactly(self):
        cell = Cell(np.diag([2.0**20] * 3))
        got, shifts = cell.wrap([[2.0**66 + 2.0**19, -3 * 2.0**60, 0.25]], return_shifts=True)
        assert got.tolist() == [[2.0**19, 0.0, 0.25]]
        assert shifts.tolist() == [[2**46, -3 * 2**40, 0]]

    @pytest.mark.parametrize("x", [1e20, -1e20, 1e300, 1.7e308])
    def test_coordinates_beyond_2_52_cells_are_refused(self, x):
        cell = Cell(np.diag([10.0, 10.0, 10.0]), [False, True, True])
        assert cell.wrap([[x, 1.0, 1.0]]).tolist() == [[x, 1.0, 1.0]]  # open axis: untouched
        with pytest.raises(ValueError, match=r"positions must lie within 2\*\*52 cell lengths "
                                             r"of the cell along periodic axes .* on axis 1 in "
                                             r"row 1 \(positions\[1\] = "):
            cell.wrap([[0.0, 1.0, 1.0], [0.0, x, 1.0]])
        with pytest.raises(ValueError, match=r"positions must lie within 2\*\*52 cell lengths"):
            pc.wrap(np.array([[x, 0.0, 0.0]]), np.eye(3) * 10)

    def test_empty_and_refused_shapes(self):
        cell = Cell(np.eye(3))
        w, s = cell.wrap(np.empty((0, 3)), return_shifts=True)
        assert w.shape == (0, 3) and s.shape == (0, 3) and s.dtype == np.int64
        with pytest.raises(ValueError, match=r"positions must have shape \(n, 3\), got \(3,\)"):
            cell.wrap([1.0, 2.0, 3.0])
        with pytest.raises(TypeError, match=r"positions must be an array of real numbers, got "
                                            r"dtype bool"):
            cell.wrap(np.ones((2, 3), bool))
        with pytest.raises(ValueError, match=r"positions must be finite, got NaN or inf in row 1"):
            cell.fractional([[0, 0, 0], [0, np.inf, 0]])


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), dims=st.sampled_from(DIMS),
       k=st.tuples(*[st.integers(-10**6, 10**6)] * 3),
       pbc=st.tuples(st.booleans(), st.booleans(), st.booleans()))
def test_wrap_idempotent_and_lattice_invariant(seed, dims, k, pbc):
    rng = np.random.default_rng(seed)
    cell = Cell.from_dimensions(dims, pbc=pbc)
    m = cell.matrix
    pos = rng.uniform(-50, 50, (30, 3))
    once = cell.wrap(pos)
    twice = cell.wrap(once)
    k = np.asarray(k) * np.asarray(pbc)
    moved = cell.wrap(pos + k @ m)
    scale = 1e-12 * (50 + np.abs(k @ m).max())
    for other in (twice, moved):
        # equal up to rounding, or one whole cell apart where rounding crossed a face
        ds = cell.fractional(other) - cell.fractional(once)
        assert np.all(np.abs(ds - np.rint(ds)) < scale + 1e-12)
        assert np.all(np.abs(np.rint(ds)) <= 1)
        assert np.all(np.rint(ds)[:, ~np.asarray(pbc)] == 0)
    s = cell.fractional(once)[:, list(pbc)]
    assert np.all(s >= -1e-12) and np.all(s < 1 + 1e-12)


class TestFarOutsideTheCell:
    """Issue 12 item 1: no hang at 1e20 outside the cell, a clear error at 1e300."""

    def test_1e20_outside_answers_without_hanging(self):
        box = [1e6, 1e6, 1e6, 90, 90, 90]
        pos = np.array([[1e20, 0.0, 0.0], [1.0, 0.0, 0.0], [5.0, 5.0, 5.0]])
        near = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [5.0, 5.0, 5.0]])  # 1e20 = 1e14 cells
        pairs, d = _within(60, granularsap.neighbor_pairs, pos, 1.5, box=box)
        want, wd = granularsap.neighbor_pairs(near, 1.5, box=box)
        assert np.array_equal(pairs, want) and wd.tolist() == [1.0]
        # the distance is the documented arithmetic on the positions as given
        # (docs/cells.md, Arithmetic): (1 - 1e20) + 1e14 * 1e6 rounds to 0, one ulp
        # of 1e20 being 16384 -- not the 1.0 of the wrapped copy
        assert d.tolist() == [abs((pos[1, 0] - pos[0, 0]) + 1e14 * 1e6)] == [0.0]
        got = _within(60, granularsap.sphere_contacts, pos, [0.6, 0.6, 0.6], box=box)
        assert np.array_equal(got, granularsap.sphere_contacts(near, [0.6] * 3, box=box))

    @pytest.mark.parametrize("x", [1e20, 1e300])
    def test_beyond_the_representable_range_is_a_clear_error(self, x):
        pos = np.array([[x, 0.0, 0.0], [1.0, 0.0, 0.0]])
        box = [10, 10, 10, 90, 90, 90]
        for call in (lambda: granularsap.neighbor_pairs(pos, 1.5, box=box),
                     lambda: granularsap.sphere_contacts(pos, [0.5, 0.5], box=box)):
            with pytest.raises(ValueError, match=r"positions.*2\*\*52 cell lengths"):
                _within(60, call)


class TestInputArrays:
    """Issue 12 item 5: a (3,) array is not one box, booleans are not numbers."""

    def test_box_overlaps_refuses_a_single_row(self):
        with pytest.raises(ValueError, match=r"lower must have shape \(n, 3\), got \(3,\); for "
                                             r"a single row pass lower.reshape\(1, 3\)"):
            granularsap.box_overlaps(np.zeros(3), np.ones((1, 3)))
        with pytest.raises(ValueError, match=r"upper must have shape \(n, 3\), got \(3,\)"):
            granularsap.SweepAndPrune().update(np.zeros((1, 3)), np.ones(3))

    @pytest.mark.parametrize("which", ["lower", "upper"])
    def test_box_overlaps_refuses_booleans(self, which):
        arrays = {"lower": np.zeros((2, 3)), "upper": np.ones((2, 3))}
        arrays[which] = np.ones((2, 3), dtype=bool)
        with pytest.raises(TypeError, match=rf"{which} must be an array of real numbers, got "
                                            r"dtype bool"):
            granularsap.box_overlaps(arrays["lower"], arrays["upper"])
        with pytest.raises(TypeError, match=rf"{which} must be an array of real numbers"):
            granularsap.SweepAndPrune().update(arrays["lower"], arrays["upper"])

    @pytest.mark.parametrize("call", [
        lambda p: granularsap.neighbor_pairs(p, 1.0),
        lambda p: granularsap.sphere_contacts(p, 0.5),
        lambda p: granularsap.NeighborSearch(1.0).update(p),
    ])
    def test_positions(self, call):
        with pytest.raises(TypeError, match=r"positions must be an array of real numbers, got "
                                            r"dtype bool"):
            call(np.zeros((3, 3), dtype=bool))
        with pytest.raises(ValueError, match=r"positions must have shape \(n, 3\), got \(3,\)"):
            call(np.zeros(3))

    def test_opt_in_keeps_the_old_reading(self):
        from granularsap.inputs import as_coords

        assert as_coords(np.array([1, 2, 3]), "x", single_row=True).shape == (1, 3)
        assert as_coords(np.ones((2, 3), bool), "x", allow_bool=True).tolist() == [[1.0] * 3] * 2


class TestConsumers:
    """The io pipeline and lammps_bridge take their cell through Cell."""

    @pytest.mark.lammps
    @pytest.mark.parametrize("pbc", [(True, False, True), (False, False, True), (True,) * 3])
    def test_lammps_bridge_takes_a_cell_with_its_pbc(self, pbc):
        import lammps_bridge

        from .oracles import brute_image_pairs

        rng = np.random.default_rng(12)
        cell = Cell.from_dimensions(DIMS[2], pbc=pbc)
        pos = rng.uniform(-3, 12, (80, 3))
        want, _ = brute_image_pairs(pos, 2.2, cell.matrix, pbc=pbc)
        got = lammps_bridge.neighbor_pairs(pos, 2.2, box=cell)
        order = np.lexsort((got[:, 1], got[:, 0]))
        assert np.array_equal(got[order], want)

    def test_engine_cell_depends_on_the_box_only(self):
        from granularsap.io import Frame
        from granularsap.io.pipeline import engine_cell

        rng = np.random.default_rng(13)
        m = np.array([[10.0, 0, 0], [2.0, 9.0, 0], [1.5, -1.0, 8.0]])
        cells = []
        for spread in (1.0, 50.0):
            fr = Frame(index=0, positions=rng.uniform(-spread, spread, (20, 3)),
                       ids=np.arange(20), cell=m, pbc=np.array([True, True, False]),
                       origin=np.array([1.0, 0.0, -2.0]))
            cells.append(engine_cell(fr))
        assert cells[0] == cells[1] and cells[0].pbc.tolist() == [True, True, False]
        assert np.array_equal(cells[0].matrix[:2], m[:2])
        open_c = cells[0].full_matrix[2]  # normal to the periodic vectors, unit length
        assert abs(open_c @ m[0]) < 1e-12 and abs(open_c @ m[1]) < 1e-12
        assert engine_cell(Frame(index=0, positions=np.zeros((0, 3)),
                                 ids=np.zeros(0, int))) is None


def test_docs_examples_run():
    import doctest
    import re

    text = (Path(__file__).resolve().parent.parent / "docs" / "cells.md").read_text()
    blocks = "\n".join(re.findall(r"```python\n(.*?)```", text, flags=re.S))
    parser = doctest.DocTestParser()
    test = parser.get_doctest(blocks, {}, "cells.md", "docs/cells.md", 0)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    runner.run(test)
    assert runner.failures == 0 and runner.tries > 10


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), dims=st.sampled_from(DIMS),
       k=st.tuples(*[st.integers(-10**5, 10**5)] * 3),
       pbc=st.sampled_from([(True, True, True), (True, False, True)]))
def test_translating_every_position_by_cell_vectors_changes_no_pair(seed, dims, k, pbc):
    """Issue 12: pairs change only within rounding of the cutoff, distances only by rounding."""
    rng = np.random.default_rng(seed)
    cell = Cell.from_dimensions(dims, pbc=pbc)
    pos = rng.uniform(0, 9, (40, 3))
    cut = 2.5
    moved = pos + (np.asarray(k) * np.asarray(pbc)) @ cell.matrix
    a, da = granularsap.neighbor_pairs(pos, cut, box=cell)
    b, db = granularsap.neighbor_pairs(moved, cut, box=cell)
    tol = 1e-15 * (10 + np.abs(moved).max()) * 8
    sa = {tuple(p): d for p, d in zip(a.tolist(), da, strict=True)}
    sb = {tuple(p): d for p, d in zip(b.tolist(), db, strict=True)}
    for p in set(sa) ^ set(sb):
        assert abs(sa.get(p, sb.get(p)) - cut) <= tol
    for p in set(sa) & set(sb):
        assert abs(sa[p] - sb[p]) <= tol
