"""sphere_contacts, neighbor_pairs and clump_contacts against brute-force oracles."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granularsap import clump_contacts, neighbor_pairs, sphere_contacts
from granularsap.periodic import cell_from_dimensions

from .oracles import brute_image_pairs, sort_pairs

BOXES = {
    "none": None,
    "ortho": [8.0, 9.0, 10.0, 90.0, 90.0, 90.0],
    "triclinic": [9.0, 10.0, 11.0, 75.0, 80.0, 105.0],
    "matrix": [[8.0, 0.0, 0.0], [2.0, 9.0, 0.0], [-1.5, 1.0, 10.0]],
}


def _cell(box):
    if box is None:
        return None
    box = np.asarray(box, dtype=float)
    return cell_from_dimensions(box) if box.shape == (6,) else box


def _sorted(pairs, dist=None):
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order], (None if dist is None else np.asarray(dist)[order])


def _assert_pairs(got, want):
    gp, gd = _sorted(*got)
    wp, wd = want
    assert gp.dtype == np.int64
    assert np.array_equal(gp, wp), (len(gp), len(wp))
    if gd is not None:
        np.testing.assert_allclose(gd, wd, rtol=1e-12, atol=1e-12)


def _points(seed, n, lo=-3.0, hi=13.0):
    rng = np.random.default_rng(seed)
    return rng.uniform(lo, hi, (n, 3))


class TestNeighborPairs:
    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("cutoff", [0.0, 1.3, 3.0])
    @pytest.mark.parametrize("seed", [0, 1])
    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_against_brute_force(self, box, cutoff, seed, n_threads):
        pos = _points(seed, 70)  # some outside the cell: never required to wrap
        got = neighbor_pairs(pos, cutoff, box=BOXES[box], n_threads=n_threads)
        want = brute_image_pairs(pos, cutoff, _cell(BOXES[box]))
        _assert_pairs(got, want)
        assert np.all(got[0][:, 0] < got[0][:, 1])

    def test_return_distances_false(self):
        pos = _points(3, 40)
        pairs = neighbor_pairs(pos, 2.0, return_distances=False)
        assert isinstance(pairs, np.ndarray) and pairs.shape[1] == 2

    def test_ties_on_integer_grid_are_included(self):
        g = np.arange(4.0)
        pos = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        pairs, d = neighbor_pairs(pos, 1.0)
        assert len(pairs) == 3 * 4 * 4 * 3  # nearest neighbours on a 4x4x4 grid
        assert np.all(d == 1.0)
        # periodic 4x4x4 cell: every site has 6 neighbours at exactly 1
        pairs, d = neighbor_pairs(pos, 1.0, box=[4, 4, 4, 90, 90, 90])
        assert len(pairs) == 64 * 6 // 2 and np.all(d == 1.0)

    def test_cutoff_exactly_half_the_cell_gives_each_pair_once(self):
        # two images of the pair tie at exactly cutoff = L / 2
        pos = np.array([[0.0, 0, 0], [2.0, 0, 0]])
        pairs, d = neighbor_pairs(pos, 2.0, box=[4, 4, 4, 90, 90, 90])
        assert pairs.tolist() == [[0, 1]] and d.tolist() == [2.0]

    def test_particles_on_faces_and_far_outside(self):
        L = 5.0
        pos = np.array([[0.0, 0, 0], [L, 0, 0], [L, L, L], [-L, 0, 0], [3 * L + 0.5, 0, 0],
                        [0.0, 0, -0.25]])
        got = neighbor_pairs(pos, 1.0, box=[L, L, L, 90, 90, 90])
        want = brute_image_pairs(pos, 1.0, np.diag([L, L, L]))
        _assert_pairs(got, want)
        assert len(got[0]) == 15  # 0,1,2,3 coincide (6 pairs); all 5 near 0/4/5

    def test_identical_positions(self):
        pos = np.zeros((5, 3))
        pairs, d = neighbor_pairs(pos, 0.0)
        assert len(pairs) == 10 and np.all(d == 0.0)

    @pytest.mark.parametrize("n", [0, 1])
    @pytest.mark.parametrize("box", [None, [5, 5, 5, 90, 90, 90]])
    def test_empty_and_single(self, n, box):
        pairs, d = neighbor_pairs(np.zeros((n, 3)), 1.0, box=box)
        assert pairs.shape == (0, 2) and pairs.dtype == np.int64
        assert d.shape == (0,) and d.dtype == np.float64

    def test_cutoff_larger_than_half_cell_raises(self):
        with pytest.raises(ValueError, match=r"cutoff 3 exceeds half the smallest "
                                             r"perpendicular cell width 2\.5"):
            neighbor_pairs(np.zeros((2, 3)), 3.0, box=[5, 6, 7, 90, 90, 90])

    def test_triclinic_uses_perpendicular_width(self):
        # edge lengths 10 but a 45 degree tilt: perpendicular width is 10 * sin(45)
        box = [10.0, 10.0, 10.0, 90.0, 90.0, 45.0]
        with pytest.raises(ValueError, match=r"half the smallest perpendicular cell width "
                                             r"3\.53553"):
            neighbor_pairs(np.zeros((2, 3)), 4.0, box=box)

    @pytest.mark.parametrize("bad, exc, match", [
        (dict(positions=np.zeros((3, 2))), ValueError, r"positions must have shape \(n, 3\)"),
        (dict(positions=[[0, 0, np.nan]]), ValueError, r"positions must be finite"),
        (dict(positions=[["a", "b", "c"]]), TypeError, r"positions must be an array of real"),
        (dict(cutoff=-1.0), ValueError, r"cutoff must be non-negative, got -1.0"),
        (dict(cutoff=np.inf), ValueError, r"cutoff must be finite"),
        (dict(cutoff="1"), TypeError, r"cutoff must be a real number"),
        (dict(box=[1, 1, 1]), ValueError, r"box must be \[lx, ly, lz, alpha, beta, gamma\]"),
        (dict(box=[5, 0, 5, 90, 90, 90]), ValueError, r"box lengths must be positive"),
        (dict(n_threads=0), ValueError, r"n_threads must be between 1"),
        (dict(n_threads=1.5), TypeError, r"n_threads must be an int"),
    ])
    def test_bad_input(self, bad, exc, match):
        kw = dict(positions=np.zeros((2, 3)), cutoff=1.0)
        kw.update(bad)
        pos = kw.pop("positions")
        cutoff = kw.pop("cutoff")
        with pytest.raises(exc, match=match):
            neighbor_pairs(pos, cutoff, **kw)


class TestSphereContacts:
    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("skin", [0.0, 0.3])
    @pytest.mark.parametrize("seed", [0, 1])
    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_polydisperse_against_brute_force(self, box, skin, seed, n_threads):
        rng = np.random.default_rng(seed + 10)
        pos = _points(seed, 80)
        radii = np.exp(rng.uniform(np.log(0.1), np.log(1.0), len(pos)))  # 1:10
        radii[::17] = 0.0  # zero radius is allowed
        got = sphere_contacts(pos, radii, skin=skin, box=BOXES[box], n_threads=n_threads,
                              return_distances=True)
        want = brute_image_pairs(pos, skin, _cell(BOXES[box]), radii=radii)
        _assert_pairs(got, want)

    def test_scalar_radius_and_default_return(self):
        pos = np.array([[0.0, 0, 0], [1.5, 0, 0], [5.0, 0, 0]])
        pairs = sphere_contacts(pos, 1.0)
        assert isinstance(pairs, np.ndarray) and pairs.tolist() == [[0, 1]]

    def test_touching_spheres_count(self):
        pos = np.array([[0.0, 0, 0], [0.75, 0, 0], [0.75, 0.75, 0.0]])
        assert _sorted(sphere_contacts(pos, [0.5, 0.25, 0.5]))[0].tolist() == [[0, 1], [1, 2]]

    @pytest.mark.parametrize("box", ["none", "triclinic"])
    def test_parallel_kernels_on_a_small_input(self, box, monkeypatch):
        # an explicit thread count runs the parallel kernels however small the
        # input; one thread runs their serial builds: both equal the oracle
        import granularsap.search.plan

        monkeypatch.setattr(granularsap.search.plan, "CHUNK", 16)  # many chunks
        pos = _points(11, 90)
        radii = np.random.default_rng(11).uniform(0.1, 1.2, 90)
        serial = _sorted(*sphere_contacts(pos, radii, box=BOXES[box], n_threads=1,
                                          return_distances=True))
        par = _sorted(*sphere_contacts(pos, radii, box=BOXES[box], n_threads=2,
                                       return_distances=True))
        assert np.array_equal(serial[0], par[0]) and np.array_equal(serial[1], par[1])
        _assert_pairs(par, brute_image_pairs(pos, 0.0, _cell(BOXES[box]), radii=radii))
        pos, radii, ids = _make_clumps(12, 40, 3, 8.0)
        sp, cp = clump_contacts(pos, radii, ids, box=BOXES[box], n_threads=2)
        wp, _, wcp = _clump_oracle(pos, radii, ids, 0.0, _cell(BOXES[box]))
        assert np.array_equal(_sorted(sp)[0], wp) and np.array_equal(cp, wcp)

    @pytest.mark.parametrize("box", ["none", "ortho", "triclinic"])
    def test_verlet_frames_in_several_chunks(self, box, monkeypatch):
        # a kept Verlet list re-tested on one thread writes each chunk's pairs
        # with room for all its entries, then closes the chunks up: the rows and
        # their order are those of the two passes two threads run, and the
        # pairs those of the brute force, frame after frame
        import granularsap.search.plan
        from granularsap import ContactSearch

        monkeypatch.setattr(granularsap.search.plan, "CHUNK", 16)  # many chunks
        rng = np.random.default_rng(21)
        pos = _points(21, 120)
        radii = rng.uniform(0.1, 1.0, 120)
        one = ContactSearch(rebuild_margin=0.4, quantities="PdDS", n_threads=1, identity=True)
        two = ContactSearch(rebuild_margin=0.4, quantities="PdDS", n_threads=2, identity=True)
        kept = 0
        for _ in range(6):
            pos = pos + rng.normal(0.0, 0.02, pos.shape)
            a = one.update(pos, radii, BOXES[box], copy=True)
            b = two.update(pos, radii, BOXES[box], copy=True)
            kept += not one.stats["rebuilt"]
            assert len(one._verlet.counts) > 1
            for x, y in zip(a, b, strict=True):
                assert np.array_equal(x, y)
            assert np.array_equal(one.previous_rows, two.previous_rows)
            assert np.array_equal(one.ended_rows, two.ended_rows)
            _assert_pairs(a[:2], brute_image_pairs(pos, 0.0, _cell(BOXES[box]), radii=radii))
        assert kept >= 3  # the list was kept, not rebuilt, on most frames

    def test_thread_count_does_not_change_result(self):
        rng = np.random.default_rng(5)
        pos = rng.uniform(0, 20, (3000, 3))
        radii = rng.uniform(0.1, 0.6, 3000)
        box = [20, 20, 20, 90, 90, 90]
        one = _sorted(*sphere_contacts(pos, radii, box=box, n_threads=1, return_distances=True))
        two = _sorted(*sphere_contacts(pos, radii, box=box, n_threads=2, return_distances=True))
        assert np.array_equal(one[0], two[0]) and np.array_equal(one[1], two[1])

    @pytest.mark.parametrize("bad, exc, match", [
        (dict(radii=[1.0, -1.0, 0.5, 0.1]), ValueError,
         r"radii must be non-negative, got -1.0 at index 1"),
        (dict(radii=[1.0, 1.0]), ValueError, r"radii must be a scalar or have shape \(4,\)"),
        (dict(radii=[1.0, np.nan, 1, 1]), ValueError, r"radii must be finite"),
        (dict(skin=-0.1), ValueError, r"skin must be non-negative"),
        (dict(box=[5, 5, 5, 90, 90, 190]), ValueError,
         r"box angles must be in \(0, 180\) degrees"),
        (dict(box=[5, 5, 5, 30, 30, 90]), ValueError, r"do not form a cell of positive volume"),
        (dict(box=np.zeros((3, 3))), ValueError, r"box vector 0 is zero"),
        (dict(box=[[1, 0, 0], [2, 0, 0], [0, 0, 1]]), ValueError,
         r"box must be a non-degenerate cell"),
        (dict(box=[5, 5, 5, 90, 90, 90], radii=1.5), ValueError,
         r"interaction range 2 \* max\(radii\) \+ skin 3 exceeds half"),
    ])
    def test_bad_input(self, bad, exc, match):
        kw = dict(radii=0.5)
        kw.update(bad)
        radii = kw.pop("radii")
        with pytest.raises(exc, match=match):
            sphere_contacts(np.zeros((4, 3)), radii, **kw)


def _clump_oracle(pos, radii, ids, skin, cell):
    pairs, dist = brute_image_pairs(pos, skin, cell, radii=radii)
    inter = ids[pairs[:, 0]] != ids[pairs[:, 1]] if len(pairs) else np.zeros(0, bool)
    pairs, dist = pairs[inter], dist[inter]
    cp = np.sort(np.stack([ids[pairs[:, 0]], ids[pairs[:, 1]]], 1), axis=1)
    cp = np.unique(cp, axis=0) if len(cp) else np.empty((0, 2), np.int64)
    return pairs, dist, cp


def _make_clumps(seed, n_clumps, size, box_len):
    """Rigid dimers/trimers: each clump is a few spheres around a random centre."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-1.0, box_len + 1.0, (n_clumps, 3))  # some outside the cell
    offsets = rng.normal(0.0, 0.35, (n_clumps, size, 3))
    pos = (centres[:, None, :] + offsets).reshape(-1, 3)
    ids = np.repeat(rng.permutation(n_clumps) * 3 + 100, size)  # arbitrary labels
    radii = rng.uniform(0.15, 0.45, len(pos))
    return pos, radii, ids


