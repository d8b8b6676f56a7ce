"""The contacts HDF5 file: schema, interruption-safe writer, reader.

Schema version 1 (also described in README.md; every name below is plain
HDF5, readable with h5py or any HDF5 tool, no granularsap needed)::

    /                        attributes
        format               "granularsap.contacts"
        schema_version       1
        granularsap_version  version that wrote the file
        complete             0 while being written, 1 once every frame is in
        n_frames             frames fully written (the only frames to trust)
        parameters           JSON: source, mode, cutoff/radius/skin, frames, ...
        pair_index           "id": pairs hold particle ids; "row": the trajectory
                             has no ids, pairs hold row numbers (LAMMPS: 1..n,
                             ASE: 0..n-1), and births/deaths compare rows
        created, finished    UTC ISO-8601 times
        timing               JSON: seconds reading / computing / writing
    /frames/index            (F,)   int64    frame number in the trajectory
    /frames/step             (F,)   int64    timestep (-1 if the file has none)
    /frames/time             (F,)   float64  time (NaN if the file has none)
    /frames/n_particles      (F,)   int64
    /frames/cell             (F,3,3) float64 cell vectors as rows (NaN: no box)
    /frames/pbc              (F,3)  bool
    /frames/n_contacts       (F,)   int64
    /frames/contact_offset   (F+1,) int64    frame f is pairs[offset[f]:offset[f+1]]
    /frames/n_born, n_died   (F,)   int64
    /frames/born_offset      (F+1,) int64    into /events/born
    /frames/died_offset      (F+1,) int64    into /events/died
    /contacts/pairs          (K,2)  int64    particle ids, id_i < id_j, rows sorted
    /contacts/distances      (K,)   float64  only if distances were requested
    /events/born             (B,2)  int64    pairs in frame f but not in frame f-1
    /events/died             (D,2)  int64    pairs in frame f-1 but not in frame f
    /clumps/pairs            (C,2)  int64    clump ids (--clumps only)
    /frames/clump_offset     (F+1,) int64    into /clumps/pairs (--clumps only)

Frame 0 of a file has no births or deaths (there is no previous frame).

Interruption safety: nothing is written under the name ``OUT.h5`` until the
run is over.  While it runs, finished frames are committed (about once a
second) as immutable segment files ``OUT.h5.partial/seg-NNNNNN.h5``, each
written under a temporary name and renamed atomically, next to ``run.json``
(the parameters).  A kill, a crash or Ctrl-C loses at most the frames since
the last commit and never damages committed ones; running the same command
again resumes after the last committed frame.  At the end the segments are
assembled into ``OUT.h5.tmp``, ``complete`` is set to 1 last, and the file is
renamed to ``OUT.h5``.  So ``OUT.h5`` either does not exist or is complete,
with at least one frame (``finish`` refuses a run without frames).
(HDF5 itself cannot survive a kill in the middle of rewriting a compressed
chunk, which is why a growing HDF5 file is not used for this.)
"""

from __future__ import annotations

import datetime
import json
import os
import shutil
import time
from dataclasses import dataclass

import numpy as np

__all__ = ["SCHEMA_VERSION", "ContactsFile", "ContactsWriter", "FrameResult",
           "IncompleteFileError", "partial_path", "read_contacts"]

FORMAT_NAME = "granularsap.contacts"
SCHEMA_VERSION = 1
_COMPRESSION = {"compression": "gzip", "compression_opts": 1, "shuffle": True}
_PER_FRAME = {  # name -> (dtype, trailing shape, fill)
    "index": (np.int64, (), None),
    "step": (np.int64, (), None),
    "time": (np.float64, (), None),
    "n_particles": (np.int64, (), None),
    "cell": (np.float64, (3, 3), None),
    "pbc": (np.bool_, (3,), None),
    "n_contacts": (np.int64, (), None),
    "n_born": (np.int64, (), None),
    "n_died": (np.int64, (), None),
}


class IncompleteFileError(OSError):
    """The contacts file is incomplete (an interrupted run): resume it or rerun."""


