"""The column sweep as a candidate builder: pass 1 over chunks of columns
(``grid.direct_count``) keeps, for each run of up to 64 candidates with a pair
among them, a record (the 64-bit mask of the pairs, the particle, the first
candidate, the lattice shift); pass 2 writes the pairs of the records
(``grid.direct_fill``), or a Verlet list keeps the records (``verlet.py``).

The values a pass reads travel in named groups (``Columns``, ``PairTest``,
``Band``, ``Levels``), spread into the kernels' arguments in this order."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..kernels import grid


class Columns(NamedTuple):
    """The frame sorted into columns, in the layout the sweep reads."""

    chunk_cols: np.ndarray  # column boundaries of the chunks of parallel work
    start: np.ndarray  # first row of each column (ncol + 1)
    nb0: int
    nb1: int
    pbc: np.ndarray
    tz: np.ndarray  # wrapped fraction along the sweep axis, by column order
    xs: np.ndarray  # wrapped Cartesian coordinates, by column order
    ys: np.ndarray
    zs: np.ndarray
    rs: np.ndarray  # half ranges (radii), by column order
    ls: np.ndarray  # clump labels, by column order
    use_label: bool
    cell: np.ndarray


class PairTest(NamedTuple):
    """What decides a candidate."""

    diag: bool  # a diagonal cell
    stencil: np.ndarray  # the column offsets met forward (``plan.ColumnPlan``)
    rmax: float
    reach: float  # the range beyond r_i + r_j that the window covers
    inv_w2: float  # 1 / width along the sweep axis
    self_images: bool  # every periodic image (a particle meets its own images)
    skin: float  # the threshold is r_i + r_j + skin
    strict: bool  # d < threshold (include_cutoff=False)
    uniform: bool  # one threshold for every pair, decided by ``x2``
    x2: float


class Band(NamedTuple):
    """The rounding band of the agreed arithmetic (``grid.frame_band``): squares
    within it are re-tested on the given positions."""

    lo2: float
    hi2: float
    dtol: float
    exact: bool
    xg: np.ndarray  # the given positions (scaled)
    perm: np.ndarray  # column order -> row
    ks: np.ndarray  # wrap shifts, by column order


class Levels(NamedTuple):
    """Two levels of columns for widely spread radii (``plan.level_split``)."""

    two: bool
    big: np.ndarray  # 1 for a particle above ``r_small``, by column order
    r_small: float
    stencil_big: np.ndarray


class Records(NamedTuple):
    word: np.ndarray  # the 64-bit mask of a run's pairs
    p: np.ndarray  # the particle (column order)
    q: np.ndarray  # the first candidate of the run
    s: np.ndarray  # the packed lattice shift


NO_BIG = np.zeros(0, np.uint8)


class ColumnSweep:
    """Pass 1 and pass 2 of the column sweep with the record buffers they share,
    kept between builds (and the record regions per chunk, sized from the last
    build)."""

    def __init__(self):
        self.records = None
        self._wcap = None

    def reserve(self, size):
        """Record buffers of ``size`` records at least."""
        if self.records is None or len(self.records.word) < size:
            self.records = Records(np.empty(size, np.uint64), np.empty(size, np.int32),
                                   np.empty(size, np.int32), np.empty(size, np.int32))

    def pass1(self, kern, cols, test, band, levels, verlet, chunk_rows):
        """Per chunk its pairs, candidates and records, in regions sized from the
        last build (a chunk that needs more is swept again, with those after it
        whose region moved); (counts, tested, wstart, wneed)."""
        n_chunks = len(cols.chunk_cols) - 1
        counts = np.zeros(n_chunks, np.int64)
        tested = np.zeros(n_chunks, np.int64)
        wneed = np.zeros(n_chunks, np.int64)
        wcap = self._wcap
        if wcap is None or len(wcap) != n_chunks:
            wcap = np.diff(chunk_rows) * (len(test.stencil) + 3) + 64
        todo = np.ones(n_chunks, np.bool_)
        mode = grid.loop_mode(test.diag, test.uniform, cols.use_label, levels.two)
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
            if self.records is None or len(self.records.word) < size:
                self.reserve(size + size // 8)
                todo[:] = True
            kern.direct_count(*cols, *test, *band, *self.records, wstart, wcap, counts,
                              tested, wneed, todo, *levels, verlet, *mode)
            over = wneed > wcap
            if not over.any():
                break
            wcap = np.where(over, wneed + wneed // 8 + 64, wcap)
            todo = over
        self._wcap = np.maximum(wcap, wneed + wneed // 8 + 64)
        return counts, tested, wstart, wneed

    def fill(self, kern, wstart, wneed, offsets, cols, test, band, want, out):
        """Pass 2: the pairs of the records from row ``offsets[c]`` of chunk ``c``
        into the output buffers ``out`` (``want``: distances, vectors, shifts)."""
        kern.direct_fill(wstart, wneed, offsets, *self.records, cols.xs, cols.ys, cols.zs,
                         cols.rs, cols.ls, cols.use_label, cols.cell, test.diag,
                         test.self_images, test.skin, test.strict, test.uniform, test.x2,
                         band.perm, band.ks, band.xg, band.exact, *want, out.p, out.d, out.v,
                         out.s)
