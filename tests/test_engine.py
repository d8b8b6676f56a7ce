"""The box broad phase against the brute-force oracle (tests/oracles.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from granularsap import SweepAndPrune, box_overlaps

from .oracles import brute_box_overlaps, sort_pairs


def _box_overlaps_path(lower, upper, *, path=None, n_threads=None, partitions=None,
                       axes="auto"):
    """``box_overlaps`` with the algorithm path forced, and a number of partitions
    independent of the thread count (the engine's test override)."""
    engine = SweepAndPrune(axes=axes, n_threads=n_threads, path=path or "auto")
    engine._partitions = partitions
    return engine.update(lower, upper)

PATHS = [("sequential", 1, None), ("parallel", 1, 3), ("parallel", 2, 2), ("parallel", 2, 5)]


def check_pairs(pairs, lower, upper):
    assert pairs.dtype == np.int64
    assert pairs.ndim == 2 and pairs.shape[1] == 2
    assert np.all(pairs[:, 0] < pairs[:, 1])
    got = sort_pairs(pairs)
    assert len(np.unique(got, axis=0)) == len(got), "duplicate pairs"
    want = brute_box_overlaps(lower, upper)
    np.testing.assert_array_equal(got, want)


def random_boxes(rng, n, grid=None, side=0.2, dtype=np.float64):
    if grid:
        lo = rng.integers(0, grid, size=(n, 3)).astype(dtype)
        hi = lo + rng.integers(0, 3, size=(n, 3)).astype(dtype)
    else:
        lo = rng.random((n, 3)).astype(dtype)
        hi = lo + (rng.random((n, 3)) * side).astype(dtype)
    return lo, hi


@pytest.mark.parametrize("path,threads,parts", PATHS)
@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("n", [0, 1, 2, 3, 17, 200, 1500])
def test_random_boxes_equal_oracle(path, threads, parts, seed, n):
    rng = np.random.default_rng(seed)
    lo, hi = random_boxes(rng, n, grid=(None, 6)[seed % 2])
    pairs = _box_overlaps_path(lo, hi, path=path, n_threads=threads, partitions=parts)
    check_pairs(pairs, lo, hi)


@pytest.mark.parametrize("threads", [None, 1, 2])
def test_public_function_matches_oracle(threads):
    rng = np.random.default_rng(42)
    lo, hi = random_boxes(rng, 700, side=0.1)
    check_pairs(box_overlaps(lo, hi, n_threads=threads), lo, hi)


box_arrays = st.integers(0, 40).flatmap(
    lambda n: st.tuples(
        hnp.arrays(np.int64, (n, 3), elements=st.integers(-4, 4)),
        hnp.arrays(np.int64, (n, 3), elements=st.integers(0, 3)),
    )
)


@given(box_arrays, st.sampled_from([np.float32, np.float64]), st.sampled_from(PATHS))
def test_integer_grid_ties(arrays, dtype, path):
    """Integer coordinates force equal endpoints, touching faces and zero-size boxes."""
    lo_i, size = arrays
    lo = lo_i.astype(dtype)
    hi = (lo_i + size).astype(dtype)
    pairs = _box_overlaps_path(lo, hi, path=path[0], n_threads=path[1], partitions=path[2])
    check_pairs(pairs, lo, hi)


@given(hnp.arrays(np.float64, st.tuples(st.integers(0, 30), st.just(3)),
                  elements=st.sampled_from([-1.5, -0.0, 0.0, 0.5, 1.0, 1e-300, -1e300, 7.25])),
       st.sampled_from(PATHS))
def test_signed_zero_and_extreme_values(lo, path):
    """-0.0 and +0.0 are the same coordinate; huge and tiny magnitudes sort correctly."""
    hi = lo.copy()
    hi[::2] += 1.0
    pairs = _box_overlaps_path(lo, hi, path=path[0], n_threads=path[1], partitions=path[2])
    check_pairs(pairs, lo, hi)


def test_touching_faces_count():
    lo = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0000001, 0, 0]])
    hi = lo + 1.0
    pairs = box_overlaps(lo, hi)
    np.testing.assert_array_equal(sort_pairs(pairs), [[0, 1]])


