"""The Verlet list: the pairs within the range plus ``rebuild_margin``, kept
between frames while no particle has moved more than half the margin.  A
frame within the margin re-tests the list (``retest``) instead of searching.

Either builder makes one: the column sweep keeps its pass-1 records (runs of
up to 64 candidates per particle, ``columns.Records``); the paper's sweep
keeps each particle's candidates by row (``vstart``, ``vstop``, the partner
and the packed shift of each entry).  Each entry's shift is corrected by the
image jumps of its two particles since the build."""

from __future__ import annotations

import numpy as np

from ..kernels import grid

_NO_ENTRIES = np.zeros(0, np.int64)
_ZERO = np.zeros(1, np.int64)  # the offset of a single chunk


class VerletList:
    """A kept Verlet list (or none: ``kind is None``)."""

    def __init__(self):
        self.clear()

    def clear(self):
        """No list: the next frame rebuilds."""
        self.kind = None
        self.counts = _NO_ENTRIES  # entries per chunk (``stats["verlet_entries"]``)
        self.dtol = 0.0

    def keep_records(self, sweep, wstart, wneed, counts, dtol):
        """The records of the column sweep's pass 1 (``sweep``: its
        ``ColumnSweep``), ``wneed[c]`` of chunk ``c`` from ``wstart[c]``;
        ``dtol``: the rounding band the list covers (later frames' band up to
        twice this one's wrap shifts and coordinates)."""
        self.kind = "records"
        self.sweep = sweep
        self.wstart, self.wneed = wstart, wneed
        self.counts = counts
        self.dtol = dtol

    def keep_rows(self, chunk_rows, vstart, vstop, vb, vs, dtol):
        """The paper's sweep's candidates: row ``p``'s in ``vb[vstart[p]:vstop[p]]``
        (partners) and ``vs`` (shifts), rows in chunks ``chunk_rows``."""
        self.kind = "rows"
        self.chunk_rows = chunk_rows
        self.vstart, self.vstop, self.vb, self.vs = vstart, vstop, vb, vs
        self.counts = vstop[chunk_rows[1:] - 1] - vstart[chunk_rows[:-1]]
        self.dtol = dtol

    @property
    def entries(self):
        return int(self.counts.sum()) if len(self.counts) else 0

    def retest(self, kern, ws, m, rs, skin, cell, diag, strict, uniform, x2, band, want, out):
        """The pairs of the list in range on this frame (count pass, then fill
        pass) into ``out`` (``outputs.OutputBuffers``), each with its entry in
        the list (``out.e``, for identity); the number of pairs.

        ``ws`` wrapped positions by build order, ``m`` the packed image jumps
        since the build, ``rs`` half ranges, ``band`` the frame's
        ``columns.Band``, ``want`` (distances, vectors, shifts)."""
        lo2, hi2, dtol, exact, xg, perm, ks = band
        if self.kind == "records" and (len(self.wstart) == 1 or kern is grid.serial):
            # one chunk, or chunks one after another: the fill pass alone, with
            # room for every entry of each chunk, leaves the number of pairs it
            # wrote; the chunks' rows then close up, in order
            room = self.counts.copy()
            offsets = _ZERO
            if len(room) > 1:
                offsets = np.zeros(len(room), np.int64)
                np.cumsum(room[:-1], out=offsets[1:])
            out.fit(int(room.sum()))
            kern.records_narrow(True, self.wstart, self.wneed, offsets, room,
                                *self.sweep.records, ws, m, rs, skin, cell, diag, strict,
                                uniform, x2, lo2, hi2, dtol, exact, xg, perm, ks, *want,
                                out.p, out.d, out.v, out.s, out.e)
            return _close_up(out, offsets, room)
        if self.kind == "rows":
            rows = self.chunk_rows
            counts = np.empty(len(rows) - 1, np.int64)
            kern.narrow_count(rows, self.vstart, self.vstop, self.vb, self.vs, ws, m, rs, skin,
                              cell, strict, uniform, x2, lo2, hi2, dtol, xg, perm, ks, counts)
        else:
            out.fit(0)
            counts = np.zeros(len(self.wstart), np.int64)
            kern.records_narrow(False, self.wstart, self.wneed, counts, counts,
                                *self.sweep.records, ws, m, rs, skin, cell, diag, strict,
                                uniform, x2, lo2, hi2, dtol, exact, xg, perm, ks, *want,
                                out.p, out.d, out.v, out.s, out.e)
        offsets = np.zeros(len(counts), np.int64)
        offsets[1:] = np.cumsum(counts)[:-1]
        total = int(counts.sum())
        out.fit(total)
        if self.kind == "rows":
            kern.narrow_fill(rows, offsets, counts, self.vstart, self.vstop, self.vb, self.vs,
                             ws, m, rs, skin, cell, strict, exact, xg, perm, ks, *want, out.p,
                             out.d, out.v, out.s, out.e)
        else:
            kern.records_narrow(True, self.wstart, self.wneed, offsets, counts,
                                *self.sweep.records, ws, m, rs, skin, cell, diag, strict,
                                uniform, x2, lo2, hi2, dtol, exact, xg, perm, ks, *want,
                                out.p, out.d, out.v, out.s, out.e)
        return total


def _close_up(out, offsets, counts):
    """Chunk ``c``'s ``counts[c]`` rows, written from ``offsets[c]`` in ``out``,
    moved to follow chunk ``c - 1``'s; the number of rows."""
    if not len(counts):
        return 0
    dst = int(counts[0])
    for c in range(1, len(counts)):
        k, src = int(counts[c]), int(offsets[c])
        if k and src != dst:
            for a in (out.p, out.d, out.v, out.s, out.e):
                if len(a):
                    a[dst:dst + k] = a[src:src + k]
        dst += k
    return dst
