"""``iter_frames``: one way to read LAMMPS dumps and anything ASE or MDAnalysis reads.

LAMMPS text dumps go through our own streaming reader (see
:mod:`granularsap.io.lammps_dump` for why).  Everything else is handed to
MDAnalysis (when a topology is given, or for formats only it reads, such as
DCD and XTC) or to ASE (``.traj``, extxyz, CIF, ...): their readers are
mature and we only translate their frames into :class:`Frame`.
"""

from __future__ import annotations

import contextlib
import os
import warnings

import numpy as np

from ._frame import Frame, box_to_cell
from .lammps_dump import count_dump_frames, iter_lammps_dump, looks_like_dump

__all__ = ["TrajectoryError", "count_frames", "describe_format", "iter_frames",
           "resolve_format"]

#: what a trajectory may be, said in every "not a trajectory" message
EXPECTED = ("expected a trajectory: a LAMMPS text dump, or a file ASE or MDAnalysis reads "
            "(choose a reader with --format / format=)")


class TrajectoryError(ValueError):
    """A file that yields no frames: the message names the file, the reader tried and why."""


@contextlib.contextmanager
def _quiet_third_party():
    """Silence the warnings ASE and MDAnalysis emit while they guess and open a file.

    Probing a file that is not a trajectory makes them warn about their own
    plumbing (an FHI-aims ``FutureWarning``, guessed masses ...); our error
    message says what matters.  Only warnings raised from inside those packages
    are ignored.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", module=r"(ase|MDAnalysis)(\.|$)")
        yield


@contextlib.contextmanager
def _no_dt_warning():
    """Silence MDAnalysis's "Reader has no dt information, set to 1.0 ps", and only it.

    Readers of files without a time step (a LAMMPS dump) warn so on opening, on
    every frame read and on every ``ts.time``; MDAnalysis then takes dt = 1.0
    ps, so a LAMMPS dump's frame time is its step number (docs/trajectories.md).
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"Reader has no dt information",
                                category=UserWarning)
        yield


def _exception_text(exc):
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")

_DUMP_SUFFIXES = {".dump", ".lammpstrj", ".lammpsdump"}
#: trajectory formats only MDAnalysis reads (ASE reads .xyz, .traj, .extxyz, .cif, .pdb ...)
_MDA_SUFFIXES = {".dcd", ".xtc", ".trr", ".nc", ".ncdf", ".h5md", ".gro", ".tng", ".lammpsdata",
                 ".data", ".psf", ".tpr", ".crd", ".mol2", ".pqr", ".trj", ".mdcrd", ".chk"}
FORMATS = ("lammps-dump", "ase", "mdanalysis")


def resolve_format(path, format=None, topology=None):
    """Return ``(backend, backend_format)``; backend is one of :data:`FORMATS`."""
    if format is not None:
        name, _, sub = str(format).partition(":")
        name = name.lower()
        if name in ("lammps-dump", "lammpsdump", "lammps_dump", "dump"):
            return "lammps-dump", None
        if name in ("ase", "mdanalysis", "mda"):
            return ("mdanalysis" if name == "mda" else name), (sub or None)
        raise ValueError(f"unknown format {format!r}; choose one of 'lammps-dump', 'ase', "
                         "'mdanalysis', 'ase:<ase format>' or 'mdanalysis:<MDAnalysis format>'")
    suffix = os.path.splitext(os.fspath(path))[1].lower()
    if topology is not None:
        return "mdanalysis", None
    if suffix in _DUMP_SUFFIXES or looks_like_dump(path):
        return "lammps-dump", None
    if suffix in _MDA_SUFFIXES:
        return "mdanalysis", None
    return "ase", None


def describe_format(path, format=None, topology=None):
    """How ``path`` is read, in words (for messages): reader and format tried."""
    backend, sub = resolve_format(path, format, topology)
    how = "given" if format is not None else "guessed from the file name and content"
    if backend == "lammps-dump":
        return f"a LAMMPS text dump, {how}"
    if backend == "mdanalysis":
        return f"MDAnalysis{f' format {sub!r}' if sub else ''}, {how}"
    if sub is None:
        sub = _ase_guess(path)[0]
    return f"ASE format {sub!r}, {how}" if sub else f"ASE, {how}"


