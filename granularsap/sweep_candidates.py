"""The particle engine's candidate list built by the paper's Sweep and Prune.

The column sweep of ``kernels/grid.py`` is one way to build the candidate
("Verlet") list that the narrow phase of :class:`~granularsap.NeighborSearch`
and :class:`~granularsap.ContactSearch` re-tests.  This module builds the same
list with Capannini & Larsson's parallel bi-dimensional Sweep and Prune
(:class:`~granularsap.SweepAndPrune`) over the particles' bounding cubes:

1. a cube ``[ws[p] - half[p], ws[p] + half[p]]`` per particle;
2. ghost cubes for the periodic images near the faces (lexicographically
   positive shifts only, several layers when the reach exceeds the cell; see
   ``kernels/ghosts.py``), at ``ws[q] + S0 cell[0] + S1 cell[1] + S2 cell[2]``;
3. every cube widened by a guard of ``64 eps`` times the largest coordinate
   magnitude, so that rounding never drops a required candidate;
4. one Sweep and Prune over real and ghost cubes; each overlapping pair maps
   back to an image ``(p, q, S)``: two real cubes give ``S = 0``, a real cube
   and a ghost the ghost's shift, two ghosts nothing (that image is also a
   real-ghost pair);
5. the images grouped by row ``p`` into the engine's Verlet layout.

A pair image ``(p, q, S)`` is *required* when every Cartesian component of
``D = (ws[q] - ws[p]) + S0 cell[0] + S1 cell[1] + S2 cell[2]`` satisfies
``|D_c| <= half[p] + half[q]``; every required image is returned, exactly
once (``(p, q, S)`` and ``(q, p, -S)`` are one image), and the only extra
ones are those within the rounding guard of that test.  ``spheres=True``
keeps only images with ``|D| <= half[p] + half[q]`` (the column sweep's build
test) and ``labels`` drops images of one rigid body.  See
``docs/sweep-candidates.md`` for measured costs against the column sweep.
"""

from __future__ import annotations

import time

import numba
import numpy as np

from ._numba import num_threads
from ._validate import as_coords, as_vector, check_n_threads
from .boxes import SweepAndPrune
from .cell import Cell
from .kernels import ghosts as gk

__all__ = ["MAX_SHIFT", "SweepCandidates", "decode_shift", "encode_shift", "sweep_candidates"]

#: largest ``|S_c|`` a packed shift code holds
MAX_SHIFT = gk.MAX_SHIFT
#: the packed code of the zero shift
ZERO_SHIFT = gk.ZERO
#: relative guard on every cube against rounding
_GUARD = 64 * np.finfo(np.float64).eps
#: boxes the sweep handles at most
_MAX_BOXES = (1 << 30) - 1
#: box pairs per chunk of the row layout at least (chunks never exceed threads)
_CHUNK_PAIRS = 65536


def encode_shift(s0, s1, s2):
    """Packed int32 code of the lattice shift ``(s0, s1, s2)``.

    ``((s0 + 512) << 20) | ((s1 + 512) << 10) | (s2 + 512)``: the layout of the
    engine's Verlet list (``kernels/grid.py``).  Accepts integers or integer
    arrays (broadcast); every component must lie in ``[-MAX_SHIFT, MAX_SHIFT]``.

    >>> encode_shift(0, 0, 0) == ZERO_SHIFT
    True
    >>> decode_shift(encode_shift(1, -2, 3))
    (1, -2, 3)
    """
    s = [np.asarray(v) for v in (s0, s1, s2)]
    for v in s:
        if v.dtype.kind not in "iu":
            raise TypeError(f"shift components must be integers, got dtype {v.dtype}")
        if v.size and (int(v.max()) > MAX_SHIFT or int(v.min()) < -MAX_SHIFT):
            raise ValueError(f"shift components must lie in [-{MAX_SHIFT}, {MAX_SHIFT}]")
    s = [v.astype(np.int64) for v in s]
    code = ((s[0] + gk.OFF) << 20) | ((s[1] + gk.OFF) << 10) | (s[2] + gk.OFF)
    code = code.astype(np.int32)
    return int(code) if code.ndim == 0 else code


def decode_shift(code):
    """``(s0, s1, s2)`` of a packed shift code (or three arrays for an array)."""
    c = np.asarray(code).astype(np.int64)
    out = ((c >> 20) - gk.OFF, ((c >> 10) & 1023) - gk.OFF, (c & 1023) - gk.OFF)
    if c.ndim == 0:
        return tuple(int(v) for v in out)
    return out


