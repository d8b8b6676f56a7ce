"""Compile granularsap's numba kernels ahead of time, and say so when a run compiles.

granularsap's kernels are compiled by numba on first use and cached on disk
(``cache=True``): the first ``granularsap contacts`` on a fresh install spends
most of its time compiling, every later run loads the compiled code in a
fraction of a second.  ``granularsap warmup`` calls the public functions the
command line uses (:func:`granularsap.sphere_contacts`,
:func:`~granularsap.neighbor_pairs`, :func:`~granularsap.clump_contacts`,
:func:`~granularsap.box_overlaps`, and the boxes' column path) on tiny inputs,
open and periodic, with one thread and with two (the serial kernels small
inputs take and the parallel ones large inputs take), so that the cache is
filled before the first real run (useful in a container image or before
starting many worker processes).

:func:`compile_notice` is how the command line notices a cold cache: it
listens to numba's ``numba:compile`` event (numba's documented event API),
which fires only when a kernel is really compiled, not when it is loaded from
the cache, and prints one line to stderr the first time a granularsap kernel
compiles.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time

__all__ = ["compile_notice", "warmup"]

#: what ``granularsap warmup --help`` says
DESCRIPTION = """\
Compile granularsap's numba kernels now, so that the first real run does not.
Kernels are compiled on first use and cached on disk (numba's cache: the
__pycache__ folders of the installed package, or NUMBA_CACHE_DIR); a cold
cache costs the first `granularsap contacts` about 20 s. This command calls
sphere_contacts, neighbor_pairs, clump_contacts and box_overlaps on tiny open
and periodic inputs; --only sphere_contacts,neighbor_pairs,clump_contacts
compiles just what `granularsap contacts` needs.
"""

#: the public functions warmup compiles, in the order it calls them
FUNCTIONS = ("sphere_contacts", "neighbor_pairs", "clump_contacts", "box_overlaps")

NOTICE = ("granularsap: compiling numba kernels on first use (once, about 20 s; they are "
          "cached for the next runs; `granularsap warmup` compiles them ahead)")


def _ours(dispatcher):
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
    return module.split(".")[0] in ("granularsap", "lammps_bridge")


class _CompileCounter:
    """Counts compilations of granularsap kernels; calls ``on_first`` at the first one."""

    def __init__(self, on_first=None):
        from numba.core import event

        counter = self

        class Listener(event.Listener):
            def on_start(self, ev):
                disp = (ev.data or {}).get("dispatcher")
                if disp is not None and _ours(disp):
                    counter.seen()

            def on_end(self, ev):
                pass

        self.count = 0
        self._lock = threading.Lock()
        self._on_first = on_first
        self.listener = Listener()

    def seen(self):
        with self._lock:
            self.count += 1
            first = self.count == 1
        if first and self._on_first is not None:
            self._on_first()


@contextlib.contextmanager
def compile_notice(*, quiet=False, stream=None):
    """Within this context, say once on ``stream`` (stderr) when a kernel compiles.

    Yields the counter; ``.count`` is the number of kernel compilations seen.
    Nothing is printed when every kernel comes from the cache, or with
    ``quiet=True``.
    """
    from numba.core import event

    def say():
        if not quiet:
            print(NOTICE, file=stream or sys.stderr, flush=True)

    counter = _CompileCounter(on_first=say)
    with event.install_listener("numba:compile", counter.listener):
        yield counter


def _inputs(seed=0):
    import numpy as np

    rng = np.random.default_rng(seed)
    n, length = 64, 4.0
    pos = rng.uniform(0.0, length, (n, 3))
    radii = rng.uniform(0.1, 0.3, n)
    clumps = np.repeat(np.arange(n // 2, dtype=np.int64), 2)
    boxes = [None, [length, length, length, 90.0, 90.0, 90.0],
             [length, length, length, 80.0, 95.0, 85.0],
             np.diag([length, length, 1000.0])]
    return pos, radii, clumps, boxes


def warmup(functions=FUNCTIONS):
    """Compile (or load from the cache) the kernels of the given public functions.

    Parameters
    ----------
    functions : sequence of str
        Names from :data:`FUNCTIONS`.

    Returns
    -------
    dict
        ``seconds`` spent and ``compiled``, the number of kernel compilations
        (0 when everything came from the cache).
    """
    import granularsap

    unknown = [f for f in functions if f not in FUNCTIONS]
    if unknown:
        raise ValueError(f"unknown function {unknown[0]!r}; choose from {', '.join(FUNCTIONS)}")
    import numba

    pos, radii, clumps, boxes = _inputs()
    # one thread runs the serial kernels; more threads the parallel ones, which
    # large inputs take
    threads = (1, 2) if numba.config.NUMBA_NUM_THREADS >= 2 else (1,)
    t0 = time.perf_counter()
    with compile_notice(quiet=True) as counter:
        for name, nt in ((name, nt) for name in functions for nt in threads):
            if name == "box_overlaps":
                lower, upper = pos - radii[:, None], pos + radii[:, None]
                granularsap.box_overlaps(lower, upper, n_threads=nt)
                granularsap.SweepAndPrune(path="columns", n_threads=nt).update(lower, upper)
                continue
            for box in boxes:
                if name == "sphere_contacts":
                    for dist in (False, True):
                        granularsap.sphere_contacts(pos, radii, skin=0.05, box=box,
                                                    return_distances=dist, n_threads=nt)
                elif name == "neighbor_pairs":
                    for dist in (False, True):
                        granularsap.neighbor_pairs(pos, 0.6, box=box, return_distances=dist,
                                                   n_threads=nt)
                else:
                    granularsap.clump_contacts(pos, radii, clumps, skin=0.05, box=box,
                                               n_threads=nt)
    return {"seconds": time.perf_counter() - t0, "compiled": counter.count}


def cache_location():
    """Where numba keeps granularsap's compiled kernels (for messages)."""
    import os

    import numba

    from . import _numba

    if not _numba.CACHE:
        return "nowhere: the cache is off (GRANULARSAP_NO_CACHE)"
    if numba.config.CACHE_DIR:
        return os.fspath(numba.config.CACHE_DIR)
    here = os.path.dirname(os.path.abspath(__file__))
    return (f"__pycache__ folders under {here} (or numba's user cache if those are not "
            "writable); set NUMBA_CACHE_DIR to choose")


# --------------------------------------------------------------------------- command


def add_arguments(parser):
    parser.add_argument("--only", default=",".join(FUNCTIONS), metavar="NAME[,NAME]",
                        help=f"functions to compile (default all: {', '.join(FUNCTIONS)})")
    parser.add_argument("-q", "--quiet", action="store_true", help="print nothing")


def run(args) -> int:
    from .cli import CLIError

    names = [n.strip() for n in args.only.split(",") if n.strip()]
    try:
        out = warmup(names)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    if not args.quiet:
        what = (f"compiled {out['compiled']} kernel signatures" if out["compiled"]
                else "nothing to compile: every kernel came from the cache")
        print(f"granularsap warmup: {', '.join(names)} ready in {out['seconds']:.1f} s "
              f"({what}); cache: {cache_location()}")
    return 0
