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
import re
import shlex
import sys
import time

from .workloads import WORKLOAD_NAMES, WORKLOADS

#: seconds between progress lines inside one peer's timed runs
PROGRESS_EVERY = 20.0
#: a peer whose warm-up, scaled linearly in N from the previous size, would take
#: more than this many times --max-seconds is left out at that size
PREDICT_FACTOR = 4.0


def _usable_cores():
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def parse_size(text):
    """``"1e5"``, ``"2^18"``, ``"2**18"``, ``"100k"``, ``"1M"`` or ``"12345"`` -> int."""
    t = text.strip().lower().replace("_", "")
    m = re.fullmatch(r"(\d+)\s*(?:\^|\*\*)\s*(\d+)", t)
    if m:
        return int(m.group(1)) ** int(m.group(2))
    mult = {"k": 10**3, "m": 10**6}
    if t and t[-1] in mult:
        return int(round(float(t[:-1]) * mult[t[-1]]))
    try:
        value = float(t)
    except ValueError:
        raise ValueError(f"cannot read size {text!r}; use e.g. 10000, 1e5, 2^18 or 100k") \
            from None
    if value < 1 or value != int(value):
        raise ValueError(f"size must be a positive whole number, got {text!r}")
    return int(value)


def _split(values):
    out = []
    for v in values or []:
        out.extend(x for x in re.split(r"[,\s]+", v) if x)
    return out


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


def _workload_specs(args):
    """[(name, n or path)] in run order."""
    from .workloads import data_files

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
    sizes = sorted({parse_size(s) for s in _split(args.sizes)}) if args.sizes else None
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
    from . import workloads

    if name == "data":
        return workloads.real_data(what, cutoff=args.cutoff or workloads.LJ_CUTOFF)
    n_frames = args.frames or (10 if args.quick else 50)
    return workloads.make(name, what, seed=args.seed, density=density, n_frames=n_frames)


class _Progress:
    """Progress lines: one per peer, and one every PROGRESS_EVERY s of a long peer."""

    def __init__(self):
        self.last = time.perf_counter()

    def peer_done(self, res):
        self.last = time.perf_counter()
        if res.status == "ok":
            _out(f"  {res.peer:<20} {res.seconds:.4g} s median of {len(res.times)} "
                 f"(min {res.min_seconds:.4g} s), {res.pairs} pairs")
        else:
            _out(f"  {res.peer:<20} {res.status}: {res.reason}")

    def tick(self, peer, done, planned, seconds):
        now = time.perf_counter()
        if now - self.last >= PROGRESS_EVERY and done < planned:
            self.last = now
            _out(f"  {peer.name:<20} ... {done}/{planned} timed runs, {seconds:.1f} s")


def list_peers(peers):
    for p in peers:
        why = p.missing()
        state = "available" if why is None else f"missing ({why})"
        _out(f"  {p.name:<20} {state}; {p.description}")


def _small_runs():
    from .harness import SMALL_RUNS

    return SMALL_RUNS


