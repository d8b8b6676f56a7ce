"""The MDAnalysis drop-in at RDF-sized cutoffs: the same pairs and distances as MDAnalysis.

Cutoffs around and beyond half the cell take every image within range from the
engine, keep one per pair and decide it with MDAnalysis's arithmetic in one
compiled pass; a group against itself is decided once per unordered pair and
mirrored.  Half-integer grids put many pairs exactly at the cutoff, where only
the same float32 arithmetic gives the same answer.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("MDAnalysis")
from MDAnalysis.lib import distances as mda_dist  # noqa: E402
from MDAnalysis.lib.mdamath import triclinic_vectors  # noqa: E402

from granularsap import _mda_arith  # noqa: E402
from granularsap import mda as gmda  # noqa: E402

from .test_mda_dropin import _assert_same, _mic_oracle  # noqa: E402

# widths about 12-14: cutoffs 5 (under half), 7.5 and 9 (beyond half, under two
# images per pair on average: the engine's every-image path) and 16 (brute force)
BOXES = {"ortho": [12.0, 13.0, 14.0, 90.0, 90.0, 90.0],
         "tric": [13.4, 13.9, 13.8, 98.5, 83.0, 76.0],
         "tric60": [12.5, 15.625, 12.5, 90.0, 90.0, 60.0]}
CUTOFFS = [5.0, 7.5, 9.0, 16.0]


def _points(seed, n, lattice):
    rng = np.random.default_rng(seed)
    if lattice:  # half-integer grid: pairs at exactly 5, 7.5, 9 and 16
        return rng.integers(-4, 30, (n, 3)) * 0.5
    return rng.uniform(-2.0, 16.0, (n, 3))


class TestSameGroupTwice:
    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("cutoff", CUTOFFS)
    @pytest.mark.parametrize("lattice", [False, True], ids=["uniform", "lattice"])
    def test_capped_distance_x_x_matches_mdanalysis(self, box, cutoff, lattice):
        x = _points(1, 300, lattice)
        got = gmda.capped_distance(x, x.copy(), cutoff, box=BOXES[box])
        want = mda_dist.capped_distance(x, x, cutoff, box=BOXES[box])
        _assert_same(got, want, swap=False)

    # (pkdtree decides inside scipy, in float64: a documented difference at ties)
    @pytest.mark.parametrize("method", ["bruteforce", "nsgrid"])
    def test_each_method_and_min_cutoff(self, method):
        x = _points(2, 200, True)
        box = BOXES["tric"]
        for cutoff in (4.5, 6.0):
            got = gmda.capped_distance(x, x, cutoff, min_cutoff=1.0, box=box, method=method)
            want = mda_dist.capped_distance(x, x, cutoff, min_cutoff=1.0, box=box,
                                            method=method)
            _assert_same(got, want, swap=False)

    def test_open_boundaries(self):
        x = _points(3, 250, True)
        for method in (None, "bruteforce", "nsgrid"):
            got = gmda.capped_distance(x, x, 6.0, method=method)
            want = mda_dist.capped_distance(x, x, 6.0, method=method)
            _assert_same(got, want, swap=False)

    def test_without_mdanalysis_arithmetic_matches_the_float64_oracle(self, monkeypatch):
        monkeypatch.setattr(gmda, "_mda_box32", lambda box: None)
        x = _points(4, 150, False).astype(np.float32).astype(np.float64)
        cell = triclinic_vectors(np.asarray(BOXES["tric"], np.float32)).astype(np.float64)
        for cutoff in (5.0, 7.5, 9.0):
            got = gmda.capped_distance(x, x, cutoff, box=BOXES["tric"])
            _assert_same(got, _mic_oracle(x, x, cutoff, cell), swap=False)


class TestBeyondHalfTheCellThroughTheEngine:
    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("cutoff", [7.5, 9.0])
    @pytest.mark.parametrize("lattice", [False, True], ids=["uniform", "lattice"])
    def test_cross_and_self_match_mdanalysis(self, box, cutoff, lattice):
        ref, conf = _points(5, 220, lattice), _points(6, 170, lattice)
        assert gmda._beyond_half_cell(gmda._box(BOXES[box]), cutoff)
        assert not gmda._many_images(gmda._box(BOXES[box]), cutoff)
        got = gmda.capped_distance(ref, conf, cutoff, box=BOXES[box])
        want = mda_dist.capped_distance(ref, conf, cutoff, box=BOXES[box])
        _assert_same(got, want, swap=False)
        got = gmda.self_capped_distance(ref, cutoff, box=BOXES[box])
        want = mda_dist.self_capped_distance(ref, cutoff, box=BOXES[box], method="bruteforce")
        _assert_same(got, want, swap=True)

    def test_float64_path_matches_the_oracle(self, monkeypatch):
        monkeypatch.setattr(gmda, "_mda_box32", lambda box: None)
        ref = _points(7, 120, False).astype(np.float32).astype(np.float64)
        conf = _points(8, 90, False).astype(np.float32).astype(np.float64)
        for box in BOXES.values():
            cell = triclinic_vectors(np.asarray(box, np.float32)).astype(np.float64)
            for cutoff in (7.5, 9.0):
                _assert_same(gmda.capped_distance(ref, conf, cutoff, box=box),
                             _mic_oracle(ref, conf, cutoff, cell), swap=False)
                wp, wd = _mic_oracle(ref, ref, cutoff, cell)
                upper = wp[:, 0] < wp[:, 1]
                _assert_same(gmda.self_capped_distance(ref, cutoff, box=box),
                             (wp[upper], wd[upper]), swap=True)

    def test_thread_count_changes_nothing(self):
        x, y = _points(9, 400, False), _points(10, 300, False)
        box = BOXES["tric"]
        for call in (lambda t: gmda.capped_distance(x, y, 8.0, box=box, n_threads=t),
                     lambda t: gmda.capped_distance(x, x, 8.0, box=box, n_threads=t),
                     lambda t: gmda.self_capped_distance(x, 8.0, box=box, n_threads=t)):
            one, two = call(1), call(2)
            assert np.array_equal(one[0], two[0]) and np.array_equal(one[1], two[1])

    def test_results_are_not_views_of_a_kept_search(self):
        x = _points(11, 300, False)
        box = BOXES["ortho"]
        first = gmda.self_capped_distance(x, 5.0, box=box)
        kept = (first[0].copy(), first[1].copy())
        gmda.self_capped_distance(x + 0.7, 5.0, box=box)
        assert np.array_equal(first[0], kept[0]) and np.array_equal(first[1], kept[1])


class TestNearestImages:
    @pytest.mark.parametrize("any_image", [False, True])
    def test_one_row_per_pair_with_the_nearest_distance(self, any_image):
        rng = np.random.default_rng(0)
        n, m, k = 30, 20, 2000
        pairs = np.stack([rng.integers(0, n, k), rng.integers(0, m, k) + 50], axis=1)
        d = rng.uniform(0, 10, k)
        a, b, dd = _mda_arith.nearest_images(pairs, d, n, m, shift=50, any_image=any_image)
        keys = pairs[:, 0] * m + pairs[:, 1] - 50
        assert sorted((a * m + b).tolist()) == sorted(set(keys.tolist()))
        for i, j, dist in zip(a, b, dd, strict=True):
            mine = d[keys == i * m + j]
            assert dist == (mine[0] if any_image else mine.min())

    def test_diagonal_dropped(self):
        pairs = np.array([[0, 0], [0, 1], [1, 1], [0, 1]])
        a, b, d = _mda_arith.nearest_images(pairs, np.array([1.0, 2.0, 3.0, 1.5]), 2, 2,
                                            drop_diagonal=True)
        assert a.tolist() == [0] and b.tolist() == [1] and d.tolist() == [1.5]


class TestDecisionKernel:
    """The compiled decision against a literal NumPy transcription of MDAnalysis's
    27-image search (calc_distances.h), on lattice points at the cutoff."""

    @staticmethod
    def _numpy_27(dx, box9):
        b = box9.astype(np.float64)
        best = np.full(len(dx), np.finfo(np.float32).max)
        out = np.zeros_like(dx)
        for ix in (-1, 0, 1):
            rx = dx[:, 0] + b[0] * ix
            for iy in (-1, 0, 1):
                ry0 = rx + b[3] * iy
                ry1 = dx[:, 1] + b[4] * iy
                for iz in (-1, 0, 1):
                    rz0 = ry0 + b[6] * iz
                    rz1 = ry1 + b[7] * iz
                    rz2 = dx[:, 2] + b[8] * iz
                    dsq = rz0 * rz0 + rz1 * rz1 + rz2 * rz2
                    take = dsq < best
                    best = np.where(take, dsq, best)
                    out[take] = np.stack([rz0, rz1, rz2], axis=1)[take]
        return (out[:, 0] * out[:, 0]) + (out[:, 1] * out[:, 1]) + (out[:, 2] * out[:, 2])

    @pytest.mark.parametrize("box", ["tric", "tric60"])
    def test_triclinic_distances_bit_for_bit(self, box):
        from MDAnalysis.lib.distances import apply_PBC

        box32 = np.asarray(BOXES[box], np.float32)
        x32 = _points(12, 200, True).astype(np.float32)
        a, b = np.triu_indices(len(x32), 1)
        cutoff = 7.0
        d, keep = _mda_arith.decide(x32, x32, a, b, box32, cutoff, "bruteforce")
        w = apply_PBC(x32, box32).astype(np.float32)
        want2 = self._numpy_27((w[b] - w[a]).astype(np.float64),
                               triclinic_vectors(box32).astype(np.float32).ravel())
        near = want2 <= cutoff * cutoff * 1.001
        assert np.array_equal(d[near], np.sqrt(want2[near]))
        assert np.array_equal(keep, np.sqrt(want2) <= cutoff)
        assert np.all(d[~near] > cutoff)


class TestBenchWorkload:
    def test_mda_capped_runs_and_checks_the_pairs(self, tmp_path, capsys):
        import json
        import os

        from granularsap.cli import main

        out = tmp_path / "mda.json"
        data = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "data")
        assert main(["bench", "mda-capped", "--sizes", "3000", "--repeats", "1",
                     "--data-dir", data, "--json", str(out)]) == 0
        rows = json.loads(out.read_text())["rows"]
        assert [r["cutoff"] for r in rows] == [1.5, 5.0, 8.0] * 2
        assert all(r["same"] and r["pairs"] == r["granularsap_pairs"] for r in rows)
        assert rows[2]["pairs"] == 3374264  # data/lj.dump at cutoff 8 (issue 20)
        assert "same pairs" in capsys.readouterr().out
