"""granularsap.ase.NeighborList and granularsap.mda.FastNS against the real
ase.neighborlist.NeighborList (both primitives) and MDAnalysis.lib.nsgrid.FastNS,
on the same inputs, and against the brute-force oracles."""

from __future__ import annotations

import pathlib

import numpy as np
import pytest

from granularsap import Cell
from granularsap.io import iter_frames

from .oracles import brute_full_image_list, brute_image_pairs

DATA = pathlib.Path(__file__).resolve().parent.parent / "data"


# =============================================================== ASE NeighborList
ase = pytest.importorskip("ase")
from ase import Atoms  # noqa: E402
from ase.neighborlist import NeighborList as AseNeighborList  # noqa: E402
from ase.neighborlist import NewPrimitiveNeighborList, PrimitiveNeighborList  # noqa: E402

from granularsap.ase import NeighborList  # noqa: E402

PRIMITIVES = [PrimitiveNeighborList, NewPrimitiveNeighborList]
CELLS = {
    "ortho": np.diag([6.0, 7.0, 8.0]),
    "triclinic": np.array([[6.0, 0.0, 0.0], [1.5, 6.5, 0.0], [-1.0, 2.0, 7.5]]),
    # cutoffs about the cell size: several images of every pair, self images too
    "small": np.array([[2.0, 0.0, 0.0], [0.7, 2.1, 0.0], [0.3, -0.5, 1.9]]),
}
PBCS = [(True, True, True), (True, False, True), (False, True, False), (False, False, False)]


def _rows(nl, n):
    """Every (a, b, S) of a neighbour list, in get_neighbors order, as (k, 5) int64."""
    parts = []
    for a in range(n):
        idx, off = nl.get_neighbors(a)
        block = np.empty((len(idx), 5), np.int64)
        block[:, 0], block[:, 1], block[:, 2:] = a, idx, np.asarray(off).reshape(-1, 3)
        parts.append(block)
    return np.concatenate(parts) if parts else np.empty((0, 5), np.int64)


def _canon(rows):
    return rows[np.lexsort(rows.T[::-1])]


def _assert_same_list(ours, theirs, n):
    got, want = _rows(ours, n), _rows(theirs, n)
    np.testing.assert_array_equal(_canon(got), _canon(want))
    # our own order: by atom, then neighbour index, then offset
    np.testing.assert_array_equal(got, _canon(got))


def _system(seed, n, cell_kind, pbc):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-3.0, 10.0, (n, 3))  # outside the cell too
    lo, hi = (1.0, 2.5) if cell_kind == "small" else (0.3, 1.5)
    cutoffs = rng.uniform(lo, hi, n)
    return Atoms(f"H{n}", positions=pos, cell=CELLS[cell_kind], pbc=pbc), cutoffs


