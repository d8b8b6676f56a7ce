"""Stateful neighbour and contact searches for particles over a sequence of frames.

:class:`NeighborSearch` (pairs with ``d <= cutoff``) and :class:`ContactSearch`
(pairs with ``d <= r_i + r_j + skin``, optional rigid-clump labels) are the
engine every particle function of granularsap goes through: the one-shot
functions (``neighbor_pairs``, ``sphere_contacts``, ``clump_contacts``), the
MDAnalysis and ASE drop-ins, the trajectory pipeline and the benchmark are
conveniences over them.

Between calls a search keeps what the frames allow (see ``kernels/grid.py``
for the algorithm):

* every buffer: wrapped positions, the column order, the Verlet list and the
  output arrays are allocated once and reused while the particle count and
  the output size allow;
* the column order of the last build: the next build sorts from it, so a
  frame whose particles moved a little sorts in close to linear time;
* a Verlet list: the pairs within the range plus ``rebuild_margin``.  While
  no particle has moved more than ``rebuild_margin / 2`` since the list was
  built (and the cell, the particle count, the radii and the labels are the
  same), a frame only re-tests the list.  This is the "skin" of LAMMPS's
  ``neighbor`` command and of ASE's ``NeighborList``; it is called
  ``rebuild_margin`` here because ``skin`` already means the contact
  distance added to ``r_i + r_j``.

Every frame's answer equals a fresh one-shot call exactly: the same pair set
and the same float64 distances, bit for bit, whether the frame rebuilt or not
and whatever the thread count.
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np

from . import _memory
from ._numba import jit, num_threads
from ._validate import as_coords, as_scalar, as_vector, check_n_threads
from .cell import Cell
from .geometry import FrameCell
from .identity import PairIdentity, as_ids
from .kernels import grid, query

__all__ = ["ContactSearch", "NeighborSearch"]

_QUANTITIES = "Pijd DS".replace(" ", "")
_LAYOUTS = ("pairs", "csr")
_PATHS = ("auto", "columns", "sweep")
#: ``path="auto"`` takes the paper's sweep where the column plan predicts more
#: candidates per pair and per particle than these, on at least _SWEEP_MIN_N
#: particles (measured: docs/engine.md, "Two paths, chosen per build")
_SWEEP_CPP = 1000.0
_SWEEP_PER_PARTICLE = 200.0
_SWEEP_MIN_N = 50000
_IMAGES = ("minimum", "all")
#: relative guard on the Verlet range against rounding (the exact test decides)
_GUARD = 64 * np.finfo(np.float64).eps
#: particles per chunk of parallel work (chunk boundaries never depend on threads)
_CHUNK = 2048
_MAX_CHUNKS = 1024
_MAX_BINS = 1 << 16
_NO_BIG = np.zeros(0, np.uint8)
_NO_ENTRIES = np.zeros(0, np.int64)
#: ``grid.small_frame``'s ``fill`` of a whole frame (count, then fill what fits)
_COUNT = (-1, True)
_NO_RADII = np.zeros(0)
#: below this many particles one thread runs (a parallel region costs more)
_PARALLEL_MIN = 20000
#: frames of up to this many particles (no Verlet margin, minimum image) are
#: built by one serial kernel (``grid.small_frame``)
_SMALL_MAX = 20000
#: the power-of-two scale of a frame keeps |coordinates| below 2**_POS_EXP, the
#: interaction range below 2**_RANGE_EXP and the smallest pair threshold at or
#: above 2**_THR_EXP (its square normal, 53 bits), and with a zero threshold every
#: nonzero coordinate difference at or above 2**_DIFF_EXP (its square nonzero)
_POS_EXP = 1000
_RANGE_EXP = 480
_THR_EXP = -480
_DIFF_EXP = -530
#: scaled distances below this may come from squares that underflowed: they are
#: recomputed row by row (``_Search._exact_small``)
_TINY_D = 2.0 ** -480
#: a frame is "far" where the coordinate-relative guard would exceed this fraction
#: of the range (an open axis holds coordinates ~1e11 ranges away or more)
_FAR = 2.0 ** -10


def _magnitudes(x):
    """(largest |x|, smallest nonzero |x|) of ``(n, 3)`` positions; (0, inf) if none.

    The frame scan's kernel (one compiled signature for both)."""
    scan = _scan_frame(np.ascontiguousarray(x, dtype=np.float64), _NO_RADII, _NO_RADII)
    return scan[1], scan[2]


@jit
def _scan_frame(x, rad, kept):
    """One pass over a frame's positions and radii: (first row of ``x`` with a NaN
    or an inf, or -1; ``_magnitudes(x)``; whether every radius is finite and
    non-negative; the smallest and the largest radius; whether ``rad`` equals
    ``kept`` value for value; the extent of ``x`` along each axis, the largest
    coordinate less the smallest, or 0 without particles)."""
    n = x.shape[0]
    bad = -1
    hi = 0.0
    lo = np.inf
    lo0 = lo1 = lo2 = np.inf
    hi0 = hi1 = hi2 = -np.inf
    for i in range(n):
        for c in range(x.shape[1]):
            a = abs(x[i, c])
            if not a < np.inf and bad < 0:
                bad = i
            hi = a if a > hi else hi
            if a > 0.0 and a < lo:
                lo = a
        v = x[i, 0]
        lo0 = v if v < lo0 else lo0
        hi0 = v if v > hi0 else hi0
        v = x[i, 1]
        lo1 = v if v < lo1 else lo1
        hi1 = v if v > hi1 else hi1
        v = x[i, 2]
        lo2 = v if v < lo2 else lo2
        hi2 = v if v > hi2 else hi2
    ok = True
    rmin = np.inf
    rmax = -np.inf
    m = rad.shape[0]  # n, or 0 to scan positions only (_magnitudes)
    same = kept.shape[0] == m
    for i in range(m):
        r = rad[i]
        ok = ok & (r >= 0.0) & (r < np.inf)
        rmin = r if r < rmin else rmin
        rmax = r if r > rmax else rmax
        if same:
            same = r == kept[i]
    if n == 0:
        return bad, hi, lo, ok, rmin, rmax, same, 0.0, 0.0, 0.0
    return bad, hi, lo, ok, rmin, rmax, same, hi0 - lo0, hi1 - lo1, hi2 - lo2


def _check_half_width(cs, reach_max, what):
    """Refuse a minimum-image frame whose largest range ``reach_max`` (named
    ``what``) exceeds half the narrowest perpendicular width of the periodic cell
    ``cs`` (a ``FrameCell``): several images of a pair would be in range."""
    widths = cs.widths
    # the narrowest periodic axis (the one the message names as the smallest)
    for c in cs.narrowest:
        if reach_max > 0.5 * widths[c] * (1.0 + 1e-12):
            raise ValueError(
                f"{what} {reach_max:.17g} exceeds half the smallest perpendicular cell "
                f"width {0.5 * widths[c]:.17g} (width {widths[c]:.17g} across cell vector "
                f"{c}); several periodic images of a pair would be in range. Use a larger "
                "cell (replicate it) or a smaller range, or periodic_images='all' to get "
                "every image with its shift")


def _far_scale(rng, width):
    """The length a frame's coordinate rounding is compared with to call it "far":
    the range, or without one (a zero cutoff) the narrowest periodic width."""
    return rng if rng > 0 else width


def _exp2(v):
    """``e`` with ``2**(e - 1) <= v < 2**e`` (``math.frexp``), for ``v > 0``."""
    return math.frexp(v)[1]


def _frame_scale(big, fine, rng, thr_min, what, range_name, thr_name):
    """Binary exponent ``k`` of the frame's scale ``2**k``: 0 where no scaling is
    needed, else the one nearest 0 that keeps every coordinate (at most ``big``)
    finite with room to spare, the squares of in-range distances (up to ``rng``)
    finite and those at the smallest pair threshold ``thr_min`` normal; with a
    zero threshold (``thr_min == 0``) also the square of every nonzero coordinate
    difference nonzero (``fine``: the smallest nonzero coordinate, the grid of
    all of them).  ValueError naming the arguments where no power of two does."""
    k_hi, k_lo = 10 ** 6, -10 ** 6
    if big > 0:
        k_hi = _POS_EXP - _exp2(big)
    if rng > 0:
        k_hi = min(k_hi, _RANGE_EXP - _exp2(rng))
    if thr_min > 0:
        k_lo = _THR_EXP + 1 - _exp2(thr_min)
    elif math.isfinite(fine):
        k_lo = _DIFF_EXP - max(_exp2(fine) - 53, -1074)
    if k_lo <= 0 <= k_hi:
        return 0
    if k_lo <= k_hi:
        return k_lo if k_lo > 0 else k_hi
    if thr_min > 0 and rng > 0 and _RANGE_EXP - _exp2(rng) < k_lo:
        raise ValueError(
            f"{range_name} {rng!r} and the smallest pair threshold {thr_min!r} "
            f"({thr_name}) are more than 2**{_RANGE_EXP - _THR_EXP - 2} apart: no "
            "power-of-two scale of the frame keeps both the squared distances at the "
            "largest range finite and those at the smallest one normal; split the "
            "search by size")
    if thr_min > 0:
        raise ValueError(
            f"positions up to {big!r} in magnitude and {what} {thr_min!r} are more "
            f"than 2**{_POS_EXP - _THR_EXP - 1} apart: no power-of-two scale of the frame "
            f"keeps the coordinates finite and the squared distances at {what} normal; "
            "move the frame's origin nearer the particles or use a larger range")
    raise ValueError(
        f"with a zero {what} only coincident points pair, but positions up to {big!r} "
        f"in magnitude and nonzero coordinates as small as {fine!r} are too far apart "
        "for any power-of-two scale to keep the coordinates finite and every nonzero "
        "squared separation nonzero")


def _check_quantities(quantities):
    if not isinstance(quantities, str) or not quantities:
        raise TypeError(f"quantities must be a non-empty string such as 'Pd' or 'ijd', "
                        f"got {quantities!r}")
    bad = [q for q in quantities if q not in _QUANTITIES]
    if bad:
        raise ValueError(f"unknown quantity {bad[0]!r} in quantities {quantities!r}; choose "
                         "from 'P' (pairs (k, 2)), 'i', 'j', 'd' (distance), "
                         "'D' (vector from i to j), 'S' (lattice shift)")
    return quantities


def _square_bound(thr, strict):
    """Largest double ``x2`` with ``sqrt(x2) <= thr`` (``< thr`` if strict), rounded
    square roots: ``d2 <= x2`` is then exactly the test on ``d = sqrt(d2)``."""
    def ok(v):
        d = math.sqrt(v)
        return d < thr or (not strict and d == thr)

    if thr < 0 or (strict and thr == 0):
        return -1.0
    x2 = thr * thr
    while not ok(x2):
        x2 = math.nextafter(x2, -math.inf)
    while math.isfinite(up := math.nextafter(x2, math.inf)) and ok(up):
        x2 = up
    return x2


def _octave16(v):
    """``v`` rounded to the nearest power of two of a sixteenth octave, ``2**(k /
    16)``, for the cost model's volumes (0, inf and NaN as they are)."""
    if not 0.0 < v < math.inf:
        return v
    return 2.0 ** (round(16.0 * math.log2(v)) / 16.0)


def _level_split(rad, rmax, reach, n, volume):
    """Radius up to which particles are "small" on a two-level column grid, or None
    for one level.

    Cost model of one frame, per particle: a visit of a stencil column costs
    about as much as ten candidates (setting up the window and leaving its
    loops).  Small particles pair among themselves on columns one range
    ``w = 2 r + reach`` wide (5 visits, about ``4.5 rho w^3`` candidates), each
    large one visits a full stencil of the range ``R = 2 rmax + reach``
    (``(2 ceil(R / w) + 1)^2`` visits, about ``rho (2 R + w)^2 2 R``
    candidates).  The split is the radius quantile of least cost, kept only if
    it saves a quarter.
    """
    if n < 1000 or not volume > 0 or not rmax > 0:
        return None
    rho = n / volume
    big_range = 2.0 * rmax + reach
    visit = 10.0

    def cost(r_c, n_big):
        w = 2.0 * r_c + reach
        small = 4.5 * rho * w ** 3 + 5 * visit
        layers = math.ceil(big_range / w)
        large = rho * (2.0 * big_range + w) ** 2 * 2.0 * big_range + (
            (2 * layers + 1) ** 2 * visit)
        return small * (n - n_big) + large * n_big

    try:  # (a cost figure only: a range whose powers overflow takes one level)
        single = cost(rmax, 0)
    except OverflowError:
        return None
    best, choice = single, None
    sorted_r = np.sort(rad)
    for qtl in (0.5, 0.7, 0.8, 0.9, 0.95, 0.98, 0.99):
        r_c = float(sorted_r[int(qtl * (n - 1))])
        if not 0.0 < r_c < rmax:
            continue
        n_big = n - int(np.searchsorted(sorted_r, r_c, side="right"))
        try:
            c = cost(r_c, n_big)
        except OverflowError:
            continue
        if c < best:
            best, choice = c, r_c
    return choice if best < single * 0.75 else None


