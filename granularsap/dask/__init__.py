"""One frame over a Dask cluster: spatial domains with halos, pairs as a Dask DataFrame.

A frame too large for one process is cut into a grid of spatial domains.  Each
domain receives the particles it *owns* plus a *halo*: every particle within
the interaction range of the domain (across periodic faces too; triclinic
cells through fractional coordinates).  The engine
(:class:`~granularsap.NeighborSearch` / :class:`~granularsap.ContactSearch`,
the full cell as ``box``) runs on that subset at the particles' original
coordinates, and the domain keeps the pairs ``(i, j)`` whose smaller index
``i`` it owns.  So every pair appears exactly once over all domains, with the
global particle indices and the same float64 distance, bit for bit, as the
single-machine :func:`granularsap.neighbor_pairs` /
:func:`granularsap.sphere_contacts` (the engine's distance of a pair depends
only on the two particles and the cell).

Ownership is a strict partition: a particle's owner is computed once, from its
wrapped fractional coordinate (Cartesian coordinate for open boundaries), as
``floor((u - lo) * k / span)`` clamped to the grid, so particles on domain
faces, at ``u == 1`` after rounding or outside an open cell each have exactly
one owner.  The halo is generous (a relative slack of 1e-6 of the range plus
rounding of the largest coordinate): the engine's exact test decides.

Every partner of an owned particle is in its domain, so per-particle
coordination numbers are complete inside the domain: no pair list is ever
gathered for them, nor for pair counts and pair-distance histograms (summed
over domains, each pair counted once, on owned pairs only).

Cost: the data move twice, particles from the input chunks to the domains
and, for per-particle results, back to chunks aligned with the input.  A
dask.array frame does both in one Dask DataFrame shuffle each (p2p on a
``distributed`` cluster), so the graph grows with chunks + domains; a NumPy
frame is routed in the calling process and scattered, one input per domain.
Nothing in the graph is as large as a domain's pairs unless they are asked for.

Needs ``pip install "granularsap[dask]"`` (dask.distributed, dask.dataframe,
pyarrow for Parquet).
"""

from __future__ import annotations

from .dataset import PAIRS_SCHEMA, read_pairs
from .domains import DEFAULT_DOMAIN_PARTICLES, DomainSearch

__all__ = [
    "DEFAULT_DOMAIN_PARTICLES",
    "DomainSearch",
    "PAIRS_SCHEMA",
    "coordination_numbers",
    "count_pairs",
    "distance_histogram",
    "neighbor_pairs",
    "radial_distribution",
    "read_pairs",
    "sphere_contacts",
    "write_pairs",
]


def neighbor_pairs(positions, cutoff, *, box=None, pbc=None, domains=None, client=None,
                   n_threads=None, cell=None):
    """Pairs with ``d <= cutoff`` of one frame as a lazy Dask DataFrame.

    The distributed twin of :func:`granularsap.neighbor_pairs`: columns ``i``,
    ``j`` (int64, ``i < j``), ``distance`` (float64), one partition per
    spatial domain, each pair once.  Arguments as for :class:`DomainSearch`.

    Examples
    --------
    >>> import numpy as np, granularsap, granularsap.dask
    >>> x = np.random.default_rng(1).uniform(0, 8, (500, 3))
    >>> df = granularsap.dask.neighbor_pairs(x, 1.2, box=[8, 8, 8, 90, 90, 90], domains=3)
    >>> pairs, d = granularsap.neighbor_pairs(x, 1.2, box=[8, 8, 8, 90, 90, 90])
    >>> len(df.compute()) == len(pairs)
    True
    """
    return DomainSearch(positions, cutoff=cutoff, box=box, cell=cell, pbc=pbc, domains=domains,
                        client=client, n_threads=n_threads).pairs()


