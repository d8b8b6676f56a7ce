"""A plain half-stencil cell list in numba: the bench's ``numba-celllist`` peer.

The textbook method, written the way a numba user would write it, so that
granularsap's searches can be compared with it on the same cores.  Space is
cut into bins at least as wide as the search reach (the cutoff, or the largest
contact distance ``2 max(r)``); particles are counting-sorted by bin into
contiguous copies; every bin is then tested against itself (``q > p``) and 13
of its 26 neighbours (a half stencil: each unordered pair of bins once), with
periodic images of orthorhombic cells through the minimum image.  A count pass
sizes every bin's slice of the output, a fill pass writes pairs ``i < j``
(original indices) and float64 distances into it; both are parallel over bins
(``numba.prange``), and every buffer is kept between calls.  Cost: O(N) bins
and about ``(27 / 2) rho w^3`` distance tests per particle for bins of width
``w``, each done twice (count and fill).

Pairs are decided with the benchmark's exact arithmetic: ``delta = x_j - x_i``,
``delta -= L * round(delta / L)`` on periodic axes, ``d = sqrt(dx^2 + dy^2 +
dz^2)``, kept when ``d <= cutoff`` (or ``d <= r_i + r_j``).  A periodic axis
needs at least three bins (the cell wider than three reaches).
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from granularsap._numba import ijit, jit, num_threads, pjit

#: own bin first, then the 13 offsets of the half stencil
_STENCIL = np.array([(0, 0, 0)] + [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1)
                                   for c in (-1, 0, 1) if (a, b, c) > (0, 0, 0)], np.int64)


@ijit
def _wrap(b, nb, periodic):
    """(bin, image) of bin coordinate ``b`` on an axis of ``nb`` bins; bin -1 outside an
    open axis, image -1/0/+1 when the neighbour is a periodic image below/in/above the cell."""
    if 0 <= b < nb:
        return b, 0
    if not periodic:
        return -1, 0
    return b % nb, (1 if b >= nb else -1)


@jit
def _sort(pos, rad, lo, inv_w, nb, length, periodic, counts, start, xs, rs, ids, cell):
    """Counting sort by bin: ``start`` (nbins + 1,), sorted copies ``xs``, ``rs``, ``ids``."""
    counts[:] = 0
    for p in range(pos.shape[0]):
        c = 0
        for a in range(3):
            x = pos[p, a] - lo[a]
            if periodic[a]:
                x -= length[a] * math.floor(x / length[a])
            b = min(max(int(x * inv_w[a]), 0), nb[a] - 1)
            c = c * nb[a] + b
        cell[p] = c
        counts[c] += 1
    start[0] = 0
    for c in range(counts.shape[0]):
        start[c + 1] = start[c] + counts[c]
        counts[c] = start[c]
    for p in range(pos.shape[0]):
        k = counts[cell[p]]
        counts[cell[p]] += 1
        for a in range(3):  # periodic axes: wrapped into [0, L), the identity inside the cell
            x = pos[p, a]
            xs[k, a] = x - length[a] * math.floor(x / length[a]) if periodic[a] else x
        rs[k], ids[k] = rad[p], p


@pjit
def _pairs(xs, rs, ids, start, nb, length, periodic, cutoff, use_radii, stencil, fill,
           counts, tested, out_p, out_d):
    """Count (``fill`` False: ``counts[c]`` pairs of bin c) or write the pairs of every bin."""
    for c in prange(nb[0] * nb[1] * nb[2]):
        b0, b1, b2 = c // (nb[1] * nb[2]), (c // nb[2]) % nb[1], c % nb[2]
        k = counts[c] if fill else 0
        t = 0
        m = start[c + 1] - start[c]
        for s in range(stencil.shape[0]):
            n0, i0 = _wrap(b0 + stencil[s, 0], nb[0], periodic[0])
            n1, i1 = _wrap(b1 + stencil[s, 1], nb[1], periodic[1])
            n2, i2 = _wrap(b2 + stencil[s, 2], nb[2], periodic[2])
            if n0 < 0 or n1 < 0 or n2 < 0:
                continue
            # the image's shift, subtracted as the minimum image x_q - x_p - L round(.) does
            s0, s1, s2 = -i0 * length[0], -i1 * length[1], -i2 * length[2]
            d = (n0 * nb[1] + n1) * nb[2] + n2
            t += m * (m - 1) // 2 if s == 0 else m * (start[d + 1] - start[d])
            for p in range(start[c], start[c + 1]):
                x0, x1, x2 = xs[p, 0], xs[p, 1], xs[p, 2]
                for q in range(p + 1 if s == 0 else start[d], start[d + 1]):
                    dx, dy, dz = xs[q, 0] - x0 - s0, xs[q, 1] - x1 - s1, xs[q, 2] - x2 - s2
                    r = math.sqrt(dx * dx + dy * dy + dz * dz)
                    if r <= (rs[p] + rs[q] if use_radii else cutoff):
                        if fill:
                            out_p[k, 0], out_p[k, 1] = min(ids[p], ids[q]), max(ids[p], ids[q])
                            out_d[k] = r
                        k += 1
        if not fill:
            counts[c] = k
            tested[c] = t


class CellList:
    """Reusable cell-list search; ``compute`` returns views into buffers kept between calls.

    Parameters
    ----------
    n_threads : int or None
        numba threads for the parallel passes (None: numba's setting).
    """

    def __init__(self, *, n_threads=None):
        self.n_threads = n_threads
        self._buf = {}
        self.stats = None

    def _get(self, name, shape, dtype):
        arr = self._buf.get(name)
        if arr is None or arr.shape[0] < shape[0]:
            grown = (int(shape[0] * 1.2) + 16, *shape[1:]) if name.startswith("out") else shape
            arr = self._buf[name] = np.empty(grown, dtype)
        return arr

    def compute(self, positions, *, cutoff=None, radii=None, box=None):
        """Pairs ``(k, 2)`` int64 with ``i < j`` and distances ``(k,)`` (views, valid until
        the next call) within ``cutoff``, or in contact (``d <= r_i + r_j``) given ``radii``.

        ``box``: None (open) or the three edge lengths of a periodic orthorhombic cell.
        """
        pos = np.ascontiguousarray(positions, dtype=np.float64).reshape(-1, 3)
        n = len(pos)
        use_radii = radii is not None
        rad = np.ascontiguousarray(radii if use_radii else np.zeros(n), dtype=np.float64)
        reach = 2.0 * float(rad.max(initial=0.0)) if use_radii else float(cutoff)
        periodic = np.array([box is not None] * 3)
        if box is not None:
            lo, length = np.zeros(3), np.asarray(box, dtype=np.float64)
        else:
            lo = pos.min(axis=0) if n else np.zeros(3)
            length = (pos.max(axis=0) - lo if n else np.zeros(3)) + 1e-300
        nb = np.maximum(np.floor(length / max(reach, 1e-300)), 1).astype(np.int64)
        nb = np.minimum(nb, max(int(round((4 * n) ** (1 / 3))), 1))  # no more bins than needed
        if np.any(periodic & (nb < 3)):
            raise ValueError(f"a periodic cell needs at least 3 bins per axis: edges {length} "
                             f"are not wider than 3 x the reach {reach}")
        nbins = int(np.prod(nb))
        counts, tested = self._get("counts", (nbins,), np.int64), self._get("t", (nbins,), np.int64)
        start = self._get("start", (nbins + 1,), np.int64)
        xs, rs = self._get("xs", (n, 3), np.float64), self._get("rs", (n,), np.float64)
        ids, cell = self._get("ids", (n,), np.int64), self._get("cell", (n,), np.int64)
        args_sort = (lo, nb / length, nb, length, periodic)
        with num_threads(self.n_threads):
            _sort(pos, rad, *args_sort, counts[:nbins], start[:nbins + 1], xs, rs, ids, cell)
            args = (xs[:n], rs[:n], ids[:n], start[:nbins + 1], nb, length, periodic,
                    float(cutoff or 0.0), use_radii, _STENCIL)
            _pairs(*args, False, counts[:nbins], tested[:nbins], self._get("out_p", (1, 2),
                   np.int64), self._get("out_d", (1,), np.float64))
            total = int(counts[:nbins].sum())
            counts[:nbins] = np.cumsum(counts[:nbins]) - counts[:nbins]
            out_p = self._get("out_p", (total, 2), np.int64)
            out_d = self._get("out_d", (total,), np.float64)
            _pairs(*args, True, counts[:nbins], tested[:nbins], out_p, out_d)
        self.stats = {"candidates_tested": int(tested[:nbins].sum()), "pairs": total,
                      "bins": nb.tolist()}
        return out_p[:total], out_d[:total]
