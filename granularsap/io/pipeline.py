"""Contacts of every frame of a trajectory into one HDF5 file, serially or with Dask.

The reader runs in the calling process; each frame's contacts are computed by
:func:`frame_contacts` (in the same process, or as a Dask task on a
``dask.distributed`` cluster) and written in frame order by
:class:`~granularsap.io.hdf5.ContactsWriter`.  At most a few frames per worker
are in flight, so memory stays bounded whatever the trajectory length.

On a cluster, frames of at least :func:`domain_threshold` particles are not
sent one per worker: each is split into spatial domains over all the workers
(:mod:`granularsap.dask`), and its pairs are gathered for the file.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import itertools
import logging
import os
import re
import time
from dataclasses import dataclass

import numpy as np

from ..cell import as_open_axes
from ._frame import Frame
from ._lock import OutputBusyError, lock_path, output_lock
from .hdf5 import ContactsWriter, FrameResult, partial_path
from .lammps_dump import DumpFormatError
from .readers import TrajectoryError, count_frames, describe_format, iter_frames, resolve_format

__all__ = ["DOMAIN_PARTICLES", "ContactParams", "OutputBusyError", "check_output",
           "compute_contacts",
           "domain_frame_contacts", "domain_threshold", "engine_cell", "frame_contacts",
           "FrameError"]

#: Default frame size (particles) from which a distributed run splits every frame
#: into spatial domains over the workers instead of sending one frame per worker.
DOMAIN_PARTICLES = 2_000_000
#: Environment variable that overrides :data:`DOMAIN_PARTICLES`.
DOMAIN_PARTICLES_ENV = "GRANULARSAP_DOMAIN_PARTICLES"


@dataclass(frozen=True)
class ContactParams:
    """What counts as a contact.

    Exactly one of ``cutoff`` (neighbour pairs with ``d <= cutoff``), ``radius``
    (spheres of one radius) or ``radius_column`` (per-particle radii from the
    file: ``"radius"``, or ``"diameter"`` which is halved, or any other column
    holding radii) applies; with none, the file's radius/diameter column is used.
    Sphere contacts are pairs with ``d <= r_i + r_j + skin``.  ``open_axes``
    (axis numbers) are searched as open whatever the file's boundaries say: a
    LAMMPS 2-D run's z (``dimension 2`` writes a periodic z one unit thick,
    which no pair crosses).
    """

    cutoff: float | None = None
    radius: float | None = None
    radius_column: str | None = None
    skin: float = 0.0
    clumps: bool = False
    distances: bool = False
    n_threads: int | None = None
    open_axes: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "open_axes", as_open_axes(self.open_axes))
        given = [n for n in ("cutoff", "radius", "radius_column") if getattr(self, n) is not None]
        if len(given) > 1:
            raise ValueError(f"give only one of cutoff, radius and radius_column, got "
                             f"{' and '.join(given)}")
        for name in ("cutoff", "radius", "skin"):
            val = getattr(self, name)
            if val is not None and (not np.isfinite(val) or val < 0):
                raise ValueError(f"{name} must be a finite non-negative number, got {val}")
        if self.cutoff is not None and (self.clumps or self.skin):
            raise ValueError("cutoff mode takes no skin and no clumps; use radius or "
                             "radius_column for sphere contacts")
        if self.clumps and self.distances:
            raise ValueError("distances are not available with clumps")

    @property
    def mode(self) -> str:
        if self.cutoff is not None:
            return "cutoff"
        return "clumps" if self.clumps else "spheres"

    def describe(self) -> dict:
        """The parameters that define the result (not how it is computed)."""
        d = dataclasses.asdict(self)
        d.pop("n_threads")
        d.pop("open_axes")
        if self.open_axes:  # (files of runs without it keep their attributes)
            d["open_axes"] = "".join("xyz"[a] for a in self.open_axes)
        d["mode"] = self.mode
        return d


def engine_cell(frame: Frame):
    """The cell to give the engine: None (open), or a :class:`granularsap.Cell`.

    The frame's cell, pbc and origin.  Non-periodic directions of a partly
    periodic box (LAMMPS ``f``/``s``/``m`` boundaries, ASE ``pbc=False`` on an
    axis) are open in the engine; their cell vectors are replaced by unit
    vectors normal to the periodic ones (``Cell.full_matrix`` of the zeroed
    rows), so that a tilt towards an open axis cannot narrow the periodic
    widths.  The result depends on the frame's box only (not on where the
    particles are), so a stateful search sees the same cell frame after frame.
    """
    from ..cell import Cell
    from ..geometry import open_axes_normal

    if frame.cell is None or not np.any(frame.pbc):
        return None
    pbc = np.asarray(frame.pbc, dtype=bool)
    return Cell(open_axes_normal(frame.cell, pbc), pbc, origin=frame.origin)


def _radii(frame: Frame, params: ContactParams):
    if params.radius is not None:
        return np.full(frame.n_particles, params.radius, dtype=np.float64)
    if params.radius_column is not None:
        name = params.radius_column
        if name == "diameter":
            return 0.5 * np.asarray(frame.column("diameter"), dtype=np.float64)
        return np.asarray(frame.column(name), dtype=np.float64)
    if frame.radius is None:
        raise ValueError(f"{frame.source} frame {frame.index} has no radius or diameter column; "
                         "give a cutoff, a radius or a radius column")
    return frame.radius


def lean_frame(frame: Frame, params: ContactParams) -> Frame:
    """A copy with only what :func:`frame_contacts` needs (cheap to ship to a worker)."""
    radius = None if params.cutoff is not None else _radii(frame, params)
    # bad numbers named by file, frame and particle id (the engine knows only row numbers)
    bad = np.flatnonzero(~np.isfinite(frame.positions).all(axis=1))
    if len(bad):
        k = bad[0]
        raise FrameError(frame.source, frame.index, frame.step,
                         f"particle id {frame.ids[k]} has a non-finite position "
                         f"{frame.positions[k].tolist()} ({len(bad)} such particles)")
    if radius is not None:
        bad = np.flatnonzero(~(np.asarray(radius) >= 0) | ~np.isfinite(radius))
        if len(bad):
            k = bad[0]
            raise FrameError(frame.source, frame.index, frame.step,
                             f"particle id {frame.ids[k]} has radius {radius[k]}; radii must "
                             f"be finite and non-negative ({len(bad)} such particles)")
    molecule = frame.molecule if params.clumps else None
    if params.clumps and molecule is None:
        raise ValueError(f"{frame.source} frame {frame.index} has no molecule (mol) column "
                         "for clumps")
    pbc = frame.pbc
    if params.open_axes:
        pbc = np.array(pbc, dtype=bool)
        pbc[list(params.open_axes)] = False
    return Frame(index=frame.index, positions=frame.positions, ids=frame.ids, cell=frame.cell,
                 pbc=pbc, step=frame.step, time=frame.time, radius=radius,
                 molecule=molecule, source=frame.source, ids_given=frame.ids_given)


def _sort_rows(pairs, *extra):
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return (pairs[order], *(None if e is None else e[order] for e in extra))


class FrameSearch:
    """The stateful search one run keeps across its frames.

    A :class:`granularsap.NeighborSearch` (``--cutoff``) or
    :class:`granularsap.ContactSearch` (radii, clumps) made once from the
    run's parameters, so consecutive frames reuse its buffers and its column
    order; the answer of every frame is the one-shot answer exactly.
    """

    def __init__(self, params: ContactParams):
        import granularsap

        quantities = "Pd" if params.distances else "P"
        if params.cutoff is not None:
            self.search = granularsap.NeighborSearch(params.cutoff, quantities=quantities,
                                                     n_threads=params.n_threads)
        else:
            self.search = granularsap.ContactSearch(skin=params.skin, quantities=quantities,
                                                    n_threads=params.n_threads)
        self.params = params

    def __call__(self, frame: Frame):
        """``(pairs (k, 2) of row indices, distances or None, clump label pairs or None)``."""
        params = self.params
        pos = frame.positions
        if params.cutoff is not None:
            out = self.search.update(pos, engine_cell(frame))
        else:
            radii = frame.radius if frame.radius is not None else _radii(frame, params)
            labels = frame.molecule if params.clumps else None
            out = self.search.update(pos, radii, engine_cell(frame), clump_ids=labels)
        pairs, distances = out if params.distances else (out, None)
        clump_pairs = None
        if params.clumps:
            mol = np.asarray(frame.molecule, dtype=np.int64)
            clump_pairs = np.sort(np.stack([mol[pairs[:, 0]], mol[pairs[:, 1]]], axis=1), axis=1)
            clump_pairs = (np.unique(clump_pairs, axis=0) if len(clump_pairs)
                           else np.empty((0, 2), np.int64))
        return pairs, distances, clump_pairs


#: one FrameSearch per parameter set in a worker process, kept for its next frames
_WORKER_SEARCHES: dict = {}


def _worker_search(params: ContactParams) -> FrameSearch:
    key = repr(sorted(params.describe().items())) + repr(params.n_threads)
    search = _WORKER_SEARCHES.get(key)
    if search is None:
        _WORKER_SEARCHES.clear()
        search = _WORKER_SEARCHES[key] = FrameSearch(params)
    return search


def worker_frame_contacts(frame: Frame, params: ContactParams) -> FrameResult:
    """:func:`frame_contacts` with the worker process's kept search (a Dask task)."""
    return frame_contacts(frame, params, _worker_search(params))


