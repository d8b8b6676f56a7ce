"""Adapters that run one benchmark workload through one library.

Every adapter turns a :class:`~granularsap.bench.workloads.Workload` frame
into a ``(k, 2)`` int64 array of pairs with ``i < j``, the way a user of that
library would: its documented entry point, all threads where it has them.
Libraries that take a single cutoff are asked for ``Workload.search_radius()``
(twice the largest radius for contacts, the largest centre distance of two
overlapping boxes for boxes) and their candidates are then filtered with the
exact test (``d <= r_i + r_j`` or the closed-box test); that filter is part
of the timed run, because it is part of what their users run.  Libraries that
compute in float32 (MDAnalysis, freud) get a slightly wider radius (also for
plain cutoff searches) and the filter uses float64 distances, so that pairs at
the cutoff and touching contacts in real DEM data are decided identically for
every peer rather than by float32 rounding.

A peer that is not installed reports why in :meth:`Peer.missing`; a peer that
cannot handle a workload (a triclinic cell, say) reports why in
:meth:`Peer.unsupported`.  Neither is an error: the harness prints the reason
and goes on.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import time

import numpy as np

#: relative widening of the candidate radius for libraries that test ``d < r``
_WIDEN = 1e-9
#: relative widening for libraries that compute in float32 (MDAnalysis, freud)
FLOAT32_WIDEN = 1e-4


def _version(dist):
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


def _orient(i, j):
    """``(k, 2)`` int64 pairs with ``i < j`` from two index arrays."""
    i = np.asarray(i, dtype=np.int64)
    j = np.asarray(j, dtype=np.int64)
    return np.stack([np.minimum(i, j), np.maximum(i, j)], axis=1)


def _half(i, j, d=None):
    """Keep one direction (``i < j``) of a full neighbour list."""
    keep = i < j
    pairs = np.stack([np.asarray(i[keep], np.int64), np.asarray(j[keep], np.int64)], axis=1)
    return pairs, (None if d is None else d[keep])


def pair_distances(positions, pairs, box):
    """Minimum-image float64 distances of ``pairs`` (open, orthorhombic or triclinic)."""
    delta = positions[pairs[:, 1]] - positions[pairs[:, 0]]
    if box is None:
        return np.sqrt(np.einsum("ij,ij->i", delta, delta))
    box = np.asarray(box, dtype=np.float64)
    if np.allclose(box[3:], 90.0):
        delta -= box[:3] * np.round(delta / box[:3])
        return np.sqrt(np.einsum("ij,ij->i", delta, delta))
    cell = _cell_matrix(box)
    frac = delta @ np.linalg.inv(cell)
    delta = (frac - np.round(frac)) @ cell
    # rounding in fractional coordinates can miss the nearest image of a skewed
    # cell: take the shortest of the 27 neighbouring images
    best = np.einsum("ij,ij->i", delta, delta)
    for shift in np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).reshape(3, -1).T:
        if shift.any():
            d = delta + shift @ cell
            best = np.minimum(best, np.einsum("ij,ij->i", d, d))
    return np.sqrt(best)


def exact_filter(workload, frame, pairs, distances=None):
    """Apply the workload's exact test to candidate ``pairs`` found with one radius."""
    if workload.kind == "cutoff":
        if distances is None:
            distances = pair_distances(workload.frames[frame], pairs, workload.box)
        return pairs[distances <= workload.cutoff]
    if workload.kind == "contacts":
        if distances is None:
            distances = pair_distances(workload.frames[frame], pairs, workload.box)
        r = workload.radii
        return pairs[distances <= r[pairs[:, 0]] + r[pairs[:, 1]]]
    lower, upper = workload.boxes(frame)
    a, b = pairs[:, 0], pairs[:, 1]
    ok = np.all((lower[a] <= upper[b]) & (lower[b] <= upper[a]), axis=1)
    return pairs[ok]


