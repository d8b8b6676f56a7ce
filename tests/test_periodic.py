"""Cells, wrapping and perpendicular widths (granularsap.periodic)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granularsap import neighbor_pairs, sphere_contacts
from granularsap import periodic as pc

from .oracles import brute_image_pairs, sort_pairs

DIMS = [
    [10.0, 10.0, 10.0, 90.0, 90.0, 90.0],
    [8.0, 9.0, 10.0, 90.0, 90.0, 60.0],
    [9.0, 10.0, 11.0, 75.0, 80.0, 105.0],
    [12.0, 7.0, 9.5, 100.0, 65.0, 80.0],
]


class TestCellFromDimensions:
    @pytest.mark.parametrize("dims", DIMS)
    def test_same_matrix_as_mdanalysis(self, dims):
        mdamath = pytest.importorskip("MDAnalysis.lib.mdamath")
        want = mdamath.triclinic_vectors(np.asarray(dims), dtype=np.float64)
        np.testing.assert_allclose(pc.cell_from_dimensions(dims), want, rtol=1e-15, atol=1e-15)

    @pytest.mark.parametrize("dims", DIMS)
    def test_lengths_and_angles_round_trip(self, dims):
        cell = pc.cell_from_dimensions(dims)
        lengths = np.linalg.norm(cell, axis=1)
        np.testing.assert_allclose(lengths, dims[:3], rtol=1e-13)

        def angle(u, v):
            return np.degrees(np.arccos(u @ v / np.linalg.norm(u) / np.linalg.norm(v)))

        got = [angle(cell[1], cell[2]), angle(cell[0], cell[2]), angle(cell[0], cell[1])]
        np.testing.assert_allclose(got, dims[3:], rtol=1e-12)

    def test_right_angles_are_exact_zeros(self):
        cell = pc.cell_from_dimensions([5, 6, 7, 90, 90, 90])
        assert np.array_equal(cell, np.diag([5.0, 6.0, 7.0]))
        cell = pc.cell_from_dimensions([5, 6, 7, 90, 90, 120])
        assert cell[2, 0] == 0.0 and cell[2, 1] == 0.0

    @pytest.mark.parametrize("dims, match", [
        ([0, 1, 1, 90, 90, 90], r"box lengths must be positive, got \[0.0, 1.0, 1.0\]"),
        ([1, 1, -1, 90, 90, 90], r"box lengths must be positive"),
        ([1, 1, 1, 0, 90, 90], r"box angles must be in \(0, 180\) degrees"),
        ([1, 1, 1, 90, 180, 90], r"box angles must be in \(0, 180\) degrees"),
        ([1, 1, 1, 20, 30, 60], r"do not form a cell of positive volume"),
    ])
    def test_invalid(self, dims, match):
        with pytest.raises(ValueError, match=match):
            pc.cell_from_dimensions(dims)


class TestAsCell:
    def test_none_and_forms(self):
        assert pc.as_cell(None) is None
        m = [[4.0, 0, 0], [1.0, 5.0, 0], [0.5, 0.5, 6.0]]
        assert np.array_equal(pc.as_cell(m), np.asarray(m))
        assert pc.as_cell(np.array([4, 5, 6, 90, 90, 90])).dtype == np.float64

    def test_zero_vector_allowed_on_open_axis(self):
        cell = pc.as_cell(np.diag([4.0, 5.0, 0.0]), pbc=[True, True, False])
        assert np.array_equal(cell[:2], np.diag([4.0, 5.0, 0.0])[:2])
        assert abs(np.linalg.det(cell)) > 0

    @pytest.mark.parametrize("box, exc, match", [
        ([1, 2], ValueError, r"box must be \[lx, ly, lz, alpha, beta, gamma\] or a \(3, 3\) "
                             r"matrix of cell vectors, got shape \(2,\)"),
        ([[1, 0, 0], [0, 1, 0], [0, 0, np.nan]], ValueError, r"box must be finite"),
        ([[1, 0, 0], [0, 1, 0], [1, 1, 0]], ValueError,
         r"box must be a non-degenerate cell with positive volume"),
        (np.diag([1.0, 0.0, 1.0]), ValueError, r"box vector 1 is zero along a periodic axis"),
        (["a"] * 6, TypeError, r"box must be an array of real numbers"),
    ])
    def test_invalid(self, box, exc, match):
        with pytest.raises(exc, match=match):
            pc.as_cell(box)

    @pytest.mark.parametrize("pbc, exc, match", [
        ([True, False], ValueError, r"pbc must be a bool or three bools, got shape \(2,\)"),
        (["x", "y", "z"], TypeError, r"pbc must be a bool or three bools, got dtype <U1"),
    ])
    def test_invalid_pbc(self, pbc, exc, match):
        with pytest.raises(exc, match=match):
            pc.as_pbc(pbc)


class TestWidthsAndWrap:
    def test_orthorhombic_widths_are_edges(self):
        assert np.array_equal(pc.perpendicular_widths(np.diag([3.0, 4.0, 5.0])), [3, 4, 5])

    @pytest.mark.parametrize("dims", DIMS)
    def test_widths_are_face_distances(self, dims):
        cell = pc.cell_from_dimensions(dims)
        w = pc.perpendicular_widths(cell)
        recip = np.linalg.inv(cell).T  # rows are normals of the faces
        np.testing.assert_allclose(w, 1.0 / np.linalg.norm(recip, axis=1), rtol=1e-13)

    @pytest.mark.parametrize("dims", DIMS)
    def test_wrap_into_cell(self, dims):
        rng = np.random.default_rng(0)
        cell = pc.cell_from_dimensions(dims)
        pos = rng.uniform(-40, 40, (200, 3))
        wrapped, shifts = pc.wrap(pos, cell)
        s = pc.fractional(wrapped, cell)
        assert np.all(s >= -1e-12) and np.all(s < 1 + 1e-12)
        np.testing.assert_allclose(wrapped + shifts @ cell, pos, atol=1e-12)

    def test_wrap_respects_open_axes(self):
        pos = np.array([[-1.0, -1.0, 25.0], [12.0, 3.0, -7.0]])
        wrapped, shifts = pc.wrap(pos, np.diag([10.0, 10.0, 10.0]), [True, False, True])
        assert np.array_equal(wrapped, [[9.0, -1.0, 5.0], [2.0, 3.0, 3.0]])
        assert np.array_equal(shifts[:, 1], [0, 0])

    def test_points_on_faces_wrap_to_zero(self):
        wrapped, shifts = pc.wrap(np.array([[10.0, 0.0, 20.0]]), np.diag([10.0, 10.0, 10.0]))
        assert np.array_equal(wrapped, [[0.0, 0.0, 0.0]]) and shifts.tolist() == [[1, 0, 2]]


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 30),
       dims=st.sampled_from(DIMS), cut=st.floats(0.0, 3.3))
def test_triclinic_neighbor_pairs_match_oracle(seed, n, dims, cut):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-20, 30, (n, 3))
    pairs, d = neighbor_pairs(pos, cut, box=dims)
    want, wd = brute_image_pairs(pos, cut, pc.cell_from_dimensions(dims))
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    assert np.array_equal(pairs[order], want)
    np.testing.assert_allclose(d[order], wd, rtol=1e-12, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.tuples(*[st.integers(-3, 3)] * 3))
def test_lattice_translation_of_one_particle_changes_nothing(seed, k):
    rng = np.random.default_rng(seed)
    dims = DIMS[2]
    cell = pc.cell_from_dimensions(dims)
    pos = rng.uniform(0, 9, (25, 3))
    radii = rng.uniform(0.2, 1.0, 25)
    a = sort_pairs(sphere_contacts(pos, radii, box=dims))
    moved = pos.copy()
    moved[0] += np.asarray(k) @ cell
    b, db = sphere_contacts(moved, radii, box=dims, return_distances=True)
    # away from the contact threshold the pair set is exactly the same
    thr = radii[b[:, 0]] + radii[b[:, 1]]
    assert {tuple(p) for p in b[db < thr - 1e-9].tolist()} <= {tuple(p) for p in a.tolist()}
    assert len(a) == len(b) or np.any(np.abs(db - thr) < 1e-9)


@pytest.mark.parametrize("pbc", [(True, True, False), (True, False, True), (False, True, False)])
def test_tilt_towards_an_open_axis_does_not_narrow_the_periodic_widths(pbc):
    """A LAMMPS "p p s" box with xz, yz tilts: the open vector is a frame of
    reference only, so a cutoff under half the periodic lattice's widths works
    whatever the open vector's tilt, with the pairs of every image."""
    rng = np.random.default_rng(5)
    cell = np.array([[6.0, 0.0, 0.0], [1.5, 5.5, 0.0], [4.0, -3.5, 5.0]])
    per = np.flatnonzero(pbc)
    m = cell.copy()
    m[~np.asarray(pbc)] = 0.0
    widths = pc.perpendicular_widths(pc.Cell(m, pbc).full_matrix)[per]
    cutoff = 0.49 * widths.min()
    assert cutoff > 0.5 * pc.perpendicular_widths(cell)[per].min()  # refused before
    x = rng.uniform(-2, 8, (150, 3))  # inside, on and outside the faces
    pairs, d = neighbor_pairs(x, cutoff, box=pc.Cell(cell, pbc))
    ref, dref = brute_image_pairs(x, cutoff, cell, pbc)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    np.testing.assert_array_equal(pairs[order], sort_pairs(ref))
    np.testing.assert_allclose(d[order], dref[np.lexsort((ref[:, 1], ref[:, 0]))], rtol=1e-12)