def _hint(path):
    """A pointer for files people pass by mistake (a contacts file instead of a trajectory)."""
    try:
        with open(path, "rb") as fh:
            if fh.read(8) == b"\x89HDF\r\n\x1a\n":
                return " (it is an HDF5 file: `granularsap info` reads contacts files)"
    except OSError:
        pass
    return ""


def _ase_guess(path):
    """ASE's guess of the file's format, or ``(None, reason)`` if it has none."""
    try:
        from ase.io.formats import filetype
    except ImportError:  # pragma: no cover - ase is a dependency of the io extra
        return None, "ASE is not installed"
    try:
        with _quiet_third_party():
            return filetype(os.fspath(path), read=True), None
    except Exception as exc:  # noqa: BLE001 - ASE raises many kinds on a foreign file
        return None, _exception_text(exc)


def _includes_first(frames):
    return (frames.start or 0) == 0 and (frames.stop is None or frames.stop > 0)


def iter_frames(path, format=None, *, frames=None, topology=None, coordinates=None, **kwargs):
    """Yield the frames of a trajectory, particles in id order.

    Parameters
    ----------
    path : str or os.PathLike
        LAMMPS text dump, or any file ASE or MDAnalysis can read.
    format : str, optional
        ``"lammps-dump"``, ``"ase"``, ``"mdanalysis"``, or ``"ase:<fmt>"`` /
        ``"mdanalysis:<fmt>"`` to pass a format to that library.  Default: by
        suffix and content (dumps start with ``ITEM:``; DCD/XTC/... go to
        MDAnalysis; the rest to ASE).
    frames : slice, optional
        Which frames to read (default all).  Frames outside are skipped without
        being parsed where the reader allows.  LAMMPS dumps and files ASE reads
        take non-negative start and stop and a positive step (each frame's
        ``index`` is its place in the file); MDAnalysis's readers any slice.
    topology : str, optional
        Topology for MDAnalysis (e.g. a PSF, PDB or LAMMPS data file for a DCD).
    coordinates : {"x", "xu", "xs", "xsu"}, optional
        LAMMPS dumps only: which coordinate columns to use.
    **kwargs
        Passed to ``MDAnalysis.Universe`` or ``ase.io.iread``.

    Yields
    ------
    Frame

    Raises
    ------
    granularsap.io.DumpFormatError
        After the good frames of a truncated or corrupt LAMMPS dump, or at
        once for a ``.dump`` file that is not one.
    granularsap.io.TrajectoryError
        If the file is empty, is not a trajectory the chosen reader can read,
        or holds no frame at all (one line naming the file, the reader and
        format tried, and why).
    FileNotFoundError
        If ``path`` does not exist.

    Examples
    --------
    >>> from granularsap.io import iter_frames
    >>> for frame in iter_frames("pour.dump"):          # doctest: +SKIP
    ...     print(frame.step, frame.n_particles, frame.box)
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"trajectory {path!r} does not exist")
    if frames is None:
        frames = slice(None)
    if not isinstance(frames, slice):
        raise TypeError(f"frames must be a slice, got {type(frames).__name__}")
    backend, sub = resolve_format(path, format, topology)
    if os.path.isfile(path) and os.path.getsize(path) == 0:
        raise TrajectoryError(f"{path} is empty (0 bytes); {EXPECTED}")
    if backend == "lammps-dump":
        if kwargs:
            raise TypeError(f"unexpected arguments for a LAMMPS dump: {', '.join(kwargs)}")
        source = iter_lammps_dump(path, frames=frames, coordinates=coordinates)
    elif backend == "mdanalysis":
        source = _iter_mdanalysis(path, sub, frames, topology, kwargs)
    else:
        source = _iter_ase(path, sub, frames, kwargs)
    n = 0
    for frame in source:
        n += 1
        yield frame
    if n == 0 and _includes_first(frames):
        raise TrajectoryError(f"{path}: no frames: read as "
                              f"{describe_format(path, format, topology)}, it holds none; "
                              f"{EXPECTED}")


def count_frames(path, format=None, *, topology=None, **kwargs):
    """Number of frames in a trajectory (None if it cannot be known cheaply)."""
    backend, sub = resolve_format(path, format, topology)
    if backend == "lammps-dump":
        return count_dump_frames(path)
    if backend == "mdanalysis":
        return len(_universe(path, sub, topology, kwargs).trajectory)
    return None


def _universe(path, sub, topology, kwargs):
    import MDAnalysis as mda

    if sub is not None:
        kwargs = {"format": sub, **kwargs}
    try:
        with _quiet_third_party(), _no_dt_warning():
            if topology is not None:
                return mda.Universe(topology, path, **kwargs)
            return mda.Universe(path, **kwargs)
    except (ImportError, MemoryError, FileNotFoundError):
        raise
    except Exception as exc:  # noqa: BLE001 - MDAnalysis raises many kinds on a foreign file
        what = f"format {sub!r}" if sub else "the format its suffix suggests"
        hint = ""
        if sub is None and str(path).lower().endswith((".dump", ".lammpstrj", ".dump.gz")):
            # MDAnalysis knows a LAMMPS dump by its format name, not by these suffixes
            hint = ("; for a LAMMPS dump ask for --format mdanalysis:LAMMPSDUMP (Python: "
                    "format='mdanalysis:LAMMPSDUMP'), or --format lammps-dump, granularsap's "
                    "own reader, which also reads dumps whose atom count changes")
        raise TrajectoryError(f"{path}: not a trajectory MDAnalysis can read as {what} "
                              f"({_exception_text(exc)}){hint}; {EXPECTED}") from None


def _iter_mdanalysis(path, sub, frames, topology, kwargs):
    u = _universe(path, sub, topology, kwargs)
    atoms = u.atoms
    ids = np.asarray(atoms.ids, dtype=np.int64)
    types = np.asarray(atoms.types) if hasattr(atoms, "types") else None
    radius = None
    if hasattr(atoms, "radii"):
        radius = np.asarray(atoms.radii, dtype=np.float64)
    molecule = None
    if hasattr(atoms, "molnums"):
        molecule = np.asarray(atoms.molnums, dtype=np.int64)
    # MDAnalysis's LAMMPS dump reader drops the boundary flags (pp ss ff ...): take them
    # from the file, or open walls would be periodic
    pbcs = None
    if str(getattr(u.trajectory, "format", "")) == "LAMMPSDUMP":
        from .lammps_dump import dump_frame_pbc

        pbcs = dump_frame_pbc(path)
    for ts in _mda_timesteps(u, frames, path):
        dims = ts.dimensions
        cell = None
        if dims is not None and np.all(np.asarray(dims[:3]) > 0):
            cell = box_to_cell(dims)
        pbc = np.full(3, cell is not None)
        if pbcs is not None and cell is not None:
            pbc = pbcs[int(ts.frame)].copy()
        step = ts.data.get("step")
        with _no_dt_warning():
            t_frame = float(ts.time)
        frame = Frame(index=int(ts.frame), positions=np.array(atoms.positions, dtype=np.float64),
                      ids=ids.copy(), cell=cell, pbc=pbc,
                      step=None if step is None else int(step), time=t_frame,
                      types=types, radius=radius, molecule=molecule, source=path)
        yield frame.sorted_by_id()


def _mda_timesteps(u, frames, path):
    """``u.trajectory[frames]``, with our message where MDAnalysis meets a count change."""
    it = iter(u.trajectory[frames])
    last = None
    while True:
        try:
            with _no_dt_warning():
                ts = next(it)
        except StopIteration:
            return
        except ValueError as exc:
            if "atoms" not in str(exc).lower() or "changed" not in str(exc).lower():
                raise
            after = "before its first frame" if last is None else f"after frame {last}"
            raise ValueError(
                f"{path}: MDAnalysis cannot read a trajectory whose atom count changes "
                f"(it stopped {after}: {exc}); read a LAMMPS dump with "
                "format='lammps-dump' (the default for LAMMPS dumps), which yields "
                "frames of any size, 0 included") from None
        last = int(ts.frame)
        yield ts


def _iter_ase(path, sub, frames, kwargs):
    import ase.io

    start = frames.start or 0
    step = frames.step or 1
    if start < 0 or (frames.stop is not None and frames.stop < 0) or step <= 0:
        # (ASE would read them, but each frame's index in the file is not known
        # without counting the file's frames first)
        raise ValueError(f"frames must be a slice with non-negative start/stop and positive "
                         f"step for a file ASE reads, got {frames}")
    index = slice(frames.start, frames.stop, frames.step)
    given = sub is not None
    if sub is None:
        sub, reason = _ase_guess(path)
        if sub is None:
            raise TrajectoryError(f"{path}: not a trajectory: ASE does not recognise its "
                                  f"format ({reason}); {EXPECTED}")
    how = "given" if given else "guessed from the file name and content"
    reader = ase.io.iread(path, index=index, format=sub, **kwargs)
    k = -1
    while True:
        try:
            with _quiet_third_party():
                atoms = next(reader)
        except StopIteration:
            return
        except (ImportError, MemoryError):
            raise
        except Exception as exc:  # noqa: BLE001 - ASE raises many kinds on a foreign file
            where = ("not a trajectory" if k < 0
                     else f"frame {start + (k + 1) * step}: unreadable")
            raise TrajectoryError(f"{path}: {where}: ASE could not read it as {sub!r} ({how}): "
                                  f"{_exception_text(exc)}{_hint(path)}; {EXPECTED}") from None
        k += 1
        n = len(atoms)
        arrays = atoms.arrays
        ids = np.asarray(arrays["id"], dtype=np.int64) if "id" in arrays else np.arange(n)
        cell = None
        pbc = np.asarray(atoms.pbc, dtype=bool)
        full = np.array(atoms.cell[:], dtype=np.float64)
        lengths = np.linalg.norm(full, axis=1)
        if pbc.any() and not np.all(lengths[pbc] > 0):
            zero = np.flatnonzero(pbc & ~(lengths > 0))
            which = (f"cell vector {zero[0]}, which is" if len(zero) == 1 else
                     f"cell vectors {', '.join(map(str, zero))}, which are")
            raise TrajectoryError(f"{path}: frame {start + k * step}: "
                                  f"periodic along {which} zero; give the cell, or pbc=False "
                                  "where there is none")
        if atoms.cell.rank == 3 or pbc.any():
            cell = full  # a slab's unused zero vector is fine: only periodic ones matter
        pbc = pbc if cell is not None else np.zeros(3, bool)
        radius = None
        for key in ("radius", "radii"):
            if key in arrays:
                radius = np.asarray(arrays[key], dtype=np.float64)
        if radius is None and "diameter" in arrays:
            radius = 0.5 * np.asarray(arrays["diameter"], dtype=np.float64)
        molecule = None
        for key in ("mol-id", "mol", "molecule", "mol_id"):
            if key in arrays:
                molecule = np.asarray(arrays[key], dtype=np.int64)
        skip = {"positions", "numbers"}
        columns = {key: np.asarray(v) for key, v in arrays.items()
                   if key not in skip and np.asarray(v).ndim == 1}
        info = atoms.info
        step_val = info.get("timestep", info.get("step"))
        time_val = info.get("time")
        frame = Frame(index=start + k * step,
                      positions=np.array(atoms.positions, dtype=np.float64), ids=ids, cell=cell,
                      pbc=pbc, step=None if step_val is None else int(step_val),
                      time=None if time_val is None else float(time_val),
                      types=np.asarray(atoms.numbers), radius=radius, molecule=molecule,
                      columns=columns, source=path, ids_given="id" in arrays)
        yield frame.sorted_by_id()