class TestNeighborListAgainstASE:
    @pytest.mark.parametrize("primitive", PRIMITIVES, ids=lambda p: p.__name__)
    @pytest.mark.parametrize("cell_kind", list(CELLS))
    @pytest.mark.parametrize("pbc", PBCS, ids=str)
    @pytest.mark.parametrize("self_interaction", [True, False])
    @pytest.mark.parametrize("bothways", [False, True])
    def test_first_build(self, primitive, cell_kind, pbc, self_interaction, bothways):
        atoms, cutoffs = _system(3, 14, cell_kind, pbc)
        kw = dict(skin=0.2, self_interaction=self_interaction, bothways=bothways,
                  primitive=primitive)
        theirs, ours = AseNeighborList(cutoffs, **kw), NeighborList(cutoffs, **kw)
        assert ours.update(atoms) is theirs.update(atoms) is True
        _assert_same_list(ours, theirs, len(atoms))
        assert ours.nupdates == theirs.nupdates == 1

    def test_open_atoms_without_cell(self):
        rng = np.random.default_rng(4)
        atoms = Atoms("H30", positions=rng.uniform(0, 4, (30, 3)))
        cutoffs = rng.uniform(0.2, 0.6, 30)
        theirs, ours = AseNeighborList(cutoffs), NeighborList(cutoffs)
        theirs.update(atoms), ours.update(atoms)
        _assert_same_list(ours, theirs, 30)

    def test_primitives_orient_half_lists_differently(self):
        # the orientation mapping is exercised: the two ASE primitives disagree
        atoms, cutoffs = _system(1, 12, "small", (True, True, True))
        lists = []
        for primitive in PRIMITIVES:
            nl = NeighborList(cutoffs, primitive=primitive)
            nl.update(atoms)
            lists.append(_canon(_rows(nl, 12)))
        assert len(lists[0]) == len(lists[1])
        assert not np.array_equal(lists[0], lists[1])

    @pytest.mark.parametrize("cell_kind", list(CELLS))
    @pytest.mark.parametrize("pbc", PBCS[:3], ids=str)
    def test_full_list_equals_brute_force(self, cell_kind, pbc):
        atoms, cutoffs = _system(5, 12, cell_kind, pbc)
        skin = 0.25
        nl = NeighborList(cutoffs, skin=skin, self_interaction=True, bothways=True)
        nl.update(atoms)
        i, j, S, _ = brute_full_image_list(atoms.positions, 0.0, atoms.cell.array, pbc,
                                           radii=cutoffs + skin, self_interaction=True)
        want = np.column_stack([i, j, S])
        np.testing.assert_array_equal(_rows(nl, 12), want)

    @pytest.mark.parametrize("primitive", PRIMITIVES, ids=lambda p: p.__name__)
    @pytest.mark.parametrize("cell_kind", ["ortho", "triclinic", "small"])
    @pytest.mark.parametrize("bothways", [False, True])
    def test_successive_updates(self, primitive, cell_kind, bothways):
        """Small moves keep the build-time list (not re-filtered), large moves,
        a changed cell and changed pbc rebuild; every answer equals ASE's."""
        atoms, cutoffs = _system(7, 16, cell_kind, (True, False, True))
        kw = dict(skin=0.3, bothways=bothways, self_interaction=False, primitive=primitive)
        theirs, ours = AseNeighborList(cutoffs, **kw), NeighborList(cutoffs, **kw)
        rng = np.random.default_rng(8)
        flags = []
        for step in range(12):
            want = theirs.update(atoms)
            got = ours.update(atoms)
            assert got is want, step
            flags.append(got)
            _assert_same_list(ours, theirs, len(atoms))
            assert ours.nupdates == theirs.nupdates
            kind = step % 4
            if kind in (0, 1):  # well within skin
                atoms.positions = atoms.positions + rng.normal(0, 0.03, atoms.positions.shape)
            elif kind == 2:  # one atom beyond skin
                atoms.positions[3] += [0.31, 0.0, 0.0]
            elif step == 7:
                atoms.set_cell(atoms.cell.array * 1.01)
            else:
                atoms.pbc = [True, True, True] if step == 3 else [True, False, True]
        assert True in flags[1:] and flags.count(False) >= 4

    def test_move_exactly_skin_does_not_rebuild(self):
        # ASE rebuilds when the squared displacement is > skin ** 2 (strict)
        atoms = Atoms("H2", positions=[[0, 0, 0], [1.0, 0, 0]])
        for nl in (AseNeighborList([0.4, 0.4], skin=0.25), NeighborList([0.4, 0.4], skin=0.25)):
            assert nl.update(atoms)
            moved = atoms.copy()
            moved.positions[0, 0] += 0.25
            assert nl.update(moved) is False
            moved.positions[0, 0] += 1e-9
            assert nl.update(moved) is True

    @pytest.mark.parametrize("sparse", [True, False])
    def test_connectivity_matrix(self, sparse):
        atoms, cutoffs = _system(9, 14, "small", (True, True, False))
        theirs, ours = AseNeighborList(cutoffs), NeighborList(cutoffs)
        theirs.update(atoms), ours.update(atoms)
        want = theirs.get_connectivity_matrix(sparse=sparse)
        got = ours.get_connectivity_matrix(sparse=sparse)
        if sparse:
            assert got.format == want.format == "dok"
            want, got = want.toarray(), got.toarray()
        assert got.dtype == want.dtype == np.int8
        np.testing.assert_array_equal(got, want)

    @pytest.mark.parametrize("self_interaction, bothways", [(False, True), (True, False),
                                                            (False, False)])
    def test_primitive_view_and_deprecated_counts(self, self_interaction, bothways):
        # ASE users read nl.nl (get_connectivity_matrix(nl.nl), nl.nl.neighbors) and the
        # deprecated nneighbors / npbcneighbors
        import warnings

        from ase.neighborlist import get_connectivity_matrix

        atoms, cutoffs = _system(9, 14, "small", (True, True, False))
        kw = dict(self_interaction=self_interaction, bothways=bothways)
        theirs, ours = AseNeighborList(cutoffs, **kw), NeighborList(cutoffs, **kw)
        theirs.update(atoms), ours.update(atoms)
        np.testing.assert_array_equal(get_connectivity_matrix(ours.nl).toarray(),
                                      get_connectivity_matrix(theirs.nl).toarray())
        _assert_same_list(ours.nl, theirs.nl, len(atoms))
        for a in range(len(atoms)):
            got = sorted(zip(ours.nl.neighbors[a].tolist(),
                             map(tuple, ours.nl.displacements[a].tolist()), strict=True))
            want = sorted(zip(theirs.nl.neighbors[a].tolist(),
                              map(tuple, theirs.nl.displacements[a].tolist()), strict=True))
            assert got == want
        assert ours.nl.nupdates == theirs.nl.nupdates == 1
        assert ours.nl.bothways == bothways and ours.nl.self_interaction == self_interaction
        np.testing.assert_array_equal(ours.nl.pbc, theirs.nl.pbc)
        np.testing.assert_array_equal(ours.nl.coordinates, theirs.nl.coordinates)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            assert ours.nneighbors == theirs.nneighbors
            assert ours.npbcneighbors == theirs.npbcneighbors
        with pytest.warns(FutureWarning, match="deprecated"):
            assert ours.nneighbors >= 0
        # the primitive's own update, as PrimitiveNeighborList.update(pbc, cell, coords)
        moved = atoms.positions + 0.4
        assert ours.nl.update(atoms.pbc, atoms.cell, moved) is theirs.nl.update(
            atoms.pbc, atoms.cell, moved) is True
        _assert_same_list(ours, theirs, len(atoms))
        with pytest.raises(ValueError, match=r"coordinates must have shape \(14, 3\)"):
            ours.nl.update(atoms.pbc, atoms.cell, moved[:3])

    def test_negative_index_and_types(self):
        atoms, cutoffs = _system(2, 10, "ortho", (True, True, True))
        nl = NeighborList(cutoffs)
        nl.update(atoms)
        idx, off = nl.get_neighbors(-1)
        np.testing.assert_array_equal(idx, nl.get_neighbors(9)[0])
        assert idx.dtype == np.int64 and off.dtype == np.int64 and off.shape == (len(idx), 3)


