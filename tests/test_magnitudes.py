"""Frames mixing coordinate magnitudes from subnormal to 1e300 (issue 18, item 1
and the subnormal cutoff of item 4).

The searches scale coordinates by a power of two where squared distances would
over- or underflow.  The reference here is float64 arithmetic with an unbounded
exponent, emulated exactly with ``fractions.Fraction`` on the given positions:

    dx = rnd(x_j - x_i) (+ S * L along a periodic axis, then rnd again)
    d2 = rnd(rnd(rnd(dx*dx) + rnd(dy*dy)) + rnd(dz*dz)),  d = rnd(sqrt(d2))
    in range iff d <= cutoff (contacts: d <= rnd(rnd(r_i + r_j) + skin))

``rnd`` rounds to 53 significant bits, round half to even, whatever the
exponent; distances and vectors are then rounded once more to float64 (where
they are subnormal).  Positions are built as small integers times powers of two
in a few magnitude clusters, inside the cell along periodic axes (so that
wrapping is exact and the test does not depend on how ties are wrapped).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from granularsap import (
    ContactSearch,
    NeighborSearch,
    SweepAndPrune,
    box_overlaps,
    clump_contacts,
    neighbor_pairs,
    sphere_contacts,
)

_SETTINGS = dict(deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


# ------------------------------------------------------- exact reference


def rnd(q):
    """``q`` (a Fraction) rounded to 53 significant bits, half to even, with an
    unbounded exponent."""
    if q == 0:
        return Fraction(0)
    sign = 1 if q > 0 else -1
    q = abs(q)
    num, den = q.numerator, q.denominator
    shift = num.bit_length() - den.bit_length() - 53
    while True:
        a, b = (num, den << shift) if shift >= 0 else (num << -shift, den)
        m, r = divmod(a, b)
        if m >= 1 << 53:
            shift += 1
        elif m < 1 << 52:
            shift -= 1
        else:
            break
    if 2 * r > b or (2 * r == b and m & 1):
        m += 1
    return sign * Fraction(m) * Fraction(2) ** shift


def rnd_sqrt(q):
    """The square root of a dyadic Fraction ``q >= 0``, rounded as ``rnd``."""
    if q == 0:
        return Fraction(0)
    num, den = q.numerator, q.denominator
    assert den & (den - 1) == 0  # dyadic
    t = -(den.bit_length() - 1)  # q = num * 2**t
    if t % 2:
        num, t = num * 2, t - 1
    p = max(0, 64 - num.bit_length() // 2)
    big = num << (2 * p)
    r = math.isqrt(big)
    sticky = r * r != big
    drop = r.bit_length() - 53
    mant, rem = r >> drop, r & ((1 << drop) - 1)
    half = 1 << (drop - 1)
    if rem > half or (rem == half and (sticky or mant & 1)):
        mant += 1
    return Fraction(mant) * Fraction(2) ** (drop + t // 2 - p)


def _separation(xi, xj, shift, lengths):
    out = []
    for c in range(3):
        d = rnd(Fraction(xj[c]) - Fraction(xi[c]))
        if shift[c]:
            d = rnd(d + shift[c] * Fraction(lengths[c]))
        out.append(d)
    return out


def _d2(v):
    return rnd(rnd(rnd(v[0] * v[0]) + rnd(v[1] * v[1])) + rnd(v[2] * v[2]))


def reference(pos, thresholds, lengths=None, pbc=(False, False, False), labels=None,
              strict=False):
    """{(i, j): (d, D, S)} of every pair in range (i < j), unbounded float64.

    ``thresholds(i, j)`` is the pair's threshold as a Fraction; ``lengths`` the
    diagonal of an orthorhombic cell whose ``pbc`` axes are periodic (positions
    inside the cell along them, ranges under a quarter of every length)."""
    n = len(pos)
    images = [(-1, 0, 1) if pbc[c] else (0,) for c in range(3)]
    out = {}
    for i in range(n):
        for j in range(i + 1, n):
            if labels is not None and labels[i] == labels[j]:
                continue
            thr = thresholds(i, j)
            for s0 in images[0]:
                for s1 in images[1]:
                    for s2 in images[2]:
                        v = _separation(pos[i], pos[j], (s0, s1, s2), lengths)
                        d = rnd_sqrt(_d2(v))
                        if d < thr or (d == thr and not strict):
                            assert (i, j) not in out, "two images in range"
                            out[i, j] = (float(d), tuple(float(x) for x in v), (s0, s1, s2))
    return out


def check(result, want, quantities):
    """Compare a pairs-layout result with ``reference``'s answer, row by row."""
    res = dict(zip(quantities, result if isinstance(result, tuple) else (result,),
                   strict=True))
    pairs = res["P"]
    got = {}
    for r, (i, j) in enumerate(pairs.tolist()):
        assert i < j and (i, j) not in got
        got[i, j] = r
    assert sorted(got) == sorted(want), (sorted(set(got) ^ set(want)))[:5]
    for key, r in got.items():
        d, vec, shift = want[key]
        if "d" in res:
            assert res["d"][r] == d, (key, res["d"][r], d)
        if "D" in res:
            assert tuple(res["D"][r].tolist()) == vec, (key, res["D"][r], vec)
        if "S" in res:
            assert tuple(res["S"][r].tolist()) == shift, (key, res["S"][r], shift)


