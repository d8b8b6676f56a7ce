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

import json
import math
import os
import shutil
from dataclasses import dataclass

import dask
import dask.array as da
import numpy as np
from dask import delayed

from .cell import Cell
from .inputs import as_coords, as_labels, as_radii, as_scalar, check_n_threads
from .search import ContactSearch, NeighborSearch

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

#: Particles per domain the automatic grid aims at (at most; never fewer domains
#: than workers).  About 1.5 kB per particle while a domain's search runs on a
#: dense liquid (engine buffers plus its pairs), so about 1.5 GB per task.
DEFAULT_DOMAIN_PARTICLES = 1_000_000
#: Particles routed per block when the frame is a NumPy array in the client.
_ROUTE_BLOCK = 1 << 20
#: Relative slack of the halo width beyond the interaction range.
_HALO_SLACK = 1e-6
#: Name of the completion marker of a pairs dataset, written last.
_MARKER = "_granularsap.json"
#: What a pairs dataset's marker says it is.
PAIRS_SCHEMA = "granularsap.pairs/1"


def _need_distributed(what):
    try:
        import distributed
    except ImportError as exc:  # pragma: no cover - the dask extra installs it
        raise ImportError(f"{what} needs dask.distributed: pip install "
                          "'granularsap[dask]'") from exc
    return distributed


def _dataframe():
    try:
        import dask.dataframe as dd
        import pandas as pd
    except ImportError as exc:  # pragma: no cover - the dask extra installs it
        raise ImportError("pairs as a Dask DataFrame need dask.dataframe and pandas: pip "
                          "install 'granularsap[dask]'") from exc
    return dd, pd


# --------------------------------------------------------------------- the plan
@dataclass(frozen=True)
class _Plan:
    """Everything a task needs to route particles and run a domain (picklable)."""

    kind: str                 # "cutoff" or "contacts"
    cutoff: float
    skin: float
    box: object               # what the engine gets as box= (a Cell or None)
    frac_cell: object         # Cell for fractional coordinates, None: Cartesian
    pbc: tuple                # per axis, for domains (all False when frac_cell is None)
    lo: tuple
    span: tuple
    grid: tuple
    halo: tuple               # per axis, in the units of u
    n: int
    n_threads: object

    @property
    def n_domains(self):
        return self.grid[0] * self.grid[1] * self.grid[2]

    def search(self):
        if self.kind == "cutoff":
            return NeighborSearch(self.cutoff, quantities="Pd", n_threads=self.n_threads)
        return ContactSearch(skin=self.skin, quantities="Pd", n_threads=self.n_threads)


def _check_finite(pos, offset, name="positions"):
    ok = np.isfinite(pos).all(axis=1)
    if not ok.all():
        bad = int(np.flatnonzero(~ok)[0])
        raise ValueError(f"{name} must be finite, got NaN or inf in row {offset + bad}")


def _raw_frac(frac_cell, pos):
    """Fractional coordinates (not wrapped), or the positions themselves."""
    if frac_cell is None:
        return np.array(pos, dtype=np.float64, copy=True)
    return frac_cell.fractional(pos)


def _frac(plan, pos):
    u = _raw_frac(plan.frac_cell, pos)
    for c in range(3):
        if plan.pbc[c]:
            u[:, c] -= np.floor(u[:, c])
    return u


def _chunk_extent(pos, rad, offset, frac_cell):
    """Per chunk: min and max of u (unwrapped), max |u|, max radius; validates."""
    pos = np.asarray(pos, dtype=np.float64)
    _check_finite(pos, offset)
    if rad is not None:
        rad = np.asarray(rad, dtype=np.float64)
        if rad.size:
            if not np.isfinite(rad).all():
                bad = int(np.flatnonzero(~np.isfinite(rad))[0])
                raise ValueError(f"radii must be finite, got {float(rad[bad])!r} at index "
                                 f"{offset + bad}")
            if rad.min() < 0:
                bad = int(np.argmin(rad))
                raise ValueError(f"radii must be non-negative, got {float(rad[bad])!r} at "
                                 f"index {offset + bad}")
    if len(pos) == 0:
        inf = np.full(3, np.inf)
        return inf, -inf, 0.0, 0.0
    s = _raw_frac(frac_cell, pos)
    rmax = float(rad.max()) if rad is not None and rad.size else 0.0
    return s.min(axis=0), s.max(axis=0), float(np.abs(s).max()), rmax