@pytest.mark.parametrize("primitive", PRIMITIVES, ids=lambda p: p.__name__)
def test_lj_trajectory_against_ase(primitive):
    """Triclinic LJ liquid (2048 atoms), frames 100 steps apart: rebuilds and
    lists equal ASE's on every frame."""
    frames = list(iter_frames(DATA / "lj.dump"))[:4]
    cutoffs = np.full(len(frames[0].positions), 0.6)
    kw = dict(skin=0.4, self_interaction=False, bothways=True, primitive=primitive)
    theirs, ours = AseNeighborList(cutoffs, **kw), NeighborList(cutoffs, **kw)
    for k, frame in enumerate(frames):
        atoms = Atoms(positions=frame.positions, cell=frame.cell, pbc=frame.pbc)
        # every other frame the same positions jittered well within skin
        for a in (atoms, Atoms(positions=frame.positions + 1e-3, cell=frame.cell,
                               pbc=frame.pbc)):
            assert ours.update(a) is theirs.update(a), k
            _assert_same_list(ours, theirs, len(a))
    assert ours.nupdates == theirs.nupdates


def test_pour_trajectory_against_ase():
    """Granular pour, open boundaries, polydisperse radii as cutoffs."""
    frames = list(iter_frames(DATA / "pour.dump"))[::4]
    radii = frames[0].radius
    kw = dict(skin=0.05, self_interaction=False, bothways=False,
              primitive=NewPrimitiveNeighborList)
    theirs, ours = AseNeighborList(radii, **kw), NeighborList(radii, **kw)
    for frame in frames:
        atoms = Atoms(positions=frame.positions, cell=frame.cell, pbc=frame.pbc)
        assert ours.update(atoms) is theirs.update(atoms)
        _assert_same_list(ours, theirs, len(atoms))