class TestClumpContacts:
    @pytest.mark.parametrize("box", ["none", "ortho", "triclinic"])
    @pytest.mark.parametrize("seed", [0, 1, 2])
    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_against_brute_force_minus_intra(self, box, seed, n_threads):
        pos, radii, ids = _make_clumps(seed, 25, 3, 8.0)
        got_sp, got_cp = clump_contacts(pos, radii, ids, skin=0.1, box=BOXES[box],
                                        n_threads=n_threads)
        wp, wd, wcp = _clump_oracle(pos, radii, ids, 0.1, _cell(BOXES[box]))
        assert np.array_equal(_sorted(got_sp)[0], wp)
        assert np.array_equal(got_cp, wcp)
        assert np.all(ids[got_sp[:, 0]] != ids[got_sp[:, 1]])

    def test_clump_straddling_the_boundary(self):
        # clump 1 sits across the x faces of the cell; clump 2 touches its far part
        pos = np.array([[9.8, 5, 5], [10.4, 5, 5], [0.9, 5, 5], [3, 3, 3]])
        ids = np.array([1, 1, 2, 3])
        sp, cp = clump_contacts(pos, 0.3, ids, box=[10, 10, 10, 90, 90, 90])
        assert _sorted(sp)[0].tolist() == [[1, 2]] and cp.tolist() == [[1, 2]]

    def test_single_clump_has_no_pairs(self):
        pos = np.zeros((4, 3))
        sp, cp = clump_contacts(pos, 1.0, [3, 3, 3, 3])
        assert sp.shape == (0, 2) and cp.shape == (0, 2)

    def test_every_sphere_its_own_clump_equals_sphere_contacts(self):
        pos = _points(7, 60)
        radii = np.random.default_rng(7).uniform(0.2, 0.8, 60)
        box = BOXES["triclinic"]
        sp, cp = clump_contacts(pos, radii, np.arange(60), box=box)
        want = sphere_contacts(pos, radii, box=box)
        assert np.array_equal(_sorted(sp)[0], _sorted(want)[0])
        assert np.array_equal(cp, _sorted(want)[0])

    def test_empty(self):
        sp, cp = clump_contacts(np.zeros((0, 3)), 1.0, [])
        assert sp.shape == (0, 2) and cp.shape == (0, 2)

    @pytest.mark.parametrize("ids, exc, match", [
        ([0, 1], ValueError, r"clump_ids must have shape \(3,\)"),
        ([0.5, 1, 2], TypeError, r"clump_ids must be integers"),
    ])
    def test_bad_ids(self, ids, exc, match):
        with pytest.raises(exc, match=match):
            clump_contacts(np.zeros((3, 3)), 0.5, ids)

    def test_uint64_ids_at_or_above_2_63_are_refused_not_made_negative(self):
        """Issue 20: such ids came back as negative int64 clump labels."""
        from granularsap import ContactSearch

        pos = np.array([[0.0, 0, 0], [0.9, 0, 0], [1.8, 0, 0]])
        big = np.array([7, 2**63, 2**63 + 5], dtype=np.uint64)
        with pytest.raises(ValueError, match=r"clump_ids must be below 2\*\*63 \(labels are "
                                             r"int64\), got 9223372036854775813 at index 2"):
            clump_contacts(pos, 0.5, big)
        with pytest.raises(ValueError, match=r"clump_ids must be below 2\*\*63"):
            ContactSearch().update(pos, 0.5, clump_ids=big)
        # below 2**63 uint64 ids are the same labels as int64 ones
        ok = np.array([7, 2**63 - 1, 2**63 - 1], dtype=np.uint64)
        sp, cp = clump_contacts(pos, 0.5, ok)
        assert sp.tolist() == [[0, 1]] and cp.tolist() == [[7, 2**63 - 1]]
        assert cp.dtype == np.int64

    def test_clump_wider_than_half_the_cell_pairs_spheres_at_their_own_images(self):
        # a chain of spheres longer than half the cell: every sphere pair between
        # different clumps is decided at its own minimum image
        pos = np.array([[0.0, 0, 0], [3.5, 0, 0], [7.0, 0, 0], [8.9, 0, 0], [5.2, 0.3, 0]])
        ids = np.array([4, 4, 4, 5, 6])
        box = [10.5, 10, 10, 90, 90, 90]
        sp, cp = clump_contacts(pos, 1.0, ids, box=box)
        wp, _, wcp = _clump_oracle(pos, np.full(5, 1.0), ids, 0.0, _cell(box))
        assert np.array_equal(_sorted(sp)[0], wp) and np.array_equal(cp, wcp)
        assert len(wp) == 4


