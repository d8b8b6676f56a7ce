"""Contact identity across calls and results that survive one more call.

The oracle is a Python dict of the previous call's pairs keyed by the two
particles' ids (unordered) and, with every periodic image, by the lattice
shift between their *true unwrapped* positions (oriented from the lower id
to the higher), whatever the search was given (wrapped or unwrapped).
"""

from __future__ import annotations

import doctest

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import granularsap.identity as identity_module
from granularsap import ContactSearch, NeighborSearch
from granularsap.identity import ContactIdentity, PairIdentity

L = 6.0
BOX = [L, L, L, 90, 90, 90]
CELL = np.eye(3) * L


@pytest.fixture(params=[1, 2], ids=["1thread", "2threads"])
def threads(request, monkeypatch):
    """1 or 2 numba threads, with the identity kernels chunked even on small inputs
    (so that 2 threads really split the work)."""
    monkeypatch.setattr(identity_module, "_PARALLEL_MIN", 0)
    return request.param


# --------------------------------------------------------------- oracle

def _oriented(ida, idb, shift):
    """Oracle key of a pair with shift (from a to b): ids low, high and the shift
    from the low id to the high one (a particle's own image: the lexicographically
    positive of +-shift)."""
    s = tuple(int(v) for v in shift)
    if ida == idb:
        neg = tuple(-v for v in s)
        return (ida, idb, max(s, neg))
    if ida > idb:
        return (idb, ida, tuple(-v for v in s))
    return (ida, idb, s)


def oracle_keys(pairs, ids, true_pos, given_pos, shifts, all_images):
    """One key per pair row: ids (and the true lattice shift under every image)."""
    keys = []
    for r, (a, b) in enumerate(pairs):
        ia, ib = int(ids[a]), int(ids[b])
        if not all_images:
            keys.append((min(ia, ib), max(ia, ib)))
            continue
        # the search's vector: given[b] - given[a] + S @ cell; in unwrapped terms
        vec = given_pos[b] - given_pos[a] + shifts[r] @ CELL
        true_shift = np.rint((vec - (true_pos[b] - true_pos[a])) / L).astype(np.int64)
        keys.append(_oriented(ia, ib, true_shift))
    assert len(set(keys)) == len(keys), "the oracle's keys must identify pairs"
    return keys


def oracle_rows(prev_keys, keys):
    where = {key: r for r, key in enumerate(prev_keys)}
    prev = np.array([where.get(key, -1) for key in keys], np.int64)
    ended = np.array(sorted(set(range(len(prev_keys))) - set(prev[prev >= 0].tolist())),
                     np.int64)
    return prev, ended


def clump_oracle(pairs, labels):
    la, lb = labels[pairs[:, 0]], labels[pairs[:, 1]]
    got = sorted({(int(min(a, b)), int(max(a, b))) for a, b in zip(la, lb, strict=True)})
    return got


# ----------------------------------------------------------- trajectories

