"""Contacts of every frame of a trajectory, written to one HDF5 file.

Reads a LAMMPS text dump or anything ASE/MDAnalysis reads, finds every
frame's contacts with granularsap, and writes them (with contact births and
deaths between consecutive frames) to OUT.h5.  An interrupted run leaves
OUT.h5.partial; running the same command again resumes it.

Exit codes: 0 done, 2 bad usage or input, 130 interrupted (resumable).
"""

from __future__ import annotations

import sys

from . import argtypes
from .errors import CLIError

__all__ = ["add_arguments", "run"]


def add_arguments(parser):
    parser.add_argument("trajectory", metavar="TRAJ",
                        help="LAMMPS text dump, or any file ASE or MDAnalysis reads")
    parser.add_argument("-o", "--output", required=True, metavar="OUT.h5",
                        help="HDF5 file to write")
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--cutoff", type=argtypes.nonneg, metavar="C",
                      help="neighbour pairs with distance <= C")
    what.add_argument("--radius", type=argtypes.nonneg, metavar="R",
                      help="sphere contacts, every particle of radius R")
    what.add_argument("--radius-column", metavar="NAME",
                      help="sphere contacts with radii from this per-particle column "
                           "('diameter' is halved); default: the file's radius or diameter")
    parser.add_argument("--skin", type=argtypes.nonneg, default=0.0, metavar="S",
                        help="sphere contacts: count pairs with d <= r_i + r_j + S (default 0)")
    parser.add_argument("--open", type=argtypes.axes, default=(), metavar="AXES",
                        help="search these axes (x, y, z letters) as open whatever the file's "
                             "boundaries: z for a LAMMPS 2-D run")
    parser.add_argument("--frames", type=argtypes.frames, default=None, metavar="START:STOP:STEP",
                        help="frames to process (default all)")
    parser.add_argument("--clumps", action="store_true",
                        help="treat the molecule column as rigid-clump ids: no intra-clump "
                             "pairs, clump pairs stored too")
    parser.add_argument("--distances", action="store_true", help="store pair distances")
    parser.add_argument("--format", default=None,
                        help="'lammps-dump', 'ase[:FMT]' or 'mdanalysis[:FMT]' (default: guess)")
    parser.add_argument("--topology", default=None, metavar="FILE",
                        help="topology file for MDAnalysis (e.g. for DCD/XTC)")
    parser.add_argument("--threads", type=argtypes.positive_int, default=None, metavar="N",
                        help="numba threads per frame (default: all cores; with --workers N, "
                             "cores / N per worker)")
    dist = parser.add_mutually_exclusive_group()
    dist.add_argument("--workers", type=argtypes.positive_int, default=None, metavar="N",
                      help="start a local Dask cluster with N worker processes")
    dist.add_argument("--scheduler", default=None, metavar="ADDRESS",
                      help="use an existing dask.distributed scheduler, e.g. tcp://host:8786")
    parser.add_argument("--domain-particles", type=argtypes.positive_int, default=None, metavar="N",
                        help="with --workers/--scheduler: frames of at least N particles are "
                             "each split into spatial domains over all the workers instead of "
                             "one frame per worker (default: $GRANULARSAP_DOMAIN_PARTICLES or "
                             "2000000)")
    parser.add_argument("--no-resume", action="store_true",
                        help="start over even if OUT.h5.partial from an interrupted run exists")
    parser.add_argument("--commit-seconds", type=argtypes.nonneg, default=1.0, metavar="S",
                        help="make finished frames durable at least every S seconds "
                             "(default 1; 0 = after every frame)")
    parser.add_argument("-f", "--force", action="store_true",
                        help="overwrite OUT.h5 if it exists")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar and no summary")


