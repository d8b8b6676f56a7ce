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

from .base import (  # noqa: F401
    FLOAT32_WIDEN,
    WIDEN,
    CutoffPeer,
    Peer,
    dist_version,
    exact_filter,
    half_list,
    need_orthorhombic,
    oriented,
    pair_distances,
)
from .celllist import NumbaCellList  # noqa: F401
from .lammps import REBUILD_STEPS, LammpsPeer, LammpsRebuild, LammpsRun0, log_sections  # noqa: F401
from .ours import (  # noqa: F401
    GranularSAP,
    GranularSAPIdentity,
    GranularSAPSteady,
    GranularSAPVerlet,
)
from .python import (  # noqa: F401
    ASEPeer,
    FreudAABB,
    FreudLinkCell,
    FreudPeer,
    MatscipyPeer,
    MDAnalysisPeer,
    MDANSGrid,
    MDAPKDTree,
    ScipyCKDTree,
    VesinPeer,
    VesinVerlet,
    cell_matrix,
)

#: every peer the bench command knows, in report order
PEERS = {cls.name: cls for cls in (
    GranularSAP, GranularSAPSteady, GranularSAPVerlet, GranularSAPIdentity, MDANSGrid, MDAPKDTree,
    ScipyCKDTree, ASEPeer,
    MatscipyPeer, VesinPeer, VesinVerlet, FreudAABB, FreudLinkCell, LammpsPeer, LammpsRebuild,
    LammpsRun0, NumbaCellList,
)}


#: names of the granularsap adapters (the reference of the ratios)
GRANULARSAP = ("granularsap", "granularsap-steady", "granularsap-verlet", "granularsap-identity")


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
