"""Drop-ins against ASE and MDAnalysis at edge cutoffs: zero cutoffs with
self_interaction, cutoffs that are not float32 numbers, cutoffs at exactly half
the box."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

ase = pytest.importorskip("ase")
pytest.importorskip("MDAnalysis")
from ase import Atoms  # noqa: E402
from ase.neighborlist import NeighborList as AseNeighborList  # noqa: E402
from ase.neighborlist import NewPrimitiveNeighborList, PrimitiveNeighborList  # noqa: E402
from ase.neighborlist import neighbor_list as ase_neighbor_list  # noqa: E402
from MDAnalysis.lib import distances as mda_distances  # noqa: E402
from MDAnalysis.lib.nsgrid import FastNS as MdaFastNS  # noqa: E402

from granularsap import _mda_arith  # noqa: E402
from granularsap import mda as gmda  # noqa: E402
from granularsap.ase import NeighborList, neighbor_list  # noqa: E402


def _rows(i, j, S):
    return sorted(zip(i.tolist(), j.tolist(), map(tuple, S.tolist()), strict=True))


def _pairs(pairs, symmetric):
    pairs = np.asarray(pairs).reshape(-1, 2)
    if symmetric:
        pairs = np.sort(pairs, axis=1)
    return set(map(tuple, pairs.tolist()))


# --------------------------------------------------------------------------- ASE


def _h3o3c2():
    rng = np.random.default_rng(3)
    return Atoms("H3O3C2", positions=rng.uniform(0, 5, (8, 3)), cell=np.eye(3) * 5, pbc=True)


@pytest.mark.parametrize("cutoff", [0.0, [0, 0, 1, 1, 0, 2, 0, 0.5], [0.0] * 8,
                                    {("H", "H"): 2.0}, {("H", "O"): 3.0, (6, 6): 4.0}],
                         ids=["zero", "some-zero-radii", "zero-radii", "dict-HH", "dict-no-OO"])
def test_self_interaction_needs_a_positive_cutoff_like_ase(cutoff):
    # ASE tests the self pair like any other (d = 0 < cutoff): an atom whose cutoff
    # with itself is zero is not its own neighbour
    atoms = _h3o3c2()
    want = ase_neighbor_list("ijS", atoms, cutoff, self_interaction=True)
    got = neighbor_list("ijS", atoms, cutoff, self_interaction=True)
    assert _rows(*got) == _rows(*want)


@pytest.mark.parametrize("primitive", [PrimitiveNeighborList, NewPrimitiveNeighborList])
@pytest.mark.parametrize("bothways", [False, True])
def test_neighborlist_self_interaction_with_zero_cutoff_and_no_skin(primitive, bothways):
    atoms = _h3o3c2()
    cutoffs = [0, 0, 1, 1, 0, 0.4, 1.2, 0]
    want = AseNeighborList(cutoffs, skin=0.0, bothways=bothways, primitive=primitive)
    got = NeighborList(cutoffs, skin=0.0, bothways=bothways, primitive=primitive)
    want.update(atoms)
    got.update(atoms)
    for a in range(len(atoms)):
        wi, wo = want.get_neighbors(a)
        gi, go = got.get_neighbors(a)
        assert sorted(zip(gi.tolist(), map(tuple, go.tolist()), strict=True)) == sorted(
            zip(wi.tolist(), map(tuple, wo.tolist()), strict=True)), a


# --------------------------------------------------------------------- MDAnalysis

_LATTICE = np.array([[x, y, z] for x in range(4) for y in range(4) for z in range(4)], float)


@pytest.mark.parametrize("box, count", [(None, 360), ([4, 4, 4, 90, 90, 90], 576),
                                        ([5, 5, 5, 90, 90, 90], 360)])
def test_nsgrid_tie_at_a_cutoff_that_is_not_a_float32(box, count):
    # FastNS keeps the cutoff in double: sqrt(2)**2 is 2.0000000000000004 there, so
    # the pairs at distance sqrt(2) are in; float32(sqrt(2))**2 would drop them
    cutoff = np.sqrt(2.0)
    want = mda_distances.self_capped_distance(_LATTICE, cutoff, box=box, method="nsgrid",
                                              return_distances=False)
    got = gmda.self_capped_distance(_LATTICE, cutoff, box=box, method="nsgrid",
                                    return_distances=False)
    assert len(want) == count and _pairs(got, True) == _pairs(want, True)
    want = mda_distances.capped_distance(_LATTICE[:10], _LATTICE, cutoff, box=box,
                                         method="nsgrid", return_distances=False)
    got = gmda.capped_distance(_LATTICE[:10], _LATTICE, cutoff, box=box, method="nsgrid",
                               return_distances=False)
    assert _pairs(got, False) == _pairs(want, False)


def test_default_method_on_a_grid_at_a_cutoff_that_is_not_a_float32():
    # 125 points: MDAnalysis's own choice for self_capped_distance is nsgrid
    pos = np.array([[x, y, z] for x in range(5) for y in range(5) for z in range(5)], float)
    box = [5, 5, 5, 90, 90, 90]
    want, dw = mda_distances.self_capped_distance(pos, np.sqrt(2.0), box=box)
    got, dg = gmda.self_capped_distance(pos, np.sqrt(2.0), box=box)
    assert _pairs(got, True) == _pairs(want, True) and len(want) == 125 * 9


def test_nsgrid_at_exactly_half_the_box():
    # cutoff == half the box: MDAnalysis's nsgrid runs (and wraps -1e-7 onto 0), so
    # its arithmetic decides, not bruteforce's
    pos = np.array([[0, 0, 0], [1, 0, 0], [-1, 0, 0], [4, 0, 0], [8, 0, 0], [-100, 0.5, 0],
                    [3.9999999, 0, 0], [-1e-7, 0, 0]])
    box = [4, 4, 4, 90, 90, 90]
    want, dw = mda_distances.self_capped_distance(pos, 2.0, box=box, method="nsgrid")
    got, dg = gmda.self_capped_distance(pos, 2.0, box=box, method="nsgrid")
    w = dict(zip(map(tuple, np.sort(want, axis=1).tolist()), dw.tolist(), strict=True))
    g = dict(zip(map(tuple, np.sort(got, axis=1).tolist()), dg.tolist(), strict=True))
    assert g == w


@pytest.mark.parametrize("box", [[10, 10, 10, 90, 90, 90], [5, 5, 5, 60, 90, 60],
                                 [27.270514, 44.25423, 18.462975, 115.28035, 94.551544, 62.521],
                                 [9, 12, 7.5, 70, 80, 100]])
def test_nsgrid_limit_is_mdanalysis_own(box):
    box32 = np.asarray(box, np.float32)
    try:
        MdaFastNS(1e9, np.zeros((1, 3), np.float32), box32)
    except ValueError as e:
        limit = float(str(e).rsplit("max ", 1)[1].rstrip(")"))
    for c in (limit, np.nextafter(limit, 0), np.nextafter(limit, 1e9), 0.99 * limit,
              1.01 * limit):
        try:
            MdaFastNS(c, np.zeros((1, 3), np.float32), box32)
            refused = False
        except ValueError:
            refused = True
        assert _mda_arith.nsgrid_refuses(c, box32) is refused, c


def test_no_box_cross_nsgrid_rounds_like_the_cutoff_type_given():
    # without a box MDAnalysis shifts both sets by min - 0.1 * max_cutoff: float32 for a
    # Python float, float64 for a numpy float64 (NEP 50); at a cutoff equal to a pair
    # distance the two give different pairs, and the drop-in must follow the one given
    rng = np.random.default_rng(0)
    for _ in range(20):
        pos = rng.uniform(-3, 12, (40, 3)).astype(np.float32)
        _, d = mda_distances.self_capped_distance(pos, 3.0, method="bruteforce")
        for cut in (d[0], float(d[0]), np.float32(d[0])):
            want = mda_distances.capped_distance(pos[:30], pos, cut, method="nsgrid",
                                                 return_distances=False)
            got = gmda.capped_distance(pos[:30], pos, cut, method="nsgrid",
                                       return_distances=False)
            assert _pairs(got, False) == _pairs(want, False), (cut, type(cut))


@pytest.mark.parametrize("box", [None, [5, 5, 5, 90, 90, 90], [10, 10, 10, 70, 80, 100]])
def test_pkdtree_distances_and_min_cutoff_are_mdanalysis_own(box):
    # MDAnalysis's pkdtree computes distances with calc_bonds (float32 inverse box:
    # 1.0000000149 for a lattice spacing of 1 in a box of 5), then applies min_cutoff
    pos = np.array([[x, y, z] for x in range(5) for y in range(5) for z in range(5)], float)
    pos = pos + np.random.default_rng(1).integers(0, 2, pos.shape) * 0.25
    for min_cutoff in (None, 1.0):
        want, dw = mda_distances.self_capped_distance(pos, 1.2, min_cutoff=min_cutoff,
                                                      box=box, method="pkdtree")
        got, dg = gmda.self_capped_distance(pos, 1.2, min_cutoff=min_cutoff, box=box,
                                            method="pkdtree")
        w = dict(zip(map(tuple, np.sort(want, axis=1).tolist()), dw.tolist(), strict=True))
        g = dict(zip(map(tuple, np.sort(got, axis=1).tolist()), dg.tolist(), strict=True))
        assert g == w and len(w) > 0


def test_too_large_cutoff_names_the_smallest_periodic_width():
    # widths 8.05, 7.69, 7.0: the message must name vector 2 (7.0), not the first
    # axis that is too narrow
    from granularsap import Cell, neighbor_pairs

    cell = Cell(np.array([[9.0, 0, 0], [4, 8, 0], [1, 2, 7]]))
    with pytest.raises(ValueError, match=r"smallest perpendicular cell width 3\.5.*"
                                         r"across cell vector 2"):
        neighbor_pairs(np.zeros((2, 3)), 4.0, box=cell)


_BOXES = [None, [8, 10, 8, 90, 90, 90], [6, 6, 6, 90, 90, 90], [10, 10, 10, 70, 80, 100],
          [7.5, 7.5, 7.5, 60, 60, 60]]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(2, 40),
       step=st.sampled_from([0.5, 0.25, 1 / 3]), box=st.sampled_from(_BOXES),
       method=st.sampled_from([None, "bruteforce", "nsgrid"]),
       numpy_cutoff=st.booleans())
def test_grid_ties_at_cutoffs_sqrt_k_like_mdanalysis(seed, k, step, box, method,
                                                     numpy_cutoff):
    # every cutoff sqrt(k) * step is the distance of many grid pairs, and most are not
    # float32 numbers
    rng = np.random.default_rng(seed)
    pos = rng.integers(-8, 30, (120, 3)) * step
    conf = rng.integers(-8, 30, (40, 3)) * step
    cut = np.sqrt(k) * step
    cut = np.float64(cut) if numpy_cutoff else float(cut)
    try:
        want, dw = mda_distances.self_capped_distance(pos, cut, box=box, method=method)
    except ValueError:  # nsgrid: cutoff too large for the box
        want = None
    if want is not None:
        got, dg = gmda.self_capped_distance(pos, cut, box=box, method=method)
        w = dict(zip(map(tuple, np.sort(want, axis=1).tolist()), dw.tolist(), strict=True))
        g = dict(zip(map(tuple, np.sort(got, axis=1).tolist()), dg.tolist(), strict=True))
        assert g == w
    try:
        want = mda_distances.capped_distance(pos, conf, cut, box=box, method=method,
                                             return_distances=False)
    except ValueError:
        return
    got = gmda.capped_distance(pos, conf, cut, box=box, method=method, return_distances=False)
    assert _pairs(got, False) == _pairs(want, False)