class Peer:
    """One library's way of answering a workload.

    Subclasses set ``name``, ``module`` (what must import), ``dist`` (the
    distribution whose version is reported) and implement :meth:`run`.
    """

    name = "peer"
    module = None
    dist = None
    description = ""
    kinds = ("cutoff", "contacts", "boxes")
    #: True when the peer keeps state between frames (``setup`` once, then ``run`` per frame)
    stateful = False
    #: True when the peer uses ``n_threads`` threads, False when it is serial
    threaded = False
    #: rebuilds the peer did on its own (stateful peers), reported with its timing
    rebuilds = 0

    def missing(self):
        """None when usable, else a short reason (the import error)."""
        if self.module is None:
            return None
        try:
            importlib.import_module(self.module)
        except Exception as exc:  # any import failure means "not usable here"
            return f"{type(exc).__name__}: {exc}"
        return None

    def version(self):
        return _version(self.dist) if self.dist else None

    def unsupported(self, workload):
        """None when the peer can answer ``workload``, else the reason it cannot."""
        if workload.kind not in self.kinds:
            return f"does not handle {workload.kind} workloads"
        return None

    def threads_used(self, n_threads):
        return n_threads if self.threaded else 1

    def setup(self, workload, n_threads):
        """Untimed preparation for one workload (and its frames)."""
        self.workload = workload
        self.n_threads = n_threads

    def run(self, frame):
        """Pairs ``(k, 2)`` int64 with ``i < j`` for ``workload.frames[frame]``."""
        raise NotImplementedError

    def last_stats(self):
        """Per-phase figures of the last run, when the peer has them."""
        return None

    def last_seconds(self):
        """The peer's own timing of the last run, or None to use the harness's wall clock.

        Peers that time themselves (LAMMPS's timers) leave the untimed parts of
        a run (reading its neighbour list back into numpy) out of the figure.
        """
        return None

    def note(self):
        """A short remark on the last run for the table (or None)."""
        return None

    def close(self):
        """Release what ``setup`` acquired (called before a new ``setup`` and at the end)."""


class CutoffPeer(Peer):
    """A library answering "all pairs within r": candidates, then the exact filter."""

    #: the library tests d < r instead of d <= r
    strict = False
    #: the library computes in float32: its radius is widened by FLOAT32_WIDEN
    #: and the exact test uses float64 distances from the input positions, so
    #: pairs at the cutoff (or touching contacts) are decided the same way by
    #: every peer instead of by float32 rounding
    float32 = False

    def search(self, positions, radius, box):
        """``(pairs (k, 2) with i < j, distances or None)`` within ``radius``."""
        raise NotImplementedError

    def run(self, frame):
        wl = self.workload
        radius = wl.search_radius()
        if self.float32:
            radius *= 1.0 + FLOAT32_WIDEN
        elif wl.kind != "cutoff" or self.strict:
            radius *= 1.0 + _WIDEN
        box = wl.box if wl.kind != "boxes" else None
        pairs, dist = self.search(wl.frames[frame], radius, box)
        if self.float32:
            return exact_filter(wl, frame, pairs, None)
        if wl.kind == "cutoff" and not self.strict:
            return pairs
        return exact_filter(wl, frame, pairs, dist)


def _need_orthorhombic(workload):
    if not workload.orthorhombic:
        return "this adapter handles orthorhombic cells only"
    return None


# --------------------------------------------------------------------- granularsap


class GranularSAP(Peer):
    """granularsap's one-shot functions: box_overlaps, sphere_contacts, neighbor_pairs."""

    name = "granularsap"
    module = "granularsap"
    dist = "granularsap"
    description = "fresh call: box_overlaps / sphere_contacts / neighbor_pairs"
    threaded = True

    def run(self, frame):
        import granularsap

        wl = self.workload
        pos = wl.frames[frame]
        if wl.kind == "boxes":
            lower, upper = wl.boxes(frame)
            return granularsap.box_overlaps(lower, upper, n_threads=self.n_threads)
        if wl.kind == "contacts":
            return granularsap.sphere_contacts(pos, wl.radii, box=wl.box,
                                               n_threads=self.n_threads)
        return granularsap.neighbor_pairs(pos, wl.cutoff, box=wl.box, n_threads=self.n_threads,
                                          return_distances=False)


