"""granularsap.mda against MDAnalysis.lib.distances on identical inputs.

MDAnalysis computes from float32 coordinates and, on some paths, in float32
arithmetic (``conf[j] - ref[i]`` of two floats).  The inputs below are chosen
so that this arithmetic is exact, which makes the comparison exact too: points
on a dyadic grid (multiples of 1/64 below 32, so every difference fits a
float32 mantissa), orthorhombic boxes with power-of-two edges (exact inverse),
triclinic points strictly inside the cell (MDAnalysis does not move them), and
open-boundary sets spanning exactly 10 (MDAnalysis's pseudo-box shift is exact).
Pair sets must then be equal and distances agree to rtol 1e-12.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

mda_dist = pytest.importorskip("MDAnalysis.lib.distances")
mdamath = pytest.importorskip("MDAnalysis.lib.mdamath")

from granularsap import mda  # noqa: E402

ORTHO = [16.0, 8.0, 16.0, 90.0, 90.0, 90.0]
TRICLINIC = [16.0, 14.0, 15.0, 80.0, 75.0, 100.0]


def _grid(rng, n, lo, hi):
    return np.round(rng.uniform(lo, hi, (n, 3)) * 64.0) / 64.0


def _inside(rng, n, dims):
    """Dyadic points strictly inside the (triclinic) cell."""
    cell = mdamath.triclinic_vectors(np.asarray(dims, dtype=np.float32)).astype(np.float64)
    out = np.empty((0, 3))
    while len(out) < n:
        p = _grid(rng, 4 * n, -8, 24)
        s = np.linalg.solve(cell.T, p.T).T
        out = np.concatenate([out, p[np.all((s > 0.01) & (s < 0.99), axis=1)]])
    return out[:n]


def _points(seed, n, box):
    rng = np.random.default_rng(seed)
    if box is None:
        # open boundaries: MDAnalysis's grid path shifts points by
        # lmin - 0.1 * extent in float32; an extent of exactly 10 keeps that exact
        pts = _grid(rng, n, -2.0, 8.0)
        pts[:1], pts[1:2] = -2.0, 8.0
        return pts
    if box is ORTHO:
        return _grid(rng, n, -4.0, 20.0)  # outside the box as well: both wrap exactly
    return _inside(rng, n, box)


def _canon(pairs, dist=None, swap=False):
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if swap:
        pairs = np.sort(pairs, axis=1)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order], (None if dist is None else np.asarray(dist)[order])


def _assert_same(got, want, swap):
    (gp, gd), (wp, wd) = _canon(*got, swap=swap), _canon(*want, swap=swap)
    assert np.array_equal(gp, wp), (len(gp), len(wp))
    np.testing.assert_allclose(gd, wd, rtol=1e-12, atol=0)


class TestSelfCappedDistance:
    # n = 60 takes MDAnalysis's brute-force path, n = 400 its grid (or KD-tree) path
    @pytest.mark.parametrize("box", [None, ORTHO, TRICLINIC], ids=["none", "ortho", "tric"])
    @pytest.mark.parametrize("n", [60, 400])
    @pytest.mark.parametrize("cutoff", [0.3, 1.5, 3.0])
    @pytest.mark.parametrize("seed", [0, 1])
    def test_matches_mdanalysis(self, box, n, cutoff, seed):
        pos = _points(seed, n, box)
        got = mda.self_capped_distance(pos, cutoff, box=box)
        want = mda_dist.self_capped_distance(pos, cutoff, box=box)
        _assert_same(got, want, swap=True)
        assert got[0].dtype == np.int64 and got[1].dtype == np.float64
        assert np.all(got[0][:, 0] < got[0][:, 1])

    @pytest.mark.parametrize("box", [None, ORTHO], ids=["none", "ortho"])
    def test_min_cutoff_and_no_distances(self, box):
        pos = _points(3, 80, box)
        got = mda.self_capped_distance(pos, 3.0, min_cutoff=1.0, box=box)
        want = mda_dist.self_capped_distance(pos, 3.0, min_cutoff=1.0, box=box)
        _assert_same(got, want, swap=True)
        pairs = mda.self_capped_distance(pos, 3.0, box=box, return_distances=False)
        want = mda_dist.self_capped_distance(pos, 3.0, box=box, return_distances=False)
        assert isinstance(pairs, np.ndarray)
        assert np.array_equal(_canon(pairs, swap=True)[0], _canon(want, swap=True)[0])

    def test_ties_are_included_like_mdanalysis(self):
        g = np.arange(4.0)
        pos = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
        for box in (None, [4.0, 4.0, 4.0, 90, 90, 90]):
            got = mda.self_capped_distance(pos, 1.0, box=box)
            want = mda_dist.self_capped_distance(pos, 1.0, box=box)
            _assert_same(got, want, swap=True)

    def test_cutoff_beyond_half_the_box_uses_minimum_image(self):
        # MDAnalysis's brute force path gives minimum-image pairs for any cutoff
        pos = _points(4, 40, ORTHO)
        box = [8.0, 8.0, 8.0, 90, 90, 90]
        got = mda.self_capped_distance(pos, 5.0, box=box)
        want = mda_dist.self_capped_distance(pos, 5.0, box=box, method="bruteforce")
        _assert_same(got, want, swap=True)

    @pytest.mark.parametrize("n", [0, 1])
    def test_empty_and_single(self, n):
        pairs, d = mda.self_capped_distance(np.zeros((n, 3)), 1.0)
        assert pairs.shape == (0, 2) and pairs.dtype == np.int64
        assert d.shape == (0,) and d.dtype == np.float64

    def test_float32_rounding_like_mdanalysis(self):
        # 0.1 is not a float32: MDAnalysis measures float32(0.1) - 0
        pos = np.array([[0.0, 0, 0], [0.1, 0, 0]])
        _, d = mda.self_capped_distance(pos, 1.0)
        assert d[0] == float(np.float32(0.1))

    def test_atomgroup(self):
        MDAnalysis = pytest.importorskip("MDAnalysis")
        u = MDAnalysis.Universe.empty(50, trajectory=True)
        u.atoms.positions = _points(5, 50, ORTHO)
        u.dimensions = ORTHO
        got = mda.self_capped_distance(u.atoms, 2.5, box=u.dimensions)
        want = mda_dist.self_capped_distance(u.atoms, 2.5, box=u.dimensions)
        _assert_same(got, want, swap=True)

    @pytest.mark.parametrize("kw, exc, match", [
        (dict(box=[10, 10, 10]), ValueError,
         r"box must be None or of the form \[lx, ly, lz, alpha, beta, gamma\]"),
        (dict(box=np.eye(3)), ValueError, r"box must be None or of the form"),
        (dict(box=[0, 10, 10, 90, 90, 90]), ValueError, r"box lengths must be positive"),
        (dict(max_cutoff=-1.0), ValueError, r"max_cutoff must be non-negative"),
        (dict(min_cutoff=np.nan), ValueError, r"min_cutoff must be finite"),
        (dict(reference=np.zeros((4, 2))), ValueError, r"reference must have shape \(n, 3\)"),
        (dict(reference=[[0, 0, np.inf]]), ValueError, r"reference must be finite"),
    ])
    def test_bad_input(self, kw, exc, match):
        args = dict(reference=np.zeros((4, 3)), max_cutoff=1.0)
        args.update(kw)
        with pytest.raises(exc, match=match):
            mda.self_capped_distance(**args)


class TestCappedDistance:
    @pytest.mark.parametrize("box", [None, ORTHO, TRICLINIC], ids=["none", "ortho", "tric"])
    @pytest.mark.parametrize("sizes", [(5, 60), (60, 5), (120, 150)])
    # open boundaries: MDAnalysis shifts by lmin - 0.1 * cutoff, exact for these
    @pytest.mark.parametrize("cutoff", [1.25, 2.5])
    def test_matches_mdanalysis(self, box, sizes, cutoff):
        ref = _points(10 + sizes[0], sizes[0], box)
        conf = _points(20 + sizes[1], sizes[1], box)
        conf[:3] = ref[:3]  # identical points across the two sets count (d = 0)
        got = mda.capped_distance(ref, conf, cutoff, box=box)
        want = mda_dist.capped_distance(ref, conf, cutoff, box=box)
        _assert_same(got, want, swap=False)

    def test_min_cutoff_single_coordinate_and_no_distances(self):
        ref = np.array([8.0, 8.0, 8.0])  # a single (3,) coordinate, as MDAnalysis allows
        conf = _points(7, 200, ORTHO)
        got = mda.capped_distance(ref, conf, 4.0, min_cutoff=2.0, box=ORTHO)
        want = mda_dist.capped_distance(ref, conf, 4.0, min_cutoff=2.0, box=ORTHO)
        _assert_same(got, want, swap=False)
        pairs = mda.capped_distance(ref, conf, 4.0, box=ORTHO, return_distances=False)
        assert pairs.shape[1] == 2 and np.all(pairs[:, 0] == 0)

    @pytest.mark.parametrize("sizes", [(10, 40), (40, 10)])
    def test_cutoff_beyond_half_the_box_uses_minimum_image(self, sizes):
        box = [8.0, 8.0, 8.0, 90, 90, 90]
        ref, conf = _points(30, sizes[0], ORTHO), _points(31, sizes[1], ORTHO)
        got = mda.capped_distance(ref, conf, 5.0, box=box)
        want = mda_dist.capped_distance(ref, conf, 5.0, box=box, method="bruteforce")
        _assert_same(got, want, swap=False)

    def test_empty(self):
        pairs, d = mda.capped_distance(np.zeros((0, 3)), np.zeros((4, 3)), 1.0)
        assert pairs.shape == (0, 2) and d.shape == (0,)

    def test_bad_configuration(self):
        with pytest.raises(ValueError, match=r"configuration must have shape \(n, 3\)"):
            mda.capped_distance(np.zeros((2, 3)), np.zeros((2, 4)), 1.0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 120),
       cutoff=st.sampled_from([0.25, 1.0, 2.0, 3.75]),
       box=st.sampled_from([None, ORTHO, TRICLINIC]))
def test_self_capped_distance_property(seed, n, cutoff, box):
    pos = _points(seed, n, box)
    got = mda.self_capped_distance(pos, cutoff, box=box)
    want = mda_dist.self_capped_distance(pos, cutoff, box=box)
    _assert_same(got, want, swap=True)


@pytest.mark.parametrize("box", [None, ORTHO], ids=["none", "ortho"])
def test_neighbor_pairs_is_self_capped_distance(box):
    # the SPEC's promise for the float64 API, on float32-exact inputs
    from granularsap import neighbor_pairs

    pos = _points(40, 300, box)
    got = neighbor_pairs(pos, 2.25, box=box)
    want = mda_dist.self_capped_distance(pos, max_cutoff=2.25, box=box)
    _assert_same(got, want, swap=True)


def test_contacts_is_reexported():
    from granularsap import mda_analysis

    assert mda.Contacts is mda_analysis.Contacts
    with pytest.raises(AttributeError, match="has no attribute 'nope'"):
        mda.nope  # noqa: B018
