"""Ties decided on the given positions plus an integer image shift (issue 18, item 2).

Every path of the particle engine must answer like the one arithmetic of
docs/cells.md ("Arithmetic"): for the pair ``i < j`` and the integer shift
``S`` relative to the positions as given,

    dx = (x[j, 0] - x[i, 0]) + S0 * cell[0, 0] + S1 * cell[1, 0] + S2 * cell[2, 0]

(added in that order; likewise dy, dz), ``d = sqrt(dx*dx + dy*dy + dz*dz)`` and
``d <= cutoff`` (``< `` with ``include_cutoff=False``), or ``d <= (r_i + r_j) +
skin`` for contacts.  The oracle below is that arithmetic written in plain
numpy, every candidate shift enumerated; the frames hold many pairs exactly at
the threshold in those coordinates, in non-dyadic and triclinic cells, with
particles several cell lengths outside the cell (so that wrapping rounds).
"""

from __future__ import annotations

import itertools

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import granularsap
from granularsap import ContactSearch, NeighborSearch

# ------------------------------------------------------------------- cells
CELLS = {
    # the issue's example: a cubic box of 6.1 (not dyadic)
    "cubic6.1": (np.diag([6.1, 6.1, 6.1]), (True, True, True)),
    "ortho10/3": (np.diag([10 / 3, 3.7, 4.3]), (True, True, True)),
    "dyadic": (np.diag([6.0, 6.5, 7.25]), (True, True, True)),
    # images summing several cell vectors
    "triclinic": (np.array([[6.1, 0.0, 0.0], [2.3, 5.9, 0.0], [-1.7, 1.1, 6.3]]),
                  (True, True, True)),
    "mixed": (np.array([[6.1, 0.0, 0.0], [1.3, 5.7, 0.0], [0.0, 0.0, 6.7]]),
              (True, False, True)),
}


# ------------------------------------------------------------------ oracle
def _sep(x, i, j, cell, s):
    """The agreed separation of pairs (i, j) through the integer shifts ``s``
    (broadcast): ``(x_j - x_i) + S0 a + S1 b + S2 c`` per component, added in that
    order."""
    s = np.asarray(s, dtype=np.int64)
    out = []
    for c in range(3):
        v = x[j, c] - x[i, c]
        v = v + s[..., 0] * cell[0, c]
        v = v + s[..., 1] * cell[1, c]
        v = v + s[..., 2] * cell[2, c]
        out.append(v)
    return np.stack(out, axis=-1)


def brute(x, cell, pbc, thr, *, strict=False, images="minimum", labels=None):
    """{(i, j, S): (d, D)} of every pair image in range by the agreed arithmetic.

    ``thr(i, j)`` is the threshold of the pair (numpy-broadcast over ``j``);
    shifts are enumerated around the nearest image (three layers, more with
    ``images="all"``)."""
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    pbc = np.asarray(pbc, bool)
    hinv = np.linalg.inv(cell)
    out = {}
    if n == 0:
        return out
    idx = np.arange(n)
    tmax = max(float(np.max(thr(i, idx))) for i in range(n))
    widths = abs(np.linalg.det(cell)) / np.linalg.norm(
        np.cross(cell[[1, 2, 0]], cell[[2, 0, 1]]), axis=1)
    m = [int(np.ceil(tmax / widths[c])) + 1 if (images == "all" and pbc[c]) else
         (1 if pbc[c] else 0) for c in range(3)]
    offs = np.array(list(itertools.product(*[range(-mc, mc + 1) for mc in m])), np.int64)
    for i in range(n):
        j = np.arange(i if images == "all" else i + 1, n)
        if labels is not None:
            j = j[labels[j] != labels[i]]
        if not len(j):
            continue
        f = (x[j] - x[i]) @ hinv
        base = np.where(pbc, -np.round(f), 0).astype(np.int64)
        shifts = base[:, None, :] + offs[None, :, :]  # (len(j), m, 3)
        jj = np.broadcast_to(j[:, None], shifts.shape[:2])
        dv = _sep(x, i, jj, cell, shifts)
        d = np.sqrt(dv[..., 0] * dv[..., 0] + dv[..., 1] * dv[..., 1] + dv[..., 2] * dv[..., 2])
        t = np.broadcast_to(np.asarray(thr(i, j), dtype=np.float64)[:, None]
                            if np.ndim(thr(i, j)) else thr(i, j), d.shape)
        ok = d < t if strict else d <= t
        if j[0] == i:  # a particle's own images: S and -S are one image, S != 0
            s0 = shifts[0]
            nz = s0 != 0
            first = np.where(nz.any(axis=1), s0[np.arange(len(s0)), nz.argmax(axis=1)], 0)
            ok[0] &= first > 0
        for a, k in zip(*np.nonzero(ok), strict=True):
            out[(i, int(j[a]), tuple(int(v) for v in shifts[a, k]))] = (d[a, k], dv[a, k])
    return out


