"""The core API across scales: cells in any units, slabs much wider than one
length unit, subnormal coordinates."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from granularsap import Cell, NeighborSearch, neighbor_pairs, sphere_contacts

# 0 - 1 direct, 0 - 2 only through the image along the periodic axis
_LINE = np.array([0.0, 1.0, 3.0])


def _points(axis):
    x = np.zeros((3, 3))
    x[:, axis] = _LINE
    return x


@pytest.mark.parametrize("scale", [1e-300, 1e-150, 1e-100, 1e-5, 1e6, 1e100, 1e150, 1e300])
@pytest.mark.parametrize("angles", [(90, 90, 90), (80, 70, 100)])
@pytest.mark.parametrize("pbc", [(True, True, True), (False, False, True), (True, False, True)])
@pytest.mark.parametrize(("path", "margin"), [("columns", 0.0), ("columns", 0.1), ("sweep", 0.1)])
def test_cell_in_any_units(scale, angles, pbc, path, margin):
    """A cell is degenerate or not by its shape only: 4e-5 or 4e6 wide cells, and
    slabs periodic along one vector, were refused (or lost pairs) before, on the
    column sweep and on the paper's sweep."""
    box = [4 * scale] * 3 + list(angles)
    cell = Cell.from_dimensions(box, pbc=pbc)
    np.testing.assert_allclose(cell.perpendicular_widths / scale,
                               Cell.from_dimensions([4, 4, 4, *angles]).perpendicular_widths,
                               rtol=1e-12)
    axis = 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        search = NeighborSearch(1.1 * scale, path=path, rebuild_margin=margin * scale)
        pairs, d = search.update(_points(axis) * scale, box, pbc=pbc)
        want, wd = neighbor_pairs(_points(axis), 1.1, box=[4, 4, 4, *angles], pbc=pbc)
    assert sorted(pairs.tolist()) == sorted(want.tolist())
    np.testing.assert_allclose(np.sort(d) / scale, np.sort(wd), rtol=1e-12)


def test_subnormal_coordinates_open():
    """math.ldexp overflowed for magnitudes below 2**-1000 (OverflowError)."""
    x = np.array([[0.0, 0, 0], [1e-323, 0, 0], [4e-323, 0, 0]])
    pairs, d = neighbor_pairs(x, 1e-323)
    assert pairs.tolist() == [[0, 1]] and d.tolist() == [1e-323]
    assert sphere_contacts(x, 5e-324).tolist() == [[0, 1]]
    search = NeighborSearch(1e-320, rebuild_margin=1e-321)
    for _ in range(2):
        assert len(search.update(x)[0]) == 3


@pytest.mark.parametrize("scale", [1e200, 1e-200])
def test_scaled_coordinates_every_output_form(scale):
    """Coordinates scaled by a power of two inside: a quantity asked for twice was
    divided twice (inf / 0), and the CSR layout raised TypeError."""
    x = np.array([[0.0, 0, 0], [1, 0, 0], [3, 0, 0]]) * scale
    p, d1, v1, d2, v2 = NeighborSearch(1.5 * scale, quantities="PdDdD").update(x)
    assert p.tolist() == [[0, 1]]
    assert d1.tolist() == d2.tolist() == [scale]
    assert v1.tolist() == v2.tolist() == [[scale, 0.0, 0.0]]
    offsets, nbr, dist = NeighborSearch(1.5 * scale, layout="csr").update(x)
    assert offsets.tolist() == [0, 1, 1, 1] and nbr.tolist() == [1]
    assert dist.tolist() == [scale]


def test_inverted_box_message_plain_floats():
    """The message showed ``lower=np.float64(2.0)`` (NumPy 2 reprs)."""
    from granularsap import box_overlaps

    lower = np.zeros((3, 3))
    upper = np.ones((3, 3))
    lower[2, 1] = 2.0
    with pytest.raises(ValueError, match=r"^lower must not exceed upper, got lower=2\.0 > "
                                         r"upper=1\.0 at box 2, axis 1$"):
        box_overlaps(lower, upper)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31), st.sampled_from([None, "ortho", "mixed"]),
       st.sampled_from([1.0, 2.0, 3.0]), st.sampled_from(["columns", "sweep", "auto"]),
       st.sampled_from([0.0, 0.5]), st.sampled_from([1, 2]))
def test_ties_on_a_lattice(seed, box, cutoff, path, margin, n_threads):
    """Integer points in an integer cell, inside, on and outside its faces: pairs at
    exactly the cutoff (1, 2, 3 = |(1, 2, 2)|) count, on every path, thread count and
    Verlet frame, as the brute force over all images says."""
    from .oracles import brute_image_pairs, sort_pairs

    rng = np.random.default_rng(seed)
    x = rng.integers(-3, 10, (30, 3)).astype(float)
    pbc = (True, False, True) if box == "mixed" else (True, True, True)
    cell = None if box is None else np.diag([6.0, 7.0, 8.0])
    want, wd = brute_image_pairs(x, cutoff, cell, pbc=pbc)
    search = NeighborSearch(cutoff, rebuild_margin=margin, path=path, n_threads=n_threads)
    for frame in (x + 0.1 * margin, x):
        pairs, d = search.update(frame, cell, pbc=pbc if cell is not None else None)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    assert np.array_equal(sort_pairs(pairs), want)
    assert np.array_equal(d[order], wd)
