"""``granularsap bench mda-capped``: the MDAnalysis drop-in against MDAnalysis itself.

``MDAnalysis.lib.distances.capped_distance(x, x, cutoff, box=box)`` (the call
an RDF of a group with itself makes) against ``granularsap.mda.capped_distance``
with the same arguments, at cutoffs 1.5, 5 and 8, on two frames:

* ``data/lj.dump``: the first frame, 2,048 atoms in a triclinic cell of about
  13.4 x 13.9 x 13.8 (a cutoff of 8 is beyond half the cell: many pairs have
  two images in range, and MDAnalysis answers with its brute-force method);
* a generated triclinic frame of 100,000 atoms (``--sizes`` changes it) at
  number density 0.05 (a dilute fluid: at cutoff 8 each atom has about 110
  neighbours, 1.1e7 pairs in all, where a liquid's 3.6e8 would need several
  GB in each library).

Both run in this process, each warmed up once, then timed ``--repeats``
times (default 5); the minimum is reported.  The pair sets must be equal (the
drop-in reproduces MDAnalysis's float32 arithmetic at the cutoff); a
difference is reported and makes the exit code 1.
"""

from __future__ import annotations

import json
import os
import time

import numpy as np

CUTOFFS = (1.5, 5.0, 8.0)
#: atoms of the generated frame and its number density
N_ATOMS = 100_000
DENSITY = 0.05
#: angles of the generated triclinic cell (degrees)
ANGLES = (80.0, 95.0, 70.0)


def lj_frame(path):
    """``(label, positions float32 (n, 3), box (6,))`` of the first frame of ``path``."""
    from ..io import cell_to_box, iter_frames

    frame = next(iter_frames(path))
    box = np.asarray(cell_to_box(frame.cell), dtype=np.float32)
    return (f"{os.path.basename(path)} ({frame.n_particles} atoms)",
            frame.positions.astype(np.float32), box)


def triclinic_frame(n, *, seed=0, density=DENSITY):
    """A uniform random frame of ``n`` atoms in a triclinic cell at ``density``."""
    from MDAnalysis.lib.mdamath import triclinic_vectors

    unit = triclinic_vectors(np.array([1.0, 1.0, 1.0, *ANGLES], dtype=np.float32))
    scale = (n / density / abs(np.linalg.det(unit.astype(np.float64)))) ** (1.0 / 3.0)
    box = np.array([scale, scale, scale, *ANGLES], dtype=np.float32)
    cell = triclinic_vectors(box).astype(np.float64)
    frac = np.random.default_rng(seed).uniform(0.0, 1.0, (n, 3))
    return (f"triclinic {n} atoms (density {density:g})", (frac @ cell).astype(np.float32),
            box)


def _best(call, repeats):
    out = call()  # warm-up (compilation, caches)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = call()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _same_pairs(a, b):
    if len(a) != len(b):
        return False
    ka = np.sort(a[:, 0] * (int(a.max(initial=0)) + 1) + a[:, 1])
    kb = np.sort(b[:, 0] * (int(a.max(initial=0)) + 1) + b[:, 1])
    return bool(np.array_equal(ka, kb))


def compare(label, x, box, cutoffs, repeats, n_threads=None):
    """Rows ``{frame, cutoff, pairs, mdanalysis_s, granularsap_s, same}``."""
    from MDAnalysis.lib import distances

    from .. import mda

    rows = []
    for cutoff in cutoffs:
        t_m, (p_m, _) = _best(lambda c=cutoff: distances.capped_distance(x, x, c, box=box),
                              repeats)
        t_g, (p_g, _) = _best(lambda c=cutoff: mda.capped_distance(x, x, c, box=box,
                                                                  n_threads=n_threads),
                              repeats)
        rows.append({"frame": label, "cutoff": cutoff, "pairs": int(len(p_m)),
                     "mdanalysis_s": t_m, "granularsap_s": t_g,
                     "same": _same_pairs(p_m, p_g), "granularsap_pairs": int(len(p_g))})
        del p_m, p_g
    return rows


def run_mda_capped(args):
    """Entry point of ``granularsap bench mda-capped``; returns an exit code."""
    try:
        import MDAnalysis  # noqa: F401
    except ImportError:
        print("granularsap bench mda-capped: MDAnalysis is not installed", flush=True)
        return 1
    repeats = getattr(args, "repeats", None) or (3 if getattr(args, "quick", False) else 5)
    sizes = getattr(args, "sizes", None)
    n = int(float(str(sizes[0]).replace("_", ""))) if sizes else (
        10_000 if getattr(args, "quick", False) else N_ATOMS)
    data_dir = getattr(args, "data_dir", None) or "data"
    threads = getattr(args, "threads", None)
    frames = []
    lj = os.path.join(data_dir, "lj.dump")
    if os.path.exists(lj):
        frames.append(lj_frame(lj))
    else:
        print(f"{lj} not found: that frame is skipped", flush=True)
    frames.append(triclinic_frame(n, seed=getattr(args, "seed", 0) or 0))
    print(f"granularsap bench mda-capped: capped_distance(x, x, cutoff, box), cutoffs "
          f"{', '.join(f'{c:g}' for c in CUTOFFS)}, min of {repeats} runs", flush=True)
    print(f"{'frame':<38} {'cutoff':>6} {'pairs':>11} {'MDAnalysis':>11} {'granularsap':>12} "
          f"{'ratio':>6}  same pairs", flush=True)
    rows = []
    for label, x, box in frames:
        for row in compare(label, x, box, CUTOFFS, repeats, threads):
            rows.append(row)
            ratio = row["granularsap_s"] / row["mdanalysis_s"]
            print(f"{label:<38} {row['cutoff']:>6g} {row['pairs']:>11} "
                  f"{row['mdanalysis_s']:>10.4f}s {row['granularsap_s']:>11.4f}s "
                  f"{ratio:>6.2f}  {'yes' if row['same'] else 'NO'}", flush=True)
    json_path = getattr(args, "json", None)
    if json_path:
        with open(json_path, "w") as fh:
            json.dump({"workload": "mda-capped", "repeats": repeats, "rows": rows}, fh,
                      indent=1)
        print(f"wrote {json_path}", flush=True)
    return 0 if all(r["same"] for r in rows) else 1
