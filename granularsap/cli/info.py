"""Summarise a contacts HDF5 file written by ``granularsap contacts``.

Prints frames, particles, contacts per frame, mean coordination number and
contact births/deaths; ``--plot`` draws contacts and coordination number over
time.  Exit codes: 0 complete file, 1 incomplete (interrupted) file, 2 error.
"""

from __future__ import annotations

import json
import os

from ..io.summary import plot, summarize
from .errors import CLIError

__all__ = ["add_arguments", "run"]


def add_arguments(parser):
    parser.add_argument("file", metavar="OUT.h5", help="contacts file (or its .partial twin)")
    parser.add_argument("--plot", metavar="PNG", default=None,
                        help="write a plot of contacts and coordination number per frame")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def _stats(values):
    import numpy as np

    if len(values) == 0:
        return "-"
    v = np.asarray(values, dtype=float)
    return f"min {v.min():g}, mean {v.mean():.4g}, max {v.max():g}"


def _particles(s):
    """Particle counts: range, and how often they change (a pour, atoms lost)."""
    counts = s["n_particles"]
    text = _stats(counts)
    if not counts:
        return text
    if not s["particles_changed"]:
        return f"{text}; the same in every frame"
    return (f"{text}; first {counts[0]}, last {counts[-1]}; count changes at "
            f"{s['particles_changed']} of {len(counts) - 1} transitions, "
            f"{s['empty_frames']} frame{'' if s['empty_frames'] == 1 else 's'} empty")


def run(args) -> int:
    path = args.file
    if not os.path.exists(path) and not os.path.exists(path + ".partial"):
        raise CLIError(f"{path} does not exist")
    s = summarize(path)
    if args.json:
        print(json.dumps(s))
    else:
        p = s["parameters"]
        if p.get("mode") == "cutoff":
            crit = f"cutoff {p['cutoff']:g}"
        else:
            src = (f"radius {p['radius']:g}" if p.get("radius") is not None
                   else f"radii from column {p.get('radius_column') or 'radius/diameter'}")
            crit = f"{p['mode']}, {src}, skin {p.get('skin', 0):g}"
        status = "complete" if s["complete"] else "INCOMPLETE (interrupted run; resumable)"
        births, deaths = sum(s["n_born"]), sum(s["n_died"])
        nf = s["frames"]
        lines = [
            f"file:          {s['path']} (schema {s['schema_version']}, "
            f"granularsap {s['granularsap_version']})",
            f"status:        {status}",
            f"source:        {p.get('source')} [{p.get('source_format')}], "
            f"frames {p.get('frames') or ':'}",
            f"contacts:      {crit}",
            f"frames:        {nf}",
            f"particles:     {_particles(s)}",
            f"contacts/frame: {_stats(s['n_contacts'])}",
            f"coordination:  {_stats(s['coordination'])}",
            f"births/deaths: {births} born, {deaths} died over {max(nf - 1, 0)} transitions "
            f"({births / max(nf - 1, 1):.4g} / {deaths / max(nf - 1, 1):.4g} per transition)",
        ]
        t = s["timing"]
        if t:
            busy = t.get("read", 0) + t.get("compute", 0) + t.get("write", 0) or 1e-12
            lines.append(f"timing:        read {t.get('read', 0):.3g} s "
                         f"({100 * t.get('read', 0) / busy:.0f}%), compute "
                         f"{t.get('compute', 0):.3g} s ({100 * t.get('compute', 0) / busy:.0f}%),"
                         f" write {t.get('write', 0):.3g} s "
                         f"({100 * t.get('write', 0) / busy:.0f}%)")
        print("\n".join(lines))
    if args.plot:
        plot(s, args.plot)
        if not args.json:
            print(f"plot:          {args.plot}")
    return 0 if s["complete"] else 1