class TestNeighborListErrors:
    def test_cutoffs_shape(self):
        with pytest.raises(ValueError, match=r"cutoffs must be a sequence of one float per "
                                              r"atom, got shape \(2, 2\)"):
            NeighborList([[1.0, 1.0], [1.0, 1.0]])

    def test_cutoffs_string(self):
        with pytest.raises(ValueError, match="cutoffs must be a sequence.*got a string"):
            NeighborList("1.0")

    def test_cutoffs_negative(self):
        with pytest.raises(ValueError, match=r"cutoffs must be finite and non-negative, got "
                                              r"-1\.0 at index 1"):
            NeighborList([1.0, -1.0])

    def test_skin_type(self):
        with pytest.raises(TypeError, match="skin must be a float, got list"):
            NeighborList([1.0], skin=[0.1])

    def test_skin_negative(self):
        with pytest.raises(ValueError, match="skin must be finite and non-negative, got -0.1"):
            NeighborList([1.0], skin=-0.1)

    def test_primitive_name(self):
        with pytest.raises(ValueError, match="primitive must be one of PrimitiveNeighborList, "
                                              "NewPrimitiveNeighborList.*got 'kdtree'"):
            NeighborList([1.0], primitive="kdtree")

    def test_primitive_type(self):
        with pytest.raises(TypeError, match="primitive must be .*got int"):
            NeighborList([1.0], primitive=3)

    def test_atom_count(self):
        nl = NeighborList([1.0, 1.0])
        with pytest.raises(ValueError, match="atoms has 3 atoms but cutoffs has 2 entries"):
            nl.update(Atoms("H3", positions=np.zeros((3, 3))))

    def test_not_atoms(self):
        with pytest.raises(TypeError, match=r"atoms must be an ase.Atoms \(missing "
                                             r"\.positions\), got ndarray"):
            NeighborList([1.0]).update(np.zeros((1, 3)))

    def test_before_update(self):
        nl = NeighborList([1.0])
        with pytest.raises(RuntimeError, match=r"Must call update\(atoms\)"):
            nl.get_neighbors(0)
        with pytest.raises(RuntimeError, match=r"Must call update\(atoms\)"):
            nl.get_connectivity_matrix()

    def test_index_range(self):
        nl = NeighborList([1.0, 1.0])
        nl.update(Atoms("H2", positions=np.zeros((2, 3))))
        with pytest.raises(IndexError, match="atom index 2 is out of range for 2 atoms"):
            nl.get_neighbors(2)


# ====================================================================== FastNS
try:
    from MDAnalysis.lib import nsgrid
except ImportError:  # pragma: no cover - MDAnalysis is a test dependency
    nsgrid = None
needs_mdanalysis = pytest.mark.skipif(nsgrid is None, reason="needs MDAnalysis")

from granularsap.mda import FastNS  # noqa: E402

BOXES = {
    "ortho": [10.0, 11.0, 12.0, 90.0, 90.0, 90.0],
    "triclinic": [10.0, 11.0, 12.0, 70.0, 80.0, 100.0],
    "rhombic": [12.0, 12.0, 12.0, 60.0, 60.0, 90.0],
}
#: float32 rounding of MDAnalysis's separations (coordinates up to ~40 here)
F32_ATOL = 2e-5


def _mda_pairs(result, self_search):
    pairs, dist = result.get_pairs(), result.get_pair_distances()
    if self_search:
        pairs = np.sort(pairs, axis=1)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order].astype(np.int64), dist[order]