class GranularSAPSteady(Peer):
    """One stateful search kept across frames: buffers, column order and (with
    ``rebuild_margin``) a Verlet list are reused.

    ``NeighborSearch`` for cutoff workloads, ``ContactSearch`` for sphere
    contacts, ``SweepAndPrune`` for boxes.  With the default margin 0 every
    frame is a full rebuild into reused memory (what a DEM code that asks for
    contacts every step pays); ``granularsap-verlet`` keeps a Verlet list.
    """

    name = "granularsap-steady"
    module = "granularsap"
    dist = "granularsap"
    description = "NeighborSearch / ContactSearch / SweepAndPrune kept across frames"
    stateful = True
    threaded = True
    #: Verlet margin, as a fraction of the workload's search radius
    margin_fraction = 0.0

    def setup(self, workload, n_threads):
        import granularsap

        super().setup(workload, n_threads)
        margin = self.margin_fraction * workload.search_radius()
        # pairs and distances, as a force loop needs them
        if workload.kind == "boxes":
            self.engine = granularsap.SweepAndPrune(n_threads=n_threads)
        elif workload.kind == "contacts":
            self.engine = granularsap.ContactSearch(rebuild_margin=margin, n_threads=n_threads,
                                                    quantities="Pd")
        else:
            self.engine = granularsap.NeighborSearch(workload.cutoff, rebuild_margin=margin,
                                                     quantities="Pd", n_threads=n_threads)
        self.rebuilds = 0

    def last_stats(self):
        stats = getattr(self.engine, "stats", None)
        return dict(stats) if stats else None

    def note(self):
        stats = getattr(self.engine, "stats", None) or {}
        if "path" not in stats:
            return None
        levels = stats.get("levels")
        return f"path {stats['path']}" + (f", {levels} column levels" if levels == 2 else "")

    def run(self, frame):
        wl = self.workload
        if wl.kind == "boxes":
            lower, upper = wl.boxes(frame)
            return self.engine.update(lower, upper)
        pos = wl.frames[frame]
        if wl.kind == "contacts":
            pairs, _ = self.engine.update(pos, wl.radii, wl.box)
        else:
            pairs, _ = self.engine.update(pos, wl.box)
        if frame > 0 and self.engine.stats.get("rebuilt"):
            self.rebuilds += 1
        return pairs


class GranularSAPVerlet(GranularSAPSteady):
    """``granularsap-steady`` with a Verlet list: rebuild margin 0.1 x the range."""

    name = "granularsap-verlet"
    description = "NeighborSearch / ContactSearch with rebuild_margin = 0.1 x range"
    margin_fraction = 0.1

    def unsupported(self, workload):
        why = super().unsupported(workload)
        if why is None and workload.kind == "boxes":
            return "boxes have no Verlet list (SweepAndPrune keeps its sort state instead)"
        if why is None and len(workload.frames) < 2:
            # repeating one frame would only ever re-test a kept list
            return "Verlet caching is for trajectories only"
        return why


# ------------------------------------------------------------------------ peers


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
        return _orient(pairs[:, 0], pairs[:, 1]), dist


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
        return super().unsupported(workload) or _need_orthorhombic(workload)

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


def _cell_matrix(box):
    """(3, 3) cell with rows as vectors from MDAnalysis box form."""
    from MDAnalysis.lib.mdamath import triclinic_vectors

    return np.asarray(triclinic_vectors(box), dtype=np.float64)


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
        if why is None and workload.box is not None and not _version("MDAnalysis"):
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
            atoms = Atoms(positions=positions, cell=_cell_matrix(box), pbc=True)
        i, j, d = neighbor_list("ijd", atoms, radius)
        return _half(i, j, d)


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
                                     cell=_cell_matrix(box), pbc=[True] * 3)
        return _half(i, j, d)


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
            pairs, d = nl.compute(positions, _cell_matrix(box), True, quantities="Pd")
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        return _orient(pairs[:, 0], pairs[:, 1]), d


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
            self.cell, self.periodic = _cell_matrix(workload.box), True

    def run(self, frame):
        (pairs,) = self.nl.compute(self.workload.frames[frame], self.cell, self.periodic,
                                   quantities="P")
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        return _orient(pairs[:, 0], pairs[:, 1])


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
        return super().unsupported(workload) or _need_orthorhombic(workload)

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
        return _half(nlist.query_point_indices, nlist.point_indices, nlist.distances)


