"""Every path of the box broad phase gives the brute-force answer (tests/oracles.py).

The paper's sweeps (``"sequential"``: Algorithm 1, ``"parallel"``: Algorithms
2-4), the column sweep (``"columns"``, granularsap/kernels/boxgrid.py) and
``"auto"`` run on the same inputs, on one and two threads, and must agree
with the oracle and so with each other: ties made exact by integer and dyadic
coordinates (faces, edges and corners that only touch), zero-size and
duplicated boxes, boxes far from the others, huge boxes among tiny ones.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from granularsap import SweepAndPrune, box_overlaps

from .oracles import brute_box_overlaps, sort_pairs

#: (path, n_threads)
CASES = [(p, t) for p in ("sequential", "parallel", "columns", "auto") for t in (1, 2)
         if not (p == "sequential" and t == 2)]


def run(path, threads, lower, upper):
    engine = SweepAndPrune(path=path, n_threads=threads)
    return engine.update(lower, upper), engine


def check(pairs, lower, upper, want=None):
    assert pairs.dtype == np.int64 and pairs.ndim == 2 and pairs.shape[1] == 2
    assert np.all(pairs[:, 0] < pairs[:, 1])
    got = sort_pairs(pairs)
    assert len(np.unique(got, axis=0)) == len(got), "a pair was reported twice"
    if want is None:
        want = brute_box_overlaps(lower, upper)
    np.testing.assert_array_equal(got, want)


def all_paths_agree(lower, upper):
    want = brute_box_overlaps(lower, upper)
    for path, threads in CASES:
        pairs, engine = run(path, threads, lower, upper)
        check(pairs, lower, upper, want)
        s = engine.stats
        assert s["candidates_tested"] >= s["pairs"] == len(pairs)
        assert s["path"] in ("sequential", "parallel", "columns")
        assert isinstance(s["path_reason"], str) and s["path_reason"]
    return want


# ------------------------------------------------------------ generated inputs

@st.composite
def grid_boxes(draw, max_n=48):
    """Boxes on an integer grid scaled by a power of two (every tie is exact), with
    optional huge boxes, far boxes, duplicates and zero sizes."""
    n = draw(st.integers(0, max_n))
    lo = draw(hnp.arrays(np.int64, (n, 3), elements=st.integers(-4, 4)))
    size = draw(hnp.arrays(np.int64, (n, 3), elements=st.integers(0, 3)))
    scale = 2.0 ** draw(st.integers(-30, 30))
    lo = lo.astype(np.float64)
    hi = lo + size
    if n and draw(st.booleans()):  # huge boxes among the others
        k = draw(st.integers(1, max(1, n // 8)))
        hi[:k] += draw(st.sampled_from([20.0, 64.0, 1e6]))
    if n > 2 and draw(st.booleans()):  # boxes far from the others
        k = draw(st.integers(1, 2))
        shift = draw(st.sampled_from([1e3, -1e6, 2.0 ** 40]))
        lo[-k:] += shift
        hi[-k:] += shift
    if n > 1 and draw(st.booleans()):  # duplicates
        lo[n // 2:] = lo[:n - n // 2]
        hi[n // 2:] = hi[:n - n // 2]
    return lo * scale, hi * scale


@settings(max_examples=60, deadline=None)
@given(grid_boxes())
def test_generated_boxes_all_paths(boxes):
    all_paths_agree(*boxes)


@settings(max_examples=25, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(0, 24), st.just(3)),
                  elements=st.sampled_from([-1.5, -0.0, 0.0, 0.5, 1.0, 1e-300, -1e300, 7.25,
                                            1e300])),
       hnp.arrays(np.float64, 3, elements=st.sampled_from([0.0, 0.25, 1.0, 1e300])))
def test_extreme_coordinates_all_paths(lower, size):
    """Signed zeros, subnormal-scale and near-overflow coordinates and sides."""
    upper = lower + size
    assert np.isfinite(upper).all()
    all_paths_agree(lower, upper)


# ------------------------------------------------------------ constructed ties

def lattice(side, cube=1.0, step=1.0):
    g = np.arange(side, dtype=np.float64) * step
    lo = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    return lo, lo + cube


def test_unit_cubes_touch_on_faces_edges_and_corners():
    """A 6^3 lattice of unit cubes: each touches its (up to) 26 neighbours exactly."""
    side = 6
    lo, hi = lattice(side)
    want = all_paths_agree(lo, hi)
    offsets = [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)
               if (a, b, c) > (0, 0, 0)]
    assert len(want) == sum(np.prod([side - abs(d) for d in o]) for o in offsets)


def test_zero_size_boxes_on_lattice_points_and_cube_corners():
    pts, _ = lattice(5)
    lo = np.concatenate([pts, pts[::7] - 1.0])
    hi = np.concatenate([pts, pts[::7]])  # unit cubes whose top corner is a point box
    all_paths_agree(lo, hi)


def test_duplicated_boxes_all_pairs():
    rng = np.random.default_rng(1)
    base = rng.integers(0, 50, (40, 3)).astype(np.float64)
    lo = np.repeat(base, 5, axis=0)
    hi = lo + 1.0
    want = all_paths_agree(lo, hi)
    assert len(want) >= 40 * 10


def test_huge_and_tiny_boxes_use_the_big_list():
    """A few huge boxes among thousands of small ones go to the big list."""
    rng = np.random.default_rng(2)
    n = 3000
    lo = rng.integers(0, 64, (n, 3)).astype(np.float64) / 2.0
    hi = lo + rng.integers(0, 3, (n, 3)) / 4.0
    hi[:12] = lo[:12] + rng.integers(8, 40, (12, 3))
    lo[12:14] = -1e6  # far away, big, and meeting nothing but each other
    hi[12:14] = -1e6 + 50.0
    want = brute_box_overlaps(lo, hi)
    for threads in (1, 2):
        pairs, engine = run("columns", threads, lo, hi)
        check(pairs, lo, hi, want)
        col = engine.stats["columns"]
        assert col["big"] == 14
        assert col["grid"][0] * col["grid"][1] > 100
    all_paths_agree(lo, hi)


@pytest.mark.parametrize("spread", [False, True])
def test_larger_random_input_many_columns(spread):
    """Close sizes take the half stencil, spread sizes the forward windows."""
    rng = np.random.default_rng(3)
    n = 4000
    lo = rng.random((n, 3)) * 12.0
    if spread:
        hi = lo + rng.random((n, 3)) * rng.choice([0.0, 0.5, 1.0], (n, 1))
    else:
        hi = lo + rng.uniform(0.4, 0.6, (n, 3))
    want = all_paths_agree(lo, hi)
    assert len(want) > n // 8
    _, engine = run("columns", 2, lo, hi)
    assert engine.stats["columns"]["stencil"] == ("forward" if spread else "half")
    assert engine.stats["columns"]["grid"][0] > 3


def test_thread_count_does_not_change_the_rows():
    """Chunks depend on the input only: even the row order is the same."""
    rng = np.random.default_rng(4)
    lo = rng.integers(0, 40, (5000, 3)).astype(np.float64)
    hi = lo + rng.integers(0, 3, (5000, 3))
    one, _ = run("columns", 1, lo, hi)
    two, _ = run("columns", 2, lo, hi)
    np.testing.assert_array_equal(one, two)


def _frames_for_order(n, big):
    rng = np.random.default_rng(14)
    lo = rng.random((n, 3)) * 1.2 * n ** (1 / 3)
    side = rng.uniform(0.5, 1.5, (n, 3))
    if big:  # boxes far above the median size: the column path's big list
        side[:big] *= 9.0
    vel = rng.uniform(-0.2, 0.2, (n, 3))
    return [(lo + f * vel, lo + f * vel + side) for f in range(3)]


@pytest.mark.parametrize("path", ["sequential", "parallel", "columns", "auto"])
@pytest.mark.parametrize("n,big", [(3000, 0), (5000, 40)])
def test_row_order_is_the_same_on_one_and_two_threads(path, n, big):
    """Every path returns the same rows in the same order on 1 and 2 threads,
    frame after frame of one engine (auto: the paper's sweep below 4096 boxes,
    the column sweep with a big list above)."""
    frames = _frames_for_order(n, big)
    got = {}
    for threads in (1, 2):
        engine = SweepAndPrune(path=path, n_threads=threads)
        got[threads] = [(engine.update(lo, hi), engine.stats["path"]) for lo, hi in frames]
        if path == "columns" or (path == "auto" and n >= 4096):
            assert engine.stats["path"] == "columns"
            assert engine.stats["columns"]["big"] == big
    for (one, p1), (two, p2) in zip(got[1], got[2], strict=True):
        assert p1 == p2
        np.testing.assert_array_equal(one, two)
    check(got[1][-1][0], *frames[-1])


# ------------------------------------------------------------ stateful engines

def moving(rng, n, frames, step=0.3):
    lo = rng.integers(0, 30, (n, 3)).astype(np.float64)
    size = rng.integers(0, 3, (n, 3)).astype(np.float64)
    vel = rng.integers(-2, 3, (n, 3)) * step
    for _ in range(frames):
        yield lo, lo + size
        lo = lo + vel


@pytest.mark.parametrize("path,threads", CASES)
def test_frames_with_moving_boxes_changing_counts_and_a_huge_box(path, threads):
    rng = np.random.default_rng(5)
    engine = SweepAndPrune(path=path, n_threads=threads)
    frames = list(moving(rng, 1500, 4))
    lo, hi = frames[-1]
    frames.append((lo[:700], hi[:700]))  # fewer boxes
    big_lo, big_hi = lo.copy(), hi.copy()
    big_lo[3] = -5.0
    big_hi[3] = 100.0  # one box over everything
    frames.append((big_lo, big_hi))
    frames.append((lo, hi))
    frames.append((lo[:1], hi[:1]))
    frames.append((np.concatenate([lo, lo[:50]]), np.concatenate([hi, hi[:50] + 0.5])))
    for f, (a, b) in enumerate(frames):
        pairs = engine.update(a, b)
        check(pairs, a, b)
        assert engine.stats["frame"] == f + 1
        assert engine.stats["candidates_tested"] >= engine.stats["pairs"]


def test_auto_alternating_paths_keep_every_frame_exact():
    """One engine switched between paths frame by frame keeps its state right."""
    rng = np.random.default_rng(6)
    engine = SweepAndPrune(n_threads=2)
    for f, (lo, hi) in enumerate(moving(rng, 2000, 6)):
        engine._path = ("columns", "parallel", None)[f % 3]
        check(engine.update(lo, hi), lo, hi)


# ------------------------------------------------------------ auto's choice

def paper_like(n, seed=0):
    rng = np.random.default_rng(seed)
    sides = rng.uniform(0.5, 1.5, (n, 3))
    world = (n / 0.35) ** (1 / 3)
    lo = rng.random((n, 3)) * (world - sides)
    return lo, lo + sides


def test_auto_records_its_choice_and_reason():
    lo, hi = paper_like(20000)
    engine = SweepAndPrune()
    engine.update(lo, hi)
    s = engine.stats
    assert s["path"] == "columns"
    assert "column" in s["path_reason"]
    assert s["columns"]["stencil"] == "half"


def test_auto_keeps_columns_for_a_wide_size_spread():
    """Sizes over 9 octaves: the forward windows keep the column sweep cheap."""
    rng = np.random.default_rng(7)
    n = 5000
    lo = rng.random((n, 3)) * 60.0
    side = 2.0 ** rng.uniform(-6, 3, (n, 1))
    engine = SweepAndPrune()
    pairs = engine.update(lo, lo + side)
    assert engine.stats["path"] == "columns"
    assert engine.stats["columns"]["spread"] > 4
    assert engine.stats["columns"]["stencil"] == "forward"
    check(pairs, lo, lo + side)


def test_auto_falls_back_when_the_grid_predicts_many_candidates(monkeypatch):
    import granularsap.api as api

    monkeypatch.setattr(api, "_AUTO_MAX_PREDICTED", 0.5)
    lo, hi = paper_like(4200)
    want = brute_box_overlaps(lo, hi)
    engine = SweepAndPrune()
    for _ in range(3):
        check(engine.update(lo, hi), lo, hi, want)
        assert engine.stats["path"] == "parallel"
        assert "predicted" in engine.stats["path_reason"]
        assert "until frame 17" in engine.stats["path_reason"]


def test_auto_falls_back_after_a_frame_with_many_candidates_then_retries(monkeypatch):
    import granularsap.api as api

    monkeypatch.setattr(api, "_AUTO_MAX_CANDIDATES", 0.01)
    monkeypatch.setattr(api, "_AUTO_RETRY", 3)
    lo, hi = paper_like(4200)
    want = brute_box_overlaps(lo, hi)
    engine = SweepAndPrune()
    paths = []
    for _ in range(6):
        check(engine.update(lo, hi), lo, hi, want)
        paths.append(engine.stats["path"])
    assert paths == ["columns", "parallel", "parallel", "parallel", "columns", "parallel"]
    engine.update(lo, hi)
    assert "candidates per box and pair in frame 5" in engine.stats["path_reason"]


def test_far_boxes_do_not_collapse_the_grid(monkeypatch):
    """Two boxes a million sides away: the grid is binned over the bulk."""
    import granularsap.api as api

    monkeypatch.setattr(api, "_SAMPLE", 256)  # the sampled range from 1024 boxes on
    lo, hi = paper_like(3000, seed=9)
    lo[:2] += 1e6
    hi[:2] += 1e6
    pairs, engine = run("columns", 2, lo, hi)
    check(pairs, lo, hi)
    nb0, nb1 = engine.stats["columns"]["grid"]
    assert nb0 * nb1 >= 25
    assert max(engine.stats["columns"]["width"]) < 10.0  # not a million / 27


def test_auto_small_inputs_take_the_paper_sweep():
    lo, hi = paper_like(100)
    engine = SweepAndPrune()
    engine.update(lo, hi)
    assert engine.stats["path"] == "parallel"
    assert "100 boxes" in engine.stats["path_reason"]


def test_forced_path_is_recorded():
    lo, hi = paper_like(500)
    for path in ("sequential", "parallel", "columns"):
        _, engine = run(path, 1, lo, hi)
        assert engine.stats["path"] == path
        assert repr(path) in engine.stats["path_reason"]


def test_box_overlaps_matches_oracle_on_auto():
    lo, hi = paper_like(3000, seed=8)
    check(box_overlaps(lo, hi), lo, hi)


def test_error_unknown_path():
    with pytest.raises(ValueError, match=r"path must be one of 'auto', 'sequential', "
                                         r"'parallel', 'columns', got 'grid'"):
        SweepAndPrune(path="grid")


def test_dense_frame_outgrows_the_region_guess():
    """About 50 partners per box in two chunks of columns, with 300 big boxes in
    two chunks: regions overflow on the first frame and run again."""
    rng = np.random.default_rng(10)
    n = 6000
    lo = rng.random((n, 3)) * 14.0
    hi = lo + rng.uniform(0.5, 1.5, (n, 3))
    hi[:300] += 6.0
    want = brute_box_overlaps(lo, hi)
    assert len(want) > 20 * n
    for threads in (1, 2):
        engine = SweepAndPrune(path="columns", n_threads=threads)
        for _ in range(2):
            check(engine.update(lo, hi), lo, hi, want)
        assert engine.stats["columns"]["big"] == 300
        assert engine.stats["columns"]["chunks"] > 1
