"""The particle engine that ``NeighborSearch`` and ``ContactSearch`` share: it
holds the state kept between frames and runs a frame through the parts of
this package, in this order (docs/architecture.md):

* the frame (``frame.py``): one scan of positions and radii, the cell state
  kept while the same box comes back (``geometry.FrameCell``), the scale;
* the rebuild decision: the kept Verlet list (``verlet.VerletList``) holds
  while no particle moved more than half the margin;
* a build: small frames in one serial kernel call (``grid.small_frame``),
  others by the column plan (``plan.py``), the chooser (``chooser.py``) and
  a candidate builder, the column sweep (``columns.ColumnSweep``) or the
  paper's Sweep and Prune (``sweep_candidates.SweepCandidates``);
* the outputs (``outputs.OutputBuffers``) and identity
  (``identity.PairIdentity``).
"""

from __future__ import annotations

import math
import time

import numpy as np

from .. import _memory
from .._numba import get_threads, num_threads
from .._validate import as_scalar, check_n_threads
from ..cell import Cell
from ..geometry import FrameCell
from ..identity import PairIdentity, as_ids
from ..kernels import grid
from . import chooser, plan
from .chooser import PATHS
from .columns import NO_BIG, Band, Columns, ColumnSweep, Levels, PairTest
from .cross import CrossQuery
from .frame import (
    FAR,
    GUARD,
    NO_RADII,
    TINY_D,
    as_radii,
    check_half_width,
    exact_bound,
    exp2,
    far_scale,
    frame_scale,
    magnitudes,
    raise_unwrappable,
    scan_frame,
    square_bound,
)
from .outputs import LAYOUTS, OutputBuffers, check_quantities
from .plan import level_split, octave16, predict_cpp
from .verlet import VerletList

_IMAGES = ("minimum", "all")
_NO_ENTRIES = np.zeros(0, np.int64)
#: ``grid.small_frame``'s ``fill`` of a whole frame (count, then fill what fits)
_COUNT = (-1, True)
#: below this many particles one thread runs (a parallel region costs more)
PARALLEL_MIN = 20000
#: frames of up to this many particles (no Verlet margin, minimum image) are
#: built by one serial kernel (``grid.small_frame``)
SMALL_MAX = 20000


