"""NeighborSearch and ContactSearch over trajectories: every frame equals a fresh
one-shot call bit for bit and the brute-force oracle."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granularsap import ContactSearch, NeighborSearch, neighbor_pairs, sphere_contacts
from granularsap.periodic import as_cell

from .oracles import brute_image_pairs

BOXES = {
    "open": (None, None),
    "ortho": ([9.0, 10.0, 11.0, 90.0, 90.0, 90.0], None),
    "triclinic": ([9.0, 10.0, 11.0, 75.0, 80.0, 105.0], None),
    "mixed": ([[9.0, 0.0, 0.0], [1.0, 10.0, 0.0], [0.0, 0.0, 11.0]], (True, False, True)),
}


def _canon(pairs, dist=None):
    pairs = np.asarray(pairs).reshape(-1, 2)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order], (None if dist is None else np.asarray(dist)[order])


def _oracle(pos, box, pbc, cutoff=0.0, radii=None, labels=None):
    cell = None if box is None else as_cell(box, pbc=(True,) * 3 if pbc is None else pbc)
    pb = (True, True, True) if pbc is None else pbc
    pairs, dist = brute_image_pairs(pos, cutoff, cell, pbc=pb, radii=radii)
    if labels is not None and len(pairs):
        keep = labels[pairs[:, 0]] != labels[pairs[:, 1]]
        pairs, dist = pairs[keep], dist[keep]
    return pairs, dist


def _frames(seed, n, n_frames=8, box_len=10.0):
    """Positions moving by small and by large steps; some frames wrapped by the 'MD code'."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, box_len + 1.0, (n, 3))
    out = []
    for f in range(n_frames):
        x = x + rng.normal(0.0, 0.3 if f % 3 == 2 else 0.02, x.shape)
        y = x - np.floor(x / box_len) * box_len if f % 4 == 1 else x
        out.append(y.copy())
    return out


class TestTrajectory:
    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("margin", [0.0, 0.5])
    @pytest.mark.parametrize("n_threads", [1, 2])
    @pytest.mark.parametrize("path", ["auto", "columns", "sweep"])
    def test_neighbor_search_equals_fresh_and_oracle(self, box, margin, n_threads, path):
        box, pbc = BOXES[box]
        search = NeighborSearch(2.1, rebuild_margin=margin, n_threads=n_threads, path=path)
        rebuilt = []
        for pos in _frames(1, 120):
            got = _canon(*search.update(pos, box, pbc=pbc))
            rebuilt.append(search.stats["rebuilt"])
            fresh = _canon(*neighbor_pairs(pos, 2.1, box=box, pbc=pbc, n_threads=1))
            assert np.array_equal(got[0], fresh[0])
            assert np.array_equal(got[1], fresh[1])  # bit for bit
            want = _oracle(pos, box, pbc, cutoff=2.1)
            assert np.array_equal(got[0], want[0])
            np.testing.assert_allclose(got[1], want[1], rtol=1e-12)
        if margin:
            assert True in rebuilt[1:] and False in rebuilt, rebuilt
        else:
            assert all(rebuilt)

    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("clumps", [False, True])
    @pytest.mark.parametrize("path", ["auto", "columns", "sweep"])
    def test_contact_search_polydisperse_and_clumps(self, box, clumps, path):
        box, pbc = BOXES[box]
        rng = np.random.default_rng(5)
        radii = rng.uniform(0.2, 1.0, 150)
        labels = rng.integers(0, 60, 150) if clumps else None
        search = ContactSearch(skin=0.05, rebuild_margin=0.4, quantities="Pd", path=path)
        for pos in _frames(2, 150):
            got = _canon(*search.update(pos, radii, box, pbc=pbc, clump_ids=labels))
            fresh = ContactSearch(skin=0.05, quantities="Pd").update(
                pos, radii, box, pbc=pbc, clump_ids=labels)
            fresh = _canon(*fresh)
            assert np.array_equal(got[0], fresh[0]) and np.array_equal(got[1], fresh[1])
            want = _oracle(pos, box, pbc, cutoff=0.05, radii=radii, labels=labels)
            assert np.array_equal(got[0], want[0])
            np.testing.assert_allclose(got[1], want[1], rtol=1e-12)

    def test_cell_scaled_every_frame_npt(self):
        search = NeighborSearch(2.0, rebuild_margin=0.3)
        rng = np.random.default_rng(3)
        s = rng.random((200, 3))
        for f in range(5):
            length = 10.0 * (1.0 + 0.01 * f)
            pos = s * length
            got = _canon(*search.update(pos, [length] * 3 + [90.0] * 3))
            assert search.stats["rebuilt"]
            assert "cell" in search.stats["reason"] or f == 0
            want = _oracle(pos, [length] * 3 + [90.0] * 3, None, cutoff=2.0)
            assert np.array_equal(got[0], want[0])

    def test_particle_count_changes_to_and_from_zero(self):
        search = ContactSearch(rebuild_margin=0.2, quantities="Pd")
        rng = np.random.default_rng(4)
        box = [8.0, 8.0, 8.0, 90, 90, 90]
        for n in [40, 70, 0, 0, 25, 25]:
            pos = rng.uniform(0, 8, (n, 3))
            pairs, dist = search.update(pos, 0.6, box)
            assert pairs.shape == (len(dist), 2) and pairs.dtype == np.int64
            want = _oracle(pos, box, None, radii=np.full(n, 0.6))
            assert np.array_equal(_canon(pairs)[0], want[0])
            if n == 0:
                assert pairs.shape == (0, 2) and dist.shape == (0,)

    def test_threads_do_not_change_the_answer(self):
        rng = np.random.default_rng(6)
        pos = rng.uniform(0, 30, (30000, 3))  # above the single-thread threshold
        one = NeighborSearch(1.5, n_threads=1).update(pos, [30] * 3 + [90] * 3, copy=True)
        two = NeighborSearch(1.5, n_threads=2).update(pos, [30] * 3 + [90] * 3, copy=True)
        assert np.array_equal(one[0], two[0]) and np.array_equal(one[1], two[1])