# ---------------------------------------------------------------- properties

coords = st.lists(st.tuples(*[st.integers(0, 40)] * 3), min_size=0, max_size=40)


@settings(max_examples=40, deadline=None)
@given(pts=coords, cut=st.integers(0, 12), seed=st.integers(0, 2**32 - 1),
       shift=st.tuples(*[st.integers(-64, 64)] * 3))
def test_permutation_and_translation_invariance(pts, cut, seed, shift):
    # dyadic grid coordinates: sums and differences are exact, so even ties
    # (d == cutoff) must survive a permutation and a translation
    pos = np.asarray(pts, dtype=float).reshape(-1, 3) / 4.0
    cutoff = cut / 4.0
    box = [16.0, 16.0, 16.0, 90, 90, 90]
    base = sort_pairs(neighbor_pairs(pos, cutoff, box=box)[0])
    perm = np.random.default_rng(seed).permutation(len(pos))
    p2 = neighbor_pairs(pos[perm], cutoff, box=box)[0]
    p2 = sort_pairs(np.sort(perm[p2], axis=1)) if len(p2) else p2
    assert np.array_equal(base, p2)
    # translations by any vector (here multiples of 1/4, also across the cell)
    p3 = sort_pairs(neighbor_pairs(pos + np.asarray(shift) / 4.0, cutoff, box=box)[0])
    assert np.array_equal(base, p3)
    # open boundaries: pairs are unique with i < j
    p4 = neighbor_pairs(pos, cutoff)[0]
    assert np.all(p4[:, 0] < p4[:, 1])
    assert len(np.unique(p4, axis=0)) == len(p4)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 30))