def _axis_range(u, lo, span, k, h, periodic):
    """Owner index, first halo index and count of domains along one axis."""
    n = len(u)
    if k == 1:
        z = np.zeros(n, np.int64)
        return z, z, np.ones(n, np.int64)
    # divide by span before multiplying by k: k / span overflows to inf for a
    # subnormal extent, and (u - lo) * inf is NaN for the particles at lo
    # (a halo much wider than a tiny extent may overflow to +-inf: clipped below)
    with np.errstate(over="ignore"):
        own = np.clip(np.floor((u - lo) / span * k), 0, k - 1).astype(np.int64)
        a = np.floor((u - h - lo) / span * k)
        b = np.floor((u + h - lo) / span * k)
    if periodic:
        cnt = (b - a + 1).astype(np.int64)
        full = cnt >= k
        a = np.where(full, 0, a).astype(np.int64) % k
        cnt = np.where(full, k, cnt)
    else:
        a = np.clip(a, 0, k - 1).astype(np.int64)
        b = np.clip(b, 0, k - 1).astype(np.int64)
        cnt = b - a + 1
    return own, a, cnt


def _route(plan, pos, rad, lab, offset):
    """Split one chunk of particles into its pieces for every domain.

    Returns a list with one ``(idx, positions, radii, labels, owned)`` per
    domain (global indices ascending; ``owned`` marks the particles the domain
    owns, the others are its halo)."""
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    _check_finite(pos, offset)
    n = len(pos)
    k = plan.grid
    u = _frac(plan, pos)
    own = []
    first = []
    count = []
    for c in range(3):
        o, a, cnt = _axis_range(u[:, c], plan.lo[c], plan.span[c], k[c], plan.halo[c],
                                plan.pbc[c])
        own.append(o)
        first.append(a)
        count.append(cnt)
    owner = (own[0] * k[1] + own[1]) * k[2] + own[2]
    local = []
    doms = []
    m = [int(cnt.max()) if n else 0 for cnt in count]
    for o0 in range(m[0]):
        s0 = o0 < count[0]
        d0 = (first[0] + o0) % k[0]
        for o1 in range(m[1]):
            s1 = s0 & (o1 < count[1])
            d1 = (first[1] + o1) % k[1]
            for o2 in range(m[2]):
                sel = np.flatnonzero(s1 & (o2 < count[2]))
                if len(sel) == 0:
                    continue
                d2 = (first[2][sel] + o2) % k[2]
                local.append(sel)
                doms.append((d0[sel] * k[1] + d1[sel]) * k[2] + d2)
    if local:
        local = np.concatenate(local)
        doms = np.concatenate(doms)
    else:
        local = np.empty(0, np.int64)
        doms = np.empty(0, np.int64)
    order = np.lexsort((local, doms))
    local = local[order]
    doms = doms[order]
    bounds = np.searchsorted(doms, np.arange(plan.n_domains + 1))
    rad = None if rad is None else np.asarray(rad, dtype=np.float64)
    lab = None if lab is None else np.asarray(lab, dtype=np.int64)
    out = []
    for d in range(plan.n_domains):
        sel = local[bounds[d]:bounds[d + 1]]
        out.append((sel + offset, pos[sel], None if rad is None else rad[sel],
                    None if lab is None else lab[sel], owner[sel] == d))
    return out


def _concat_pieces(*pieces):
    """One domain's input from its pieces of every chunk (chunk order = index order)."""
    if len(pieces) == 1:
        return pieces[0]
    idx = np.concatenate([p[0] for p in pieces])
    pos = np.concatenate([p[1] for p in pieces]).reshape(-1, 3)
    rad = None if pieces[0][2] is None else np.concatenate([p[2] for p in pieces])
    lab = None if pieces[0][3] is None else np.concatenate([p[3] for p in pieces])
    owned = np.concatenate([p[4] for p in pieces])
    return idx, pos, rad, lab, owned