def _assert_like_mda(ours, theirs, cutoff, self_search):
    """Pair sets equal except pairs within float32 rounding of the cutoff (none
    expected here); distances equal to float32 rounding."""
    p_want, d_want = _mda_pairs(theirs, self_search)
    p_got, d_got = ours.get_pairs(), ours.get_pair_distances()
    assert p_got.dtype == np.int64 and d_got.dtype == np.float64
    np.testing.assert_array_equal(p_got, p_got[np.lexsort((p_got[:, 1], p_got[:, 0]))])
    if self_search:
        assert (p_got[:, 0] < p_got[:, 1]).all()
    got, want = set(map(tuple, p_got.tolist())), set(map(tuple, p_want.tolist()))
    if got != want:  # only float32 ties may differ
        extra = {k: d for k, d in zip(map(tuple, p_got.tolist()), d_got, strict=True)}
        for pair in got - want:
            assert abs(extra[pair] - cutoff) < F32_ATOL, pair
        missing = {k: d for k, d in zip(map(tuple, p_want.tolist()), d_want, strict=True)}
        for pair in want - got:
            assert abs(missing[pair] - cutoff) < F32_ATOL, pair
        return
    np.testing.assert_array_equal(p_got, p_want)
    np.testing.assert_allclose(d_got, d_want, rtol=0, atol=F32_ATOL)


@needs_mdanalysis
class TestFastNSAgainstMDAnalysis:
    @pytest.mark.parametrize("box_kind", list(BOXES))
    @pytest.mark.parametrize("cutoff", [0.8, 2.5, 3.6])
    @pytest.mark.parametrize("seed", [0, 1])
    def test_periodic(self, box_kind, cutoff, seed):
        rng = np.random.default_rng(seed)
        box = np.array(BOXES[box_kind], np.float32)
        coords = rng.uniform(-5, 20, (300, 3)).astype(np.float32)
        query = rng.uniform(-5, 20, (60, 3)).astype(np.float32)
        theirs, ours = nsgrid.FastNS(cutoff, coords, box), FastNS(cutoff, coords, box)
        _assert_like_mda(ours.self_search(), theirs.self_search(), cutoff, True)
        _assert_like_mda(ours.search(query), theirs.search(query), cutoff, False)
        # and exactly the float64 brute-force answer on the same numbers (a subset;
        # the oracle gets them wrapped, which changes distances by rounding only)
        coords, query = coords[:100], query[:25]
        ours = FastNS(cutoff, coords, box)
        cell = Cell.from_dimensions(box).matrix
        both = np.concatenate([coords, query]).astype(np.float64)
        both -= np.floor(both @ np.linalg.inv(cell)) @ cell
        pairs, dist = brute_image_pairs(both[:100], cutoff, cell)
        res = ours.self_search()
        np.testing.assert_array_equal(res.get_pairs(), pairs)
        np.testing.assert_allclose(res.get_pair_distances(), dist, rtol=1e-12)
        pairs, dist = brute_image_pairs(both, cutoff, cell)
        cross = (pairs[:, 0] < 100) & (pairs[:, 1] >= 100)
        want = np.column_stack([pairs[cross, 1] - 100, pairs[cross, 0]])
        order = np.lexsort((want[:, 1], want[:, 0]))
        res = ours.search(query)
        np.testing.assert_array_equal(res.get_pairs(), want[order])
        np.testing.assert_allclose(res.get_pair_distances(), dist[cross][order], rtol=1e-12)

    @pytest.mark.parametrize("cutoff", [0.7, 2.0])
    def test_open_with_pseudo_box(self, cutoff):
        rng = np.random.default_rng(2)
        coords = rng.uniform(0, 9.5, (250, 3)).astype(np.float32)
        query = rng.uniform(0, 9.5, (40, 3)).astype(np.float32)
        box = np.array([10, 10, 10, 90, 90, 90], np.float32)
        theirs = nsgrid.FastNS(cutoff, coords, box, pbc=False)
        ours = FastNS(cutoff, coords, box, pbc=False)
        _assert_like_mda(ours.self_search(), theirs.self_search(), cutoff, True)
        _assert_like_mda(ours.search(query), theirs.search(query), cutoff, False)
        pairs, dist = brute_image_pairs(coords, cutoff, None)
        np.testing.assert_array_equal(ours.self_search().get_pairs(), pairs)
        np.testing.assert_allclose(ours.self_search().get_pair_distances(), dist, rtol=1e-12)

    def test_per_atom_lists(self):
        rng = np.random.default_rng(3)
        coords = rng.uniform(0, 10, (120, 3))
        query = rng.uniform(0, 10, (30, 3))
        ns = FastNS(2.0, coords, [10, 10, 10, 90, 90, 90])
        res = ns.self_search()
        pairs, dist = res.get_pairs(), res.get_pair_distances()
        indices, distances = res.get_indices(), res.get_distances()
        assert len(indices) == len(distances) == 120
        for a in range(120):
            mine = (pairs == a).any(axis=1)
            other = np.where(pairs[mine, 0] == a, pairs[mine, 1], pairs[mine, 0])
            order = np.argsort(other)
            np.testing.assert_array_equal(indices[a], other[order])
            np.testing.assert_array_equal(distances[a], dist[mine][order])
        res = ns.search(query)
        pairs, dist = res.get_pairs(), res.get_pair_distances()
        indices, distances = res.get_indices(), res.get_distances()
        assert len(indices) == 30
        for q in range(30):
            np.testing.assert_array_equal(indices[q], pairs[pairs[:, 0] == q, 1])
            np.testing.assert_array_equal(distances[q], dist[pairs[:, 0] == q])

    def test_empty_and_results_are_copies(self):
        ns = FastNS(1.0, np.zeros((0, 3), np.float32), [5, 5, 5, 90, 90, 90])
        res = ns.self_search()
        assert res.get_pairs().shape == (0, 2) and res.get_pair_distances().shape == (0,)
        assert ns.search(np.zeros((2, 3))).get_pairs().shape == (0, 2)
        coords = np.array([[0, 0, 0], [0.5, 0, 0]], np.float64)
        ns = FastNS(1.0, coords, [5, 5, 5, 90, 90, 90])
        coords[1] = 3.0  # FastNS copied its coordinates, as MDAnalysis does
        res = ns.self_search()
        res.get_pairs()[:] = -1
        assert res.get_pairs().tolist() == [[0, 1]]