def test_identical_boxes_all_pairs():
    lo = np.zeros((50, 3))
    hi = np.ones((50, 3))
    pairs = box_overlaps(lo, hi)
    assert len(pairs) == 50 * 49 // 2
    check_pairs(pairs, lo, hi)


def test_zero_size_boxes_on_one_point():
    lo = np.full((30, 3), 2.5)
    pairs = box_overlaps(lo, lo.copy())
    assert len(pairs) == 30 * 29 // 2


def test_non_contiguous_and_float32_inputs():
    rng = np.random.default_rng(3)
    big = rng.random((400, 6))
    lo = big[::2, :3]
    hi = lo + big[::2, 3:] * 0.2
    assert not lo.flags.c_contiguous
    check_pairs(box_overlaps(lo, hi), lo, hi)
    lo32 = np.asfortranarray(lo.astype(np.float32))
    hi32 = np.asfortranarray(hi.astype(np.float32))
    check_pairs(box_overlaps(lo32, hi32), lo32, hi32)


def test_empty_results_are_typed():
    for n in (0, 1):
        pairs = box_overlaps(np.zeros((n, 3)), np.ones((n, 3)))
        assert pairs.shape == (0, 2) and pairs.dtype == np.int64


def test_thread_count_does_not_change_result():
    rng = np.random.default_rng(9)
    lo, hi = random_boxes(rng, 3000, grid=20)
    ref = sort_pairs(box_overlaps(lo, hi, n_threads=1))
    for t in (2,):
        np.testing.assert_array_equal(sort_pairs(box_overlaps(lo, hi, n_threads=t)), ref)
    np.testing.assert_array_equal(
        sort_pairs(_box_overlaps_path(lo, hi, path="sequential", n_threads=1)), ref)


# ---------------------------------------------------------------- stateful engine

def moving_frames(rng, n, frames, side=0.05, step=0.01):
    lo = rng.random((n, 3))
    size = rng.random((n, 3)) * side
    vel = (rng.random((n, 3)) - 0.5) * step
    for _ in range(frames):
        yield lo, lo + size
        lo = lo + vel
        out = (lo < 0) | (lo > 1)
        vel[out] *= -1


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("axes", ["auto", (0, 1), "zx"])
def test_update_over_moving_frames_equals_fresh_call(threads, axes):
    rng = np.random.default_rng(5)
    engine = SweepAndPrune(axes=axes, n_threads=threads)
    for lo, hi in moving_frames(rng, 800, 8):
        pairs = engine.update(lo, hi)
        check_pairs(pairs, lo, hi)
        assert engine.stats["pairs"] == len(pairs)


def test_stats_report_phases_and_dispersion():
    rng = np.random.default_rng(6)
    engine = SweepAndPrune(n_threads=2)
    for lo, hi in moving_frames(rng, 5000, 4):
        engine.update(lo, hi)
    s = engine.stats
    for key in ("sort", "candidates", "pairing", "total"):
        assert s["seconds"][key] >= 0.0
    assert len(s["axes"]) == 2
    assert set(s["dispersion"]) == set(s["axes"])
    assert s["candidates_tested"] >= s["pairs"]
    assert s["frame"] == 4
    # temporal coherence: later frames are balanced
    assert max(s["dispersion"].values()) < 0.1


def test_plane_collapse_swaps_axes_and_stays_exact():
    """Every box collapses onto the plane x = 0.5: the engine swaps x out of the sweep."""
    rng = np.random.default_rng(7)
    n = 3000
    centre = rng.random((n, 3))
    half = 0.002
    engine = SweepAndPrune(axes="auto", n_threads=2)
    for t in np.linspace(0.0, 1.0, 8):
        c = centre.copy()
        c[:, 0] = 0.5 + (centre[:, 0] - 0.5) * (1.0 - t)
        lo, hi = c - half, c + half
        check_pairs(engine.update(lo, hi), lo, hi)
    assert engine.stats["swaps"] >= 1
    assert 0 not in engine.stats["axes"]