def _as_cell(cell, pbc):
    pbc_arr = np.asarray(pbc)
    if pbc_arr.dtype.kind != "b" or pbc_arr.shape != (3,):
        raise ValueError(f"pbc must be three booleans, got {pbc!r}")
    pbc_arr = np.ascontiguousarray(pbc_arr, dtype=np.bool_)
    if cell is None:
        if pbc_arr.any():
            raise ValueError("cell is None but pbc has periodic axes; give the cell matrix")
        return np.eye(3), np.eye(3), pbc_arr
    m = np.asarray(cell)
    if m.dtype.kind not in "fiu":
        raise TypeError(f"cell must be a (3, 3) matrix of real numbers, got dtype {m.dtype}")
    m = np.ascontiguousarray(m, dtype=np.float64)
    if m.shape != (3, 3):
        raise ValueError(f"cell must be a (3, 3) matrix (rows are cell vectors), got shape "
                         f"{m.shape}")
    if not np.isfinite(m).all():
        raise ValueError("cell must be finite, got NaN or inf")
    if not pbc_arr.any():
        return np.eye(3), np.eye(3), pbc_arr
    zero = ~m.any(axis=1)
    if np.any(zero & ~pbc_arr) and not np.any(zero[pbc_arr]):
        m = np.array(Cell(m, pbc_arr).full_matrix)  # zero rows of open axes completed
    # on every vector scaled by a power of two (exact): degenerate or not by the
    # angles only, whatever the units
    unit = np.ldexp(m, -np.frexp(np.abs(m).max(axis=1))[1][:, None])
    if not abs(float(np.linalg.det(unit))) > 1e-12 * float(
            np.prod(np.linalg.norm(unit, axis=1))):
        raise ValueError(f"cell must be non-degenerate (positive volume), got {m.tolist()}; "
                         "complete the rows of open axes (Cell.full_matrix)")
    return m, np.linalg.inv(m), pbc_arr


