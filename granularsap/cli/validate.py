"""Compare granularsap's pairs with LAMMPS's and MDAnalysis's, frame by frame.

For every frame of TRAJ, granularsap finds the pairs within --cutoff (or the
sphere contacts d <= r_i + r_j + skin, radii from --radius-column) and each
reference in --against does the same.  lammps: LAMMPS's own neighbour list
through lammps_bridge (pair_style zero for a cutoff, a granular size list for
radii), every candidate re-tested with d <= reach in float64 (README.md, "LAMMPS"
says what LAMMPS counts).  mdanalysis: MDAnalysis.lib.distances.
self_capped_distance, float32 inside; for radii its pairs within
2 max(r) + skin, filtered with its own distances.

A table gives, per frame, the pairs found by each and the differences (+a/-b:
a pairs only granularsap has, b only the reference has).  A differing pair
whose float64 distance lies within the reference's rounding of the cutoff is a
tie and is counted in its own column; every differing pair is listed below the
table with its distance and whether it is a tie.

Exit codes: 0 every frame identical; 1 some pair differs beyond rounding;
3 the only differences are ties at the cutoff (0 with --allow-ties);
2 bad usage or input.
"""

from __future__ import annotations

import argparse

from ..compare import DEFAULT_CUTOFF, REFERENCES
from . import argtypes

__all__ = ["add_arguments", "run"]


def _against(text):
    names = [t.strip().lower() for t in text.split(",") if t.strip()]
    bad = [t for t in names if t not in REFERENCES]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"unknown reference {', '.join(map(repr, bad)) or repr(text)}; choose from "
            f"{', '.join(REFERENCES)}")
    return list(dict.fromkeys(names))


def add_arguments(parser):
    parser.add_argument("trajectory", metavar="TRAJ",
                        help="LAMMPS text dump, or any file ASE or MDAnalysis reads")
    parser.add_argument("--against", type=_against, default=list(REFERENCES),
                        metavar="REF[,REF]",
                        help="references to compare with: lammps, mdanalysis (default both)")
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--cutoff", type=argtypes.nonneg, metavar="C",
                      help="neighbour pairs with d <= C (default: sphere contacts from the "
                           f"file's radius column, else C = {DEFAULT_CUTOFF:g})")
    what.add_argument("--radius-column", metavar="NAME",
                      help="sphere contacts d <= r_i + r_j + skin, radii from this column "
                           "(default when the file has a radius column)")
    parser.add_argument("--skin", type=argtypes.nonneg, default=0.0, metavar="S",
                        help="skin added to r_i + r_j (with radii; default 0)")
    parser.add_argument("--frames", type=argtypes.frames, default=None, metavar="START:STOP:STEP",
                        help="frames to check (default all)")
    parser.add_argument("--format", default=None, help="trajectory format (see iter_frames)")
    parser.add_argument("--open", type=argtypes.axes, default=(), metavar="AXES",
                        help="compare these axes (x, y, z letters) as open whatever the file's "
                             "boundaries: z for a LAMMPS 2-D run")
    parser.add_argument("--allow-ties", action="store_true",
                        help="exit 0 (instead of 3) when the only differences are ties at the "
                             "cutoff")
    parser.add_argument("--show", type=int, default=10, metavar="N",
                        help="differing pairs listed per frame and reference (default 10)")


def run(args) -> int:
    from ..compare import compare_trajectory
    from ..warmup import compile_notice

    with compile_notice():  # one line on stderr if kernels compile (a cold cache)
        total = compare_trajectory(args.trajectory, against=args.against, cutoff=args.cutoff,
                                   radius_column=args.radius_column, skin=args.skin,
                                   frames=args.frames, format=args.format, show=args.show,
                                   open_axes=args.open)
    if total["diff"]:
        return 1
    if total["ties"] and not args.allow_ties:
        return 3
    return 0
