"""The particle engine's paths: the column sweep (one or two column levels, direct or
through a Verlet list) and the paper's Sweep and Prune over bounding cubes give the
same pairs and the same distances, bit for bit, as each other and the oracle."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granularsap import ContactSearch, NeighborSearch
from granularsap.periodic import as_cell

from .oracles import brute_image_pairs

PATHS = ("columns", "sweep", "auto")

#: dyadic cells, so that quarter-integer coordinates give exact ties
CELLS = {
    "open": (None, None),
    "ortho": ([[8.0, 0, 0], [0, 8.0, 0], [0, 0, 8.0]], None),
    "triclinic": ([[8.0, 0, 0], [2.0, 8.0, 0], [-1.0, 1.5, 8.0]], None),
    "mixed": ([[8.0, 0, 0], [1.0, 8.0, 0], [0, 0, 8.0]], (True, False, True)),
}


def _canon(pairs, dist):
    pairs = np.asarray(pairs).reshape(-1, 2)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order], np.asarray(dist)[order]


def _oracle(pos, box, pbc, cutoff=0.0, radii=None):
    cell = None if box is None else as_cell(box, pbc=(True,) * 3 if pbc is None else pbc)
    pb = (True, True, True) if pbc is None else pbc
    return brute_image_pairs(pos, cutoff, cell, pbc=pb, radii=radii)


def _run(search, pos, box, pbc, radii=None):
    if radii is None:
        return _canon(*search.update(pos, box, pbc=pbc))
    return _canon(*search.update(pos, radii, box, pbc=pbc))


def _check_all_paths(pos, box, pbc, *, cutoff=None, radii=None, skin=0.0, margin=0.0,
                     levels=None):
    """Every path and thread count on one frame: equal to each other bit for bit and
    to the oracle."""
    results = {}
    for path in PATHS:
        for n_threads in (1, 2):
            if radii is None:
                search = NeighborSearch(cutoff, path=path, n_threads=n_threads,
                                        rebuild_margin=margin)
            else:
                search = ContactSearch(skin=skin, path=path, n_threads=n_threads,
                                       rebuild_margin=margin, quantities="Pd")
            if levels is not None:
                search._levels = levels
            results[path, n_threads] = _run(search, pos, box, pbc, radii)
            if path != "auto":
                assert search.stats["path"] == path
    (p0, d0) = results["columns", 1]
    for key, (p, d) in results.items():
        assert np.array_equal(p, p0), key
        assert np.array_equal(d, d0), key  # bit for bit
    want_p, want_d = _oracle(pos, box, pbc, cutoff=skin if cutoff is None else cutoff,
                             radii=radii)
    assert np.array_equal(p0, want_p)
    np.testing.assert_allclose(d0, want_d, rtol=1e-12)
    return p0


coords = st.lists(st.tuples(*[st.integers(-16, 48)] * 3), min_size=0, max_size=28)


@settings(max_examples=25, deadline=None)
@given(pts=coords, cut=st.integers(0, 14), cell=st.sampled_from(sorted(CELLS)))
def test_cutoff_ties_on_every_path(pts, cut, cell):
    # quarter-integer coordinates, some outside the cell and on its faces; a
    # quarter-integer cutoff makes distances at the cutoff exact ties
    pos = np.asarray(pts, dtype=float).reshape(-1, 3) / 4.0
    box, pbc = CELLS[cell]
    _check_all_paths(pos, box, pbc, cutoff=cut / 4.0)


@settings(max_examples=25, deadline=None)
@given(pts=coords, rad=st.lists(st.integers(0, 6), min_size=28, max_size=28),
       cell=st.sampled_from(sorted(CELLS)), margin=st.sampled_from([0.0, 0.5]))
def test_touching_spheres_on_every_path(pts, rad, cell, margin):
    # dyadic radii: spheres exactly touching (d == r_i + r_j) are ties; zero radii
    # are points that touch only where they coincide
    pos = np.asarray(pts, dtype=float).reshape(-1, 3) / 4.0
    radii = np.asarray(rad[: len(pos)], dtype=float) / 8.0
    box, pbc = CELLS[cell]
    _check_all_paths(pos, box, pbc, radii=radii, margin=margin)


@pytest.mark.parametrize("cell", sorted(CELLS))
def test_two_column_levels_equal_one(cell):
    # widely spread radii with the small/large split forced: the large spheres
    # walk a wider stencil, large-large pairs are kept by their lower end
    rng = np.random.default_rng(7)
    n = 400
    box, pbc = CELLS[cell]
    pos = rng.uniform(-1.0, 9.0, (n, 3))
    radii = np.where(rng.random(n) < 0.1, rng.uniform(0.8, 1.5, n), rng.uniform(0.05, 0.3, n))
    radii[:3] = 1.5  # ties among the largest
    for split in (0.3, 0.8):
        pairs = _check_all_paths(pos, box, pbc, radii=radii, skin=0.02, levels=split)
        assert len(pairs)
        search = ContactSearch(skin=0.02)
        search._levels = split
        search.update(pos, radii, box, pbc=pbc)
        assert search.stats["levels"] == 2


def test_levels_chosen_for_a_wide_size_spread():
    # many small spheres and a few large ones: the cost model splits them
    rng = np.random.default_rng(8)
    n = 20000
    radii = np.where(rng.random(n) < 0.02, 2.0, 0.2)
    length = 30.0
    pos = rng.uniform(0.0, length, (n, 3))
    box = [length] * 3 + [90.0] * 3
    search = ContactSearch(quantities="Pd")
    got = _canon(*search.update(pos, radii, box))
    assert search.stats["levels"] == 2
    one = ContactSearch(quantities="Pd")
    one._levels = False
    want = _canon(*one.update(pos, radii, box))
    assert one.stats["levels"] == 1
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


def test_auto_keeps_one_path_over_frames_of_widely_spread_sizes():
    # a sparse frame of widely spread sizes: the column sweep tests many candidates
    # per contact; auto decides from the frame (tests/test_path_choice.py), so the
    # same frame keeps its path, and the contacts never change
    rng = np.random.default_rng(9)
    n = 3000
    radii = np.where(rng.random(n) < 0.01, 3.0, 0.1)
    pos = rng.uniform(0.0, 60.0, (n, 3))
    box = [60.0] * 3 + [90.0] * 3
    search = ContactSearch(quantities="Pd")
    search._levels = False
    seen = []
    first = None
    for _ in range(3):
        got = _canon(*search.update(pos, radii, box))
        first = got if first is None else first
        assert np.array_equal(got[0], first[0]) and np.array_equal(got[1], first[1])
        seen.append((search.stats["path"], search.stats["path_reason"]))
    assert seen[0] == seen[1] == seen[2]


def test_auto_keeps_columns_on_dense_points():
    rng = np.random.default_rng(10)
    pos = rng.uniform(0.0, 12.0, (3000, 3))
    search = NeighborSearch(1.5)
    for _ in range(3):
        search.update(pos, [12.0] * 3 + [90.0] * 3)
        assert search.stats["path"] == "columns"
    assert "3000 particles" in search.stats["path_reason"]


def test_bad_path_is_named():
    with pytest.raises(ValueError, match=r"path must be one of 'auto', 'columns', 'sweep'"):
        NeighborSearch(1.0, path="grid")
    with pytest.raises(ValueError, match=r"path must be one of"):
        ContactSearch(path=None)