def engine(search, x, box, pbc, radii=None, labels=None):
    """{(i, j, S): (d, D)} of the engine's answer (quantities 'PdDS')."""
    if radii is None:
        p, d, dv, s = search.update(x, box, pbc=pbc)
    else:
        p, d, dv, s = search.update(x, radii, box, pbc=pbc, clump_ids=labels)
    out = {}
    for k in range(len(p)):
        key = (int(p[k, 0]), int(p[k, 1]), tuple(int(v) for v in s[k]))
        assert key not in out, key
        out[key] = (d[k], dv[k])
    return out


def assert_same(got, want, what=""):
    missing = sorted(set(want) - set(got))
    extra = sorted(set(got) - set(want))
    assert not missing and not extra, (what, f"missing {missing[:5]} ({len(missing)})",
                                       f"extra {extra[:5]} ({len(extra)})")
    for key, (d, dv) in want.items():
        gd, gv = got[key]
        # the returned distance and vector follow the same arithmetic, bit for bit
        assert gd == d, (what, key, gd, d)
        assert np.array_equal(gv, dv), (what, key, gv, dv)


# ------------------------------------------------------------------ frames
def tie_frame(cell, pbc, cutoff, n_ties, rng, *, out=3.0, n_random=0):
    """Positions holding at least ``n_ties`` pairs exactly at ``cutoff`` by the
    agreed arithmetic, one end or both up to ``out`` cell lengths outside the
    cell, reached through shifts of several cell vectors; plus random points.
    Returns (x, number of exact ties built)."""
    pbc = np.asarray(pbc, bool)
    dirs = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.6, 0.8, 0], [0, 0.6, 0.8],
                     [0.8, 0, -0.6], [-0.48, 0.6, 0.64]])
    pts = []
    ties = 0
    tries = 0
    while ties < n_ties:
        tries += 1
        assert tries < 200 * n_ties, "could not build ties"
        f = rng.uniform(-out, 1.0 + out, 3)
        f[~pbc] = rng.uniform(0, 1, np.count_nonzero(~pbc))
        xi = f @ cell
        u = dirs[rng.integers(len(dirs))] * rng.choice([-1.0, 1.0])
        s = np.where(pbc, rng.integers(-3, 4, 3), 0)
        xj = xi + cutoff * u - s @ cell
        pair = np.array([xi, xj])
        dv = _sep(pair, 0, 1, cell, s[None, :])[0]
        d = np.sqrt(dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2])
        if d == cutoff:
            pts.extend(pair)
            ties += 1
    if n_random:
        f = rng.uniform(-out, 1.0 + out, (n_random, 3))
        f[:, ~pbc] = rng.uniform(0, 1, (n_random, np.count_nonzero(~pbc)))
        pts.extend(f @ cell)
    x = np.array(pts)
    return x[rng.permutation(len(x))], ties


def n_exact(want, cutoff):
    return sum(d == cutoff for d, _ in want.values())


def _neighbor(cutoff, **kw):
    kw.setdefault("quantities", "PdDS")
    return NeighborSearch(cutoff, **kw)


def _contacts(**kw):
    kw.setdefault("quantities", "PdDS")
    return ContactSearch(**kw)


# ----------------------------------------------------------- the issue's case
def test_issue_example_box_6_1_ties_at_1_5():
    """A box of 6.1, 214 exact ties at 1.5 with one end or both wrapped: every tie
    is found, on the small-frame path and the general one."""
    cell, pbc = CELLS["cubic6.1"]
    rng = np.random.default_rng(18)
    x, ties = tie_frame(cell, pbc, 1.5, 214, rng)
    want = brute(x, cell, pbc, lambda i, j: 1.5)
    assert n_exact(want, 1.5) >= 214
    for small in (True, False):
        search = _neighbor(1.5, n_threads=1)
        if not small:
            search._small_max = 0
        assert_same(engine(search, x, cell, pbc), want, f"small={small}")