# ------------------------------------------------------------- frames

#: binary exponents of the interaction range: subnormal to near overflow
_RANGE_EXP = [-1074, -1070, -1040, -1000, -700, -300, -60, -1, 0, 2, 60, 300, 700, 1000]


@st.composite
def clustered(draw, e, n_max=14, lengths=None, pbc=(False, False, False), far=1400):
    """Positions in 1 to 3 clusters: each ``o * 2**E + k * 2**F`` (small ints
    ``o``, ``k``) with the spacing ``F`` near the range's exponent ``e`` or far
    from it, clusters up to 2**1400 times larger than the range; inside the
    cell (``lengths``) along periodic axes."""
    rows = []
    for _ in range(draw(st.integers(1, 3))):
        f = draw(st.sampled_from([e - 1, e - 2, e - 3, e - 50, e - 300, e - 700, e + 5, e + 400]))
        f = min(max(f, -1074), 1010)
        big = draw(st.sampled_from([None, f + 20, f + 45, e + min(300, far), e + min(1000, far),
                                    e + far]))
        m = draw(st.integers(1, 6))
        for _ in range(m):
            row = []
            for c in range(3):
                if pbc[c]:
                    # a grid of a sixteenth of the length, inside the cell
                    k = draw(st.integers(0, 15))
                    row.append(lengths[c] * k / 16)
                    continue
                k = draw(st.integers(-6, 6))
                x = math.ldexp(k, f)
                if big is not None and min(big, 1015) >= f:
                    o = draw(st.integers(-3, 3))
                    x = math.ldexp(o, min(big, 1015)) + x
                row.append(x)
            rows.append(row)
            if draw(st.booleans()) and len(rows) < n_max:  # a duplicate: d = 0 pairs
                rows.append(list(row))
    rows = rows[:n_max]
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def _searches(make):
    """(search, name) of every path for one maker ``make(**kw)``."""
    small = make(path="columns")
    general = make(path="columns", n_threads=2)
    general._small_max = 0
    general1 = make(path="columns", n_threads=1)
    general1._small_max = 0
    sweep = make(path="sweep", n_threads=2)
    return [(small, "small"), (general, "columns/2"), (general1, "columns/1"),
            (sweep, "sweep/2")]


@settings(max_examples=60, **_SETTINGS)
@given(st.data())
def test_neighbor_pairs_open_mixed_magnitudes(data):
    e = data.draw(st.sampled_from(_RANGE_EXP))
    cutoff = math.ldexp(data.draw(st.integers(1, 7)), e - 2)
    pos = data.draw(clustered(e))
    want = reference(pos, lambda i, j: Fraction(cutoff))
    for search, _name in _searches(lambda **kw: NeighborSearch(cutoff, quantities="PdD", **kw)):
        check(search.update(pos), want, "PdD")
    check(neighbor_pairs(pos, cutoff), want, "Pd")


@settings(max_examples=40, **_SETTINGS)
@given(st.data())
def test_neighbor_pairs_partly_periodic(data):
    e = data.draw(st.sampled_from([-1000, -300, 0, 300, 900]))
    cutoff = math.ldexp(data.draw(st.integers(1, 7)), e - 2)
    pbc = data.draw(st.sampled_from([(True, False, False), (False, True, True),
                                     (True, True, False)]))
    lengths = [math.ldexp(8, e) if p else 0.0 for p in pbc]  # cutoff < lengths / 4
    box = np.diag([ln if ln else 1.0 for ln in lengths])
    pos = data.draw(clustered(e, lengths=lengths, pbc=pbc))
    want = reference(pos, lambda i, j: Fraction(cutoff), lengths, pbc)
    for search, _name in _searches(lambda **kw: NeighborSearch(cutoff, quantities="PdDS",
                                                               **kw)):
        check(search.update(pos, box, pbc=pbc), want, "PdDS")