class FreudAABB(FreudPeer):
    name = "freud-aabb"
    structure = "AABBQuery"
    description = "freud AABBQuery(box, points).query(points, r_max, exclude_ii)"


class FreudLinkCell(FreudPeer):
    name = "freud-linkcell"
    structure = "LinkCell"
    description = "freud LinkCell(box, points, cell_width=r).query(points, r_max, exclude_ii)"


class LammpsPeer(CutoffPeer):
    """LAMMPS's own neighbour build, through lammps_bridge.neighbor_pairs."""

    name = "lammps"
    module = "lammps_bridge"
    dist = "lammps"
    description = "LAMMPS neighbour list via lammps_bridge.neighbor_pairs"

    def missing(self):
        why = super().missing()
        if why:
            return why
        import lammps_bridge

        if not hasattr(lammps_bridge, "neighbor_pairs"):
            return "lammps_bridge.neighbor_pairs is not part of this build"
        try:
            importlib.import_module("lammps")
        except Exception as exc:
            return f"{type(exc).__name__}: {exc}"
        return None

    def search(self, positions, radius, box):
        import lammps_bridge

        pairs = lammps_bridge.neighbor_pairs(positions, radius, box=box)
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        return _orient(pairs[:, 0], pairs[:, 1]), None


# ------------------------------------------------------------ LAMMPS, self-timed

#: LAMMPS's neighbour entries carry "special" bond bits above this mask
_NEIGHMASK = 0x1FFFFFFF
#: relative enlargement of LAMMPS's cutoff before the exact test (LAMMPS keeps rsq <= cutneighsq)
_LAMMPS_WIDEN = 1e-8
#: steps of the self-timed run of ``lammps-rebuild`` (one neighbour build per step)
REBUILD_STEPS = 10


_LAMMPS_PROBE = {}


def _lammps_probe():
    """``{"missing": reason or None, "omp": has the OPENMP package}``, probed once."""
    if not _LAMMPS_PROBE:
        try:
            import lammps_bridge

            lmp = lammps_bridge.new_lammps()
        except Exception as exc:  # ImportError, or a library that does not load
            _LAMMPS_PROBE.update(missing=f"{type(exc).__name__}: {exc}", omp=False)
        else:
            _LAMMPS_PROBE.update(missing=None, omp=bool(lmp.has_package("OPENMP")))
            lmp.close()
    return _LAMMPS_PROBE


def _omp_words():
    if _lammps_probe()["omp"]:
        return "OPENMP package (package omp T, suffix omp)"
    return "serial: this LAMMPS build has no OPENMP package"


def _f(x):
    """A float as LAMMPS reads it back exactly."""
    return repr(float(x))


def _log_sections(path):
    """``{section: avg seconds}`` of the last timer breakdown in a LAMMPS log file."""
    with open(path) as fh:
        lines = fh.read().splitlines()
    head = max((k for k, line in enumerate(lines) if line.startswith("Section |")), default=None)
    if head is None:
        raise RuntimeError(f"LAMMPS wrote no timer breakdown to {path}")
    out = {}
    for line in lines[head + 2:]:
        cols = [c.strip() for c in line.split("|")]
        if len(cols) < 3 or not cols[0]:
            break
        out[cols[0]] = float(cols[2])
    return out


