"""The MDAnalysis drop-ins decide pairs at the cutoff as MDAnalysis does.

Half-integer grids make many pairs lie exactly at the cutoff; MDAnalysis's
methods disagree with each other there (each wraps and takes the minimum image
with its own float32 arithmetic), so the drop-ins must reproduce the method
MDAnalysis would run, including positions outside the cell and triclinic boxes.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("MDAnalysis")
from MDAnalysis.lib.distances import capped_distance, self_capped_distance  # noqa: E402

from granularsap import mda as gmda  # noqa: E402

BOXES = [None, [8, 10, 8, 90, 90, 90], [12.5, 12.5, 12.5, 90, 90, 90],
         [10, 10, 10, 70, 80, 100], [12.5, 15.625, 12.5, 90, 90, 60]]


def _set(pairs, symmetric):
    pairs = np.asarray(pairs).reshape(-1, 2)
    if symmetric:
        pairs = np.sort(pairs, axis=1)
    return set(map(tuple, pairs.tolist()))


@pytest.mark.parametrize("method", [None, "bruteforce", "nsgrid"])
@pytest.mark.parametrize("box", BOXES)
@pytest.mark.parametrize("seed", range(3))
def test_ties_like_mdanalysis(method, box, seed):
    rng = np.random.default_rng(seed)
    n = (40, 150, 260)[seed]
    pos = rng.integers(-8, 40, (n, 3)) * 0.5
    conf = rng.integers(-8, 40, (60, 3)) * 0.5
    cutoff = (1.5, 2.0, 2.5)[seed]
    want, dwant = self_capped_distance(pos, cutoff, box=box, method=method)
    got, dgot = gmda.self_capped_distance(pos, cutoff, box=box, method=method)
    assert _set(got, True) == _set(want, True)
    order_w = np.lexsort(np.sort(want, axis=1).T[::-1])
    order_g = np.lexsort(np.sort(got, axis=1).T[::-1])
    np.testing.assert_allclose(dgot[order_g], dwant[order_w], rtol=1e-12)
    want = capped_distance(pos, conf, cutoff, box=box, method=method, return_distances=False)
    got = gmda.capped_distance(pos, conf, cutoff, box=box, method=method,
                               return_distances=False)
    assert _set(got, False) == _set(want, False)


def test_pkdtree_distances_stay_within_max_cutoff():
    # MDAnalysis's pkdtree path decides inside scipy, then computes distances with
    # calc_bonds; a pair at a float32 tie (a lattice across a triclinic box's
    # corner) or at calc_bonds' image of a skewed cell came back with a distance
    # beyond max_cutoff: it is left out, as MDAnalysis's own answer leaves it
    g = np.stack(np.meshgrid(*[np.arange(6)] * 3, indexing="ij"), -1).reshape(-1, 3)
    x = g.astype(np.float32) + np.float32(97.0)
    box = np.array([100, 100, 100, 70, 80, 100], np.float32)
    want_p, want_d = self_capped_distance(x, 2.0, box=box)  # pkdtree (method=None)
    got_p, got_d = gmda.self_capped_distance(x, 2.0, box=box)
    assert got_d.max() <= 2.0
    order = np.lexsort((got_p[:, 1], got_p[:, 0]))
    w = np.lexsort((want_p[:, 1], want_p[:, 0]))
    np.testing.assert_array_equal(got_p[order], want_p[w])
    np.testing.assert_array_equal(got_d[order], want_d[w])
    skewed = np.array([15, 9, 7, 50, 115, 80.0], np.float32)
    ref = np.array([[4.3618503, 4.0551124, 7.374729]], np.float32)
    conf = np.array([[3.623267, 5.077148, 0.7140875]], np.float32)
    assert len(capped_distance(ref, conf, 6.0, box=skewed, method="pkdtree")[0]) == 0
    assert len(gmda.capped_distance(ref, conf, 6.0, box=skewed, method="pkdtree")[0]) == 0
