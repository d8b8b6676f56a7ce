"""granularsap itself as a peer: one-shot, kept engine (steady state), kept Verlet list,
kept engine with contact identity."""

from __future__ import annotations

from .base import Peer


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

    #: contact identity (``identity=True``): the previous-row map of every call
    identity = False
    #: why a setting skips box workloads, and single frames (None: it runs them)
    no_boxes = None
    one_frame = None

    def unsupported(self, workload):
        why = super().unsupported(workload)
        if why is None and self.no_boxes and workload.kind == "boxes":
            return self.no_boxes
        if why is None and self.one_frame and len(workload.frames) < 2:
            return self.one_frame
        return why

    def setup(self, workload, n_threads):
        import granularsap

        super().setup(workload, n_threads)
        margin = self.margin_fraction * workload.search_radius()
        # pairs and distances, as a force loop needs them
        if workload.kind == "boxes":
            self.engine = granularsap.SweepAndPrune(n_threads=n_threads)
        elif workload.kind == "contacts":
            self.engine = granularsap.ContactSearch(rebuild_margin=margin, n_threads=n_threads,
                                                    quantities="Pd", identity=self.identity)
        else:
            self.engine = granularsap.NeighborSearch(workload.cutoff, rebuild_margin=margin,
                                                     quantities="Pd", n_threads=n_threads,
                                                     identity=self.identity)
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
    no_boxes = "boxes have no Verlet list (SweepAndPrune keeps its sort state instead)"
    # repeating one frame would only ever re-test a kept list
    one_frame = "Verlet caching is for trajectories only"


class GranularSAPIdentity(GranularSAPSteady):
    """``granularsap-steady`` with contact identity: every frame also maps each pair
    to its row in the previous frame's result (``previous_rows``, -1 for a new
    pair) and lists the rows that ended, what a DEM loop with history asks for."""

    name = "granularsap-identity"
    description = "NeighborSearch / ContactSearch kept across frames, identity=True"
    identity = True
    no_boxes = "contact identity is for particle searches"
    # repeating one frame, every pair continues itself in step
    one_frame = "contact identity is measured on trajectories only"
