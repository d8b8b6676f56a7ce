"""Compare granularsap's pairs with LAMMPS's and MDAnalysis's, frame by frame.

What ``granularsap validate`` runs (its command line is
:mod:`granularsap.cli.validate`): :func:`compare_trajectory` finds, for every
frame, the pairs within a cutoff (or the sphere contacts d <= r_i + r_j + skin)
with granularsap and with each reference.  lammps: LAMMPS's own neighbour list
through lammps_bridge (pair_style zero for a cutoff, a granular size list for
radii), every candidate re-tested with d <= reach in float64 (README.md,
"LAMMPS" says what LAMMPS counts).  mdanalysis: MDAnalysis.lib.distances.
self_capped_distance, float32 inside; for radii its pairs within
2 max(r) + skin, filtered with its own distances; a partly periodic frame
goes to it in a fully periodic stand-in cell (:func:`periodic_stand_in`).  A differing pair whose
float64 distance lies within the reference's rounding of the cutoff is a tie.
"""

from __future__ import annotations

import sys
import time

__all__ = ["DEFAULT_CUTOFF", "REFERENCES", "compare_trajectory"]

#: references this comparison knows
REFERENCES = ("lammps", "mdanalysis")
#: the cutoff of a trajectory without radii when none is given: the usual
#: Lennard-Jones cutoff, 2.5 sigma (``pair_style lj/cut 2.5``, as in data/lj.in)
DEFAULT_CUTOFF = 2.5


# --------------------------------------------------------------------------- helpers

def _keys(pairs, n):
    import numpy as np

    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    a = np.minimum(pairs[:, 0], pairs[:, 1])
    b = np.maximum(pairs[:, 0], pairs[:, 1])
    return np.unique(a * n + b)


def _pair_distances(positions, cell, pbc, keys, n):
    """Float64 minimum-image distances of the pairs encoded in ``keys`` (images
    along the periodic axes of ``pbc`` only)."""
    import numpy as np

    i, j = keys // n, keys % n
    d = positions[j] - positions[i]
    if cell is None or len(keys) == 0:
        return np.sqrt((d * d).sum(axis=1))
    inv = np.linalg.inv(cell)
    f = d @ inv
    periodic = np.asarray(pbc, dtype=bool)
    f[:, periodic] -= np.rint(f[:, periodic])
    steps = [(-1, 0, 1) if periodic[k] else (0,) for k in range(3)]
    shifts = np.array([[a, b, c] for a in steps[0] for b in steps[1] for c in steps[2]],
                      dtype=np.float64)
    best = np.full(len(keys), np.inf)
    for s in shifts:
        v = (f + s) @ cell
        best = np.minimum(best, (v * v).sum(axis=1))
    return np.sqrt(best)