@needs_mdanalysis
def test_float32_tie_is_decided_in_float64():
    """The documented difference: MDAnalysis wraps -0.3158... into the box in
    float32 and finds the pair a hair beyond the cutoff; the exact distance of
    the given numbers is the cutoff itself, and d <= cutoff keeps it."""
    x = np.float32(-0.31582937)
    coords = np.array([[x, 0, 0], [9.0, 0, 0]], np.float32)
    box = np.array([10, 10, 10, 90, 90, 90], np.float32)
    cutoff = float(x) + 1.0  # exact: the distance across the periodic boundary
    assert len(nsgrid.FastNS(cutoff, coords, box).self_search().get_pairs()) == 0
    res = FastNS(cutoff, coords, box).self_search()
    assert res.get_pairs().tolist() == [[0, 1]]
    assert res.get_pair_distances().tolist() == [cutoff]
    pairs, dist = brute_image_pairs(coords, cutoff, Cell.from_dimensions(box).matrix)
    assert pairs.tolist() == [[0, 1]] and dist.tolist() == [cutoff]


@needs_mdanalysis
def test_lj_trajectory_against_mdanalysis():
    """Triclinic LJ liquid: self and cross searches equal MDAnalysis's on every frame."""
    for frame in list(iter_frames(DATA / "lj.dump"))[::2]:
        box = np.asarray(Cell(frame.cell).dimensions, np.float32)
        coords = frame.positions.astype(np.float32)
        theirs, ours = nsgrid.FastNS(2.5, coords, box), FastNS(2.5, coords, box)
        _assert_like_mda(ours.self_search(), theirs.self_search(), 2.5, True)
        _assert_like_mda(ours.search(coords[::7]), theirs.search(coords[::7]), 2.5, False)