@settings(max_examples=40, **_SETTINGS)
@given(st.data())
def test_verlet_frames_mixed_magnitudes(data):
    """A kept list re-tested on a second frame (each moved by at most an eighth of
    the margin) equals the reference on both frames."""
    e = data.draw(st.sampled_from(_RANGE_EXP[2:-1]))
    cutoff = math.ldexp(data.draw(st.integers(1, 7)), e - 2)
    margin = math.ldexp(1, e - 3)
    pos = data.draw(clustered(e))
    move = np.array(data.draw(st.lists(st.integers(-1, 1), min_size=3 * len(pos),
                                       max_size=3 * len(pos)))).reshape(-1, 3)
    pos2 = pos + move * math.ldexp(1, e - 7)
    thr = lambda i, j: Fraction(cutoff)  # noqa: E731
    searches = [NeighborSearch(cutoff, rebuild_margin=margin, quantities="PdD", path=p,
                               n_threads=t) for p, t in (("columns", 1), ("columns", 2),
                                                         ("sweep", 1))]
    for frame in (pos, pos2):
        want = reference(frame, thr)
        for search in searches:
            check(search.update(frame), want, "PdD")


@settings(max_examples=50, **_SETTINGS)
@given(st.data())
def test_contacts_radii_and_clumps_mixed_magnitudes(data):
    """Radii and skin of several magnitudes (the thresholds up to 2**900 apart),
    with and without clump labels, on every path."""
    e = data.draw(st.sampled_from(_RANGE_EXP[1:]))
    lo = max(e - data.draw(st.sampled_from([0, 3, 60, 900])), -1074)
    pos = data.draw(clustered(e, far=1400 - (e - lo)))
    n = len(pos)
    radii = np.array([math.ldexp(data.draw(st.integers(0, 3)),
                                 data.draw(st.sampled_from([lo, e - 3]))) for _ in range(n)])
    skin = math.ldexp(data.draw(st.integers(0, 2)), lo)
    labels = np.array(data.draw(st.lists(st.integers(0, 2), min_size=n, max_size=n)))
    if not (2 * radii.min() + skin) > 0:
        radii[:] = np.maximum(radii, math.ldexp(1, lo))  # zero thresholds: see below

    def thr(i, j):
        return rnd(rnd(Fraction(radii[i]) + Fraction(radii[j])) + Fraction(skin))

    want = reference(pos, thr)
    want_l = reference(pos, thr, labels=labels)
    for search, _name in _searches(lambda **kw: ContactSearch(skin=skin, quantities="PdD",
                                                              **kw)):
        check(search.update(pos, radii), want, "PdD")
        check(search.update(pos, radii, clump_ids=labels), want_l, "PdD")
    check(sphere_contacts(pos, radii, skin=skin), want, "P")
    sp, cp = clump_contacts(pos, radii, labels, skin=skin)
    check(sp, want_l, "P")


@settings(max_examples=30, **_SETTINGS)
@given(st.data())
def test_zero_cutoff_finds_coincident_points_only(data):
    """Cutoff 0: only coincident points, also where a nonzero separation's square
    underflows."""
    e = data.draw(st.sampled_from([-1074, -1000, -600, -300, 0, 300]))
    pos = data.draw(clustered(e))
    want = reference(pos, lambda i, j: Fraction(0))
    for search, _name in _searches(lambda **kw: NeighborSearch(0.0, quantities="PdD", **kw)):
        check(search.update(pos), want, "PdD")


# ------------------------------------------------------------ regressions


def _issue_frame():
    rng = np.random.default_rng(2024)
    x = rng.uniform(0, 10, (300, 3))
    x[7] = [1e300, 0.0, 0.0]
    return x


