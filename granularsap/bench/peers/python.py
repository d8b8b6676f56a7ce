"""The Python neighbour libraries: MDAnalysis (nsgrid, pkdtree), scipy's cKDTree, ASE,
matscipy, vesin and freud, each through its documented entry point."""

from __future__ import annotations

import numpy as np

from .base import (
    CutoffPeer,
    Peer,
    cell_matrix,
    dist_version,
    half_list,
    need_orthorhombic,
    oriented,
)


class MDAnalysisPeer(CutoffPeer):
    """MDAnalysis.lib.distances.self_capped_distance with an explicit method."""

    module = "MDAnalysis"
    dist = "MDAnalysis"
    method = "nsgrid"
    float32 = True

    def unsupported(self, workload):
        why = super().unsupported(workload)
        if why is None and self.method == "nsgrid" and workload.box is None and workload.n < 2:
            return "nsgrid needs at least two particles"
        return why

    def search(self, positions, radius, box):
        from MDAnalysis.lib.distances import self_capped_distance

        pairs, dist = self_capped_distance(positions, max_cutoff=radius, box=box,
                                           method=self.method, return_distances=True)
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        return oriented(pairs[:, 0], pairs[:, 1]), dist


class MDANSGrid(MDAnalysisPeer):
    name = "mda-nsgrid"
    method = "nsgrid"
    description = "MDAnalysis self_capped_distance(method='nsgrid')"


class MDAPKDTree(MDAnalysisPeer):
    name = "mda-pkdtree"
    method = "pkdtree"
    description = "MDAnalysis self_capped_distance(method='pkdtree')"


class ScipyCKDTree(CutoffPeer):
    """scipy.spatial.cKDTree(..., boxsize=L).query_pairs(r, output_type='ndarray').

    ``query_pairs`` has no ``workers`` argument (only the ``query*`` methods
    that take query points do), so this peer is serial.
    """

    name = "scipy-ckdtree"
    module = "scipy.spatial"
    dist = "scipy"
    description = "scipy cKDTree(boxsize=L).query_pairs(r, output_type='ndarray')"

    def unsupported(self, workload):
        return super().unsupported(workload) or need_orthorhombic(workload)

    def search(self, positions, radius, box):
        from scipy.spatial import cKDTree

        if box is None:
            tree = cKDTree(positions)
        else:
            lengths = np.asarray(box[:3], dtype=np.float64)
            wrapped = np.mod(positions, lengths)
            wrapped[wrapped >= lengths] = 0.0
            tree = cKDTree(wrapped, boxsize=lengths)
        pairs = tree.query_pairs(radius, output_type="ndarray").astype(np.int64, copy=False)
        return pairs.reshape(-1, 2), None


def _open_cell(positions, radius):
    """A bounding cell (origin, (3, 3) matrix) for libraries that always want one."""
    if len(positions) == 0:
        return np.zeros(3), np.eye(3)
    lo = positions.min(axis=0) - radius
    hi = positions.max(axis=0) + radius
    return lo, np.diag(np.maximum(hi - lo, 1e-9))


class ASEPeer(CutoffPeer):
    """ase.neighborlist.neighbor_list('ijd', atoms, r) (full list, halved)."""

    name = "ase"
    module = "ase.neighborlist"
    dist = "ase"
    description = "ASE neighbor_list('ijd', Atoms(...), r)"

    def unsupported(self, workload):
        why = super().unsupported(workload)
        if why is None and workload.box is not None and not dist_version("MDAnalysis"):
            return "triclinic conversion needs MDAnalysis"
        return why

    def search(self, positions, radius, box):
        from ase import Atoms
        from ase.neighborlist import neighbor_list

        if box is None:
            # a bounding cell: without one ASE's search over an empty cell is ~10x slower
            origin, cell = _open_cell(positions, radius)
            atoms = Atoms(positions=positions - origin, cell=cell, pbc=False)
        else:
            atoms = Atoms(positions=positions, cell=cell_matrix(box), pbc=True)
        i, j, d = neighbor_list("ijd", atoms, radius)
        return half_list(i, j, d)


class MatscipyPeer(CutoffPeer):
    """matscipy.neighbours.neighbour_list('ijd', positions=..., cell=..., pbc=...)."""

    name = "matscipy"
    module = "matscipy.neighbours"
    dist = "matscipy"
    description = "matscipy neighbour_list('ijd', positions=, cutoff=, cell=, pbc=)"

    def search(self, positions, radius, box):
        from matscipy.neighbours import neighbour_list

        if box is None:
            origin, cell = _open_cell(positions, radius)
            i, j, d = neighbour_list("ijd", positions=positions, cutoff=radius, cell=cell,
                                     pbc=[False] * 3, cell_origin=origin)
        else:
            i, j, d = neighbour_list("ijd", positions=positions, cutoff=radius,
                                     cell=cell_matrix(box), pbc=[True] * 3)
        return half_list(i, j, d)


