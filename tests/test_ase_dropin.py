"""granularsap.ase.neighbor_list against ASE's own function and a brute-force oracle."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

ase = pytest.importorskip("ase")
from ase import Atoms  # noqa: E402
from ase.build import bulk, molecule  # noqa: E402
from ase.neighborlist import neighbor_list as ase_neighbor_list  # noqa: E402

from granularsap.ase import neighbor_list, primitive_neighbor_list  # noqa: E402

from .oracles import brute_full_image_list  # noqa: E402

CELLS = {
    "ortho": np.diag([6.0, 7.0, 8.0]),
    "triclinic": np.array([[6.0, 0.0, 0.0], [1.5, 6.5, 0.0], [-1.0, 2.0, 7.5]]),
    "left_handed": np.array([[0.0, 6.0, 0.0], [6.5, 0.0, 0.0], [0.5, 1.0, 7.0]]),
}
PBCS = [(True, True, True), (True, False, True), (False, False, True), (False, False, False)]


def _canon(i, j, S, *rest):
    order = np.lexsort((S[:, 2], S[:, 1], S[:, 0], j, i))
    return (i[order], j[order], S[order]) + tuple(r[order] for r in rest)


def _atoms(seed, n, cell, pbc, symbols=None):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-3.0, 10.0, (n, 3))  # outside the cell too; ASE does not wrap D
    if symbols is None:
        symbols = rng.choice(["H", "C", "O"], n).tolist()
    return Atoms(symbols, positions=pos, cell=cell, pbc=pbc)


def _assert_same(got, want):
    gi, gj, gS, gd, gD = _canon(*got)
    wi, wj, wS, wd, wD = _canon(*want)
    assert np.array_equal(gi, wi) and np.array_equal(gj, wj) and np.array_equal(gS, wS), (
        len(gi), len(wi))
    np.testing.assert_allclose(gd, wd, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(gD, wD, rtol=1e-12, atol=1e-12)


class TestAgainstASE:
    @pytest.mark.parametrize("cell", list(CELLS))
    @pytest.mark.parametrize("pbc", PBCS, ids=lambda p: "".join("TF"[not x] for x in p))
    @pytest.mark.parametrize("cutoff", [1.0, 3.5, 9.0])  # 9.0: several images per pair
    def test_float_cutoff(self, cell, pbc, cutoff):
        atoms = _atoms(0, 30, CELLS[cell], pbc)
        _assert_same(neighbor_list("ijSdD", atoms, cutoff),
                     ase_neighbor_list("ijSdD", atoms, cutoff))

    @pytest.mark.parametrize("cell", list(CELLS))
    @pytest.mark.parametrize("pbc", PBCS[:2], ids=["TTT", "TFT"])
    def test_per_atom_radii(self, cell, pbc):
        atoms = _atoms(1, 40, CELLS[cell], pbc)
        radii = np.random.default_rng(2).uniform(0.2, 2.0, len(atoms))
        _assert_same(neighbor_list("ijSdD", atoms, radii),
                     ase_neighbor_list("ijSdD", atoms, radii))
        # the same as a plain list
        _assert_same(neighbor_list("ijSdD", atoms, radii.tolist()),
                     ase_neighbor_list("ijSdD", atoms, radii.tolist()))

    @pytest.mark.parametrize("pbc", PBCS[:2], ids=["TTT", "TFT"])
    def test_dict_cutoff_symbols_and_numbers(self, pbc):
        atoms = _atoms(3, 40, CELLS["triclinic"], pbc)
        cut = {("H", "H"): 1.2, ("C", "H"): 2.0, (8, 6): 3.1, ("O", "O"): 4.0}
        _assert_same(neighbor_list("ijSdD", atoms, cut), ase_neighbor_list("ijSdD", atoms, cut))

    def test_self_interaction(self):
        atoms = _atoms(4, 20, CELLS["ortho"], (True, True, True))
        _assert_same(neighbor_list("ijSdD", atoms, 3.0, self_interaction=True),
                     ase_neighbor_list("ijSdD", atoms, 3.0, self_interaction=True))

    def test_quantity_order_and_single_quantity(self):
        atoms = bulk("Cu", "fcc", a=3.6, cubic=True).repeat((2, 2, 2))
        d, i = neighbor_list("di", atoms, 3.0)
        assert len(d) == len(i) == 12 * len(atoms)
        np.testing.assert_allclose(np.sort(d), np.full(len(d), 3.6 / np.sqrt(2)), rtol=1e-12)
        i_only = neighbor_list("i", atoms, 3.0)
        assert isinstance(i_only, np.ndarray) and np.array_equal(np.sort(i_only), np.sort(i))
        assert np.all(np.diff(i_only) >= 0)  # sorted by i like ASE

    def test_single_atom_cell_many_images(self):
        atoms = bulk("Cu", "fcc", a=3.6)
        _assert_same(neighbor_list("ijSdD", atoms, 6.0), ase_neighbor_list("ijSdD", atoms, 6.0))

    def test_molecule_without_cell(self):
        atoms = molecule("CH3CH2OH")
        _assert_same(neighbor_list("ijSdD", atoms, 1.6), ase_neighbor_list("ijSdD", atoms, 1.6))

    def test_ties_are_excluded_like_ase(self):
        g = np.arange(3.0)
        pos = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        atoms = Atoms(f"Ar{len(pos)}", positions=pos, cell=np.diag([3.0, 3, 3]), pbc=True)
        for cutoff in (1.0, 2.0):
            _assert_same(neighbor_list("ijSdD", atoms, cutoff),
                         ase_neighbor_list("ijSdD", atoms, cutoff))
        assert len(neighbor_list("i", atoms, 1.0)) == 0

    def test_empty(self):
        atoms = Atoms(cell=np.eye(3) * 5, pbc=True)
        out = neighbor_list("ijdDS", atoms, 2.0)
        want = ase_neighbor_list("ijdDS", atoms, 2.0)
        for a, b in zip(out, want, strict=True):
            assert a.shape == b.shape and a.dtype.kind == b.dtype.kind


class TestAgainstOracle:
    @pytest.mark.parametrize("cell", list(CELLS))
    @pytest.mark.parametrize("pbc", PBCS, ids=lambda p: "".join("TF"[not x] for x in p))
    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_brute_force(self, cell, pbc, n_threads):
        atoms = _atoms(5, 15, CELLS[cell], pbc)
        i, j, S, d = neighbor_list("ijSd", atoms, 7.0, n_threads=n_threads)
        wi, wj, wS, wd = brute_full_image_list(atoms.positions, 7.0, CELLS[cell], pbc)
        gi, gj, gS, gd = _canon(i, j, S, d)
        assert np.array_equal(gi, wi) and np.array_equal(gj, wj) and np.array_equal(gS, wS)
        np.testing.assert_allclose(gd, wd, rtol=1e-12)

    def test_full_list_is_symmetric(self):
        atoms = _atoms(6, 50, CELLS["triclinic"], (True, True, False))
        i, j, S, D = neighbor_list("ijSD", atoms, 4.0)
        assert np.array_equal(np.bincount(i, minlength=50), np.bincount(j, minlength=50))
        fwd = {(a, b, *s) for a, b, s in zip(i.tolist(), j.tolist(), S.tolist(), strict=True)}
        rev = {(b, a, *(-x for x in s))
               for a, b, s in zip(i.tolist(), j.tolist(), S.tolist(), strict=True)}
        assert fwd == rev
        pos, cell = atoms.positions, atoms.cell.array
        np.testing.assert_allclose(D, pos[j] - pos[i] + S @ cell, rtol=1e-12, atol=1e-12)


class TestErrors:
    @pytest.mark.parametrize("args, exc, match", [
        (("ijx", 2.0), ValueError, r"Unsupported quantity specified: 'x'"),
        ((1, 2.0), TypeError, r"quantities must be a string"),
        (("ij", -1.0), ValueError, r"cutoff must be non-negative, got -1.0 at index 0"),
        (("ij", [1.0, 1.0]), ValueError, r"cutoff must be a scalar or have shape \(3,\)"),
        (("ij", [1.0, -2.0, 1.0]), ValueError, r"cutoff must be non-negative, got -2.0 at index 1"),
        (("ij", {("H", "Xx"): 1.0}), ValueError, r"cutoff dict keys must be element symbols"),
        (("ij", {("H", "H"): -1.0}), ValueError, r"cutoff for \('H', 'H'\) must be finite"),
    ])
    def test_bad_arguments(self, args, exc, match):
        atoms = Atoms("H3", positions=np.zeros((3, 3)), cell=np.eye(3) * 4, pbc=True)
        with pytest.raises(exc, match=match):
            neighbor_list(args[0], atoms, args[1])

    def test_not_atoms(self):
        with pytest.raises(TypeError, match=r"a must be an ase.Atoms \(missing .positions\)"):
            neighbor_list("ij", np.zeros((3, 3)), 1.0)

    def test_degenerate_periodic_cell(self):
        atoms = Atoms("H2", positions=np.zeros((2, 3)), cell=np.diag([4.0, 0.0, 4.0]), pbc=True)
        with pytest.raises(ValueError, match=r"cell vector 1 is zero along a periodic axis"):
            neighbor_list("ij", atoms, 1.0)

    def test_primitive_needs_numbers_for_dict(self):
        with pytest.raises(ValueError, match=r"a dict cutoff needs the atomic numbers"):
            primitive_neighbor_list("ij", [True] * 3, np.eye(3) * 4, np.zeros((2, 3)),
                                    {(1, 1): 1.0})


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 25),
       cutoff=st.floats(0.1, 8.0), pbc=st.sampled_from(PBCS), cell=st.sampled_from(list(CELLS)))
def test_matches_ase_property(seed, n, cutoff, pbc, cell):
    atoms = _atoms(seed, n, CELLS[cell], pbc)
    _assert_same(neighbor_list("ijSdD", atoms, cutoff), ase_neighbor_list("ijSdD", atoms, cutoff))


class TestRowOrder:
    """Rows sorted by i, then j, then S (ASE's ``NeighborList.get_neighbors``
    compares its two primitives element by element, issue 12 item 13)."""

    @pytest.mark.parametrize("cell", list(CELLS))
    @pytest.mark.parametrize("pbc", PBCS[:3], ids=["TTT", "TFT", "FFT"])
    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_sorted_by_i_j_shift(self, cell, pbc, n_threads):
        atoms = _atoms(7, 40, CELLS[cell], pbc)
        i, j, S, d = neighbor_list("ijSd", atoms, 9.0, n_threads=n_threads)
        key = np.stack([i, j, S[:, 0], S[:, 1], S[:, 2]], axis=1)
        order = np.lexsort(key.T[::-1])
        assert np.array_equal(order, np.arange(len(i)))
        # and the same rows as ASE's
        _assert_same((i, j, S, d, neighbor_list("D", atoms, 9.0)),
                     ase_neighbor_list("ijSdD", atoms, 9.0))

    def test_order_does_not_depend_on_threads(self):
        atoms = _atoms(8, 60, CELLS["triclinic"], (True, True, True))
        one = neighbor_list("ijSdD", atoms, 5.0, n_threads=1)
        two = neighbor_list("ijSdD", atoms, 5.0, n_threads=2)
        for a, b in zip(one, two, strict=True):
            assert np.array_equal(a, b)

    def test_small_cell_and_large_cutoff_neighbors_in_order(self):
        # ASE's test_small_cell_and_large_cutoff: our rows for atom 0 equal
        # ASE's own PrimitiveNeighborList (bothways), element by element
        from ase.neighborlist import NeighborList

        atoms = bulk("Cu", "fcc", a=3.6) * (2, 2, 2)
        atoms.set_pbc(False)
        i, j = neighbor_list("ij", atoms, 100.0)
        assert np.array_equal(j[i == 0], np.arange(1, 8))
        nl = NeighborList([50.0] * len(atoms), skin=0.0, self_interaction=False,
                          bothways=True)
        nl.update(atoms)
        assert np.array_equal(nl.get_neighbors(0)[0], j[i == 0])

    def test_one_cutoff_per_atom_is_required(self):
        # stricter than ASE, which ignores surplus per-atom cutoffs
        atoms = bulk("Cu", "fcc", a=3.6)
        with pytest.raises(ValueError, match=r"cutoff must be a scalar or have shape \(1,\), "
                                             r"got \(2,\)"):
            primitive_neighbor_list("ij", atoms.pbc, atoms.cell, atoms.positions, [2.3, 1.7])


class TestCutoffManyTimesTheCell:
    """Every image of every pair, in memory proportional to the output (the
    ghost-image search needed 14 GB for one atom and cutoff 40)."""

    @pytest.mark.parametrize("atoms, cutoff", [
        (bulk("Cu", "fcc", a=3.6), 14.0),
        (bulk("Cu", "fcc", a=3.6) * (2, 2, 1), 12.0),
        (Atoms("H5", positions=np.random.default_rng(0).uniform(-2, 6, (5, 3)),
               cell=[[3, 0, 0], [1, 3.5, 0], [-0.5, 0.7, 2.8]], pbc=[True, False, True]), 11.0),
        (Atoms("HO", positions=[[0, 0, 0], [0.4, 0.3, 5.0]], cell=[2.0, 2.5, 0.0],
               pbc=[True, True, False]), 9.0),
    ], ids=["fcc1", "fcc4", "tric-TFT", "slab-zero-vector"])
    def test_matches_ase(self, atoms, cutoff):
        _assert_same(neighbor_list("ijSdD", atoms, cutoff),
                     ase_neighbor_list("ijSdD", atoms, cutoff))

    def test_per_atom_and_dict_cutoffs(self):
        atoms = bulk("NaCl", "rocksalt", a=5.6)
        radii = [4.0, 6.5]
        _assert_same(neighbor_list("ijSdD", atoms, radii),
                     ase_neighbor_list("ijSdD", atoms, radii))
        cut = {("Na", "Na"): 9.0, ("Na", "Cl"): 12.0, ("Cl", "Cl"): 3.0}
        _assert_same(neighbor_list("ijSdD", atoms, cut), ase_neighbor_list("ijSdD", atoms, cut))
        _assert_same(neighbor_list("ijSdD", atoms, 10.0, self_interaction=True),
                     ase_neighbor_list("ijSdD", atoms, 10.0, self_interaction=True))

    def test_matches_oracle_and_threads(self):
        atoms = _atoms(9, 6, CELLS["left_handed"], (True, True, True))
        got = [neighbor_list("ijSd", atoms, 16.0, n_threads=t) for t in (1, 2)]
        for a, b in zip(*got, strict=True):
            assert np.array_equal(a, b)
        wi, wj, wS, wd = brute_full_image_list(atoms.positions, 16.0, CELLS["left_handed"],
                                               (True, True, True))
        gi, gj, gS, gd = _canon(*got[0])
        assert np.array_equal(gi, wi) and np.array_equal(gj, wj) and np.array_equal(gS, wS)
        np.testing.assert_allclose(gd, wd, rtol=1e-12)

    @pytest.mark.parametrize("cutoff", [20.0, 30.0])
    def test_memory_is_bounded_by_the_output(self, cutoff):
        import tracemalloc

        atoms = bulk("Cu", "fcc", a=3.6)
        neighbor_list("ijdDS", atoms, 5.0 * cutoff / 4)  # compile outside the measurement
        tracemalloc.start()
        try:
            out = neighbor_list("ijdDS", atoms, cutoff)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 8 * sum(o.nbytes for o in out) + (1 << 20), peak
