"""``DomainSearch``: one frame cut into spatial domains over a Dask cluster."""

from __future__ import annotations

import math
import os

import dask
import dask.array as da
import numpy as np
from dask import delayed

from ..cell import Cell
from ..inputs import as_coords, as_labels, as_radii, as_scalar, check_n_threads
from ..search import ContactSearch, NeighborSearch
from ._deps import dataframe, need_distributed
from .dataset import write_search_pairs
from .plan import (
    HALO_SLACK,
    ROUTE_BLOCK,
    Plan,
    as_grid,
    choose_grid,
    chunk_extent,
    concat_pieces,
    route,
    route_frame,
)
from .tasks import (
    assemble,
    check_block,
    domain_coordination_part,
    domain_coordination_split,
    domain_count,
    domain_histogram,
    domain_pairs,
    domain_pairs_part,
    part_count,
    part_histogram,
    route_partition,
)

#: Particles per domain the automatic grid aims at (at most; never fewer domains
#: than workers).  About 1.5 kB per particle while a domain's search runs on a
#: dense liquid (engine buffers plus its pairs), so about 1.5 GB per task.
DEFAULT_DOMAIN_PARTICLES = 1_000_000


def resolve_client(client):
    """(client or None, number of workers) for placing data and sizing the grid."""
    if client is None:
        try:
            from distributed import get_client

            client = get_client()
        except (ImportError, ValueError):
            client = None
    elif isinstance(client, str):
        distributed = need_distributed("client given as an address")
        client = distributed.Client(client)
    elif not hasattr(client, "scatter") or not hasattr(client, "nthreads"):
        raise TypeError(f"client must be a dask.distributed Client, a scheduler address or "
                        f"None, got {type(client).__name__}")
    if client is None:
        return None, os.cpu_count() or 1
    # nthreads() asks the scheduler directly; scheduler_info() returns a cache
    # that the client's periodic refresh may have emptied of workers meanwhile
    workers = len(client.nthreads())
    return client, max(1, workers)


def is_dask(x):
    return isinstance(x, da.Array)


