"""Benchmark granularsap against the neighbour searches people use today.

Runs the same deterministic inputs through granularsap and every installed
peer (MDAnalysis nsgrid/pkdtree, scipy cKDTree, ASE, matscipy, vesin, freud
AABBQuery/LinkCell, LAMMPS's own neighbour list rebuilt every step and timed
by LAMMPS, LAMMPS ``run 0`` per trajectory frame, a plain numba cell list),
checks that all found the same pairs, and prints a table per workload: the
fresh call of stateful peers beside their steady state (median over repeated
runs or trajectory frames after a warm-up), peer/granularsap ratio,
candidates tested per pair found, peak memory, pairs and threads.  --json and
--plot write the full report and PNG plots.  Workload ``paper`` runs the
engine's own reproduction of the paper's experiments instead, and
``dem-loop`` a DEM time loop (search + contact history per step) against
LAMMPS's ``pair_style granular`` on the same pour.  The reference
is docs/bench.md.

examples:
  granularsap bench md-liquid granular-polydisperse --quick
  granularsap bench md-liquid --sizes 1e4 1e5 --peers granularsap,vesin,mda-nsgrid
  granularsap bench md-liquid --sizes 1e5 --peers lammps-rebuild,numba-celllist,vesin
  granularsap bench all --json bench.json --plot bench.png
  granularsap bench paper --quick
  granularsap bench dem-loop --sizes 2000 --steps 1000
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys

from ..bench.workloads import WORKLOAD_NAMES, WORKLOADS
from .argtypes import parse_size, split_list

__all__ = ["add_arguments", "run"]


def add_arguments(parser):
    parser.formatter_class = argparse.RawDescriptionHelpFormatter  # keep the examples' lines
    parser.add_argument("workloads", nargs="*", metavar="WORKLOAD",
                        help="one or more of: " + ", ".join(WORKLOAD_NAMES)
                        + ", all (every generated workload and data/)")
    parser.add_argument("--sizes", nargs="+", metavar="N",
                        help="particle/box counts (1e4, 2^18, 100k; space or comma separated); "
                        "default: each workload's own list")
    parser.add_argument("--repeats", type=int, default=None, metavar="R",
                        help="timed runs after the warm-up (default 5, 3 with --quick)")
    parser.add_argument("--peers", metavar="A,B,...",
                        help="peers to run (default: all); granularsap is always included")
    parser.add_argument("--exclude", metavar="A,B,...", help="peers not to run")
    parser.add_argument("--threads", type=int, default=None, metavar="T",
                        help="threads for the peers that have them (default: usable cores)")
    parser.add_argument("--quick", action="store_true",
                        help="small sizes, fewer repeats and frames (all workloads in minutes)")
    parser.add_argument("--json", metavar="PATH", help="write the full report as JSON")
    parser.add_argument("--plot", metavar="PATH", help="write PNG plots (time against N, "
                        "granularsap per phase)")
    parser.add_argument("--seed", type=int, default=0, help="workload seed (default 0)")
    parser.add_argument("--density", nargs="+", default=None, metavar="D",
                        help="paper-boxes densities (default 0.35)")
    parser.add_argument("--frames", type=int, default=None,
                        help="trajectory frames (default 50, 10 with --quick)")
    parser.add_argument("--max-seconds", type=float, default=120.0, metavar="S",
                        help="time budget per peer per workload; a peer whose warm-up takes "
                        "longer is timed once and left out at larger sizes, and so is one "
                        "whose warm-up extrapolated linearly in N would exceed 4 S "
                        "(default 120)")
    parser.add_argument("--data-dir", default="data",
                        help="directory of real trajectories for the 'data' workload")
    parser.add_argument("--cutoff", type=float, default=None,
                        help="cutoff for data/ files without radii (default 2.8)")
    parser.add_argument("--steps", type=int, default=None, metavar="S",
                        help="dem-loop: timed time steps (default 1000, 200 with --quick)")
    parser.add_argument("--settle", type=int, default=None, metavar="S",
                        help="dem-loop: untimed LAMMPS steps that settle the pour first "
                        "(default 10000, 2000 with --quick)")
    parser.add_argument("--list", action="store_true",
                        help="list workloads and peers (with availability) and exit")


def _out(text=""):
    print(text, flush=True)


def _err(text):
    print(text, file=sys.stderr, flush=True)


def _small_runs():
    from ..bench.harness import SMALL_RUNS

    return SMALL_RUNS


def _workload_specs(args):
    """[(name, n or path)] in run order."""
    from ..bench.workloads import data_files

    names = []
    for w in args.workloads:
        if w == "all":
            names.extend([*WORKLOADS, "data"])
        elif w in WORKLOAD_NAMES:
            names.append(w)
        else:
            raise ValueError(f"unknown workload {w!r}; choose from "
                             f"{', '.join(WORKLOAD_NAMES)} or all")
    names = list(dict.fromkeys(names))
    sizes = sorted({parse_size(s) for s in split_list(args.sizes)}) if args.sizes else None
    specs = []
    for name in names:
        if name == "data":
            files = data_files(args.data_dir)
            if not files:
                _out(f"data: no trajectory files in {args.data_dir}/; real-data workload "
                     "skipped")
            specs.extend(("data", f) for f in files)
            continue
        default, quick = WORKLOADS[name][1:]
        for n in sizes or (quick if args.quick else default):
            specs.append((name, n))
    return specs


def _build(name, what, args, density):
    from ..bench import workloads

    if name == "data":
        return workloads.real_data(what, cutoff=args.cutoff or workloads.LJ_CUTOFF)
    n_frames = args.frames or (10 if args.quick else 50)
    return workloads.make(name, what, seed=args.seed, density=density, n_frames=n_frames)


def _run_paper(args):
    try:
        from ..bench.paper import run_paper
    except ModuleNotFoundError as exc:
        if exc.name == "granularsap.bench.paper":
            _err("granularsap bench paper: unavailable in this build "
                 "(granularsap.bench.paper is missing)")
            return 1
        raise
    return int(run_paper(args) or 0)


def _run_dem_loop(args):
    from ..bench.demloop import run_dem_loop
    from ..bench.runner import usable_cores

    args.dem_sizes = sorted({parse_size(s) for s in split_list(args.sizes)}) if args.sizes else None
    args.threads = args.threads or usable_cores()
    return int(run_dem_loop(args) or 0)


def run(args) -> int:
    from ..bench.peers import GRANULARSAP, PEERS, make_peers
    from ..bench.runner import execute, list_peers, usable_cores

    if args.list:
        _out("workloads: " + ", ".join(WORKLOAD_NAMES))
        _out("peers:")
        list_peers(make_peers())
        return 0
    if not args.workloads:
        raise ValueError("give at least one WORKLOAD: " + ", ".join(WORKLOAD_NAMES) + ", all")
    if "mda-capped" in args.workloads:
        if len(args.workloads) > 1:
            raise ValueError("run 'mda-capped' on its own: granularsap bench mda-capped "
                             "[options]")
        from ..bench.mda_capped import run_mda_capped

        return int(run_mda_capped(args) or 0)
    if "paper" in args.workloads:
        if len(args.workloads) > 1:
            raise ValueError("run 'paper' on its own: granularsap bench paper [options]")
        return _run_paper(args)
    if "dem-loop" in args.workloads:
        if len(args.workloads) > 1:
            raise ValueError("run 'dem-loop' on its own: granularsap bench dem-loop [options]")
        return _run_dem_loop(args)
    names = split_list([args.peers]) if args.peers else list(PEERS)
    for g in reversed(GRANULARSAP):
        if g not in names:
            names.insert(0, g)
    excluded = set(split_list([args.exclude])) if args.exclude else set()
    peers = make_peers([n for n in names if n not in excluded])
    make_peers(list(excluded))  # validates the excluded names
    n_threads = args.threads or usable_cores()
    if n_threads < 1:
        raise ValueError(f"--threads must be at least 1, got {n_threads}")
    repeats = args.repeats or (3 if args.quick else 5)
    if repeats < 1:
        raise ValueError(f"--repeats must be at least 1, got {repeats}")
    densities = [float(d) for d in split_list(args.density)] if args.density else [0.35]
    specs = []
    for name, what in _workload_specs(args):
        if name == "paper-boxes":
            specs.extend((name, what, d) for d in densities)
        else:
            specs.append((name, what))
    if not specs:
        _out("nothing to run")
        return 0
    settings = {"command": shlex.join([os.path.basename(sys.argv[0]), *sys.argv[1:]]),
                "seed": args.seed, "quick": args.quick, "frames": args.frames,
                "densities": densities}

    def build(name, what, density=0.35):
        return _build(name, what, args, density)

    results = execute(specs, peers, build=build, repeats=repeats, n_threads=n_threads,
                      max_seconds=args.max_seconds, settings=settings, json_path=args.json,
                      plot_path=args.plot, small_runs=_small_runs())
    return 1 if any(w.disagreements for w in results) else 0
