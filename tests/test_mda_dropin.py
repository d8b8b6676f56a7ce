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


def _mic_oracle(ref, conf, cutoff, cell):
    """Float64 brute force: cross pairs with minimum-image distance <= cutoff,
    the images enumerated explicitly (a cell's neighbours two deep)."""
    inv = np.linalg.inv(cell)
    fr = ref @ inv
    fc = conf @ inv
    fr -= np.floor(fr)
    fc -= np.floor(fc)
    r = fr @ cell
    c = fc @ cell
    g = np.arange(-2, 3)
    shifts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) @ cell
    dx = c[None, :, None, :] - r[:, None, None, :] + shifts[None, None, :, :]
    d = np.sqrt((dx * dx).sum(axis=3)).min(axis=2)
    i, j = np.nonzero(d <= cutoff)
    return np.stack([i, j], axis=1), d[i, j]


class TestCutoffBeyondHalfTheCell:
    """Cutoffs past half the cell width: one minimum image per pair, like
    MDAnalysis, in memory proportional to the output (issue: the image
    enumeration took 26 s and 8.9 GB for 200 x 150 points, box 10, cutoff 15)."""

    BOXES = {"ortho": [10.0, 10.0, 10.0, 90.0, 90.0, 90.0],
             "tric": [10.0, 11.0, 12.0, 70.0, 80.0, 100.0]}

    @staticmethod
    def _sets(seed=0):
        rng = np.random.default_rng(seed)
        return rng.uniform(0, 10, (200, 3)), rng.uniform(0, 10, (150, 3))

    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("cutoff", [5.5, 7.5, 15.0, 20.0])
    def test_capped_distance_matches_mdanalysis(self, box, cutoff):
        ref, conf = self._sets()
        got = mda.capped_distance(ref, conf, cutoff, box=self.BOXES[box])
        want = mda_dist.capped_distance(ref, conf, cutoff, box=self.BOXES[box])
        _assert_same(got, want, swap=False)

    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("cutoff", [5.5, 7.5, 15.0, 20.0])
    def test_self_capped_distance_matches_mdanalysis_bruteforce(self, box, cutoff):
        # MDAnalysis's own choice for 200 points, nsgrid, raises "Cutoff too large
        # for box"; its bruteforce method answers with the minimum image
        ref, _ = self._sets(1)
        for method in (None, "bruteforce"):
            got = mda.self_capped_distance(ref, cutoff, box=self.BOXES[box], method=method)
            want = mda_dist.self_capped_distance(ref, cutoff, box=self.BOXES[box],
                                                 method="bruteforce")
            _assert_same(got, want, swap=True)

    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("cutoff", [6.0, 9.0])
    def test_float64_path_matches_oracle(self, box, cutoff, monkeypatch):
        # without MDAnalysis's arithmetic (as when MDAnalysis is not installed)
        monkeypatch.setattr(mda, "_mda_box32", lambda box: None)
        ref, conf = self._sets(2)
        # the drop-in rounds coordinates to float32 as MDAnalysis does
        ref = ref[:60].astype(np.float32).astype(np.float64)
        conf = conf[:50].astype(np.float32).astype(np.float64)
        cell = mdamath.triclinic_vectors(np.asarray(self.BOXES[box], np.float32))
        cell = cell.astype(np.float64)
        want = _mic_oracle(ref, conf, cutoff, cell)
        got = mda.capped_distance(ref, conf, cutoff, box=self.BOXES[box])
        _assert_same(got, want, swap=False)
        got = mda.self_capped_distance(ref, cutoff, box=self.BOXES[box])
        wp, wd = _mic_oracle(ref, ref, cutoff, cell)
        upper = wp[:, 0] < wp[:, 1]
        _assert_same(got, (wp[upper], wd[upper]), swap=True)

    def test_thread_count_changes_nothing(self):
        ref, conf = self._sets(3)
        box = self.BOXES["tric"]
        one = mda.capped_distance(ref, conf, 8.0, box=box, n_threads=1)
        two = mda.capped_distance(ref, conf, 8.0, box=box, n_threads=2)
        assert np.array_equal(one[0], two[0]) and np.array_equal(one[1], two[1])
        one = mda.self_capped_distance(ref, 8.0, box=box, n_threads=1)
        two = mda.self_capped_distance(ref, 8.0, box=box, n_threads=2)
        assert np.array_equal(one[0], two[0]) and np.array_equal(one[1], two[1])

    @pytest.mark.parametrize("cutoff", [15.0, 20.0])
    def test_memory_is_bounded_by_the_output(self, cutoff):
        import tracemalloc

        ref, conf = self._sets(4)
        for box in self.BOXES.values():
            for call in (lambda b=box: mda.capped_distance(ref, conf, cutoff, box=b),
                         lambda b=box: mda.self_capped_distance(ref, cutoff, box=b)):
                call()  # compile outside the measurement
                tracemalloc.start()
                try:
                    pairs, dist = call()
                    peak = tracemalloc.get_traced_memory()[1]
                finally:
                    tracemalloc.stop()
                assert peak < 16 * (pairs.nbytes + dist.nbytes) + (1 << 20), peak


