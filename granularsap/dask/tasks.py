"""What one domain's task runs on a worker: the engine on the domain's particles,
then the pairs, counts, histograms or coordination numbers it owns."""

from __future__ import annotations

import numpy as np

from .plan import route_frame, unpack


def domain_search(plan, inp):
    """Pairs of one domain's subset: (local pairs, distances, idx, owned)."""
    idx, pos, rad, lab, owned = unpack(inp)
    search = plan.search()
    if plan.kind == "cutoff":
        pairs, dist = search.update(pos, plan.box)
    else:
        pairs, dist = search.update(pos, rad, plan.box, clump_ids=lab)
    return pairs, dist, idx, owned


def domain_pairs(plan, inp):
    """The pairs a domain owns as a pandas DataFrame (global indices)."""
    import pandas as pd

    pairs, dist, idx, owned = domain_search(plan, inp)
    keep = owned[pairs[:, 0]]  # idx ascending: local i < j is global i < j
    return pd.DataFrame({"i": idx[pairs[keep, 0]], "j": idx[pairs[keep, 1]],
                         "distance": np.array(dist[keep], dtype=np.float64)})


def domain_count(plan, inp):
    pairs, _, _, owned = domain_search(plan, inp)
    return np.int64(np.count_nonzero(owned[pairs[:, 0]]))


def domain_histogram(plan, inp, edges):
    pairs, dist, _, owned = domain_search(plan, inp)
    counts, _ = np.histogram(dist[owned[pairs[:, 0]]], bins=edges)
    return counts.astype(np.int64)


def domain_coordination(plan, inp):
    """Coordination numbers of the particles a domain owns: DataFrame gid, cn."""
    import pandas as pd

    pairs, _, idx, owned = domain_search(plan, inp)
    m = len(idx)
    cn = np.bincount(pairs[:, 0], minlength=m) + np.bincount(pairs[:, 1], minlength=m)
    return pd.DataFrame({"gid": idx[owned], "cn": cn[owned].astype(np.int64)})


def domain_coordination_split(plan, inp, bounds):
    """Coordination numbers of the owned particles, split by output chunk."""
    pairs, _, idx, owned = domain_search(plan, inp)
    m = len(idx)
    cn = np.bincount(pairs[:, 0], minlength=m) + np.bincount(pairs[:, 1], minlength=m)
    gid = idx[owned]
    cn = cn[owned].astype(np.int64)
    cut = np.searchsorted(gid, bounds)
    return tuple((gid[cut[c]:cut[c + 1]], cn[cut[c]:cut[c + 1]])
                 for c in range(len(bounds) - 1))


def assemble(lo, hi, *pieces):
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


def domain_pairs_part(part, plan):
    return domain_pairs(plan, part)


def domain_coordination_part(part, plan):
    return domain_coordination(plan, part)


def route_partition(part, plan):
    """Route one partition of the frame (index: global particle index)."""
    offset = int(part.index[0]) if len(part) else 0
    if len(part) and not np.array_equal(part.index.to_numpy(),
                                        np.arange(offset, offset + len(part))):
        raise RuntimeError("positions partition rows are not consecutive particles")
    pos = part[["x", "y", "z"]].to_numpy(dtype=np.float64)
    rad = part["r"].to_numpy() if "r" in part.columns else None
    lab = part["label"].to_numpy() if "label" in part.columns else None
    return route_frame(plan, pos, rad, lab, offset)


def part_count(part, plan):
    import pandas as pd

    return pd.Series([domain_count(plan, part)], dtype=np.int64)


def part_histogram(part, plan, edges):
    import pandas as pd

    return pd.Series(domain_histogram(plan, part, edges), dtype=np.int64)


def check_block(df, bounds, partition_info=None):
    """One output chunk (rows sorted by particle index): every particle exactly once."""
    k = partition_info["number"]
    lo, hi = int(bounds[k]), int(bounds[k + 1])
    gid = df.index.to_numpy()
    if len(gid) != hi - lo or not np.array_equal(gid, np.arange(lo, hi)):
        raise RuntimeError(f"particles {lo}..{hi - 1}: {len(gid)} coordination numbers "
                           f"instead of {hi - lo}; the decomposition is inconsistent")
    return df["cn"]