class VesinPeer(CutoffPeer):
    """vesin.NeighborList(cutoff=r, full_list=False, n_threads=T).compute(...)."""

    name = "vesin"
    module = "vesin"
    dist = "vesin"
    description = "vesin NeighborList(cutoff, full_list=False, n_threads=T).compute(..., 'Pd')"
    threaded = True
    strict = True

    def search(self, positions, radius, box):
        from vesin import NeighborList

        nl = NeighborList(cutoff=radius, full_list=False, n_threads=self.n_threads)
        if box is None:
            pairs, d = nl.compute(positions, np.zeros((3, 3)), False, quantities="Pd")
        else:
            pairs, d = nl.compute(positions, cell_matrix(box), True, quantities="Pd")
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        return oriented(pairs[:, 0], pairs[:, 1]), d


class VesinVerlet(Peer):
    """vesin.NeighborList with ``skin``: Verlet caching between trajectory frames.

    vesin keeps the list of pairs within ``cutoff + skin`` until some atom has
    moved more than ``skin / 2`` and filters it to ``cutoff`` on every call.
    Trajectories only (on a repeated identical frame the cache would always hit).
    """

    name = "vesin-verlet"
    module = "vesin"
    dist = "vesin"
    description = "vesin NeighborList(cutoff, skin=0.3, n_threads=T) reused across frames"
    kinds = ("cutoff",)
    stateful = True
    threaded = True
    skin = 0.3

    def unsupported(self, workload):
        why = super().unsupported(workload)
        if why is None and len(workload.frames) < 2:
            return "Verlet caching is for trajectories only"
        return why

    def setup(self, workload, n_threads):
        from vesin import NeighborList

        super().setup(workload, n_threads)
        self.nl = NeighborList(cutoff=workload.cutoff, full_list=False, skin=self.skin,
                               n_threads=n_threads)
        if workload.box is None:
            self.cell, self.periodic = np.zeros((3, 3)), False
        else:
            self.cell, self.periodic = cell_matrix(workload.box), True

    def run(self, frame):
        (pairs,) = self.nl.compute(self.workload.frames[frame], self.cell, self.periodic,
                                   quantities="P")
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        return oriented(pairs[:, 0], pairs[:, 1])


class FreudPeer(CutoffPeer):
    """freud.locality.AABBQuery / LinkCell queried with r_max and exclude_ii.

    freud has no pair queries in non-periodic boxes, so open systems go into a
    periodic box padded by the radius on every side (no image comes close).
    """

    module = "freud"
    dist = "freud-analysis"
    threaded = True
    strict = True
    float32 = True
    structure = "AABBQuery"

    def unsupported(self, workload):
        return super().unsupported(workload) or need_orthorhombic(workload)

    def search(self, positions, radius, box):
        import freud

        freud.parallel.set_num_threads(self.n_threads)
        if box is None:
            # freud has no pair queries in non-periodic boxes; its users pad a
            # periodic box so that no image comes within r_max
            origin, cell = _open_cell(positions, radius)
            lengths = np.diag(cell) + 2.0 * radius
            fbox = freud.box.Box(*lengths)
            points = positions - (origin - radius) - lengths / 2.0
        else:
            lengths = np.asarray(box[:3], dtype=np.float64)
            fbox = freud.box.Box(*lengths)
            points = np.mod(positions, lengths) - lengths / 2.0
        points = np.ascontiguousarray(points, dtype=np.float64)
        if self.structure == "LinkCell":
            nq = freud.locality.LinkCell(fbox, points, cell_width=radius)
        else:
            nq = freud.locality.AABBQuery(fbox, points)
        nlist = nq.query(points, {"r_max": radius, "exclude_ii": True}).toNeighborList()
        return half_list(nlist.query_point_indices, nlist.point_indices, nlist.distances)


class FreudAABB(FreudPeer):
    name = "freud-aabb"
    structure = "AABBQuery"
    description = "freud AABBQuery(box, points).query(points, r_max, exclude_ii)"


class FreudLinkCell(FreudPeer):
    name = "freud-linkcell"
    structure = "LinkCell"
    description = "freud LinkCell(box, points, cell_width=r).query(points, r_max, exclude_ii)"