def partial_path(path) -> str:
    """Name under which ``path`` is written until it is complete."""
    return os.fspath(path) + ".partial"


def _h5py():
    try:
        import h5py
    except ImportError as exc:  # pragma: no cover - h5py is in the io extra
        raise ImportError("writing contacts needs h5py: pip install 'granularsap[io]'") from exc
    return h5py


def _now():
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


@dataclass
class FrameResult:
    """Contacts of one frame, as computed by a worker and written by the writer."""

    index: int
    step: int
    time: float
    n_particles: int
    cell: np.ndarray          # (3, 3), NaN when no box
    pbc: np.ndarray           # (3,) bool
    pairs: np.ndarray         # (k, 2) int64 particle ids, sorted
    distances: np.ndarray | None = None
    clump_pairs: np.ndarray | None = None
    seconds: float = 0.0
    read_seconds: float = 0.0
    ids_given: bool = True    # False: pairs hold row numbers (the file has no ids)


def pair_difference(a, b):
    """Rows of sorted-unique pair array ``a`` that are not in ``b`` (both (k, 2) int64)."""
    if len(a) == 0 or len(b) == 0:
        return a.copy()
    top = int(max(a.max(), b.max())) + 1
    if top < 3_000_000_000:
        ka = a[:, 0] * top + a[:, 1]
        kb = b[:, 0] * top + b[:, 1]
        if np.all(kb[1:] > kb[:-1]):  # rows sorted (as written): binary search, no sort
            at = np.minimum(np.searchsorted(kb, ka), len(kb) - 1)
            return a[kb[at] != ka]
        return a[~np.isin(ka, kb, assume_unique=True)]
    dt = np.dtype([("i", np.int64), ("j", np.int64)])  # pragma: no cover - huge ids
    va = np.ascontiguousarray(a).view(dt).ravel()
    vb = np.ascontiguousarray(b).view(dt).ravel()
    return a[~np.isin(va, vb)]


def _block_from_frames(batch, *, distances, clumps):
    """Arrays of the schema (offsets local, from 0) for a list of queued frames."""
    block = {
        "frames/index": np.array([r.index for r, *_ in batch], dtype=np.int64),
        "frames/step": np.array([-1 if r.step is None else r.step for r, *_ in batch],
                                dtype=np.int64),
        "frames/time": np.array([np.nan if r.time is None else r.time for r, *_ in batch],
                                dtype=np.float64),
        "frames/n_particles": np.array([r.n_particles for r, *_ in batch], dtype=np.int64),
        "frames/cell": np.array([r.cell for r, *_ in batch], dtype=np.float64).reshape(-1, 3, 3),
        "frames/pbc": np.array([r.pbc for r, *_ in batch], dtype=bool).reshape(-1, 3),
        "frames/n_contacts": np.array([len(p) for _, p, _, _ in batch], dtype=np.int64),
        "frames/n_born": np.array([len(b) for _, _, b, _ in batch], dtype=np.int64),
        "frames/n_died": np.array([len(d) for _, _, _, d in batch], dtype=np.int64),
    }

    def stack(parts, name, off):
        block[name] = (np.concatenate(parts) if parts
                       else np.empty((0, 2), np.int64)).astype(np.int64).reshape(-1, 2)
        block[f"frames/{off}"] = np.concatenate([[0], np.cumsum([len(x) for x in parts],
                                                                dtype=np.int64)])

    stack([p for _, p, _, _ in batch], "contacts/pairs", "contact_offset")
    stack([b for _, _, b, _ in batch], "events/born", "born_offset")
    stack([d for _, _, _, d in batch], "events/died", "died_offset")
    if clumps:
        stack([np.asarray(r.clump_pairs, dtype=np.int64).reshape(-1, 2) for r, *_ in batch],
              "clumps/pairs", "clump_offset")
    if distances:
        block["contacts/distances"] = np.concatenate(
            [np.asarray(r.distances, dtype=np.float64).ravel() for r, *_ in batch]
            or [np.empty(0)])
    return block