# ---------------------------------------------------------- every path, cutoff
PATHS = ["small", "columns", "sweep", "verlet", "verlet-sweep", "levels"]


def _search_for(path, n_threads, *, cutoff=None, images="minimum", strict=False):
    kw = dict(n_threads=n_threads, periodic_images=images, include_cutoff=not strict)
    if path in ("sweep", "verlet-sweep"):
        kw["path"] = "sweep"
    else:
        kw["path"] = "columns"
    if path.startswith("verlet"):
        kw["rebuild_margin"] = 0.3
    search = _neighbor(cutoff, **kw) if cutoff is not None else _contacts(**kw)
    if path != "small":
        search._small_max = 0
    if path == "levels":
        search._levels = 0.5  # two column levels split at this radius
    return search


@pytest.mark.parametrize("name", sorted(CELLS))
@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("n_threads", [1, 2])
def test_cutoff_ties_every_path(name, path, n_threads):
    cell, pbc = CELLS[name]
    rng = np.random.default_rng([18, len(name), n_threads])
    cutoff = 1.5
    x, _ = tie_frame(cell, pbc, cutoff, 60, rng, n_random=60)
    want = brute(x, cell, pbc, lambda i, j: cutoff)
    assert n_exact(want, cutoff) >= 60
    search = _search_for(path, n_threads, cutoff=cutoff)
    assert_same(engine(search, x, cell, pbc), want, (name, path))
    if path == "small":
        assert search.stats["threads"] == 1
    strict = brute(x, cell, pbc, lambda i, j: cutoff, strict=True)
    search = _search_for(path, n_threads, cutoff=cutoff, strict=True)
    assert_same(engine(search, x, cell, pbc), strict, (name, path, "strict"))


@pytest.mark.parametrize("name", ["cubic6.1", "triclinic"])
@pytest.mark.parametrize("n_threads", [1, 2])
def test_verlet_frames_follow_the_given_positions(name, n_threads):
    """A Verlet list re-tested over frames whose particles jump by whole cell
    vectors (no motion in the cell, the wrap shifts change) and move a little."""
    cell, pbc = CELLS[name]
    rng = np.random.default_rng([5, n_threads])
    x, _ = tie_frame(cell, pbc, 1.5, 50, rng, n_random=40)
    for path in ("verlet", "verlet-sweep"):
        search = _search_for(path, n_threads, cutoff=1.5)
        frames = [x]
        for _ in range(3):
            jump = np.where(np.asarray(pbc), rng.integers(-4, 5, (len(x), 3)), 0)
            frames.append(x + jump @ cell)  # the same frame, other wrap shifts
        frames.append(x + rng.uniform(-0.05, 0.05, x.shape))
        rebuilt = []
        for k, xf in enumerate(frames):
            want = brute(xf, cell, pbc, lambda i, j: 1.5)
            assert_same(engine(search, xf, cell, pbc), want, (name, path, k))
            rebuilt.append(search.stats["rebuilt"])
        assert not all(rebuilt[1:]), rebuilt  # some frames re-tested the kept list


@pytest.mark.parametrize("path", ["columns", "verlet"])
@pytest.mark.parametrize("n_threads", [1, 2])
def test_all_images_ties(path, n_threads):
    """periodic_images='all' in a cell narrower than twice the cutoff: images of a
    pair (and a particle's own images) summing several cell vectors."""
    cell = np.array([[2.9, 0.0, 0.0], [0.7, 3.1, 0.0], [-0.4, 0.9, 3.3]])
    pbc = (True, True, True)
    rng = np.random.default_rng([7, n_threads])
    x, _ = tie_frame(cell, pbc, 2.25, 12, rng, out=2.0, n_random=6)
    want = brute(x, cell, pbc, lambda i, j: 2.25, images="all")
    assert n_exact(want, 2.25) >= 12
    search = _search_for(path, n_threads, cutoff=2.25, images="all")
    assert_same(engine(search, x, cell, pbc), want, path)


