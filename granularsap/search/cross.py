"""The cross-set query's kept state (``NeighborSearch.query``,
``ContactSearch.query``): the configuration's column grid and the query's
output buffers, and what a query does after its passes (exact tiny
separations, the memory check, the half-width de-duplication)."""

from __future__ import annotations

import math
import time

import numpy as np

from .. import _memory
from .._numba import get_threads, num_threads
from ..kernels import grid, query
from . import plan
from .frame import (
    FAR,
    GUARD,
    NO_RADII,
    TINY_D,
    check_half_width,
    exp2,
    far_scale,
    frame_scale,
    raise_unwrappable,
    scan_frame,
    square_bound,
)

#: reference points per chunk of a query's parallel passes (boundaries depend on
#: the number of reference points only)
QUERY_CHUNK = 256
#: below this many points in all one thread runs (``engine.PARALLEL_MIN``)
PARALLEL_MIN = 20000
#: ``todo`` of a query's one chunk (read by the kernel, never written)
_ONE_CHUNK = np.ones(1, np.bool_)
_NO_ENTRIES = np.zeros(0, np.int64)


class CrossQuery:
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
                                    plan.wrap_chunks(m))
        if bad >= 0:
            return bad
        pbc, widths = cs.pbc, cs.widths
        lo = np.zeros(3)
        span = np.ones(3)
        for c in range(2):
            if not pbc[c]:
                lo[c] = t[:, c].min()
                span[c] = t[:, c].max() - lo[c]
        inv_f = np.zeros(2)
        f = np.zeros(2)
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            nb = plan.column_counts(span, rng / widths, m)
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
        segments = 1 if kern is grid.serial else min(get_threads(),
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

    def run(self, reference, ref_r, configuration, conf_r, skin, cs, *, minimum, strict,
            quantities, layout, n_threads, names):
        """One cross-set query of validated inputs: pairs ``(i, j)`` of
        ``reference[i]`` and ``configuration[j]`` with ``d <= (ref_r[i] +
        conf_r[j]) + skin`` in the cell ``cs`` (a ``FrameCell``), the
        configuration's grid kept while it, its radii, the cell and the frame's
        scale come back.  ``names``: the argument names of messages (reference,
        configuration, the range, the largest range, the smallest threshold).
        Returns (output set, pairs, CSR offsets by reference point, stats)."""
        t_start = time.perf_counter()
        n, m = len(reference), len(configuration)
        scan_r = scan_frame(reference, ref_r, NO_RADII)
        if scan_r[0] >= 0:
            raise ValueError(f"{names[0]} must be finite, got NaN or inf in row {scan_r[0]}")
        same = (self.conf is not None and len(self.conf) == m and np.array_equal(self.conf,
                                                                              configuration)
                and np.array_equal(self.conf_r, conf_r))
        scan_c = self.scan if same else scan_frame(configuration, conf_r, NO_RADII)
        if scan_c[0] >= 0:
            raise ValueError(f"{names[1]} must be finite, got NaN or inf in row {scan_c[0]}")
        rmax_r, rmax_c = (scan_r[5] if n else 0.0), (scan_c[5] if m else 0.0)
        reach_max = rmax_r + rmax_c + skin
        if cs.cell is not None and minimum:
            check_half_width(cs, reach_max, names[3])
        q = quantities
        times = {}
        stats = {"query": True, "n_reference": n, "n_configuration": m, "threads": 1,
                 "grid": "none", "grid_builds": self.builds, "columns": (0, 0),
                 "candidates_tested": 0, "pairs": 0, "seconds": times}
        if n == 0 or m == 0:
            buf = self.outputs(0, ("d" in q, "D" in q, "S" in q))
            times["total"] = time.perf_counter() - t_start
            return buf, 0, np.zeros(n + 1, np.int64), stats
        big = max(scan_r[1], scan_c[1], cs.magnitude)
        fine = min(scan_r[2], scan_c[2], cs.fine)
        thr_min = scan_r[4] + scan_c[4] + skin
        k = frame_scale(big, fine, reach_max, thr_min, *names[2:])
        scale = math.ldexp(1.0, k) if k else 1.0
        fine_q = max(exp2(fine) - 53, -1074) if math.isfinite(fine) else None
        # tiny separations whose squares the scale lets underflow: recomputed
        tiny = fine_q is not None and fine_q + exp2(scale) - 1 < -480
        cs_s = cs.scaled(scale) if scale != 1.0 else cs
        xr, xc = reference, configuration
        rr, rc, skin_s = ref_r, conf_r, skin
        if scale != 1.0:
            xr, xc, rr, rc, skin_s = xr * scale, xc * scale, rr * scale, rc * scale, skin * scale
        range_s = reach_max * scale
        key = (cs.key, scale)
        threads = n_threads
        if threads is None and n + m < PARALLEL_MIN:
            threads = 1
        serial = threads == 1 or (m < PARALLEL_MIN and n < 2 * QUERY_CHUNK)
        # (serial kernels only: no thread setting, as small frames of update)
        with num_threads(None if serial else threads) as threads:
            if serial:
                threads = 1
            gkern = grid.serial if threads == 1 else grid
            qkern = query.serial if threads == 1 or n < 2 * QUERY_CHUNK else query
            t0 = time.perf_counter()
            if same and self.key == key and self.range <= 2.0 * range_s + 1e-300:
                stats["grid"] = "kept"
            else:
                # the grid keeps its own copy (the given array may be edited in place)
                kept = self.buffer("conf", configuration.shape, np.float64)
                np.copyto(kept, configuration)
                bad = self.build(kept, conf_r, kept * scale if scale != 1.0 else kept, rc, cs_s,
                               key, range_s, gkern, scan_c)
                raise_unwrappable(configuration, bad, names[1])
                stats["grid"] = "built"
            g = self.grid
            t1 = time.perf_counter()
            times["grid"] = t1 - t0
            tr = np.empty((n, 3))
            kr = np.empty((n, 3), np.int64)
            wr = np.empty((n, 3))
            bad, wext_r, kmax_r = gkern.wrap(xr, cs_s.hinv, cs_s.matrix, cs_s.diag, cs_s.pbc,
                                             tr, kr, wr, plan.wrap_chunks(n))
            raise_unwrappable(reference, bad, names[0])
            wext = max(float(wext_r), self.wk[0])
            kmax = max(int(kmax_r), self.wk[1])
            pbc_s = cs_s.pbc
            far = bool(GUARD * wext > far_scale(range_s, cs_s.min_periodic_width) * FAR
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
                memo = self.square
                if memo[0] != thr:
                    memo = self.square = (thr, square_bound(*thr))
                x2 = memo[1]
            lo2, hi2, dtol, exact = grid.frame_band(wext, kmax, cs_s.matrix, pbc_s,
                                                    cs_s.widths, range_s, range_s, x2)
            guard = GUARD * (wext + range_s) + np.finfo(np.float64).tiny
            if pbc_s.any() and guard > 0.25 * cs_s.min_periodic_width:
                raise ValueError(
                    f"{names[0]} and {names[1]} up to {big!r} in magnitude: their rounding "
                    f"(about {guard / scale:.3g}) exceeds a quarter of the cell width "
                    f"{cs.min_periodic_width:.17g}; give coordinates nearer the cell")
            inv_w = 1.0 / cs_s.widths
            gap = pbc_s | (not far)  # (no gap test along open axes of a far frame)
            if n > QUERY_CHUNK:  # visited column by column (the grid's memory in order)
                col = np.empty(n, np.int64)
                gkern.columns_of(tr, np.array([g.lo0, g.lo1, 0.0]),
                                 np.array([g.inv_f0, g.inv_f1, 0.0]), g.nb0, g.nb1, col)
                order = np.argsort(col, kind="stable")
            else:
                order = np.arange(n, dtype=np.int64)
            ref = query.Ref(xr, tr, kr, wr, rr, order)
            ts = query.Test(cs_s.matrix, pbc_s.copy(), bool(cs_s.diag), inv_w, float(skin_s),
                            strict, bool(uniform), float(x2), float(lo2), float(hi2), float(dtol),
                            bool(exact), self.rmax, float(skin_s + guard + dtol),
                            float(guard), gap)
            n_chunks = (n + QUERY_CHUNK - 1) // QUERY_CHUNK
            counts = np.empty(n, np.int64)
            tested = np.empty(n_chunks, np.int64)
            dedup = (minimum and cs.cell is not None
                     and 2.0 * reach_max >= cs.min_periodic_width * (1.0 - 1e-9))
            want = ("d" in q or dedup or tiny, "D" in q, "S" in q or tiny)
            t2 = time.perf_counter()
            times["wrap"] = t2 - t1
            rec, wstart, wneed = self.pass1(qkern, g, ref, ts, counts, tested, QUERY_CHUNK)
            offsets = np.zeros(n + 1, np.int64)
            np.cumsum(counts, out=offsets[1:])
            total = int(offsets[-1])
            t3 = time.perf_counter()
            times["count"] = t3 - t2
            query_memory(total, q, layout)
            buf = self.outputs(total, want)
            out = query.Out(buf["p"], buf["d"], buf["v"], buf["s"], *want)
            if total:
                qkern.fill(g, ref, ts, rec, wstart, wneed, offsets, out)
            times["fill"] = time.perf_counter() - t3
        if dedup and total:
            total = query_dedup(buf, total, m)
            if total < offsets[-1]:
                offsets = np.searchsorted(buf["p"][:total, 0], np.arange(n + 1)).astype(np.int64)
        if total and (scale != 1.0 or tiny):
            d, v = buf["d"][:total], buf["v"][:total]
            if scale != 1.0:
                inv = 1.0 / scale
                d *= inv
                v *= inv
            if tiny:
                rows = np.flatnonzero(d < TINY_D / scale) if fine_q + k >= -1074 else (
                    np.arange(total))
                if len(rows):
                    query_tiny(reference, configuration, cs, buf["p"], buf["s"], d, v, rows)
        times["total"] = time.perf_counter() - t_start
        stats.update(threads=threads, grid_builds=self.builds, columns=(g.nb0, g.nb1),
                     candidates_tested=int(tested.sum()), pairs=total)
        return buf, total, offsets, stats

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


def query_tiny(reference, configuration, cs, pairs, shifts, d, v, rows):
    """Distances and vectors of ``rows`` of a query recomputed from the given
    positions and the lattice shifts (``SearchEngine._exact_small`` with two sets):
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


def query_memory(total, quantities, layout):
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


def query_dedup(buf, total, m):
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

