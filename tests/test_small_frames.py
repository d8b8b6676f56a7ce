"""Small frames: searches of up to ``_SMALL_MAX`` particles without a Verlet margin run
one serial kernel (``grid.small_frame``) and keep the resolved
cell between calls.  Their answer must be the general path's bit for bit (rows in the
same order) and the brute-force oracle's, for every size down to 0 particles."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granularsap import Cell, ContactSearch, NeighborSearch
from granularsap.periodic import as_cell

from .oracles import brute_image_pairs

CELLS = {
    "open": (None, None),
    "ortho": ([[8.0, 0, 0], [0, 8.0, 0], [0, 0, 8.0]], None),
    "triclinic": ([[8.0, 0, 0], [2.0, 8.0, 0], [-1.0, 1.5, 8.0]], None),
    "mixed": ([[8.0, 0, 0], [1.0, 8.0, 0], [0, 0, 8.0]], (True, False, True)),
    "tiny": ([[2.0, 0, 0], [0, 2.0, 0], [0, 0, 2.0]], None),
}


def _oracle(pos, box, pbc, radii, skin):
    cell = None if box is None else as_cell(box, pbc=(True,) * 3 if pbc is None else pbc)
    pb = (True, True, True) if pbc is None else pbc
    return brute_image_pairs(pos, skin, cell, pbc=pb, radii=radii)


def _pair(pos, radii, box, pbc, *, skin=0.0, labels=None, quantities="PdDS", **kw):
    """(small path, general path) results of one frame, as tuples of copies."""
    out = []
    for small_max in (None, 0):
        s = ContactSearch(skin=skin, quantities=quantities, **kw)
        if small_max is not None:
            s._small_max = small_max
        res = s.update(pos, radii, box, pbc=pbc, clump_ids=labels, copy=True)
        out.append((res if isinstance(res, tuple) else (res,), dict(s.stats)))
    return out


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape
        assert np.array_equal(x, y)  # rows in the same order, floats bit for bit


coords = st.lists(st.tuples(*[st.integers(-16, 48)] * 3), min_size=0, max_size=24)


@settings(max_examples=40, deadline=None)
@given(pts=coords, rad=st.lists(st.integers(0, 4), min_size=24, max_size=24),
       cell=st.sampled_from(sorted(CELLS)), skin=st.sampled_from([0.0, 0.25]),
       n_threads=st.sampled_from([1, 2]), path=st.sampled_from(["auto", "columns"]))
def test_small_frames_equal_the_general_path_and_the_oracle(pts, rad, cell, skin, n_threads,
                                                            path):
    # quarter-integer coordinates and dyadic radii: touching spheres are exact ties;
    # 0, 1 and 2 particles included; the tiny cell is barely wider than the range
    pos = np.asarray(pts, dtype=float).reshape(-1, 3) / 4.0
    radii = np.asarray(rad[: len(pos)], dtype=float) / (16.0 if cell == "tiny" else 8.0)
    box, pbc = CELLS[cell]
    (small, s_stats), (general, g_stats) = _pair(pos, radii, box, pbc, skin=skin,
                                                 n_threads=n_threads, path=path)
    assert s_stats["path"] == g_stats["path"] == "columns"
    _same(small, general)
    want_p, want_d = _oracle(pos, box, pbc, radii, skin)
    p, d = small[0], small[1]
    order = np.lexsort((p[:, 1], p[:, 0]))
    assert np.array_equal(p[order], want_p)
    np.testing.assert_allclose(d[order], want_d, rtol=1e-12)


@settings(max_examples=40, deadline=None)
@given(pts=st.lists(st.tuples(*[st.integers(-12, 44)] * 3), min_size=16, max_size=120),
       rad=st.lists(st.integers(1, 6), min_size=120, max_size=120),
       cell=st.sampled_from(["open", "ortho", "mixed"]), skin=st.sampled_from([0.0, 0.125]),
       strict=st.booleans())
def test_dense_polydisperse_columns_equal_the_general_path_and_the_oracle(pts, rad, cell,
                                                                          skin, strict):
    # many spheres of unequal radii to a column: four particles share a window
    # (the superset loop of an orthorhombic cell); quarter-integer coordinates,
    # some outside the cell (wrapped: the band's re-test), and radii in eighths
    # make touching spheres exact ties
    pos = np.asarray(pts, dtype=float).reshape(-1, 3) / 4.0
    radii = np.asarray(rad[: len(pos)], dtype=float) / 8.0
    radii[0] = 0.125 if radii[-1] != 0.125 else 0.25  # never one radius for all
    box, pbc = CELLS[cell]
    (small, s_stats), (general, _) = _pair(pos, radii, box, pbc, skin=skin,
                                           include_cutoff=not strict)
    _same(small, general)
    assert s_stats["pairs"] == len(small[0])
    # the agreed arithmetic by brute force: D = (x_j - x_i) + S0 a + S1 b + S2 c,
    # every shift that can matter (coordinates up to two cells out)
    i, j = np.triu_indices(len(pos), 1)
    mat = np.zeros((3, 3)) if box is None else np.asarray(box, dtype=float)
    per = (False,) * 3 if box is None else ((True,) * 3 if pbc is None else pbc)
    ks = [range(-3, 4) if per[c] else range(1) for c in range(3)]
    found = np.zeros(len(i), bool)
    thr = (radii[i] + radii[j]) + skin
    for s0 in ks[0]:
        for s1 in ks[1]:
            for s2 in ks[2]:
                dv = (pos[j] - pos[i]) + s0 * mat[0] + s1 * mat[1] + s2 * mat[2]
                d = np.sqrt(dv[:, 0] * dv[:, 0] + dv[:, 1] * dv[:, 1] + dv[:, 2] * dv[:, 2])
                found |= (d < thr) if strict else (d <= thr)
    p = small[0]
    assert np.array_equal(p[np.lexsort((p[:, 1], p[:, 0]))],
                          np.stack([i[found], j[found]], axis=1).reshape(-1, 2))


@pytest.mark.parametrize("cell", sorted(CELLS))
@pytest.mark.parametrize("n", [0, 1, 2, 3])
def test_fewest_particles(cell, n):
    box, pbc = CELLS[cell]
    pos = np.array([[0.5, 0.5, 0.5], [1.25, 0.5, 0.5], [7.75, 0.5, 0.5]])[:n]
    radii = np.full(n, 0.375)
    (small, _), (general, _) = _pair(pos, radii, box, pbc)
    _same(small, general)
    want_p, _ = _oracle(pos, box, pbc, radii, 0.0)
    assert np.array_equal(np.sort(small[0], axis=0), np.sort(want_p, axis=0))
    assert small[0].dtype == np.int64 and small[0].shape == (len(want_p), 2)


def _granular(n, seed, spread=3.0):
    rng = np.random.default_rng(seed)
    radii = np.clip(rng.lognormal(0.0, 0.6, n), 0.3, spread)
    length = (np.sum(4.0 / 3.0 * np.pi * radii ** 3) / 0.3) ** (1.0 / 3.0)
    return rng.random((n, 3)) * length, radii, length


@pytest.mark.parametrize("kind", ["periodic", "open", "triclinic", "labels", "strict"])
def test_polydisperse_frames_equal_the_general_path(kind):
    pos, radii, length = _granular(1500, 3)
    box = [length] * 3 + [90.0] * 3
    kw = {}
    labels = None
    if kind == "open":
        box = None
    elif kind == "triclinic":
        box = [[length, 0, 0], [0.2 * length, length, 0], [0.1 * length, -0.3 * length, length]]
    elif kind == "labels":
        labels = np.arange(len(pos)) // 3
    elif kind == "strict":
        kw["include_cutoff"] = False
    (small, s_stats), (general, _) = _pair(pos, radii, box, None, labels=labels, **kw)
    assert s_stats["pairs"] > 100
    _same(small, general)


@pytest.mark.parametrize("kind", ["periodic", "open-z", "triclinic"])
def test_sparse_small_frames_take_wider_columns(kind):
    # polydisperse spheres hold about 5 candidates per range-wide column window:
    # frames the small-frame kernel takes on any thread count widen their
    # columns (plan.wide_columns), the general path and two threads alike, and
    # the answer is still the oracle's
    pos, radii, length = _granular(1000, 11)
    box, pbc = [length] * 3 + [90.0] * 3, None
    if kind == "open-z":
        pbc = (True, True, False)
    elif kind == "triclinic":
        box = [[length, 0, 0], [0.2 * length, length, 0], [0.1 * length, -0.3 * length, length]]
    (small, s_stats), (general, g_stats) = _pair(pos, radii, box, pbc, quantities="PdS")
    _same(small, general)
    assert s_stats["columns"] == g_stats["columns"]
    two = ContactSearch(quantities="PdS", n_threads=2).update(pos, radii, box, pbc=pbc)
    _same(small, two)
    # columns one range wide would be about the cell's width over 2 rmax
    cell = Cell.coerce(box, pbc=pbc)
    range_wide = int(cell.perpendicular_widths[:2].min() / (2.0 * radii.max()))
    assert max(s_stats["columns"]) < range_wide
    p, d, _ = small
    order = np.lexsort((p[:, 1], p[:, 0]))
    assert np.array_equal(p[order], _nearby(pos, radii, cell))


def _nearby(pos, radii, cell):
    """Pairs i < j with d <= r_i + r_j over the 27 nearest images (a range below
    half the cell), vectorised in blocks of rows."""
    m = cell.matrix
    shifts = np.array([a * m[0] + b * m[1] + c * m[2] for a in (-1, 0, 1) for b in (-1, 0, 1)
                       for c in (-1, 0, 1) if all((a, b, c)[k] == 0 or cell.pbc[k]
                                                  for k in range(3))])
    out = []
    for lo in range(0, len(pos), 64):
        x = pos[lo:lo + 64]
        sep = pos[None, :, None, :] + shifts[None, None] - x[:, None, None, :]
        d = np.sqrt((sep ** 2).sum(axis=-1)).min(axis=-1)
        i, j = np.nonzero(d <= radii[lo:lo + 64, None] + radii[None, :])
        keep = lo + i < j
        out.append(np.stack([lo + i[keep], j[keep]], axis=1))
    return np.concatenate(out)


def test_wide_columns_only_where_every_thread_count_takes_the_small_kernel():
    from granularsap.kernels import grid
    from granularsap.search import plan

    # the small-frame kernel runs any thread count below two chunks of work
    assert grid.WIDE_MAX == 2 * plan.CHUNK - 1
    nb = plan.wide_columns([12, 12], np.ones(3), np.full(3, 1 / 12), 1000)
    assert nb == [12 // 3, 12 // 3] or max(nb) < 12
    # a dense frame keeps columns one range wide
    assert plan.wide_columns([8, 8], np.ones(3), np.full(3, 1 / 8), 64 * 400) == [8, 8]
    # no division by zero without particles
    assert plan.wide_columns([4, 4], np.ones(3), np.full(3, 0.25), 0) == [1, 1]


def test_two_levels_on_a_small_frame():
    # 2 % large spheres: the cost model splits the radii on the small path too
    rng = np.random.default_rng(8)
    n = 3000
    radii = np.where(rng.random(n) < 0.02, 2.0, 0.2)
    pos = rng.uniform(0.0, 20.0, (n, 3))
    (small, s_stats), (general, g_stats) = _pair(pos, radii, [20.0] * 3 + [90.0] * 3, None)
    assert s_stats["levels"] == g_stats["levels"] == 2
    _same(small, general)


@pytest.mark.parametrize("small_max", [None, 0])
def test_kept_search_splits_levels_as_a_fresh_one(small_max):
    # open axes: the spread of the particles sets the volume of the cost model,
    # which changes every frame of a moving pack; a kept search decides each
    # frame's column levels as a fresh search does (a function of the frame)
    rng = np.random.default_rng(9)
    n = 3000
    radii = np.where(rng.random(n) < 0.02, 2.0, 0.2)
    base = rng.uniform(0.0, 20.0, (n, 3))
    kept = ContactSearch(quantities="P")
    if small_max is not None:
        kept._small_max = small_max
    seen = set()
    for scale in (1.0, 1.003, 1.02, 3.0, 1.0, 12.0, 1.001, 40.0, 1.0):
        pos = base * scale
        got = kept.update(pos, radii, copy=True)
        fresh = ContactSearch(quantities="P")
        if small_max is not None:
            fresh._small_max = small_max
        want = fresh.update(pos, radii)
        assert kept.stats["levels"] == fresh.stats["levels"], scale
        assert np.array_equal(got, want)
        seen.add(kept.stats["levels"])
    assert seen == {1, 2}


def test_dense_frame_grows_its_records():
    # every pair in range: pass 1 needs more records than first sized, runs again
    rng = np.random.default_rng(2)
    pos = rng.random((300, 3))
    search = NeighborSearch(2.0, quantities="Pd")
    pairs, d = search.update(pos)
    assert len(pairs) == 300 * 299 // 2
    general = NeighborSearch(2.0, quantities="Pd")
    general._small_max = 0
    _same((pairs, d), general.update(pos))


def test_neighbor_search_uniform_ranges():
    rng = np.random.default_rng(4)
    pos = rng.random((2000, 3)) * 12.0
    box = [12.0] * 3 + [90.0] * 3
    a = NeighborSearch(2.5, quantities="PdDS")
    b = NeighborSearch(2.5, quantities="PdDS")
    b._small_max = 0
    for step in range(3):
        x = pos + 0.05 * step
        _same(a.update(x, box, copy=True), b.update(x, box, copy=True))


def test_kept_cell_follows_a_box_changed_in_place():
    # the resolved cell is kept while the same values come back; an array edited
    # in place between calls is a new cell
    rng = np.random.default_rng(5)
    pos = rng.random((200, 3)) * 10.0
    box = np.array([10.0, 10.0, 10.0, 90.0, 90.0, 90.0])
    search = NeighborSearch(1.5, quantities="Pd")
    first = search.update(pos, box, copy=True)
    box[0] = 12.0
    second = search.update(pos, box, copy=True)
    fresh = NeighborSearch(1.5, quantities="Pd").update(pos, box)
    _same(second, fresh)
    assert len(first[0]) != len(second[0])
    cell = Cell.from_dimensions([12.0, 10.0, 10.0, 90.0, 90.0, 90.0])
    _same(search.update(pos, cell, copy=True), fresh)
    _same(search.update(pos, cell, pbc=(True, False, True), copy=True),
          NeighborSearch(1.5, quantities="Pd").update(pos, cell, pbc=(True, False, True)))


def test_particle_count_changes_between_small_frames():
    pos, radii, length = _granular(1200, 6)
    box = [length] * 3 + [90.0] * 3
    search = ContactSearch(quantities="Pd")
    general = ContactSearch(quantities="Pd")
    general._small_max = 0
    for n in (1200, 700, 1200, 5, 0, 1200):
        _same(search.update(pos[:n], radii[:n], box, copy=True),
              general.update(pos[:n], radii[:n], box, copy=True))


def test_far_outside_the_cell_is_named_on_the_small_path():
    pos = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0 ** 60, 0, 0]])
    with pytest.raises(ValueError, match=r"positions row 2 .* outside the cell"):
        NeighborSearch(1.5).update(pos, [5.0] * 3 + [90.0] * 3)


def test_bench_repeats_a_small_frame_and_reports_its_minimum():
    from granularsap.bench import harness, workloads
    from granularsap.bench.peers import make_peers

    wl = workloads.make("granular-polydisperse", 200)
    (peer,) = make_peers(["granularsap-steady"])
    many = harness.run_peer(peer, wl, repeats=3, small_runs=20)
    assert len(many.times) == 20 and many.min_seconds == min(many.times)
    assert many.min_seconds <= many.seconds
    (peer,) = make_peers(["granularsap-steady"])
    few = harness.run_peer(peer, wl, repeats=3)
    assert len(few.times) == 3


def test_two_threads_above_one_chunk_keep_the_parallel_path():
    # n_threads=2 asked for with more particles than one chunk of parallel work:
    # the general path on two threads, the same rows as the serial small path
    pos, radii, length = _granular(5000, 9)
    box = [length] * 3 + [90.0] * 3
    one = ContactSearch(quantities="PdD", n_threads=1)
    two = ContactSearch(quantities="PdD", n_threads=2)
    a = one.update(pos, radii, box, copy=True)
    b = two.update(pos, radii, box, copy=True)
    assert one.stats["threads"] == 1 and two.stats["threads"] == 2
    _same(a, b)


def test_a_plan_wider_than_the_small_stencil_falls_back():
    # the small path keeps room for the stencils of one or two column layers;
    # a plan needing more (here: no room at all) runs the general path instead
    pos, radii, length = _granular(800, 10)
    box = [length] * 3 + [90.0] * 3
    s = ContactSearch(quantities="PdDS")
    want = s.update(pos, radii, box, copy=True)
    s._small_scratch = s._small_scratch[:3] + (np.empty((0, 2), np.int64),)
    _same(s.update(pos, radii, box, copy=True), want)
    assert s.stats["seconds"]["sort"] > 0.0  # the general path's own sort ran


def test_particles_crowded_along_the_sweep_axis_take_the_general_path():
    # 1,000 spheres in a thin slab across the open sweep axis: the small path's
    # sweep buckets would each hold dozens of particles, so the frame runs the
    # general path, with the same answer as the oracle
    rng = np.random.default_rng(4)
    pos = np.concatenate([rng.uniform(0, 3, (1000, 2)), rng.uniform(0, 1e-3, (1000, 1))],
                         axis=1)
    radii = rng.uniform(0.2, 0.4, 1000)
    (small, s_stats), (general, _) = _pair(pos, radii, None, None)
    _same(small, general)
    assert s_stats["seconds"]["sort"] > 0.0  # the general path's own sort ran
    want, _ = _oracle(pos, None, None, radii, 0.0)
    assert sorted(map(tuple, small[0].tolist())) == sorted(map(tuple, want.tolist()))


def test_a_settled_pile_stays_on_the_small_path(monkeypatch):
    # the bundled pour's last frames: spheres settled in layers on a flat floor,
    # each layer in one sweep bucket of the widened columns; the bucket check
    # scales with the columns' area, so the frame stays on the small-frame
    # kernel (it fell to the general path, three times slower, when the check
    # was that of range-wide columns) and still equals the general path
    from pathlib import Path

    import granularsap.search.engine as engine
    from granularsap.io import iter_frames

    frames = list(iter_frames(Path(__file__).parent.parent / "data" / "pour.dump"))
    taken = []
    real = engine.SearchEngine._small

    def small(self, *args):
        out = real(self, *args)
        taken.append(out is not None)  # None: the general path takes the frame
        return out

    monkeypatch.setattr(engine.SearchEngine, "_small", small)
    for f in frames[-4:]:
        taken.clear()
        (small, s_stats), (general, _) = _pair(f.positions, f.radius, f.cell, f.pbc)
        assert taken and taken[0]
        assert s_stats["columns"][0] < 8  # widened (range-wide columns: 9 x 9)
        _same(small, general)