def _brute(x, cutoff):
    d = np.sqrt(((x[:, None, :] - x[None, :, :]) ** 2).sum(-1))
    i, j = np.nonzero(np.triu(d <= cutoff, 1))
    return {(a, b): d[a, b] for a, b in zip(i.tolist(), j.tolist(), strict=True)}


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("far", [1e300, -1e300, 1.7e308, 1e200])
def test_one_point_at_1e300_among_300(far, threads):
    """Issue 18 item 1: the rescale was chosen from the far point, every squared
    distance of the others underflowed and 44,551 pairs came back (566 are in)."""
    x = _issue_frame()
    x[7, 0] = far
    with np.errstate(over="ignore", invalid="ignore"):
        want = _brute(x, 1.5)
    assert 7 not in {a for p in want for a in p}
    makers = [dict(), dict(path="sweep"), dict(rebuild_margin=0.25),
              dict(rebuild_margin=0.25, path="sweep")]
    for kw in makers:
        pairs, d = NeighborSearch(1.5, n_threads=threads, **kw).update(x)
        got = dict(zip(map(tuple, pairs.tolist()), d.tolist(), strict=True))
        assert got == want, (kw, len(got), len(want))
    pairs, d = neighbor_pairs(x, 1.5, n_threads=threads)
    assert dict(zip(map(tuple, pairs.tolist()), d.tolist(), strict=True)) == want
    assert set(map(tuple, sphere_contacts(x, 0.75, n_threads=threads).tolist())) == set(want)
    # periodic along y and z, open along x where the far point is
    box = np.diag([1.0, 10.0, 10.0])
    with np.errstate(over="ignore", invalid="ignore"):
        v = x[None, :, :] - x[:, None, :]
        v[..., 1:] -= 10.0 * np.round(v[..., 1:] / 10.0)
        dd = np.sqrt((v ** 2).sum(-1))
    want_p = set(zip(*(a.tolist() for a in np.nonzero(np.triu(dd <= 1.5, 1))), strict=True))
    for kw in makers:
        pairs = NeighborSearch(1.5, n_threads=threads, **kw).update(
            x, box, pbc=(False, True, True))[0]
        assert set(map(tuple, pairs.tolist())) == want_p and len(pairs) == len(want_p)


def test_subnormal_cutoff_with_its_lowest_bit_set():
    """Issue 18 item 4: 5e-324 / 2 rounds to 0, so a cutoff halved into radii
    found nothing at the cutoff."""
    tiny = 5e-324
    x = np.array([[0.0, 0, 0], [tiny, 0, 0], [0, 0, 1.0], [0, 0, 1.0], [3 * tiny, 0, 0]])
    for cutoff, want in ((tiny, [[0, 1], [2, 3]]), (3 * tiny, [[0, 1], [0, 4], [1, 4],
                                                                [2, 3]])):
        for kw in (dict(), dict(path="sweep"), dict(rebuild_margin=tiny)):
            pairs, d = NeighborSearch(cutoff, **kw).update(x)
            order = np.lexsort(pairs.T[::-1])
            assert pairs[order].tolist() == want, (cutoff, kw)
            dist = {(0, 1): tiny, (2, 3): 0.0, (0, 4): 3 * tiny, (1, 4): 2 * tiny}
            assert d[order].tolist() == [dist[tuple(p)] for p in want]
        strict = NeighborSearch(cutoff, include_cutoff=False).update(x)[0].tolist()
        at = [0, 1] if cutoff == tiny else [0, 4]
        assert at not in strict and [2, 3] in strict and [0, 1] in want


def test_no_common_scale_is_a_clear_error():
    """Coordinates 1e300 with a cutoff 1e-300: no power of two keeps both the
    coordinates finite and the squares at the cutoff normal."""
    x = np.array([[0.0, 0, 0], [1e-300, 0, 0], [1e300, 0, 0]])
    with pytest.raises(ValueError, match=r"positions .*1e\+300.* cutoff 1e-300"):
        neighbor_pairs(x, 1e-300)
    with pytest.raises(ValueError, match=r"radii"):
        sphere_contacts(x[:2], [1e300, 1e-300])


# ------------------------------------------------------------------ boxes


@st.composite
def _boxes(draw):
    n = draw(st.integers(0, 16))
    lows, ups = [], []
    for _ in range(n):
        lo, up = [], []
        for _c in range(3):
            e = draw(st.sampled_from([-1074, -1000, -300, 0, 2, 300, 1000]))
            a = math.ldexp(draw(st.integers(-8, 8)), e)
            side = math.ldexp(draw(st.integers(0, 8)), draw(st.sampled_from([-1074, e, 1020])))
            lo.append(a)
            up.append(a + side if math.isfinite(a + side) else a)
        lows.append(lo)
        ups.append(up)
    return (np.array(lows, dtype=np.float64).reshape(-1, 3),
            np.array(ups, dtype=np.float64).reshape(-1, 3))


def _box_brute(lower, upper):
    n = len(lower)
    return {(i, j) for i in range(n) for j in range(i + 1, n)
            if np.all(lower[i] <= upper[j]) and np.all(lower[j] <= upper[i])}