def _route_frame(plan, pos, rad, lab, offset):
    """:func:`_route` as one pandas DataFrame with a ``dom`` column (for a shuffle)."""
    import pandas as pd

    pieces = _route(plan, pos, rad, lab, offset)
    cols = {"dom": np.concatenate([np.full(len(p[0]), d, np.int64)
                                   for d, p in enumerate(pieces)]),
            "idx": np.concatenate([p[0] for p in pieces])}
    xyz = np.concatenate([p[1] for p in pieces]).reshape(-1, 3)
    cols["x"], cols["y"], cols["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if rad is not None:
        cols["r"] = np.concatenate([p[2] for p in pieces])
    if lab is not None:
        cols["label"] = np.concatenate([p[3] for p in pieces])
    cols["owned"] = np.concatenate([p[4] for p in pieces])
    return pd.DataFrame(cols)


def _unpack(inp):
    """A domain's input as ``(idx, positions, radii, labels, owned)``, idx ascending."""
    if isinstance(inp, tuple):
        return inp
    order = np.argsort(inp["idx"].to_numpy(), kind="stable")
    idx = inp["idx"].to_numpy()[order]
    pos = np.ascontiguousarray(inp[["x", "y", "z"]].to_numpy(dtype=np.float64)[order])
    rad = inp["r"].to_numpy()[order] if "r" in inp.columns else None
    lab = inp["label"].to_numpy()[order] if "label" in inp.columns else None
    return idx, pos, rad, lab, inp["owned"].to_numpy()[order]


# -------------------------------------------------------------- domain tasks
def _domain_search(plan, inp):
    """Pairs of one domain's subset: (local pairs, distances, idx, owned)."""
    idx, pos, rad, lab, owned = _unpack(inp)
    search = plan.search()
    if plan.kind == "cutoff":
        pairs, dist = search.update(pos, plan.box)
    else:
        pairs, dist = search.update(pos, rad, plan.box, clump_ids=lab)
    return pairs, dist, idx, owned


def _domain_pairs(plan, inp):
    """The pairs a domain owns as a pandas DataFrame (global indices)."""
    import pandas as pd

    pairs, dist, idx, owned = _domain_search(plan, inp)
    keep = owned[pairs[:, 0]]  # idx ascending: local i < j is global i < j
    return pd.DataFrame({"i": idx[pairs[keep, 0]], "j": idx[pairs[keep, 1]],
                         "distance": np.array(dist[keep], dtype=np.float64)})


def _domain_count(plan, inp):
    pairs, _, _, owned = _domain_search(plan, inp)
    return np.int64(np.count_nonzero(owned[pairs[:, 0]]))


def _domain_histogram(plan, inp, edges):
    pairs, dist, _, owned = _domain_search(plan, inp)
    counts, _ = np.histogram(dist[owned[pairs[:, 0]]], bins=edges)
    return counts.astype(np.int64)


def _domain_coordination(plan, inp):
    """Coordination numbers of the particles a domain owns: DataFrame gid, cn."""
    import pandas as pd

    pairs, _, idx, owned = _domain_search(plan, inp)
    m = len(idx)
    cn = np.bincount(pairs[:, 0], minlength=m) + np.bincount(pairs[:, 1], minlength=m)
    return pd.DataFrame({"gid": idx[owned], "cn": cn[owned].astype(np.int64)})


def _domain_coordination_split(plan, inp, bounds):
    """Coordination numbers of the owned particles, split by output chunk."""
    pairs, _, idx, owned = _domain_search(plan, inp)
    m = len(idx)
    cn = np.bincount(pairs[:, 0], minlength=m) + np.bincount(pairs[:, 1], minlength=m)
    gid = idx[owned]
    cn = cn[owned].astype(np.int64)
    cut = np.searchsorted(gid, bounds)
    return tuple((gid[cut[c]:cut[c + 1]], cn[cut[c]:cut[c + 1]])
                 for c in range(len(bounds) - 1))


def _assemble(lo, hi, *pieces):
    """One output chunk of per-particle values from every domain's piece."""
    out = np.zeros(hi - lo, np.int64)
    seen = np.zeros(hi - lo, np.int64)
    for gid, val in pieces:
        out[gid - lo] = val
        seen[gid - lo] += 1
    if not np.all(seen == 1):
        bad = int(np.flatnonzero(seen != 1)[0])
        raise RuntimeError(f"particle {lo + bad} was owned by {int(seen[bad])} domains "
                           "instead of one; the decomposition is inconsistent")
    return out


def _domain_pairs_part(part, plan):
    return _domain_pairs(plan, part)


def _domain_coordination_part(part, plan):
    return _domain_coordination(plan, part)


def _route_partition(part, plan):
    """Route one partition of the frame (index: global particle index)."""
    offset = int(part.index[0]) if len(part) else 0
    if len(part) and not np.array_equal(part.index.to_numpy(),
                                        np.arange(offset, offset + len(part))):
        raise RuntimeError("positions partition rows are not consecutive particles")
    pos = part[["x", "y", "z"]].to_numpy(dtype=np.float64)
    rad = part["r"].to_numpy() if "r" in part.columns else None
    lab = part["label"].to_numpy() if "label" in part.columns else None
    return _route_frame(plan, pos, rad, lab, offset)


def _part_count(part, plan):
    import pandas as pd

    return pd.Series([_domain_count(plan, part)], dtype=np.int64)


def _part_histogram(part, plan, edges):
    import pandas as pd

    return pd.Series(_domain_histogram(plan, part, edges), dtype=np.int64)


def _check_block(df, bounds, partition_info=None):
    """One output chunk (rows sorted by particle index): every particle exactly once."""
    k = partition_info["number"]
    lo, hi = int(bounds[k]), int(bounds[k + 1])
    gid = df.index.to_numpy()
    if len(gid) != hi - lo or not np.array_equal(gid, np.arange(lo, hi)):
        raise RuntimeError(f"particles {lo}..{hi - 1}: {len(gid)} coordination numbers "
                           f"instead of {hi - lo}; the decomposition is inconsistent")
    return df["cn"]


# ------------------------------------------------------------------ the grid
def _choose_grid(n_domains, halo_norm, splittable):
    """Domains per axis (product >= n_domains, < 2 n_domains) with the fewest
    particle copies: halo_norm[c] is the halo width over the extent."""
    best = None
    target = max(1, int(n_domains))
    top = [target if splittable[c] else 1 for c in range(3)]
    for k0 in range(1, top[0] + 1):
        for k1 in range(1, min(top[1], -(-target // k0)) + 1):
            k2 = -(-target // (k0 * k1))
            if k2 > top[2]:
                continue
            k = (k0, k1, k2)
            if k0 * k1 * k2 >= 2 * target and target > 1:
                continue
            cost = 1.0
            for c in range(3):
                cost *= min(1.0 + 2.0 * k[c] * halo_norm[c], float(k[c]))
            key = (cost, k0 * k1 * k2, k)
            if best is None or key < best:
                best = key
    if best is None:  # nothing splittable enough: as many as allowed
        return tuple(min(top[c], target) if c == int(np.argmax(top)) else 1 for c in range(3))
    return best[2]


def _as_grid(domains, splittable):
    arr = np.asarray(domains)
    if arr.dtype.kind not in "iu" or arr.shape != (3,) or (arr < 1).any():
        raise ValueError(f"domains must be a positive int or three positive ints (domains "
                         f"along each cell vector), got {domains!r}")
    k = tuple(int(v) for v in arr)
    for c in range(3):
        if k[c] > 1 and not splittable[c]:
            raise ValueError(f"domains {k} splits axis {c}, along which every particle has the "
                             "same coordinate; give 1 domain on that axis")
    return k


# ----------------------------------------------------------------- the search
def _resolve_client(client):
    """(client or None, number of workers) for placing data and sizing the grid."""
    if client is None:
        try:
            from distributed import get_client

            client = get_client()
        except (ImportError, ValueError):
            client = None
    elif isinstance(client, str):
        distributed = _need_distributed("client given as an address")
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


def _is_dask(x):
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
    cell : None, (6,) or (3, 3) array_like of float, Cell or ase.Atoms, optional
        The periodic cell, in any form a ``box=`` takes; None for open boundaries.
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
    >>> ds = DomainSearch(x, cutoff=1.5, cell=[10, 10, 10, 90, 90, 90], domains=4)
    >>> ds.grid, ds.pairs().npartitions
    ((1, 1, 4), 4)
    >>> int(ds.count_pairs().compute()) == len(ds.pairs().compute())
    True
    """

    def __init__(self, positions, *, cutoff=None, radii=None, skin=0.0, clump_ids=None,
                 cell=None, pbc=None, domains=None, client=None, n_threads=None,
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
        self.client, self.n_workers = _resolve_client(client)
        box = Cell.coerce(cell, pbc=pbc, name="cell")
        frac_cell = box if box is not None and box.any_periodic else None
        pbc_u = tuple(bool(p) for p in frac_cell.pbc) if frac_cell is not None else \
            (False,) * 3
        # ------------------------------------------------------- the inputs
        self._dask = _is_dask(positions)
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
            if _is_dask(radii):
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
            ext = [delayed(_chunk_extent, nout=4)(b, r, int(o), frac_cell)
                   for b, r, o in zip(blocks, rblocks, offsets[:-1], strict=True)]
            ext = self._compute(ext)
            lo_s = np.min([e[0] for e in ext], axis=0) if ext else np.full(3, np.inf)
            hi_s = np.max([e[1] for e in ext], axis=0) if ext else np.full(3, -np.inf)
            mag = max([e[2] for e in ext], default=0.0)
            rmax = max([e[3] for e in ext], default=0.0)
        else:
            lo_s, hi_s, mag, rmax = _chunk_extent(positions, rad, 0, frac_cell)
        if n == 0:
            lo_s, hi_s = np.zeros(3), np.zeros(3)
        reach = cutoff if cutoff is not None else 2.0 * rmax + skin
        self.reach = float(reach)
        self._probe(cutoff, skin, rmax, box, n)
        widths = frac_cell.perpendicular_widths if frac_cell is not None else np.ones(3)
        lo = np.where(pbc_u, 0.0, lo_s)
        span = np.where(pbc_u, 1.0, hi_s - lo_s)
        slack = 64 * np.finfo(np.float64).eps * (mag + 1.0)
        halo = reach / widths * (1.0 + _HALO_SLACK) + slack
        splittable = [bool(pbc_u[c] or span[c] > 0) for c in range(3)]
        if domains is None:
            want = max(self.n_workers, -(-n // per))
            norm = np.where(span > 0, halo / np.where(span > 0, span, 1.0), np.inf)
            grid = _choose_grid(min(want, max(1, n)), norm, splittable)
        elif isinstance(domains, (int, np.integer)) and not isinstance(domains, bool):
            if domains < 1:
                raise ValueError(f"domains must be a positive int or three positive ints, "
                                 f"got {domains!r}")
            norm = np.where(span > 0, halo / np.where(span > 0, span, 1.0), np.inf)
            grid = _choose_grid(int(domains), norm, splittable)
        else:
            if n < 2:
                # no pair to find on any grid: honour the one given; an axis
                # without extent gets a nominal one (every particle in its
                # first domain, the others empty)
                span = np.where(span > 0, span, 1.0)
                splittable = [True] * 3
            grid = _as_grid(domains, splittable)
        self.grid = grid
        self.plan = _Plan(kind="cutoff" if cutoff is not None else "contacts",
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
            dd, _ = _dataframe()
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
            meta = _route_frame(self.plan, np.empty((0, 3)),
                                None if rad is None else np.empty(0),
                                None if lab is None else np.empty(0, np.int64), 0)
            routed = frame.map_partitions(_route_partition, self.plan, meta=meta)
            self._routed = routed.set_index("dom", divisions=list(range(nd + 1)),
                                            shuffle_method=self._shuffle)
            self._bounds = np.unique(offsets)
        else:
            pieces = [_route(self.plan, positions[a:a + _ROUTE_BLOCK],
                             None if rad is None else rad[a:a + _ROUTE_BLOCK],
                             None if lab is None else lab[a:a + _ROUTE_BLOCK], a)
                      for a in range(0, max(n, 1), _ROUTE_BLOCK)]
            inputs = [_concat_pieces(*[p[d] for p in pieces])
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
            _, pd = _dataframe()
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
        dd, pd = _dataframe()
        meta = pd.DataFrame({"i": np.empty(0, np.int64), "j": np.empty(0, np.int64),
                             "distance": np.empty(0, np.float64)})
        if self._routed is not None:
            return self._routed.map_partitions(_domain_pairs_part, self.plan, meta=meta)
        return dd.from_delayed(self._per_domain(_domain_pairs), meta=meta, verify_meta=False)

    def count_pairs(self):
        """Total number of pairs (contacts), a lazy 0-d int64 dask.array."""
        if self._routed is not None:
            _, pd = _dataframe()
            counts = self._routed.map_partitions(_part_count, self.plan,
                                                 meta=pd.Series(np.empty(0, np.int64)))
            return counts.to_dask_array(lengths=[1] * self.n_domains).sum()
        parts = [da.from_delayed(p, shape=(), dtype=np.int64)
                 for p in self._per_domain(_domain_count)]
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
            _, pd = _dataframe()
            meta = pd.DataFrame({"gid": np.empty(0, np.int64), "cn": np.empty(0, np.int64)})
            owned = self._routed.map_partitions(_domain_coordination_part, self.plan,
                                                meta=meta)
            # domains -> chunks in input order, in one shuffle
            by_chunk = owned.set_index("gid", divisions=[int(v) for v in bounds],
                                       shuffle_method=self._shuffle)
            values = by_chunk.map_partitions(_check_block, bounds,
                                             meta=pd.Series(np.empty(0, np.int64), name="cn"))
            return values.to_dask_array(lengths=[int(v) for v in np.diff(bounds)])
        nc = len(bounds) - 1
        parts = [delayed(_domain_coordination_split, nout=nc, pure=True)(self.plan, inp,
                                                                          bounds)
                 for inp in self._inputs]
        blocks = []
        for c in range(nc):
            lo, hi = int(bounds[c]), int(bounds[c + 1])
            task = delayed(_assemble, pure=True)(lo, hi, *[p[c] for p in parts])
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
        edges = _edges(bins, self.reach)
        nb = len(edges) - 1
        if self._routed is not None:
            _, pd = _dataframe()
            counts = self._routed.map_partitions(_part_histogram, self.plan, edges,
                                                 meta=pd.Series(np.empty(0, np.int64)))
            arr = counts.to_dask_array(lengths=[nb] * self.n_domains)
            return arr.reshape(self.n_domains, nb).sum(axis=0), edges
        parts = [da.from_delayed(p, shape=(nb,), dtype=np.int64)
                 for p in self._per_domain(_domain_histogram, edges)]
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
        return _write_pairs(self, path, overwrite=overwrite)


def _edges(bins, reach):
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


# --------------------------------------------------------------- Parquet output
def _remove(path):
    if os.path.isdir(path) and not os.path.islink(path):
        shutil.rmtree(path)
    elif os.path.lexists(path):
        os.remove(path)


def _write_pairs(search, path, *, overwrite=False):
    # no trailing separator: PATH.partial and PATH.replaced are siblings of PATH
    path = os.path.normpath(os.fspath(path))
    if os.path.exists(path) and not overwrite:
        raise FileExistsError(f"{path} already exists; remove it or pass overwrite=True")
    if os.path.isdir(path) and os.listdir(path) and \
            not os.path.exists(os.path.join(path, _MARKER)):
        raise FileExistsError(f"{path} is a directory that is not a granularsap pairs dataset "
                              f"(no {_MARKER}); overwrite replaces only a pairs dataset, a "
                              "file or an empty directory")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise FileNotFoundError(f"output directory {parent} does not exist")
    partial = path + ".partial"
    replaced = path + ".replaced"  # an old dataset moved aside, being deleted
    _remove(partial)
    _remove(replaced)
    df = search.pairs()
    nd = search.n_domains
    width = max(5, len(str(nd - 1)))
    kwargs = {"write_index": False, "write_metadata_file": True,
              "name_function": lambda k: f"domain-{k:0{width}d}.parquet"}
    if search.client is not None:
        kwargs["compute_kwargs"] = {"scheduler": search.client}
    df.to_parquet(partial, **kwargs)
    import pyarrow.parquet as pq

    rows = int(pq.read_metadata(os.path.join(partial, "_metadata")).num_rows)
    marker = {"schema": PAIRS_SCHEMA, "complete": True, "n_pairs": rows,
              "n_particles": search.n, "domains": nd, "grid": list(search.grid),
              "columns": {"i": "int64", "j": "int64", "distance": "float64"},
              "mode": search.plan.kind, "cutoff": search.plan.cutoff if
              search.plan.kind == "cutoff" else None, "skin": search.plan.skin,
              "range": search.reach}
    with open(os.path.join(partial, _MARKER), "w") as fh:
        json.dump(marker, fh, indent=1)
        fh.flush()
        os.fsync(fh.fileno())
    if os.path.lexists(path):
        # moved aside in one rename, so PATH never holds a half-deleted dataset
        os.replace(path, replaced)
    os.replace(partial, path)
    _remove(replaced)
    return marker


def read_pairs(path):
    """Open a pairs dataset written by :func:`write_pairs`, refusing an incomplete one.

    A plain ``pandas.read_parquet(path)`` or ``dask.dataframe.read_parquet(path)``
    reads it too; this checks the completion marker first.

    Returns
    -------
    dask.dataframe.DataFrame
        One partition per domain file.
    """
    dd, _ = _dataframe()
    path = os.fspath(path)
    marker = os.path.join(path, _MARKER)
    if not os.path.exists(marker):
        raise ValueError(f"{path} is not a complete granularsap pairs dataset (no {_MARKER}); "
                         "an interrupted write leaves only PATH.partial")
    try:
        with open(marker) as fh:
            meta = json.load(fh)
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: the marker {_MARKER} is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: the marker {_MARKER} is not a JSON object")
    if meta.get("schema") != PAIRS_SCHEMA or not meta.get("complete"):
        raise ValueError(f"{path}: unknown or incomplete pairs dataset {meta.get('schema')!r}")
    files = sorted(f for f in os.listdir(path) if f.endswith(".parquet") and f[0] not in "._")
    nd = meta.get("domains")
    if isinstance(nd, int) and not isinstance(nd, bool):
        width = max(5, len(str(nd - 1)))
        want = [f"domain-{k:0{width}d}.parquet" for k in range(nd)]
        missing = sorted(set(want) - set(files))
        if missing:
            raise ValueError(f"{path} is incomplete: its marker names {nd} domain files and "
                             f"{len(missing)} are missing ({', '.join(missing[:3])}"
                             f"{', ...' if len(missing) > 3 else ''})")
        files = want
    _, pd = _dataframe()
    meta = pd.DataFrame({"i": np.empty(0, np.int64), "j": np.empty(0, np.int64),
                         "distance": np.empty(0, np.float64)})
    return dd.from_map(_read_part, [os.path.join(path, f) for f in files], meta=meta,
                       enforce_metadata=False)


def _read_part(path):
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pandas()


# ------------------------------------------------------------ conveniences
def neighbor_pairs(positions, cutoff, *, cell=None, pbc=None, domains=None, client=None,
                   n_threads=None):
    """Pairs with ``d <= cutoff`` of one frame as a lazy Dask DataFrame.

    The distributed twin of :func:`granularsap.neighbor_pairs`: columns ``i``,
    ``j`` (int64, ``i < j``), ``distance`` (float64), one partition per
    spatial domain, each pair once.  Arguments as for :class:`DomainSearch`.

    Examples
    --------
    >>> import numpy as np, granularsap, granularsap.dask
    >>> x = np.random.default_rng(1).uniform(0, 8, (500, 3))
    >>> df = granularsap.dask.neighbor_pairs(x, 1.2, cell=[8, 8, 8, 90, 90, 90], domains=3)
    >>> pairs, d = granularsap.neighbor_pairs(x, 1.2, box=[8, 8, 8, 90, 90, 90])
    >>> len(df.compute()) == len(pairs)
    True
    """
    return DomainSearch(positions, cutoff=cutoff, cell=cell, pbc=pbc, domains=domains,
                        client=client, n_threads=n_threads).pairs()


def sphere_contacts(positions, radii, *, skin=0.0, cell=None, pbc=None, clump_ids=None,
                    domains=None, client=None, n_threads=None):
    """Sphere contacts ``d <= r_i + r_j + skin`` of one frame as a lazy Dask DataFrame.

    The distributed twin of :func:`granularsap.sphere_contacts` (with
    ``return_distances=True``); columns ``i``, ``j``, ``distance``.
    """
    return DomainSearch(positions, radii=radii, skin=skin, clump_ids=clump_ids, cell=cell,
                        pbc=pbc, domains=domains, client=client, n_threads=n_threads).pairs()


def coordination_numbers(positions, cutoff=None, *, radii=None, skin=0.0, cell=None, pbc=None,
                         domains=None, client=None, n_threads=None):
    """Pairs per particle (neighbours within ``cutoff``, or contacts with ``radii``).

    Returns an ``(n,)`` int64 dask.array aligned with ``positions``; no pair
    list is gathered anywhere.
    """
    return DomainSearch(positions, cutoff=cutoff, radii=radii, skin=skin, cell=cell, pbc=pbc,
                        domains=domains, client=client,
                        n_threads=n_threads).coordination_numbers()


def count_pairs(positions, cutoff=None, *, radii=None, skin=0.0, cell=None, pbc=None,
                domains=None, client=None, n_threads=None):
    """Number of pairs (or contacts) of one frame, a lazy 0-d dask.array."""
    return DomainSearch(positions, cutoff=cutoff, radii=radii, skin=skin, cell=cell, pbc=pbc,
                        domains=domains, client=client, n_threads=n_threads).count_pairs()


def distance_histogram(positions, cutoff=None, *, bins=100, radii=None, skin=0.0, cell=None,
                       pbc=None, domains=None, client=None, n_threads=None):
    """Pair-distance histogram ``(counts dask.array, edges)``; see
    :meth:`DomainSearch.distance_histogram`."""
    return DomainSearch(positions, cutoff=cutoff, radii=radii, skin=skin, cell=cell, pbc=pbc,
                        domains=domains, client=client,
                        n_threads=n_threads).distance_histogram(bins)


def radial_distribution(positions, cutoff, *, bins=100, cell, pbc=None, domains=None,
                        client=None, n_threads=None):
    """g(r) up to ``cutoff`` of a periodic frame ``(g dask.array, edges)``; see
    :meth:`DomainSearch.radial_distribution`."""
    return DomainSearch(positions, cutoff=cutoff, cell=cell, pbc=pbc, domains=domains,
                        client=client, n_threads=n_threads).radial_distribution(bins)


def write_pairs(path, positions, cutoff=None, *, radii=None, skin=0.0, cell=None, pbc=None,
                domains=None, client=None, n_threads=None, overwrite=False):
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
    search = DomainSearch(positions, cutoff=cutoff, radii=radii, skin=skin, cell=cell,
                          pbc=pbc, domains=domains, client=client, n_threads=n_threads)
    return search.write_pairs(path, overwrite=overwrite)