def trajectory(seed, steps, n0, *, churn, reorder, wrap, drift=0.0, step=0.08):
    """Frames (true unwrapped positions, given positions, ids, radii, labels):
    Gaussian steps (plus a drift that carries particles across periodic faces),
    ``churn`` deletions and insertions per step, rows shuffled when ``reorder``,
    given positions wrapped into the cell when ``wrap``."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0, L, (n0, 3))
    ids = rng.permutation(10 * n0)[:n0] + 100
    rad = rng.uniform(0.2, 0.5, n0)
    lab = rng.integers(0, n0 // 3 + 1, n0)
    next_id = 20 * n0 + 100
    frames = []
    for _ in range(steps):
        given = pos - np.floor(pos / L) * L if wrap else pos.copy()
        frames.append((pos.copy(), given, ids.copy(), rad.copy(), lab.copy()))
        pos = pos + rng.normal(0, step, pos.shape) + drift
        if churn:
            keep = np.sort(rng.permutation(len(pos))[churn:])
            pos, ids, rad, lab = pos[keep], ids[keep], rad[keep], lab[keep]
            add = rng.uniform(0, L, (churn + rng.integers(0, 2), 3))
            pos = np.concatenate([pos, add])
            ids = np.concatenate([ids, np.arange(next_id, next_id + len(add))])
            next_id += len(add)
            rad = np.concatenate([rad, rng.uniform(0.2, 0.5, len(add))])
            lab = np.concatenate([lab, rng.integers(0, n0 // 3 + 1, len(add))])
        if reorder:
            order = rng.permutation(len(pos))
            pos, ids, rad, lab = pos[order], ids[order], rad[order], lab[order]
    return frames


def run_and_check(search, frames, *, use_ids, contacts, all_images, clumps=False):
    prev_keys = None
    prev_clumps = None
    rebuilt = set()
    for true_pos, shown, ids, rad, lab in frames:
        kw = {"ids": ids} if use_ids else {}
        if contacts:
            if clumps:
                kw["clump_ids"] = lab
            out = search.update(shown, rad, BOX, **kw)
        else:
            out = search.update(shown, BOX, **kw)
        pairs, shifts = out[0], out[-1]
        rebuilt.add(search.stats["rebuilt"])
        row_ids = ids if use_ids else np.arange(len(shown))
        keys = oracle_keys(pairs, row_ids, true_pos, shown, shifts, all_images)
        if prev_keys is None:
            want_prev = np.full(len(pairs), -1)
            want_ended = np.zeros(0, np.int64)
        else:
            want_prev, want_ended = oracle_rows(prev_keys, keys)
        assert search.previous_rows.dtype == np.int64
        np.testing.assert_array_equal(search.previous_rows, want_prev)
        np.testing.assert_array_equal(search.ended_rows, want_ended)
        if clumps:
            want = clump_oracle(pairs, lab)
            got = [tuple(r) for r in search.clump_pairs.tolist()]
            assert got == want
            if prev_clumps is None:
                assert np.all(search.previous_clump_rows == -1)
            else:
                cp, ce = oracle_rows(prev_clumps, want)
                np.testing.assert_array_equal(search.previous_clump_rows, cp)
                np.testing.assert_array_equal(search.ended_clump_rows, ce)
            prev_clumps = want
        prev_keys = keys
    return rebuilt


# ------------------------------------------------------------------ tests

class TestAgainstOracle:
    @pytest.mark.parametrize("path", ["columns", "sweep"])
    @pytest.mark.parametrize("margin", [0.0, 0.4], ids=["rebuild", "verlet"])
    @pytest.mark.parametrize("wrap", [False, True], ids=["unwrapped", "wrapped"])
    def test_neighbors_with_ids_insertions_deletions(self, threads, path, margin, wrap):
        frames = trajectory(1, 8, 150, churn=3, reorder=True, wrap=wrap, drift=0.11)
        search = NeighborSearch(1.3, rebuild_margin=margin, quantities="PdS", path=path,
                                n_threads=threads, identity=True)
        run_and_check(search, frames, use_ids=True, contacts=False, all_images=False)

    @pytest.mark.parametrize("path", ["columns", "sweep"])
    @pytest.mark.parametrize("margin", [0.0, 0.5], ids=["rebuild", "verlet"])
    def test_verlet_frames_happen(self, threads, path, margin):
        frames = trajectory(2, 10, 150, churn=0, reorder=False, wrap=True, step=0.02,
                            drift=0.07)
        search = NeighborSearch(1.3, rebuild_margin=margin, quantities="PS", path=path,
                                n_threads=threads, identity=True)
        rebuilt = run_and_check(search, frames, use_ids=True, contacts=False,
                                all_images=False)
        assert rebuilt == ({True} if margin == 0 else {True, False})

    @pytest.mark.parametrize("path", ["columns", "sweep"])
    @pytest.mark.parametrize("margin", [0.0, 0.4], ids=["rebuild", "verlet"])
    @pytest.mark.parametrize("wrap", [False, True], ids=["unwrapped", "wrapped"])
    @pytest.mark.parametrize("use_ids", [True, False], ids=["ids", "rows"])
    def test_every_image_in_a_small_cell(self, threads, path, margin, wrap, use_ids):
        # a cell 6 wide, cutoff 3.4: several images of a pair and particles' own
        # images; the drift carries particles over faces every few steps
        frames = trajectory(3, 8, 20, churn=1 if use_ids else 0, reorder=use_ids,
                            wrap=wrap, drift=0.37)
        search = NeighborSearch(3.4, rebuild_margin=margin, quantities="PdS", path=path,
                                periodic_images="all", n_threads=threads, identity=True)
        run_and_check(search, frames, use_ids=use_ids, contacts=False, all_images=True)

    def test_every_image_without_asking_for_shifts(self, threads):
        frames = trajectory(4, 6, 20, churn=1, reorder=True, wrap=True, drift=0.3)
        search = NeighborSearch(3.4, quantities="PD", periodic_images="all",
                                n_threads=threads, identity=True)
        with_s = NeighborSearch(3.4, quantities="PD", periodic_images="all",
                                n_threads=threads, identity=True)
        assert search.quantities == "PD"
        prev_keys = None
        for true_pos, shown, ids, _, _ in frames:
            pairs, vec = search.update(shown, BOX, ids=ids)
            shifts = np.rint((vec - (shown[pairs[:, 1]] - shown[pairs[:, 0]])) / L)
            keys = oracle_keys(pairs, ids, true_pos, shown, shifts.astype(np.int64), True)
            if prev_keys is not None:
                want, ended = oracle_rows(prev_keys, keys)
                np.testing.assert_array_equal(search.previous_rows, want)
                np.testing.assert_array_equal(search.ended_rows, ended)
            prev_keys = keys
            with_s.update(shown, BOX, ids=ids)

    @pytest.mark.parametrize("path", ["columns", "sweep"])
    @pytest.mark.parametrize("margin", [0.0, 0.3], ids=["rebuild", "verlet"])
    def test_contacts_with_clumps(self, threads, path, margin):
        frames = trajectory(5, 8, 200, churn=4, reorder=True, wrap=True, drift=0.09)
        search = ContactSearch(skin=0.1, rebuild_margin=margin, quantities="PS", path=path,
                               n_threads=threads, identity=True)
        run_and_check(search, frames, use_ids=True, contacts=True, all_images=False,
                      clumps=True)

    def test_rows_without_ids_and_a_changing_count(self, threads):
        # no ids: particles are rows; rows past the shorter count are new or ended
        rng = np.random.default_rng(6)
        pos = rng.uniform(0, L, (120, 3))
        search = NeighborSearch(1.4, n_threads=threads, identity=True)
        prev_keys = None
        for n in (120, 120, 100, 130, 0, 50, 50):
            pos = pos + rng.normal(0, 0.05, pos.shape)
            if len(pos) < n:
                pos = np.concatenate([pos, rng.uniform(0, L, (n - len(pos), 3))])
            x = pos[:n]
            pairs, _ = search.update(x, BOX)
            keys = oracle_keys(pairs, np.arange(n), x, x, None, False)
            if prev_keys is not None:
                want, ended = oracle_rows(prev_keys, keys)
                np.testing.assert_array_equal(search.previous_rows, want)
                np.testing.assert_array_equal(search.ended_rows, ended)
            else:
                assert np.all(search.previous_rows == -1) and len(search.ended_rows) == 0
            prev_keys = keys

    def test_open_and_mixed_cells(self, threads):
        frames = trajectory(7, 6, 150, churn=2, reorder=True, wrap=False, drift=0.1)
        for pbc in ([False] * 3, [True, False, True]):
            search = NeighborSearch(1.3, quantities="PS", n_threads=threads, identity=True,
                                    periodic_images="all")
            prev_keys = None
            for true_pos, shown, ids, _, _ in frames:
                pairs, shifts = search.update(shown, BOX, pbc=pbc, ids=ids)
                keys = oracle_keys(pairs, ids, true_pos, shown, shifts, True)
                if prev_keys is not None:
                    want, ended = oracle_rows(prev_keys, keys)
                    np.testing.assert_array_equal(search.previous_rows, want)
                    np.testing.assert_array_equal(search.ended_rows, ended)
                prev_keys = keys

    def test_sparse_ids_use_a_hash_table(self, threads):
        frames = trajectory(8, 5, 150, churn=3, reorder=True, wrap=True)
        frames = [(t, g, ids * 10**12 - 5 * 10**17, r, lab) for t, g, ids, r, lab in frames]
        search = NeighborSearch(1.3, quantities="P", n_threads=threads, identity=True)
        prev_keys = None
        for true_pos, shown, ids, _, _ in frames:
            pairs = search.update(shown, BOX, ids=ids)
            keys = oracle_keys(pairs, ids, true_pos, shown, None, False)
            if prev_keys is not None:
                want, ended = oracle_rows(prev_keys, keys)
                np.testing.assert_array_equal(search.previous_rows, want)
                np.testing.assert_array_equal(search.ended_rows, ended)
            prev_keys = keys

    def test_thread_counts_agree_on_a_large_frame(self):
        rng = np.random.default_rng(9)
        n = 20000
        box = [30.0] * 3 + [90] * 3
        x = rng.uniform(0, 30, (n, 3))
        ids = rng.permutation(n)
        runs = []
        for threads in (1, 2):
            s = NeighborSearch(1.6, quantities="P", n_threads=threads, identity=True)
            s.update(x, box, ids=ids)
            order = rng.permutation(n) if threads == 1 else runs[0][2]
            s.update(x[order] + 0.03, box, ids=ids[order])
            runs.append((s.previous_rows.copy(), s.ended_rows.copy(), order))
        assert len(runs[0][0]) > 50000  # the parallel kernels ran
        np.testing.assert_array_equal(runs[0][0], runs[1][0])
        np.testing.assert_array_equal(runs[0][1], runs[1][1])
        assert np.all(runs[0][0] >= 0)


def test_shuffled_pairs_go_through_the_sorted_second_pass(threads):
    # pairs in a new order every call defeat pass 1's cursor: nearly all are
    # matched by pass 2 (both lists sorted by code, one per thread, then merged)
    rng = np.random.default_rng(31)
    n = 3000
    universe = np.unique(np.sort(rng.integers(0, n, (20000, 2)), axis=1), axis=0)
    universe = universe[universe[:, 0] < universe[:, 1]]
    track = PairIdentity(n_threads=threads)
    prev = None
    for _ in range(4):
        pairs = universe[rng.random(len(universe)) < 0.8]
        pairs = pairs[rng.permutation(len(pairs))]
        rows = track.update(pairs, n)
        if prev is not None:
            where = {tuple(p): q for q, p in enumerate(prev.tolist())}
            want = np.array([where.get(tuple(p), -1) for p in pairs.tolist()])
            np.testing.assert_array_equal(rows, want)
            ended = np.setdiff1d(np.arange(len(prev)), want[want >= 0])
            np.testing.assert_array_equal(track.ended_rows, ended)
            assert track.matched_by == "pairs" and track._last_counts[0] > len(pairs) // 2
        prev = pairs



@pytest.mark.parametrize("threads", [1, 2])
def test_second_pass_work_growing_from_call_to_call(threads):
    # pass 2's buffers are made as large as its work, and grow with it
    rng = np.random.default_rng(21)
    n = 400
    track = PairIdentity(n_threads=threads)
    prev = None
    for churn in (0, 1, 3, 40, 10, 300, 2000, 5):
        pairs = np.unique(np.sort(rng.integers(0, n, (3000, 2)), axis=1), axis=0)
        pairs = pairs[pairs[:, 0] < pairs[:, 1]]
        if prev is not None:  # most of the previous pairs, shuffled, and churn new ones
            keep = prev[rng.random(len(prev)) > churn / (churn + len(prev))]
            pairs = np.unique(np.concatenate([keep, pairs[:churn]]), axis=0)
            pairs = pairs[rng.permutation(len(pairs))]
        rows = track.update(pairs, n)
        if prev is not None:
            where = {(int(a), int(b)): q for q, (a, b) in enumerate(prev)}
            want = [where.get((int(a), int(b)), -1) for a, b in pairs]
            assert rows.tolist() == want
            ended = sorted(set(range(len(prev))) - {q for q in want if q >= 0})
            assert track.ended_rows.tolist() == ended
        prev = pairs


class TestOneKeptList:
    """Verlet frames on the list of the last rebuild match pairs by their entry in
    it; anything else (a rebuild, ids that changed) takes the general matching."""

    def _run(self, search, frames, contacts, all_images=False, use_ids=True):
        prev_keys, seen = None, []
        for true_pos, shown, ids, rad, _ in frames:
            kw = {"ids": ids} if use_ids else {}
            out = (search.update(shown, rad, BOX, **kw) if contacts
                   else search.update(shown, BOX, **kw))
            pairs, shifts = out[0], out[-1]
            keys = oracle_keys(pairs, ids if use_ids else np.arange(len(shown)), true_pos,
                               shown, shifts, all_images)
            if prev_keys is not None:
                want, ended = oracle_rows(prev_keys, keys)
                np.testing.assert_array_equal(search.previous_rows, want)
                np.testing.assert_array_equal(search.ended_rows, ended)
            seen.append((search.stats["rebuilt"], search.stats["identity_by"]))
            prev_keys = keys
        return seen

    @pytest.mark.parametrize("path", ["columns", "sweep"])
    def test_verlet_frames_match_by_entry_right_after_a_rebuild(self, threads, path):
        frames = trajectory(11, 12, 200, churn=0, reorder=False, wrap=True, step=0.03,
                            drift=0.05)
        search = ContactSearch(skin=0.1, rebuild_margin=0.3, quantities="PdS", path=path,
                               n_threads=threads, identity=True)
        seen = self._run(search, frames, contacts=True)
        assert seen[0] == (True, "nothing")
        rebuilds = [t for t, (rebuilt, _) in enumerate(seen) if rebuilt]
        assert len(rebuilds) >= 2  # the drift forces rebuilds mid-run
        for t in range(1, len(seen)):
            rebuilt, by = seen[t]
            assert by == ("pairs" if rebuilt else "entries"), (t, seen)

    @pytest.mark.parametrize("wrap", [False, True], ids=["unwrapped", "wrapped"])
    def test_every_image_by_entry_across_faces(self, threads, wrap):
        frames = trajectory(12, 10, 20, churn=0, reorder=False, wrap=wrap, drift=0.1,
                            step=0.02)
        search = NeighborSearch(3.4, rebuild_margin=0.8, quantities="PdS",
                                periodic_images="all", n_threads=threads, identity=True)
        seen = self._run(search, frames, contacts=False, all_images=True, use_ids=False)
        assert ("entries" in {by for _, by in seen})

    def test_a_verlet_frame_after_ids_change(self, threads):
        # same rows and positions, one particle replaced (a new id at a row): no
        # rebuild, but pairs of the new id are new and its old pairs ended
        frames = trajectory(13, 6, 200, churn=0, reorder=False, wrap=True, step=0.01)
        t3, g3, ids3, r3, l3 = frames[3]
        ids3 = ids3.copy()
        ids3[[5, 17]] = [10**6, 10**6 + 1]
        frames[3] = (t3, g3, ids3, r3, l3)
        for t in range(4, 6):
            frames[t] = frames[t][:2] + (ids3,) + frames[t][3:]
        search = NeighborSearch(1.3, rebuild_margin=0.4, quantities="PS", n_threads=threads,
                                identity=True)
        seen = self._run(search, frames, contacts=False)
        assert [rebuilt for rebuilt, _ in seen[1:]] == [False] * 5
        assert [by for _, by in seen[1:]] == ["entries", "entries", "pairs", "entries",
                                             "entries"]

    def test_minimum_image_near_half_a_cell_takes_the_general_path(self, threads):
        # two images of a pair may both be in the kept list: not matched by entry
        frames = trajectory(14, 6, 30, churn=0, reorder=False, wrap=True, step=0.02)
        search = NeighborSearch(2.9, rebuild_margin=0.5, quantities="PS", n_threads=threads,
                                identity=True)
        seen = self._run(search, frames, contacts=False)
        assert {by for _, by in seen[1:]} == {"pairs"}

    def test_a_tracker_given_entries_that_do_not_rise(self):
        track = PairIdentity()
        pairs = np.array([[0, 1], [1, 2], [2, 3]])
        track.update(pairs, 4, entries=(0, np.array([1, 2, 3])))
        got = track.update(pairs[::-1], 4, entries=(0, np.array([3, 2, 1])))
        assert track.matched_by == "pairs"
        assert got.tolist() == [2, 1, 0]
        got = track.update(pairs, 4, entries=(0, np.array([1, 2, 3])))
        assert track.matched_by == "pairs"  # the previous entries did not rise
        assert got.tolist() == [2, 1, 0]
        got = track.update(pairs[1:], 4, entries=(0, np.array([2, 3])))
        assert track.matched_by == "entries"
        assert got.tolist() == [1, 2] and track.ended_rows.tolist() == [0]


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 60), moved=st.booleans())
def test_any_permutation_of_ids_keeps_every_pair(seed, n, moved):
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 4, (n, 3))
    ids = rng.choice(10**6, n, replace=False)
    search = NeighborSearch(1.2, quantities="P", identity=True)
    first = search.update(x, [4.0] * 3 + [90] * 3, ids=ids).copy()
    order = rng.permutation(n)
    y = x[order] + (rng.normal(0, 0.01, (n, 3)) if moved else 0.0)
    second = search.update(y, [4.0] * 3 + [90] * 3, ids=ids[order])
    keys1 = oracle_keys(first, ids, x, x, None, False)
    keys2 = oracle_keys(second, ids[order], y, y, None, False)
    want, ended = oracle_rows(keys1, keys2)
    np.testing.assert_array_equal(search.previous_rows, want)
    np.testing.assert_array_equal(search.ended_rows, ended)
    if not moved:
        assert np.all(search.previous_rows >= 0) and len(search.ended_rows) == 0


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k1=st.integers(0, 40), k2=st.integers(0, 40),
       width=st.integers(1, 3))
def test_contact_identity_matches_a_dict(seed, k1, k2, width):
    rng = np.random.default_rng(seed)
    pool = np.unique(rng.integers(-3, 4, (90, width)), axis=0)
    a = pool[rng.permutation(len(pool))[:k1]]
    b = pool[rng.permutation(len(pool))[:k2]]
    want, ended = oracle_rows([tuple(r) for r in a.tolist()], [tuple(r) for r in b.tolist()])
    # a small call's one kernel, and the chunked kernels of a large one
    old = identity_module._PARALLEL_MIN
    for parallel_min in (old, 0):
        identity_module._PARALLEL_MIN = parallel_min
        try:
            track = ContactIdentity()
            track.update(a)
            got = track.update(b)
        finally:
            identity_module._PARALLEL_MIN = old
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(track.ended_rows, ended)


# ---------------------------------------------------------------- carry

class TestCarry:
    def test_history_follows_its_pair(self):
        frames = trajectory(11, 6, 150, churn=3, reorder=True, wrap=True)
        search = ContactSearch(skin=0.1, quantities="P", identity=True)
        hist = None
        for _true_pos, shown, ids, rad, _ in frames:
            pairs = search.update(shown, rad, BOX, ids=ids)
            pid = np.sort(ids[pairs], axis=1)
            if hist is not None:
                hist = search.carry(hist, fill=-1)
                new = search.previous_rows < 0
                assert np.all(hist[new] == -1)
                # the history of a continuing pair is the pair's ids it was made from
                assert np.array_equal(hist[~new] // 10**7, pid[~new, 0])
                assert np.array_equal(hist[~new] % 10**7, pid[~new, 1])
            fresh = pid[:, 0] * 10**7 + pid[:, 1]
            hist = fresh if hist is None else np.where(hist < 0, fresh, hist)

    def test_shapes_dtypes_and_out(self):
        search = NeighborSearch(1.3, identity=True)
        rng = np.random.default_rng(12)
        x = rng.uniform(0, L, (150, 3))
        p1, _ = search.update(x, BOX)
        h = rng.normal(size=(len(p1), 3)).astype(np.float32)
        p2, _ = search.update(x + 0.05, BOX)
        got = search.carry(h, fill=7.0)
        assert got.shape == (len(p2), 3) and got.dtype == np.float32
        prev = search.previous_rows
        np.testing.assert_array_equal(got[prev >= 0], h[prev[prev >= 0]])
        assert np.all(got[prev < 0] == 7.0)
        out = np.empty_like(got)
        assert search.carry(h, 7.0, out=out) is out
        np.testing.assert_array_equal(out, got)
        vec = search.carry(np.arange(len(p1)), fill=[-1])
        assert vec.shape == (len(p2),)

    @pytest.mark.parametrize("shape", [(), (3,), (0,), (2, 2)])
    @pytest.mark.parametrize("fill", [0.0, -2, np.float64(np.nan), [5.0]])
    @pytest.mark.parametrize("how", ["new", "out", "strided out", "strided history"])
    def test_every_history_carries_as_a_gather(self, shape, fill, how):
        search = NeighborSearch(1.3, identity=True)
        rng = np.random.default_rng(13)
        x = rng.uniform(0, L, (150, 3))
        p1, _ = search.update(x, BOX)
        h = rng.normal(size=(len(p1), *shape))
        p2, _ = search.update(x + rng.normal(0, 0.1, x.shape), BOX)
        prev = search.previous_rows
        assert (prev < 0).any() and (prev >= 0).any()
        want = np.empty((len(p2), *shape))
        want[prev >= 0] = h[prev[prev >= 0]]
        want[prev < 0] = fill
        if how == "strided history":
            h = np.repeat(h, 2, axis=0)[::2]
        if how == "new" or how == "strided history":
            got = search.carry(h, fill)
        else:
            base = np.full((len(p2), *shape, 2) if how == "strided out" else want.shape, 9.0)
            out = base[..., 0] if how == "strided out" else base
            assert search.carry(h, fill, out=out) is out
            got = out
        np.testing.assert_array_equal(got, want)

    def test_clump_pair_history(self):
        frames = trajectory(16, 5, 200, churn=2, reorder=True, wrap=True)
        search = ContactSearch(skin=0.1, identity=True)
        hist = None
        for _true_pos, shown, ids, rad, lab in frames:
            search.update(shown, rad, BOX, ids=ids, clump_ids=lab)
            cp = search.clump_pairs
            code = cp[:, 0] * 10**6 + cp[:, 1]
            if hist is not None:
                hist = search.carry(hist, fill=-1, clumps=True)
                old = search.previous_clump_rows >= 0
                np.testing.assert_array_equal(hist[old], code[old])
                assert np.all(hist[~old] == -1)
            hist = code

    def test_carry_from_nothing(self):
        search = NeighborSearch(1.3, identity=True)
        search.update(np.zeros((0, 3)), BOX)
        search.update(np.random.default_rng(0).uniform(0, L, (40, 3)), BOX)
        got = search.carry(np.zeros((0, 2)), fill=3.0)
        assert got.shape == (len(search.previous_rows), 2) and np.all(got == 3.0)


# ------------------------------------------------------- double buffers

QUANTITIES = ["PijdDS", "P", "dD", "S"]


def _snapshot(out):
    out = out if isinstance(out, tuple) else (out,)
    return out, [np.array(a) for a in out]


class TestResultsSurviveOneMoreCall:
    @pytest.mark.parametrize("quantities", QUANTITIES)
    @pytest.mark.parametrize("path", ["columns", "sweep"])
    @pytest.mark.parametrize("margin", [0.0, 0.5], ids=["rebuild", "verlet"])
    @pytest.mark.parametrize("layout", ["pairs", "csr"])
    def test_previous_arrays_unchanged(self, quantities, path, margin, layout):
        if layout == "csr" and quantities not in ("P", "PijdDS"):
            pytest.skip("csr returns offsets, neighbours and distances")
        rng = np.random.default_rng(13)
        x = rng.uniform(0, L, (300, 3))
        search = NeighborSearch(1.2, rebuild_margin=margin, quantities=quantities,
                                layout=layout, path=path, identity=layout == "pairs")
        views, kept = _snapshot(search.update(x, BOX))
        maps = None
        for step in range(4):
            # every other call moves far enough to rebuild, a different count of
            # pairs, so that a reused buffer would show
            x = x + rng.normal(0, 0.02 if step % 2 else 0.3, x.shape)
            if step == 2:
                x = x[:250]
            new_views, new_kept = _snapshot(search.update(x, BOX))
            for v, k in zip(views, kept, strict=True):
                np.testing.assert_array_equal(v, k)
            if maps is not None:
                for v, k in zip(maps[0], maps[1], strict=True):
                    np.testing.assert_array_equal(v, k)
            if search.identity:
                maps = ((search.previous_rows, search.ended_rows),
                        (search.previous_rows.copy(), search.ended_rows.copy()))
            views, kept = new_views, new_kept
        if margin:
            assert search.stats["rebuilds"] < search.stats["frame"]

    def test_copy_returns_fresh_arrays(self):
        rng = np.random.default_rng(14)
        search = ContactSearch(quantities="Pd", identity=True)
        a = search.update(rng.uniform(0, L, (200, 3)), 0.4, BOX)
        b = search.update(rng.uniform(0, L, (200, 3)), 0.4, BOX, copy=True)
        rows_b = search.previous_rows
        c = search.update(rng.uniform(0, L, (200, 3)), 0.4, BOX)
        assert not any(np.shares_memory(u, v) for u in b for v in a + c)
        assert np.shares_memory(a[0], c[0])  # the buffers alternate
        assert not np.shares_memory(rows_b, search.previous_rows)
        rows_b_copy = rows_b.copy()
        search.update(rng.uniform(0, L, (200, 3)), 0.4, BOX)
        np.testing.assert_array_equal(rows_b, rows_b_copy)

    def test_a_failed_call_keeps_both(self):
        rng = np.random.default_rng(15)
        search = NeighborSearch(1.2, identity=True)
        x = rng.uniform(0, L, (200, 3))
        p1, _ = search.update(x, BOX)
        kept = p1.copy()
        with pytest.raises(ValueError, match="positions"):
            search.update(np.full((200, 3), np.nan), BOX)
        with pytest.raises(ValueError, match="cutoff"):
            search.update(x, [2.0] * 3 + [90] * 3)
        p2, _ = search.update(x, BOX)
        np.testing.assert_array_equal(p1, kept)
        assert np.all(search.previous_rows >= 0)


# --------------------------------------------------------------- errors

class TestErrors:
    def test_ids_need_identity(self):
        with pytest.raises(ValueError, match="ids are used by contact identity.*identity=True"):
            NeighborSearch(1.0).update(np.zeros((2, 3)), ids=[1, 2])

    def test_identity_needs_pairs_layout(self):
        with pytest.raises(ValueError, match="identity=True needs layout='pairs'"):
            ContactSearch(layout="csr", identity=True)
        with pytest.raises(TypeError, match="identity must be True or False"):
            NeighborSearch(1.0, identity="yes")

    def test_bad_ids(self):
        s = NeighborSearch(1.0, identity=True)
        x = np.zeros((3, 3))
        with pytest.raises(TypeError, match=r"ids must be integers .*float64"):
            s.update(x, ids=[1.0, 2.0, 3.0])
        with pytest.raises(ValueError, match=r"ids must have shape \(3,\)"):
            s.update(x, ids=[1, 2])
        with pytest.raises(ValueError, match=r"ids must be unique.*id 2 is at rows 1 and 2"):
            s.update(x, ids=[1, 2, 2])
        with pytest.raises(ValueError, match=r"ids must be unique.*id 7"):
            s.update(x, ids=[7, 10**15, 7])
        with pytest.raises(ValueError, match="ids must fit in int64"):
            s.update(x, ids=np.array([1, 2, 2**63], np.uint64))

    def test_ids_on_every_call_or_none(self):
        s = NeighborSearch(1.0, identity=True)
        s.update(np.zeros((3, 3)), ids=[1, 2, 3])
        with pytest.raises(ValueError, match="ids must be given on every call or on none"):
            s.update(np.zeros((3, 3)))

    def test_maps_need_identity(self):
        s = NeighborSearch(1.0)
        s.update(np.zeros((3, 3)))
        with pytest.raises(ValueError, match="identity=True"):
            _ = s.previous_rows
        with pytest.raises(ValueError, match="identity=True"):
            s.carry(np.zeros(1))

    def test_bad_carry(self):
        s = NeighborSearch(1.5, identity=True)
        with pytest.raises(ValueError, match="carry needs a previous update"):
            s.carry(np.zeros(3))
        x = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
        s.update(x)
        s.update(x)
        with pytest.raises(ValueError, match=r"history must have one row per contact .*\(2 rows\)"):
            s.carry(np.zeros(3))
        h = np.zeros(2)
        with pytest.raises(ValueError, match=r"out must have shape \(2,\) and dtype float64"):
            s.carry(h, out=np.zeros(2, np.float32))
        with pytest.raises(ValueError, match="out must not overlap history"):
            s.carry(h, out=h)
        with pytest.raises(TypeError, match="out must be a numpy array"):
            s.carry(h, out=[0, 0])
        with pytest.raises(ValueError, match="clump identity needs clump labels"):
            s.carry(h, clumps=True)

    def test_bad_keys(self):
        track = ContactIdentity()
        with pytest.raises(TypeError, match="keys must be integers"):
            track.update([[0.5, 1.0]])
        with pytest.raises(ValueError, match=r"keys must have shape \(k, w\)"):
            track.update([1, 2, 3])
        with pytest.raises(ValueError, match=r"keys must be unique rows: rows 0 and 2"):
            track.update([[1, 2], [2, 3], [1, 2]])
        track.update([[1, 2]])
        with pytest.raises(ValueError, match="keys must have the same columns"):
            track.update([[1, 2, 3]])

    def test_pair_identity_needs_shifts(self):
        with pytest.raises(ValueError, match="shifts must be given"):
            PairIdentity(shifts=True).update(np.zeros((1, 2), np.int64), 2)

    def test_more_than_2_to_the_32_particles(self):
        # pass 2 codes a pair by its two previous rows in one uint64
        track = PairIdentity(n_threads=1)
        track.update(np.array([[0, 1], [1, 2]]), 2**32)
        with pytest.raises(ValueError, match="up to 2\\*\\*32 particles"):
            track.update(np.array([[0, 3], [1, 2]]), 2**32)
        track = PairIdentity(n_threads=1)
        track.update(np.array([[0, 1], [1, 2]]), 2**32 - 1)
        assert track.update(np.array([[0, 3], [1, 2]]), 2**32 - 1).tolist() == [-1, 1]


def test_docstring_examples():
    result = doctest.testmod(identity_module, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0 and result.attempted > 0


@pytest.mark.parametrize("margin", [0.0, 0.3])
def test_results_are_read_only_with_identity(margin):
    # the next call matches against these buffers: a script cannot change them
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 6, (200, 3))
    search = ContactSearch(rebuild_margin=margin, quantities="PdS", identity=True)
    pairs, d, s = search.update(x, 0.5, ids=np.arange(200) + 7)
    assert len(pairs) > 20
    for arr in (pairs, d, s):
        assert not arr.flags.writeable
    with pytest.raises(ValueError, match="read-only"):
        pairs[0, 0] = 3
    kept = pairs.copy()
    rows = search.update(x, 0.5, ids=np.arange(200) + 7)[0]
    np.testing.assert_array_equal(rows, kept)
    np.testing.assert_array_equal(search.previous_rows, np.arange(len(kept)))
    own = search.update(x, 0.5, ids=np.arange(200) + 7, copy=True)
    assert all(arr.flags.writeable for arr in own)
    plain = ContactSearch(rebuild_margin=margin).update(x, 0.5)
    assert plain.flags.writeable  # no identity: nothing borrowed
