"""Run benchmark workloads through peers: progress lines, tables, JSON and plots.

What ``granularsap bench`` runs once its arguments are read
(:mod:`granularsap.cli.bench`): :func:`execute` times every spec with
:func:`.harness.run_workload`, leaves out peers too slow for the next size,
prints one table per workload (:mod:`.report`) and writes the report.
"""

from __future__ import annotations

import os
import sys
import time

__all__ = ["PREDICT_FACTOR", "PROGRESS_EVERY", "execute", "list_peers", "usable_cores"]

#: seconds between progress lines inside one peer's timed runs
PROGRESS_EVERY = 20.0
#: a peer whose warm-up, scaled linearly in N from the previous size, would take
#: more than this many times --max-seconds is left out at that size
PREDICT_FACTOR = 4.0


def usable_cores():
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _out(text=""):
    print(text, flush=True)


def _err(text):
    print(text, file=sys.stderr, flush=True)


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
    """One line per peer: available, or missing and why."""
    for p in peers:
        why = p.missing()
        state = "available" if why is None else f"missing ({why})"
        _out(f"  {p.name:<20} {state}; {p.description}")


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
