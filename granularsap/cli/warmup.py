"""``granularsap warmup``: compile the numba kernels now (:mod:`granularsap.warmup`)."""

from __future__ import annotations

import sys

from ..warmup import GROUPS, cache_location, resolve, warmup
from .errors import CLIError

__all__ = ["DESCRIPTION", "add_arguments", "run"]

#: what ``granularsap warmup --help`` says
DESCRIPTION = """\
Compile granularsap's numba kernels now, so that the first real run does not.
Kernels are compiled on first use and cached on disk (numba's cache: the
__pycache__ folders of the installed package, or NUMBA_CACHE_DIR). This
command runs what each command and search runs, on tiny inputs, group by group
(one line per group on stderr): contacts (`granularsap contacts` in every mode,
`granularsap info`, `validate`, sphere_contacts, neighbor_pairs,
clump_contacts), search (NeighborSearch and ContactSearch with a Verlet list,
vectors, shifts, CSR, every image, contact identity), boxes (box_overlaps, SweepAndPrune) and
dropins (granularsap.mda, granularsap.ase). --only contacts is what the quick
start needs.
"""


def add_arguments(parser):
    parser.add_argument("--only", default=",".join(GROUPS), metavar="GROUP[,GROUP]",
                        help=f"groups to compile (default all: {', '.join(GROUPS)}; "
                             "contacts is what `granularsap contacts` and `info` use)")
    parser.add_argument("-q", "--quiet", action="store_true", help="print nothing")


def run(args) -> int:
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    try:
        groups = resolve(names)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    if not groups:
        raise CLIError(f"--only names no group; choose from {', '.join(GROUPS)}")

    def progress(group, seconds, compiled):
        if not args.quiet:
            k = groups.index(group) + 1
            what = (f"compiled {compiled} kernel signatures" if compiled
                    else "every kernel came from the cache")
            print(f"granularsap warmup: [{k}/{len(groups)}] {group} ready in {seconds:.1f} s "
                  f"({what}): {GROUPS[group]}", file=sys.stderr, flush=True)

    if not args.quiet:
        print(f"granularsap warmup: compiling {', '.join(groups)} into {cache_location()} "
              "(a minute or two on a cold cache, a few seconds on a warm one)",
              file=sys.stderr, flush=True)
    out = warmup(groups, progress=progress)
    if not args.quiet:
        what = (f"compiled {out['compiled']} kernel signatures" if out["compiled"]
                else "nothing to compile: every kernel came from the cache")
        print(f"granularsap warmup: {', '.join(groups)} ready in {out['seconds']:.1f} s "
              f"({what}); cache: {cache_location()}")
    return 0