class _Setup:
    """What every frame is asked: cutoff or radii, and each backend's call."""

    def __init__(self, cutoff, radius_column, skin, first_frame):
        self.cutoff = cutoff
        self.radius_column = radius_column
        self.skin = skin
        self.defaulted = False
        if self.cutoff is None and self.radius_column is None:
            if first_frame.radius is not None or "radius" in first_frame.columns:
                self.radius_column = "radius"
            else:
                self.cutoff, self.defaulted = DEFAULT_CUTOFF, True

    def describe(self):
        if self.cutoff is not None:
            why = (f" (no radius column and no --cutoff: the default {DEFAULT_CUTOFF:g}, "
                   "Lennard-Jones's usual 2.5 sigma)" if self.defaulted else "")
            return f"neighbour pairs d <= {self.cutoff:g}{why}"
        return f"sphere contacts d <= r_i + r_j + {self.skin:g} (radii: {self.radius_column})"

    def radii(self, frame):
        import numpy as np

        try:
            return np.ascontiguousarray(frame.column(self.radius_column), dtype=np.float64)
        except KeyError as exc:
            raise ValueError(str(exc.args[0])) from None

    def reach(self, radii, keys, n):
        if self.cutoff is not None:
            return self.cutoff
        return radii[keys // n] + radii[keys % n] + self.skin


def _geometry(frame, open_axes=()):
    """(positions, cell or None, pbc) in the form granularsap takes: no cell for
    a frame open along every axis; ``open_axes`` open whatever the frame says."""
    import numpy as np

    pos = np.ascontiguousarray(frame.positions, dtype=np.float64)
    pbc = tuple(bool(f) and c not in open_axes for c, f in enumerate(frame.pbc))
    if frame.cell is None or not any(pbc):
        return pos, None, (False, False, False)
    return pos, np.asarray(frame.cell, dtype=np.float64), pbc


def _run_granularsap(setup, pos, cell, pbc, radii):
    import granularsap

    if setup.cutoff is not None:
        return granularsap.neighbor_pairs(pos, setup.cutoff, box=cell, pbc=pbc,
                                          return_distances=False)
    return granularsap.sphere_contacts(pos, radii, skin=setup.skin, box=cell, pbc=pbc)


def _run_lammps(setup, pos, cell, pbc, radii):
    import lammps_bridge

    if setup.cutoff is not None:
        return lammps_bridge.neighbor_pairs(pos, setup.cutoff, cell, pbc=pbc)
    return lammps_bridge.sphere_contacts(pos, radii, skin=setup.skin, box=cell, pbc=pbc)


def periodic_stand_in(positions, cell, pbc, reach):
    """A fully periodic cell with the same pairs within ``reach`` as the partly
    periodic ``(cell, pbc)``, for a reference that has no open axes (MDAnalysis).

    The periodic cell vectors are kept; each open one is replaced by a vector
    normal to the periodic ones (and to the other open one,
    :func:`granularsap.cell.open_directions`, as LAMMPS's box gets) of length
    ``L = 2 (e + reach)`` (a millionth more), ``e`` the particles' extent along
    it.  Two particles are at most ``e`` apart along that normal, so every image across it is
    farther than ``L - e > reach``: the pairs within ``reach`` are those with
    images along the periodic axes only, as in ``(cell, pbc)``.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.array([[0.5, 0.5, 0.0], [0.5, 0.5, 9.0]])
    >>> periodic_stand_in(x, 10.0 * np.eye(3), (True, True, False), 1.0).round(4).tolist()
    [[10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, 20.0]]
    """
    import numpy as np

    from .cell import open_directions

    cell = np.array(cell, dtype=np.float64)
    periodic = [k for k in range(3) if pbc[k]]
    opened = [k for k in range(3) if not pbc[k]]
    for normal, k in zip(open_directions(cell[periodic]), opened, strict=True):
        along = positions @ normal
        extent = float(along.max() - along.min()) if len(positions) else 0.0
        # (a hair more: MDAnalysis checks reach <= L / 2 in float32, where 2 reach
        # may round below it; particles all in one plane, a LAMMPS 2-D run, give L = 2 reach)
        length = 2.0 * (extent + reach) * (1.0 + 1e-6)
        cell[k] = normal * (length if length > 0.0 else 1.0)
    if np.linalg.det(cell) < 0.0:
        cell[opened[-1]] *= -1.0
    return cell


def _run_mdanalysis(setup, pos, cell, pbc, radii):
    import numpy as np

    try:
        from MDAnalysis.lib.distances import self_capped_distance
    except ImportError as exc:
        raise ImportError("the mdanalysis reference needs MDAnalysis: "
                          "pip install granularsap[mda]") from exc
    reach_max = setup.cutoff
    if reach_max is None:
        reach_max = 2.0 * float(radii.max()) + setup.skin if len(radii) else 0.0
    box = None
    if cell is not None:
        from .io import box_to_cell, cell_to_box

        if not all(pbc):  # MDAnalysis has no partly periodic box
            cell = periodic_stand_in(pos, cell, pbc, reach_max)
        box = cell_to_box(cell)
        std = box_to_cell(box)  # MDAnalysis's own orientation of that cell
        pos = pos @ np.linalg.solve(cell, std)
    if setup.cutoff is not None:
        pairs = self_capped_distance(pos, max_cutoff=setup.cutoff, box=box,
                                     return_distances=False)
        return np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    pairs, dist = self_capped_distance(pos, max_cutoff=reach_max, box=box)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    keep = dist <= radii[pairs[:, 0]] + radii[pairs[:, 1]] + setup.skin
    return pairs[keep]


_RUNNERS = {"lammps": _run_lammps, "mdanalysis": _run_mdanalysis}


def _tie_tolerance(ref, pos, cell, reach_scale):
    """Absolute band around the cutoff within which a difference is a rounding tie."""
    import numpy as np

    scale = float(np.abs(pos).max()) if len(pos) else 0.0
    if cell is not None:
        scale += float(np.abs(cell).max())
    scale = max(scale, reach_scale)
    # MDAnalysis rounds coordinates and box to float32; LAMMPS and granularsap stay float64
    eps = float(np.finfo(np.float32).eps) if ref == "mdanalysis" else float(np.finfo(float).eps)
    return 4.0 * eps * scale


# --------------------------------------------------------------------------- the comparison

def compare_trajectory(trajectory, *, against=REFERENCES, cutoff=None, radius_column=None,
                       skin=0.0, frames=None, format=None, show=10, out=None,
                       name="granularsap validate", open_axes=()):
    """Compare granularsap's pairs with each reference of ``against``, frame by frame.

    Prints a header line, one table row per frame, every differing pair (at most
    ``show`` per frame and reference, with its float64 distance and whether it is
    a tie at the cutoff) and a verdict to ``out`` (default ``sys.stdout``), each
    line of the command's own starting with ``name``.

    Parameters
    ----------
    trajectory : str or path
        Anything :func:`granularsap.io.iter_frames` reads.
    against : sequence of {"lammps", "mdanalysis"}
    cutoff : float, optional
        Neighbour pairs with d <= cutoff; without it (and without
        ``radius_column``) sphere contacts from the file's radius column, else
        ``cutoff = DEFAULT_CUTOFF``.
    radius_column : str, optional
        Sphere contacts d <= r_i + r_j + skin, radii from this column.
    skin : float
    frames : slice, optional
    format : str, optional
        As :func:`granularsap.io.iter_frames` takes it.
    show : int
        Differing pairs listed per frame and reference.
    open_axes : sequence of int
        Axes (0, 1, 2) compared as open whatever the file's boundaries say (a
        LAMMPS 2-D run's z), by every code.

    Returns
    -------
    dict
        ``frames`` compared, ``diff`` (differing pairs beyond rounding) and
        ``ties`` (differing pairs within the reference's rounding of the cutoff).

    Raises
    ------
    ValueError
        ``frames`` selects no frame, the radius column is missing.
    """
    import numpy as np

    from .cell import as_open_axes
    from .io import iter_frames
    from .io.pipeline import FrameError

    open_axes = as_open_axes(open_axes)
    stream = out if out is not None else sys.stdout

    def say(line):
        print(line, file=stream)

    frames_iter = iter_frames(trajectory, format=format, frames=frames)
    refs = list(against)
    setup = None
    header_done = False
    total = {"frames": 0, "diff": 0, "ties": 0}
    details = []
    for frame in frames_iter:
        if setup is None:
            setup = _Setup(cutoff, radius_column, skin, frame)
            say(f"{name}: {trajectory}: {setup.describe()}; against {', '.join(refs)}")
        pos, cell, pbc = _geometry(frame, open_axes)
        n = len(pos)
        radii = setup.radii(frame) if setup.cutoff is None else None
        t0 = time.perf_counter()
        try:
            mine = _keys(_run_granularsap(setup, pos, cell, pbc, radii), max(n, 1))
        except ValueError as exc:  # named by file, frame and particle id
            raise FrameError.of(frame, exc) from None
        times = {"granularsap": time.perf_counter() - t0}
        row = [f"{frame.index:>5}", f"{frame.step if frame.step is not None else '-':>8}",
               f"{n:>6}", f"{len(mine):>11}"]
        frame_ties = 0
        for ref in refs:
            t0 = time.perf_counter()
            theirs = _keys(_RUNNERS[ref](setup, pos, cell, pbc, radii), max(n, 1))
            times[ref] = time.perf_counter() - t0
            only_mine = np.setdiff1d(mine, theirs, assume_unique=True)
            only_theirs = np.setdiff1d(theirs, mine, assume_unique=True)
            diff = np.concatenate([only_mine, only_theirs])
            n_ties = 0
            if len(diff):
                d = _pair_distances(pos, cell, pbc, diff, max(n, 1))
                reach = setup.reach(radii, diff, max(n, 1))
                reach_arr = np.broadcast_to(np.asarray(reach, dtype=float), d.shape)
                tol = _tie_tolerance(ref, pos, cell, float(reach_arr.max()))
                tie = np.abs(d - reach_arr) <= tol
                n_ties = int(tie.sum())
                for k in range(min(len(diff), show)):
                    who = "granularsap only" if k < len(only_mine) else f"{ref} only"
                    kind = (f"tie: |d - reach| = {abs(d[k] - reach_arr[k]):.3g} <= "
                            f"{tol:.3g}" if tie[k] else "NOT a tie")
                    details.append(f"  frame {frame.index}: pair ({diff[k] // n}, "
                                   f"{diff[k] % n}) {who}: d = {float(d[k])!r}, reach = "
                                   f"{float(reach_arr[k])!r} ({kind})")
                if len(diff) > show:
                    details.append(f"  frame {frame.index}: ... {len(diff) - show} more "
                                   f"differences against {ref}")
            frame_ties += n_ties
            total["diff"] += len(diff) - n_ties
            total["ties"] += n_ties
            row += [f"{len(theirs):>11}", f"{f'+{len(only_mine)}/-{len(only_theirs)}':>9}"]
        row += [f"{frame_ties:>5}"]
        row += [f"{1e3 * times[k]:>8.1f}" for k in ["granularsap", *refs]]
        if not header_done:
            head = ["frame", "step", "n", "granularsap"]
            for ref in refs:
                head += [ref, f"diff:{ref[:3]}"]
            head += ["ties"] + [f"ms:{k[:5]}" for k in ["granularsap", *refs]]
            widths = [5, 8, 6, 11] + [11, 9] * len(refs) + [5] + [8] * (len(refs) + 1)
            say(" ".join(f"{h:>{w}}" for h, w in zip(head, widths, strict=True)))
            header_done = True
        say(" ".join(row))
        stream.flush()
        total["frames"] += 1
    if setup is None:
        raise ValueError(f"--frames selects no frame of {trajectory}")
    for line in details:
        say(line)
    verdict = ("identical" if total["diff"] == 0 and total["ties"] == 0 else
               f"{total['diff']} differing pair(s) beyond rounding, {total['ties']} tie(s) "
               "at the cutoff")
    say(f"{name}: {total['frames']} frame(s): {verdict}")
    return total