def _write_block(f, block):
    for name, data in block.items():
        rows = max(1, min(len(data), 65536 if data.ndim == 1 else 32768))
        f.create_dataset(name, data=data, maxshape=(None, *data.shape[1:]),
                         chunks=(rows, *data.shape[1:]), **_COMPRESSION)


def _assemble(h5py, paths, target, empty_block):
    """Copy segment files into ``target`` one segment at a time (bounded memory).

    Offsets are re-based as they are copied; data sets get their final sizes
    up front.  With no segments, ``empty_block`` gives the (empty) layout.
    """
    if not paths:
        _write_block(target, empty_block)
        return 0
    totals, dtypes = {}, {}
    for path in paths:
        with h5py.File(path, "r") as f:
            def visit(name, obj):
                if hasattr(obj, "shape"):
                    n = obj.shape[0] - (1 if name.endswith("_offset") else 0)
                    totals[name] = totals.get(name, 0) + n
                    dtypes[name] = (obj.dtype, obj.shape[1:])
            f.visititems(visit)
    for name, n in totals.items():
        dtype, tail = dtypes[name]
        n += 1 if name.endswith("_offset") else 0
        rows = max(1, min(n, 65536 if not tail else 32768))
        target.create_dataset(name, shape=(n, *tail), dtype=dtype, maxshape=(None, *tail),
                              chunks=(rows, *tail), **_COMPRESSION)
    pos = dict.fromkeys(totals, 0)
    base = {}
    n_frames = 0
    for path in paths:
        with h5py.File(path, "r") as f:
            for name in totals:
                data = f[name][()]
                if name.endswith("_offset"):
                    b = base.get(name, 0)
                    if pos[name] == 0:
                        target[name][0] = 0
                    target[name][pos[name] + 1:pos[name] + len(data)] = data[1:] + b
                    base[name] = b + int(data[-1])
                    pos[name] += len(data) - 1
                else:
                    target[name][pos[name]:pos[name] + len(data)] = data
                    pos[name] += len(data)
            n_frames += len(f["frames/index"])
    return n_frames