class TestOutputs:
    def test_quantities_are_consistent(self):
        rng = np.random.default_rng(7)
        pos = rng.uniform(-5, 15, (150, 3))
        box = [10.0, 11.0, 12.0, 80.0, 95.0, 110.0]
        cell = as_cell(box)
        i, j, d, vec, shift, pairs = NeighborSearch(3.0, quantities="ijdDSP").update(pos, box)
        assert np.array_equal(pairs[:, 0], i) and np.array_equal(pairs[:, 1], j)
        assert np.all(i < j) and shift.dtype == np.int64
        np.testing.assert_allclose(pos[j] - pos[i] + shift @ cell, vec, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(vec, axis=1), d, rtol=1e-12)

    def test_csr_layout_holds_the_same_half_list(self):
        rng = np.random.default_rng(8)
        pos = rng.uniform(0, 10, (300, 3))
        offsets, nbrs, dist = NeighborSearch(1.8, layout="csr").update(pos, [10] * 3 + [90] * 3)
        pairs, d = NeighborSearch(1.8).update(pos, [10] * 3 + [90] * 3)
        rows = np.repeat(np.arange(300), np.diff(offsets))
        assert offsets[0] == 0 and offsets[-1] == len(pairs)
        assert np.all(rows < nbrs)
        got = _canon(np.stack([rows, nbrs], 1), dist)
        want = _canon(pairs, d)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])

    def test_views_are_reused_and_copies_are_not(self):
        rng = np.random.default_rng(9)
        search = NeighborSearch(1.5)
        p1, d1 = search.update(rng.uniform(0, 10, (200, 3)))
        kept = p1.copy()
        c1, _ = search.update(rng.uniform(0, 10, (200, 3)), copy=True)
        p2, _ = search.update(rng.uniform(0, 10, (200, 3)))
        assert np.shares_memory(p1, p2)
        assert not np.shares_memory(c1, p2)
        assert kept.shape[1] == 2

    def test_all_images_in_a_small_cell(self):
        rng = np.random.default_rng(10)
        pos = rng.uniform(0, 3, (12, 3))
        box = [3.0, 3.5, 4.0, 90, 90, 90]
        cell = as_cell(box)
        i, j, shift, d = NeighborSearch(5.0, periodic_images="all", include_cutoff=False,
                                        quantities="ijSd").update(pos, box)
        # brute force over every image: half list of (i, j, S), self images included once
        want = set()
        rng_s = range(-3, 4)
        for a in range(12):
            for b in range(a, 12):
                for s in ((x, y, z) for x in rng_s for y in rng_s for z in rng_s):
                    if a == b and s <= (0, 0, 0):
                        continue
                    if np.linalg.norm(pos[b] - pos[a] + np.array(s) @ cell) < 5.0:
                        want.add((a, b, s))
        got = set()
        for a, b, s in zip(i.tolist(), j.tolist(), map(tuple, shift.tolist()), strict=True):
            if a == b and s < (0, 0, 0):
                s = tuple(-v for v in s)
            got.add((a, b, s))
        assert got == want


