"""The cross-set query's kept state (``NeighborSearch.query``,
``ContactSearch.query``): the configuration's column grid and the query's
output buffers, and what a query does after its passes (exact tiny
separations, the memory check, the half-width de-duplication)."""

from __future__ import annotations

import math

import numba
import numpy as np

from .. import _memory
from ..kernels import grid, query
from . import plan

#: reference points per chunk of a query's parallel passes (boundaries depend on
#: the number of reference points only)
QUERY_CHUNK = 256
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