class SweepCandidates:
    """Candidate lists of particles by Sweep and Prune, over a sequence of frames.

    Holds one :class:`~granularsap.SweepAndPrune` across calls, so the sweep
    keeps its axes (and, while the number of boxes stays the same, its sort
    buckets and buffers) from frame to frame.

    Parameters
    ----------
    n_threads : int, optional
        numba threads for each call (restored afterwards); results do not
        depend on it.
    axes : "auto" or pair of axes
        Sweep axes of the :class:`~granularsap.SweepAndPrune`.
    path : str
        Algorithm path of the :class:`~granularsap.SweepAndPrune`; the default
        ``"parallel"`` is the paper's parallel sweep (Algorithms 2-4),
        ``"sequential"`` its Algorithm 1.  Results do not depend on it.

    Examples
    --------
    >>> import numpy as np
    >>> ws = np.array([[0.5, 5.0, 5.0], [9.5, 5.0, 5.0], [5.0, 5.0, 5.0]])
    >>> vstart, vstop, vb, vs = SweepCandidates().build(
    ...     ws, np.full(3, 0.6), 10.0 * np.eye(3), np.array([True, False, False]), False)
    >>> [(p, int(vb[e]), decode_shift(vs[e])) for p in range(3)
    ...  for e in range(vstart[p], vstop[p])]
    [(1, 0, (1, 0, 0))]
    """

    def __init__(self, *, n_threads=None, axes="auto", path="parallel"):
        self.n_threads = check_n_threads(n_threads)
        self._sap = SweepAndPrune(axes=axes, n_threads=self.n_threads, path=path)
        self.stats = {}

    def build(self, ws, half, cell, pbc, self_images, *, spheres=False, labels=None):
        """Candidate images of one frame in the engine's Verlet layout.

        Parameters
        ----------
        ws : (n, 3) array_like of float
            Cartesian positions, wrapped into the cell along periodic axes.
        half : (n,) array_like of float
            Half-width of each particle's bounding cube (non-negative).
        cell : (3, 3) array_like of float or None
            Rows are cell vectors (rows of open axes completed to a
            non-degenerate matrix; they are never used as shifts).  None when
            no axis is periodic.
        pbc : (3,) array_like of bool
            Periodic axes.
        self_images : bool
            Report a particle's own images ``(p, p, S)``, ``S != 0``.
        spheres : bool, optional
            Keep only the images whose spheres of radius ``half`` touch,
            ``|D| <= half[p] + half[q]`` (up to the rounding guard), instead of
            every pair of overlapping cubes: the test the column sweep's build
            applies, about 1.9 (6 / pi) times fewer entries.
        labels : (n,) array_like of int, optional
            Rigid-body labels: images of two particles with equal labels (a
            particle's own images included) are not reported, as in the
            column sweep's build with clump ids.

        Returns
        -------
        vstart, vstop : (n,) ndarray of int64
            Row ``p``'s entries are ``vstart[p]:vstop[p]`` (consecutive rows:
            ``vstop[p] == vstart[p + 1]``).
        vb : (k,) ndarray of int32
            Partner ``q`` of each entry.
        vs : (k,) ndarray of int32
            Packed shift ``S`` of each entry (:func:`encode_shift`), for the
            separation ``D = (ws[q] - ws[p]) + S @ cell``.

        Every image ``(p, q, S)`` with ``|D_c| <= half[p] + half[q]`` on every
        axis (with ``spheres``: with ``|D| <= half[p] + half[q]``) is present
        exactly once, as ``(p, q, S)`` or ``(q, p, -S)``; rows
        hold ``S`` lexicographically positive, or ``S = 0`` and ``p < q``.
        Inside a row, entries are sorted by (partner, code).
        """
        t_start = time.perf_counter()
        ws = as_coords(ws, "ws")
        n = len(ws)
        half = as_vector(half, "half", n)
        cell, hinv, pbc = _as_cell(cell, pbc)
        if not isinstance(self_images, (bool, np.bool_)):
            raise TypeError(f"self_images must be True or False, got {self_images!r}")
        self_images = bool(self_images)
        if not isinstance(spheres, (bool, np.bool_)):
            raise TypeError(f"spheres must be True or False, got {spheres!r}")
        use_labels = labels is not None
        if use_labels:
            labels = np.asarray(labels)
            if labels.dtype.kind not in "iu":
                raise TypeError(f"labels must be integers, got dtype {labels.dtype}")
            if labels.shape != (n,):
                raise ValueError(f"labels must have shape ({n},), got {labels.shape}")
            labels = np.ascontiguousarray(labels, dtype=np.int64)
        else:
            labels = np.zeros(0, np.int64)
        if n >= (1 << 31) - 1:
            raise ValueError(f"at most 2**31 - 2 particles are supported, got {n}")
        with num_threads(self.n_threads):
            return self._build(ws, half, cell, hinv, pbc, self_images, bool(spheres), labels,
                               use_labels, n, t_start)

    def build_resolved(self, ws, half, frame_cell, self_images, *, spheres=False,
                       labels=None):
        """:meth:`build` for the engine, which holds its inputs checked already.

        ``ws`` and ``half`` are contiguous float64 arrays, ``labels`` None or
        int64, and ``frame_cell`` the frame's :class:`granularsap.geometry.FrameCell`
        (validated once, when the search resolved the box): nothing is validated
        or converted again.

        >>> import numpy as np
        >>> from granularsap.geometry import FrameCell
        >>> ws = np.array([[0.5, 5.0, 5.0], [9.5, 5.0, 5.0], [5.0, 5.0, 5.0]])
        >>> fc = FrameCell.of(10.0 * np.eye(3), [True, False, False])
        >>> vstart, vstop, vb, vs = SweepCandidates().build_resolved(ws, np.full(3, 0.6), fc,
        ...                                                          False)
        >>> [(p, int(vb[e]), decode_shift(vs[e])) for p in range(3)
        ...  for e in range(vstart[p], vstop[p])]
        [(1, 0, (1, 0, 0))]
        """
        t_start = time.perf_counter()
        fc = frame_cell
        if fc.any_periodic:
            cell = fc.matrix
            hinv = fc.hinv if not fc.diag else np.linalg.inv(cell)
        else:
            cell = hinv = np.eye(3)
        use_labels = labels is not None
        if not use_labels:
            labels = np.zeros(0, np.int64)
        with num_threads(self.n_threads):
            return self._build(ws, half, cell, hinv, fc.pbc, bool(self_images), bool(spheres),
                               labels, use_labels, len(ws), t_start)

    def _build(self, ws, half, cell, hinv, pbc, self_images, spheres, labels, use_labels, n,
               t_start):
        t0 = time.perf_counter()
        hmax = float(half.max()) if n else 0.0
        per = np.flatnonzero(pbc)
        # ghosts: fractional coordinates, the real span and the reach per axis
        owner = np.empty(0, np.int64)
        gcode = np.empty(0, np.int32)
        gpos = np.empty((0, 3))
        mag = float(np.abs(ws).max()) if n else 0.0
        if n and len(per):
            t = ws @ hinv
            lo = t.min(axis=0)
            hi = t.max(axis=0)
            l1 = np.abs(hinv).sum(axis=0)
            # the cube guard (ghosts are near the cell, so bounded through it)
            reach_layers = (2.0 * hmax) * l1 * (1.0 + 1e-9) + (hi - lo) + 2.0
            bound = mag + float(np.sum(np.where(pbc, np.ceil(reach_layers), 0.0)
                                       * np.abs(cell).max(axis=1)))
            guard = _GUARD * (bound + hmax) + np.finfo(np.float64).tiny
            if np.any(np.where(pbc, reach_layers, 0.0) > MAX_SHIFT):
                c = int(np.argmax(np.where(pbc, reach_layers, 0.0)))
                hint = ("; ws must be wrapped into the cell along periodic axes (their "
                        f"fractional span along axis {c} is {hi[c] - lo[c]:.6g})"
                        if hi[c] - lo[c] > 1.0 + 1e-6 else "; use a larger cell or smaller "
                        "ranges")
                raise ValueError(
                    f"the cube reach 2 * max(half) = {2.0 * hmax:.17g} needs lattice shifts "
                    f"beyond {MAX_SHIFT} cell vectors along axis {c}{hint}")
            slack = 1e-9 * (1.0 + np.maximum(np.abs(lo), np.abs(hi)))
            extra = hmax + 2.0 * guard
            counts = np.empty(n, np.int64)
            gk.count_ghosts(t, half, extra, pbc, lo, hi, l1, slack, counts)
            offsets = np.zeros(n, np.int64)
            np.cumsum(counts[:-1], out=offsets[1:])
            n_ghosts = int(counts.sum())
            if n + n_ghosts > _MAX_BOXES:
                raise ValueError(f"{n_ghosts} ghost images of {n} particles exceed the "
                                 f"{_MAX_BOXES} boxes of the sweep; use a larger cell or "
                                 "smaller ranges")
            owner = np.empty(n_ghosts, np.int64)
            gcode = np.empty(n_ghosts, np.int32)
            gpos = np.empty((n_ghosts, 3))
            gk.fill_ghosts(ws, t, half, extra, pbc, lo, hi, l1, slack, cell, offsets, owner,
                           gcode, gpos)
        else:
            guard = _GUARD * (mag + hmax) + np.finfo(np.float64).tiny
        n_ghosts = len(owner)
        lower = np.empty((n + n_ghosts, 3))
        upper = np.empty((n + n_ghosts, 3))
        gk.boxes(ws, half, gpos, owner, guard, lower, upper)
        t1 = time.perf_counter()
        pairs = self._sap.update(lower, upper)
        t2 = time.perf_counter()
        # two counting sorts: images by partner, then by row walking the
        # partners in order, so every row comes out sorted by partner
        vstart = np.empty(n, np.int64)
        vstop = np.empty(n, np.int64)
        n_overlaps = len(pairs)
        n_chunks = max(1, min(numba.get_num_threads(), n_overlaps // _CHUNK_PAIRS))
        cnt = np.empty((n_chunks, n), np.int64)
        sel = (self_images, spheres, ws, gpos, half, 2.0 * guard, labels, use_labels)
        gk.image_counts(pairs, n, owner, gcode, *sel, cnt, True)
        qstart = np.empty(n, np.int64)
        qstop = np.empty(n, np.int64)
        total = gk.offsets(cnt, qstart, qstop)
        key = np.empty(total, np.int64)
        gk.scatter_by_partner(pairs, n, owner, gcode, *sel, cnt, key)
        del pairs
        gk.row_counts(qstart, qstop, key, cnt)
        gk.offsets(cnt, vstart, vstop)
        vb = np.empty(total, np.int32)
        vs = np.empty(total, np.int32)
        gk.scatter_rows(qstart, qstop, key, cnt, vb, vs)
        del key
        gk.sort_ties(vstart, vstop, vb, vs)
        t3 = time.perf_counter()
        sap = self._sap.stats
        self.stats = {
            "n": n, "ghosts": n_ghosts, "boxes": n + n_ghosts, "overlaps": n_overlaps,
            "candidates": int(total), "guard": guard, "layout_chunks": n_chunks,
            "sweep_candidates_tested": sap.get("candidates_tested"),
            "axes": sap.get("axes"), "path": sap.get("path"),
            "seconds": {"ghosts": t1 - t0, "sweep": t2 - t1, "layout": t3 - t2,
                        "total": time.perf_counter() - t_start},
        }
        return vstart, vstop, vb, vs


def sweep_candidates(ws, half, cell, pbc, self_images, *, spheres=False, labels=None,
                     n_threads=None):
    """Candidate images of one frame by Sweep and Prune, in the engine's Verlet layout.

    One call of a fresh :class:`SweepCandidates`; see
    :meth:`SweepCandidates.build` for the arguments and the result
    ``(vstart, vstop, vb, vs)``.
    """
    return SweepCandidates(n_threads=n_threads).build(ws, half, cell, pbc, self_images,
                                                      spheres=spheres, labels=labels)