class TestExtremeMagnitudesAndBadInput:
    @pytest.mark.parametrize("scale", [1e154, 1e200, 1e300, 1e-200, 1e-300])
    def test_huge_and_tiny_coordinates_decide_every_pair(self, scale):
        rng = np.random.default_rng(11)
        unit = rng.uniform(0, 10, (200, 3))
        want = _oracle(unit, None, None, cutoff=2.0)
        pairs, dist = neighbor_pairs(unit * scale, 2.0 * scale)
        got = _canon(pairs, dist)
        assert np.array_equal(got[0], want[0])
        np.testing.assert_allclose(got[1] / scale, want[1], rtol=1e-12)
        sp = sphere_contacts(unit * scale, 1.0 * scale)
        assert np.array_equal(_canon(sp)[0], want[0])

    def test_far_outside_a_periodic_cell(self):
        # 1e13 cell lengths out: still 2 fractional digits, wrapped in O(1)
        pos = np.array([[1e14, 0.0, 0.0], [1e14 + 0.5, 0.0, 0.0], [3.0, 3.0, 3.0]])
        pairs, d = neighbor_pairs(pos, 1.0, box=[10, 10, 10, 90, 90, 90])
        assert pairs.tolist() == [[0, 1]] and d.tolist() == [0.5]
        # beyond 2**52 cell lengths nothing of the position survives wrapping
        for far in (1e20, 1e300):
            shown = re.escape(f"positions row 0 ([{far!r}, 0.0, 0.0])")
            with pytest.raises(ValueError, match=shown + r" .* outside the cell"):
                neighbor_pairs(np.array([[far, 0, 0], [0, 0, 0]]), 1.0,
                               box=[10, 10, 10, 90, 90, 90])

    @pytest.mark.parametrize("kwargs, exc, match", [
        (dict(quantities="ijx"), ValueError, r"unknown quantity 'x' in quantities 'ijx'"),
        (dict(quantities=3), TypeError, r"quantities must be a non-empty string"),
        (dict(layout="dense"), ValueError, r"layout must be one of 'pairs', 'csr'"),
        (dict(periodic_images="some"), ValueError, r"periodic_images must be 'minimum'"),
        (dict(include_cutoff=1), TypeError, r"include_cutoff must be True or False"),
        (dict(rebuild_margin=-1.0), ValueError, r"rebuild_margin must be non-negative"),
    ])
    def test_bad_options(self, kwargs, exc, match):
        with pytest.raises(exc, match=match):
            NeighborSearch(1.0, **kwargs)

    def test_range_beyond_half_the_cell(self):
        with pytest.raises(ValueError, match=r"cutoff 6 exceeds half the smallest perpendicular"):
            NeighborSearch(6.0).update(np.zeros((3, 3)), [10, 10, 10, 90, 90, 90])

    def test_pbc_without_a_box(self):
        with pytest.raises(ValueError, match=r"pbc asks for periodic axes but box is None"):
            NeighborSearch(1.0).update(np.zeros((3, 3)), None, pbc=True)


coords = st.lists(st.tuples(*[st.integers(0, 32)] * 3), min_size=0, max_size=30)


@settings(max_examples=40, deadline=None)
@given(pts=coords, cut=st.integers(0, 12), margin=st.sampled_from([0.0, 0.25, 1.0]),
       pbc=st.tuples(st.booleans(), st.booleans(), st.booleans()),
       moves=st.lists(st.tuples(*[st.integers(-2, 2)] * 3), min_size=1, max_size=3))
def test_ties_on_a_dyadic_grid_survive_verlet_frames(pts, cut, margin, pbc, moves):
    # quarter-integer coordinates and cutoff: distances at the cutoff are exact ties
    pos = np.asarray(pts, dtype=float).reshape(-1, 3) / 4.0
    cutoff = cut / 4.0
    box = [8.0, 8.0, 8.0, 90, 90, 90]
    search = NeighborSearch(cutoff, rebuild_margin=margin)
    for mv in moves:
        pos = pos + np.asarray(mv, dtype=float) / 16.0
        got = _canon(*search.update(pos, box, pbc=pbc))
        want = _oracle(pos, box if any(pbc) else None, pbc if any(pbc) else None,
                       cutoff=cutoff)
        assert np.array_equal(got[0], want[0])
        np.testing.assert_allclose(got[1], want[1], rtol=1e-12)


def test_kept_search_whose_record_regions_grow_between_frames():
    # a dense blob of a new size every frame: some chunk of the column sweep
    # outgrows the record region the last frame sized for it, which moves the
    # regions after it; a kept search must answer every frame as a fresh one
    rng = np.random.default_rng(0)
    length = 40.0
    box = [length] * 3 + [90.0] * 3
    kept = NeighborSearch(2.5, quantities="P", n_threads=1)
    for _ in range(5):
        x = rng.uniform(0.0, length, (25_000, 3))
        k = int(rng.integers(0, 4000))
        x[:k] = (rng.uniform(0.0, length, 3) + rng.normal(0.0, rng.uniform(1.5, 4.0), (k, 3))) \
            % length
        got = kept.update(x, box, copy=True)
        want = NeighborSearch(2.5, quantities="P", n_threads=1).update(x, box)
        assert np.array_equal(np.sort(got[:, 0] * len(x) + got[:, 1]),
                              np.sort(want[:, 0] * len(x) + want[:, 1]))