class _LammpsSystem:
    """One LAMMPS instance holding a workload's particles, set up as its users do.

    ``units lj``; a box equal to the workload's cell (orthorhombic ``block`` or
    restricted triclinic ``prism``, the form of MDAnalysis's cell vectors) or,
    for open boundaries, a fixed (``f``) box around the particles; ``pair_style
    zero`` at the cutoff for points, ``atom_style sphere`` with per-atom
    diameters and ``pair_style gran/hooke`` for contacts (LAMMPS's size-based
    list, ``rsq <= (r_i + r_j + skin)^2``); ``neighbor 0.0 bin`` (contacts: a
    skin of 1e-8 of the largest contact distance) and ``neigh_modify every 1
    delay 0 check no``; ``package omp T`` and ``suffix omp`` when the build has
    the OPENMP package.  The cutoff is widened by a relative 1e-8 and the list
    is filtered with the workload's exact test, as ``lammps_bridge`` does.
    """

    def __init__(self, workload, n_threads):
        import shutil
        import tempfile
        import weakref

        import lammps_bridge

        self.wl = workload
        folder = tempfile.mkdtemp(prefix="granularsap-bench-lammps-")
        self._cleanup = weakref.finalize(self, shutil.rmtree, folder, ignore_errors=True)
        self.log = f"{folder}/log.lammps"
        self.lmp = lammps_bridge.new_lammps(cmdargs=["-log", self.log, "-screen", "none"],
                                            quiet=False)
        self.omp = bool(self.lmp.has_package("OPENMP"))
        self.sphere = workload.kind == "contacts"
        self.frame = None
        try:
            self._build(n_threads)
        except Exception:
            self.close()
            raise

    def _build(self, n_threads):
        wl, lmp = self.wl, self.lmp
        reach = wl.search_radius()
        cmds = [f"package omp {int(n_threads)}", "suffix omp"] if self.omp else []
        cmds += ["units lj", "atom_style sphere" if self.sphere else "atom_style atomic",
                 "atom_modify map array"]
        if wl.box is None:
            pos = wl.frames[0]
            lo = (pos.min(axis=0) if wl.n else np.zeros(3)) - reach - 1.0
            hi = (pos.max(axis=0) if wl.n else np.zeros(3)) + reach + 1.0
            self.h = None
            cmds += ["boundary f f f", "region box block " + " ".join(
                f"{_f(a)} {_f(b)}" for a, b in zip(lo, hi, strict=True)) + " units box"]
        else:
            h = self.h = _cell_matrix(wl.box)
            if abs(h[1, 0]) + abs(h[2, 0]) + abs(h[2, 1]) > 0:
                region = (f"region box prism 0 {_f(h[0, 0])} 0 {_f(h[1, 1])} 0 {_f(h[2, 2])} "
                          f"{_f(h[1, 0])} {_f(h[2, 0])} {_f(h[2, 1])} units box")
            else:
                region = (f"region box block 0 {_f(h[0, 0])} 0 {_f(h[1, 1])} 0 {_f(h[2, 2])} "
                          "units box")
            cmds += ["boundary p p p", region]
        cmds += ["create_box 1 box"]
        if self.sphere:
            skin = _LAMMPS_WIDEN * max(reach, 1e-300)
            cmds += ["comm_modify vel yes", "pair_style gran/hooke 1.0 0.0 0.0 0.0 0.0 0",
                     "pair_coeff * *", f"neighbor {_f(skin)} bin"]
            self.style = "gran/hooke"
        else:
            cmds += ["mass 1 1.0", f"pair_style zero {_f(wl.cutoff * (1.0 + _LAMMPS_WIDEN))}",
                     "pair_coeff * *", "neighbor 0.0 bin"]
            self.style = "zero"
        cmds += ["neigh_modify every 1 delay 0 check no"]
        for c in cmds:
            lmp.command(c)
        n = wl.n
        x = self._wrapped(0)
        created = lmp.create_atoms(n, list(range(1, n + 1)), [1] * n, x.ravel().tolist())
        if created != n:
            raise RuntimeError(f"LAMMPS created {created} of {n} atoms")
        if self.sphere:
            tag = self._tags()
            lmp.numpy.extract_atom("radius", nelem=n)[:n] = wl.radii[tag]
            lmp.numpy.extract_atom("rmass", nelem=n)[:n] = 1.0
        self.frame = 0

    def _wrapped(self, frame):
        """Positions of ``frame`` wrapped into the cell (unchanged inside it)."""
        pos = self.wl.frames[frame]
        if self.h is None:
            return pos
        if self.wl.orthorhombic:
            lengths = np.diag(self.h)
            return pos - lengths * np.floor(pos / lengths)
        frac = pos @ np.linalg.inv(self.h)
        return (frac - np.floor(frac)) @ self.h

    def _tags(self):
        n = self.lmp.extract_setting("nlocal")
        return np.asarray(self.lmp.numpy.extract_atom("id", nelem=n)[:n], dtype=np.int64) - 1

    def scatter(self, frame, *, force=False):
        """Write ``frame``'s positions into LAMMPS's own (possibly re-sorted) atom order."""
        if frame == self.frame and not force:
            return
        n = self.lmp.extract_setting("nlocal")
        x = self.lmp.numpy.extract_atom("x", nelem=n)
        x[:n] = self._wrapped(frame)[self._tags()]
        self.frame = frame

    def run(self, command, *, timers=True):
        """Run ``command``; with ``timers``, in a fresh log, returning ``{section: seconds}``
        of LAMMPS's timer breakdown."""
        if not timers:
            self.lmp.command(command)
            return {}
        self.lmp.command(f"log {self.log}")
        self.lmp.command(command)
        self.lmp.command("log none")
        return _log_sections(self.log)

    def pairs(self):
        """(pairs with i < j filtered exactly, entries of LAMMPS's list) of the current frame."""
        lmp = self.lmp
        nlocal = lmp.extract_setting("nlocal")
        nall = nlocal + lmp.extract_setting("nghost")
        tag = np.asarray(lmp.numpy.extract_atom("id", nelem=nall)[:nall], dtype=np.int64) - 1
        style = self.style
        if self.omp and lmp.has_style("pair", style + "/omp"):
            style += "/omp"  # what ``suffix omp`` made of it
        idx = lmp.find_pair_neighlist(style, reqid=0)
        if idx < 0:
            raise RuntimeError(f"LAMMPS has no neighbour list for pair style {self.style}")
        nl = lmp.numpy.get_neighlist(idx)
        ii, jj = [np.empty(0, np.int64)], [np.empty(0, np.int64)]
        for k in range(len(nl)):
            i, neigh = nl.get(k)
            ii.append(np.full(len(neigh), i, dtype=np.int64))
            jj.append(np.asarray(neigh, dtype=np.int64) & _NEIGHMASK)
        ti, tj = tag[np.concatenate(ii)], tag[np.concatenate(jj)]
        entries = len(ti)
        keep = ti != tj
        pairs = _orient(ti[keep], tj[keep])
        code = np.unique(pairs[:, 0] * max(self.wl.n, 1) + pairs[:, 1])
        pairs = np.stack([code // max(self.wl.n, 1), code % max(self.wl.n, 1)], axis=1)
        return exact_filter(self.wl, self.frame, pairs), entries

    def close(self):
        if getattr(self, "lmp", None) is not None:
            self.lmp.close()
            self.lmp = None
        self._cleanup()


class _LammpsSelfTimed(Peer):
    """Shared set-up of the LAMMPS peers that report LAMMPS's own time."""

    module = "lammps"
    dist = "lammps"
    kinds = ("cutoff", "contacts")
    threaded = True

    def missing(self):
        return _lammps_probe()["missing"]

    def threads_used(self, n_threads):
        return n_threads if getattr(self, "omp", True) else 1

    def setup(self, workload, n_threads):
        super().setup(workload, n_threads)
        self.close()
        self.system = _LammpsSystem(workload, n_threads)
        self.omp = self.system.omp
        self.seconds = None
        self.stats = None
        self.cache = None

    def _pairs(self, frame):
        """The exact pairs of ``frame`` from LAMMPS's list (kept while the frame repeats)."""
        if self.cache is None or self.cache[0] != frame:
            pairs, entries = self.system.pairs()
            self.cache = (frame, pairs, entries)
        return self.cache[1], self.cache[2]

    def last_seconds(self):
        return self.seconds

    def last_stats(self):
        return self.stats

    def note(self):
        if not self.stats:
            return None
        where = f" on frame {self.cache[0]}" if len(self.workload.frames) > 1 else ""
        return f"LAMMPS list{where}: {self.stats['list_entries']} entries"

    def close(self):
        system = getattr(self, "system", None)
        if system is not None:
            system.close()
            self.system = None


class LammpsRebuild(_LammpsSelfTimed):
    """LAMMPS's own neighbour list rebuilt every step, timed by LAMMPS's timers.

    ``run 10`` with ``neigh_modify every 1 delay 0 check no`` rebuilds the list
    on every step; the figure is the ``Neigh`` plus ``Comm`` sections of
    LAMMPS's timer breakdown (binning, the list build, ghost atoms) divided by
    the 10 steps.  The pairs are read back from the list after the run
    (untimed) and filtered with the exact test.
    """

    name = "lammps-rebuild"

    @property
    def description(self):
        return (f"LAMMPS neighbor 0.0 bin, rebuilt every step: (Neigh + Comm) / {REBUILD_STEPS} "
                f"of its timers in run {REBUILD_STEPS}; {_omp_words()}")

    def run(self, frame):
        self.system.scatter(frame)
        t0 = time.perf_counter()
        sections = self.system.run(f"run {REBUILD_STEPS}")
        wall = time.perf_counter() - t0
        neigh, comm = sections.get("Neigh", 0.0), sections.get("Comm", 0.0)
        self.seconds = (neigh + comm) / REBUILD_STEPS
        pairs, entries = self._pairs(frame)
        self.stats = {"list_entries": int(entries), "pairs": len(pairs),
                      "seconds": {"neigh": neigh / REBUILD_STEPS, "comm": comm / REBUILD_STEPS,
                                  "run_wall": wall / REBUILD_STEPS},
                      "omp": self.omp}
        return pairs


class LammpsRun0(_LammpsSelfTimed):
    """One running LAMMPS instance answering each trajectory frame with ``run 0``.

    Per frame the new positions are written into LAMMPS's atom array (in its
    own order, through the numpy views) and ``run 0 post no`` builds the list;
    the time is measured around those two in Python, which is what a user
    post-processing a trajectory in LAMMPS pays.  Reading the list back into
    numpy is not timed.
    """

    name = "lammps-run0"
    stateful = True

    @property
    def description(self):
        return f"LAMMPS run 0 per frame on one instance: scatter positions + run 0; {_omp_words()}"

    def unsupported(self, workload):
        why = super().unsupported(workload)
        if why is None and len(workload.frames) < 2:
            return "run 0 per frame is for trajectories (lammps-rebuild times one frame)"
        return why

    def run(self, frame):
        t0 = time.perf_counter()
        self.system.scatter(frame, force=True)
        self.system.run("run 0 post no", timers=False)
        self.seconds = time.perf_counter() - t0
        self.cache = None
        pairs, entries = self._pairs(frame)
        self.stats = {"list_entries": int(entries), "pairs": len(pairs), "omp": self.omp}
        return pairs



# ------------------------------------------------------------------ numba cell list


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
        why = super().unsupported(workload) or _need_orthorhombic(workload)
        if why is None and workload.box is not None:
            if np.min(workload.box[:3]) < 3.0 * workload.search_radius():
                return "a periodic cell needs at least 3 bins of the reach per axis"
        return why

    def setup(self, workload, n_threads):
        from .celllist import CellList

        super().setup(workload, n_threads)
        self.cells = CellList(n_threads=n_threads)
        if workload.kind == "boxes":  # half diagonals, widened past rounding
            self._box_radii = np.linalg.norm(workload.half_extents, axis=1) * (1.0 + _WIDEN)

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


#: every peer the bench command knows, in report order
PEERS = {cls.name: cls for cls in (
    GranularSAP, GranularSAPSteady, GranularSAPVerlet, MDANSGrid, MDAPKDTree, ScipyCKDTree, ASEPeer,
    MatscipyPeer, VesinPeer, VesinVerlet, FreudAABB, FreudLinkCell, LammpsPeer, LammpsRebuild,
    LammpsRun0, NumbaCellList,
)}

#: names of the granularsap adapters (the reference of the ratios)
GRANULARSAP = ("granularsap", "granularsap-steady", "granularsap-verlet")


def make_peers(names=None):
    """Peer instances for ``names`` (all known peers when None).

    Raises
    ------
    ValueError
        For a name that is not a known peer.
    """
    if names is None:
        names = list(PEERS)
    unknown = [n for n in names if n not in PEERS]
    if unknown:
        raise ValueError(f"unknown peer {unknown[0]!r}; choose from {', '.join(PEERS)}")
    return [PEERS[n]() for n in names]