class ContactsWriter:
    """Write frames to a contacts file; see the module docstring for the schema.

    Frames are queued and committed in batches: each commit writes one
    immutable segment file ``OUT.h5.partial/seg-NNNNNN.h5`` under a temporary
    name and renames it atomically, so a killed run loses at most the frames
    queued since the last commit, and never damages what was committed.
    :meth:`finish` assembles the segments into ``OUT.h5.tmp``, marks it
    complete and renames it to ``OUT.h5``.

    Parameters
    ----------
    path : str or os.PathLike
        Final name of the file.
    parameters : dict
        JSON-serialisable description of the run; a resumed run must match it.
    distances : bool
        Store a distance for every pair.
    clumps : bool
        Store clump pairs too.
    resume : bool
        If ``path + '.partial'`` holds segments of a run with the same
        parameters, continue after its last committed frame; otherwise start over.
    commit_seconds : float
        Commit queued frames at least this often (0: after every frame).

    Attributes
    ----------
    n_frames : int
        Frames committed or queued so far (after a resume, those already there).
    resumed : bool
    discarded_reason : str or None
        Why an existing partial run was not resumed.
    """

    def __init__(self, path, parameters, *, distances=False, clumps=False, resume=True,
                 commit_seconds=1.0, source_stamp=None):
        self.h5py = _h5py()
        self.path = os.fspath(path)
        self.tmp = partial_path(self.path)
        self.parameters = json.loads(json.dumps(parameters))
        self.source_stamp = None if source_stamp is None else json.loads(json.dumps(
            source_stamp))
        self.distances = bool(distances)
        self.clumps = bool(clumps)
        self.commit_seconds = float(commit_seconds)
        self.resumed = False
        self.discarded_reason = None
        self._prev = None
        self.last_n_particles = None
        self._buffer = []
        self._buffered_pairs = 0
        self._last_commit = time.monotonic()
        self._segments = []   # (file name, frame indices)
        self.n_frames = 0
        self._timing = {}
        self._earlier = {}    # seconds of the earlier runs of a resumed file (their segments)
        self._live = None     # (this run's timing dict, its start) to split among segments
        self._committed = {}  # this run's seconds up to its last segment
        if resume and os.path.exists(self.tmp):
            self._try_resume()
        if not self.resumed:
            self._create()

    def _run_info(self):
        from .._version import __version__

        return {"format": FORMAT_NAME, "schema_version": SCHEMA_VERSION,
                "granularsap_version": __version__, "parameters": self.parameters,
                "distances": self.distances, "clumps": self.clumps, "created": _now(),
                "source_stamp": self.source_stamp}

    def _create(self):
        if os.path.isdir(self.tmp):
            shutil.rmtree(self.tmp)
        elif os.path.exists(self.tmp):
            os.remove(self.tmp)
        os.makedirs(self.tmp)
        self.info = self._run_info()
        _atomic_write_text(os.path.join(self.tmp, "run.json"), json.dumps(self.info, indent=1))

    def _try_resume(self):
        try:
            with open(os.path.join(self.tmp, "run.json")) as fh:
                info = json.load(fh)
        except (OSError, ValueError) as exc:
            self.discarded_reason = f"unreadable partial run ({exc})"
            return
        mine = self._run_info()
        same = all(info.get(k) == mine[k] for k in ("format", "schema_version", "distances",
                                                     "clumps"))
        old, new = dict(info.get("parameters") or {}), dict(mine["parameters"])
        old_frames, new_frames = old.pop("frames", None), new.pop("frames", None)
        if not same or old != new:
            self.discarded_reason = "partial run with different parameters"
            return
        if info.get("source_stamp") != mine["source_stamp"]:
            # the same size, but written again since (another run of the simulation)
            self.discarded_reason = "partial run of a trajectory modified since"
            return
        segments, last, rows = _list_segments(self.tmp, self.h5py)
        if old_frames != new_frames:
            # another STOP only (a run cut short by a damaged frame, finished without it):
            # the committed frames are the first ones of the new selection too
            done = np.concatenate([idx for _, idx in segments]) if segments else []
            if not _same_prefix(old_frames, new_frames, done):
                self.discarded_reason = "partial run with different parameters"
                return
            info["parameters"] = mine["parameters"]
            _atomic_write_text(os.path.join(self.tmp, "run.json"), json.dumps(info, indent=1))
        if rows:
            info["pair_index"] = "row"
        self.info = info
        self._earlier = _segment_timing(self.tmp, segments, self.h5py)
        self._segments = segments
        self.n_frames = sum(len(idx) for _, idx in segments)
        self._prev = last
        self.resumed = True

    @property
    def done_indices(self):
        """Trajectory frame numbers already committed."""
        if not self._segments:
            return np.empty(0, np.int64)
        return np.concatenate([idx for _, idx in self._segments])

    def append(self, res: FrameResult):
        """Queue one frame (births/deaths against the previous one); commit if it is time."""
        pairs = np.ascontiguousarray(res.pairs, dtype=np.int64).reshape(-1, 2)
        if self._prev is None:
            born = died = np.empty((0, 2), np.int64)
        else:
            born = pair_difference(pairs, self._prev)
            died = pair_difference(self._prev, pairs)
        self._prev = pairs
        self.last_n_particles = res.n_particles
        if not res.ids_given:
            self.info["pair_index"] = "row"
        self._buffer.append((res, pairs, born, died))
        self._buffered_pairs += len(pairs)
        self.n_frames += 1
        if (time.monotonic() - self._last_commit >= self.commit_seconds
                or self._buffered_pairs >= 4_000_000):
            self.commit()

    def commit(self):
        """Write the queued frames as one segment: temporary name, then atomic rename."""
        self._last_commit = time.monotonic()
        if not self._buffer:
            return
        block = _block_from_frames(self._buffer, distances=self.distances, clumps=self.clumps)
        name = f"seg-{len(self._segments):06d}.h5"
        final = os.path.join(self.tmp, name)
        tmp = final + ".tmp"
        with self.h5py.File(tmp, "w") as f:
            f.attrs["format"] = FORMAT_NAME + ".segment"  # never mistaken for a contacts file
            f.attrs["pair_index"] = self.info.get("pair_index", "id")
            f.attrs["complete"] = np.int8(0)
            f.attrs["n_frames"] = np.int64(len(self._buffer))
            f.attrs["timing"] = json.dumps(self._timing_delta(), sort_keys=True)
            _write_block(f, block)
        _fsync_path(tmp)
        os.replace(tmp, final)
        self._segments.append((name, block["frames/index"]))
        self._buffer = []
        self._buffered_pairs = 0

    def set_timing(self, timing: dict):
        self._timing = dict(timing)

    def track_timing(self, timing: dict, started: float):
        """Follow this run's ``timing`` (read/compute/write seconds, updated in place) and
        its start (``time.perf_counter()``): every segment records the seconds spent since
        the previous one, so that a resumed file's ``timing`` counts every run."""
        self._live = (timing, started)

    def _timing_now(self):
        if self._live is None:
            return {}
        timing, started = self._live
        now = {k: float(timing.get(k, 0.0)) for k in _TIMED}
        now["wall"] = time.perf_counter() - started
        return now

    def _timing_delta(self):
        now = self._timing_now()
        delta = {k: v - self._committed.get(k, 0.0) for k, v in now.items()}
        self._committed = now
        delta["run"] = int(self._earlier.get("runs", 0))  # which run wrote the segment
        return delta

    def finish(self, timing=None):
        """Assemble the segments into the final file, mark it complete, rename it.

        The file's ``timing`` is ``timing`` (this run) plus the seconds of the
        earlier runs of a resumed file; ``runs`` counts them.

        Raises
        ------
        ValueError
            No frame was appended (nor resumed): a contacts file marked complete
            holds at least one frame, so nothing is written, and the empty
            partial run is removed.
        """
        if self.n_frames == 0:
            self.close()  # removes the empty partial run
            raise ValueError(
                f"ContactsWriter.finish(): no frame was appended, so {self.path} was not "
                "written (a contacts file marked complete holds at least one frame); "
                "append() frames before finish(), or close() to drop the run")
        if timing is not None:
            self.set_timing(timing)
        self.commit()
        if self._timing:
            total = dict(self._timing)
            for k in (*_TIMED, "wall"):
                if k in total or k in self._earlier:
                    total[k] = float(total.get(k, 0.0)) + self._earlier.get(k, 0.0)
            total["runs"] = int(self._earlier.get("runs", 0)) + 1
            self._timing = total
        paths = [os.path.join(self.tmp, name) for name, _ in self._segments]
        tmp = self.path + ".tmp"
        if os.path.isfile(tmp):  # left by a run killed while assembling: never trusted
            os.remove(tmp)
        with self.h5py.File(tmp, "w") as f:
            _write_header(f, self.info, self.n_frames, complete=False)
            _assemble(self.h5py, paths, f,
                      _block_from_frames([], distances=self.distances, clumps=self.clumps))
            f.attrs["timing"] = json.dumps(self._timing, sort_keys=True)
            f.attrs["finished"] = _now()
            f.flush()
            f.attrs["complete"] = np.int8(1)  # written last
        _fsync_path(tmp)
        os.replace(tmp, self.path)
        shutil.rmtree(self.tmp, ignore_errors=True)

    def close(self):
        """Commit what is queued (the partial run stays resumable; empty ones are removed)."""
        self.commit()
        if not self._segments and os.path.isdir(self.tmp):
            shutil.rmtree(self.tmp, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _write_header(f, info, n_frames, *, complete):
    f.attrs["format"] = FORMAT_NAME
    f.attrs["schema_version"] = SCHEMA_VERSION
    f.attrs["granularsap_version"] = info["granularsap_version"]
    f.attrs["complete"] = np.int8(1 if complete else 0)
    f.attrs["n_frames"] = np.int64(n_frames)
    f.attrs["parameters"] = json.dumps(info["parameters"], sort_keys=True)
    f.attrs["pair_index"] = info.get("pair_index", "id")
    f.attrs["created"] = info["created"]
    f.attrs["timing"] = json.dumps({})


def _atomic_write_text(path, text):
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _fsync_path(path):
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


_TIMED = ("read", "compute", "write")


def _same_prefix(old_frames, new_frames, done):
    """True if the frames ``done`` of selection ``old_frames`` ("START:STOP:STEP") are the
    first frames of ``new_frames`` too (same START and STEP, every one before its STOP)."""
    def parts(text):
        try:
            vals = [int(v) if v else None for v in str(text).split(":")]
        except ValueError:
            return None
        return vals if len(vals) == 3 else None

    a, b = parts(old_frames), parts(new_frames)
    if a is None or b is None or (a[0] or 0, a[2] or 1) != (b[0] or 0, b[2] or 1):
        return False
    return b[1] is None or all(int(i) < b[1] for i in done)


def _segment_timing(directory, segments, h5py):
    """Seconds recorded by the committed segments (the earlier runs), and how many runs
    wrote them (``runs``)."""
    total, runs = {}, set()
    for name, _ in segments:
        with h5py.File(os.path.join(directory, name), "r") as f:
            seg = json.loads(f.attrs.get("timing", "{}"))
        runs.add(int(seg.pop("run", 0)))
        for k, v in seg.items():
            total[k] = total.get(k, 0.0) + float(v)
    total["runs"] = len(runs)
    return total


def _list_segments(directory, h5py):
    """Committed segments in order (stray temporaries removed) and the last frame's pairs."""
    names = sorted(n for n in os.listdir(directory) if n.startswith("seg-"))
    segments, last = [], None
    for n in names:
        if not n.endswith(".h5"):
            os.remove(os.path.join(directory, n))  # a commit cut short
            continue
        if n != f"seg-{len(segments):06d}.h5":
            break
        with h5py.File(os.path.join(directory, n), "r") as f:
            idx = f["frames/index"][()]
            off = f["frames/contact_offset"][-2:]
            rows = f.attrs.get("pair_index", "id") == "row"
            if len(idx):
                last = f["contacts/pairs"][off[0]:off[1]]
        segments.append((n, idx, rows))
    return [(n, idx) for n, idx, _ in segments], last, any(r for _, _, r in segments)


def _assemble_in_memory(directory, h5py):
    """A read-only in-memory contacts file of a partial run (for ContactsFile)."""
    with open(os.path.join(directory, "run.json")) as fh:
        info = json.load(fh)
    names = sorted(n for n in os.listdir(directory)
                   if n.startswith("seg-") and n.endswith(".h5"))
    f = h5py.File(f"partial-{id(names)}.h5", "w", driver="core", backing_store=False)
    for n in names:
        with h5py.File(os.path.join(directory, n), "r") as seg:
            if seg.attrs.get("pair_index", "id") == "row":
                info["pair_index"] = "row"
    _write_header(f, info, 0, complete=False)
    n_frames = _assemble(h5py, [os.path.join(directory, n) for n in names], f,
                         _block_from_frames([], distances=info["distances"],
                                            clumps=info["clumps"]))
    f.attrs["n_frames"] = np.int64(n_frames)
    return f


class ContactsFile:
    """Read a contacts file (complete or not).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.h5`` file, or its ``.partial`` twin.
    allow_incomplete : bool
        If False (default), an incomplete file raises :class:`IncompleteFileError`.

    Examples
    --------
    >>> with ContactsFile("out.h5") as cf:                  # doctest: +SKIP
    ...     for f in range(cf.n_frames):
    ...         ids = cf.pairs(f)    # (k, 2) particle ids
    """

    def __init__(self, path, *, allow_incomplete=False):
        h5 = _h5py()
        path = os.fspath(path)
        if not os.path.exists(path) and os.path.exists(partial_path(path)):
            if not allow_incomplete:
                raise IncompleteFileError(
                    f"{path} does not exist but {partial_path(path)} does: the run was "
                    "interrupted; rerun the same command to resume it")
            path = partial_path(path)
        self.path = path
        if os.path.isdir(path):  # an interrupted run: its committed segments
            if not os.path.exists(os.path.join(path, "run.json")):
                raise ValueError(f"{path} is a directory, not a granularsap contacts file "
                                 "(nor the .partial directory of an interrupted run)")
            if not allow_incomplete:
                raise IncompleteFileError(f"{path} is an interrupted run: rerun the same "
                                          "command to resume it")
            self.file = _assemble_in_memory(path, h5)
        else:
            if not h5.is_hdf5(path):
                size = os.path.getsize(path)
                raise ValueError(f"{path} is not a granularsap contacts file: not an HDF5 file "
                                 f"({'empty' if size == 0 else f'{size} bytes'}); contacts "
                                 "files are written by `granularsap contacts`")
            try:
                self.file = h5.File(path, "r")
            except OSError as exc:  # an HDF5 signature, then a torn or cut file
                torn = (" (the torn assembly file of an interrupted run: rerun the same "
                        "command)" if path.endswith(".h5.tmp") else "")
                raise ValueError(f"{path} is not a readable granularsap contacts file: a "
                                 f"damaged HDF5 file ({exc}){torn}") from None
        attrs = self.file.attrs
        if attrs.get("format") != FORMAT_NAME:
            self.file.close()
            raise ValueError(f"{path} is not a granularsap contacts file "
                             f"(format attribute {attrs.get('format')!r})")
        version = int(attrs["schema_version"])
        if version > SCHEMA_VERSION:
            self.file.close()
            raise ValueError(f"{path} has schema version {version}; this granularsap reads "
                             f"up to {SCHEMA_VERSION}: upgrade granularsap")
        self.complete = bool(attrs["complete"])
        if not self.complete and not allow_incomplete:
            n_done = int(attrs["n_frames"])
            self.file.close()
            raise IncompleteFileError(f"{path} is incomplete ({n_done} frames "
                                      "written): rerun the same command to resume it")
        self.n_frames = int(attrs["n_frames"])
        self.schema_version = version
        self.parameters = json.loads(attrs["parameters"])
        self.timing = json.loads(attrs.get("timing", "{}"))
        self.granularsap_version = str(attrs["granularsap_version"])

    def _col(self, name):
        return self.file["frames"][name][: self.n_frames]

    def __getattr__(self, name):
        if name in _PER_FRAME:
            return self._col(name)
        raise AttributeError(name)

    def _block(self, off, ds, f):
        if not 0 <= f < self.n_frames:
            raise IndexError(f"frame {f} out of range for {self.n_frames} frames")
        lo, hi = self.file["frames"][off][f:f + 2]
        return self.file[ds][lo:hi]

    def pairs(self, f):
        """(k, 2) int64 particle-id pairs of file frame ``f``."""
        return self._block("contact_offset", "contacts/pairs", f)

    def distances(self, f):
        if "distances" not in self.file["contacts"]:
            raise KeyError(f"{self.path} has no distances (run with --distances)")
        return self._block("contact_offset", "contacts/distances", f)

    def born(self, f):
        return self._block("born_offset", "events/born", f)

    def died(self, f):
        return self._block("died_offset", "events/died", f)

    def clump_pairs(self, f):
        if "clumps" not in self.file:
            raise KeyError(f"{self.path} has no clump pairs (run with --clumps)")
        return self._block("clump_offset", "clumps/pairs", f)

    def close(self):
        self.file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def read_contacts(path, *, allow_incomplete=False):
    """Every frame's contact pairs as a list of (k, 2) int64 arrays of particle ids."""
    with ContactsFile(path, allow_incomplete=allow_incomplete) as cf:
        off = cf.file["frames/contact_offset"][: cf.n_frames + 1]
        allpairs = cf.file["contacts/pairs"][: off[-1]]
        return [allpairs[off[k]:off[k + 1]] for k in range(cf.n_frames)]
