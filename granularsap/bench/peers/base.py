"""Peers' shared parts: the ``Peer`` interface, the exact filter every cutoff peer's
candidates go through, and their float32 widening."""

from __future__ import annotations

import importlib
import importlib.metadata

import numpy as np

#: relative widening of the candidate radius for libraries that test ``d < r``
WIDEN = 1e-9


#: relative widening for libraries that compute in float32 (MDAnalysis, freud)
FLOAT32_WIDEN = 1e-4


def dist_version(dist):
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


def oriented(i, j):
    """``(k, 2)`` int64 pairs with ``i < j`` from two index arrays."""
    i = np.asarray(i, dtype=np.int64)
    j = np.asarray(j, dtype=np.int64)
    return np.stack([np.minimum(i, j), np.maximum(i, j)], axis=1)


def half_list(i, j, d=None):
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
    cell = cell_matrix(box)
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
        return dist_version(self.dist) if self.dist else None

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
            radius *= 1.0 + WIDEN
        box = wl.box if wl.kind != "boxes" else None
        pairs, dist = self.search(wl.frames[frame], radius, box)
        if self.float32:
            return exact_filter(wl, frame, pairs, None)
        if wl.kind == "cutoff" and not self.strict:
            return pairs
        return exact_filter(wl, frame, pairs, dist)


def need_orthorhombic(workload):
    if not workload.orthorhombic:
        return "this adapter handles orthorhombic cells only"
    return None


def cell_matrix(box):
    """(3, 3) cell with rows as vectors from MDAnalysis box form."""
    from MDAnalysis.lib.mdamath import triclinic_vectors

    return np.asarray(triclinic_vectors(box), dtype=np.float64)