def execute(specs, peers, *, build, repeats, n_threads, max_seconds, settings,
            json_path=None, plot_path=None, small_runs=0):
    """Run ``specs`` through ``peers``; print tables; write JSON/PNG; return results.

    ``build(name, what)`` makes a workload for one spec.  Peers that are not
    installed are skipped with one line each.  ``small_runs``: steady runs of
    small single-frame workloads (``harness.run_peer``).
    """
    from . import harness, report

    harness.stabilise_malloc()
    machine = report.machine_description()
    load = machine.get("load_average")
    _out(f"machine: {machine['cpu_model']}, {machine['usable_cores']} usable cores, "
         f"{n_threads} threads for threaded peers"
         + (f", load average {load[0]:.2f}" if load else ""))
    usable = []
    missing = {}
    for p in peers:
        why = p.missing()
        if why is None:
            usable.append(p)
        else:
            missing[p.name] = why
            _out(f"skipping peer {p.name}: not available ({why})")
    settings = dict(settings, missing_peers=missing, threads=n_threads, repeats=repeats,
                    max_seconds=max_seconds, peers=[p.name for p in usable])
    results = []
    slow = {}  # (workload family, peer) -> reason it is left out at larger sizes
    history = {}  # (workload family, peer) -> (n, warm-up seconds) of its last size
    total = len(specs)
    for k, (name, what, *rest) in enumerate(specs, 1):
        density = rest[0] if rest else 0.35
        try:
            workload = build(name, what, density) if rest else build(name, what)
        except (ValueError, OSError) as exc:
            if name != "data":
                raise
            _out(f"[{k}/{total}] skipping {what}: cannot use it ({exc})")
            continue
        family = (name, density)
        _out(f"[{k}/{total}] {workload.label}: {len(usable)} peers, "
             f"{len(workload.frames) - 1 if len(workload.frames) > 1 else repeats} timed runs")
        run_peers = []
        for p in usable:
            if (family, p.name) not in slow and (family, p.name) in history:
                n0, warm = history[family, p.name]
                predicted = warm * workload.n / max(n0, 1)
                if predicted > PREDICT_FACTOR * max_seconds:
                    slow[family, p.name] = (f"its warm-up would take about {predicted:.0f} s "
                                            f"(it took {warm:.1f} s at N={n0})")
            if (family, p.name) in slow:
                _out(f"  {p.name:<20} left out: {slow[family, p.name]}")
            else:
                run_peers.append(p)

        lines = _Progress()
        wres = harness.run_workload(workload, run_peers, repeats=repeats, n_threads=n_threads,
                                    max_seconds=max_seconds, progress=lines.peer_done,
                                    tick=lines.tick, small_runs=small_runs)
        for r in wres.results:
            if r.status == "ok" and r.warmup_seconds:
                history[family, r.peer] = (workload.n, r.warmup_seconds)
            if r.status == "ok" and r.warmup_seconds and r.warmup_seconds > max_seconds:
                slow[family, r.peer] = (f"took {r.warmup_seconds:.1f} s at N={workload.n} "
                                        f"(--max-seconds {max_seconds:g})")
        results.append(wres)
        loud = report.disagreement_message(wres)
        if loud:
            _out(loud)
            if not (sys.stdout.isatty() and sys.stderr.isatty()):
                _err(loud)  # also on stderr when stdout goes to a file
        _out()
        _out(report.format_table(wres))
        _out()
    if json_path:
        report.to_json(results, settings=settings, path=json_path)
        _out(f"wrote {json_path}")
    if plot_path:
        report.plot(results, plot_path)
        _out(f"wrote {plot_path}")
    return results


def _run_paper(args):
    try:
        from .paper import run_paper
    except ModuleNotFoundError as exc:
        if exc.name == "granularsap.bench.paper":
            _err("granularsap bench paper: unavailable in this build "
                 "(granularsap.bench.paper is missing)")
            return 1
        raise
    return int(run_paper(args) or 0)


def _run_dem_loop(args):
    from .demloop import run_dem_loop

    args.dem_sizes = sorted({parse_size(s) for s in _split(args.sizes)}) if args.sizes else None
    args.threads = args.threads or _usable_cores()
    return int(run_dem_loop(args) or 0)


def run(args) -> int:
    from .peers import GRANULARSAP, PEERS, make_peers

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
        from .mda_capped import run_mda_capped

        return int(run_mda_capped(args) or 0)
    if "paper" in args.workloads:
        if len(args.workloads) > 1:
            raise ValueError("run 'paper' on its own: granularsap bench paper [options]")
        return _run_paper(args)
    if "dem-loop" in args.workloads:
        if len(args.workloads) > 1:
            raise ValueError("run 'dem-loop' on its own: granularsap bench dem-loop [options]")
        return _run_dem_loop(args)
    names = _split([args.peers]) if args.peers else list(PEERS)
    for g in reversed(GRANULARSAP):
        if g not in names:
            names.insert(0, g)
    excluded = set(_split([args.exclude])) if args.exclude else set()
    peers = make_peers([n for n in names if n not in excluded])
    make_peers(list(excluded))  # validates the excluded names
    n_threads = args.threads or _usable_cores()
    if n_threads < 1:
        raise ValueError(f"--threads must be at least 1, got {n_threads}")
    repeats = args.repeats or (3 if args.quick else 5)
    if repeats < 1:
        raise ValueError(f"--repeats must be at least 1, got {repeats}")
    densities = [float(d) for d in _split(args.density)] if args.density else [0.35]
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