def _predict_cpp(occ, n_stencil, n_stencil_big, widths, span, volume, rad, skin, reach,
                 rmax, r_small):
    """Candidates the column sweep will test per pair it finds, predicted from the
    column plan before the sweep runs (a deterministic function of the frame).

    Candidates: every particle of a column meets the particles of its stencil
    columns (``occ`` of its own column each, the local density) inside a
    window ``2 (2 r + reach) / w_2`` of the sweep axis, its own column forward
    only; with two levels the large ones walk the full wide stencil with the
    largest window.  Pairs: the same local density over the column volume
    times the mean volume of a pair's range sphere, ``4/3 pi E[(a_i + a_j)^3]
    = 4/3 pi (2 m3 + 6 m1 m2)`` from the moments of ``a = r + skin / 2``.
    Returns (candidates per pair, candidates per particle), or (0, 0) without
    particles or volume.
    """
    n = len(rad)
    if n == 0 or not volume > 0:
        return 0.0, 0.0
    s2 = float((occ * occ).sum())

    def window(r):
        return min(1.0, 2.0 * (2.0 * r + reach) / widths[2] / span[2])

    if r_small is None:
        per = (n_stencil + 0.5) * window(rmax)
    else:
        n_big = int(np.count_nonzero(rad > r_small))
        per = ((n - n_big) * (n_stencil + 0.5) * window(r_small)
               + n_big * n_stencil_big * window(rmax)) / n
    cand = s2 * per
    # plain reductions, not BLAS (np.dot): BLAS threads would spin on the
    # cores the parallel kernels are about to use
    a = rad + 0.5 * skin
    a2 = a * a
    m1 = float(a.sum()) / n
    m2 = float(a2.sum()) / n
    m3 = float((a2 * a).sum()) / n
    sphere = 4.0 / 3.0 * math.pi * (2.0 * m3 + 6.0 * m1 * m2)
    pairs = 0.5 * s2 * len(occ) / volume * sphere
    if not pairs > 0:
        return math.inf, cand / n
    return cand / pairs, cand / n


def _exact_bound(rad, skin, strict):
    """(uniform, x2): whether every pair has one threshold ``2 r + skin``, and then
    the squared bound that decides it exactly (``_square_bound``)."""
    uniform = bool(rad.min() == rad.max())
    if not uniform:
        return False, 0.0
    return True, _square_bound(float(rad[0]) + float(rad[0]) + skin, strict)


