"""Public entry points of the box broad phase: validate, then call kernels.

``SweepAndPrune`` is the stateful engine of Capannini & Larsson's parallel
bi-dimensional Sweep and Prune; ``box_overlaps`` is one call of a fresh
engine.  The engine keeps, between frames, everything temporal coherence
allows: the bucket boundaries of the parallel sort (Algorithm 2), the sweep
axes chosen by the dispersion heuristic (Section 5), the expected number of
pairs per partition, and every working buffer (so steady-state frames write
into memory that is already mapped).  Beside the paper's sweep it has a
column sweep (``kernels/boxgrid.py``), with its own kept state (the previous
frame's column order, region sizes), and ``path="auto"`` picks one of the two
per call (``SweepAndPrune._choose``).
"""

from __future__ import annotations

import time

import numpy as np

from ._numba import num_threads
from ._validate import as_coords, check_n_threads
from .kernels import boxgrid as bg
from .kernels import checks as _checks
from .kernels import cross as _cross
from .kernels import grid as column_kernels
from .kernels import radixsort as rs
from .kernels import succtree as st
from .kernels import sweep as sw

_AXIS_NAMES = {"x": 0, "y": 1, "z": 2}
#: Endpoints per sort bucket below which fewer buckets are used.
_MIN_BUCKET = 256
#: Buckets of the sort (Algorithm 2's m), so that the dispersion D can see
#: clustering (Section 5) and the buckets spread over the threads.  A constant,
#: not a multiple of the thread count: D decides the axis swaps, and the sweep
#: axes decide the row order, which must not depend on the threads.  (64
#: buckets made the parallel sweep of 2^18 paper boxes 4-21% slower on 1 and
#: 2 threads, one run on a shared 2-core machine.)
_SORT_BUCKETS = 16
#: Boxes below which one thread is used unless n_threads asks otherwise
#: (starting a parallel region costs more than the whole search).
_PARALLEL_MIN = 32768
MAX_BOXES = (1 << 30) - 1
#: the algorithm paths of ``SweepAndPrune(path=...)``
PATHS = ("auto", "sequential", "parallel", "columns")
#: chunks of the column path's per-box passes (at most; fixed, not per thread)
_MEASURE_CHUNKS = 64
#: at most this fraction (1 / _BIG_FRACTION) of the boxes goes to the big list
_BIG_FRACTION = 16
#: columns: at least this many small boxes per column on average ...
_BOXES_PER_COLUMN = 4
#: ... and at most this many columns along one axis
_MAX_SIDE = 1 << 20
#: columns are this many times the largest small side wide (at least 1: the
#: 3 x 3 stencil needs it; wider columns mean fewer columns visited per box
#: for more candidates in each)
_COLUMN_WIDTH = 2.0
#: the half stencil when the largest small side on the sweep axis is at most
#: this many times the mean side (else all 8 neighbours with forward windows)
_HALF_STENCIL = 2.0
#: centres sampled to find the binning range when far boxes stretch the span
_SAMPLE = 4096
#: boxes per chunk of columns (parallel work unit, independent of threads)
_CHUNK_BOXES = 4096
#: big boxes per chunk
_BIG_CHUNK = 256
#: auto: fewer boxes than this take the paper's sweep (the column sweep is
#: faster from about 700 boxes, by 0.1-0.2 ms per call at 1000-4000: docs/boxes.md)
_AUTO_MIN_BOXES = 4096
#: auto: more predicted candidates per box than this take the paper's sweep
_AUTO_MAX_PREDICTED = 256
#: auto: candidates tested per (box + pair) of a column frame above which the
#: paper's sweep takes over for _AUTO_RETRY frames
_AUTO_MAX_CANDIDATES = 64
_AUTO_RETRY = 16
#: Pairs per box of the last search in this process: the first guess of a
#: fresh engine's pair buffers (repeated one-shot calls on similar data then
#: fill them in one pass).
_LAST_PAIRS_PER_BOX = [2.0]
#: ... but never more than this many pairs per box (one dense call, say all
#: boxes on one point, must not make the next engine reserve gigabytes; the
#: buffers grow when a frame needs more)
_MAX_PAIRS_HINT = 16.0
#: Leaf bits of one pairing partition's sharded SuccTree (2**21 bits = 256 KiB).
_PAIR_TREE_BITS = 1 << 21
#: Pairing partitions: at least this many (work for up to as many threads) and
#: a multiple of it, unless that would make partitions of fewer than
#: _PAIR_PART_MIN ranks.  Partitions are rank ranges and the rows come out
#: partition by partition, so their number depends on the input only, never
#: on the thread count.
_PAIR_PARTS = 16
_PAIR_PART_MIN = 1024


def _parse_axes(axes):
    if isinstance(axes, str) and axes == "auto":
        return (0, 1), True
    msg = ("axes must be 'auto' or two distinct axes such as (0, 1) or 'xz', "
           f"got {axes!r}")
    try:
        if isinstance(axes, str):
            if len(axes) != 2 or any(a not in _AXIS_NAMES for a in axes.lower()):
                raise ValueError(msg)
            pair = tuple(_AXIS_NAMES[a] for a in axes.lower())
        else:
            pair = tuple(int(a) for a in axes)
            if any(not float(a).is_integer() for a in axes):
                raise ValueError(msg)
    except (TypeError, ValueError):
        raise ValueError(msg) from None
    if len(pair) != 2 or pair[0] == pair[1] or not all(0 <= a <= 2 for a in pair):
        raise ValueError(msg)
    return pair, False


def _check_boxes(lower, upper, names=("lower", "upper")):
    ln, un = names
    lower = as_coords(lower, ln, check_finite=False)
    upper = as_coords(upper, un, check_finite=False)
    if lower.shape[0] != upper.shape[0]:
        raise ValueError(f"{ln} and {un} must have the same number of rows, got "
                         f"{lower.shape[0]} and {upper.shape[0]}")
    if lower.shape[0] > MAX_BOXES:
        raise ValueError(f"at most {MAX_BOXES} boxes are supported, got {lower.shape[0]}")
    status, i, a = _checks.check_boxes(lower, upper)
    if status == _checks.NONFINITE_LOWER:
        raise ValueError(f"{ln} must be finite, got NaN or inf in row {i}")
    if status == _checks.NONFINITE_UPPER:
        raise ValueError(f"{un} must be finite, got NaN or inf in row {i}")
    if status == _checks.INVERTED:
        raise ValueError(f"{ln} must not exceed {un}, got {ln}={float(lower[i, a])!r} > "
                         f"{un}={float(upper[i, a])!r} at box {i}, axis {a}")
    return lower, upper


