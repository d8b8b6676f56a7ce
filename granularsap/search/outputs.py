"""The output buffers of a search: two sets that alternate between calls, so
that the arrays a call returns stay valid until the call after next (a DEM
script matches this step's contacts against the last step's); the layout
(``pairs`` or ``csr``) and the quantities asked for."""

from __future__ import annotations

import numpy as np

from ..kernels import grid
from .frame import QUANTITIES

#: the values of ``layout=``
LAYOUTS = ("pairs", "csr")
_NO_ENTRIES = np.zeros(0, np.int64)


def check_quantities(quantities):
    """``quantities`` if it is a non-empty string of known letters, else the error."""
    if not isinstance(quantities, str) or not quantities:
        raise TypeError(f"quantities must be a non-empty string such as 'Pd' or 'ijd', "
                        f"got {quantities!r}")
    bad = [q for q in quantities if q not in QUANTITIES]
    if bad:
        raise ValueError(f"unknown quantity {bad[0]!r} in quantities {quantities!r}; choose "
                         "from 'P' (pairs (k, 2)), 'i', 'j', 'd' (distance), "
                         "'D' (vector from i to j), 'S' (lattice shift)")
    return quantities


class OutputBuffers:
    """Two sets of output arrays; every kernel of a call writes into the set the
    last finished call did not use (``begin``), grown when a call needs more
    rows (``fit``).

    ``p`` (pairs), ``d`` (distances), ``v`` (vectors), ``s`` (lattice shifts)
    and ``e`` (each pair's entry in a kept Verlet list, for identity) are this
    call's arrays, of length 0 for a quantity not ``computed``."""

    def __init__(self, computed, entries):
        self.computed = computed
        self.entries = entries
        self.sets = [{"cap": 0}, {"cap": 0}]
        self.last = 1
        self.now = 0
        self._use(self.sets[0])

    def begin(self):
        """Point at the set the last finished call did not use."""
        self.now = 1 - self.last
        self._use(self.sets[self.now])

    def done(self):
        """This call's set holds a finished result."""
        self.last = self.now

    def _use(self, buf):
        if "p" not in buf:
            buf.update(p=np.empty((0, 2), np.int64), d=np.empty(0), v=np.empty((0, 3)),
                       s=np.empty((0, 3), np.int64))
        self.cap = buf["cap"]
        self.p, self.d, self.v, self.s = buf["p"], buf["d"], buf["v"], buf["s"]
        self.e = buf.get("e", _NO_ENTRIES)

    def fit(self, total):
        """This call's set with room for ``total`` pairs (grown by an eighth)."""
        q = self.computed
        buf = self.sets[self.now]
        if total <= buf["cap"] and "p" in buf:
            self._use(buf)
            return
        cap = max(1024, total + total // 8)
        buf.update(cap=cap, p=np.empty((cap, 2), np.int64), d=np.empty(cap if "d" in q else 0),
                   v=np.empty((cap if "D" in q else 0, 3)),
                   s=np.empty((cap if "S" in q else 0, 3), np.int64),
                   e=np.empty(cap if self.entries else 0, np.int64))
        self._use(buf)

    def arrays(self):
        """Every array of both sets (for ``nbytes``)."""
        return [v for buf in self.sets for v in buf.values() if isinstance(v, np.ndarray)]

    def dedup(self, total, n):
        """Pairs whose two images tie at exactly half a cell width: keep one (the
        nearer, the first of equal ones), in order; the number kept."""
        p = self.p[:total]
        key = p[:, 0] * max(n, 1) + p[:, 1]
        if len(np.unique(key)) == total:
            return total
        d = self.d[:total] if len(self.d) else np.zeros(total)
        order = np.lexsort((d, key))
        first = np.ones(total, bool)
        first[1:] = key[order][1:] != key[order][:-1]
        keep = np.sort(order[first])
        k = len(keep)
        self.p[:k] = p[keep]
        for buf in (self.d, self.v, self.s):
            if len(buf):
                buf[:k] = buf[:total][keep]
        return k

    def csr(self, total, n, want_d):
        """The first ``total`` pairs of ``n`` particles as (offsets, columns[,
        distances]) in this call's set."""
        buf = self.sets[self.now]
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
        grid.csr_from_pairs(n, self.p[:total], self.d[:total] if want_d else cd, want_d,
                            offsets, col, cd)
        return (offsets, col, cd) if want_d else (offsets, col)

    def pick(self, total, quantities):
        """The first ``total`` rows of each quantity asked for, in order."""
        out = []
        for q in quantities:
            if q == "P":
                out.append(self.p[:total])
            elif q == "i":
                out.append(self.p[:total, 0])
            elif q == "j":
                out.append(self.p[:total, 1])
            elif q == "d":
                out.append(self.d[:total])
            elif q == "D":
                out.append(self.v[:total])
            else:
                out.append(self.s[:total])
        return tuple(out)