class TestMethodAndBackend:
    @pytest.mark.parametrize("func", ["capped_distance", "self_capped_distance"])
    def test_unknown_method_raises_keyerror_like_mdanalysis(self, func):
        ref = np.random.default_rng(0).uniform(0, 10, (20, 3))
        args = (ref, ref) if func == "capped_distance" else (ref,)
        with pytest.raises(KeyError):
            getattr(mda_dist, func)(*args, 2.0, method="bogus")
        match = (r"method must be one of 'bruteforce', 'nsgrid', 'pkdtree' \(any case\) or "
                 r"None, got 'bogus'")
        with pytest.raises(KeyError, match=match):
            getattr(mda, func)(*args, 2.0, method="bogus")
        with pytest.raises(ValueError, match=match):
            getattr(mda, func)(*args, 2.0, method="bogus")

    def test_method_is_case_insensitive_like_mdanalysis(self):
        ref = _points(0, 50, ORTHO)
        got = mda.self_capped_distance(ref, 2.0, box=ORTHO, method="BruteForce")
        want = mda_dist.self_capped_distance(ref, 2.0, box=ORTHO, method="BruteForce")
        _assert_same(got, want, swap=True)

    def test_method_not_a_string(self):
        ref = np.zeros((3, 3))
        with pytest.raises(AttributeError):
            mda_dist.self_capped_distance(ref, 1.0, method=3)
        with pytest.raises(TypeError, match=r"method must be a string or None, got int"):
            mda.self_capped_distance(ref, 1.0, method=3)
        with pytest.raises(AttributeError, match=r"method must be a string or None, got int"):
            mda.capped_distance(ref, ref, 1.0, method=3)

    @pytest.mark.parametrize("backend, exc, match", [
        ("bogus", ValueError,
         r"backend must be one of 'serial', 'OpenMP', 'distopia' \(any case\), got 'bogus'"),
        (None, TypeError, r"backend must be a string, got NoneType"),
    ])
    def test_bad_backend(self, backend, exc, match):
        ref = np.zeros((3, 3))
        with pytest.raises(exc, match=match):
            mda.self_capped_distance(ref, 1.0, backend=backend)
        with pytest.raises(exc, match=match):
            mda.capped_distance(ref, ref, 1.0, backend=backend)

    def test_openmp_backend_is_accepted(self):
        ref = _points(1, 30, ORTHO)
        got = mda.self_capped_distance(ref, 2.0, box=ORTHO, backend="OpenMP")
        want = mda_dist.self_capped_distance(ref, 2.0, box=ORTHO, backend="OpenMP")
        _assert_same(got, want, swap=True)


class TestCoordinatesBeyondFloat32:
    """MDAnalysis rounds coordinates to float32; beyond its range the error
    names the caller's argument (it used to say ``lower must be finite``)."""

    @pytest.mark.parametrize("box", [None, ORTHO], ids=["none", "ortho"])
    @pytest.mark.parametrize("scale", [1e39, 1e300])
    def test_named_error(self, box, scale):
        ok = _points(0, 20, ORTHO)
        bad = ok.copy()
        bad[3, 1] = scale
        with pytest.raises(ValueError, match=r"reference must be within float32 range "
                                             r"\(\|x\| <= 3\.403e\+38; MDAnalysis computes in "
                                             r"float32\), got 1e\+\d+ in row 3"):
            mda.self_capped_distance(bad, 1.0, box=box)
        with pytest.raises(ValueError, match=r"reference must be within float32 range"):
            mda.capped_distance(bad, ok, 1.0, box=box)
        with pytest.raises(ValueError, match=r"configuration must be within float32 range.*"
                                             r"in row 3"):
            mda.capped_distance(ok, -bad, 1.0, box=box)

    def test_largest_float32_is_accepted(self):
        pos = np.array([[3.0e38, 0, 0], [3.0e38, 1.0, 0], [0, 0, 0]])
        pairs, d = mda.self_capped_distance(pos, 1.5)
        want = mda_dist.self_capped_distance(pos, 1.5)
        _assert_same((pairs, d), want, swap=True)