def run(args) -> int:
    from ..io.pipeline import ContactParams, check_output, compute_contacts

    threads = args.threads
    if threads is not None:
        from .._numba import max_threads

        top = max_threads()
        if threads > top:
            raise CLIError(f"--threads {threads} is more than the {top} threads numba can run "
                           f"here (the cores, or NUMBA_NUM_THREADS if set); give --threads 1 "
                           f"to {top}")
    if threads is None and args.workers is not None:
        import os

        threads = max(1, (os.cpu_count() or 1) // args.workers)
    try:
        params = ContactParams(cutoff=args.cutoff, radius=args.radius,
                               radius_column=args.radius_column, skin=args.skin,
                               clumps=args.clumps, distances=args.distances, n_threads=threads,
                               open_axes=args.open)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    import os

    if not os.path.exists(args.trajectory):
        raise CLIError(f"trajectory {args.trajectory} does not exist")
    if args.topology is not None and not os.path.exists(args.topology):
        raise CLIError(f"--topology {args.topology} does not exist")
    try:
        check_output(args.output, overwrite=args.force)
    except FileExistsError:
        raise CLIError(f"{args.output} already exists; use --force to overwrite it") from None

    def on_resume(done, reason):
        if args.quiet:
            return
        if reason:
            print(f"starting over: {reason}", file=sys.stderr)
        if done:
            print(f"resuming {args.output}.partial after {done} complete frames",
                  file=sys.stderr)

    def on_plan(message):
        if not args.quiet:
            print(message, file=sys.stderr)

    def on_warning(message):  # about the results: shown even with --quiet
        print(f"granularsap contacts: warning: {message}", file=sys.stderr)

    import signal

    # SIGTERM/Ctrl-C: finish the frame in hand, commit, exit 130 (resumable); a second
    # signal interrupts at once.  (An exception raised straight from a signal handler can
    # land in a destructor and be swallowed, so the first signal only sets a flag.)
    stop = []

    def on_signal(signum, frame):
        if stop:
            raise KeyboardInterrupt
        stop.append(signum)

    old_handlers = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    bar = None
    if not args.quiet:
        from tqdm import tqdm

        # shown on a terminal only, and only for runs longer than half a second
        bar = tqdm(total=None, unit="frame", desc="contacts", file=sys.stderr,
                   dynamic_ncols=True, mininterval=0.5, delay=0.5, disable=None)
    from ..warmup import compile_notice, warm_contacts

    try:
        with compile_notice(quiet=args.quiet):
            if args.workers is not None:
                # compile once here rather than in every worker at the same time; the
                # workers then load the kernels from the disk cache
                warm_contacts(modes=(params.mode,))
            summary = compute_contacts(args.trajectory, args.output, params,
                                       format=args.format, topology=args.topology,
                                       frames=args.frames, resume=not args.no_resume,
                                       overwrite=args.force, workers=args.workers,
                                       scheduler=args.scheduler, progress=bar,
                                       on_resume=on_resume,
                                       commit_seconds=args.commit_seconds,
                                       should_stop=lambda: bool(stop),
                                       domain_particles=args.domain_particles,
                                       on_plan=on_plan, on_warning=on_warning)
    except KeyError as exc:
        raise CLIError(exc.args[0] if exc.args else str(exc)) from None
    except FileExistsError:  # another run finished it while this one started
        raise CLIError(f"{args.output} already exists; use --force to overwrite it") from None
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        print(f"granularsap contacts: interrupted; complete frames are kept in "
              f"{args.output}.partial; run the same command again to resume", file=sys.stderr)
        raise
    finally:
        for sig, handler in old_handlers.items():
            signal.signal(sig, handler)
        if bar is not None:
            bar.close()
    if not args.quiet:
        t = summary["timing"]
        wall = t.get("wall", 0.0) or 1e-12
        n = t.get("frames_this_run", 0)
        busy = t["read"] + t["compute"] + t["write"] or 1e-12
        print(f"wrote {args.output}: {summary['frames']} frames "
              f"({n} this run, {n / wall:.2f} frames/s); time share: "
              f"read {100 * t['read'] / busy:.0f}%, compute {100 * t['compute'] / busy:.0f}%, "
              f"write {100 * t['write'] / busy:.0f}%")
    return 0