def test_number_of_boxes_may_change_between_updates():
    rng = np.random.default_rng(8)
    engine = SweepAndPrune()
    for n in (100, 300, 0, 5, 300):
        lo, hi = random_boxes(rng, n)
        check_pairs(engine.update(lo, hi), lo, hi)


# ---------------------------------------------------------------- errors

def test_error_nan():
    lo = np.zeros((3, 3))
    lo[1, 2] = np.nan
    with pytest.raises(ValueError, match=r"lower must be finite, got NaN or inf in row 1"):
        box_overlaps(lo, np.ones((3, 3)))


def test_error_inf():
    hi = np.ones((3, 3))
    hi[2, 0] = np.inf
    with pytest.raises(ValueError, match=r"upper must be finite"):
        box_overlaps(np.zeros((3, 3)), hi)


def test_error_shape():
    with pytest.raises(ValueError, match=r"lower must have shape \(n, 3\), got \(10, 2\)"):
        box_overlaps(np.zeros((10, 2)), np.ones((10, 2)))


def test_error_mismatched_lengths():
    with pytest.raises(ValueError, match=r"lower and upper must have the same number of rows"):
        box_overlaps(np.zeros((4, 3)), np.ones((5, 3)))


def test_error_lower_greater_than_upper():
    lo = np.zeros((4, 3))
    hi = np.ones((4, 3))
    hi[3, 1] = -1.0
    with pytest.raises(ValueError, match=r"lower must not exceed upper.*box 3, axis 1"):
        box_overlaps(lo, hi)


def test_error_dtype():
    with pytest.raises(TypeError, match=r"lower must be an array of real numbers"):
        box_overlaps(np.array([["a", "b", "c"]]), np.ones((1, 3)))


def test_error_axes():
    with pytest.raises(ValueError, match=r"axes must be 'auto' or two distinct axes"):
        SweepAndPrune(axes=(0, 0))
    with pytest.raises(ValueError, match=r"axes must be 'auto' or two distinct axes"):
        SweepAndPrune(axes="xq")


def test_error_threads():
    with pytest.raises(ValueError, match=r"n_threads must be between 1 and"):
        box_overlaps(np.zeros((2, 3)), np.ones((2, 3)), n_threads=0)
    with pytest.raises(TypeError, match=r"n_threads must be an int or None"):
        SweepAndPrune(n_threads=1.5)


@pytest.mark.parametrize("path,threads,parts", PATHS)
def test_coordinates_near_the_float_range(path, threads, parts):
    """Extents that overflow to inf must not break the third-axis shards."""
    lo = np.array([[0, 0, -1e308], [0, 0, 1e308 - 1], [0, 0, 0.0], [-1e308, 5, 5]])
    hi = lo.copy()
    hi[:, 2] = [1e308, 1e308, 1.0, 1e308]
    hi[3] = [1e308, 6, 1e308]
    pairs = _box_overlaps_path(lo, hi, path=path, n_threads=threads, partitions=parts)
    check_pairs(pairs, lo, hi)


def test_error_swap_threshold():
    with pytest.raises(ValueError, match=r"swap_threshold must be positive, got 0"):
        SweepAndPrune(swap_threshold=0)


def test_error_too_many_boxes(monkeypatch):
    import granularsap.api as api

    monkeypatch.setattr(api, "MAX_BOXES", 3)
    with pytest.raises(ValueError, match=r"at most 3 boxes are supported, got 4"):
        box_overlaps(np.zeros((4, 3)), np.ones((4, 3)))


def test_nbytes_reports_working_memory():
    rng = np.random.default_rng(2)
    engine = SweepAndPrune()
    lo, hi = random_boxes(rng, 5000)
    engine.update(lo, hi)
    assert 60 * 5000 < engine.nbytes < 400 * 5000
    assert engine.staging_nbytes >= 16 * engine.stats["pairs"]
