"""The Sweep-and-Prune candidate list against a brute-force oracle over images.

The oracle loops over every particle pair and every lattice shift in a range
derived independently (perpendicular widths and the Euclidean bound of a cube
overlap, ``|D| <= sqrt(3) (h_p + h_q)``) and evaluates the required test
``|D_c| <= half[p] + half[q]`` on the separation written as the spec writes it.
"""

from __future__ import annotations

import doctest
import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import granularsap.sweep_candidates as scmod
from granularsap import Cell, NeighborSearch
from granularsap.kernels import grid
from granularsap.sweep_candidates import (
    MAX_SHIFT,
    ZERO_SHIFT,
    SweepCandidates,
    decode_shift,
    encode_shift,
    sweep_candidates,
)

# ---------------------------------------------------------------- oracle


def _shift_ranges(ws, half, cell, pbc):
    hmax = float(half.max()) if len(half) else 0.0
    vol = abs(np.linalg.det(cell))
    t = ws @ np.linalg.inv(cell)
    reps = []
    for c in range(3):
        if not pbc[c]:
            reps.append(range(0, 1))
            continue
        width = vol / np.linalg.norm(np.cross(cell[(c + 1) % 3], cell[(c + 2) % 3]))
        span = np.ptp(t[:, c]) if len(t) else 0.0
        m = int(np.ceil(span + np.sqrt(3.0) * 2.0 * hmax / width)) + 1
        reps.append(range(-m, m + 1))
    return reps


def _key(p, q, s):
    """One name for an image: (p, q, S) and (q, p, -S) are the same."""
    a = (p, q, s)
    b = (q, p, tuple(-v for v in s))
    return min(a, b)


def oracle(ws, half, cell, pbc, self_images, slack=0.0, spheres=False):
    """Keys of every image with ``|D_c| <= (h_p + h_q) (1 + slack) + slack``
    (with ``spheres``: ``|D| <= ...``)."""
    n = len(ws)
    cell = np.eye(3) if cell is None else np.asarray(cell, float)
    out = set()
    if n == 0:
        return out
    diff = ws[None, :, :] - ws[:, None, :]  # diff[p, q] = ws[q] - ws[p]
    thr = half[:, None] + half[None, :]
    thr = thr * (1.0 + slack) + slack
    iu = np.arange(n)
    for s in itertools.product(*_shift_ranges(ws, half, cell, pbc)):
        d = diff + s[0] * cell[0]
        d = d + s[1] * cell[1]
        d = d + s[2] * cell[2]
        if spheres:
            ok = np.sqrt(np.sum(d * d, axis=2)) <= thr
        else:
            ok = np.all(np.abs(d) <= thr[:, :, None], axis=2)
        if s == (0, 0, 0) or not self_images:
            ok[iu, iu] = False
        for p, q in zip(*np.nonzero(ok), strict=True):
            out.add(_key(int(p), int(q), s))
    return out


def entries(result):
    vstart, vstop, vb, vs = result
    out = []
    for p in range(len(vstart)):
        for e in range(vstart[p], vstop[p]):
            out.append((p, int(vb[e]), decode_shift(int(vs[e]))))
    return out


def _positive(s):
    for v in s:
        if v:
            return v > 0
    return False