class SweepAndPrune:
    """Stateful parallel Sweep and Prune over a sequence of frames.

    Parameters
    ----------
    axes : "auto" or pair of axes
        ``"auto"`` starts sweeping x (primary) and y (secondary) and swaps an
        axis with the unused one when its dispersion passes
        ``swap_threshold`` (Section 5).  A pair such as ``(0, 2)`` or ``"xz"``
        fixes the sweep axes.
    n_threads : int, optional
        Numba threads for each call; ``None`` uses numba's current setting.
        One thread runs the sequential Algorithm 1.  Results do not depend on
        it.
    swap_threshold : float
        Dispersion D (equation 1 of the paper) of a sweep axis's sort buckets
        above which the axis is swapped out.
    path : {"auto", "sequential", "parallel", "columns"}
        ``"sequential"`` runs Algorithm 1 as written, ``"parallel"`` Algorithms
        2-4 (with any number of threads, one included), ``"columns"`` the
        column sweep (``kernels/boxgrid.py``: boxes binned by centre into
        columns over two axes, swept along the third).  ``"auto"`` (default)
        chooses per call between the parallel sweep and the column sweep from
        what the engine measured (number of boxes, spread of their sizes,
        candidates tested per pair in the last frame) and records the choice
        in ``stats["path"]`` and ``stats["path_reason"]``.  Results are the
        same on every path (docs/boxes.md).

    Notes
    -----
    Boxes are closed: ``i`` and ``j`` overlap iff ``lower_i <= upper_j`` and
    ``lower_j <= upper_i`` on every axis.  The number of boxes may change
    between calls (the temporal state is then reset).

    ``stats`` after each call: ``path`` and ``path_reason``; ``seconds`` per
    phase (``sort``, ``candidates``, ``pairing``, ``total``; the column path
    counts measuring, choosing, binning and sorting as ``sort`` and its sweep
    as ``pairing``);
    ``axes`` and ``dispersion`` (the paper's sweep axes and the D of its sort
    buckets; on the column path the two column axes and the D of the boxes
    over the grid's slabs along each); ``swaps``; ``candidates_tested`` and
    ``pairs``; on the column path ``columns`` (axes, sweep axis, grid, widths,
    boxes in the big list).

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import SweepAndPrune
    >>> engine = SweepAndPrune()
    >>> lower = np.array([[0.0, 0, 0], [1.0, 0, 0], [5.0, 5, 5]])
    >>> engine.update(lower, lower + 1.0)
    array([[0, 1]])
    >>> engine.stats["pairs"]
    1
    """

    def __init__(self, *, axes="auto", n_threads=None, swap_threshold=0.25, path="auto"):
        self._axes, self._dynamic = _parse_axes(axes)
        self.n_threads = check_n_threads(n_threads)
        self.swap_threshold = float(swap_threshold)
        if not self.swap_threshold > 0:
            raise ValueError(f"swap_threshold must be positive, got {swap_threshold!r}")
        #: Most bins of the third-axis sharding of the pairing active lists
        #: (1 = the paper's Algorithm 4 exactly).
        self.max_bins = 64
        if path not in PATHS:
            raise ValueError(f"path must be one of {', '.join(map(repr, PATHS))}, "
                             f"got {path!r}")
        self._path = None if path == "auto" else path
        self._partitions = None  # override of the number of partitions (tests)
        self._n = -1
        self._layout = None
        self._bounds = {}
        self._pair_hint = None
        self._swaps = 0
        self._frame = 0
        self.stats = {}
        # column path state (kept between frames: order, buffers, region sizes)
        self._g_meas = None
        self._g_perm = None
        self._g_start = None
        self._g_out = None
        self._g_caps = None
        self._g_ratio = None
        self._g_z = None
        self._g_big_engine = None
        self._g_binned = None  # (frame, grid, fresh) of the last binning
        # what auto measured: the paper sweep's dispersion, per-path history
        self._sap_disp = {}
        self._history = {}
        self._last_path = None
        self._g_avoid_until = 0
        self._g_avoid_reason = ""
        # cross-set queries: the second set, its grid and binning of the last call
        self._cross_kept = None
        self._cross_memo = {}  # the last plan of the kept second set's grid

    # ------------------------------------------------------------------ buffers
    def _ensure(self, n, parts, buckets):
        layout = (n, parts, buckets)
        if self._layout == layout:
            return False
        if self._n != n or self._layout is None or self._layout[2] != buckets:
            self._bounds = {}
            self._pair_hint = None
        self._n = n
        self._layout = layout
        n2 = 2 * n
        # One scratch block: sort keys, their ping-pong copy and index scratch
        # during sorting; the routed pairing events afterwards.
        # (48 bytes per box: room for 3n routed events, which covers candidate
        # ranges up to about one pairing partition long.)
        self._scratch = np.empty(6 * n + 2, np.uint64)
        self._keys = self._scratch[:n2]
        self._keys_tmp = self._scratch[n2:2 * n2]
        self._idx_tmp = self._scratch[2 * n2:2 * n2 + n].view(np.int32)
        self._events = self._scratch.view(np.int64).reshape(-1, 2)
        self._pair_layout = None
        self._ix = np.empty(n2, np.int32)
        self._iy = np.empty(n2, np.int32)
        # Per object: rank, candidate bounds L and U, third-axis bin.
        self._info = np.empty((n, 4), np.int32)
        self._rank = self._info[:, 0]
        self._lcand = self._info[:, 1]
        self._ucand = self._info[:, 2]
        self._rinv = np.empty(n, np.int32)
        self._br = np.empty((n, 4), np.float64)
        self._hist = np.empty((parts, buckets), np.int64)
        self._starts = np.empty(buckets + 1, np.int64)
        self._counts = np.zeros(parts, np.int64)
        self._off_full = st.layout(n)
        self._trees_cand = np.zeros((parts, self._off_full[-1]), np.uint64)
        self._out = np.empty((parts, 0), np.int64)
        return True

    def _bounds_for(self, axis, lower, upper, buckets):
        b = self._bounds.get(axis)
        if b is None:
            b = np.empty(buckets - 1, np.uint64)
            rs.bounds_from_span(lower, upper, axis, b)
            self._bounds[axis] = b
            return b, False
        return b, True

    @property
    def nbytes(self):
        """Bytes of working memory the engine keeps between calls, excluding
        the input boxes, the returned pairs and the per-partition pair staging
        buffers (``staging_nbytes``, about the size of the last output)."""
        seen = {id(self._out)} if hasattr(self, "_out") else set()
        seen.add(id(self._g_out))
        total = 0
        if self._g_meas is not None:
            total += sum(a.nbytes for a in self._g_meas)
        if self._g_big_engine is not None:
            total += self._g_big_engine.nbytes
        for value in vars(self).values():
            if isinstance(value, np.ndarray):
                base = value if value.base is None else value.base
                while isinstance(base, np.ndarray) and base.base is not None:
                    base = base.base
                if id(base) not in seen:
                    seen.add(id(base))
                    total += base.nbytes
            elif isinstance(value, dict):
                total += sum(v.nbytes for v in value.values() if isinstance(v, np.ndarray))
        return total

    @property
    def staging_nbytes(self):
        """Bytes of the per-partition (column path: per-chunk) buffers pairs
        are written to before being concatenated into the returned array."""
        total = self._out.nbytes if hasattr(self, "_out") else 0
        if self._g_out is not None:
            total += self._g_out.nbytes
        if self._g_big_engine is not None:
            total += self._g_big_engine.staging_nbytes
        return total

    # ------------------------------------------------------------------ update
    def update(self, lower, upper, lower_b=None, upper_b=None):
        """Overlapping pairs of the boxes ``[lower, upper]`` of this frame.

        Parameters
        ----------
        lower, upper : (n, 3) array_like of float
            Box corners; float32 is widened exactly to float64.
        lower_b, upper_b : (m, 3) array_like of float, optional
            A second set: the pairs across the two sets instead (as
            :func:`box_overlaps` with a second set).  The engine keeps the
            second set's grid between calls while that set is unchanged (a
            fixed reference, the triangles of a static wall), so a frame then
            pays for the first set only.

        Returns
        -------
        pairs : (k, 2) ndarray of int64
            Each overlapping pair once, ``i < j`` in every row; rows are not
            sorted, but their order is the same on any thread count
            (docs/boxes.md, "Row order").  With a second set: ``(a, b)`` rows of the first and
            the second set, rows sorted.

        Raises
        ------
        ValueError
            NaN or inf, wrong shapes, mismatched lengths, or ``lower > upper``.

        Examples
        --------
        >>> import numpy as np
        >>> from granularsap import SweepAndPrune
        >>> engine = SweepAndPrune()
        >>> floor = np.array([[0.0, 0, 0], [1.0, 0, 0]])
        >>> engine.update([[0.5, 0.2, -0.1]], [[0.7, 0.4, 0.1]], floor, floor + [1, 1, 0])
        array([[0, 0]])
        >>> engine.update([[1.5, 0.2, -0.1]], [[1.7, 0.4, 0.1]], floor, floor + [1, 1, 0])
        array([[0, 1]])
        >>> engine.stats["second_set_kept"]
        True
        """
        if lower_b is not None or upper_b is not None:
            return self._update_cross(lower, upper, lower_b, upper_b)
        lower, upper = _check_boxes(lower, upper)
        threads = self.n_threads
        if threads is None and self._partitions is None and len(lower) < _PARALLEL_MIN:
            threads = 1  # a parallel region costs more than the whole job
        with num_threads(threads) as threads:
            return self._update(lower, upper, threads)

    def _update_cross(self, lower, upper, lower_b, upper_b):
        t_start = time.perf_counter()
        lower, upper = _check_boxes(lower, upper)
        lower_b, upper_b = _second_set(lower_b, upper_b)
        n, m = len(lower), len(lower_b)
        threads = self.n_threads
        if threads is None and n + m < _PARALLEL_MIN:
            threads = 1
        self._frame += 1
        kept = False
        with num_threads(threads) as threads:
            kern = _cross if threads > 1 else _cross.serial
            plan = None if n == 0 or m == 0 else _cross_grid_plan(
                lower, upper, lower_b, upper_b, kept=True, memo=self._cross_memo)
            if plan is None:
                pairs = np.empty((0, 2), np.int64)
            else:
                c = self._cross_kept
                kept = (c is not None and (c[2] is plan or all(
                    np.array_equal(a, b) for a, b in zip(c[2], plan, strict=True)))
                        and np.array_equal(c[0], lower_b) and np.array_equal(c[1], upper_b))
                if kept:
                    binned = c[3]
                else:
                    binned = _cross_bin(kern, lower_b, upper_b, plan)
                    self._cross_kept = (lower_b.copy(), upper_b.copy(), plan, binned)
                pairs = _cross_query(kern, lower, upper, lower_b, upper_b, plan, binned)
        total = time.perf_counter() - t_start
        self.stats = {"frame": self._frame, "n": n, "n_b": m, "threads": threads,
                      "path": "cross", "path_reason": "a second set of boxes was given",
                      "second_set_kept": bool(kept), "pairs": len(pairs),
                      "seconds": {"total": total}}
        return pairs

    def _update(self, lower, upper, threads):
        t_start = time.perf_counter()
        self._frame += 1
        geometry = None  # measured by auto, reused by the column path
        if self._path is not None:
            path, reason = self._path, f"path={self._path!r} was asked for"
        else:
            path, reason, geometry = self._choose(lower, upper, threads)
        if path == "columns":
            pairs = self._update_columns(lower, upper, threads, t_start, geometry)
        else:
            pairs = self._update_sap(lower, upper, threads, t_start, path)
        self.stats["path_reason"] = reason
        self._last_path = path
        st_ = self.stats
        self._history[path] = {"frame": self._frame, "n": st_["n"],
                               "seconds": st_["seconds"]["total"],
                               "tested": st_["candidates_tested"], "pairs": st_["pairs"]}
        return pairs

    def _update_sap(self, lower, upper, threads, t_start, path):
        n = lower.shape[0]
        parts = 1 if path == "sequential" else (self._partitions or threads)
        buckets = max(1, min(_SORT_BUCKETS, (2 * n) // _MIN_BUCKET))
        if self._partitions:
            buckets = max(buckets, min(self._partitions, max(1, 2 * n)))
        fresh = self._ensure(n, parts, buckets)
        a0, a1 = self._axes
        a2 = 3 - a0 - a1
        stats = {"frame": self._frame, "n": n, "threads": threads, "path": path,
                 "partitions": parts, "buckets": buckets, "fresh": fresh}
        if n < 2:
            pairs = np.empty((0, 2), np.int64)
            self._finish(stats, pairs, 0, {"sort": 0.0, "candidates": 0.0, "pairing": 0.0},
                         {a0: 0.0, a1: 0.0}, t_start)
            return pairs

        # Sorting (Algorithm 2; Algorithm 1 lines 5 and 15).
        t0 = time.perf_counter()
        disp = {}
        trusted = {}
        for axis, idx in ((a0, self._ix), (a1, self._iy)):
            b, trusted[axis] = self._bounds_for(axis, lower, upper, buckets)
            if path == "sequential":
                rs.sort_sequential(lower, upper, axis, self._keys, self._keys_tmp, idx,
                                   self._idx_tmp)
                rs.bucket_sizes_sorted(lower, upper, axis, idx, b, self._starts)
            else:
                rs.sort_parallel(lower, upper, axis, b, self._keys, self._keys_tmp, idx,
                                 self._idx_tmp, self._hist, self._starts, parts)
            disp[axis] = float(rs.dispersion(self._starts))
            rs.bounds_from_order(lower, upper, axis, idx, b)
        t1 = time.perf_counter()

        # Candidate generation and pairing.
        if path == "sequential":
            sw.candidates_sequential(self._ix, n, lower, upper, a0, a2, self._rank,
                                     self._rinv, self._lcand, self._ucand, self._br,
                                     self._trees_cand[0], self._off_full)
            t2 = time.perf_counter()
            cand_s = t2 - t1
            self._out = self._grow(self._out, 1, self._capacity(n, 1))
            while True:
                cnt, tested = sw.pairing_sequential(
                    self._iy, n, self._rank, self._rinv, self._lcand, self._ucand,
                    self._br, self._trees_cand[0], self._off_full, self._out[0])
                if cnt <= self._out.shape[1] // 2:
                    break
                self._out = self._grow(self._out, 1, cnt + cnt // 4)
            self._counts[0] = cnt
            counts = self._counts[:1]
        else:
            sw.candidates_parallel(self._ix, n, self._info, self._rinv, self._idx_tmp,
                                   self._trees_cand, self._off_full, self._counts)
            t2 = time.perf_counter()
            cand_s = t2 - t1
            z0, inv_h, reach, nbins = sw.third_axis_bins(lower, upper, a2, self.max_bins)
            pparts = self._pair_parts(n, nbins)
            delta = (n + pparts - 1) // pparts
            if self._pair_layout != (pparts, nbins, threads):
                self._pair_layout = (pparts, nbins, threads)
                self._off_part = st.layout(delta)
                self._trees_pair = np.empty((pparts, nbins * self._off_part[-1]), np.uint64)
                self._reg_count = np.zeros((threads, pparts), np.int64)
                self._reg_cap = None
                self._pcounts = np.zeros(pparts, np.int64)
                self._ptested = np.zeros(pparts, np.int64)
                self._pair_hint = None
            # Event regions per (chunk, partition), sized from the last frame.
            events = self._events
            if self._reg_cap is None:
                guess = (3 * n) // (threads * pparts)
                self._reg_cap = np.full((threads, pparts), guess, np.int64)
            while True:
                reg_start = np.zeros_like(self._reg_cap)
                flat = np.cumsum(self._reg_cap.ravel())
                reg_start.ravel()[1:] = flat[:-1]
                need = int(flat[-1])
                if need > events.shape[0]:
                    # Very long candidate ranges: more events than the scratch holds.
                    events = self._events = np.empty((need + need // 8, 2), np.int64)
                ok = sw.gather_parallel(self._iy, n, lower, upper, a0, a2, self._info,
                                        self._br, z0, inv_h, nbins, delta, reg_start,
                                        self._reg_cap, self._reg_count, events)
                used = self._reg_count
                self._reg_cap = used + used // 16 + 64
                if ok:
                    break
            stats["bins"] = nbins
            stats["pair_partitions"] = pparts
            stats["events"] = int(used.sum())
            self._out = self._grow(self._out, pparts, self._capacity(n, pparts))
            todo = np.ones(pparts, np.bool_)
            while True:
                sw.pairing_parallel(events, reg_start, self._reg_count, n, self._br,
                                    self._rinv, self._trees_pair, self._off_part, nbins, z0,
                                    inv_h, reach, self._out, self._pcounts, self._ptested,
                                    todo)
                need = int(self._pcounts.max())
                if need <= self._out.shape[1] // 2:
                    break
                todo = self._pcounts > self._out.shape[1] // 2
                self._out = self._grow(self._out, pparts, need + need // 4, keep=~todo)
            tested = int(self._ptested.sum())
            counts = self._pcounts
        total = int(counts.sum())
        pairs = np.empty((total, 2), np.int64)
        sw.assemble(self._out, counts, pairs)
        t3 = time.perf_counter()
        self._pair_hint = int(counts.max())
        _LAST_PAIRS_PER_BOX[0] = total / max(n, 1)
        self._finish(stats, pairs, tested,
                     {"sort": t1 - t0, "candidates": cand_s, "pairing": t3 - t1 - cand_s},
                     disp, t_start)
        self._sap_disp = dict(disp)
        self._maybe_swap(disp, trusted)
        return pairs

    # ------------------------------------------------------------ path choice
    def _choose(self, lower, upper, threads):
        """``(path, reason)`` for this frame (``path="auto"``).

        The column sweep, unless there are few boxes, or the grid predicts
        many candidates per box (boxes piled into few columns), or the last
        column frame tested many candidates per box and pair (then the paper's
        sweep runs for ``_AUTO_RETRY`` frames before the columns are tried
        again).  The paper's dispersion D, when it has run, is quoted.
        Returns ``(path, reason, geometry or None)``."""
        n = lower.shape[0]
        if n < _AUTO_MIN_BOXES:
            return "parallel", (f"{n} boxes: below {_AUTO_MIN_BOXES}, the paper's sweep "
                                "costs less than building columns"), None
        if self._frame < self._g_avoid_until:
            return "parallel", self._g_avoid_reason, None
        last = self._history.get("columns")
        if last is not None and last["frame"] == self._frame - 1:
            per = last["tested"] / max(last["pairs"] + last["n"], 1)
            if per > _AUTO_MAX_CANDIDATES:
                self._g_avoid_until = self._frame + _AUTO_RETRY
                self._g_avoid_reason = (
                    f"the column sweep tested {per:.0f} candidates per box and pair in "
                    f"frame {last['frame']} (above {_AUTO_MAX_CANDIDATES}): the paper's "
                    f"sweep until frame {self._g_avoid_until}")
                return "parallel", self._g_avoid_reason, None
        geo = self._geometry(lower, upper, threads)
        grid = self._bin_columns(lower, upper, threads, geo)
        pred = self._predict_candidates(geo, grid)
        if pred > _AUTO_MAX_PREDICTED:
            self._g_avoid_until = self._frame + _AUTO_RETRY
            self._g_avoid_reason = (
                f"the column grid {grid[7]} x {grid[8]} predicted {pred:.0f} candidates per "
                f"box in frame {self._frame} (above {_AUTO_MAX_PREDICTED}): the paper's "
                f"sweep until frame {self._g_avoid_until}")
            return "parallel", self._g_avoid_reason, geo
        reason = (f"{n} boxes, column grid {grid[7]} x {grid[8]} predicting {pred:.0f} "
                  f"candidates per box, sizes spread {geo['spread']:.1f}x, {geo['big']} in "
                  "the big list: the column sweep")
        if self._sap_disp:
            d = max(self._sap_disp.values())
            reason += f" (the paper's sort last had dispersion D = {d:.2f})"
        return "columns", reason, geo

    # ------------------------------------------------------------ column path
    def _geometry(self, lower, upper, threads):
        """Sizes and spans of this frame's boxes (one parallel pass) and the
        column grid they call for; see ``kernels/boxgrid.py``."""
        n = lower.shape[0]
        k = bg if threads > 1 else bg.serial
        m = max(1, min(_MEASURE_CHUNKS, n // 8192))
        if self._g_meas is None or self._g_meas[0].shape[0] != m:
            self._g_meas = (np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3)),
                            np.empty((m, bg.NBUCKETS), np.int64),
                            np.empty((m, bg.NBUCKETS, 3)))
        cmin, cmax, ssum, hist, hext = self._g_meas
        geo = {"n": n}
        if n == 0:
            geo.update(big_bucket=bg.NBUCKETS, big=0, spread=1.0, width=np.zeros(3),
                       cmin=np.zeros(3), cmax=np.zeros(3), typical=0.0, mean=np.zeros(3))
            return geo
        k.measure(lower, upper, cmin, cmax, ssum, hist, hext)
        counts = hist.sum(axis=0)
        nz = np.flatnonzero(counts)
        counts = counts[nz]
        ext = hext[:, nz].max(axis=0)
        cum = np.cumsum(counts)
        med = int(np.searchsorted(cum, (n + 1) // 2))
        suffix = n - np.concatenate(([0], cum[:-1]))  # boxes in buckets nz[j:]
        limit = n // _BIG_FRACTION
        j_big = len(nz)
        for j in range(med + 1, len(nz)):
            if suffix[j] <= limit and nz[j] >= nz[med] + 2:
                j_big = j
                break
        big_bucket = int(nz[j_big]) if j_big < len(nz) else bg.NBUCKETS
        big = int(suffix[j_big]) if j_big < len(nz) else 0
        width = ext[:j_big].max(axis=0) if j_big else np.zeros(3)
        top = float(width.max())
        typical = float(np.ldexp(1.0, int(nz[med]) - bg.OFFSET))  # above the median side
        geo.update(big_bucket=big_bucket, big=big, width=width, typical=typical,
                   spread=top / typical if typical > 0 and np.isfinite(top) else 1.0,
                   cmin=cmin.min(axis=0), cmax=cmax.max(axis=0), mean=ssum.sum(axis=0) / n)
        return geo

    def _grid(self, geo, lower, upper):
        """Column axes, sweep axis, origin, widths and counts of the grid."""
        n_small = geo["n"] - geo["big"]
        cmin, cmax = geo["cmin"].copy(), geo["cmax"].copy()
        mag = np.maximum(np.abs(cmin), np.abs(cmax))
        with np.errstate(over="ignore", invalid="ignore"):
            span = cmax - cmin
            w0 = geo["width"] * (1.0 + 1e-9) + 1e-12 * mag
        cap = max(1, n_small // _BOXES_PER_COLUMN)
        if n_small > 4 * _SAMPLE and np.all(np.isfinite(span)) and np.prod(
                np.minimum(span / np.maximum(w0 * _COLUMN_WIDTH, 1e-300), 1e9) + 1.0) > cap:
            # Too many columns for the boxes: a few far boxes may stretch the
            # span.  Bin over the range that holds all but 1% of a sample of
            # the centres; boxes outside go to the edge columns (clamping keeps
            # neighbouring columns neighbours).
            step = n_small // _SAMPLE
            centre = 0.5 * lower[::step] + 0.5 * upper[::step]
            q = np.quantile(centre, [0.005, 0.995], axis=0)
            pad = 0.01 * (q[1] - q[0]) + w0
            lo_q, hi_q = q[0] - pad, q[1] + pad
            keep = (hi_q - lo_q) < 0.5 * span
            cmin = np.where(keep, lo_q, cmin)
            cmax = np.where(keep, hi_q, cmax)
            span = cmax - cmin
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            # the margin covers the rounding of centres and of the binning
            w = geo["width"] * (1.0 + 1e-9) + 1e-12 * mag
            w = np.where(np.isnan(w), np.inf, w)
            bins = np.where((w > 0) & np.isfinite(span) & np.isfinite(w), span / w, 0.0) + 1.0
        z = int(np.argmin(bins))
        if self._g_z is not None and bins[self._g_z] <= 2.0 * bins[z]:
            z = self._g_z  # hysteresis: keep the axis the kept order is sorted on
        c0, c1 = (a for a in range(3) if a != z)
        ws = [0.0, 0.0]
        nb = [1, 1]
        for a, c in enumerate((c0, c1)):
            s, wa = float(span[c]), float(w[c])
            if not (np.isfinite(s) and s > 0) or wa == np.inf or not np.isfinite(s / max(
                    wa, 1e-300)):
                continue  # one column along this axis
            # zero-size sides: pairs share the coordinate, any width will do
            nb[a] = _MAX_SIDE if wa == 0.0 else int(min(s / (_COLUMN_WIDTH * wa), _MAX_SIDE))
            nb[a] = max(nb[a], 1)
            ws[a] = s / nb[a]  # columns tile the centres' span exactly, no narrower than wa
            if ws[a] < wa:
                ws[a] = wa
        while nb[0] * nb[1] > cap:
            f = float(np.sqrt(nb[0] * nb[1] / cap))
            for a, c in enumerate((c0, c1)):
                if nb[a] > 1:
                    s = float(span[c])
                    nb[a] = max(1, int(nb[a] / f))
                    ws[a] = max(ws[a], s / nb[a])
        inv = [0.0, 0.0]
        for a in range(2):
            if nb[a] > 1:
                inv[a] = 1.0 / ws[a]
                if not np.isfinite(inv[a]):
                    nb[a], inv[a] = 1, 0.0
        # largest small side per axis with the rounding margin (inf if it overflowed)
        reach = [float(w[c0]), float(w[c1]), float(w[z])]
        return (c0, c1, z, float(cmin[c0]), float(cmin[c1]), inv[0], inv[1], nb[0], nb[1], ws,
                reach)

    def _bin_columns(self, lower, upper, threads, geo):
        """Grid, column of every box and the counting sort by column over the
        previous frame's order; returns the grid (also kept for the sweep)."""
        n = lower.shape[0]
        k = bg if threads > 1 else bg.serial
        grid = self._grid(geo, lower, upper)
        c0, c1, z, o0, o1, inv0, inv1, nb0, nb1, ws, reach = grid
        ncol = nb0 * nb1
        fresh = self._g_perm is None or self._g_perm.shape[0] != n
        if fresh:
            self._g_perm = np.arange(n, dtype=np.int64)
            self._g_prev = np.empty(n, np.int64)
            self._g_col = np.empty(n, np.int64)
            self._g_soa = np.empty((6, n))
            self._g_caps = None
        fresh = fresh or self._g_z != z
        self._g_z = z
        chunks = max(1, min(_MEASURE_CHUNKS, n // 8192))
        k.bin_boxes(lower, upper, c0, c1, o0, o1, inv0, inv1, nb0, nb1, geo["big_bucket"],
                    chunks, self._g_col)
        # counting sort by column over the previous frame's order
        self._g_prev, self._g_perm = self._g_perm, self._g_prev
        if self._g_start is None or self._g_start.shape[0] < ncol + 2:
            self._g_start = np.empty(ncol + 2, np.int64)
            self._g_chunks = np.empty(ncol + 2, np.int64)
        start = self._g_start[:ncol + 2]
        column_kernels.serial.counting_sort(self._g_col, self._g_prev, ncol + 1, start,
                                            self._g_perm, np.empty((1, ncol + 1), np.int64))
        self._g_binned = (self._frame, grid, fresh)
        return grid

    def _predict_candidates(self, geo, grid):
        """Candidates per box the column sweep would test if the boxes were
        spread evenly along the sweep axis inside each column: half the pairs
        of boxes in neighbouring columns, times the fraction of a column's
        length that a typical box's window covers."""
        nb0, nb1 = grid[7], grid[8]
        z = grid[2]
        n_small = geo["n"] - geo["big"]
        if n_small < 2:
            return 0.0
        occ = np.diff(self._g_start[:nb0 * nb1 + 1]).reshape(nb0, nb1).astype(np.float64)
        pad = np.pad(occ, 1)
        near = sum(pad[1 + a:1 + a + nb0, 1 + b:1 + b + nb1]
                   for a in (-1, 0, 1) for b in (-1, 0, 1))
        side = 0.75 * geo["typical"]  # the middle of the median size bucket
        length = float(geo["cmax"][z] - geo["cmin"][z]) + side
        frac = min(1.0, side / length) if length > 0 and np.isfinite(length) else 1.0
        return 0.5 * float((occ * near).sum()) * frac / n_small

    def _update_columns(self, lower, upper, threads, t_start, geo):
        n = lower.shape[0]
        k = bg if threads > 1 else bg.serial
        if geo is None:
            geo = self._geometry(lower, upper, threads)
        stats = {"frame": self._frame, "n": n, "threads": threads, "path": "columns"}
        if n < 2:
            pairs = np.empty((0, 2), np.int64)
            self._finish(stats, pairs, 0, {"sort": 0.0, "candidates": 0.0, "pairing": 0.0},
                         {a: 0.0 for a in self._axes}, t_start)
            return pairs
        if self._g_binned is None or self._g_binned[0] != self._frame:
            self._bin_columns(lower, upper, threads, geo)
        _, grid, fresh = self._g_binned
        c0, c1, z, o0, o1, inv0, inv1, nb0, nb1, ws, reach = grid
        h0, h1, reach_z = 0.5 * reach[0], 0.5 * reach[1], reach[2]
        # the half stencil when the largest small side on the sweep axis is
        # close to the mean one (its windows are longer by that side)
        half = bool(reach_z <= _HALF_STENCIL * float(geo["mean"][z]))
        ncol = nb0 * nb1
        start = self._g_start[:ncol + 2]
        perm = self._g_perm
        nch = bg.column_chunks(start, ncol + 1, _CHUNK_BOXES, self._g_chunks)
        sort_chunks = self._g_chunks[:nch + 1]
        xl, xu, yl, yu, zl, zu = self._g_soa
        k.sort_columns(sort_chunks, start, perm, lower, upper, c0, c1, z, fresh, xl, xu, yl,
                       yu, zl, zu)
        t1 = time.perf_counter()
        sweep_chunks = np.minimum(sort_chunks, ncol)
        big0 = int(start[ncol])
        n_big = n - big0
        big_chunks = np.arange(0, n_big + _BIG_CHUNK, _BIG_CHUNK, dtype=np.int64)
        big_chunks[-1] = n_big
        if n_big == 0:
            big_chunks = np.zeros(1, np.int64)
        # one region per chunk of columns, then per chunk of big boxes, sized
        # from the last frame (temporal coherence)
        rows = np.concatenate((np.diff(start[sweep_chunks]), np.diff(big_chunks)))
        nreg = len(rows)
        ratio = self._g_ratio or min(max(_LAST_PAIRS_PER_BOX[0], 2.0), _MAX_PAIRS_HINT)
        caps = (rows * (1.25 * ratio)).astype(np.int64) + 64
        if self._g_caps is not None and len(self._g_caps) == nreg:
            caps = np.maximum(self._g_caps, caps // 2)
        need = np.zeros(nreg, np.int64)
        tested = np.zeros(nreg, np.int64)
        todo = np.ones(nreg, np.bool_)
        reg = np.zeros(nreg, np.int64)
        reg[1:] = np.cumsum(caps)[:-1]
        end = int(caps.sum())
        if self._g_out is None or self._g_out.shape[0] < 2 * end:
            self._g_out = np.empty(2 * end + end // 4, np.int64)
        ns = len(sweep_chunks) - 1
        while True:
            if todo[:ns].any():
                k.sweep(sweep_chunks, start, nb0, nb1, o0, o1, inv0, inv1, h0, h1, reach_z, half,
                        xl, xu, yl, yu, zl, zu, perm, self._g_out, reg[:ns], caps[:ns],
                        todo[:ns], need[:ns], tested[:ns])
            if n_big and todo[ns:].any():
                k.sweep_big(big_chunks, big0, start, nb0, nb1, o0, o1, inv0, inv1, reach_z,
                            xl, xu, yl, yu, zl, zu, perm, self._g_out, reg[ns:], caps[ns:],
                            todo[ns:], need[ns:], tested[ns:])
            todo = need > caps
            if not todo.any():
                break
            # overflowed regions move to the end of the buffer and run again
            grown = need[todo] + need[todo] // 4 + 64
            reg[todo] = end + np.concatenate(([0], np.cumsum(grown)[:-1]))
            caps[todo] = grown
            end += int(grown.sum())
            if self._g_out.shape[0] < 2 * end:
                old = self._g_out
                self._g_out = np.empty(2 * end + end // 4, np.int64)
                self._g_out[:old.shape[0]] = old
        self._g_caps = caps
        total = int(need.sum())
        big_pairs = np.empty((0, 2), np.int64)
        big_tested = 0
        if n_big > 1:
            ids = perm[big0:]
            if self._g_big_engine is None:
                self._g_big_engine = SweepAndPrune(path="parallel", n_threads=threads)
            sub = self._g_big_engine
            sub.n_threads = threads
            bp = sub.update(lower[ids], upper[ids])
            big_tested = sub.stats["candidates_tested"]
            a, b = ids[bp[:, 0]], ids[bp[:, 1]]
            big_pairs = np.stack((np.minimum(a, b), np.maximum(a, b)), axis=1)
        pairs = np.empty((total + len(big_pairs), 2), np.int64)
        k.assemble(self._g_out, reg, need, pairs)
        pairs[total:] = big_pairs
        t2 = time.perf_counter()
        self._g_ratio = max(len(pairs) / n, 0.5)
        _LAST_PAIRS_PER_BOX[0] = len(pairs) / n
        stats.update(columns={"axes": (c0, c1), "sweep_axis": z, "grid": (nb0, nb1),
                              "width": tuple(ws), "big": n_big, "chunks": ns,
                              "stencil": "half" if half else "forward",
                              "big_bucket_side": float(np.ldexp(1.0, geo["big_bucket"] - 1
                                                                - bg.OFFSET))
                              if n_big else None,
                              "spread": geo["spread"], "fresh": bool(fresh)})
        # dispersion D (equation 1) of the small boxes over the grid's slabs along
        # each column axis: how unevenly the columns fill
        occ = np.diff(start[:ncol + 1]).reshape(nb0, nb1)
        n_small = max(n - n_big, 1)
        disp = {c0: float(np.abs(occ.sum(axis=1) - n_small / nb0).sum() / n_small),
                c1: float(np.abs(occ.sum(axis=0) - n_small / nb1).sum() / n_small)}
        self._finish(stats, pairs, int(tested.sum()) + big_tested,
                     {"sort": t1 - t_start, "candidates": 0.0, "pairing": t2 - t1}, disp,
                     t_start,
                     axes=(c0, c1))
        return pairs

    def _pair_parts(self, n, nbins):
        """Rank partitions of the pairing phase: small enough that a
        partition's sharded SuccTree stays in L2 cache, and enough of them
        for the threads, from ``n`` and ``nbins`` only (the rows are written
        partition by partition: their order must not depend on the threads)."""
        if self._partitions:
            return self._partitions
        target = max(4096, _PAIR_TREE_BITS // max(nbins, 1))
        parts = max(-(-n // target), min(_PAIR_PARTS, -(-n // _PAIR_PART_MIN)))
        if parts > _PAIR_PARTS:
            parts = -(-parts // _PAIR_PARTS) * _PAIR_PARTS
        return parts

    def _capacity(self, n, parts):
        """Pairs each partition's buffer should hold (a guess; it grows)."""
        if self._pair_hint is not None:
            return max(1024, self._pair_hint + self._pair_hint // 8)
        ratio = min(max(_LAST_PAIRS_PER_BOX[0], 2.0), _MAX_PAIRS_HINT)
        return 1024 + int(1.25 * ratio * n / parts)

    @staticmethod
    def _grow(out, parts, cap, keep=None):
        if out.shape[0] == parts and out.shape[1] >= 2 * cap:
            return out
        new = np.empty((parts, 2 * cap), np.int64)
        if keep is not None and out.shape[0] == parts:
            w = min(out.shape[1], new.shape[1])
            for p in np.flatnonzero(keep):
                new[p, :w] = out[p, :w]
        return new

    def _finish(self, stats, pairs, tested, seconds, disp, t_start, axes=None):
        seconds = dict(seconds)
        seconds["total"] = time.perf_counter() - t_start
        axes = tuple(self._axes) if axes is None else axes
        stats.update(seconds=seconds, axes=axes, dispersion=disp,
                     swaps=self._swaps, candidates_tested=int(tested), pairs=len(pairs))
        self.stats = stats

    def _maybe_swap(self, disp, trusted):
        """Section 5: swap the most dispersed sweep axis with the unused one."""
        if not self._dynamic:
            return
        a0, a1 = self._axes
        worst = max((a0, a1), key=lambda a: disp[a])
        if not trusted[worst] or disp[worst] <= self.swap_threshold:
            return
        unused = 3 - a0 - a1
        self._axes = (unused, a1) if worst == a0 else (a0, unused)
        self._bounds.pop(unused, None)  # re-initialised from the span
        self._swaps += 1


#: cross-set grid: boxes of the second set spanning more cells than this, and
#: boxes of the first visiting more, go to the cross-set sweep instead
_CROSS_MAX_SPAN = 64
_CROSS_MAX_VISIT = 512
#: one thread runs the whole query in one pass (``grid_query``) up to this many
#: boxes of the second set spanning many cells (each tested against every box)
_FUSED_BIG = 16


def _cross_axis(lower, upper, lower_b, upper_b):
    """Sweep axis of the cross-set sweep: the one with the fewest expected
    candidates, ``n m (mean side of A + mean side of B) / span`` (boxes spread
    evenly over the span of both sets), from the data only."""
    best, axis = np.inf, 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for c in range(3):
            span = max(float(upper[:, c].max()), float(upper_b[:, c].max())) - min(
                float(lower[:, c].min()), float(lower_b[:, c].min()))
            side = float(np.mean(upper[:, c] - lower[:, c])) + float(
                np.mean(upper_b[:, c] - lower_b[:, c]))
            cost = side / span if span > 0 else np.inf
            if not np.isfinite(cost):
                cost = np.inf
            if cost < best:
                best, axis = cost, c
    return axis


def _cross_sweep(kern, lower, upper, lower_b, upper_b, rows_a, rows_b):
    """Pairs (row of A, row of B) of the boxes ``rows_a`` against ``rows_b``
    by the cross-set sweep (``kernels/cross.py``)."""
    if len(rows_a) == 0 or len(rows_b) == 0:
        return np.empty((0, 2), np.int64)
    la, ua, lb, ub = lower[rows_a], upper[rows_a], lower_b[rows_b], upper_b[rows_b]
    axis = _cross_axis(la, ua, lb, ub)
    o1, o2 = (axis + 1) % 3, (axis + 2) % 3

    def soa(lo, hi):
        order = np.argsort(lo[:, axis], kind="stable")
        cols = [lo[order, axis], hi[order, axis], lo[order, o1], hi[order, o1],
                lo[order, o2], hi[order, o2]]
        return np.ascontiguousarray(np.stack(cols, axis=1)), order

    sa, oa = soa(la, ua)
    sb, ob = soa(lb, ub)
    cnt_a = np.empty(len(sa), np.int64)
    cnt_b = np.empty(len(sb), np.int64)
    key_a = np.ascontiguousarray(sa[:, 0])
    key_b = np.ascontiguousarray(sb[:, 0])
    kern.sweep_count(sa, key_a, sb, key_b, cnt_a, cnt_b)
    off = np.zeros(len(sa) + len(sb) + 1, np.int64)
    np.cumsum(np.concatenate((cnt_a, cnt_b)), out=off[1:])
    out = np.empty((int(off[-1]), 2), np.int64)
    if len(out):
        kern.sweep_fill(sa, key_a, sb, key_b, np.ascontiguousarray(rows_a[oa]),
                        np.ascontiguousarray(rows_b[ob]), off[:len(sa)], off[len(sa):-1], out)
    return out


def _cross_grid_plan(lower, upper, lower_b, upper_b, *, kept=False, memo=None):
    """The grid of the cross-set query: (lower corner, upper corner, inverse cell
    sides, cells per axis), or None when no box can overlap.

    One call (``kept=False``) grids the region where both sets' spans meet.
    A kept second set (``kept=True``, ``SweepAndPrune``) grids the second
    set's own span with cell sides rounded up to a power of two, so that the
    grid, and the second set's binning, stay while that set does; ``memo`` (a
    dict) then keeps the last plan, returned itself (the same tuple) while the
    second set's span, the rounded sides and the count are the same.
    """
    if kept:
        # one pass over both sets gives all the plan depends on: the memo's key
        got = np.empty((3, 3))
        if not _cross.kept_plan_key(lower, upper, lower_b, upper_b, got):
            return None
        n_all = 2 * len(lower_b)
        key = (got.tobytes(), n_all)
        if memo is not None:
            last = memo.get("plan")
            if last is not None and last[0] == key:
                return last[1]
        lo, hi, side = got[0], got[1], got[2]
    else:
        lo_a, hi_a, side_a = np.empty(3), np.empty(3), np.empty(3)
        lo_b, hi_b, side_b = np.empty(3), np.empty(3), np.empty(3)
        _cross.extent(lower, upper, lo_a, hi_a, side_a)
        _cross.extent(lower_b, upper_b, lo_b, hi_b, side_b)
        if (np.maximum(lo_a, lo_b) > np.minimum(hi_a, hi_b)).any():
            return None
        lo, hi = np.maximum(lo_a, lo_b), np.minimum(hi_a, hi_b)
        side = np.maximum(side_a, side_b)
        n_all = len(lower) + len(lower_b)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        ext = hi - lo
        dims = np.ones(3)
        for c in range(3):
            if not (ext[c] > 0 and np.isfinite(ext[c])):
                continue
            if side[c] > 0 and np.isfinite(side[c]):
                dims[c] = max(1.0, min(np.floor(ext[c] / side[c]), float(_MAX_SIDE)))
            else:  # points along this axis: about n^(1/3) cells
                dims[c] = max(1.0, np.floor(np.cbrt(n_all)))
        cap = 2.0 * n_all + 64.0
        while np.prod(dims) > cap:
            dims = np.maximum(1.0, np.floor(dims / np.cbrt(np.prod(dims) / cap)))
        inv = np.where(dims > 1, dims / np.where(ext > 0, ext, 1.0), 0.0)
        inv = np.where(np.isfinite(inv), inv, 0.0)
    dims = np.where(inv > 0, dims, 1.0).astype(np.int64)
    plan = (lo, hi, inv, dims)
    if kept and memo is not None:
        memo["plan"] = (key, plan)
    return plan


def _cross_bin(kern, lower_b, upper_b, plan):
    """The second set's boxes by cell of the grid ``plan`` (those spanning more
    than ``_CROSS_MAX_SPAN`` cells apart, for the sweep)."""
    lo, hi, inv, dims = plan
    span_b = np.empty(len(lower_b), np.int64)
    kern.spans(lower_b, upper_b, lo, inv, dims, span_b)
    big = span_b > _CROSS_MAX_SPAN
    small = np.flatnonzero(~big)
    start = np.zeros(int(np.prod(dims)) + 1, np.int64)
    members = np.empty(int(span_b[small].sum()), np.int64)
    if len(small):
        _cross.bin_boxes(lower_b, upper_b, small, lo, inv, dims, start, members)
    return small, np.flatnonzero(big), start, members


def _cross_query(kern, lower, upper, lower_b, upper_b, plan, binned):
    """Pairs (a, b), rows sorted, of the first set against the binned second."""
    n, m = lower.shape[0], lower_b.shape[0]
    lo, hi, inv, dims = plan
    small_b, big_b, start, members = binned
    if kern is _cross.serial and len(big_b) <= _FUSED_BIG:
        # one thread: the whole query in one serial pass, unless a box of A
        # visits too many cells (then the general passes below)
        out = np.empty((2 * n + 64, 2), np.int64)
        k = _cross.grid_query(lower, upper, lower_b, upper_b, lo, hi, inv, dims, start,
                              members, big_b, _CROSS_MAX_VISIT, out)
        if k > len(out):
            out = np.empty((k, 2), np.int64)
            k = _cross.grid_query(lower, upper, lower_b, upper_b, lo, hi, inv, dims, start,
                                  members, big_b, _CROSS_MAX_VISIT, out)
        if k >= 0:
            return out[:k]
    span_a = np.empty(n, np.int64)
    kern.spans(lower, upper, lo, inv, dims, span_a)
    big_a = span_a > _CROSS_MAX_VISIT
    small_a = np.flatnonzero(~big_a)
    parts = []
    if len(small_a) and len(small_b):
        cnt = np.empty(len(small_a), np.int64)
        kern.grid_count(lower, upper, lower_b, upper_b, small_a, lo, hi, inv, dims, start,
                        members, cnt)
        # the fill pass visits only the boxes that found pairs
        found = np.flatnonzero(cnt)
        off = np.zeros(len(found) + 1, np.int64)
        np.cumsum(cnt[found], out=off[1:])
        out = np.empty((int(off[-1]), 2), np.int64)
        if len(out):
            kern.grid_fill(lower, upper, lower_b, upper_b, small_a[found], lo, hi, inv, dims,
                           start, members, off[:-1], out)
        parts.append(out)
    parts.append(_cross_sweep(kern, lower, upper, lower_b, upper_b, np.arange(n), big_b))
    parts.append(_cross_sweep(kern, lower, upper, lower_b, upper_b, np.flatnonzero(big_a),
                              small_b))
    out = np.concatenate(parts)
    if len(out) > 1:
        if n * m < (1 << 62):
            out = out[np.argsort(out[:, 0] * m + out[:, 1], kind="stable")]
        else:  # pragma: no cover - more than 2**31 boxes in each set
            out = out[np.lexsort((out[:, 1], out[:, 0]))]
    return out


def _cross_overlaps(lower, upper, lower_b, upper_b, threads):
    """Pairs (a, b) of overlapping boxes of two validated sets, rows sorted."""
    if lower.shape[0] == 0 or lower_b.shape[0] == 0:
        return np.empty((0, 2), np.int64)
    kern = _cross if threads > 1 else _cross.serial
    plan = _cross_grid_plan(lower, upper, lower_b, upper_b)
    if plan is None:
        return np.empty((0, 2), np.int64)
    binned = _cross_bin(kern, lower_b, upper_b, plan)
    return _cross_query(kern, lower, upper, lower_b, upper_b, plan, binned)


def _second_set(lower_b, upper_b):
    """Both corners of the second set validated, or a ValueError naming the missing one."""
    if lower_b is None or upper_b is None:
        given, missing = ("lower_b", "upper_b") if upper_b is None else ("upper_b", "lower_b")
        raise ValueError(f"{given} was given without {missing}; give both corners of the "
                         "second set, or neither for pairs within one set")
    return _check_boxes(lower_b, upper_b, ("lower_b", "upper_b"))


def box_overlaps(lower, upper, lower_b=None, upper_b=None, *, n_threads=None):
    """All pairs of overlapping axis-aligned boxes, in one set or across two.

    With one set, one call of a fresh :class:`SweepAndPrune` with
    ``path="auto"``: the column sweep for boxes of similar sizes, the paper's
    parallel sweep for few boxes or widely spread sizes (docs/boxes.md).
    With a second set (``lower_b``, ``upper_b``), every pair of a box of the
    first set and a box of the second that overlap (a cross-set query:
    spheres against the triangles of a wall, a reference against a
    configuration), from a sweep over both sets with set labels
    (``kernels/cross.py``).

    Parameters
    ----------
    lower, upper : (n, 3) array_like of float
        Minimum and maximum corners.  Boxes are closed (touching counts).
    lower_b, upper_b : (m, 3) array_like of float, optional
        The second set's corners; give both or neither.
    n_threads : int, optional
        Numba threads; ``None`` keeps numba's setting.

    Returns
    -------
    pairs : (k, 2) ndarray of int64
        One set: each overlapping pair once with ``i < j``; rows are not
        sorted, but their order is the same on any thread count
        (docs/boxes.md, "Row order").  Two sets: ``(a, b)`` with ``a`` a row of the first set
        and ``b`` a row of the second, rows sorted (by ``a``, then ``b``).

    Raises
    ------
    ValueError
        NaN or inf, wrong shapes, mismatched lengths, ``lower > upper`` (or
        ``lower_b > upper_b``), or only one of ``lower_b`` and ``upper_b``.
    TypeError
        Non-numeric input or a non-integer ``n_threads``.

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import box_overlaps
    >>> lower = np.array([[0.0, 0, 0], [0.5, 0.5, 0.5], [2.0, 2, 2]])
    >>> box_overlaps(lower, lower + 1.0)
    array([[0, 1]])
    >>> box_overlaps(lower, lower + 1.0, [[1.0, 1, 1]], [[2.0, 2, 2]])
    array([[0, 0],
           [1, 0],
           [2, 0]])
    """
    if lower_b is None and upper_b is None:
        return SweepAndPrune(n_threads=n_threads).update(lower, upper)
    threads = check_n_threads(n_threads)
    lower, upper = _check_boxes(lower, upper)
    lower_b, upper_b = _second_set(lower_b, upper_b)
    if threads is None and len(lower) + len(lower_b) < _PARALLEL_MIN:
        threads = 1
    with num_threads(threads) as threads:
        return _cross_overlaps(lower, upper, lower_b, upper_b, threads)