class FrameError(ValueError):
    """The search refused a frame (a cell too narrow for the range, a particle far
    outside it, ...): the message names the file, the frame, its step and, where
    the search names a row, that particle's id."""

    def __init__(self, source, frame, step, message):
        self.source, self.frame, self.step, self.message = source, frame, step, message
        super().__init__(f"{source}: frame {frame} (step {step}): {message}")

    def __reduce__(self):  # survives pickling (errors raised on Dask workers)
        return (type(self), (self.source, self.frame, self.step, self.message))

    @classmethod
    def of(cls, frame, exc):
        """The error ``exc`` that a search of ``frame`` raised, named by its frame."""
        message = _row_ids(str(exc), frame)
        if "perpendicular cell width" in message:
            # (trajectories are searched by minimum image: the engine's every-image
            # option is not theirs to offer)
            message = message.replace(
                ", or periodic_images='all' to get every image with its shift", "")
            if "across cell vector 2" in message:
                message += ("; or search z as open if it is no real axis, as a LAMMPS 2-D "
                            "run's periodic z one unit thick (--open z; Python: "
                            "open_axes=(2,))")
        return cls(frame.source, frame.index, frame.step, message)


def _row_ids(message, frame):
    """``message`` with the particle id of the first row it names (the search knows
    rows only), when the frame has ids."""
    found = re.search(r"\brows? (\d+)\b", message)
    if found is None or not frame.ids_given:
        return message
    row = int(found.group(1))
    if row >= frame.n_particles:
        return message
    return f"{message} (row {row} is particle id {int(frame.ids[row])})"