def sphere_contacts(positions, radii, *, skin=0.0, box=None, pbc=None, clump_ids=None, cell=None,
                    domains=None, client=None, n_threads=None):
    """Sphere contacts ``d <= r_i + r_j + skin`` of one frame as a lazy Dask DataFrame.

    The distributed twin of :func:`granularsap.sphere_contacts` (with
    ``return_distances=True``); columns ``i``, ``j``, ``distance``.
    """
    return DomainSearch(positions, radii=radii, skin=skin, clump_ids=clump_ids, box=box, cell=cell,
                        pbc=pbc, domains=domains, client=client, n_threads=n_threads).pairs()


def coordination_numbers(positions, cutoff=None, *, radii=None, skin=0.0, box=None, pbc=None,
                         domains=None, client=None, n_threads=None, cell=None):
    """Pairs per particle (neighbours within ``cutoff``, or contacts with ``radii``).

    Returns an ``(n,)`` int64 dask.array aligned with ``positions``; no pair
    list is gathered anywhere.
    """
    return DomainSearch(positions, cutoff=cutoff, radii=radii, skin=skin, box=box, pbc=pbc,
                        cell=cell, domains=domains, client=client,
                        n_threads=n_threads).coordination_numbers()


def count_pairs(positions, cutoff=None, *, radii=None, skin=0.0, box=None, pbc=None,
                domains=None, client=None, n_threads=None, cell=None):
    """Number of pairs (or contacts) of one frame, a lazy 0-d dask.array."""
    return DomainSearch(positions, cutoff=cutoff, radii=radii, skin=skin, box=box, pbc=pbc,
                        cell=cell, domains=domains, client=client,
                        n_threads=n_threads).count_pairs()


def distance_histogram(positions, cutoff=None, *, bins=100, radii=None, skin=0.0, box=None,
                       pbc=None, domains=None, client=None, n_threads=None, cell=None):
    """Pair-distance histogram ``(counts dask.array, edges)``; see
    :meth:`DomainSearch.distance_histogram`."""
    return DomainSearch(positions, cutoff=cutoff, radii=radii, skin=skin, box=box, pbc=pbc,
                        cell=cell, domains=domains, client=client,
                        n_threads=n_threads).distance_histogram(bins)


def radial_distribution(positions, cutoff, *, bins=100, box=None, pbc=None, domains=None, cell=None,
                        client=None, n_threads=None):
    """g(r) up to ``cutoff`` of a periodic frame ``(g dask.array, edges)``; see
    :meth:`DomainSearch.radial_distribution`."""
    return DomainSearch(positions, cutoff=cutoff, box=box, cell=cell, pbc=pbc, domains=domains,
                        client=client, n_threads=n_threads).radial_distribution(bins)


def write_pairs(path, positions, cutoff=None, *, radii=None, skin=0.0, box=None, pbc=None,
                domains=None, client=None, n_threads=None, overwrite=False, cell=None):
    """Write the pairs of a frame to a Parquet dataset, from the workers.

    Each domain's task writes its own ``PATH.partial/domain-NNNNN.parquet``
    (columns ``i``, ``j`` int64, ``distance`` float64; Dask also writes
    ``_metadata`` and ``_common_metadata``); then the calling process writes
    the marker ``_granularsap.json`` (schema, pair count, domains) and renames
    ``PATH.partial`` to ``PATH``.  A dataset at ``PATH`` is therefore always
    complete; an interrupted write leaves only ``PATH.partial``.  With
    ``overwrite=True`` an existing dataset (or a file, or an empty directory)
    is first renamed to ``PATH.replaced`` and deleted after the new one is in
    place; a non-empty directory that is not a pairs dataset is refused
    (``FileExistsError``), never deleted.  Read it with
    ``pandas.read_parquet(PATH)``, ``pyarrow.dataset.dataset(PATH)``, polars,
    DuckDB or :func:`read_pairs` (files starting with ``_`` are metadata,
    ignored by those readers).  The workers and the calling process must see
    the same file system.

    Returns
    -------
    dict
        The marker's content (``n_pairs``, ``domains``, ...).
    """
    search = DomainSearch(positions, cutoff=cutoff, radii=radii, skin=skin, box=box, cell=cell,
                          pbc=pbc, domains=domains, client=client, n_threads=n_threads)
    return search.write_pairs(path, overwrite=overwrite)
