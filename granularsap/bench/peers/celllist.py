"""A plain numba cell list as a peer (``bench/celllist.py``)."""

from __future__ import annotations

import numpy as np

from .base import WIDEN, Peer, exact_filter, need_orthorhombic


class NumbaCellList(Peer):
    """The plain numba cell list of :mod:`granularsap.bench.celllist`, buffers kept.

    Bins are at least the cutoff wide (contacts: the largest contact distance
    ``2 max(r)``, and the exact ``d <= r_i + r_j`` test in the kernel), with a
    half stencil; periodic orthorhombic cells or open boundaries.  Boxes: the
    contacts of the spheres around them (radius the half diagonal), then the
    closed-box test.
    """

    name = "numba-celllist"
    module = "numba"
    dist = "numba"
    description = "plain numba half-stencil cell list (count + fill passes), buffers kept"
    kinds = ("cutoff", "contacts", "boxes")
    stateful = True
    threaded = True

    def unsupported(self, workload):
        why = super().unsupported(workload) or need_orthorhombic(workload)
        if why is None and workload.box is not None:
            if np.min(workload.box[:3]) < 3.0 * workload.search_radius():
                return "a periodic cell needs at least 3 bins of the reach per axis"
        return why

    def setup(self, workload, n_threads):
        from ..celllist import CellList

        super().setup(workload, n_threads)
        self.cells = CellList(n_threads=n_threads)
        if workload.kind == "boxes":  # half diagonals, widened past rounding
            self._box_radii = np.linalg.norm(workload.half_extents, axis=1) * (1.0 + WIDEN)

    def last_stats(self):
        return self.cells.stats

    def run(self, frame):
        wl = self.workload
        box = None if wl.box is None else wl.box[:3]
        if wl.kind == "boxes":  # spheres around the boxes in contact, then the box test
            pairs, _ = self.cells.compute(wl.frames[frame], radii=self._box_radii)
            return exact_filter(wl, frame, pairs)
        if wl.kind == "contacts":
            pairs, _ = self.cells.compute(wl.frames[frame], radii=wl.radii, box=box)
        else:
            pairs, _ = self.cells.compute(wl.frames[frame], cutoff=wl.cutoff, box=box)
        return pairs