def frame_contacts(frame: Frame, params: ContactParams, search: FrameSearch | None = None
                   ) -> FrameResult:
    """Contacts of one frame as particle-id pairs (rows sorted).

    Parameters
    ----------
    frame : Frame
    params : ContactParams
    search : FrameSearch, optional
        The run's search, kept across frames (a fresh one if None).

    Returns
    -------
    FrameResult
    """
    t0 = time.perf_counter()
    if search is None:
        search = FrameSearch(params)
    try:
        pairs, distances, clump_pairs = search(frame)
    except ValueError as exc:
        raise FrameError.of(frame, exc) from None
    return _frame_result(frame, pairs, distances, clump_pairs, t0)


def _frame_result(frame, pairs, distances, clump_pairs, t0):
    """A :class:`FrameResult` from row-index pairs: particle ids, rows sorted."""
    if distances is not None:
        distances = np.array(distances, dtype=np.float64)
    pairs = frame.ids[np.asarray(pairs, dtype=np.int64).reshape(-1, 2)]
    pairs = np.sort(pairs, axis=1)  # ids ascending within a row
    pairs, distances = _sort_rows(pairs, distances)
    if clump_pairs is not None:
        clump_pairs = np.sort(np.asarray(clump_pairs, dtype=np.int64).reshape(-1, 2), axis=1)
        (clump_pairs,) = _sort_rows(clump_pairs)
    cell = np.full((3, 3), np.nan) if frame.cell is None else np.asarray(frame.cell, np.float64)
    return FrameResult(index=frame.index, step=frame.step, time=frame.time,
                       n_particles=frame.n_particles, cell=cell,
                       pbc=np.asarray(frame.pbc, dtype=bool), pairs=pairs, distances=distances,
                       clump_pairs=clump_pairs, seconds=time.perf_counter() - t0,
                       ids_given=frame.ids_given)