@settings(max_examples=30, **_SETTINGS)
@given(_boxes(), st.sampled_from([1, 2]))
def test_boxes_mixed_magnitudes(boxes, threads):
    """Boxes compare coordinates only (no arithmetic decides a pair): exact on
    every path with sides and places from subnormal to 1e308."""
    lower, upper = boxes
    want = _box_brute(lower, upper)
    got = box_overlaps(lower, upper, n_threads=threads)
    assert set(map(tuple, got.tolist())) == want and len(got) == len(want)
    for path in ("sequential", "parallel", "columns"):
        sap = SweepAndPrune(n_threads=threads, path=path)
        for _ in range(2):
            got = sap.update(lower, upper)
            assert set(map(tuple, np.sort(got, axis=1).tolist())) == want, path
            assert len(got) == len(want)


@pytest.mark.parametrize("where", [[1e300, 0.0, 0.0], [5.0, 5.0, -1e300]])
@pytest.mark.parametrize("kw", [dict(), dict(rebuild_margin=0.25), dict(path="sweep")])
def test_far_point_in_a_large_frame(where, kw):
    """A frame above the memory check's sampling size with one point at 1e300: the
    others' pairs are those of the frame without it, the rounding guard comes from
    the range (not every pair a candidate) and no overflow warning escapes."""
    rng = np.random.default_rng(5)
    x = rng.uniform(0, 45.0, (30000, 3))
    rest = np.delete(x, 7, axis=0)
    want = NeighborSearch(1.5, quantities="Pd").update(rest)
    x[7] = where
    search = NeighborSearch(1.5, quantities="Pd", **kw)
    got = search.update(x)
    keep = np.arange(len(x)) != 7
    remap = np.cumsum(keep) - 1
    assert not np.isin(7, got[0])
    got_p = remap[got[0]]
    a, b = np.lexsort(want[0].T[::-1]), np.lexsort(got_p.T[::-1])
    assert np.array_equal(want[0][a], got_p[b]) and np.array_equal(want[1][a], got[1][b])
    assert search.stats["candidates_tested"] is None or (
        search.stats["candidates_tested"] < 100 * len(got_p))


@settings(max_examples=60, **_SETTINGS)
@given(st.data())
def test_frame_scan_matches_numpy(data):
    """The one-pass frame scan against numpy: the first row holding a NaN or an
    inf, the largest and the smallest nonzero magnitude, the extents along each
    axis, the radii checks and the comparison with the kept radii."""
    from granularsap.search.frame import NO_RADII, scan_frame

    n = data.draw(st.integers(0, 40))
    values = st.sampled_from([0.0, -0.0, 1.0, -2.5, 3e-310, -5e-324, 1e300, -1e300,
                              math.inf, -math.inf, math.nan, 7.25, -0.125])
    x = np.array(data.draw(st.lists(values, min_size=3 * n, max_size=3 * n)),
                 float).reshape(n, 3)
    rad = np.array(data.draw(st.lists(st.sampled_from([0.0, 1.0, 2.5, -1.0, math.inf,
                                                       math.nan]), min_size=n, max_size=n)),
                   float)
    kept = rad.copy() if data.draw(st.booleans()) else np.ones(n)
    bad, hi, lo, ok, rmin, rmax, same, e0, e1, e2 = scan_frame(x, rad, kept)
    finite = np.isfinite(x).all(axis=1)
    assert bad == (int(np.argmin(finite)) if not finite.all() else -1)
    a = np.abs(x)
    seen = a[~np.isnan(a)]
    assert hi == (seen.max() if seen.size else 0.0)
    nonzero = seen[seen > 0]
    assert lo == (nonzero.min() if nonzero.size else math.inf)
    with np.errstate(invalid="ignore"):
        assert ok == bool(np.all((rad >= 0) & (rad < math.inf)))
        assert same == bool(np.array_equal(rad, kept))
    if n and not np.isnan(rad).any():
        assert (rmin, rmax) == (rad.min(), rad.max())
    if n:
        for c, e in enumerate((e0, e1, e2)):
            col = x[:, c][~np.isnan(x[:, c])]
            if col.size:
                with np.errstate(invalid="ignore", over="ignore"):
                    want = col.max() - col.min()
                assert e == want or (math.isnan(e) and math.isnan(want))
    # positions alone (``magnitudes``): the same answer for the positions
    assert scan_frame(x, NO_RADII, NO_RADII)[:3] == (bad, hi, lo)
