"""granularsap: parallel Sweep-and-Prune contact and neighbour search.

Exact lists of overlapping axis-aligned boxes, sphere contacts and neighbour
pairs for molecular dynamics and granular (DEM) simulation, built on the
parallel bi-dimensional Sweep and Prune of Capannini & Larsson.
"""

from ._version import __version__
from .boxes import SweepAndPrune, box_overlaps
from .cell import Cell
from .contact_list import ContactList
from .particles import clump_contacts, neighbor_pairs, sphere_contacts
from .search import ContactSearch, NeighborSearch
from .walls import Plane, TriangleMesh, WallContacts, WallSearch

__all__ = [
    "Cell",
    "ContactList",
    "ContactSearch",
    "NeighborSearch",
    "Plane",
    "SweepAndPrune",
    "TriangleMesh",
    "WallContacts",
    "WallSearch",
    "__version__",
    "box_overlaps",
    "clump_contacts",
    "neighbor_pairs",
    "sphere_contacts",
]