def test_rotation_invariance_open_boundaries(seed, n):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0, 6, (n, 3))
    radii = rng.uniform(0.1, 1.0, n)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    a, da = sphere_contacts(pos, radii, return_distances=True)
    b, db = sphere_contacts(pos @ q.T, radii, return_distances=True)
    (a, da), (b, db) = _sorted(a, da), _sorted(b, db)
    # rotation changes rounding: compare away from the contact threshold
    thr_a = radii[a[:, 0]] + radii[a[:, 1]] if len(a) else np.zeros(0)
    thr_b = radii[b[:, 0]] + radii[b[:, 1]] if len(b) else np.zeros(0)
    sa = {tuple(p) for p, d, t in zip(a.tolist(), da, thr_a, strict=True) if d < t - 1e-9}
    sb = {tuple(p) for p, d, t in zip(b.tolist(), db, thr_b, strict=True) if d < t - 1e-9}
    assert sa <= {tuple(p) for p in b.tolist()} and sb <= {tuple(p) for p in a.tolist()}


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 40),
       box=st.sampled_from(["none", "ortho", "triclinic", "matrix"]))
def test_sphere_contacts_match_oracle_random(seed, n, box):
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-5, 15, (n, 3))
    radii = rng.uniform(0.0, 1.5, n)
    got = sphere_contacts(pos, radii, box=BOXES[box], return_distances=True)
    _assert_pairs(got, brute_image_pairs(pos, 0.0, _cell(BOXES[box]), radii=radii))