def _warn(message):
    import warnings

    warnings.warn(message, UserWarning, stacklevel=3)


def domain_threshold(domain_particles=None) -> int:
    """Frame size (particles) from which a distributed run uses spatial domains.

    ``domain_particles`` if given, else the environment variable
    ``GRANULARSAP_DOMAIN_PARTICLES``, else :data:`DOMAIN_PARTICLES`.
    """
    if domain_particles is None:
        text = os.environ.get(DOMAIN_PARTICLES_ENV)
        if text is None:
            return DOMAIN_PARTICLES
        try:
            domain_particles = int(text)
        except ValueError:
            raise ValueError(f"{DOMAIN_PARTICLES_ENV} must be a positive integer, got "
                             f"{text!r}") from None
    if isinstance(domain_particles, bool) or int(domain_particles) != domain_particles or \
            domain_particles < 1:
        raise ValueError(f"domain_particles must be a positive integer, got "
                         f"{domain_particles!r}")
    return int(domain_particles)


def domain_frame_contacts(frame: Frame, params: ContactParams, client):
    """Contacts of one large frame split into spatial domains over ``client``'s workers.

    The same :class:`FrameResult` as :func:`frame_contacts` (pairs, distances
    bit for bit), computed by :class:`granularsap.dask.DomainSearch`; the
    pairs are gathered in the calling process for the contacts file.

    Returns
    -------
    (FrameResult, DomainSearch)
    """
    from .. import dask as gdask

    t0 = time.perf_counter()
    common = dict(client=client, n_threads=params.n_threads)
    if params.cutoff is not None:
        search = gdask.DomainSearch(frame.positions, cutoff=params.cutoff,
                                    box=engine_cell(frame), **common)
    else:
        radii = frame.radius if frame.radius is not None else _radii(frame, params)
        labels = frame.molecule if params.clumps else None
        search = gdask.DomainSearch(frame.positions, radii=radii, skin=params.skin,
                                    clump_ids=labels, box=engine_cell(frame), **common)
    df = client.compute(search.pairs()).result()
    pairs = np.stack([df["i"].to_numpy(), df["j"].to_numpy()], axis=1).astype(np.int64)
    pairs = pairs.reshape(-1, 2)
    distances = df["distance"].to_numpy() if params.distances else None
    del df
    clump_pairs = None
    if params.clumps:
        mol = np.asarray(frame.molecule, dtype=np.int64)
        clump_pairs = np.sort(np.stack([mol[pairs[:, 0]], mol[pairs[:, 1]]], axis=1), axis=1)
        clump_pairs = (np.unique(clump_pairs, axis=0) if len(clump_pairs)
                       else np.empty((0, 2), np.int64))
    return _frame_result(frame, pairs, distances, clump_pairs, t0), search