class SearchEngine:
    """What NeighborSearch and ContactSearch share: state, rebuilds, outputs."""

    #: frames of up to this many particles without a Verlet margin take the
    #: serial two-call path (``_small``); tests set 0 to force the general one
    _small_max = SMALL_MAX
    _cell_memo = None
    _small_scratch = None
    #: the band's coordinate extent of a frame far beyond the range (``_build``)
    _far_ext = None
    #: ``scan_frame`` of the positions and radii of the call under way (``update``),
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
        self.quantities = check_quantities(quantities)
        if layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {', '.join(map(repr, LAYOUTS))}, "
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
        #: call returns stay valid until the call after next)
        self._out = OutputBuffers(self._computed, entries=identity)
        #: the column sweep's record buffers, and the Verlet list a build keeps
        self._sweep = ColumnSweep()
        self._verlet = VerletList()
        if not isinstance(include_cutoff, (bool, np.bool_)):
            raise TypeError(f"include_cutoff must be True or False, got {include_cutoff!r}")
        self.include_cutoff = bool(include_cutoff)
        self.n_threads = check_n_threads(n_threads)
        if path not in PATHS:
            raise ValueError(f"path must be one of {', '.join(map(repr, PATHS))}, got {path!r}")
        self.path = path
        self._sweeper = None
        self.stats = {}
        self._frames = 0
        self._rebuilds = 0
        self._key = None
        self._n = -1
        self._perm = None
        #: two column levels for widely spread radii (direct frames): True chooses
        #: by cost, False never, a radius forces that split
        self._levels = True

    def _scan_inputs(self, positions, rad):
        """The finiteness check of ``positions`` (``as_coords``'s, same message), the
        checks of ``rad`` (float64, one per row: ``as_radii``'s) and what the frame
        needs of both, in one pass (``scan_frame``): (-1, largest |x|, smallest
        nonzero |x|, smallest radius, largest radius, True, whether the radii
        equal the kept ones, the extents of the positions along x, y and z),
        for ``_frame``."""
        kept = self._rad if self._rad is not None else NO_RADII
        scan = scan_frame(positions, rad, kept)
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

    @property
    def nbytes(self):
        """Bytes of working memory the search keeps between frames (all buffers,
        the output buffers included)."""
        seen, total = set(), 0
        values = [*vars(self).values()]
        values += self._out.arrays()
        values += list(self._sweep.records or ()) + list(vars(self._verlet).values())
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
            check_half_width(cs, reach_max, self._what)
        # Coordinates are scaled by a power of two, which is exact, where squared
        # distances would overflow or underflow (frame_scale): the scale comes from
        # the interaction range, the smallest pair threshold and the largest
        # coordinate, so that a far particle cannot push the others' squares
        # under the smallest normal double; every comparison and distance is then
        # that of float64 with an unbounded exponent
        self._given = positions  # as the caller gave them, for messages
        self._given_cs = cs
        scale = 1.0
        self._fine_q = None
        if n:
            big, fine = magnitudes(positions) if scan is None else scan[1:3]
            big = max(big, cs.magnitude)
            fine = min(fine, cs.fine)
            if math.isfinite(fine):
                # every coordinate (and cell entry) is a multiple of 2**q
                self._fine_q = max(exp2(fine) - 53, -1074)
            rmin = float(rad.min()) if scan is None else scan[3]
            k = frame_scale(big, fine, reach_max + self.rebuild_margin,
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
        self._far = bool(n and not cs.all_periodic and GUARD * big * scale
                         > far_scale(reach_max + self._margin, cs.min_periodic_width) * FAR)
        if self._takes_small(n, minimum):  # serial kernels only: no thread setting
            self._kern = grid.serial
            result = self._run(positions, rad, skin, cs, labels, n, rmax, reach_max, minimum,
                               1, t_start, scale)
        else:
            threads = self.n_threads
            if threads is None and n < PARALLEL_MIN:
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
        ``n_threads`` below ``PARALLEL_MIN``), or too few particles for a second
        chunk of parallel work."""
        if not (0 < n <= self._small_max and self._margin == 0.0 and minimum
                and self.path != "sweep" and self._levels is True
                and not self._far):
            return False
        one = self.n_threads == 1 or (self.n_threads is None and n < PARALLEL_MIN)
        return one or n < 2 * plan.CHUNK

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
            elif self._band(0.0)[2] > self._verlet.dtol:
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
            total = self._out.dedup(total, self._n)
        times["narrow"] = time.perf_counter() - t0
        self._unscale(total)
        result = self._results(total)
        times["total"] = time.perf_counter() - t_start
        self.stats = {
            "frame": self._frames, "n": n, "threads": threads, "path": self._path_now,
            "path_reason": self._path_reason, "levels": 1 if self._r_small is None else 2,
            "rebuilt": reason is not None, "reason": reason or "within the rebuild margin",
            "rebuilds": self._rebuilds, "max_displacement": max_disp,
            "verlet_entries": self._verlet.entries,
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
                self._out.d[:total] *= inv
            if want_v:
                self._out.v[:total] *= inv
        fine = self._fine_q
        if fine is None or not (want_d or want_v):
            return
        k = exp2(scale) - 1
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
            rows = np.flatnonzero(self._out.d[:total] < TINY_D / scale)
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
        pairs = self._out.p[rows]
        v = x[pairs[:, 1]] - x[pairs[:, 0]]
        cs = self._given_cs
        if cs.cell is not None:
            if "S" in self._computed:
                shift = self._out.s[rows]
            else:
                # a separation far below the cell widths: the shift is the nearest
                # lattice vector
                h = cs.hinv if not cs.diag else np.diag(1.0 / np.diag(cs.matrix))
                frac = v[:, 0:1] * h[0] + v[:, 1:2] * h[1] + v[:, 2:3] * h[2]
                shift = np.where(cs.pbc, -np.rint(frac), 0.0).astype(np.int64)
            for c in range(3):
                v += shift[:, c:c + 1] * cs.cell[c]
        if want_v:
            self._out.v[rows] = v
        if want_d:
            e = np.frexp(np.abs(v).max(axis=1))[1]
            u = np.ldexp(v, -e[:, None])
            self._out.d[rows] = np.ldexp(
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
        raise_unwrappable(self._given, bad, name)

    def _build(self, positions, rad, skin, cs, labels, n, rmax, reach_max, minimum, key,
               times):
        """A rebuild of a general frame: wrap, the column plan, the sort into
        columns, the chooser, and a candidate builder (pairs straight from the
        column sweep, or a Verlet list from either builder).  Returns the
        candidates tested."""
        t0 = time.perf_counter()
        cell, hinv, diag, pbc = cs.matrix, cs.hinv, cs.diag, cs.pbc
        self._key = key
        self._rad = rad.copy()
        self._rad_version += 1
        self._labels = None if labels is None else labels.copy()
        self._m[:] = 0
        self._verlet.clear()
        if n == 0:
            self._chunk_rows = np.zeros(1, np.int64)
            self._grid_shape = (0, 0)
            self._perm = np.empty(0, np.int64)
            times["sort"] = times["build"] = 0.0
            return 0
        bad, extent, kmax = self._kern.wrap(positions, hinv, cell, diag, pbc, self._t, self._k,
                                            self._w, plan.wrap_chunks(n))
        self._raise_bad(bad)
        t, w = self._t, self._w
        rng = reach_max + self._margin
        far = bool(GUARD * extent > far_scale(rng, cs.min_periodic_width) * FAR
                   and not pbc.all() and (diag or not pbc.any()))
        self._far_ext = None
        if far:
            # coordinates far beyond the range along open axes (one particle at
            # 1e300): on those axes the window and the separations are
            # differences of the coordinates, whose rounding is relative to the
            # range, so the guard is taken from the periodic lengths only (the
            # column layers get the binning's rounding instead, plan_columns).
            # The band too: open axes are not wrapped, so their separations are
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
        extent = extent + rng
        guard = GUARD * extent + np.finfo(np.float64).tiny
        reach = skin + self._margin + guard + cover
        if pbc.any() and guard > 0.25 * float(widths[pbc].min()):
            raise ValueError(
                f"positions up to {float(np.abs(self._given).max())!r} in magnitude: their "
                f"rounding (about {guard / self._scale:.3g}) exceeds a quarter of the "
                f"cell width {float(widths[pbc].min()) / self._scale:.17g}; give "
                "coordinates nearer the cell")
        # the column plan
        lo, span = plan.open_span(t, pbc)
        with np.errstate(over="ignore", under="ignore"):
            # a cost figure only (spans up to 2**1001: the volume may be inf or 0)
            volume = float(np.prod(span)) * cs.det
        r_small = self._split(rad, rmax, reach, n, span, cs, minimum)
        self._r_small = r_small
        # the frames the small-frame kernel takes on any thread count widen sparse
        # columns as it does (the rows in the same order, on any thread count)
        wide = self._margin == 0.0 and minimum and n <= grid.WIDE_MAX
        cp = plan.plan_columns(lo, span, pbc, widths, rmax, r_small, reach, guard, far, n,
                               wide)
        nb0, nb1 = cp.nb0, cp.nb1
        self._grid_shape = (nb0, nb1)
        ncol = nb0 * nb1
        # the sort into columns, from the last build's order
        self._kern.columns_of(t, cp.lo, cp.inv_f, nb0, nb1, self._col)
        fresh = self._perm is None or len(self._perm) != n
        prev = np.arange(n, dtype=np.int64) if fresh else self._perm
        start = np.empty(ncol + 1, np.int64)
        perm = self._perm_buf
        segments = 1 if self._kern is grid.serial else min(get_threads(),
                                                             max(1, n // (4 * ncol + 1)))
        hist = self._hist
        if hist.shape != (segments, ncol):
            hist = self._hist = np.empty((segments, ncol), np.int64)
        self._kern.counting_sort(self._col, prev, ncol, start, perm, hist)
        # refused before any pair is searched: the plan's columns bound the pairs
        # at once; only a frame they do not show to fit takes the full bound
        with np.errstate(over="ignore", invalid="ignore"):  # spans up to 2**1001
            _memory.check_pair_memory(self, t, cs, 2.0 * float(rad.min()) + skin,
                                      labels, columns=(start, nb0, nb1, *cp.layers_big))
        self._kern.sort_columns(start, ncol, perm, t, 2, fresh)
        self._perm_buf = prev if not fresh else np.empty(n, np.int64)
        self._perm = perm
        use_label = labels is not None
        lab = labels if use_label else self._ls
        occ = np.diff(start)
        # the chooser
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            self._cpp = predict_cpp(occ, len(cp.stencil), len(cp.stencil_big), widths, span,
                                    volume, rad, skin, reach, rmax, r_small)
        path, self._path_reason = chooser.choose_path(self.path, n, minimum, self._cpp, far,
                                                      FAR / GUARD)
        self._path_now = path
        # the gather into the layout the builder reads
        if self._margin == 0.0 and path == "columns":  # the column sweep's layout
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
        times["sort"] = time.perf_counter() - t0
        if path == "sweep":
            self._r_small = None
            return self._sweep_build(cs, minimum, reach, use_label, n, times, cover)
        chunk_cols = plan.chunk_columns(occ, nb0, nb1, n)
        self._chunk_rows = start[chunk_cols]
        cols = Columns(chunk_cols, start, nb0, nb1, pbc, tz, xs, ys, zs, self._rs, self._ls,
                       use_label, cell)
        big = (self._rs > r_small).view(np.uint8) if r_small is not None else NO_BIG
        levels = Levels(r_small is not None, big, r_small or 0.0, cp.stencil_big)
        inv_w2 = 1.0 / widths[2]
        times["build"] = 0.0
        if self._margin == 0.0:
            return self._direct(cols, diag, cp.stencil, rmax, reach, inv_w2, minimum, skin,
                                rad, times, levels)
        # a Verlet list: the records of the pairs within the range plus the margin
        t1 = time.perf_counter()
        uniform = bool(rad.min() == rad.max())
        thr = float(rad[0]) + float(rad[0]) + float(reach) if uniform else 0.0
        x2 = thr * thr * (1.0 + 1e-12)
        test = PairTest(diag, cp.stencil, rmax, reach, inv_w2, not minimum, reach, False,
                        uniform, x2)
        band = Band(x2, x2, 0.0, True, self._xg, self._perm, self._ks)  # a superset: no band
        counts, tested, wstart, wneed = self._sweep.pass1(self._kern, cols, test, band, levels,
                                                          True, self._chunk_rows)
        self._verlet.keep_records(self._sweep, wstart, wneed, counts, cover)
        times["build"] = time.perf_counter() - t1
        return int(tested.sum())

    def _split(self, rad, rmax, reach, n, span, cs, minimum):
        """The radius of two column levels (``plan.level_split``), or None for one:
        only direct minimum-image frames split; the volume is taken with the
        span to a sixteenth octave, as small frames take it (a decision of the
        frame alone, kept while it holds)."""
        if self._margin != 0.0 or not minimum or self._levels is False:
            return None
        if self._levels is not True:  # a forced split (tests)
            return float(self._levels) if 0.0 < self._levels < rmax else None
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            split_volume = octave16(float(np.prod(span))) * cs.det
        memo = getattr(self, "_split_memo", None)
        if (memo is not None and memo[0] == (n, reach, split_volume)
                and np.array_equal(memo[1], rad)):
            return memo[2]
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            r_small = level_split(rad, rmax, reach, n, split_volume)
        self._split_memo = ((n, reach, split_volume), rad.copy(), r_small)
        return r_small

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
        uniform, x2 = self._exact_bound(rad, skin, strict)
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
        zidx, ts0, ts1 = sc[4:] if len(sc) > 4 else (np.empty(0, np.int32), NO_RADII,
                                                      NO_RADII)
        sweep, out = self._sweep, self._out
        if sweep.records is None or len(sweep.records.word) < n + 64:
            sweep.reserve(4 * n + 1024)
        q = self._computed
        want = ("d" in q, "D" in q, "S" in q)
        fast, tri = grid.loop_mode(cs.diag, uniform, use_label, bool(r_small))
        while True:
            # both passes in one call while the records and the pairs fit the kept
            # buffers (this call's output set as the last call of it left it)
            bad, total, tested, need, nb0, nb1, exact, done = grid.small_frame(
                positions, rad, labels if use_label else self._ls, use_label, cs.matrix,
                cs.hinv, cs.diag, cs.pbc, cs.widths, skin, strict, uniform, x2, GUARD,
                r_small or 0.0, fresh, prev, self._t, self._k, self._w, self._col, perm, start,
                cursor, self._tz, self._xs, self._ys, self._zs, self._rs, self._ls, big,
                stencil, *sweep.records, self._ks, zidx, ts0, ts1, *want, out.p, out.d, out.v,
                out.s, fast, tri, _COUNT)
            if bad == -2:  # a plan of more than one column layer, or particles crowded
                return None  # along an open sweep axis: the general path
            if bad == -3:
                raise AssertionError("small frame: the candidate loop given is not the frame's")
            self._raise_bad(bad)
            if need <= len(sweep.records.word):
                break
            sweep.reserve(need + need // 8 + 64)
        self._perm = perm
        self._perm_buf = prev if not fresh else np.empty(n, np.int64)
        t1 = time.perf_counter()
        out.fit(total)
        if not done:  # the pairs of the records just made, into the grown outputs
            grid.small_frame(
                positions, rad, labels if use_label else self._ls, use_label, cs.matrix,
                cs.hinv, cs.diag, cs.pbc, cs.widths, skin, strict, uniform, x2, GUARD,
                r_small or 0.0, fresh, prev, self._t, self._k, self._w, self._col, perm, start,
                cursor, self._tz, self._xs, self._ys, self._zs, self._rs, self._ls, big,
                stencil, *sweep.records, self._ks, zidx, ts0, ts1, *want, out.p, out.d, out.v,
                out.s, fast, tri, (int(need), bool(exact)))
        self._direct_done = True
        self._direct_total = total
        self._verlet.clear()
        self._grid_shape = (int(nb0), int(nb1))
        self._r_small = r_small
        self._cpp = (None, None)
        self._path_now = "columns"
        reason = self._small_reason
        if reason[0] != n:
            reason = self._small_reason = (n, chooser.small_frame_reason(self.path, n))
        self._path_reason = reason[1]
        times["sort"] = times["build"] = 0.0
        times["count"] = t1 - t0
        times["fill"] = time.perf_counter() - t1
        return int(tested)

    def _exact_bound(self, rad, skin, strict):
        """``frame.exact_bound`` of ``rad``, which are the frame's radii: uniform from
        the frame's scan (its smallest and largest radius), the squared bound kept
        while the threshold is the same."""
        scan = self._scan_now
        if scan is None:
            return exact_bound(rad, skin, strict)
        if scan[3] != scan[4]:
            return False, 0.0
        thr = (float(rad[0]) + float(rad[0]) + skin, strict)
        memo = self._square_memo
        if memo[0] != thr:
            memo = self._square_memo = (thr, square_bound(*thr))
        return True, memo[1]

    def _small_levels(self, positions, rad, rmax, skin, cs, n):
        """``level_split`` for a small frame, kept while the radii, the cell and
        the extent along open axes are the same."""
        if n < 1000:
            return None
        span = 1.0
        if not cs.all_periodic:
            scan = self._scan_now
            if cs.diag and scan is not None:
                # the extents the frame's scan found (positions unscaled), in Python
                # floats (a DEM loop's rebuild comes here with cold caches, where
                # each NumPy call costs microseconds)
                for c in range(3):
                    length = cs.open_lengths[c]
                    if length:
                        span *= float(scan[7][c]) / length
            else:
                open_axes = ~cs.pbc
                with np.errstate(over="ignore", under="ignore"):
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
            span = octave16(span)
        memo = getattr(self, "_small_split_memo", None)
        # (``_small`` has just made the kept radii these: a memo of the same
        # version of them is of the same values)
        key = (n, skin, span, cs.key, self._rad_version)
        if memo is not None and memo[0] == key:
            return memo[1]
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            r_small = level_split(rad, rmax, skin, n, span * cs.det)
        self._small_split_memo = (key, r_small)
        return r_small

    def _direct(self, cols, diag, stencil, rmax, reach, inv_w2, minimum, skin, rad, times,
                levels):
        """A frame without a rebuild margin: pairs straight from the column sweep
        (``columns.ColumnSweep``: pass 1 counts and keeps records, pass 2 writes
        the pairs of the records into the output buffers).  No Verlet list is
        kept."""
        t0 = time.perf_counter()
        self._direct_done = True
        strict = not self.include_cutoff
        uniform, x2 = exact_bound(rad, skin, strict)
        test = PairTest(diag, stencil, rmax, reach, inv_w2, not minimum, skin, strict, uniform,
                        x2)
        band = Band(*self._band(x2), self._xg, self._perm, self._ks)
        counts, tested, wstart, wneed = self._sweep.pass1(self._kern, cols, test, band, levels,
                                                          False, self._chunk_rows)
        offsets = np.zeros(len(counts), np.int64)
        offsets[1:] = np.cumsum(counts)[:-1]
        total = int(counts.sum())
        t1 = time.perf_counter()
        self._out.fit(total)
        q = self._computed
        self._sweep.fill(self._kern, wstart, wneed, offsets, cols, test, band,
                         ("d" in q, "D" in q, "S" in q), self._out)
        self._direct_total = total
        times["count"] = t1 - t0
        times["fill"] = time.perf_counter() - t1
        return int(tested.sum())

    def _sweep_build(self, cs, minimum, reach, use_label, n, times, cover):
        """The Verlet list from the paper's Sweep and Prune over bounding cubes
        (``cover``: the rounding band it covers)."""
        from ..sweep_candidates import SweepCandidates

        t0 = time.perf_counter()
        if self._sweeper is None:
            self._sweeper = SweepCandidates(n_threads=self.n_threads)
        half = self._rs + 0.5 * reach
        vstart, vstop, vb, vs = self._sweeper.build_resolved(
            self._ws, half, cs, not minimum, spheres=True,
            labels=self._ls if use_label else None)
        self._vstart[:] = vstart
        self._vstop[:] = vstop
        rows = np.unique(np.concatenate([np.arange(0, n, plan.CHUNK), [n]])).astype(np.int64)
        self._chunk_rows = rows
        self._verlet.keep_rows(rows, self._vstart, self._vstop, vb, vs, cover)
        times["build"] = time.perf_counter() - t0
        return int(self._sweeper.stats.get("sweep_candidates_tested") or len(vb))

    def _narrow(self, skin, cell, diag):
        """A Verlet frame: re-test the kept list (``verlet.VerletList.retest``)."""
        if self._n == 0:
            self._out.fit(0)
            return 0
        strict = not self.include_cutoff
        q = self._computed
        # (a Verlet frame has the radii of its build: those of the frame's scan)
        uniform, x2 = self._exact_bound(self._rs, skin, strict)
        band = Band(*self._band(x2), self._xg, self._perm, self._ks)
        return self._verlet.retest(self._kern, self._ws, self._m, self._rs, skin, cell, diag,
                                   strict, uniform, x2, band, ("d" in q, "D" in q, "S" in q),
                                   self._out)

    def _results(self, total):
        if self.layout == "csr":
            return self._out.csr(total, self._n, "d" in self.quantities)
        if self._tracker is None:
            return self._out.pick(total, self.quantities)
        self._track(total)
        out = self._out.pick(total, self.quantities)
        # the tracker matches the next call's pairs against these very buffers:
        # read-only views, so that a script cannot change them under it
        for arr in out:
            arr.flags.writeable = False
        return out

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
        shifts = self._out.s[:total] if self._tracker.shifts else None
        # rows re-tested from a kept list carry their entry in it: two calls on one
        # list match by entry (unless two images of a pair may both be in the list)
        entries = None
        if not self._direct_done and len(self._out.e) >= total and len(positions):
            twice = False
            if cell is not None and self.periodic_images == "minimum" and pbc_arr.any():
                reach = 2.0 * (2.0 * float(rad.max()) + skin + self.rebuild_margin)
                twice = reach >= cs.min_periodic_width * (1 - 1e-6)
            if not twice:
                entries = (self._rebuilds, self._out.e[:total])
        # the pairs are every pair within rad_i + rad_j + skin: the tracker tells
        # new pairs from their previous distance
        self._tracker.update(self._out.p[:total], len(positions), ids=ids, shifts=shifts,
                             positions=positions, cell=cell, pbc=pbc_arr, labels=labels,
                             radii=rad, skin=skin, borrow=True, entries=entries)
        self._identity_seconds = time.perf_counter() - t0

    def _run_tracked(self, positions, rad, skin, box, pbc, labels, copy, ids):
        """One call through ``_frame``, its outputs in this call's buffer set, and
        the identity of its pairs."""
        self._id_call = (ids, positions, labels, rad, skin)
        self._identity_seconds = None
        self._out.begin()
        result = self._frame(positions, rad, skin, box, pbc, labels, copy)
        self._out.done()
        if copy and self._tracker is not None:
            self._tracker.detach()
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
        (ref_r[i] + conf_r[j]) + skin``, the configuration's grid kept
        (``cross.CrossQuery``).  ``names``: the argument names of messages."""
        cq = self._cross
        if cq is None:
            cq = self._cross = CrossQuery()
        cs = self._cell_state(box, pbc)
        buf, total, offsets, self.stats = cq.run(
            reference, ref_r, configuration, conf_r, skin, cs,
            minimum=self.periodic_images == "minimum", strict=not self.include_cutoff,
            quantities=self.quantities, layout=self.layout, n_threads=self.n_threads,
            names=names)
        return self._query_results(buf, total, len(reference), offsets, copy)

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