def check(ws, half, cell, pbc, self_images, n_threads=None, spheres=False):
    """Run the sweep and assert everything the contract promises; returns entries."""
    ws = np.asarray(ws, float)
    half = np.asarray(half, float)
    pbc = np.asarray(pbc, bool)
    res = sweep_candidates(ws, half, cell, pbc, self_images, n_threads=n_threads,
                           spheres=spheres)
    vstart, vstop, vb, vs = res
    n = len(ws)
    assert vstart.dtype == np.int64 and vstop.dtype == np.int64
    assert vb.dtype == np.int32 and vs.dtype == np.int32
    assert vstart.shape == vstop.shape == (n,)
    assert len(vb) == len(vs)
    if n:
        assert vstart[0] == 0 and vstop[-1] == len(vb)
        assert np.all(vstop >= vstart)
        assert np.array_equal(vstart[1:], vstop[:-1])
    got = entries(res)
    for p, q, s in got:
        assert 0 <= q < n
        assert all(abs(v) <= MAX_SHIFT for v in s)
        assert all(v == 0 for v, per in zip(s, pbc, strict=True) if not per)
        # the documented orientation: S > 0 lexicographically, or S = 0 and p < q
        assert _positive(s) or (s == (0, 0, 0) and p < q)
        if p == q:
            assert self_images
    keys = [_key(p, q, s) for p, q, s in got]
    assert len(set(keys)) == len(keys), "an image reported twice"
    required = oracle(ws, half, cell, pbc, self_images, spheres=spheres)
    missing = required - set(keys)
    assert not missing, f"required candidates missing: {sorted(missing)[:5]}"
    # extras only within the rounding guard (no ghost-ghost leftovers, no far pairs)
    scale = float(np.abs(ws).max()) + (float(np.abs(cell).max()) * 8 if cell is not None
                                       else 0.0) + 1.0
    loose = oracle(ws, half, cell, pbc, self_images, slack=1e-9 * scale, spheres=spheres)
    far = set(keys) - loose
    assert not far, f"candidates that are not near-overlaps: {sorted(far)[:5]}"
    return got


def _rng(seed):
    return np.random.default_rng(seed)


def _wrap(x, cell, pbc):
    return Cell(cell, pbc).wrap(x)


# ------------------------------------------------------------ the codes


def test_shift_codes_match_the_engine():
    for s in [(0, 0, 0), (1, -1, 0), (-511, 511, 3), (511, -511, -511), (2, 0, -7)]:
        code = encode_shift(*s)
        assert code == grid.encode(*s)
        assert tuple(grid.decode(code)) == s == decode_shift(code)
    assert ZERO_SHIFT == grid.encode(0, 0, 0)
    a = np.array([-3, 0, 5])
    codes = encode_shift(a, -a, a * 2)
    assert codes.dtype == np.int32
    for k in range(3):
        assert tuple(grid.decode(int(codes[k]))) == (a[k], -a[k], 2 * a[k])
    with pytest.raises(ValueError, match="shift components"):
        encode_shift(512, 0, 0)
    with pytest.raises(TypeError):
        encode_shift(0.5, 0, 0)


def test_returned_codes_decode_as_the_engine_decodes():
    rng = _rng(1)
    cell = np.array([[3.0, 0, 0], [0.7, 3.1, 0], [-0.4, 0.5, 2.9]])
    ws = _wrap(rng.random((12, 3)) * 3, cell, True)
    vstart, vstop, vb, vs = sweep_candidates(ws, np.full(12, 1.1), cell, np.ones(3, bool),
                                             True)
    assert len(vs)
    for code in vs:
        assert tuple(grid.decode(int(code))) == decode_shift(int(code))
        assert encode_shift(*decode_shift(int(code))) == code


