"""The ``granularsap`` command line: the front-ends above the library.

Layers, top down (``tests/test_layering.py`` fails on an import cycle):

- this module: :func:`main` and :func:`build_parser`, which loads the
  subcommands of :data:`SUBCOMMANDS` by name;
- one module per subcommand (:mod:`.bench`, :mod:`.contacts`, :mod:`.info`,
  :mod:`.validate`, :mod:`.warmup`), each ``add_arguments(parser)`` and
  ``run(args) -> int``, calling into the library; heavy imports happen inside
  ``run`` so that ``granularsap --help`` stays instant;
- :mod:`.argtypes` (argument types shared by the subcommands) and
  :mod:`.errors` (:class:`CLIError`), leaves that import nothing of granularsap;
- the library (:mod:`granularsap.bench`, :mod:`granularsap.io`,
  :mod:`granularsap.compare`, :mod:`granularsap.warmup`, the engine), which
  never imports this package (the aliases kept for one release aside): it
  raises ``ValueError``, ``OSError`` and the like, reported here the same way
  as a :class:`CLIError` (one line, exit 2).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .errors import CLIError

#: subcommand -> (module, one-line help)
SUBCOMMANDS = {
    "bench": ("granularsap.cli.bench", "benchmark granularsap against other neighbour searches"),
    "contacts": ("granularsap.cli.contacts", "contacts of every frame of a trajectory to HDF5"),
    "info": ("granularsap.cli.info", "summarise a contacts HDF5 file"),
    "validate": ("granularsap.cli.validate",
                 "compare granularsap with LAMMPS / MDAnalysis per frame"),
    "warmup": ("granularsap.cli.warmup",
               "compile the numba kernels now (they are cached on disk)"),
}

__all__ = ["SUBCOMMANDS", "CLIError", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    from .._version import __version__

    parser = argparse.ArgumentParser(
        prog="granularsap",
        description="Parallel Sweep-and-Prune contact and neighbour search.",
    )
    parser.add_argument("--version", action="version", version=f"granularsap {__version__}")
    parser.add_argument("--traceback", action="store_true",
                        help="show the full Python traceback on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (modname, helptext) in SUBCOMMANDS.items():
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name and exc.name.startswith("granularsap"):
                continue  # subcommand not part of this build
            raise
        text = getattr(mod, "DESCRIPTION", None) or mod.__doc__ or helptext
        p = sub.add_parser(name, help=helptext, description=text.strip())
        p.add_argument("--traceback", action="store_true", default=argparse.SUPPRESS,
                       help="show the full Python traceback on errors")
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def _silence_stdout():
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no real stdout (captured, closed)
        pass


def main(argv=None) -> int:
    try:
        return _main(argv)
    except BrokenPipeError:
        # the reader went away (`granularsap info f.h5 | head -1`): stop quietly, as Unix
        # tools do, and keep Python from complaining when it flushes stdout at exit
        _silence_stdout()
        return 141  # 128 + SIGPIPE, what a shell reports for a tool SIGPIPE ended


def _main(argv):
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except BrokenPipeError:
        raise  # see main
    except KeyboardInterrupt:
        print("granularsap: interrupted", file=sys.stderr)
        return 130
    except (CLIError, ValueError, TypeError, OSError, ImportError) as exc:
        if getattr(args, "traceback", False):
            raise
        print(f"granularsap {args.command}: error: {exc}", file=sys.stderr)
        return 2