@needs_mdanalysis
def test_pour_trajectory_against_mdanalysis():
    """Granular pour, open boundaries, MDAnalysis's pseudo-box recipe."""
    for frame in list(iter_frames(DATA / "pour.dump"))[::5]:
        coords = frame.positions.astype(np.float32)
        lmin, lmax = coords.min(axis=0), coords.max(axis=0)
        box = np.zeros(6, np.float32)
        box[:3], box[3:] = 1.1 * (lmax - lmin), 90.0
        shifted = coords - lmin
        theirs = nsgrid.FastNS(2.0, shifted, box, pbc=False)
        ours = FastNS(2.0, shifted, box, pbc=False)
        _assert_like_mda(ours.self_search(), theirs.self_search(), 2.0, True)


class TestFastNSErrors:
    def test_cutoff_negative(self):
        with pytest.raises(ValueError, match="cutoff must be non-negative, got -1.0"):
            FastNS(-1.0, np.zeros((2, 3)), [5, 5, 5, 90, 90, 90])

    def test_coords_shape(self):
        with pytest.raises(ValueError, match=r"coords must have shape \(n, 3\), got \(4, 2\)"):
            FastNS(1.0, np.zeros((4, 2)), [5, 5, 5, 90, 90, 90])

    @pytest.mark.parametrize("box, got", [(None, "None"), (np.eye(3), r"shape \(3, 3\)")])
    def test_box_shape(self, box, got):
        with pytest.raises(ValueError, match=r"box must be \[lx, ly, lz, alpha, beta, gamma\] "
                                              rf"\(shape \(6,\)\), got {got}"):
            FastNS(1.0, np.zeros((2, 3)), box)

    def test_box_zero_length(self):
        with pytest.raises(ValueError, match="box lengths must be positive"):
            FastNS(1.0, np.zeros((2, 3)), [5, 0, 5, 90, 90, 90])

    def test_pbc_type(self):
        with pytest.raises(TypeError, match="pbc must be True or False, got 'yes'"):
            FastNS(1.0, np.zeros((2, 3)), [5, 5, 5, 90, 90, 90], pbc="yes")

    def test_cutoff_too_large(self):
        with pytest.raises(ValueError, match=r"Cutoff 3.0 too large for box \(max 2.5\): at "
                                              r"most half the smallest perpendicular cell "
                                              r"width"):
            FastNS(3.0, np.zeros((2, 3)), [5, 6, 7, 90, 90, 90])

    @pytest.mark.parametrize("cutoff, match", [(-4, "Cutoff must be positive"),
                                               (100000, "Cutoff 100000 too large for box")])
    def test_cutoff_errors_worded_like_mdanalysis(self, cutoff, match):
        # MDAnalysisTests lib/test_nsgrid.py::test_nsgrid_badcutoff, with the class
        # substituted (tests/test_peer_suites.py runs the original too)
        with pytest.raises(ValueError, match=match):
            FastNS(cutoff, np.zeros((2, 3)), [10, 10, 10, 90, 90, 90]).search(np.zeros((1, 3)))

    def test_search_coords_shape(self):
        ns = FastNS(1.0, np.zeros((2, 3)), [5, 5, 5, 90, 90, 90])
        with pytest.raises(ValueError, match=r"search_coords must have shape \(n, 3\)"):
            ns.search(np.zeros(3))


@pytest.mark.parametrize("n_threads", [1, 2])
def test_thread_count_changes_nothing(n_threads):
    frame = next(iter(iter_frames(DATA / "lj.dump")))
    atoms = Atoms(positions=frame.positions, cell=frame.cell, pbc=frame.pbc)
    cutoffs = np.full(len(atoms), 0.6)
    ref, nl = NeighborList(cutoffs, n_threads=1), NeighborList(cutoffs, n_threads=n_threads)
    ref.update(atoms), nl.update(atoms)
    np.testing.assert_array_equal(_rows(nl, len(atoms)), _rows(ref, len(atoms)))
    box = Cell(frame.cell).dimensions
    a = FastNS(2.5, frame.positions, box, n_threads=1)
    b = FastNS(2.5, frame.positions, box, n_threads=n_threads)
    for ra, rb in ((a.self_search(), b.self_search()),
                   (a.search(frame.positions[::5]), b.search(frame.positions[::5]))):
        np.testing.assert_array_equal(rb.get_pairs(), ra.get_pairs())
        np.testing.assert_array_equal(rb.get_pair_distances(), ra.get_pair_distances())