def test_docstring_examples():
    result = doctest.testmod(scmod, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0 and result.attempted > 0


# ------------------------------------------------------------ geometries


@pytest.mark.parametrize("seed", [0, 1])
def test_open(seed):
    rng = _rng(seed)
    ws = rng.random((60, 3)) * 6 - 3
    half = rng.random(60) * 0.8
    got = check(ws, half, None, np.zeros(3, bool), False)
    assert all(s == (0, 0, 0) for _, _, s in got)
    # an open system gives the same list whatever cell matrix is passed
    other = sweep_candidates(ws, half, 5.0 * np.eye(3), np.zeros(3, bool), True)
    assert sorted(entries(other)) == sorted(got)


@pytest.mark.parametrize("self_images", [False, True])
def test_orthorhombic(self_images):
    rng = _rng(2)
    cell = np.diag([5.0, 6.0, 7.0])
    ws = _wrap(rng.random((50, 3)) * [5, 6, 7], cell, True)
    half = rng.random(50) * 1.2
    got = check(ws, half, cell, np.ones(3, bool), self_images)
    assert any(s != (0, 0, 0) for _, _, s in got)


@pytest.mark.parametrize("spheres", [False, True])
@pytest.mark.parametrize("self_images", [False, True])
def test_triclinic(self_images, spheres):
    rng = _rng(3)
    cell = np.array([[5.0, 0, 0], [2.1, 4.6, 0], [-1.3, 1.7, 4.4]])
    ws = _wrap(rng.random((50, 3)) @ cell, cell, True)
    half = rng.random(50) * 1.3
    got = check(ws, half, cell, np.ones(3, bool), self_images, spheres=spheres)
    if spheres:  # fewer than the cubes, all of them among the cubes
        cubes = check(ws, half, cell, np.ones(3, bool), self_images)
        assert set(got) < set(cubes)


def test_triclinic_cube_corners_beyond_the_sphere_reach():
    """Cubes reach further in fractional coordinates than spheres of the same
    half-width: ghosts are chosen with the L1 norm of the inverse's columns."""
    cell = np.array([[4.0, 0, 0], [2.0, 4.0, 0], [0, 0, 4.0]])
    # q near the lower face of axis 0, p near the upper one; the cube overlap
    # is along a corner direction (|D_c| = 0.9 <= 0.5 + 0.5 on each axis)
    ws = np.array([[3.3, 0.2, 1.0], [0.4 - 0.05, 0.2 + 0.9 - 1e-3, 1.9]])
    ws = _wrap(ws, cell, True)
    check(ws, np.array([0.5, 0.5]), cell, np.ones(3, bool), False)
    rng = _rng(33)
    for _ in range(5):
        ws = _wrap(rng.random((25, 3)) @ cell, cell, True)
        check(ws, rng.random(25) * 0.9, cell, np.ones(3, bool), False)


@pytest.mark.parametrize("pbc", [(True, False, True), (False, True, False),
                                 (True, True, False), (False, False, True)])
def test_mixed_periodicity(pbc):
    rng = _rng(4)
    m = np.array([[4.5, 0, 0], [0.8, 5.0, 0], [0.6, -0.9, 4.8]])
    m[~np.array(pbc)] = 0.0
    cell = Cell(m, pbc)
    full = np.array(cell.full_matrix)
    x = rng.random((45, 3)) * 12 - 4
    ws = cell.wrap(x)
    half = rng.random(45)
    got = check(ws, half, full, np.array(pbc), True)
    assert any(s != (0, 0, 0) for _, _, s in got)


def test_small_cell_several_layers_of_self_images():
    cell = np.array([[1.0, 0, 0], [0.3, 1.2, 0], [0.2, -0.25, 0.9]])
    rng = _rng(5)
    ws = _wrap(rng.random((6, 3)) @ cell, cell, True)
    half = np.array([1.5, 0.2, 0.9, 1.1, 0.0, 1.4])
    got = check(ws, half, cell, np.ones(3, bool), True)
    assert max(max(abs(v) for v in s) for _, _, s in got) >= 3
    check(ws, half, cell, np.ones(3, bool), True, spheres=True)
    assert any(p == q for p, q, _ in got)
    # one particle alone: only its own images
    got = check(ws[:1], half[:1], cell, np.ones(3, bool), True)
    assert got and all(p == q == 0 for p, q, _ in got)
    assert check(ws[:1], half[:1], cell, np.ones(3, bool), False) == []


def test_faces_and_positions_outside_the_cell():
    cell = np.diag([4.0, 4.0, 4.0])
    x = np.array([[0.0, 0.0, 0.0], [4.0, 2.0, 2.0], [-4.0, 3.999, 0.0], [8.0, -0.001, 4.0],
                  [2.0, 2.0, 12.0], [-1e-17, 1.0, 1.0], [3.6, 0.0, 3.5]])
    ws = _wrap(x, cell, True)
    check(ws, np.full(len(ws), 0.5), cell, np.ones(3, bool), False)
    check(ws, np.full(len(ws), 2.1), cell, np.ones(3, bool), True)
    tri = np.array([[4.0, 0, 0], [1.0, 4.0, 0], [1.0, 1.0, 4.0]])
    ws = _wrap(x @ np.linalg.inv(np.diag([4.0, 4, 4])) @ tri, tri, True)
    check(ws, np.full(len(ws), 0.6), tri, np.ones(3, bool), False)


def test_ties_on_a_dyadic_grid():
    """|D_c| exactly h_p + h_q: touching cubes are required candidates."""
    g = np.arange(4) * 1.0
    ws = np.array(list(itertools.product(g, g, g)))
    cell = 4.0 * np.eye(3)
    got = check(ws, np.full(len(ws), 0.5), cell, np.ones(3, bool), False)
    # each point touches its 26 lattice neighbours (through the faces too)
    assert len(got) == len(ws) * 26 // 2
    got = check(ws, np.full(len(ws), 0.25), cell, np.ones(3, bool), False)
    assert got == []


def test_zero_half_widths_and_duplicates():
    cell = 2.0 * np.eye(3)
    ws = np.array([[0.0, 0, 0], [0.0, 0, 0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0],
                   [0.0, 1.0, 0.5]])
    half = np.zeros(len(ws))
    got = check(ws, half, cell, np.ones(3, bool), True)
    assert sorted(got) == [(0, 1, (0, 0, 0)), (2, 3, (0, 0, 0)), (2, 4, (0, 0, 0)),
                           (3, 4, (0, 0, 0))]
    check(ws, np.full(len(ws), 0.5), cell, np.ones(3, bool), True)
    check(ws, np.zeros(len(ws)), None, np.zeros(3, bool), False)


@pytest.mark.parametrize("spheres", [False, True])
def test_labels_drop_pairs_of_one_body(spheres):
    rng = _rng(11)
    cell = np.array([[2.5, 0, 0], [0.4, 2.6, 0], [0.3, -0.2, 2.4]])
    ws = _wrap(rng.random((30, 3)) @ cell, cell, True)
    half = rng.random(30) * 0.9
    labels = rng.integers(0, 6, 30)
    full = check(ws, half, cell, np.ones(3, bool), True, spheres=spheres)
    got = entries(sweep_candidates(ws, half, cell, np.ones(3, bool), True, spheres=spheres,
                                   labels=labels))
    assert sorted(got) == sorted(e for e in full if labels[e[0]] != labels[e[1]])
    assert len(got) < len(full)
    with pytest.raises(ValueError, match="labels"):
        sweep_candidates(ws, half, cell, np.ones(3, bool), True, labels=labels[:-1])
    with pytest.raises(TypeError, match="labels"):
        sweep_candidates(ws, half, cell, np.ones(3, bool), True, labels=labels * 0.5)


def test_empty_and_single():
    for pbc in (np.zeros(3, bool), np.ones(3, bool)):
        res = sweep_candidates(np.empty((0, 3)), np.empty(0), 3.0 * np.eye(3), pbc, True)
        assert [len(a) for a in res] == [0, 0, 0, 0]
        res = sweep_candidates(np.zeros((1, 3)), np.zeros(1), 3.0 * np.eye(3), pbc, True)
        assert [len(a) for a in res] == [1, 1, 0, 0]


# ------------------------------------------------------------ hypothesis


@st.composite
def dyadic_frames(draw):
    n = draw(st.integers(1, 14))
    pbc = np.array(draw(st.lists(st.booleans(), min_size=3, max_size=3)))
    lengths = np.array([draw(st.sampled_from([1.0, 1.5, 2.0, 3.0])) for _ in range(3)])
    tilt = draw(st.booleans())
    cell = np.diag(lengths)
    if tilt:
        cell[1, 0] = draw(st.sampled_from([-0.5, 0.25, 0.5]))
        cell[2, 0] = draw(st.sampled_from([-0.25, 0.0, 0.5]))
        cell[2, 1] = draw(st.sampled_from([-0.5, 0.0, 0.25]))
    steps = st.integers(0, 15)
    x = np.array([[draw(steps) * 0.25 - 0.5 for _ in range(3)] for _ in range(n)])
    half = np.array([draw(st.sampled_from([0.0, 0.125, 0.25, 0.5, 0.75])) for _ in range(n)])
    if draw(st.booleans()) and n > 1:  # duplicates
        x[1] = x[0]
    self_images = draw(st.booleans())
    spheres = draw(st.booleans())
    return x, half, cell, pbc, self_images, spheres


@settings(max_examples=60, deadline=None)
@given(dyadic_frames())
def test_dyadic_ties_and_degenerate_frames(frame):
    x, half, cell, pbc, self_images, spheres = frame
    ws = Cell(cell, pbc).wrap(x) if pbc.any() else x
    check(ws, half, cell if pbc.any() else None, pbc, self_images, spheres=spheres)


# ------------------------------------------------------------ threads, state


def test_one_and_two_threads_give_the_same_list():
    rng = _rng(7)
    cell = np.array([[6.0, 0, 0], [1.0, 6.0, 0], [0.5, 0.5, 6.0]])
    ws = _wrap(rng.random((400, 3)) @ cell, cell, True)
    half = rng.random(400) * 0.7
    a = sweep_candidates(ws, half, cell, np.ones(3, bool), True, n_threads=1)
    b = sweep_candidates(ws, half, cell, np.ones(3, bool), True, n_threads=2)
    for u, v in zip(a, b, strict=True):
        assert np.array_equal(u, v)
    c = SweepCandidates(path="sequential").build(ws, half, cell, np.ones(3, bool), True)
    for u, v in zip(a, c, strict=True):
        assert np.array_equal(u, v)
    check(ws[:120], half[:120], cell, np.ones(3, bool), True, n_threads=2)


def test_layout_in_several_chunks(monkeypatch):
    """The row layout split into per-thread chunks gives the same arrays."""
    rng = _rng(13)
    cell = np.array([[3.0, 0, 0], [0.6, 3.2, 0], [0.3, -0.4, 2.9]])
    ws = _wrap(rng.random((90, 3)) @ cell, cell, True)
    half = rng.random(90) * 1.4
    one = sweep_candidates(ws, half, cell, np.ones(3, bool), True, n_threads=2)
    monkeypatch.setattr(scmod, "_CHUNK_PAIRS", 1)
    sc = SweepCandidates(n_threads=2)
    many = sc.build(ws, half, cell, np.ones(3, bool), True)
    assert sc.stats["layout_chunks"] == 2
    for u, v in zip(one, many, strict=True):
        assert np.array_equal(u, v)
    check(ws, half, cell, np.ones(3, bool), True, n_threads=2)
    check(ws[:40], half[:40], cell, np.ones(3, bool), False, n_threads=2, spheres=True)


def test_stateful_frames_and_stats():
    rng = _rng(8)
    cell = 5.0 * np.eye(3)
    sc = SweepCandidates(n_threads=1)
    for n in (40, 40, 55):
        ws = _wrap(rng.random((n, 3)) * 5, cell, True)
        half = rng.random(n) * 0.8
        got = sc.build(ws, half, cell, np.ones(3, bool), False)
        ref = sweep_candidates(ws, half, cell, np.ones(3, bool), False)
        for u, v in zip(got, ref, strict=True):
            assert np.array_equal(u, v)
        assert sc.stats["n"] == n and sc.stats["candidates"] == len(got[2])
        assert sc.stats["boxes"] == n + sc.stats["ghosts"]


@pytest.mark.parametrize("spheres", [False, True])
def test_feeds_the_engines_narrow_phase(spheres):
    """Distances tested on the candidates give NeighborSearch's pairs with every
    image (the engine's own column sweep)."""
    rng = _rng(9)
    cell = np.array([[4.0, 0, 0], [0.9, 4.2, 0], [-0.6, 0.8, 3.9]])
    ws = _wrap(rng.random((70, 3)) @ cell, cell, True)
    cutoff = 2.3
    vstart, vstop, vb, vs = sweep_candidates(ws, np.full(70, cutoff / 2), cell,
                                             np.ones(3, bool), True, spheres=spheres)
    mine = set()
    for p, q, s in entries((vstart, vstop, vb, vs)):
        d = ws[q] - ws[p]
        d = d + s[0] * cell[0]
        d = d + s[1] * cell[1]
        d = d + s[2] * cell[2]
        if np.sqrt(d @ d) <= cutoff:
            mine.add(_key(p, q, s))
    i, j, S = NeighborSearch(cutoff, periodic_images="all", quantities="ijS").update(
        ws, box=cell)
    theirs = {_key(int(a), int(b), tuple(int(v) for v in s))
              for a, b, s in zip(i, j, S, strict=True)}
    assert mine == theirs and len(mine) > 100


# ------------------------------------------------------------ bad input


def test_bad_input():
    ws = np.zeros((3, 3))
    cell = np.eye(3)
    pbc = np.ones(3, bool)
    with pytest.raises(ValueError, match="half"):
        sweep_candidates(ws, [0.1, -0.1, 0.1], cell, pbc, False)
    with pytest.raises(ValueError, match="ws"):
        sweep_candidates(np.full((3, 3), np.nan), np.zeros(3), cell, pbc, False)
    with pytest.raises(ValueError, match="ws"):
        sweep_candidates(np.zeros((3, 2)), np.zeros(3), cell, pbc, False)
    with pytest.raises(ValueError, match="cell"):
        sweep_candidates(ws, np.zeros(3), np.zeros((3, 3)), pbc, False)
    with pytest.raises(ValueError, match="cell"):
        sweep_candidates(ws, np.zeros(3), None, pbc, False)
    with pytest.raises(ValueError, match="pbc"):
        sweep_candidates(ws, np.zeros(3), cell, [1, 1, 1], False)
    with pytest.raises(TypeError, match="self_images"):
        sweep_candidates(ws, np.zeros(3), cell, pbc, 1)
    with pytest.raises(TypeError, match="spheres"):
        sweep_candidates(ws, np.zeros(3), cell, pbc, True, spheres=None)
    with pytest.raises(ValueError, match="lattice shifts.*larger cell"):
        sweep_candidates(ws, np.full(3, 400.0), cell, pbc, True)
    far = np.array([[0.0, 0, 0], [5000.0, 0, 0], [0.5, 0.5, 0.5]])
    with pytest.raises(ValueError, match="wrapped"):
        sweep_candidates(far, np.zeros(3), cell, pbc, True)
    with pytest.raises(ValueError, match="non-degenerate"):
        sweep_candidates(ws, np.zeros(3), np.diag([1.0, 0.0, 1.0]), pbc, False)


def test_zero_rows_of_open_axes_are_completed():
    rng = _rng(14)
    m = np.array([[3.0, 0, 0], [0.0, 0.0, 0.0], [0.5, 0.4, 3.2]])
    pbc = np.array([True, False, True])
    full = np.array(Cell(m, pbc).full_matrix)
    ws = Cell(m, pbc).wrap(rng.random((30, 3)) * 4)
    half = rng.random(30) * 0.7
    a = sweep_candidates(ws, half, m, pbc, True)
    b = sweep_candidates(ws, half, full, pbc, True)
    for u, v in zip(a, b, strict=True):
        assert np.array_equal(u, v)
    check(ws, half, full, pbc, True)


def _spec_component(wq, wp, s, cell, c):
    d = wq - wp
    d = d + s[0] * cell[0, c]
    d = d + s[1] * cell[1, c]
    return d + s[2] * cell[2, c]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rounding_ties_are_kept(seed):
    """Partners at the last float64 for which the required test still holds
    (|D_c| == h_p + h_q, or the largest value below it, on every axis),
    across faces of a triclinic cell with large non-dyadic coordinates: the
    guard keeps them all."""
    rng = _rng(100 + seed)
    cell = np.array([[1000.3, 0, 0], [101.7, 998.1, 0], [-57.3, 83.9, 1003.7]])
    n = 40
    # near the faces, corners and edges, so that most partners are images
    frac = rng.random((n, 3)) * 4e-4 + rng.choice([0.0, 1.0 - 4e-4], size=(n, 3))
    base = _wrap(frac @ cell, cell, True)
    half = rng.random(2 * n) * 0.37 + 0.1
    sign = np.where(frac > 0.5, 1.0, -1.0)
    thr = half[:n] + half[n:]
    partner, shifts = Cell(cell, True).wrap(base + sign * thr[:, None], return_shifts=True)
    for i in range(n):
        for c in range(3):
            sgn = sign[i, c]
            y = partner[i, c]
            for _ in range(200):  # inward until the test holds
                if abs(_spec_component(y, base[i, c], shifts[i], cell, c)) <= thr[i]:
                    break
                y = np.nextafter(y, -sgn * np.inf)
            for _ in range(200):  # outward while it still holds
                z = np.nextafter(y, sgn * np.inf)
                if abs(_spec_component(z, base[i, c], shifts[i], cell, c)) > thr[i]:
                    break
                y = z
            partner[i, c] = y
    ws = np.concatenate([base, partner])
    got = check(ws, half, cell, np.ones(3, bool), False)
    check(ws, half, cell, np.ones(3, bool), False, spheres=True)
    keys = {_key(p, q, s) for p, q, s in got}
    for i in range(n):
        s = tuple(int(v) for v in shifts[i])
        assert _key(i, n + i, s) in keys
    assert (np.abs(shifts).sum(axis=1) > 0).sum() >= 3 * n // 4


def _spec_norm(wq, wp, s, cell):
    return np.sqrt(sum(_spec_component(wq[c], wp[c], s, cell, c) ** 2 for c in range(3)))


@pytest.mark.parametrize("seed", [0, 1])
def test_rounding_ties_are_kept_with_spheres(seed):
    """Partners at the last float64 for which |D| <= h_p + h_q still holds,
    along one axis across a face: ``spheres=True`` keeps them all."""
    rng = _rng(200 + seed)
    cell = np.array([[1000.3, 0, 0], [101.7, 998.1, 0], [-57.3, 83.9, 1003.7]])
    n = 40
    frac = rng.random((n, 3)) * 4e-4 + rng.choice([0.0, 1.0 - 4e-4], size=(n, 3))
    base = _wrap(frac @ cell, cell, True)
    half = rng.random(2 * n) * 0.37 + 0.1
    axis = rng.integers(0, 3, n)
    sign = np.where(frac[np.arange(n), axis] > 0.5, 1.0, -1.0)
    thr = half[:n] + half[n:]
    step = np.zeros((n, 3))
    step[np.arange(n), axis] = sign * thr
    partner, shifts = Cell(cell, True).wrap(base + step, return_shifts=True)
    for i in range(n):
        c, sgn = axis[i], sign[i]
        y = partner[i].copy()
        for _ in range(200):
            if _spec_norm(y, base[i], shifts[i], cell) <= thr[i]:
                break
            y[c] = np.nextafter(y[c], -sgn * np.inf)
        for _ in range(200):
            z = y.copy()
            z[c] = np.nextafter(y[c], sgn * np.inf)
            if _spec_norm(z, base[i], shifts[i], cell) > thr[i]:
                break
            y = z
        partner[i] = y
    ws = np.concatenate([base, partner])
    got = check(ws, half, cell, np.ones(3, bool), False, spheres=True)
    keys = {_key(p, q, s) for p, q, s in got}
    for i in range(n):
        assert _key(i, n + i, tuple(int(v) for v in shifts[i])) in keys
    assert (np.abs(shifts).sum(axis=1) > 0).sum() >= n // 2


def test_feeds_the_engines_contacts_with_clumps():
    """Polydisperse radii and clump ids: the narrow test on the candidates gives
    ContactSearch's contacts with every image."""
    from granularsap import ContactSearch

    rng = _rng(12)
    cell = np.array([[5.0, 0, 0], [1.1, 4.7, 0], [0.4, -0.9, 4.9]])
    n = 80
    ws = _wrap(rng.random((n, 3)) @ cell, cell, True)
    radii = np.clip(rng.lognormal(-1.0, 0.6, n), 0.05, 1.2)
    labels = rng.integers(0, 25, n)
    vstart, vstop, vb, vs = sweep_candidates(ws, radii, cell, np.ones(3, bool), True,
                                             spheres=True, labels=labels)
    mine = set()
    for p, q, s in entries((vstart, vstop, vb, vs)):
        d = ws[q] - ws[p]
        d = d + s[0] * cell[0]
        d = d + s[1] * cell[1]
        d = d + s[2] * cell[2]
        if np.sqrt(d @ d) <= radii[p] + radii[q]:
            mine.add(_key(p, q, s))
    i, j, S = ContactSearch(periodic_images="all", quantities="ijS").update(
        ws, radii, box=cell, clump_ids=labels)
    theirs = {_key(int(a), int(b), tuple(int(v) for v in s))
              for a, b, s in zip(i, j, S, strict=True)}
    assert mine == theirs and len(mine) > 50