def _domain_results(frames, params, client, threshold, on_plan):
    """Results of frames each split over the cluster; ``on_plan`` told once."""
    told = False
    for frame in frames:
        try:
            res, search = domain_frame_contacts(frame, params, client)
        except ValueError as exc:
            raise FrameError.of(frame, exc) from None
        if not told and on_plan is not None:
            k0, k1, k2 = search.grid
            on_plan(f"frame of {frame.n_particles} particles (>= {threshold}, the domain "
                    f"threshold): each frame is split into {search.n_domains} spatial "
                    f"domains ({k0}x{k1}x{k2}) over {search.n_workers} Dask workers")
            told = True
        yield res


def _dump_frame_atoms(path, offset):
    """``ITEM: NUMBER OF ATOMS`` of the dump frame starting at ``offset``, or None."""
    from .lammps_dump import open_dump

    try:
        with open_dump(path) as fh:
            fh.seek(offset)
            for _ in range(8):
                line = fh.readline()
                if not line:
                    return None
                if line.startswith(b"ITEM: NUMBER OF ATOMS"):
                    return int(fh.readline().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return None


def _prefetch(iterable, depth=2):
    """Iterate ``iterable`` in a background thread, ``depth`` items ahead.

    Reading the next frame (text parsing) overlaps the engine's work on the
    current one, which releases the GIL.  Exceptions are re-raised in order.
    """
    import queue
    import threading

    q = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def work():
        try:
            for item in iterable:
                while not stop.is_set():
                    try:
                        q.put((True, item), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put((True, done))
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            q.put((False, exc))

    thread = threading.Thread(target=work, name="granularsap-reader", daemon=True)
    thread.start()
    try:
        while True:
            ok, item = q.get()
            if not ok:
                raise item
            if item is done:
                return
            yield item
    finally:
        stop.set()


def _frames_text(frames: slice) -> str:
    return ":".join("" if v is None else str(v) for v in (frames.start, frames.stop, frames.step))


def dump_frame_contacts(path, offset, line, index, params: ContactParams) -> FrameResult:
    """Read frame ``index`` of a LAMMPS dump from its byte offset, then its contacts.

    The task a Dask worker runs when it can see the trajectory itself (local
    cluster): the client only ships four numbers per frame.
    """
    from .lammps_dump import iter_lammps_dump

    t0 = time.perf_counter()
    (frame,) = iter_lammps_dump(path, frames=slice(0, 1), start_at=(offset, line, index))
    frame = lean_frame(frame, params)
    read = time.perf_counter() - t0
    res = frame_contacts(frame, params, _worker_search(params))
    res.read_seconds = read
    return res


class _DaskRunner:
    """Submit frames to a dask.distributed cluster, hand results back in order."""

    def __init__(self, workers=None, scheduler=None, n_threads=None):
        from distributed import Client, LocalCluster

        self.cluster = None
        if scheduler is not None:
            self.client = Client(scheduler)
        else:
            # silence_logs: a task's error (a truncated dump) reaches the caller as the
            # run's one-line error; the workers' own "Compute Failed" log would print it
            # again on the terminal with a traceback.  dashboard_address ":0": a free
            # port (None means 8787, and a warning on stderr when a cluster holds it)
            self.cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1,
                                        processes=True, dashboard_address=":0",
                                        silence_logs=logging.CRITICAL)
            self.client = Client(self.cluster)
        n = len(self.client.nthreads()) or int(workers or 1)
        self.window = 2 * n + 1

    def map_ordered(self, frames, params):
        pending = collections.deque()
        for frame in frames:
            data = self.client.scatter(frame)
            pending.append(self.client.submit(worker_frame_contacts, data, params, pure=False))
            if len(pending) >= self.window:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()

    def map_dump(self, path, rows, params):
        """Workers read the frames themselves: rows are (offset, line, index)."""
        pending = collections.deque()
        for offset, line, index in rows:
            pending.append(self.client.submit(dump_frame_contacts, path, int(offset), int(line),
                                              int(index), params, pure=False))
            if len(pending) >= self.window:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()

    def close(self):
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def check_output(output, *, overwrite=False):
    """Refuse an output path that cannot be written, before any frame is computed.

    Raises
    ------
    IsADirectoryError
        ``output`` (or its ``.tmp`` twin) is a directory.
    FileExistsError
        ``output`` exists and ``overwrite`` is False.
    FileNotFoundError, PermissionError
        The directory that would hold ``output`` is missing or not writable.
    """
    output = os.fspath(output)
    if os.path.isdir(output):
        raise IsADirectoryError(f"output {output} is a directory; give a file name, e.g. "
                                f"{os.path.join(output, 'contacts.h5')}")
    if os.path.isdir(output + ".tmp"):
        raise IsADirectoryError(f"{output}.tmp is a directory; the contacts file is assembled "
                                "under that name: remove or rename it")
    if os.path.exists(output) and not overwrite:
        raise FileExistsError(f"{output} already exists; remove it or pass overwrite")
    parent = os.path.dirname(os.path.abspath(output))
    if not os.path.isdir(parent):
        raise FileNotFoundError(f"output directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"output directory {parent} is not writable")


def _nothing_selected(trajectory, format, topology, frames):
    """The error for a frame selection that matched no frame of a readable trajectory."""
    try:
        total = count_frames(trajectory, format, topology=topology)
    except Exception:  # noqa: BLE001 - only for the message
        total = None
    has = "" if total is None else f", which has {total} frame{'s' * (total != 1)}"
    return TrajectoryError(
        f"frames {_frames_text(frames)} selects no frame of {trajectory}{has} (read as "
        f"{describe_format(trajectory, format, topology)}; frames are numbered from 0)")


def _one_writer(func):
    """Run ``func(trajectory, output, ...)`` holding the exclusive lock of ``output``.

    The path checks come first (their messages beat a failed ``open`` of the
    lock file); ``func`` checks again under the lock, where an output that
    appeared meanwhile is final.
    """
    @functools.wraps(func)
    def locked(trajectory, output, *args, overwrite=False, on_warning=None, **kwargs):
        check_output(output, overwrite=overwrite)
        if os.path.isdir(lock_path(output)):
            raise IsADirectoryError(f"{lock_path(output)} is a directory; the run locks its "
                                    "output under that name: remove or rename it")
        with output_lock(output, on_warning=on_warning):
            return func(trajectory, output, *args, overwrite=overwrite, on_warning=on_warning,
                        **kwargs)
    return locked


@_one_writer
def compute_contacts(trajectory, output, params: ContactParams, *, format=None, topology=None,
                     frames=None, resume=True, overwrite=False, workers=None, scheduler=None,
                     progress=None, on_resume=None, commit_seconds=1.0, should_stop=None,
                     domain_particles=None, on_plan=None, on_warning=None):
    """Write the contacts of every selected frame of ``trajectory`` to ``output``.

    Parameters
    ----------
    trajectory : str or os.PathLike
    output : str or os.PathLike
        HDF5 file to write (schema in :mod:`granularsap.io.hdf5`).
    params : ContactParams
    format, topology
        See :func:`iter_frames`.
    frames : slice, optional
        Non-negative ``start:stop:step`` selection of trajectory frames.
    resume : bool
        Continue an interrupted run (``output + '.partial'``) with the same
        parameters instead of starting over.
    overwrite : bool
        Replace an existing complete ``output``.
    workers : int, optional
        Start a local Dask cluster with this many worker processes.
    scheduler : str, optional
        Address of an existing ``dask.distributed`` scheduler.
    progress : object with ``update(n)`` and a writable ``total``, optional
        Told about every frame written (e.g. a ``tqdm`` bar).
    on_resume : callable, optional
        Called with ``(n_frames_already_done, reason_or_None)`` after the
        partial file is examined.
    commit_seconds : float
        Make finished frames durable at least this often (0: after every frame).
    should_stop : callable, optional
        Checked after every frame written; when it returns True the run stops
        with ``KeyboardInterrupt`` after committing what it has (resumable).
    domain_particles : int, optional
        With ``workers`` or ``scheduler``: when the first selected frame has at
        least this many particles, every frame is split into spatial domains
        over all the workers (:mod:`granularsap.dask`) instead of one frame per
        worker.  Default :func:`domain_threshold` (environment variable
        ``GRANULARSAP_DOMAIN_PARTICLES``, else 2,000,000).
    on_plan : callable, optional
        Called once with a one-line description when frames are split into
        domains.
    on_warning : callable, optional
        Called with a one-line message about the results (a trajectory without
        particle ids whose rows do not follow particles); default
        :func:`warnings.warn`.

    Returns
    -------
    dict
        ``frames``, ``contacts``, ``seconds`` and a ``timing`` breakdown.

    Raises
    ------
    granularsap.io.TrajectoryError
        The trajectory is empty or not a trajectory, or ``frames`` selects none
        of its frames: nothing is written.
    IsADirectoryError, FileExistsError, FileNotFoundError, PermissionError
        ``output`` cannot be written (see :func:`check_output`); raised before
        any frame is read.
    OutputBusyError
        Another run is writing ``output`` (it holds ``output + '.lock'`` for
        its whole run); raised at once, before anything is read or written.
        The lock dies with its holder, so a killed run's partial state is
        resumed by the next run.
    """
    trajectory = os.fspath(trajectory)
    output = os.fspath(output)
    frames = slice(None) if frames is None else frames
    start, stop, step = frames.start or 0, frames.stop, frames.step or 1
    if start < 0 or (stop is not None and stop < 0) or step <= 0:
        raise ValueError(f"frames must be START:STOP:STEP with non-negative START/STOP and "
                         f"positive STEP, got {_frames_text(frames)}")
    if stop is not None and stop <= start:
        raise ValueError(f"frames {_frames_text(slice(start, stop, step))} selects no frame: "
                         "STOP must be greater than START")
    check_output(output, overwrite=overwrite)
    threshold = domain_threshold(domain_particles)
    if not os.path.exists(trajectory):
        raise FileNotFoundError(f"trajectory {trajectory!r} does not exist")
    backend, sub = resolve_format(trajectory, format, topology)
    described = {
        "source": os.path.abspath(trajectory),
        "source_size": os.path.getsize(trajectory),
        "source_format": backend if sub is None else f"{backend}:{sub}",
        "topology": None if topology is None else os.path.abspath(topology),
        "frames": _frames_text(slice(start, stop, step)),
        **params.describe(),
    }
    # (its size is in the parameters; a file rewritten at the same size differs here)
    writer = ContactsWriter(output, described, distances=params.distances,
                            clumps=params.clumps, resume=resume,
                            commit_seconds=commit_seconds,
                            source_stamp={"mtime_ns": os.stat(trajectory).st_mtime_ns})
    done = writer.n_frames
    if on_resume is not None:
        on_resume(done, writer.discarded_reason)
    timing = {"read": 0.0, "compute": 0.0, "write": 0.0}
    runner = None
    t_start = time.perf_counter()
    writer.track_timing(timing, t_start)
    n_contacts = n_new = 0
    try:
        if progress is not None:
            try:
                total = count_frames(trajectory, format, topology=topology)
            except Exception:  # noqa: BLE001 - a progress total is a nicety
                total = None
            if total is not None:
                end = total if stop is None else min(stop, total)
                progress.total = max(0, -(-(end - start) // step))
                progress.update(done)
        todo = slice(start + done * step, stop, step)
        source = iter_frames(trajectory, format, frames=todo, topology=topology)

        def timed_frames():
            while True:
                t0 = time.perf_counter()
                try:
                    frame = next(source)
                except StopIteration:
                    return
                frame = lean_frame(frame, params)
                timing["read"] += time.perf_counter() - t0
                yield frame

        frames_in = timed_frames()
        n_first = rows = None
        if workers is not None or scheduler is not None:
            # the first frame's size chooses between one frame per worker and
            # spatial domains over all the workers; workers read a dump themselves,
            # unless it is gzip-compressed (they could not seek in it cheaply)
            from .lammps_dump import dump_frame_index, is_gzip

            if backend == "lammps-dump" and not is_gzip(trajectory):

                offsets, lines = dump_frame_index(trajectory)
                rows = [(offsets[k], lines[k], k) for k in range(len(offsets))[todo]]
                n_first = _dump_frame_atoms(trajectory, int(rows[0][0])) if rows else None
            else:
                first = next(frames_in, None)
                if first is not None:
                    n_first = first.n_particles
                    frames_in = itertools.chain([first], frames_in)
        if workers is None and scheduler is None:
            search = FrameSearch(params)
            results = (frame_contacts(fr, params, search) for fr in _prefetch(frames_in))
        elif n_first is not None and n_first >= threshold:
            runner = _DaskRunner(workers=workers, scheduler=scheduler)
            results = _domain_results(_prefetch(frames_in, depth=1), params, runner.client,
                                      threshold, on_plan)
        elif rows is not None and scheduler is None:
            # local workers see the file: each reads its own frames from their byte offsets
            if len(offsets) == 0:  # not a dump, or nothing selected: the reader says which
                for _ in iter_frames(trajectory, format, frames=todo, topology=topology):
                    pass
            results = iter(())
            if rows:
                runner = _DaskRunner(workers=workers)
                results = runner.map_dump(trajectory, rows, params)
        else:
            runner = _DaskRunner(workers=workers, scheduler=scheduler)
            results = runner.map_ordered(frames_in, params)
        rows_told = False
        for res in results:
            timing["compute"] += res.seconds
            timing["read"] += res.read_seconds
            if not res.ids_given and not rows_told and writer.n_frames > 0:
                why = None
                if backend == "lammps-dump":
                    why = "LAMMPS reorders a dump's rows between steps (atom_modify sort)"
                elif writer.last_n_particles not in (None, res.n_particles):
                    why = f"particles come and go (frame {res.index} has {res.n_particles})"
                if why is not None:
                    (on_warning or _warn)(
                        f"{trajectory} has no particle ids: pairs hold row numbers and "
                        f"births/deaths compare rows, which misleads where {why}; the file "
                        f"records pair_index='row' (write an id column to follow particles)")
                    rows_told = True
            t0 = time.perf_counter()
            writer.append(res)
            timing["write"] += time.perf_counter() - t0
            n_contacts += len(res.pairs)
            n_new += 1
            if progress is not None:
                progress.update(1)
            if should_stop is not None and should_stop():
                raise KeyboardInterrupt
        if done + n_new == 0:
            raise _nothing_selected(trajectory, format, topology, slice(start, stop, step))
        timing["wall"] = time.perf_counter() - t_start
        timing["frames_this_run"] = n_new
        t0 = time.perf_counter()
        writer.finish(timing)
        timing["write"] += time.perf_counter() - t0
    except (DumpFormatError, FrameError) as exc:
        kept = writer.n_frames
        if not kept or exc.frame is None or exc.frame <= start:
            raise
        # the good frames are kept, but the same command would stop at the same frame
        sel = f"{start}:{exc.frame}" + (f":{step}" if step != 1 else "")
        advice = (f"; the {kept} good frames before it are kept in {partial_path(output)}, "
                  f"but running the same command again stops here again: to finish "
                  f"{output} without frame {exc.frame} and the frames after it, run it with "
                  f"--frames {sel} (Python: frames=slice({start}, {exc.frame}, {step})), "
                  "which resumes from them; or repair the trajectory")
        if isinstance(exc, FrameError):
            raise FrameError(exc.source, exc.frame, exc.step, exc.message + advice) from None
        raise DumpFormatError(exc.path, exc.frame, exc.line, exc.message + advice) from None
    finally:
        if runner is not None:
            runner.close()
        writer.close()
    return {"frames": done + n_new, "resumed_from": done, "contacts_this_run": n_contacts,
            "timing": timing, "output": output, "partial": partial_path(output)}