class DomainSearch:
    """One frame split into spatial domains with halos, for a Dask cluster.

    Parameters
    ----------
    positions : (n, 3) dask.array or array_like of float
        Particle positions; a dask.array may have any chunking along the
        particles (it is rechunked to whole rows).  They need not be wrapped.
    cutoff : float, optional
        Neighbour pairs with ``d <= cutoff`` (exactly one of ``cutoff`` and
        ``radii``).
    radii : (n,) dask.array, array_like of float, or float, optional
        Sphere contacts with ``d <= r_i + r_j + skin``.
    skin : float, optional
        Contact distance added to ``r_i + r_j`` (with ``radii``).
    clump_ids : (n,) array_like of int, optional
        Rigid-clump labels (with ``radii``): no pairs inside a clump.
    box : None, (6,) or (3, 3) array_like of float, Cell or ase.Atoms, optional
        The periodic cell, in any form the core's ``box=`` takes; None for open
        boundaries.
    cell : optional
        The older name of ``box`` (kept for one release); give one of the two.
    pbc : bool or (3,) bools, optional
        Periodic axes of ``cell`` (default: all, or the Cell's own).
    domains : int or (3,) ints, optional
        How many spatial domains (the grid is chosen to copy the fewest halo
        particles), or the number along each cell vector.  Default: at least
        one per worker and at most ``particles_per_domain`` particles each.
    client : distributed.Client or str, optional
        A ``dask.distributed`` client, or a scheduler address to connect a
        client to (it becomes the default client).  Default: the current
        default client if there is one, else Dask's threaded scheduler.
    n_threads : int, optional
        numba threads for each domain's search.
    particles_per_domain : int, optional
        Target size of a domain for the automatic grid
        (:data:`DEFAULT_DOMAIN_PARTICLES`).

    Notes
    -----
    A NumPy frame is routed in the calling process and each domain's input is
    sent once to the cluster (``client.scatter``): if a worker dies, the
    domains it held cannot be recomputed and the computation raises.  A
    dask.array frame is routed on the workers; Dask recomputes whatever a lost
    worker held from the array's own graph, so persist (or load from zarr or
    HDF5) a frame you want to survive worker loss.  For a dask.array, one
    pass over the data (extents and validation) runs when the search is made.

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap.dask import DomainSearch
    >>> x = np.random.default_rng(0).uniform(0, 10, (2000, 3))
    >>> ds = DomainSearch(x, cutoff=1.5, box=[10, 10, 10, 90, 90, 90], domains=4)
    >>> ds.grid, ds.pairs().npartitions
    ((1, 1, 4), 4)
    >>> int(ds.count_pairs().compute()) == len(ds.pairs().compute())
    True
    """

    def __init__(self, positions, *, cutoff=None, radii=None, skin=0.0, clump_ids=None,
                 box=None, cell=None, pbc=None, domains=None, client=None,
                 n_threads=None,
                 particles_per_domain=None):
        if (cutoff is None) == (radii is None):
            raise ValueError("give exactly one of cutoff (neighbour pairs) and radii "
                             "(sphere contacts)")
        if cutoff is not None and clump_ids is not None:
            raise ValueError("clump_ids apply to sphere contacts: give radii, not cutoff")
        n_threads = check_n_threads(n_threads)
        skin = as_scalar(skin, "skin")
        cutoff = None if cutoff is None else as_scalar(cutoff, "cutoff")
        per = DEFAULT_DOMAIN_PARTICLES if particles_per_domain is None else \
            particles_per_domain
        if isinstance(per, bool) or not isinstance(per, (int, np.integer)) or per < 1:
            raise ValueError(f"particles_per_domain must be a positive int, got {per!r}")
        self.client, self.n_workers = resolve_client(client)
        name = "box"
        if cell is not None:
            if box is not None:
                raise TypeError("give the cell as box= (cell= is its older name), not both")
            box, name = cell, "cell"
        box = Cell.coerce(box, pbc=pbc, name=name)
        frac_cell = box if box is not None and box.any_periodic else None
        pbc_u = tuple(bool(p) for p in frac_cell.pbc) if frac_cell is not None else \
            (False,) * 3
        # ------------------------------------------------------- the inputs
        self._dask = is_dask(positions)
        if self._dask:
            if positions.ndim != 2 or positions.shape[1] != 3:
                raise ValueError(f"positions must have shape (n, 3), got {positions.shape}")
            if positions.dtype.kind not in "fiu":
                raise TypeError(f"positions must be an array of real numbers, got dtype "
                                f"{positions.dtype}")
            if math.isnan(positions.shape[0]):
                raise ValueError("positions must have known chunk sizes; call "
                                 "positions.compute_chunk_sizes() first")
            positions = positions.rechunk({1: 3})
            n = int(positions.shape[0])
            rows = positions.chunks[0]
        else:
            positions = as_coords(positions, "positions")
            n = len(positions)
            rows = None
        rad = lab = None
        if radii is not None:
            if is_dask(radii):
                if radii.shape != (n,):
                    raise ValueError(f"radii must be a scalar or have shape ({n},), got "
                                     f"{radii.shape}")
                rad = radii.rechunk((rows,)) if self._dask else as_radii(radii.compute(), n)
            else:
                rad = as_radii(radii, n)
                if self._dask:
                    rad = da.from_array(rad, chunks=(rows,))
            if clump_ids is not None:
                lab = as_labels(np.asarray(clump_ids), n)
                if self._dask:
                    lab = da.from_array(lab, chunks=(rows,))
        self.n = n
        # ------------------------------------------------ extents and range
        if self._dask:
            blocks = positions.to_delayed().ravel()
            rblocks = rad.to_delayed().ravel() if rad is not None else [None] * len(blocks)
            offsets = np.concatenate([[0], np.cumsum(rows)]).astype(np.int64)
            ext = [delayed(chunk_extent, nout=4)(b, r, int(o), frac_cell)
                   for b, r, o in zip(blocks, rblocks, offsets[:-1], strict=True)]
            ext = self._compute(ext)
            lo_s = np.min([e[0] for e in ext], axis=0) if ext else np.full(3, np.inf)
            hi_s = np.max([e[1] for e in ext], axis=0) if ext else np.full(3, -np.inf)
            mag = max([e[2] for e in ext], default=0.0)
            rmax = max([e[3] for e in ext], default=0.0)
        else:
            lo_s, hi_s, mag, rmax = chunk_extent(positions, rad, 0, frac_cell)
        if n == 0:
            lo_s, hi_s = np.zeros(3), np.zeros(3)
        reach = cutoff if cutoff is not None else 2.0 * rmax + skin
        self.reach = float(reach)
        self._probe(cutoff, skin, rmax, box, n)
        widths = frac_cell.perpendicular_widths if frac_cell is not None else np.ones(3)
        lo = np.where(pbc_u, 0.0, lo_s)
        span = np.where(pbc_u, 1.0, hi_s - lo_s)
        slack = 64 * np.finfo(np.float64).eps * (mag + 1.0)
        halo = reach / widths * (1.0 + HALO_SLACK) + slack
        splittable = [bool(pbc_u[c] or span[c] > 0) for c in range(3)]
        if domains is None:
            want = max(self.n_workers, -(-n // per))
            norm = np.where(span > 0, halo / np.where(span > 0, span, 1.0), np.inf)
            grid = choose_grid(min(want, max(1, n)), norm, splittable)
        elif isinstance(domains, (int, np.integer)) and not isinstance(domains, bool):
            if domains < 1:
                raise ValueError(f"domains must be a positive int or three positive ints, "
                                 f"got {domains!r}")
            norm = np.where(span > 0, halo / np.where(span > 0, span, 1.0), np.inf)
            grid = choose_grid(int(domains), norm, splittable)
        else:
            if n < 2:
                # no pair to find on any grid: honour the one given; an axis
                # without extent gets a nominal one (every particle in its
                # first domain, the others empty)
                span = np.where(span > 0, span, 1.0)
                splittable = [True] * 3
            grid = as_grid(domains, splittable)
        self.grid = grid
        self.plan = Plan(kind="cutoff" if cutoff is not None else "contacts",
                          cutoff=0.0 if cutoff is None else cutoff, skin=skin, box=box,
                          frac_cell=frac_cell, pbc=pbc_u, lo=tuple(float(v) for v in lo),
                          span=tuple(float(v) for v in span), grid=grid,
                          halo=tuple(float(v) for v in halo), n=n, n_threads=n_threads)
        # ------------------------------------------------- route to domains
        self._shuffle = "p2p" if self.client is not None else "tasks"
        self._routed = None
        if self._dask:
            # chunks -> domains in one shuffle (p2p on a cluster: O(chunks + domains)
            # tasks instead of one per chunk and domain); the frame's index is the
            # global particle index
            dd, _ = dataframe()
            nd = self.plan.n_domains
            cols = [positions.astype(np.float64)]
            names = ["x", "y", "z"]
            if rad is not None:
                cols.append(rad.astype(np.float64)[:, None])
                names.append("r")
            frame = dd.from_dask_array(da.concatenate(cols, axis=1) if len(cols) > 1
                                       else cols[0], columns=names)
            if lab is not None:
                frame["label"] = dd.from_dask_array(lab)
            meta = route_frame(self.plan, np.empty((0, 3)),
                                None if rad is None else np.empty(0),
                                None if lab is None else np.empty(0, np.int64), 0)
            routed = frame.map_partitions(route_partition, self.plan, meta=meta)
            self._routed = routed.set_index("dom", divisions=list(range(nd + 1)),
                                            shuffle_method=self._shuffle)
            self._bounds = np.unique(offsets)
        else:
            pieces = [route(self.plan, positions[a:a + ROUTE_BLOCK],
                             None if rad is None else rad[a:a + ROUTE_BLOCK],
                             None if lab is None else lab[a:a + ROUTE_BLOCK], a)
                      for a in range(0, max(n, 1), ROUTE_BLOCK)]
            inputs = [concat_pieces(*[p[d] for p in pieces])
                      for d in range(self.plan.n_domains)]
            del pieces
            if self.client is not None:
                self._inputs = self.client.scatter(inputs, hash=False)
            else:
                self._inputs = [delayed(inp, traverse=False) for inp in inputs]
            step = max(1, -(-n // max(1, self.plan.n_domains)))
            self._bounds = np.unique(np.concatenate(
                [np.arange(0, n, step), [n]])).astype(np.int64)
        self._sizes = None if self._dask else [len(i[0]) for i in inputs]

    # ------------------------------------------------------------- helpers
    def _compute(self, objs):
        if self.client is not None:
            return self.client.gather(self.client.compute(objs))
        return list(dask.compute(*objs))

    @staticmethod
    def _probe(cutoff, skin, rmax, box, n):
        """The engine's own error for a range too large for the cell, raised here."""
        if box is None or not box.any_periodic or n == 0:
            return
        one = np.zeros((1, 3))
        if cutoff is not None:
            NeighborSearch(cutoff, quantities="P", n_threads=1).update(one, box)
        else:
            ContactSearch(skin=skin, quantities="P", n_threads=1).update(one, [rmax], box)

    @property
    def n_domains(self):
        """Number of spatial domains (partitions of :meth:`pairs`)."""
        return self.plan.n_domains

    def persist(self):
        """Route the particles to their domains now and keep them on the cluster
        (or in memory with the threaded scheduler), so that several results of
        a dask.array frame route it once.  Dask can still recompute what a lost
        worker held.  Returns ``self``."""
        if self._dask:
            if self.client is not None:
                self._routed = self.client.persist(self._routed)
            else:
                self._routed = self._routed.persist(scheduler="threads")
        return self

    def _per_domain(self, func, *args):
        return [delayed(func, pure=True)(self.plan, inp, *args) for inp in self._inputs]

    def domain_sizes(self):
        """Particles (owned plus halo) given to each domain, a list (computed now
        for a dask.array frame: a routing pass unless :meth:`persist` ran)."""
        if self._sizes is None:
            _, pd = dataframe()
            sizes = self._routed.map_partitions(
                lambda part: pd.Series([len(part)], dtype=np.int64),
                meta=pd.Series(np.empty(0, np.int64)))
            self._sizes = [int(v) for v in self._compute([sizes])[0]]
        return list(self._sizes)

    # ------------------------------------------------------------- results
    def pairs(self):
        """All pairs as a lazy ``dask.dataframe.DataFrame``, one partition per domain.

        Columns ``i``, ``j`` (int64 global particle indices, ``i < j``) and
        ``distance`` (float64, the single-machine distance bit for bit); each
        pair in exactly one partition, row order within a partition unspecified.
        """
        dd, pd = dataframe()
        meta = pd.DataFrame({"i": np.empty(0, np.int64), "j": np.empty(0, np.int64),
                             "distance": np.empty(0, np.float64)})
        if self._routed is not None:
            return self._routed.map_partitions(domain_pairs_part, self.plan, meta=meta)
        return dd.from_delayed(self._per_domain(domain_pairs), meta=meta, verify_meta=False)

    def count_pairs(self):
        """Total number of pairs (contacts), a lazy 0-d int64 dask.array."""
        if self._routed is not None:
            _, pd = dataframe()
            counts = self._routed.map_partitions(part_count, self.plan,
                                                 meta=pd.Series(np.empty(0, np.int64)))
            return counts.to_dask_array(lengths=[1] * self.n_domains).sum()
        parts = [da.from_delayed(p, shape=(), dtype=np.int64)
                 for p in self._per_domain(domain_count)]
        return da.stack(parts).sum()

    def coordination_numbers(self):
        """Pairs per particle, an ``(n,)`` int64 dask.array in input order.

        Chunked like a dask.array input (empty chunks dropped; NumPy input:
        about ``n / domains`` per chunk).  Equals ``np.bincount(i, minlength=n)
        + np.bincount(j, minlength=n)`` of the single-machine pairs.
        """
        bounds = self._bounds
        if self.n == 0:
            return da.zeros(0, dtype=np.int64, chunks=1)
        if self._routed is not None:
            _, pd = dataframe()
            meta = pd.DataFrame({"gid": np.empty(0, np.int64), "cn": np.empty(0, np.int64)})
            owned = self._routed.map_partitions(domain_coordination_part, self.plan,
                                                meta=meta)
            # domains -> chunks in input order, in one shuffle
            by_chunk = owned.set_index("gid", divisions=[int(v) for v in bounds],
                                       shuffle_method=self._shuffle)
            values = by_chunk.map_partitions(check_block, bounds,
                                             meta=pd.Series(np.empty(0, np.int64), name="cn"))
            return values.to_dask_array(lengths=[int(v) for v in np.diff(bounds)])
        nc = len(bounds) - 1
        parts = [delayed(domain_coordination_split, nout=nc, pure=True)(self.plan, inp,
                                                                          bounds)
                 for inp in self._inputs]
        blocks = []
        for c in range(nc):
            lo, hi = int(bounds[c]), int(bounds[c + 1])
            task = delayed(assemble, pure=True)(lo, hi, *[p[c] for p in parts])
            blocks.append(da.from_delayed(task, shape=(hi - lo,), dtype=np.int64))
        return da.concatenate(blocks)

    def distance_histogram(self, bins):
        """Pair-distance histogram without gathering the pairs.

        Parameters
        ----------
        bins : int or (m + 1,) array_like of float
            Number of equal bins over ``[0, range]`` (the cutoff, or ``2 *
            max(radii) + skin``), or the bin edges (increasing).

        Returns
        -------
        counts : (m,) int64 dask.array
            ``np.histogram(distances, bins=edges)[0]`` of the single-machine
            distances, each pair once.
        edges : (m + 1,) ndarray of float64
        """
        edges = histogram_edges(bins, self.reach)
        nb = len(edges) - 1
        if self._routed is not None:
            _, pd = dataframe()
            counts = self._routed.map_partitions(part_histogram, self.plan, edges,
                                                 meta=pd.Series(np.empty(0, np.int64)))
            arr = counts.to_dask_array(lengths=[nb] * self.n_domains)
            return arr.reshape(self.n_domains, nb).sum(axis=0), edges
        parts = [da.from_delayed(p, shape=(nb,), dtype=np.int64)
                 for p in self._per_domain(domain_histogram, edges)]
        return da.stack(parts).sum(axis=0), edges

    def radial_distribution(self, bins):
        """The radial distribution function g(r) of a fully periodic cell.

        ``g_k = counts_k / (n (n - 1) / (2 V) * 4/3 pi (r_{k+1}^3 - r_k^3))``
        from :meth:`distance_histogram` (each pair once, the cell volume V):
        MDAnalysis ``InterRDF``'s normalisation of a group with itself.

        Returns
        -------
        g : (m,) float64 dask.array
        edges : (m + 1,) ndarray of float64
        """
        box = self.plan.box
        if box is None or not bool(np.all(box.pbc)):
            raise ValueError("radial_distribution needs a cell periodic on every axis (the "
                             "density is n / cell volume); use distance_histogram otherwise")
        if self.n < 2:
            raise ValueError(f"radial_distribution needs at least 2 particles (pairs), got "
                             f"{self.n}")
        counts, edges = self.distance_histogram(bins)
        shell = 4.0 / 3.0 * np.pi * (edges[1:] ** 3 - edges[:-1] ** 3)
        ideal = self.n * (self.n - 1) / (2.0 * box.volume) * shell
        return counts / ideal, edges

    def write_pairs(self, path, *, overwrite=False):
        """Write the pairs to a Parquet dataset from the workers; see :func:`write_pairs`."""
        return write_search_pairs(self, path, overwrite=overwrite)


def histogram_edges(bins, reach):
    if isinstance(bins, (int, np.integer)) and not isinstance(bins, bool):
        if bins < 1:
            raise ValueError(f"bins must be a positive int or increasing edges, got {bins}")
        return np.linspace(0.0, reach, int(bins) + 1)
    edges = np.asarray(bins, dtype=np.float64)
    if edges.ndim != 1 or len(edges) < 2 or not np.all(np.diff(edges) > 0) or \
            not np.isfinite(edges).all():
        raise ValueError(f"bins must be a positive int or at least two increasing finite "
                         f"edges, got {bins!r}")
    return edges
