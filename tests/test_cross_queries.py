"""Cross-set queries (``NeighborSearch.query``, ``ContactSearch.query``) against a
brute force written in the agreed arithmetic of docs/cells.md.

The oracle tries every image shift ``S`` that could matter and sums ``D =
(conf[j] - ref[i]) + S0 a + S1 b + S2 c`` in that order, ``d = sqrt(Dx*Dx +
Dy*Dy + Dz*Dz)``, so ties at the threshold, points on and outside the cell's
faces and non-dyadic cells must come out bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from granularsap import Cell, ContactSearch, NeighborSearch

# ------------------------------------------------------------------ the oracle


def _widths(cell):
    big = np.abs(cell).max()
    cell = cell / big
    vol = abs(np.linalg.det(cell))
    return big * np.array([vol / np.linalg.norm(np.cross(cell[(k + 1) % 3], cell[(k + 2) % 3]))
                           for k in range(3)])


def _norm(D):
    """``sqrt(Dx*Dx + Dy*Dy + Dz*Dz)`` as float64 with an unbounded exponent (the
    engine's arithmetic, docs/cells.md): each row scaled by a power of two
    first, which is exact, so no square overflows or underflows."""
    e = np.frexp(np.abs(D).max(axis=1))[1]
    u = np.ldexp(D, -e[:, None])
    with np.errstate(over="ignore"):  # (beyond 1.8e308: out of every range)
        return np.ldexp(np.sqrt(u[:, 0] * u[:, 0] + u[:, 1] * u[:, 1] + u[:, 2] * u[:, 2]), e)


def oracle(ref, conf, cell, pbc, thr, *, strict=False, images="minimum", scale=1.0):
    """``{(i, j, S0, S1, S2): (d, Dx, Dy, Dz)}`` of every image in range (``images
    ="all"``), or the nearest image in range of every pair (``"minimum"``).

    ``thr[i, j]`` is the pair's threshold (already summed as the engine sums
    it); ``cell`` the (3, 3) rows the shifts multiply (None: open).  ``scale``, a
    power of two, is applied first and taken off at the end (exact): the
    arithmetic of an unbounded exponent for tiny or huge coordinates."""
    ref = np.asarray(ref, np.float64).reshape(-1, 3) * scale
    conf = np.asarray(conf, np.float64).reshape(-1, 3) * scale
    thr = np.asarray(thr, np.float64) * scale
    if cell is not None:
        cell = np.asarray(cell, np.float64) * scale
    n, m = len(ref), len(conf)
    if n == 0 or m == 0:
        return {}
    shifts = [(0, 0, 0)]
    if cell is not None:
        cell = np.asarray(cell, np.float64)
        w = _widths(cell)
        both = np.concatenate([ref, conf])
        frac = both @ np.linalg.inv(cell)
        reps = []
        for k in range(3):
            if not pbc[k]:
                reps.append(range(0, 1))
                continue
            mm = int(math.ceil(float(thr.max()) / w[k] + np.ptp(frac[:, k]))) + 2
            reps.append(range(-mm, mm + 1))
        shifts = [(a, b, c) for a in reps[0] for b in reps[1] for c in reps[2]]
    out = {}
    for i in range(n):
        base = conf - ref[i]
        for s in shifts:
            D = base.copy()
            if cell is not None:
                for r in range(3):
                    D = D + float(s[r]) * cell[r]
            d = _norm(D)
            t = thr[i]
            ok = (d < t) if strict else (d <= t)
            for j in np.flatnonzero(ok):
                key = (i, int(j), *s)
                val = (float(d[j]) / scale, *(float(v) / scale for v in D[j]))
                if images == "all":
                    out[key] = val
                else:
                    prev = out.get((i, int(j)))
                    if prev is None or val[0] < prev[0][0]:
                        out[(i, int(j))] = (val, s)
    if images == "all":
        return out
    return {(i, j, *s): val for (i, j), (val, s) in out.items()}


def as_dict(res, images):
    pairs, d, D, S = res
    out = {}
    for r in range(len(pairs)):
        key = (int(pairs[r, 0]), int(pairs[r, 1]), *map(int, S[r]))
        assert key not in out, f"pair {key} twice"
        out[key] = (float(d[r]), *map(float, D[r]))
    return out


def assert_same(got, want, minimum_ties=False):
    if minimum_ties:  # which of two images tying at half the cell is kept is not fixed
        got = {k[:2]: v[0] for k, v in got.items()}
        want = {k[:2]: v[0] for k, v in want.items()}
    assert set(got) == set(want), (sorted(set(got) - set(want))[:5],
                                   sorted(set(want) - set(got))[:5])
    for k in want:
        g, w = got[k], want[k]
        if isinstance(w, tuple):  # bit for bit (signed zeros of D aside)
            assert g == w, (k, g, w)
        else:
            assert g == w, (k, g, w)


def _matrix(box, pbc):
    c = Cell.coerce(box, pbc=pbc)
    return None if c is None or not c.any_periodic else np.array(c.matrix)


def run_neighbor(ref, conf, cutoff, box, pbc=None, images="minimum", strict=False, **kw):
    s = NeighborSearch(cutoff, quantities="PdDS", periodic_images=images,
                       include_cutoff=not strict, **kw)
    return s.query(ref, conf, box, pbc=pbc)


def check_neighbor(ref, conf, cutoff, box, pbc=None, images="minimum", strict=False,
                   scale=1.0, **kw):
    got = as_dict(run_neighbor(ref, conf, cutoff, box, pbc, images, strict, **kw), images)
    cell = Cell.coerce(box, pbc=pbc)
    p = cell.pbc if cell is not None else np.zeros(3, bool)
    thr = np.full((len(ref), len(conf)), float(cutoff))
    want = oracle(ref, conf, _matrix(box, pbc), p, thr, strict=strict, images=images,
                  scale=scale)
    ties = images == "minimum" and cell is not None and cell.any_periodic and (
        2 * cutoff >= cell.perpendicular_widths[cell.pbc].min() * (1 - 1e-9))
    assert_same(got, want, minimum_ties=ties)
    return got


def check_contact(ref, rr, conf, rc, skin, box, pbc=None, images="minimum", strict=False):
    s = ContactSearch(skin=skin, quantities="PdDS", periodic_images=images,
                      include_cutoff=not strict)
    got = as_dict(s.query(ref, rr, conf, rc, box, pbc=pbc), images)
    cell = Cell.coerce(box, pbc=pbc)
    p = cell.pbc if cell is not None else np.zeros(3, bool)
    rr = np.broadcast_to(np.asarray(rr, float), (len(ref),))
    rc = np.broadcast_to(np.asarray(rc, float), (len(conf),))
    thr = (rr[:, None] + rc[None, :]) + skin
    want = oracle(ref, conf, _matrix(box, pbc), p, thr, strict=strict, images=images)
    assert_same(got, want)
    return got


# ------------------------------------------------------------------ the cells

BOXES = {
    "open": (None, None),
    "ortho": ([6.1, 7.3, 5.9, 90, 90, 90], None),
    "tric": ([6.3, 7.1, 6.7, 80, 95, 72], None),
    "slab": (np.diag([6.1, 7.3, 5.9]), (True, True, False)),
    "wire": ([6.3, 7.1, 6.7, 80, 95, 72], (False, False, True)),
    "xz": ([6.1, 7.3, 5.9, 90, 90, 90], (True, False, True)),
}


def _points(rng, n, spread):
    """Points in [-spread, 6 + spread) with some exactly on cell faces."""
    x = rng.uniform(-spread, 6.0 + spread, (n, 3))
    if n:
        x[rng.random((n, 3)) < 0.15] = 0.0
    return x


class TestAgainstTheOracle:
    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("images", ["minimum", "all"])
    @pytest.mark.parametrize("seed", range(3))
    def test_neighbor_query(self, box, images, seed):
        rng = np.random.default_rng(seed)
        ref, conf = _points(rng, 40, 3.0), _points(rng, 70, 3.0)
        for cutoff in (0.9, 2.2):
            check_neighbor(ref, conf, cutoff, *BOXES[box], images=images)
        if images == "all":  # beyond the cell: many images of one pair
            check_neighbor(ref[:10], conf[:15], 9.5, *BOXES[box], images=images)

    @pytest.mark.parametrize("box", list(BOXES))
    @pytest.mark.parametrize("images", ["minimum", "all"])
    def test_contact_query(self, box, images):
        rng = np.random.default_rng(7)
        ref, conf = _points(rng, 30, 2.0), _points(rng, 60, 2.0)
        rr, rc = rng.uniform(0.1, 0.9, 30), rng.uniform(0.0, 0.6, 60)
        check_contact(ref, rr, conf, rc, 0.2, *BOXES[box], images=images)
        check_contact(ref, 0.5, conf, 0.25, 0.0, *BOXES[box], images=images)

    @pytest.mark.parametrize("box", list(BOXES))
    def test_strict(self, box):
        rng = np.random.default_rng(3)
        ref = rng.integers(-4, 28, (30, 3)) * 0.25
        conf = rng.integers(-4, 28, (50, 3)) * 0.25
        check_neighbor(ref, conf, 1.25, *BOXES[box], strict=True)
        check_neighbor(ref, conf, 1.25, *BOXES[box], strict=False)


class TestTies:
    def test_ties_at_the_cutoff_on_a_lattice(self):
        # every coordinate a multiple of 0.5: many separations exactly 1.5, 2.5
        rng = np.random.default_rng(0)
        ref = rng.integers(-6, 20, (60, 3)) * 0.5
        conf = rng.integers(-6, 20, (80, 3)) * 0.5
        for box in ([8.0, 8.0, 8.0, 90, 90, 90], [8.0, 8.0, 8.0, 90, 90, 60], None):
            for cutoff in (1.5, 2.5, math.sqrt(2.0)):
                got = check_neighbor(ref, conf, cutoff, box)
                assert got  # ties are there
                check_neighbor(ref, conf, cutoff, box, images="all")

    def test_ties_with_points_outside_a_non_dyadic_cell(self):
        # the cells docs' case: a row outside the cell, a tie 1.5 on the given positions
        ref = np.array([[-0.3, 1.0, 1.0], [6.4, 1.0, 1.0], [12.5, 1.0, 1.0]])
        conf = np.array([[1.2, 1.0, 1.0], [4.9, 1.0, 1.0], [-4.9, 1.0, 1.0]])
        box = np.diag([6.1, 6.1, 6.1])
        got = check_neighbor(ref, conf, 1.5, box)
        assert (0, 0, 0, 0, 0) in got and got[(0, 0, 0, 0, 0)][0] == 1.5
        check_neighbor(ref, conf, 1.5, box, images="all")

    def test_ties_built_from_representable_coordinates_in_every_cell(self):
        # pairs at exactly the cutoff across faces, several cells away, triclinic
        rng = np.random.default_rng(5)
        base = rng.integers(0, 24, (40, 3)) * 0.25
        off = rng.integers(-2, 3, (40, 3)) * 6.0
        conf = base + off  # outside by whole cells
        ref = base[rng.permutation(40)] + np.array([1.25, 0.0, 0.0])
        for box in ([6.0, 6.0, 6.0, 90, 90, 90], [6.0, 6.0, 6.0, 90, 90, 60],
                    [6.0, 6.0, 6.0, 70, 80, 60]):
            check_neighbor(ref, conf, 1.25, box)
            check_neighbor(ref, conf, 1.25, box, images="all")
            check_neighbor(ref, conf, 1.25, box, pbc=(True, False, True))

    def test_half_cell_ties_minimum_image(self):
        # two images at exactly half the cell: one row per pair
        ref = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
        conf = np.array([[2.0, 0.0, 0.0], [3.0, 2.0, 3.0]])
        pairs, d, D, S = run_neighbor(ref, conf, 2.0, [4.0, 4.0, 4.0, 90, 90, 90])
        assert sorted(map(tuple, pairs.tolist())) == [(0, 0), (1, 1)]
        assert d.tolist() == [2.0, 2.0]


class TestEdges:
    @pytest.mark.parametrize("box", list(BOXES))
    def test_empty_and_one(self, box):
        rng = np.random.default_rng(1)
        x = _points(rng, 5, 1.0)
        for ref, conf in ((x[:0], x), (x, x[:0]), (x[:0], x[:0]), (x[:1], x[:1]),
                          (x[:1], x), (x, x[:1])):
            res = run_neighbor(ref, conf, 1.5, *BOXES[box])
            assert res[0].shape[1] == 2 and res[0].dtype == np.int64
            check_neighbor(ref, conf, 1.5, *BOXES[box])
            check_neighbor(ref, conf, 1.5, *BOXES[box], images="all")

    def test_duplicates_and_the_same_set(self):
        rng = np.random.default_rng(2)
        x = _points(rng, 20, 1.0)
        x = np.concatenate([x, x[:7], x[:3]])
        for box, pbc in BOXES.values():
            got = check_neighbor(x, x, 1.5, box, pbc)
            # every point with itself at distance 0, once
            for i in range(len(x)):
                assert got[(i, i, 0, 0, 0)][0] == 0.0

    def test_zero_cutoff(self):
        x = np.array([[0.0, 0, 0], [1.0, 1, 1], [6.1, 0, 0]])
        y = np.array([[0.0, 0, 0], [1.0, 1, 1.0000000000000002]])
        check_neighbor(x, y, 0.0, None)
        check_neighbor(x, y, 0.0, np.diag([6.1, 6.1, 6.1]))

    def test_far_points_along_an_open_axis(self):
        rng = np.random.default_rng(4)
        ref = _points(rng, 20, 1.0)
        conf = _points(rng, 30, 1.0)
        conf[0] = (1e300, 2.0, 3.0)
        ref[1] = (-1e300, 2.0, 3.0)
        conf[1] = (-1e300, 2.0, 3.5)
        check_neighbor(ref, conf, 1.5, None)
        check_neighbor(ref, conf, 1.5, np.diag([6.1, 6.1, 6.1]), pbc=(False, True, True))

    def test_tiny_and_huge_magnitudes(self):
        x = np.array([[0.0, 0, 0], [3e-300, 0, 0], [1e-299, 5e-300, 0]])
        y = np.array([[1e-300, 0, 0], [4e-300, 1e-300, 0], [0.0, 4e-300, 0]])
        for cutoff in (5e-300, 3e-300, 5e-324):
            check_neighbor(x, y, cutoff, None, scale=2.0 ** 1000)
            check_neighbor(x, y, cutoff, np.diag([1e-298] * 3), scale=2.0 ** 1000)
        x, y = x * 1e299 * 1e300, y * 1e299 * 1e300
        check_neighbor(x, y, 5e299, None, scale=2.0 ** -600)
        check_neighbor(x, y, 5e299, np.diag([2e301] * 3), scale=2.0 ** -600)

    def test_csr_layout(self):
        rng = np.random.default_rng(6)
        ref, conf = _points(rng, 25, 1.0), _points(rng, 60, 1.0)
        box = [6.1, 7.3, 5.9, 90, 90, 90]
        pairs, d = NeighborSearch(1.7).query(ref, conf, box)
        offsets, cols, dd = NeighborSearch(1.7, layout="csr").query(ref, conf, box)
        assert offsets.shape == (26,) and offsets[-1] == len(pairs)
        assert np.array_equal(np.repeat(np.arange(25), np.diff(offsets)), pairs[:, 0])
        assert np.array_equal(cols, pairs[:, 1]) and np.array_equal(dd, d)

    def test_rows_grouped_by_reference(self):
        rng = np.random.default_rng(8)
        ref, conf = _points(rng, 700, 1.0), _points(rng, 900, 1.0)
        pairs, _ = NeighborSearch(1.2).query(ref, conf, [6.1, 7.3, 5.9, 90, 90, 90])
        assert np.all(np.diff(pairs[:, 0]) >= 0)


class TestKeptGrid:
    def test_one_grid_many_queries(self):
        rng = np.random.default_rng(9)
        conf = _points(rng, 500, 1.0)
        box = [6.1, 7.3, 5.9, 80, 95, 72]
        s = NeighborSearch(1.3, quantities="PdDS")
        for k in range(4):
            ref = _points(rng, 30 + 20 * k, 1.0)
            got = as_dict(s.query(ref, conf, box), "minimum")
            assert s.stats["grid"] == ("built" if k == 0 else "kept")
            fresh = as_dict(NeighborSearch(1.3, quantities="PdDS").query(ref, conf, box),
                            "minimum")
            assert got == fresh
        assert s.stats["grid_builds"] == 1
        # the configuration edited in place: a new grid
        conf[3] += 0.5
        s.query(ref, conf, box)
        assert s.stats["grid"] == "built"
        check_neighbor(ref, conf, 1.3, box)
        # another cell: a new grid
        s.query(ref, conf, [6.1, 7.3, 5.9, 90, 90, 90])
        assert s.stats["grid"] == "built"

    def test_contact_radii_change_rebuilds(self):
        rng = np.random.default_rng(10)
        conf, ref = _points(rng, 200, 1.0), _points(rng, 40, 1.0)
        s = ContactSearch(skin=0.1, quantities="Pd")
        rc = rng.uniform(0.1, 0.5, 200)
        a = s.query(ref, 0.3, conf, rc)
        b = s.query(ref[::-1], 0.2, conf, rc)
        assert s.stats["grid"] == "kept"
        c = s.query(ref, 0.3, conf, rc * 1.5)
        assert s.stats["grid"] == "built"
        assert len(a[0]) and len(b[0]) and len(c[0]) >= len(a[0])

    def test_results_valid_until_the_query_after_next(self):
        rng = np.random.default_rng(11)
        conf = _points(rng, 300, 1.0)
        s = NeighborSearch(1.5)
        first = s.query(_points(rng, 20, 1.0), conf)
        kept = [a.copy() for a in first]
        s.query(_points(rng, 25, 1.0), conf)
        assert all(np.array_equal(a, b) for a, b in zip(first, kept, strict=True))
        c = s.query(_points(rng, 20, 1.0), conf, copy=True)
        s.query(_points(rng, 20, 1.0), conf)
        s.query(_points(rng, 20, 1.0), conf)
        assert c[0].flags.owndata or c[0].base is not None

    def test_update_and_query_keep_their_own_state(self):
        rng = np.random.default_rng(12)
        x = _points(rng, 300, 0.0)
        s = NeighborSearch(1.2, rebuild_margin=0.3)
        p1, _ = s.update(x, [6.5, 6.5, 6.5, 90, 90, 90])
        p1 = p1.copy()
        s.query(x[:10], x, [6.5, 6.5, 6.5, 90, 90, 90])
        p2, _ = s.update(x + 0.01, [6.5, 6.5, 6.5, 90, 90, 90])
        assert not s.stats["rebuilt"]


class TestThreads:
    @pytest.mark.parametrize("box", ["ortho", "tric", "slab"])
    def test_one_and_two_threads_agree(self, box):
        rng = np.random.default_rng(13)
        length = 30.0
        conf = rng.uniform(-1.0, length + 1.0, (25_000, 3))
        ref = rng.uniform(-1.0, length + 1.0, (3_000, 3))
        b, pbc = {"ortho": ([length] * 3 + [90, 90, 90], None),
                  "tric": ([length] * 3 + [80, 95, 72], None),
                  "slab": (np.diag([length] * 3), (True, True, False))}[box]
        res = [NeighborSearch(1.1, quantities="PdDS", n_threads=t).query(ref, conf, b, pbc=pbc)
               for t in (1, 2)]
        for a, c in zip(*res, strict=True):
            assert np.array_equal(a, c)
        r2 = [ContactSearch(skin=0.1, quantities="PdS", n_threads=t,
                            periodic_images="all").query(ref, 0.3, conf, 0.2, b, pbc=pbc)
              for t in (1, 2)]
        for a, c in zip(*r2, strict=True):
            assert np.array_equal(a, c)


class TestErrors:
    def test_bad_input_names_the_argument(self):
        x = np.zeros((3, 3))
        s = NeighborSearch(1.0)
        with pytest.raises(ValueError, match="reference must have shape"):
            s.query(np.zeros((3, 2)), x)
        with pytest.raises(ValueError, match="configuration must have shape"):
            s.query(x, np.zeros(4))
        bad = x.copy()
        bad[1, 2] = np.nan
        with pytest.raises(ValueError, match="reference must be finite.*row 1"):
            s.query(bad, x)
        with pytest.raises(ValueError, match="configuration must be finite.*row 1"):
            s.query(x, bad)
        with pytest.raises(TypeError, match="configuration must be an array of real"):
            s.query(x, np.array([["a", "b", "c"]]))
        c = ContactSearch()
        with pytest.raises(ValueError, match="ref_radii must be non-negative"):
            c.query(x, [0.1, -0.2, 0.1], x, 0.1)
        with pytest.raises(ValueError, match=r"conf_radii must be a scalar or have shape \(3,\)"):
            c.query(x, 0.1, x, [0.1, 0.2])
        with pytest.raises(ValueError, match="exceeds half the smallest perpendicular"):
            s.query(x, x, [1.5, 3, 3, 90, 90, 90])
        with pytest.raises(ValueError, match="configuration row 0"):
            s.query(x, np.array([[1e300, 0, 0]]), [3, 3, 3, 90, 90, 90])
        with pytest.raises(ValueError, match="reference row 0"):
            s.query(np.array([[1e300, 0, 0]]), x, [3, 3, 3, 90, 90, 90])


# ------------------------------------------------------------ property tests

coords = st.floats(-8.0, 14.0, allow_nan=False, width=64)
lattice = st.integers(-16, 56).map(lambda k: k * 0.25)


@st.composite
def frames(draw):
    kind = draw(st.sampled_from(list(BOXES)))
    el = draw(st.sampled_from([coords, lattice]))
    n = draw(st.integers(0, 12))
    m = draw(st.integers(0, 15))
    ref = np.array(draw(st.lists(st.tuples(el, el, el), min_size=n, max_size=n)),
                   np.float64).reshape(-1, 3)
    conf = np.array(draw(st.lists(st.tuples(el, el, el), min_size=m, max_size=m)),
                    np.float64).reshape(-1, 3)
    cutoff = draw(st.sampled_from([0.0, 0.5, 1.0, 1.25, 2.0, 2.5, 2.75]))
    images = draw(st.sampled_from(["minimum", "all"]))
    return kind, ref, conf, cutoff, images


def _unless_refused(check):
    """Run ``check``; a frame the engine refuses as documented (no power-of-two
    scale keeps both its range and its smallest threshold exact: docs/cells.md,
    supported magnitudes) passes."""
    try:
        check()
    except ValueError as exc:
        assert "power-of-two scale" in str(exc), exc


@given(frames())
def test_property_neighbor_query_equals_the_oracle(frame):
    kind, ref, conf, cutoff, images = frame
    _unless_refused(lambda: check_neighbor(ref, conf, cutoff, *BOXES[kind], images=images))


@given(frames(), st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.booleans())
def test_property_contact_query_equals_the_oracle(frame, a, b, strict):
    kind, ref, conf, cutoff, images = frame
    rr = np.linspace(0.0, a, len(ref))
    rc = np.linspace(b, 0.0, len(conf))
    _unless_refused(lambda: check_contact(ref, rr, conf, rc, 0.5 * cutoff, *BOXES[kind],
                                          images=images, strict=strict))


def test_subnormal_separations_as_with_an_unbounded_exponent():
    # (found by the property test) a separation of 5e-324: its square underflows in
    # plain float64, the engine's distance is 5e-324, and a zero threshold excludes it
    ref = np.zeros((1, 3))
    conf = np.array([[0.0, 0.0, 5e-324], [0.0, 0.0, 0.0]])
    got = check_contact(ref, 0.0, conf, [1e-300, 0.0], 0.0, None)
    assert got[(0, 0, 0, 0, 0)][0] == 5e-324
    got = check_contact(ref, 0.0, conf, 0.0, 0.0, None)
    assert set(got) == {(0, 1, 0, 0, 0)}


def test_pairs_beyond_the_memory_available_are_refused(monkeypatch):
    from granularsap import _memory

    monkeypatch.setattr(_memory, "available_memory", lambda: 1 << 20)
    x = np.random.default_rng(0).uniform(0, 1, (4000, 3))
    with pytest.raises(MemoryError, match="the query has 16000000 pairs"):
        NeighborSearch(2.0).query(x, x)


def test_records_outgrowing_their_regions():
    # a first query sizes the records' regions (few pairs per point); a second one
    # needs far more in some chunks and none in others: the chunks that overflow
    # run again in new regions, the others keep theirs
    rng = np.random.default_rng(14)
    box = [12.0, 12.0, 12.0, 90, 90, 90]
    conf = rng.uniform(0, 12, (3000, 3))
    s = ContactSearch(skin=0.0, quantities="PdS")
    s.query(rng.uniform(0, 12, (1200, 3)), 0.0, conf, 0.05, box)
    ref = rng.uniform(0, 12, (1200, 3))
    rr = np.where(ref[:, 0] < 6.0, 0.0, 1.5)  # (chunks follow the columns: space)
    got = as_dict_pds(s.query(ref, rr, conf, 0.05, box))
    fresh = ContactSearch(skin=0.0, quantities="PdS")
    fresh.query(ref[:1], 0.0, conf, 0.05, box)
    fresh._cross.per_ref = 1e4  # (regions large enough at once)
    want = as_dict_pds(fresh.query(ref, rr, conf, 0.05, box))
    assert got == want and len(got) > 10000


def as_dict_pds(res):
    pairs, d, S = res
    return {(int(a), int(b), *map(int, s)): float(x) for (a, b), x, s in zip(pairs, d, S,
                                                                            strict=True)}


def test_fastns_keeps_the_grid_of_its_coords():
    from granularsap.mda import FastNS

    rng = np.random.default_rng(15)
    coords = rng.uniform(0, 10, (400, 3)).astype(np.float32)
    box = np.array([10, 10, 10, 90, 90, 90], np.float32)
    ns = FastNS(1.2, coords, box)
    for k in range(3):
        q = rng.uniform(0, 10, (20, 3)).astype(np.float32)
        res = ns.search(q)
        assert ns._cross.stats["grid"] == ("built" if k == 0 else "kept")
        want = check_neighbor(q.astype(np.float64), coords.astype(np.float64), 1.2,
                              box.astype(np.float64))
        assert sorted(map(tuple, res.get_pairs().tolist())) == sorted(k_[:2] for k_ in want)