# ---------------------------------------------------------------- contacts
@pytest.mark.parametrize("name", ["cubic6.1", "triclinic", "mixed"])
@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("n_threads", [1, 2])
def test_contact_ties_every_path(name, path, n_threads):
    cell, pbc = CELLS[name]
    rng = np.random.default_rng([11, len(name), n_threads])
    skin = 0.25
    radius = 0.625  # (0.625 + 0.625) + 0.25 == 1.5: uniform radii, exact ties
    x, _ = tie_frame(cell, pbc, 1.5, 40, rng, n_random=40)
    rad = np.full(len(x), radius)
    want = brute(x, cell, pbc, lambda i, j: (rad[i] + rad[j]) + skin)
    assert n_exact(want, 1.5) >= 40
    search = _search_for(path, n_threads)
    search.skin = skin
    assert_same(engine(search, x, cell, pbc, radii=rad), want, (name, path, "uniform"))
    # varied radii: pairs at exactly 1.5 whose radii sum to 1.25 in either order
    choices = np.array([0.3, 0.45, 0.625, 0.8, 0.95])
    rad = choices[rng.integers(len(choices), size=len(x))]
    labels = rng.integers(0, len(x) // 2, len(x))
    want = brute(x, cell, pbc, lambda i, j: (rad[i] + rad[j]) + skin)
    search = _search_for(path, n_threads)
    search.skin = skin
    assert_same(engine(search, x, cell, pbc, radii=rad), want, (name, path, "varied"))
    want = brute(x, cell, pbc, lambda i, j: (rad[i] + rad[j]) + skin, labels=labels)
    search = _search_for(path, n_threads)
    search.skin = skin
    assert_same(engine(search, x, cell, pbc, radii=rad, labels=labels), want,
                (name, path, "clumps"))


# --------------------------------------------------------------- properties
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), name=st.sampled_from(sorted(CELLS)),
       path=st.sampled_from(PATHS), cutoff=st.sampled_from([0.7, 1.1, 1.5, 1.6]),
       out=st.sampled_from([0.0, 1.0, 4.0]))
def test_ties_property(seed, name, path, cutoff, out):
    cell, pbc = CELLS[name]
    rng = np.random.default_rng(seed)
    x, _ = tie_frame(cell, pbc, cutoff, 15, rng, out=out, n_random=int(rng.integers(0, 40)))
    want = brute(x, cell, pbc, lambda i, j: cutoff)
    search = _search_for(path, int(rng.integers(1, 3)), cutoff=cutoff)
    assert_same(engine(search, x, cell, pbc), want, (name, path))


def test_one_shot_functions_follow_the_arithmetic():
    cell, pbc = CELLS["triclinic"]
    rng = np.random.default_rng(3)
    x, _ = tie_frame(cell, pbc, 1.5, 40, rng)
    want = brute(x, cell, pbc, lambda i, j: 1.5)
    pairs, d = granularsap.neighbor_pairs(x, 1.5, box=cell)
    got = {(int(a), int(b)) for a, b in pairs}
    assert got == {(i, j) for i, j, _ in want}
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        pairs2, d2 = granularsap.neighbor_pairs(x, 1.5, box=cell)
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(pairs, pairs2) and np.array_equal(d, d2)


# -------------------------------------------------------------------- dask
def test_dask_domains_follow_the_arithmetic():
    pytest.importorskip("dask.dataframe")
    pytest.importorskip("distributed")
    gdask = pytest.importorskip("granularsap.dask")
    cell, pbc = CELLS["triclinic"]
    rng = np.random.default_rng(21)
    x, _ = tie_frame(cell, pbc, 1.5, 80, rng, n_random=80)
    want = brute(x, cell, pbc, lambda i, j: 1.5)
    assert n_exact(want, 1.5) >= 80
    for domains in (2, (2, 2, 1)):
        df = gdask.neighbor_pairs(x, 1.5, cell=cell, domains=domains).compute(
            scheduler="threads")
        got = {(int(i), int(j)): float(d) for i, j, d in df[["i", "j", "distance"]]
               .itertuples(index=False)}
        assert set(got) == {(i, j) for i, j, _ in want}, domains
        for (i, j, _), (d, _) in want.items():
            assert got[i, j] == d
