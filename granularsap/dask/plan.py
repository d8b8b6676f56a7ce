"""The domain plan: which domain owns each particle, which halos hold it, and the
grid of domains with the fewest halo copies."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..search import ContactSearch, NeighborSearch
from ..search.frame import WRAP_LIMIT, raise_unwrappable

#: Particles routed per block when the frame is a NumPy array in the client.
ROUTE_BLOCK = 1 << 20


#: Relative slack of the halo width beyond the interaction range.
HALO_SLACK = 1e-6


@dataclass(frozen=True)
class Plan:
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


def check_finite(pos, offset, name="positions"):
    ok = np.isfinite(pos).all(axis=1)
    if not ok.all():
        bad = int(np.flatnonzero(~ok)[0])
        raise ValueError(f"{name} must be finite, got NaN or inf in row {offset + bad}")


def raw_frac(frac_cell, pos):
    """Fractional coordinates (not wrapped), or the positions themselves."""
    if frac_cell is None:
        return np.array(pos, dtype=np.float64, copy=True)
    return frac_cell.fractional(pos)


def frac(plan, pos):
    u = raw_frac(plan.frac_cell, pos)
    for c in range(3):
        if plan.pbc[c]:
            u[:, c] -= np.floor(u[:, c])
    return u


def chunk_extent(pos, rad, offset, frac_cell):
    """Per chunk: min and max of u (unwrapped), max |u|, max radius; validates."""
    pos = np.asarray(pos, dtype=np.float64)
    check_finite(pos, offset)
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
    s = raw_frac(frac_cell, pos)
    if frac_cell is not None:
        # as the engine refuses it: a particle so far out along a periodic axis that
        # wrapping it keeps no significant digit (its limit and its message)
        far = np.abs(s[:, np.asarray(frac_cell.pbc, bool)]) >= WRAP_LIMIT
        if far.any():
            bad = int(np.flatnonzero(far.any(axis=1))[0])
            raise_unwrappable(pos, bad, "positions", row=offset + bad)
    rmax = float(rad.max()) if rad is not None and rad.size else 0.0
    return s.min(axis=0), s.max(axis=0), float(np.abs(s).max()), rmax


def axis_range(u, lo, span, k, h, periodic):
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


def route(plan, pos, rad, lab, offset):
    """Split one chunk of particles into its pieces for every domain.

    Returns a list with one ``(idx, positions, radii, labels, owned)`` per
    domain (global indices ascending; ``owned`` marks the particles the domain
    owns, the others are its halo)."""
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    check_finite(pos, offset)
    n = len(pos)
    k = plan.grid
    u = frac(plan, pos)
    own = []
    first = []
    count = []
    for c in range(3):
        o, a, cnt = axis_range(u[:, c], plan.lo[c], plan.span[c], k[c], plan.halo[c],
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


def concat_pieces(*pieces):
    """One domain's input from its pieces of every chunk (chunk order = index order)."""
    if len(pieces) == 1:
        return pieces[0]
    idx = np.concatenate([p[0] for p in pieces])
    pos = np.concatenate([p[1] for p in pieces]).reshape(-1, 3)
    rad = None if pieces[0][2] is None else np.concatenate([p[2] for p in pieces])
    lab = None if pieces[0][3] is None else np.concatenate([p[3] for p in pieces])
    owned = np.concatenate([p[4] for p in pieces])
    return idx, pos, rad, lab, owned


def route_frame(plan, pos, rad, lab, offset):
    """:func:`route` as one pandas DataFrame with a ``dom`` column (for a shuffle)."""
    import pandas as pd

    pieces = route(plan, pos, rad, lab, offset)
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


def unpack(inp):
    """A domain's input as ``(idx, positions, radii, labels, owned)``, idx ascending."""
    if isinstance(inp, tuple):
        return inp
    order = np.argsort(inp["idx"].to_numpy(), kind="stable")
    idx = inp["idx"].to_numpy()[order]
    pos = np.ascontiguousarray(inp[["x", "y", "z"]].to_numpy(dtype=np.float64)[order])
    rad = inp["r"].to_numpy()[order] if "r" in inp.columns else None
    lab = inp["label"].to_numpy()[order] if "label" in inp.columns else None
    return idx, pos, rad, lab, inp["owned"].to_numpy()[order]


def choose_grid(n_domains, halo_norm, splittable):
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


def as_grid(domains, splittable):
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