class _Search:
    """What NeighborSearch and ContactSearch share: state, rebuilds, outputs."""

    #: frames of up to this many particles without a Verlet margin take the
    #: serial two-call path (``_small``); tests set 0 to force the general one
    _small_max = _SMALL_MAX
    _cell_memo = None
    _small_scratch = None
    #: the band's coordinate extent of a frame far beyond the range (``_build``)
    _far_ext = None
    #: ``_scan_frame`` of the positions and radii of the call under way (``update``),
    #: or None; and what the frame kept from it (``_frame``)
    _scan = None
    _scan_now = None
    #: the radii the last build kept (``_rad``) and a count of their changes
    _rad = None
    _rad_version = 0
    _square_memo = (None, None)
    _small_reason = (-1, None)

    def __init__(self, *, rebuild_margin, quantities, layout, n_threads, periodic_images,
                 include_cutoff, path, identity=False):
        self.rebuild_margin = as_scalar(rebuild_margin, "rebuild_margin")
        self.quantities = _check_quantities(quantities)
        if layout not in _LAYOUTS:
            raise ValueError(f"layout must be one of {', '.join(map(repr, _LAYOUTS))}, "
                             f"got {layout!r}")
        self.layout = layout
        if periodic_images not in _IMAGES:
            raise ValueError(f"periodic_images must be 'minimum' or 'all', got "
                             f"{periodic_images!r}")
        self.periodic_images = periodic_images
        if not isinstance(identity, (bool, np.bool_)):
            raise TypeError(f"identity must be True or False, got {identity!r}")
        if identity and layout != "pairs":
            raise ValueError(f"identity=True needs layout='pairs' (rows of pairs to follow), "
                             f"got layout={layout!r}")
        self.identity = bool(identity)
        #: what the kernels compute: the quantities asked for, and the lattice
        #: shifts that identity with every periodic image compares
        self._computed = self.quantities
        if identity and periodic_images == "all" and "S" not in self.quantities:
            self._computed += "S"
        self._tracker = (PairIdentity(shifts=periodic_images == "all") if identity
                         else None)
        self._id_call = None
        #: two sets of output buffers that alternate between calls (the arrays a
        #: call returns stay valid until the call after next); the last set
        #: that holds a finished call's result
        self._out_sets = [{"cap": 0}, {"cap": 0}]
        self._out_last = 1
        self._out_now = 0
        if not isinstance(include_cutoff, (bool, np.bool_)):
            raise TypeError(f"include_cutoff must be True or False, got {include_cutoff!r}")
        self.include_cutoff = bool(include_cutoff)
        self.n_threads = check_n_threads(n_threads)
        if path not in _PATHS:
            raise ValueError(f"path must be one of {', '.join(map(repr, _PATHS))}, got {path!r}")
        self.path = path
        self._sweeper = None
        self.stats = {}
        self._frames = 0
        self._rebuilds = 0
        self._key = None
        self._n = -1
        self._out_cap = 0
        self._perm = None
        #: two column levels for widely spread radii (direct frames): True chooses
        #: by cost, False never, a radius forces that split
        self._levels = True

    def _scan_inputs(self, positions, rad):
        """The finiteness check of ``positions`` (``as_coords``'s, same message), the
        checks of ``rad`` (float64, one per row: ``as_radii``'s) and what the frame
        needs of both, in one pass (``_scan_frame``): (-1, largest |x|, smallest
        nonzero |x|, smallest radius, largest radius, True, whether the radii
        equal the kept ones, the extents of the positions along x, y and z),
        for ``_frame``."""
        kept = self._rad if self._rad is not None else _NO_RADII
        scan = _scan_frame(positions, rad, kept)
        if scan[0] >= 0:
            raise ValueError(f"positions must be finite, got NaN or inf in row {scan[0]}")
        if not scan[3]:
            as_radii(rad, len(rad))  # raises what is wrong
        return scan[:3] + (scan[4], scan[5], scan[3], scan[6] and kept is self._rad,
                           scan[7:10])

    # ------------------------------------------------------------- buffers
    def _alloc_particles(self, n):
        if self._n == n:
            return
        self._n = n
        self._t = np.empty((n, 3))
        self._k = np.empty((n, 3), np.int64)
        self._w = np.empty((n, 3))
        self._ts = np.empty((n, 3))
        self._ws = np.empty((n, 3))
        self._tz = np.empty(n)
        self._xs = np.empty(n)
        self._ys = np.empty(n)
        self._zs = np.empty(n)
        self._hist = np.empty((0, 0), np.int64)
        self._rs = np.empty(n)
        self._ls = np.empty(n, np.int64)
        self._m = np.zeros(n, np.int64)  # image jumps since the build, packed
        self._ks = np.zeros((n, 3), np.int64)
        self._col = np.empty(n, np.int64)
        self._perm = None
        self._perm_buf = np.empty(n, np.int64)
        self._vstart = np.empty(n, np.int64)
        self._vstop = np.empty(n, np.int64)

    def _outputs_begin(self):
        """Point the output buffers at the set the last finished call did not use:
        every kernel of this call writes there."""
        self._out_now = 1 - self._out_last
        self._use_outputs(self._out_sets[self._out_now])

    def _outputs_done(self, copy):
        self._out_last = self._out_now
        if copy and self._tracker is not None:
            self._tracker.detach()

    def _use_outputs(self, buf):
        if "p" not in buf:
            buf.update(p=np.empty((0, 2), np.int64), d=np.empty(0), v=np.empty((0, 3)),
                       s=np.empty((0, 3), np.int64))
        self._out_cap = buf["cap"]
        self._out_p, self._out_d, self._out_v, self._out_s = buf["p"], buf["d"], buf["v"], buf["s"]
        self._out_e = buf.get("e", _NO_ENTRIES)

    def _alloc_output(self, total):
        """Output buffers of this call (its set) for ``total`` pairs."""
        q = self._computed
        buf = self._out_sets[self._out_now]
        if total <= buf["cap"] and "p" in buf:
            self._use_outputs(buf)
            return
        cap = max(1024, total + total // 8)
        buf.update(cap=cap, p=np.empty((cap, 2), np.int64), d=np.empty(cap if "d" in q else 0),
                   v=np.empty((cap if "D" in q else 0, 3)),
                   s=np.empty((cap if "S" in q else 0, 3), np.int64),
                   e=np.empty(cap if self._tracker is not None else 0, np.int64))
        self._use_outputs(buf)

    @property
    def nbytes(self):
        """Bytes of working memory the search keeps between frames (all buffers,
        the output buffers included)."""
        seen, total = set(), 0
        values = [*vars(self).values()]
        for buf in self._out_sets:
            values += buf.values()
        if self._cross is not None:  # the cross-set query's grid and outputs
            values += self._cross.arrays()
        for value in values:
            if isinstance(value, np.ndarray) and id(value) not in seen:
                seen.add(id(value))
                total += value.nbytes
        if self._tracker is not None:
            total += self._tracker.nbytes
        return total

    # --------------------------------------------------------------- frame
    def _frame(self, positions, rad, skin, box, pbc, labels, copy):
        t_start = time.perf_counter()
        scan, self._scan = self._scan, None
        cs = self._cell_state(box, pbc)
        cell = cs.cell
        n = len(positions)
        minimum = self.periodic_images == "minimum"
        rmax = (float(rad.max()) if scan is None else scan[4]) if n else 0.0
        reach_max = 2.0 * rmax + skin
        periodic_run = cell is not None
        if periodic_run and minimum:
            _check_half_width(cs, reach_max, self._what)
        # Coordinates are scaled by a power of two, which is exact, where squared
        # distances would overflow or underflow (_frame_scale): the scale comes from
        # the interaction range, the smallest pair threshold and the largest
        # coordinate, so that a far particle cannot push the others' squares
        # under the smallest normal double; every comparison and distance is then
        # that of float64 with an unbounded exponent
        self._given = positions  # as the caller gave them, for messages
        self._given_cs = cs
        scale = 1.0
        self._fine_q = None
        if n:
            big, fine = _magnitudes(positions) if scan is None else scan[1:3]
            big = max(big, cs.magnitude)
            fine = min(fine, cs.fine)
            if math.isfinite(fine):
                # every coordinate (and cell entry) is a multiple of 2**q
                self._fine_q = max(_exp2(fine) - 53, -1074)
            rmin = float(rad.min()) if scan is None else scan[3]
            k = _frame_scale(big, fine, reach_max + self.rebuild_margin,
                             2.0 * rmin + skin, *self._names)
            if k:
                scale = math.ldexp(1.0, k)
                positions = positions * scale
                rad = rad * scale
                skin = skin * scale
                rmax *= scale
                reach_max *= scale
                if cell is not None:
                    cs = cs.scaled(scale)
                    cell = cs.cell
        self._scale = scale
        self._margin = self.rebuild_margin * scale
        # what the scan knows of the radii holds for the frame's radii when unscaled
        self._scan_now = scan if (scan is not None and scale == 1.0 and n) else None
        # coordinates far beyond the range along an open axis: the general path,
        # which guards open axes by the range (``_build``), not by the coordinates
        self._far = bool(n and not cs.all_periodic and _GUARD * big * scale
                         > _far_scale(reach_max + self._margin, cs.min_periodic_width) * _FAR)
        if self._takes_small(n, minimum):  # serial kernels only: no thread setting
            self._kern = grid.serial
            result = self._run(positions, rad, skin, cs, labels, n, rmax, reach_max, minimum,
                               1, t_start, scale)
        else:
            threads = self.n_threads
            if threads is None and n < _PARALLEL_MIN:
                threads = 1
            with num_threads(threads) as threads:
                self._kern = grid.serial if threads == 1 else grid
                result = self._run(positions, rad, skin, cs, labels, n, rmax, reach_max,
                                   minimum, threads, t_start, scale)
        if copy:
            result = tuple(np.array(r) for r in result)
        return result[0] if len(result) == 1 else result

    def _takes_small(self, n, minimum):
        """Whether this frame runs the small-frame kernels (``_small``): few
        particles, no Verlet margin, and one thread asked for (or implied: no
        ``n_threads`` below ``_PARALLEL_MIN``), or too few particles for a second
        chunk of parallel work."""
        if not (0 < n <= self._small_max and self._margin == 0.0 and minimum
                and self.path != "sweep" and self._levels is True
                and not self._far):
            return False
        one = self.n_threads == 1 or (self.n_threads is None and n < _PARALLEL_MIN)
        return one or n < 2 * _CHUNK

    def _cell_state(self, box, pbc):
        """The resolved cell of ``box`` and ``pbc`` with what every frame derives from
        it, kept while the same cell comes back (the same Cell, or an array or list
        with the same values)."""
        if box is None or isinstance(box, Cell):
            key = (box, None)
        elif isinstance(box, (np.ndarray, list, tuple)):
            arr = np.asarray(box)
            key = (None, (arr.shape, arr.dtype.str, arr.tobytes()))
        else:  # an ase.Atoms or anything else: resolved every time
            key = None
        if pbc is not None and key is not None:
            if isinstance(pbc, (bool, np.bool_)):
                key += (bool(pbc),)
            else:
                p = np.asarray(pbc)
                key += ((p.shape, p.dtype.str, p.tobytes()),)
        last = self._cell_memo
        if key is not None and last is not None and last[0][0] is key[0] and last[0][1:] == key[1:]:
            return last[1]
        state = FrameCell.of(box, pbc)
        self._cell_memo = None if key is None else (key, state)
        return state

    def _run(self, positions, rad, skin, cs, labels, n, rmax, reach_max, minimum,
             threads, t_start, scale):
        self._frames += 1
        cell, pbc = cs.cell, cs.pbc
        cell_k, diag, hinv = cs.matrix, cs.diag, cs.hinv
        # the given positions (scaled: exact) and the frame's largest range, for
        # the band of the agreed arithmetic (grid.band)
        self._xg = positions
        self._reach_max = reach_max
        self._cs_now = cs
        key = (n, cs.key, skin, minimum, self.include_cutoff, labels is not None, scale)
        self._alloc_particles(n)
        if n == 0:
            self._path_now = "columns" if self.path == "auto" else self.path
            self._path_reason, self._r_small = "no particles", None
            self._cpp = (0.0, 0.0)
        margin = self._margin
        reason = None
        if self._key != key:
            reason = "first frame" if self._key is None else (
                "particle count changed" if self._key[0] != n else "cell or settings changed")
        elif not (self._scan_now[6] if self._scan_now is not None
                  else np.array_equal(rad, self._rad)):
            reason = "radii changed"
        elif labels is not None and not np.array_equal(labels, self._labels):
            reason = "clump ids changed"
        elif margin == 0.0:
            reason = "no rebuild margin"
        times = {}
        max_disp = None
        t0 = time.perf_counter()
        if reason is None and n:
            n_chunks = len(self._chunk_rows) - 1
            disp2 = np.empty(n_chunks)
            bad, wext, kmax = self._kern.wrap_sorted(positions, self._perm, hinv, cell_k, diag,
                                                     pbc, self._ts, n_chunks, self._t,
                                                     self._ks, self._ws, self._m, disp2)
            self._raise_bad(bad)
            if self._far_ext is not None:  # see _build: open axes are not wrapped
                wext = min(wext, self._far_ext)
            self._wk = (wext, kmax)
            max_disp = math.sqrt(float(disp2.max()))
            if max_disp > 0.5 * margin:
                reason = f"a particle moved {max_disp:.6g} > rebuild_margin / 2"
            elif self._band(0.0)[2] > self._list_dtol:
                reason = ("positions moved by whole cell vectors beyond the rounding band the "
                          "list was built for")
        times["wrap"] = time.perf_counter() - t0
        tested = None
        self._direct_done = False
        if reason is not None:
            if self._takes_small(n, minimum):
                tested = self._small(positions, rad, skin, cs, labels, n, rmax, key, times)
            if tested is None:
                tested = self._build(positions, rad, skin, cs, labels, n, rmax, reach_max,
                                     minimum, key, times)
            self._rebuilds += 1
        t0 = time.perf_counter()
        total = self._direct_total if self._direct_done else self._narrow(skin, cell_k, diag)
        if (cell is not None and minimum and total
                and 2.0 * reach_max >= cs.min_periodic_width * (1.0 - 1e-9)):
            total = self._dedup(total)
        times["narrow"] = time.perf_counter() - t0
        self._unscale(total)
        result = self._results(total)
        times["total"] = time.perf_counter() - t_start
        self.stats = {
            "frame": self._frames, "n": n, "threads": threads, "path": self._path_now,
            "path_reason": self._path_reason, "levels": 1 if self._r_small is None else 2,
            "rebuilt": reason is not None, "reason": reason or "within the rebuild margin",
            "rebuilds": self._rebuilds, "max_displacement": max_disp,
            "verlet_entries": int(self._vneed.sum()) if len(self._vneed) else 0,
            "candidates_tested": tested, "pairs": total, "seconds": times,
            "columns": self._grid_shape, "predicted_cpp": self._cpp[0],
        }
        return result

    def _unscale(self, total):
        """Distances and vectors of this call back to the caller's units (the
        buffers, in place), and those the scaled arithmetic may not have got
        exactly recomputed from the given positions (``_exact_small``)."""
        if total == 0:
            return
        q = self._computed
        want_d, want_v = "d" in q, "D" in q
        scale = self._scale
        if scale != 1.0:
            inv = 1.0 / scale  # a power of two: the products are exact divisions
            if want_d:
                self._out_d[:total] *= inv
            if want_v:
                self._out_v[:total] *= inv
        fine = self._fine_q
        if fine is None or not (want_d or want_v):
            return
        k = _exp2(scale) - 1
        if fine + k >= -480:
            # every nonzero separation is at least 2**-480 scaled: its square and
            # the sum of squares are those of an unbounded exponent
            return
        periodic_s = self._given_cs.cell is None or "S" in q
        if fine + k < -1074 and periodic_s:
            # the scale dropped low bits of the smallest coordinates: every row
            # (with its shift: the nearest lattice vector is the shift of tiny
            # separations only)
            rows = np.arange(total)
        elif want_d:
            rows = np.flatnonzero(self._out_d[:total] < _TINY_D / scale)
        else:  # vectors are exact differences
            return
        if len(rows):
            self._exact_small(rows, want_d, want_v)

    def _exact_small(self, rows, want_d, want_v):
        """Distances and vectors of ``rows`` from the given positions and the pair's
        lattice shift ``S`` (``D = x_j - x_i + S0 a + S1 b + S2 c``, added in this
        order), the distance scaled row by row by a power of two: exact where the
        frame's scale let squares of tiny separations underflow."""
        x = self._given
        pairs = self._out_p[rows]
        v = x[pairs[:, 1]] - x[pairs[:, 0]]
        cs = self._given_cs
        if cs.cell is not None:
            if "S" in self._computed:
                shift = self._out_s[rows]
            else:
                # a separation far below the cell widths: the shift is the nearest
                # lattice vector
                h = cs.hinv if not cs.diag else np.diag(1.0 / np.diag(cs.matrix))
                frac = v[:, 0:1] * h[0] + v[:, 1:2] * h[1] + v[:, 2:3] * h[2]
                shift = np.where(cs.pbc, -np.rint(frac), 0.0).astype(np.int64)
            for c in range(3):
                v += shift[:, c:c + 1] * cs.cell[c]
        if want_v:
            self._out_v[rows] = v
        if want_d:
            e = np.frexp(np.abs(v).max(axis=1))[1]
            u = np.ldexp(v, -e[:, None])
            self._out_d[rows] = np.ldexp(
                np.sqrt(u[:, 0] * u[:, 0] + u[:, 1] * u[:, 1] + u[:, 2] * u[:, 2]), e)

    def _band(self, x2, wk=None):
        """``grid.frame_band`` of this frame (or of ``wk = (largest wrapped
        coordinate, largest wrap shift)``): (lo2, hi2, dtol, exact) of the agreed
        arithmetic's re-test band for the squared bound ``x2``."""
        cs = self._cs_now
        wext, kmax = self._wk if wk is None else wk
        return grid.frame_band(float(wext), int(kmax), cs.matrix, cs.pbc, cs.widths,
                               self._reach_max + self._margin, self._reach_max, x2)

    def _raise_bad(self, bad, name="positions"):
        """The error of row ``bad`` of ``self._given`` (argument ``name``) too far
        outside the cell to wrap; nothing when ``bad`` is -1."""
        if bad >= 0:
            raise ValueError(
                f"{name} row {bad} ({self._given[bad].tolist()}) lies about "
                f"{grid.WRAP_LIMIT:.3g} cell lengths or more outside the cell along a "
                "periodic axis: wrapping it into the cell would keep no significant digit. "
                "Give coordinates within 2**52 cell lengths of the cell")

    def _build(self, positions, rad, skin, cs, labels, n, rmax, reach_max, minimum, key,
               times):
        t0 = time.perf_counter()
        cell, hinv, diag, pbc = cs.matrix, cs.hinv, cs.diag, cs.pbc
        self._key = key
        self._rad = rad.copy()
        self._rad_version += 1
        self._labels = None if labels is None else labels.copy()
        self._m[:] = 0
        if n == 0:
            self._chunk_rows = np.zeros(1, np.int64)
            self._vneed = np.zeros(0, np.int64)
            self._grid_shape = (0, 0)
            self._perm = np.empty(0, np.int64)
            times["sort"] = times["build"] = 0.0
            return 0
        bad, extent, kmax = self._kern.wrap(positions, hinv, cell, diag, pbc, self._t, self._k,
                                            self._w, int(min(_MAX_CHUNKS, max(1, n // _CHUNK))))
        self._raise_bad(bad)
        t, w = self._t, self._w
        rng = reach_max + self._margin
        far = bool(_GUARD * extent > _far_scale(rng, cs.min_periodic_width) * _FAR
                   and not pbc.all() and (diag or not pbc.any()))
        self._far_ext = None
        if far:
            # coordinates far beyond the range along open axes (one particle at
            # 1e300): on those axes the window and the separations are
            # differences of the coordinates, whose rounding is relative to the
            # range, so the guard is taken from the periodic lengths only (the
            # column layers get the binning's rounding instead, below).  The
            # band too: open axes are not wrapped, so their separations are
            # those of the agreed arithmetic, bit for bit
            extent = 2.0 * max((abs(float(cell[c, c])) for c in range(3) if pbc[c]),
                               default=0.0)
            self._far_ext = extent
        widths = cs.widths
        self._wk = (extent, kmax)
        # every superset holds the band of the agreed arithmetic (grid.band); a
        # Verlet list the band of later frames too, up to twice the wrap shifts
        # and coordinates of this one plus two cells (a frame beyond rebuilds)
        cover = self._band(0.0)[2]
        if self._margin > 0.0:
            cover = max(cover, self._band(0.0, (2.0 * extent + self._margin, 2 * kmax + 2))[2])
        self._list_dtol = cover
        extent = extent + rng
        guard = _GUARD * extent + np.finfo(np.float64).tiny
        reach = skin + self._margin + guard + cover
        if pbc.any() and guard > 0.25 * float(widths[pbc].min()):
            raise ValueError(
                f"positions up to {float(np.abs(self._given).max())!r} in magnitude: their "
                f"rounding (about {guard / self._scale:.3g}) exceeds a quarter of the "
                f"cell width {float(widths[pbc].min()) / self._scale:.17g}; give "
                "coordinates nearer the cell")
        lo = np.zeros(3)
        span = np.ones(3)
        for c in range(3):
            if not pbc[c]:
                lo[c] = t[:, c].min()
                span[c] = t[:, c].max() - lo[c]
        r_small = None
        with np.errstate(over="ignore", under="ignore"):
            # a cost figure only (spans up to 2**1001: the volume may be inf or 0)
            volume = float(np.prod(span)) * cs.det
        if self._margin == 0.0 and minimum and self._levels is not False:
            if self._levels is True:
                # the volume with the span to a sixteenth octave, as small frames
                # take it (a decision of the frame alone, kept while it holds)
                with np.errstate(over="ignore", under="ignore", invalid="ignore"):
                    split_volume = _octave16(float(np.prod(span))) * cs.det
                memo = getattr(self, "_split_memo", None)
                if (memo is not None and memo[0] == (n, reach, split_volume)
                        and np.array_equal(memo[1], rad)):
                    r_small = memo[2]
                else:
                    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
                        r_small = _level_split(rad, rmax, reach, n, split_volume)
                    self._split_memo = ((n, reach, split_volume), rad.copy(), r_small)
            elif 0.0 < self._levels < rmax:  # a forced split (tests)
                r_small = float(self._levels)
        self._r_small = r_small
        bin_range = 2.0 * (rmax if r_small is None else r_small) + reach + guard
        delta = bin_range / widths
        delta_big = (2.0 * rmax + reach + guard) / widths
        nb = [1, 1]
        for c in range(2):
            if span[c] > 0:
                with np.errstate(over="ignore", divide="ignore"):
                    ratio = span[c] / delta[c] if delta[c] > 0 else math.inf
                nb[c] = int(max(1.0, math.floor(min(ratio, float(_MAX_BINS)))))
        while nb[0] * nb[1] > max(1, n) and max(nb) > 1:
            c = 0 if nb[0] >= nb[1] else 1
            nb[c] = max(1, nb[c] // 2)
        inv_f = np.zeros(3)
        layers = []
        layers_big = []
        for c in range(2):
            f = float(span[c]) / nb[c]
            with np.errstate(over="ignore", divide="ignore"):
                inv_f[c] = nb[c] / span[c] if span[c] > 0 else 0.0
            if not math.isfinite(inv_f[c]):  # a subnormal span: one column
                nb[c], inv_f[c], f = 1, 0.0, 0.0
            # (layers capped: a range beyond 2**62 columns is all of an open axis)
            d_c, db_c = float(delta[c]), float(delta_big[c])
            if far and not pbc[c]:
                # a column index is rounded by at most 2 eps nb: the layers cover it
                pad = 8.0 * np.finfo(np.float64).eps * nb[c] * f
                d_c, db_c = d_c + pad, db_c + pad
            L = 1 if (f >= d_c or f == 0) else math.ceil(min(d_c / f, 2.0 ** 62))
            L_big = 1 if (f >= db_c or f == 0) else math.ceil(min(db_c / f, 2.0 ** 62))
            if not pbc[c]:
                L = min(L, nb[c] - 1)
                L_big = min(L_big, nb[c] - 1)
            layers.append(L)
            layers_big.append(L_big)
        stencil = [(o0, o1) for o0 in range(-layers[0], layers[0] + 1)
                   for o1 in range(-layers[1], layers[1] + 1)
                   if o0 > 0 or (o0 == 0 and o1 > 0)]
        stencil = np.array(stencil, np.int64).reshape(-1, 2)
        stencil_big = np.array([(o0, o1) for o0 in range(-layers_big[0], layers_big[0] + 1)
                                for o1 in range(-layers_big[1], layers_big[1] + 1)],
                               np.int64).reshape(-1, 2)
        nb0, nb1 = nb
        self._grid_shape = (nb0, nb1)
        ncol = nb0 * nb1
        self._kern.columns_of(t, lo, inv_f, nb0, nb1, self._col)
        fresh = self._perm is None or len(self._perm) != n
        prev = np.arange(n, dtype=np.int64) if fresh else self._perm
        start = np.empty(ncol + 1, np.int64)
        perm = self._perm_buf
        segments = 1 if self._kern is grid.serial else min(numba.get_num_threads(),
                                                             max(1, n // (4 * ncol + 1)))
        hist = self._hist
        if hist.shape != (segments, ncol):
            hist = self._hist = np.empty((segments, ncol), np.int64)
        self._kern.counting_sort(self._col, prev, ncol, start, perm, hist)
        # refused before any pair is searched: the plan's columns bound the pairs
        # at once; only a frame they do not show to fit takes the full bound
        with np.errstate(over="ignore", invalid="ignore"):  # spans up to 2**1001
            _memory.check_pair_memory(self, t, cs, 2.0 * float(rad.min()) + skin,
                                      labels,
                                      columns=(start, nb0, nb1, layers_big[0], layers_big[1]))
        self._kern.sort_columns(start, ncol, perm, t, 2, fresh)
        self._perm_buf = prev if not fresh else np.empty(n, np.int64)
        self._perm = perm
        use_label = labels is not None
        lab = labels if use_label else self._ls
        occ = np.diff(start)
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            self._cpp = _predict_cpp(occ, len(stencil), len(stencil_big), widths, span,
                                     volume, rad, skin, reach, rmax, r_small)
        path, self._path_reason = self._choose_path(n, minimum, self._cpp)
        if path == "sweep" and far:
            # the paper's sweep widens every cube by the rounding of the largest
            # coordinate: a far particle would make every cube overlap (and,
            # with periodic axes, every particle a ghost of many cells)
            path, self._path_reason = "columns", (
                f"{self._path_reason}; but coordinates lie more than "
                f"{_FAR / _GUARD:.3g} ranges away along an open axis, where the paper's "
                "sweep would widen every cube by their rounding: the column sweep")
        self._path_now = path
        direct = self._margin == 0.0 and path == "columns"
        if direct:  # straight into the layout the column sweep reads
            tz, xs, ys, zs = self._tz, self._xs, self._ys, self._zs
            self._kern.gather_columns(perm, t, w, rad, lab, tz, xs, ys, zs, self._rs,
                                      self._ls, use_label)
        else:
            self._kern.gather(perm, t, w, rad, lab, self._ts, self._ws, self._rs, self._ls,
                              use_label)
            if path == "columns":  # a Verlet build sweeps columns too (the sweep path
                # reads the rows)
                tz = np.ascontiguousarray(self._ts[:, 2])
                xs, ys, zs = (np.ascontiguousarray(self._ws[:, c]) for c in range(3))
        if "S" in self._computed or kmax != 0:  # (a band re-test reads them)
            np.take(self._k, perm, axis=0, out=self._ks)
        t1 = time.perf_counter()
        times["sort"] = t1 - t0
        # chunks of whole columns with about equal candidate counts, estimated as
        # a column's particles times those of its 3 x 3 neighbourhood (uniform
        # frames: equal particle counts); they depend on the input only
        n_chunks = int(min(ncol, max(1, n // _CHUNK), _MAX_CHUNKS))
        occ = occ.reshape(nb0, nb1).astype(np.float64)
        near = occ.copy()
        for s0 in (-1, 0, 1):
            for s1 in (-1, 0, 1):
                if s0 or s1:
                    near += np.roll(occ, (s0, s1), axis=(0, 1))
        weight = np.zeros(ncol + 1)
        np.cumsum((occ * near).ravel(), out=weight[1:])
        targets = np.arange(1, n_chunks) * (weight[-1] / n_chunks)
        cuts = np.searchsorted(weight, targets, side="left")
        chunk_cols = np.unique(np.concatenate([[0], cuts, [ncol]])).astype(np.int64)
        n_chunks = len(chunk_cols) - 1
        self._chunk_rows = start[chunk_cols]
        inv_w2 = 1.0 / widths[2]
        if path == "sweep":
            self._r_small = None
            return self._sweep_build(cs, minimum, reach, use_label, n, times)
        geometry = (chunk_cols, start, nb0, nb1, pbc, tz, xs, ys, zs,
                    self._rs, self._ls, use_label, cell)
        big = (self._rs > r_small).view(np.uint8) if r_small is not None else _NO_BIG
        levels = (r_small is not None, big, r_small or 0.0, stencil_big)
        times["build"] = 0.0
        if self._margin == 0.0:
            return self._direct(geometry, diag, stencil, rmax, reach, inv_w2, minimum, skin,
                                rad, times, levels)
        # a Verlet list: the records of the pairs within the range plus the margin
        t1 = time.perf_counter()
        uniform = bool(rad.min() == rad.max())
        thr = float(rad[0]) + float(rad[0]) + float(reach) if uniform else 0.0
        x2 = thr * thr * (1.0 + 1e-12)
        tests = (diag, stencil, rmax, reach, inv_w2, not minimum, reach, False, uniform, x2)
        band = (x2, x2, 0.0, True, self._xg, self._perm, self._ks)  # a superset: no band
        counts, tested, wstart, wneed = self._pass1(geometry, tests, band, levels, True)
        self._rows_list = False
        self._wstart, self._wneed = wstart, wneed
        self._vneed = counts
        times["build"] = time.perf_counter() - t1
        return int(tested.sum())

    def _small(self, positions, rad, skin, cs, labels, n, rmax, key, times):
        """A frame of few particles without a Verlet margin: one serial kernel call
        (``grid.small_frame``) wraps, plans the columns, sorts, gathers, runs pass
        1 of the column sweep and writes the outputs (a second call writes them
        when they had to grow).  It is the general path's sweep on one chunk, so
        the answer is that of ``_build`` + ``_direct`` bit for bit, rows in the
        same order."""
        t0 = time.perf_counter()
        self._key = key
        kept = self._rad
        scan = self._scan_now
        if kept is None or kept.shape != rad.shape:
            self._rad = rad.copy()
            self._rad_version += 1
        elif not (scan[6] if scan is not None else np.array_equal(kept, rad)):
            np.copyto(kept, rad)
            self._rad_version += 1
        self._labels = None if labels is None else labels.copy()
        use_label = labels is not None
        strict = not self.include_cutoff
        if scan is None:
            uniform, x2 = _exact_bound(rad, skin, strict)
        else:
            uniform, x2 = scan[3] == scan[4], 0.0
            if uniform:
                thr = (float(rad[0]) + float(rad[0]) + skin, strict)
                memo = self._square_memo
                if memo[0] != thr:
                    memo = self._square_memo = (thr, _square_bound(*thr))
                x2 = memo[1]
        r_small = None if uniform else self._small_levels(positions, rad, rmax, skin, cs, n)
        fresh = self._perm is None or len(self._perm) != n
        prev = self._perm_buf if fresh else self._perm
        perm = self._perm_buf if not fresh else np.empty(n, np.int64)
        sc = self._small_scratch
        if sc is None or len(sc[0]) < n + 2:
            sc = self._small_scratch = (np.empty(n + 2, np.int64), np.empty(n + 2, np.int64),
                                        np.empty(n, np.uint8), np.empty((12, 2), np.int64),
                                        np.empty(6 * n + 64, np.int32), np.empty(n),
                                        np.empty(n))
        start, cursor, big, stencil = sc[:4]
        zidx, ts0, ts1 = sc[4:] if len(sc) > 4 else (np.empty(0, np.int32), _NO_RADII,
                                                      _NO_RADII)
        if getattr(self, "_words", None) is None or len(self._words) < n + 64:
            self._records(4 * n + 1024)
        q = self._computed
        want = ("d" in q, "D" in q, "S" in q)
        fast, tri = grid.loop_mode(cs.diag, uniform, use_label, bool(r_small))
        while True:
            # both passes in one call while the records and the pairs fit the kept
            # buffers (this call's output set as the last call of it left it)
            bad, total, tested, need, nb0, nb1, exact, done = grid.small_frame(
                positions, rad, labels if use_label else self._ls, use_label, cs.matrix,
                cs.hinv, cs.diag, cs.pbc, cs.widths, skin, strict, uniform, x2, _GUARD,
                r_small or 0.0, fresh, prev, self._t, self._k, self._w, self._col, perm, start,
                cursor, self._tz, self._xs, self._ys, self._zs, self._rs, self._ls, big,
                stencil, self._words, self._rec_p, self._rec_q, self._rec_s, self._ks, zidx,
                ts0, ts1, *want, self._out_p, self._out_d, self._out_v, self._out_s, fast,
                tri, _COUNT)
            if bad == -2:  # a plan of more than one column layer, or particles crowded
                return None  # along an open sweep axis: the general path
            if bad == -3:
                raise AssertionError("small frame: the candidate loop given is not the frame's")
            self._raise_bad(bad)
            if need <= len(self._words):
                break
            self._records(need + need // 8 + 64)
        self._perm = perm
        self._perm_buf = prev if not fresh else np.empty(n, np.int64)
        t1 = time.perf_counter()
        self._alloc_output(total)
        if not done:  # the pairs of the records just made, into the grown outputs
            grid.small_frame(
                positions, rad, labels if use_label else self._ls, use_label, cs.matrix,
                cs.hinv, cs.diag, cs.pbc, cs.widths, skin, strict, uniform, x2, _GUARD,
                r_small or 0.0, fresh, prev, self._t, self._k, self._w, self._col, perm, start,
                cursor, self._tz, self._xs, self._ys, self._zs, self._rs, self._ls, big,
                stencil, self._words, self._rec_p, self._rec_q, self._rec_s, self._ks, zidx,
                ts0, ts1, *want, self._out_p, self._out_d, self._out_v, self._out_s, fast,
                tri, (int(need), bool(exact)))
        self._direct_done = True
        self._direct_total = total
        self._vneed = _NO_ENTRIES
        self._grid_shape = (int(nb0), int(nb1))
        self._r_small = r_small
        self._cpp = (None, None)
        self._path_now = "columns"
        reason = self._small_reason
        if reason[0] != n:
            reason = self._small_reason = (n, f"path={self.path!r} given" if self.path != "auto"
                                           else (f"{n} particles: the column sweep (the "
                                                 "paper's sweep is considered from "
                                                 f"{_SWEEP_MIN_N} particles)"))
        self._path_reason = reason[1]
        times["sort"] = times["build"] = 0.0
        times["count"] = t1 - t0
        times["fill"] = time.perf_counter() - t1
        return int(tested)

    def _small_levels(self, positions, rad, rmax, skin, cs, n):
        """``_level_split`` for a small frame, kept while the radii, the cell and
        the extent along open axes are the same."""
        if n < 1000:
            return None
        span = 1.0
        if not cs.all_periodic:
            open_axes = ~cs.pbc
            scan = self._scan_now
            with np.errstate(over="ignore", under="ignore"):
                if cs.diag and scan is not None:
                    # the extents the frame's scan found (positions unscaled)
                    for c in range(3):
                        if open_axes[c]:
                            span *= scan[7][c] / abs(float(cs.matrix[c, c]))
                else:
                    if cs.diag:
                        frac = positions[:, open_axes] / np.diag(cs.matrix)[open_axes]
                    else:  # (a sum of products, not a BLAS product: no BLAS threads)
                        h = cs.hinv[:, open_axes]
                        frac = (positions[:, 0:1] * h[0] + positions[:, 1:2] * h[1]
                                + positions[:, 2:3] * h[2])
                    span = float(np.prod(frac.max(axis=0) - frac.min(axis=0)))
            # particles moving along open axes change the span a little every
            # step: the decision takes it to a sixteenth of an octave, so that a
            # DEM loop keeps it (still a function of the frame alone)
            span = _octave16(span)
        memo = getattr(self, "_small_split_memo", None)
        # (``_small`` has just made the kept radii these: a memo of the same
        # version of them is of the same values)
        key = (n, skin, span, cs.key, self._rad_version)
        if memo is not None and memo[0] == key:
            return memo[1]
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            r_small = _level_split(rad, rmax, skin, n, span * cs.det)
        self._small_split_memo = (key, r_small)
        return r_small

    def _records(self, size):
        """Record buffers of pass 1 for ``size`` records at least."""
        self._words = np.empty(size, np.uint64)
        self._rec_p = np.empty(size, np.int32)
        self._rec_q = np.empty(size, np.int32)
        self._rec_s = np.empty(size, np.int32)

    def _pass1(self, geometry, tests, band, levels, verlet):
        """Pass 1 of the column sweep: per chunk its pairs, candidates and records,
        in regions sized from the last build (a chunk that needs more is swept
        again); (counts, tested, wstart, wneed)."""
        n_chunks = len(geometry[0]) - 1
        stencil = tests[1]
        counts = np.zeros(n_chunks, np.int64)
        tested = np.zeros(n_chunks, np.int64)
        wneed = np.zeros(n_chunks, np.int64)
        rows = np.diff(self._chunk_rows)
        wcap = getattr(self, "_wcap", None)
        if wcap is None or len(wcap) != n_chunks:
            wcap = rows * (len(stencil) + 3) + 64
        todo = np.ones(n_chunks, np.bool_)
        mode = grid.loop_mode(tests[0], tests[8], geometry[11], levels[0])
        before = None
        while True:
            wstart = np.zeros(n_chunks, np.int64)
            wstart[1:] = np.cumsum(wcap)[:-1]
            if before is not None:
                # a grown region moves the regions after it: their records were
                # written where they no longer start, so those chunks run again
                todo |= wstart != before
            before = wstart
            size = int(wcap.sum())
            if getattr(self, "_words", None) is None or len(self._words) < size:
                size += size // 8
                self._words = np.empty(size, np.uint64)
                self._rec_p = np.empty(size, np.int32)
                self._rec_q = np.empty(size, np.int32)
                self._rec_s = np.empty(size, np.int32)
                todo[:] = True
            records = (self._words, self._rec_p, self._rec_q, self._rec_s)
            self._kern.direct_count(*geometry, *tests, *band, *records, wstart, wcap, counts,
                                    tested, wneed, todo, *levels, verlet, *mode)
            over = wneed > wcap
            if not over.any():
                break
            wcap = np.where(over, wneed + wneed // 8 + 64, wcap)
            todo = over
        self._wcap = np.maximum(wcap, wneed + wneed // 8 + 64)
        return counts, tested, wstart, wneed

    def _direct(self, geometry, diag, stencil, rmax, reach, inv_w2, minimum, skin, rad,
                times, levels):
        """A frame without a rebuild margin: pairs straight from the column sweep.

        Pass 1 tests every candidate and keeps, for each run of up to 64
        candidates with a pair among them, a record (the 64-bit mask of the
        pairs, the particle, the first candidate, the lattice shift); pass 2
        writes the pairs of the records into the output buffers.  No Verlet
        list is kept."""
        t0 = time.perf_counter()
        self._direct_done = True
        self._vneed = np.zeros(0, np.int64)
        strict = not self.include_cutoff
        uniform, x2 = _exact_bound(rad, skin, strict)
        tests = (diag, stencil, rmax, reach, inv_w2, not minimum, skin, strict, uniform, x2)
        lo2, hi2, dtol, exact = self._band(x2)
        band = (lo2, hi2, dtol, exact, self._xg, self._perm, self._ks)
        counts, tested, wstart, wneed = self._pass1(geometry, tests, band, levels, False)
        offsets = np.zeros(len(counts), np.int64)
        offsets[1:] = np.cumsum(counts)[:-1]
        total = int(counts.sum())
        t1 = time.perf_counter()
        self._alloc_output(total)
        q = self._computed
        (_, _, _, _, _, xs, ys, zs, rs, ls, use_label, cell) = geometry[1:]
        records = (self._words, self._rec_p, self._rec_q, self._rec_s)
        self._kern.direct_fill(wstart, wneed, offsets, *records, xs, ys, zs, rs, ls, use_label,
                               cell, diag, not minimum, skin, strict, uniform, x2, self._perm,
                               self._ks, self._xg, exact, "d" in q, "D" in q, "S" in q,
                               self._out_p, self._out_d, self._out_v, self._out_s)
        self._direct_total = total
        times["count"] = t1 - t0
        times["fill"] = time.perf_counter() - t1
        return int(tested.sum())

    def _choose_path(self, n, minimum, cpp):
        """(path, reason) of this build: forced, or chosen from the frame alone.

        ``cpp`` is ``_predict_cpp``'s (candidates per pair, per particle) of the
        column plan.  The paper's sweep tests a few candidates per pair whatever
        the size spread but pays several times more per particle (its sort and
        ghost cubes), so it is taken only where the column sweep is predicted
        to test very many candidates per pair and per particle on a large frame
        (the measurements are in docs/engine.md).  No timing enters: the same
        frame gets the same path in every process, with any thread count."""
        if self.path != "auto":
            return self.path, f"path={self.path!r} given"
        if not minimum:
            return "columns", "every periodic image asked for: the column sweep wraps its stencil"
        per_pair, per_particle = cpp
        figures = (f"the column plan predicts {per_pair:.1f} candidates per pair "
                   f"({per_particle:.1f} per particle) on {n} particles")
        limits = f"{_SWEEP_CPP:g} per pair and {_SWEEP_PER_PARTICLE:g} per particle"
        if n < _SWEEP_MIN_N:
            return "columns", f"{figures}: below {_SWEEP_MIN_N} particles, the column sweep"
        if per_pair > _SWEEP_CPP and per_particle > _SWEEP_PER_PARTICLE:
            return "sweep", f"{figures}: above {limits}, the paper's sweep"
        return "columns", f"{figures}: not above {limits}, the column sweep"

    def _sweep_build(self, cs, minimum, reach, use_label, n, times):
        """The Verlet list from the paper's Sweep and Prune over bounding cubes."""
        from .sweep_candidates import SweepCandidates

        t0 = time.perf_counter()
        if self._sweeper is None:
            self._sweeper = SweepCandidates(n_threads=self.n_threads)
        half = self._rs + 0.5 * reach
        self._rows_list = True
        vstart, vstop, vb, vs = self._sweeper.build_resolved(
            self._ws, half, cs, not minimum, spheres=True,
            labels=self._ls if use_label else None)
        self._vstart[:] = vstart
        self._vstop[:] = vstop
        self._vb, self._vs = vb, vs
        rows = np.unique(np.concatenate([np.arange(0, n, _CHUNK), [n]])).astype(np.int64)
        self._chunk_rows = rows
        self._vneed = vstop[rows[1:] - 1] - vstart[rows[:-1]]
        times["build"] = time.perf_counter() - t0
        return int(self._sweeper.stats.get("sweep_candidates_tested") or len(vb))

    def _narrow(self, skin, cell, diag):
        """A Verlet frame: re-test the kept list (count pass, then fill pass)."""
        if self._n == 0:
            self._alloc_output(0)
            return 0
        strict = not self.include_cutoff
        q = self._computed
        wants = ("d" in q, "D" in q, "S" in q)
        uniform, x2 = _exact_bound(self._rs, skin, strict)
        lo2, hi2, dtol, exact = self._band(x2)
        tests = (cell, diag, strict, uniform, x2, lo2, hi2, dtol, exact, self._xg)
        if self._rows_list:  # the list of the paper's sweep, by particle row
            rows = self._chunk_rows
            counts = np.empty(len(rows) - 1, np.int64)
            self._kern.narrow_count(rows, self._vstart, self._vstop, self._vb, self._vs,
                                    self._ws, self._m, self._rs, skin, cell, strict, uniform,
                                    x2, lo2, hi2, dtol, self._xg, self._perm, self._ks,
                                    counts)
        else:
            self._alloc_output(0)
            counts = np.zeros(len(self._wstart), np.int64)
            records = (self._words, self._rec_p, self._rec_q, self._rec_s)
            self._kern.records_narrow(False, self._wstart, self._wneed, counts, counts,
                                      *records, self._ws, self._m, self._rs, skin, *tests,
                                      self._perm, self._ks, *wants, self._out_p,
                                      self._out_d, self._out_v, self._out_s, self._out_e)
        offsets = np.zeros(len(counts), np.int64)
        offsets[1:] = np.cumsum(counts)[:-1]
        total = int(counts.sum())
        self._alloc_output(total)
        if self._rows_list:
            self._kern.narrow_fill(rows, offsets, counts, self._vstart, self._vstop, self._vb,
                                   self._vs, self._ws, self._m, self._rs, skin, cell, strict,
                                   exact, self._xg, self._perm, self._ks, *wants,
                                   self._out_p, self._out_d, self._out_v, self._out_s,
                                   self._out_e)
        else:
            self._kern.records_narrow(True, self._wstart, self._wneed, offsets, counts,
                                      *records, self._ws, self._m, self._rs, skin, *tests,
                                      self._perm, self._ks, *wants, self._out_p,
                                      self._out_d, self._out_v, self._out_s, self._out_e)
        return total

    def _dedup(self, total):
        """Pairs whose two images tie at exactly half a cell width: keep one."""
        p = self._out_p[:total]
        key = p[:, 0] * max(self._n, 1) + p[:, 1]
        if len(np.unique(key)) == total:
            return total
        d = self._out_d[:total] if len(self._out_d) else np.zeros(total)
        order = np.lexsort((d, key))
        first = np.ones(total, bool)
        first[1:] = key[order][1:] != key[order][:-1]
        keep = np.sort(order[first])
        k = len(keep)
        self._out_p[:k] = p[keep]
        for buf in (self._out_d, self._out_v, self._out_s):
            if len(buf):
                buf[:k] = buf[:total][keep]
        return k

    def _results(self, total):
        if self.layout == "csr":
            n = self._n
            want_d = "d" in self.quantities
            buf = self._out_sets[self._out_now]
            if buf.get("csr_n", -1) < n + 1:
                buf["csr_o"] = np.empty(n + 1 + n // 8, np.int64)
                buf["csr_n"] = len(buf["csr_o"])
            if buf.get("csr_cap", -1) < total:
                cap = total + total // 8
                buf["csr_c"] = np.empty(cap, np.int64)
                buf["csr_d"] = np.empty(cap)
                buf["csr_cap"] = cap
            offsets = buf["csr_o"][:n + 1]
            col = buf["csr_c"][:total]
            cd = buf["csr_d"][:total if want_d else 0]
            grid.csr_from_pairs(n, self._out_p[:total], self._out_d[:total] if want_d else cd,
                                want_d, offsets, col, cd)
            return (offsets, col, cd) if want_d else (offsets, col)
        if self._tracker is not None:
            self._track(total)
        out = []
        for q in self.quantities:
            if q == "P":
                out.append(self._out_p[:total])
            elif q == "i":
                out.append(self._out_p[:total, 0])
            elif q == "j":
                out.append(self._out_p[:total, 1])
            elif q == "d":
                out.append(self._out_d[:total])
            elif q == "D":
                out.append(self._out_v[:total])
            else:
                out.append(self._out_s[:total])
        return tuple(out)

    # ------------------------------------------------------------ identity
    def _check_ids(self, ids, n):
        if ids is None:
            return None
        if self._tracker is None:
            raise ValueError("ids are used by contact identity: build the search with "
                             "identity=True to pass ids")
        return as_ids(ids, n)

    def _track(self, total):
        """Contact identity of this call's pairs (granularsap.identity)."""
        t0 = time.perf_counter()
        ids, positions, labels, rad, skin = self._id_call
        # the cell as given (unscaled), resolved once by this call's frame
        cs = self._given_cs
        cell, pbc_arr = cs.cell, cs.pbc
        shifts = self._out_s[:total] if self._tracker.shifts else None
        # rows re-tested from a kept list carry their entry in it: two calls on one
        # list match by entry (unless two images of a pair may both be in the list)
        entries = None
        if not self._direct_done and len(self._out_e) >= total and len(positions):
            twice = False
            if cell is not None and self.periodic_images == "minimum" and pbc_arr.any():
                reach = 2.0 * (2.0 * float(rad.max()) + skin + self.rebuild_margin)
                twice = reach >= cs.min_periodic_width * (1 - 1e-6)
            if not twice:
                entries = (self._rebuilds, self._out_e[:total])
        # the pairs are every pair within rad_i + rad_j + skin: the tracker tells
        # new pairs from their previous distance
        self._tracker.update(self._out_p[:total], len(positions), ids=ids, shifts=shifts,
                             positions=positions, cell=cell, pbc=pbc_arr, labels=labels,
                             radii=rad, skin=skin, borrow=True, entries=entries)
        self._identity_seconds = time.perf_counter() - t0

    def _run_tracked(self, positions, rad, skin, box, pbc, labels, copy, ids):
        """One call through ``_frame``, its outputs in this call's buffer set, and
        the identity of its pairs."""
        self._id_call = (ids, positions, labels, rad, skin)
        self._identity_seconds = None
        self._outputs_begin()
        result = self._frame(positions, rad, skin, box, pbc, labels, copy)
        self._outputs_done(copy)
        if self._identity_seconds is not None:
            self.stats["seconds"]["identity"] = self._identity_seconds
            self.stats["identity_by"] = self._tracker.matched_by
        return result

    def _identity_state(self):
        if self._tracker is None:
            raise ValueError("contact identity needs the search built with identity=True")
        return self._tracker

    @property
    def previous_rows(self):
        """(k,) int64: for each pair of the last result, its row in the result of the
        call before, or -1 for a new pair (``identity=True``; docs/identity.md)."""
        return self._identity_state().previous_rows

    @property
    def ended_rows(self):
        """(m,) int64: rows of the result of the call before the last whose pair did
        not continue, ascending (``identity=True``)."""
        return self._identity_state().ended_rows

    @property
    def clump_pairs(self):
        """(c, 2) int64: the clump pairs in contact in the last call, by label,
        ``label_a < label_b``, sorted (``identity=True`` and ``clump_ids``)."""
        tracker = self._identity_state()
        tracker._clump_tracker()
        return tracker.clump_pairs

    @property
    def previous_clump_rows(self):
        """(c,) int64: row of each clump pair in the call before's ``clump_pairs``,
        or -1."""
        return self._identity_state().previous_clump_rows

    @property
    def ended_clump_rows(self):
        """(m,) int64: rows of the call before's ``clump_pairs`` that ended."""
        return self._identity_state().ended_clump_rows

    def carry(self, history, fill=0.0, out=None, *, clumps=False):
        """A history array of the previous call's pairs, moved to the last call's rows.

        Parameters
        ----------
        history : (k_prev, ...) array_like
            One row per pair of the result of the call before the last.
        fill : scalar or array_like, optional
            Value for new pairs (default 0).
        out : (k, ...) ndarray, optional
            Where to write (same dtype, not overlapping ``history``).
        clumps : bool, optional
            ``history`` has one row per clump pair (``clump_pairs``) instead.

        Returns
        -------
        (k, ...) ndarray
            ``history[previous_rows]``, ``fill`` where ``previous_rows == -1``.
        """
        return self._identity_state().carry(history, fill, out, clumps=clumps)


    # -------------------------------------------------------- cross queries
    _cross = None

    def _query(self, reference, ref_r, configuration, conf_r, skin, box, pbc, copy, names):
        """One cross-set query of validated inputs (``query`` of the subclasses):
        pairs ``(i, j)`` of ``reference[i]`` and ``configuration[j]`` with ``d <=
        (ref_r[i] + conf_r[j]) + skin``, the configuration's grid kept (see
        ``_CrossQuery``).  ``names``: the argument names of messages (reference,
        configuration, the range, the largest range, the smallest threshold)."""
        t_start = time.perf_counter()
        cq = self._cross
        if cq is None:
            cq = self._cross = _CrossQuery()
        n, m = len(reference), len(configuration)
        cs = self._cell_state(box, pbc)
        minimum = self.periodic_images == "minimum"
        strict = not self.include_cutoff
        scan_r = _scan_frame(reference, ref_r, _NO_RADII)
        if scan_r[0] >= 0:
            raise ValueError(f"{names[0]} must be finite, got NaN or inf in row {scan_r[0]}")
        same = (cq.conf is not None and len(cq.conf) == m and np.array_equal(cq.conf,
                                                                              configuration)
                and np.array_equal(cq.conf_r, conf_r))
        scan_c = cq.scan if same else _scan_frame(configuration, conf_r, _NO_RADII)
        if scan_c[0] >= 0:
            raise ValueError(f"{names[1]} must be finite, got NaN or inf in row {scan_c[0]}")
        rmax_r, rmax_c = (scan_r[5] if n else 0.0), (scan_c[5] if m else 0.0)
        reach_max = rmax_r + rmax_c + skin
        if cs.cell is not None and minimum:
            _check_half_width(cs, reach_max, names[3])
        q = self.quantities
        times = {}
        stats = {"query": True, "n_reference": n, "n_configuration": m, "threads": 1,
                 "grid": "none", "grid_builds": cq.builds, "columns": (0, 0),
                 "candidates_tested": 0, "pairs": 0, "seconds": times}
        if n == 0 or m == 0:
            buf = cq.outputs(0, ("d" in q, "D" in q, "S" in q))
            times["total"] = time.perf_counter() - t_start
            self.stats = stats
            return self._query_results(buf, 0, n, np.zeros(n + 1, np.int64), copy)
        big = max(scan_r[1], scan_c[1], cs.magnitude)
        fine = min(scan_r[2], scan_c[2], cs.fine)
        thr_min = scan_r[4] + scan_c[4] + skin
        k = _frame_scale(big, fine, reach_max, thr_min, *names[2:])
        scale = math.ldexp(1.0, k) if k else 1.0
        fine_q = max(_exp2(fine) - 53, -1074) if math.isfinite(fine) else None
        # tiny separations whose squares the scale lets underflow: recomputed
        tiny = fine_q is not None and fine_q + _exp2(scale) - 1 < -480
        cs_s = cs.scaled(scale) if scale != 1.0 else cs
        xr, xc = reference, configuration
        rr, rc, skin_s = ref_r, conf_r, skin
        if scale != 1.0:
            xr, xc, rr, rc, skin_s = xr * scale, xc * scale, rr * scale, rc * scale, skin * scale
        range_s = reach_max * scale
        key = (cs.key, scale)
        threads = self.n_threads
        if threads is None and n + m < _PARALLEL_MIN:
            threads = 1
        serial = threads == 1 or (m < _PARALLEL_MIN and n < 2 * _QUERY_CHUNK)
        # (serial kernels only: no thread setting, as small frames of update)
        with num_threads(None if serial else threads) as threads:
            if serial:
                threads = 1
            gkern = grid.serial if threads == 1 else grid
            qkern = query.serial if threads == 1 or n < 2 * _QUERY_CHUNK else query
            t0 = time.perf_counter()
            if same and cq.key == key and cq.range <= 2.0 * range_s + 1e-300:
                stats["grid"] = "kept"
            else:
                # the grid keeps its own copy (the given array may be edited in place)
                kept = cq.buffer("conf", configuration.shape, np.float64)
                np.copyto(kept, configuration)
                bad = cq.build(kept, conf_r, kept * scale if scale != 1.0 else kept, rc, cs_s,
                               key, range_s, gkern, scan_c)
                if bad >= 0:
                    self._given = configuration
                    self._raise_bad(bad, names[1])
                stats["grid"] = "built"
            g = cq.grid
            t1 = time.perf_counter()
            times["grid"] = t1 - t0
            tr = np.empty((n, 3))
            kr = np.empty((n, 3), np.int64)
            wr = np.empty((n, 3))
            bad, wext_r, kmax_r = gkern.wrap(xr, cs_s.hinv, cs_s.matrix, cs_s.diag, cs_s.pbc,
                                             tr, kr, wr, int(min(_MAX_CHUNKS,
                                                                 max(1, n // _CHUNK))))
            if bad >= 0:
                self._given = reference
                self._raise_bad(bad, names[0])
            wext = max(float(wext_r), cq.wk[0])
            kmax = max(int(kmax_r), cq.wk[1])
            pbc_s = cs_s.pbc
            far = bool(_GUARD * wext > _far_scale(range_s, cs_s.min_periodic_width) * _FAR
                       and not pbc_s.all() and (cs_s.diag or not pbc_s.any()))
            if far:
                # coordinates far beyond the range along open axes (``_build``): the
                # band and the guard from the periodic lengths; open axes are not
                # wrapped and their column edges are not trusted (no gap test)
                wext = 2.0 * max((abs(float(cs_s.matrix[c, c])) for c in range(3) if pbc_s[c]),
                                 default=0.0)
            uniform = scan_r[4] == scan_r[5] and scan_c[4] == scan_c[5]
            x2 = 0.0
            if uniform:
                thr = ((float(rr[0]) + float(rc[0])) + skin_s, strict)
                memo = cq.square
                if memo[0] != thr:
                    memo = cq.square = (thr, _square_bound(*thr))
                x2 = memo[1]
            lo2, hi2, dtol, exact = grid.frame_band(wext, kmax, cs_s.matrix, pbc_s,
                                                    cs_s.widths, range_s, range_s, x2)
            guard = _GUARD * (wext + range_s) + np.finfo(np.float64).tiny
            if pbc_s.any() and guard > 0.25 * cs_s.min_periodic_width:
                raise ValueError(
                    f"{names[0]} and {names[1]} up to {big!r} in magnitude: their rounding "
                    f"(about {guard / scale:.3g}) exceeds a quarter of the cell width "
                    f"{cs.min_periodic_width:.17g}; give coordinates nearer the cell")
            inv_w = 1.0 / cs_s.widths
            gap = pbc_s | (not far)  # (no gap test along open axes of a far frame)
            if n > _QUERY_CHUNK:  # visited column by column (the grid's memory in order)
                col = np.empty(n, np.int64)
                gkern.columns_of(tr, np.array([g.lo0, g.lo1, 0.0]),
                                 np.array([g.inv_f0, g.inv_f1, 0.0]), g.nb0, g.nb1, col)
                order = np.argsort(col, kind="stable")
            else:
                order = np.arange(n, dtype=np.int64)
            ref = query.Ref(xr, tr, kr, wr, rr, order)
            ts = query.Test(cs_s.matrix, pbc_s.copy(), bool(cs_s.diag), inv_w, float(skin_s),
                            strict, bool(uniform), float(x2), float(lo2), float(hi2), float(dtol),
                            bool(exact), cq.rmax, float(skin_s + guard + dtol),
                            float(guard), gap)
            n_chunks = (n + _QUERY_CHUNK - 1) // _QUERY_CHUNK
            counts = np.empty(n, np.int64)
            tested = np.empty(n_chunks, np.int64)
            dedup = (minimum and cs.cell is not None
                     and 2.0 * reach_max >= cs.min_periodic_width * (1.0 - 1e-9))
            want = ("d" in q or dedup or tiny, "D" in q, "S" in q or tiny)
            t2 = time.perf_counter()
            times["wrap"] = t2 - t1
            rec, wstart, wneed = cq.pass1(qkern, g, ref, ts, counts, tested, _QUERY_CHUNK)
            offsets = np.zeros(n + 1, np.int64)
            np.cumsum(counts, out=offsets[1:])
            total = int(offsets[-1])
            t3 = time.perf_counter()
            times["count"] = t3 - t2
            _query_memory(total, q, self.layout)
            buf = cq.outputs(total, want)
            out = query.Out(buf["p"], buf["d"], buf["v"], buf["s"], *want)
            if total:
                qkern.fill(g, ref, ts, rec, wstart, wneed, offsets, out)
            times["fill"] = time.perf_counter() - t3
        if dedup and total:
            total = _query_dedup(buf, total, m)
            if total < offsets[-1]:
                offsets = np.searchsorted(buf["p"][:total, 0], np.arange(n + 1)).astype(np.int64)
        if total and (scale != 1.0 or tiny):
            d, v = buf["d"][:total], buf["v"][:total]
            if scale != 1.0:
                inv = 1.0 / scale
                d *= inv
                v *= inv
            if tiny:
                rows = np.flatnonzero(d < _TINY_D / scale) if fine_q + k >= -1074 else (
                    np.arange(total))
                if len(rows):
                    _query_tiny(reference, configuration, cs, buf["p"], buf["s"], d, v, rows)
        times["total"] = time.perf_counter() - t_start
        stats.update(threads=threads, grid_builds=cq.builds, columns=(g.nb0, g.nb1),
                     candidates_tested=int(tested.sum()), pairs=total)
        self.stats = stats
        return self._query_results(buf, total, n, offsets, copy)

    def _query_results(self, buf, total, n, offsets, copy):
        p = buf["p"][:total] if total else np.empty((0, 2), np.int64)
        if self.layout == "csr":
            result = (offsets, p[:, 1])
            if "d" in self.quantities:
                result += (buf["d"][:total] if total else np.empty(0),)
        else:
            pick = {"P": lambda: p, "i": lambda: p[:, 0], "j": lambda: p[:, 1],
                    "d": lambda: buf["d"][:total] if total else np.empty(0),
                    "D": lambda: buf["v"][:total] if total else np.empty((0, 3)),
                    "S": lambda: buf["s"][:total] if total else np.empty((0, 3), np.int64)}
            result = tuple(pick[c]() for c in self.quantities)
        if copy:
            result = tuple(np.array(r) for r in result)
        return result[0] if len(result) == 1 else result


# ----------------------------------------------------------- cross queries

#: reference points per chunk of a query's parallel passes (boundaries depend on
#: the number of reference points only)
_QUERY_CHUNK = 256
#: ``todo`` of a query's one chunk (read by the kernel, never written)
_ONE_CHUNK = np.ones(1, np.bool_)


class _CrossQuery:
    """The cross-set query of a search (``NeighborSearch.query``,
    ``ContactSearch.query``): the configuration's column grid, kept between
    queries while the configuration, its radii, the cell and the frame's scale
    are the same, and the query's output buffers (two sets that alternate).

    The kernels are ``kernels/query.py``; the grid is the self-search's
    (``grid.wrap``, ``columns_of``, ``counting_sort``, ``sort_columns``,
    ``gather_columns``), built on the configuration alone."""

    def __init__(self):
        self.conf = None  # the configuration as given (a copy), its radii, and
        self.conf_r = None  # the key of the cell and scale the grid was built for
        self.key = None
        self.range = 0.0
        self.perm = None
        self.builds = 0
        self.out_sets = [{}, {}]
        self.out_now = 0
        self.bufs = {}  # the build's arrays, reused while the configuration's size stays
        self.records = None  # pass 1's records (query.Rec), grown as needed
        self.square = (None, None)  # the last threshold and its squared bound
        self.per_ref = 16.0  # records per reference point to make room for

    def buffer(self, name, shape, dtype):
        """The build's array ``name``, reused when its shape and type fit."""
        arr = self.bufs.get(name)
        if arr is None or arr.shape != shape or arr.dtype != dtype:
            arr = self.bufs[name] = np.empty(shape, dtype)
        return arr

    def build(self, conf, conf_r, xs_scaled, rs_scaled, cs, key, rng, kern, scan):
        """The column grid of the configuration ``conf`` (a copy the grid keeps) with
        radii ``conf_r`` (``xs_scaled``, ``rs_scaled``: both times the frame's
        scale; ``rng`` the range the columns are sized for).  Returns the first
        row that cannot be wrapped, or -1."""
        m = len(xs_scaled)
        self.conf = None  # (invalid until the build is done)
        t = self.buffer("t", (m, 3), np.float64)
        k = self.buffer("k", (m, 3), np.int64)
        w = self.buffer("w", (m, 3), np.float64)
        bad, wext, kmax = kern.wrap(xs_scaled, cs.hinv, cs.matrix, cs.diag, cs.pbc, t, k, w,
                                    int(min(_MAX_CHUNKS, max(1, m // _CHUNK))))
        if bad >= 0:
            return bad
        pbc, widths = cs.pbc, cs.widths
        lo = np.zeros(3)
        span = np.ones(3)
        for c in range(2):
            if not pbc[c]:
                lo[c] = t[:, c].min()
                span[c] = t[:, c].max() - lo[c]
        nb = [1, 1]
        inv_f = np.zeros(2)
        f = np.zeros(2)
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            delta = rng / widths
            for c in range(2):
                if span[c] > 0:
                    ratio = span[c] / delta[c] if delta[c] > 0 else math.inf
                    nb[c] = int(max(1.0, math.floor(min(ratio, float(_MAX_BINS)))))
            while nb[0] * nb[1] > max(1, m) and max(nb) > 1:
                c = 0 if nb[0] >= nb[1] else 1
                nb[c] = max(1, nb[c] // 2)
            for c in range(2):
                f[c] = float(span[c]) / nb[c]
                inv_f[c] = nb[c] / span[c] if span[c] > 0 else 0.0
                if not math.isfinite(inv_f[c]):  # a subnormal span: one column
                    nb[c], inv_f[c], f[c] = 1, 0.0, 0.0
        nb0, nb1 = nb
        ncol = nb0 * nb1
        col = self.buffer("col", (m,), np.int64)
        kern.columns_of(t, lo, np.array([inv_f[0], inv_f[1], 0.0]), nb0, nb1, col)
        fresh = self.perm is None or len(self.perm) != m
        prev = np.arange(m, dtype=np.int64) if fresh else self.perm
        start = np.empty(ncol + 1, np.int64)
        perm = self.buffer("perm_spare", (m,), np.int64)
        segments = 1 if kern is grid.serial else min(numba.get_num_threads(),
                                                       max(1, m // (4 * ncol + 1)))
        kern.counting_sort(col, prev, ncol, start, perm, np.empty((segments, ncol), np.int64))
        kern.sort_columns(start, ncol, perm, t, 2, fresh)
        tz, xs, ys, zs, rs = (self.buffer(name, (m,), np.float64)
                              for name in ("tz", "xs", "ys", "zs", "rs"))
        kern.gather_columns(perm, t, w, rs_scaled, _NO_ENTRIES, tz, xs, ys, zs, rs,
                            _NO_ENTRIES, False)
        if kmax == 0:  # (nothing was wrapped: zeros, pages the kernels only read)
            ks = np.zeros((m, 3), np.int64)
        else:
            ks = np.take(k, perm, axis=0, out=self.buffer("ks", (m, 3), np.int64))
        # sweep buckets: about two slots a bucket (``query.zindex``)
        nz = int(max(1, min(m // (2 * ncol), 1 << 16)))
        zlo, zspan = (0.0, 1.0) if pbc[2] else (float(t[:, 2].min()), float(np.ptp(t[:, 2])))
        with np.errstate(over="ignore", divide="ignore"):
            inv_bz = nz / zspan if zspan > 0 else 0.0
        if not math.isfinite(inv_bz):
            nz, inv_bz = 1, 0.0
        zidx = self.buffer("zidx", (ncol * (nz + 1),), np.int64)
        kq = query.serial if kern is grid.serial else query
        kq.zindex(start, tz, zidx, nz, zlo, inv_bz)
        self.grid = query.Grid(start, nb0, nb1, float(lo[0]), float(lo[1]), float(inv_f[0]),
                               float(inv_f[1]), float(f[0]), float(f[1]), tz, xs, ys, zs, rs,
                               ks, perm, xs_scaled, zidx, nz, zlo, float(inv_bz))
        self.bufs["perm_spare"] = self.perm if not fresh else None
        self.perm = perm
        self.wk = (float(wext), int(kmax))
        self.conf = conf
        self.conf_r = np.array(conf_r)
        self.rmax = float(rs.max()) if m else 0.0
        self.scan = scan
        self.key = key
        self.range = rng
        self.builds += 1
        return -1

    def pass1(self, kern, g, ref, ts, counts, tested, chunk):
        """Pass 1 of a query (``query.count``) with its records in regions sized
        from the last query's records per reference point; a chunk that needs
        more is run again in a new region after all the others (theirs stay
        where they are).  Returns (records, wstart, wneed)."""
        n_chunks = len(tested)
        n = len(counts)
        if n_chunks == 1:  # (few reference points: no array arithmetic)
            wcap = np.array([int(n * self.per_ref) + 64])
            wstart = np.zeros(1, np.int64)
            todo = _ONE_CHUNK
        else:
            rows = np.minimum(chunk, n - chunk * np.arange(n_chunks))
            wcap = (rows * self.per_ref).astype(np.int64) + 64
            wstart = np.zeros(n_chunks, np.int64)
            np.cumsum(wcap[:-1], out=wstart[1:])
            todo = np.ones(n_chunks, np.bool_)
        wneed = np.zeros(n_chunks, np.int64)
        end = int(wstart[-1] + wcap[-1])
        while True:
            rec = self.records
            if rec is None or len(rec.word) < end:
                size = end + end // 8
                grown = query.Rec(np.empty(size, np.uint64), np.empty(size, np.int64),
                                  np.empty(size, np.int64), np.empty(size, np.int64))
                if rec is not None and not todo.all():  # the regions made so far
                    for old, new in zip(rec, grown, strict=True):
                        new[:len(old)] = old
                rec = self.records = grown
            kern.count(g, ref, ts, chunk, counts, tested, rec, wstart, wcap, wneed, todo)
            over = wneed > wcap
            if not over.any():
                break
            for c in np.flatnonzero(over):
                wstart[c] = end
                wcap[c] = wneed[c] + wneed[c] // 8 + 64
                end += int(wcap[c])
            todo = over
        self.per_ref = max(1.0, float(wneed.sum()) / max(n, 1) * 1.25)
        return rec, wstart, wneed

    def arrays(self):
        """Every array the query keeps (for ``nbytes``)."""
        out = [v for v in vars(self).values() if isinstance(v, np.ndarray)]
        out += [v for v in self.bufs.values() if isinstance(v, np.ndarray)]
        if self.records is not None:
            out += list(self.records)
        grid_ = getattr(self, "grid", None)
        if grid_ is not None:
            out += [v for v in grid_ if isinstance(v, np.ndarray)]
        for buf in self.out_sets:
            out += [v for v in buf.values() if isinstance(v, np.ndarray)]
        return out

    def outputs(self, total, want):
        """This query's output set for ``total`` rows (``want``: d, D, S)."""
        self.out_now = 1 - self.out_now
        buf = self.out_sets[self.out_now]
        if buf.get("cap", -1) < total or buf.get("want") != want:
            cap = max(256, total + total // 8)
            buf.update(cap=cap, want=want, p=np.empty((cap, 2), np.int64),
                       d=np.empty(cap if want[0] else 0),
                       v=np.empty((cap if want[1] else 0, 3)),
                       s=np.empty((cap if want[2] else 0, 3), np.int64))
        return buf


def _query_tiny(reference, configuration, cs, pairs, shifts, d, v, rows):
    """Distances and vectors of ``rows`` of a query recomputed from the given
    positions and the lattice shifts (``_Search._exact_small`` with two sets):
    exact where the frame's scale let squares of tiny separations underflow."""
    p = pairs[rows]
    vec = configuration[p[:, 1]] - reference[p[:, 0]]
    if cs.cell is not None:
        s = shifts[rows]
        for c in range(3):
            vec += s[:, c:c + 1] * cs.cell[c]
    if len(v):
        v[rows] = vec
    if len(d):
        e = np.frexp(np.abs(vec).max(axis=1))[1]
        u = np.ldexp(vec, -e[:, None])
        d[rows] = np.ldexp(np.sqrt(u[:, 0] * u[:, 0] + u[:, 1] * u[:, 1] + u[:, 2] * u[:, 2]),
                           e)


def _query_memory(total, quantities, layout):
    """MemoryError when a query's ``total`` pairs (counted by its first pass, so
    exactly) cannot be written in the memory available."""
    need = total * _memory.bytes_per_pair(quantities, layout)
    room = _memory.available_memory() if need > (256 << 20) else None
    if room is not None and need > room:
        raise MemoryError(
            f"the query has {total} pairs, which need {need / 2**30:.3g} GiB of outputs "
            f"({_memory.bytes_per_pair(quantities, layout)} bytes per pair for quantities "
            f"{quantities!r}) but about {room / 2**30:.3g} GiB is available; query fewer "
            "reference points at a time or with a smaller range")


def _query_dedup(buf, total, m):
    """Pairs of a minimum-image query whose two images tie at half a cell width:
    keep the nearest (the first of equal ones); returns the rows kept, in order."""
    p = buf["p"][:total]
    key = p[:, 0] * max(m, 1) + p[:, 1]
    if len(np.unique(key)) == total:
        return total
    d = buf["d"][:total]
    order = np.lexsort((d, key))
    first = np.ones(total, bool)
    first[1:] = key[order][1:] != key[order][:-1]
    keep = np.sort(order[first])
    k = len(keep)
    p[:k] = p[keep]
    for name in ("d", "v", "s"):
        arr = buf[name]
        if len(arr):
            arr[:k] = arr[:total][keep]
    return k


class NeighborSearch(_Search):
    """Pairs of particles within ``cutoff`` over a sequence of frames.

    Parameters
    ----------
    cutoff : float
        Pairs with (minimum-image) distance ``d <= cutoff`` are returned.
    rebuild_margin : float, optional
        Verlet margin: the kept candidate list holds every pair within
        ``cutoff + rebuild_margin`` and is rebuilt only when some particle has
        moved more than ``rebuild_margin / 2`` since it was built (or the cell,
        the particle count changed).  0 rebuilds every frame, reusing buffers.
    quantities : str, optional
        What :meth:`update` returns, in this order: ``'P'`` pairs ``(k, 2)``
        int64 with ``i < j``; ``'i'``, ``'j'`` their columns; ``'d'`` distances;
        ``'D'`` vectors from ``i`` to ``j``; ``'S'`` integer lattice shifts with
        ``D = positions[j] - positions[i] + S @ cell``.  Default ``'Pd'``.
    layout : {"pairs", "csr"}, optional
        ``"csr"``: :meth:`update` returns the half list by particle instead,
        ``(offsets (n + 1,), neighbors[, distances])``: the partners ``j > i``
        of particle ``i`` are ``neighbors[offsets[i]:offsets[i + 1]]``.
    periodic_images : {"minimum", "all"}, optional
        ``"minimum"``: one image per pair, and ``cutoff`` must not exceed half
        the smallest perpendicular width of the cell.  ``"all"``: every image
        within range, including a particle's own images (the ASE convention;
        ask for ``'S'`` to tell them apart).
    include_cutoff : bool, optional
        True (default): ``d <= cutoff``; False: ``d < cutoff`` (ASE).
    n_threads : int, optional
        numba threads for each call (restored afterwards); results do not
        depend on it.
    path : {"auto", "columns", "sweep"}, optional
        How candidates are found when the list is built.  ``"columns"``: the
        column sweep (a sweep along one axis inside columns over the other
        two); ``"sweep"``: the paper's parallel bi-dimensional Sweep and
        Prune over the particles' bounding cubes, with ghost cubes for
        periodic images.  ``"auto"`` (default) decides from the frame alone:
        the column sweep, unless the column plan predicts very many
        candidates per pair and per particle on a large frame; no timing
        enters, so the same input gets the same path in every process and
        with any thread count.  ``stats["path"]`` and ``stats["path_reason"]``
        say which and why.  Results are the same on every path.

    identity : bool, optional
        Follow pairs across calls: after each :meth:`update`,
        ``previous_rows`` (the row of each pair in the previous call's result,
        -1 for a new pair), ``ended_rows`` and :meth:`carry` (a history array
        moved to the new rows); particles matched by ``ids=`` or by row, with
        every periodic image also by lattice shift (docs/identity.md).  Needs
        ``layout="pairs"``.

    Notes
    -----
    Returned arrays are views of buffers the search owns: they stay valid and
    unchanged until the call after next of the same search (two sets of
    output buffers alternate, so the previous call's result can be read while
    this call's is in hand); pass ``copy=True`` (or copy them) to keep them
    longer.  Indices are int64; inside, particles are held in column order
    with int64 partner indices and int32-packed shifts.

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import NeighborSearch
    >>> search = NeighborSearch(1.5, rebuild_margin=0.2)
    >>> pos = np.array([[0.0, 0, 0], [1.0, 0, 0], [4.0, 0, 0]])
    >>> pairs, d = search.update(pos, box=[5, 5, 5, 90, 90, 90])
    >>> pairs.tolist(), d.tolist()
    ([[0, 1], [0, 2]], [1.0, 1.0])
    >>> pairs, d = search.update(pos + 0.05, box=[5, 5, 5, 90, 90, 90])
    >>> search.stats["rebuilt"]
    False
    """

    _what = "cutoff"
    #: names of the range, the largest range and the smallest threshold in messages
    _names = ("cutoff", "cutoff + rebuild_margin", "cutoff")
    #: the names of ``query``'s messages: the two sets, the range, the largest
    #: range, the smallest threshold
    _query_names = ("reference", "configuration", "cutoff", "cutoff", "cutoff")

    def __init__(self, cutoff, *, rebuild_margin=0.0, quantities="Pd", layout="pairs",
                 periodic_images="minimum", include_cutoff=True, n_threads=None, path="auto",
                 identity=False):
        self.cutoff = as_scalar(cutoff, "cutoff")
        super().__init__(rebuild_margin=rebuild_margin, quantities=quantities, layout=layout,
                         n_threads=n_threads, periodic_images=periodic_images,
                         include_cutoff=include_cutoff, path=path, identity=identity)
        self._half = None
        # the threshold of every pair is (half + half) + rest == cutoff exactly: half
        # is cutoff / 2 rounded down, and rest is 0 unless the cutoff is a subnormal
        # with its lowest bit set (5e-324 / 2 rounds to 0): then the lost bit
        half = 0.5 * self.cutoff
        if half + half > self.cutoff:
            half = math.nextafter(half, 0.0)
        self._half_cutoff = half
        self._rest = self.cutoff - (half + half)

    def update(self, positions, box=None, *, pbc=None, copy=False, ids=None):
        """Pairs of this frame.

        Parameters
        ----------
        positions : (n, 3) array_like of float
            Need not be wrapped into the cell; the count may change between calls.
        box : None, (6,) or (3, 3) array_like of float, or Cell, optional
            MDAnalysis ``[lx, ly, lz, alpha, beta, gamma]``, a matrix of cell
            vectors (rows) or a :class:`granularsap.Cell`; None for open boundaries.
        pbc : bool or (3,) bools, optional
            Periodic axes (default: all, when a box is given).
        copy : bool, optional
            Return copies instead of views of the search's buffers.
        ids : (n,) array_like of int, optional
            Unique id of every particle (``identity=True``): pairs are followed
            across calls by ids, so that particles may be inserted, deleted or
            reordered; by row without ids.

        Returns
        -------
        tuple of arrays (or one array) as chosen by ``quantities`` / ``layout``.
        """
        positions = as_coords(positions, "positions", check_finite=False)
        n = len(positions)
        if self._half is None or len(self._half) != n:
            self._half = np.full(n, self._half_cutoff)
        scan = self._scan_inputs(positions, self._half)
        ids = self._check_ids(ids, n)
        self._scan = scan
        return self._run_tracked(positions, self._half, self._rest, box, pbc, None, copy, ids)

    def query(self, reference, configuration, box=None, *, pbc=None, copy=False):
        """Pairs of a reference point and a configuration point within ``cutoff``.

        A cross-set query: every pair ``(i, j)`` of ``reference[i]`` and
        ``configuration[j]`` with ``d <= cutoff`` (``<`` with
        ``include_cutoff=False``), each pair once (no symmetry: ``(i, j)`` is
        not ``(j, i)``), minimum image or, with ``periodic_images="all"``, every
        image within range.  The search builds a column grid on the
        configuration and keeps it while the same configuration (the same
        values), the same cell and the same frame scale come back: a grid is
        built once and queried many times (MDAnalysis's ``FastNS(cutoff,
        coords, box).search(query)``), a query costing only the visits of its
        own reference points.  ``stats["grid"]`` says ``"built"`` or ``"kept"``.
        A query does not touch what :meth:`update` keeps (its Verlet list,
        identity), and ``rebuild_margin`` plays no part in it.

        Parameters
        ----------
        reference : (n, 3) array_like of float
            Query points; need not be wrapped.
        configuration : (m, 3) array_like of float
            Points the grid is built on; need not be wrapped.
        box, pbc, copy
            As for :meth:`update`.

        Returns
        -------
        tuple of arrays (or one array) as chosen by ``quantities``: ``'P'``
        ``(k, 2)`` int64 pairs ``(reference index, configuration index)``;
        ``'i'``, ``'j'`` their columns; ``'d'`` distances; ``'D'`` vectors from
        ``reference[i]`` to the image of ``configuration[j]``; ``'S'`` integer
        lattice shifts with ``D = configuration[j] - reference[i] + S @ cell``
        (the arithmetic of docs/cells.md, added in that order).  Rows are
        grouped by reference index, ascending; inside a group they come in
        the order the grid was visited, which depends on the input only, never
        on the thread count (sort them if an order by configuration index is
        needed).  ``layout="csr"`` returns
        ``(offsets (n + 1,), configuration indices[, distances])`` instead.
        Views of buffers the search owns, valid until the query after next
        (``copy=True`` for copies).

        Examples
        --------
        >>> import numpy as np
        >>> from granularsap import NeighborSearch
        >>> search = NeighborSearch(1.5)
        >>> conf = np.array([[0.5, 0, 0], [4.5, 0, 0], [2.0, 2.0, 2.0]])
        >>> pairs, d = search.query([[0.0, 0, 0]], conf, box=[5, 5, 5, 90, 90, 90])
        >>> sorted(pairs.tolist()), d.tolist()  # rows of one point: in the order visited
        ([[0, 0], [0, 1]], [0.5, 0.5])
        >>> pairs, d = search.query([[2.0, 2.0, 3.0]], conf, box=[5, 5, 5, 90, 90, 90])
        >>> pairs.tolist(), search.stats["grid"]
        ([[0, 2]], 'kept')
        """
        ref = as_coords(reference, "reference", check_finite=False)
        conf = as_coords(configuration, "configuration", check_finite=False)
        return self._query(ref, np.zeros(len(ref)), conf, np.zeros(len(conf)), self.cutoff,
                           box, pbc, copy, self._query_names)


class ContactSearch(_Search):
    """Sphere contacts ``d <= r_i + r_j + skin`` over a sequence of frames.

    Parameters
    ----------
    skin : float, optional
        Contact distance added to every pair's ``r_i + r_j``.
    rebuild_margin, quantities, layout, periodic_images, include_cutoff, n_threads, path, identity
        As for :class:`NeighborSearch` (default quantities ``'P'``).

    Notes
    -----
    As for :class:`NeighborSearch`: results stay valid until the call after
    next.  With ``identity=True`` and ``clump_ids``, the clump pairs in
    contact get their own identity (``clump_pairs``, ``previous_clump_rows``,
    ``ended_clump_rows``, ``carry(h, clumps=True)``).

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import ContactSearch
    >>> search = ContactSearch(rebuild_margin=0.1)
    >>> pos = np.array([[0.0, 0, 0], [1.5, 0, 0], [5.0, 0, 0]])
    >>> search.update(pos, [1.0, 0.5, 1.0]).tolist()
    [[0, 1]]
    >>> search.update(pos, [1.0, 0.5, 1.0], clump_ids=[3, 3, 4]).tolist()
    []

    Contacts followed across calls, particles by id (here reordered):

    >>> search = ContactSearch(identity=True)
    >>> search.update(pos, 1.0, ids=[7, 8, 9]).tolist()
    [[0, 1]]
    >>> search.update(pos[::-1], 1.0, ids=[9, 8, 7]).tolist(), search.previous_rows.tolist()
    ([[1, 2]], [0])
    >>> search.carry(np.array([0.25]), fill=0.0).tolist()
    [0.25]
    """

    _what = "interaction range 2 * max(radii) + skin"
    _names = ("the smallest contact distance 2 * min(radii) + skin",
              "the interaction range 2 * max(radii) + skin + rebuild_margin",
              "2 * min(radii) + skin")
    _query_names = ("reference", "configuration",
                    "the smallest contact distance min(ref_radii) + min(conf_radii) + skin",
                    "the interaction range max(ref_radii) + max(conf_radii) + skin",
                    "min(ref_radii) + min(conf_radii) + skin")

    def __init__(self, *, skin=0.0, rebuild_margin=0.0, quantities="P", layout="pairs",
                 periodic_images="minimum", include_cutoff=True, n_threads=None, path="auto",
                 identity=False):
        self.skin = as_scalar(skin, "skin")
        super().__init__(rebuild_margin=rebuild_margin, quantities=quantities, layout=layout,
                         n_threads=n_threads, periodic_images=periodic_images,
                         include_cutoff=include_cutoff, path=path, identity=identity)

    def update(self, positions, radii, box=None, *, pbc=None, clump_ids=None, copy=False,
               ids=None):
        """Contacts of this frame.

        Parameters
        ----------
        positions : (n, 3) array_like of float
        radii : (n,) array_like of float or float
            Non-negative radii (a scalar applies to every sphere).
        box, pbc, copy, ids
            As for :meth:`NeighborSearch.update`.
        clump_ids : (n,) array_like of int, optional
            Rigid-body label of every sphere: spheres with equal labels are never
            paired.  With ``identity=True`` the clump pairs in contact get their
            own identity, by label (``clump_pairs``, ``previous_clump_rows``,
            ``ended_clump_rows``, ``carry(h, clumps=True)``).

        Returns
        -------
        tuple of arrays (or one array) as chosen by ``quantities`` / ``layout``.
        """
        positions = as_coords(positions, "positions", check_finite=False)
        n = len(positions)
        if (type(radii) is np.ndarray and radii.dtype == np.float64 and radii.shape == (n,)
                and radii.flags.c_contiguous):
            scan = self._scan_inputs(positions, radii)
        else:
            # a scalar, a list or another dtype: made (n,) float64 first, then the
            # same one-pass scan as an array given so
            radii = as_radii(radii, n)
            scan = self._scan_inputs(positions, radii)
        labels = None if clump_ids is None else as_labels(clump_ids, n)
        ids = self._check_ids(ids, n)
        self._scan = scan
        return self._run_tracked(positions, radii, self.skin, box, pbc, labels, copy, ids)

    def query(self, reference, ref_radii, configuration, conf_radii, box=None, *, pbc=None,
              copy=False):
        """Contacts ``d <= ref_radii[i] + conf_radii[j] + skin`` of two sets.

        A cross-set query, as :meth:`NeighborSearch.query`: every pair ``(i,
        j)`` of ``reference[i]`` and ``configuration[j]`` in contact, each once,
        the threshold summed ``(ref_radii[i] + conf_radii[j]) + skin``; the
        configuration's grid is kept while the configuration, its radii, the
        cell and the frame scale come back.  No clump labels.

        Parameters
        ----------
        reference : (n, 3) array_like of float
        ref_radii : (n,) array_like of float or float
            Non-negative radii of the reference spheres (a scalar applies to all).
        configuration : (m, 3) array_like of float
        conf_radii : (m,) array_like of float or float
        box, pbc, copy
            As for :meth:`update`.

        Returns
        -------
        As :meth:`NeighborSearch.query`: pairs ``(reference index,
        configuration index)``, grouped by reference index.

        Examples
        --------
        >>> import numpy as np
        >>> from granularsap import ContactSearch
        >>> search = ContactSearch(skin=0.1, quantities="Pd")
        >>> pairs, d = search.query([[0.0, 0, 0]], 1.0, [[1.5, 0, 0], [3.0, 0, 0]], [0.5, 1.0])
        >>> pairs.tolist(), d.tolist()
        ([[0, 0]], [1.5])
        """
        ref = as_coords(reference, "reference", check_finite=False)
        conf = as_coords(configuration, "configuration", check_finite=False)
        rr = as_radii(ref_radii, len(ref), "ref_radii")
        rc = as_radii(conf_radii, len(conf), "conf_radii")
        return self._query(ref, rr, conf, rc, self.skin, box, pbc, copy, self._query_names)


def as_radii(radii, n, name="radii"):
    """Validated ``(n,)`` float64 radii (a scalar is broadcast); plain-float messages."""
    arr = as_vector(radii, name, n, nonnegative=False)
    if arr.size and arr.min() < 0:
        bad = int(np.argmin(arr))
        raise ValueError(f"{name} must be non-negative, got {float(arr[bad])!r} at index {bad}")
    return arr


def as_labels(clump_ids, n, name="clump_ids"):
    """Validated ``(n,)`` int64 labels."""
    ids = np.asarray(clump_ids)
    if ids.dtype.kind not in "iu":
        if ids.dtype.kind == "f" and ids.size and np.all(np.isfinite(ids)) and np.all(
                ids == np.round(ids)):
            ids = ids.astype(np.int64)
        elif ids.size == 0:
            ids = ids.astype(np.int64)
        else:
            raise TypeError(f"{name} must be integers, got dtype {ids.dtype}")
    if ids.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {ids.shape}")
    if ids.dtype.kind == "u" and ids.dtype.itemsize == 8 and ids.size:
        big = int(np.argmax(ids))
        if ids[big] > np.iinfo(np.int64).max:  # would come back as a negative label
            raise ValueError(f"{name} must be below 2**63 (labels are int64), got "
                             f"{int(ids[big])} at index {big}; renumber the clumps, e.g. with "
                             f"np.unique({name}, return_inverse=True)[1]")
    return np.ascontiguousarray(ids, dtype=np.int64)
