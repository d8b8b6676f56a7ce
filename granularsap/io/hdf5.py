"""The contacts HDF5 file: schema, interruption-safe writer, reader.

Schema version 1 (also described in ``docs/io.md``; every name below is plain
HDF5, readable with h5py or any HDF5 tool, no granularsap needed)::

    /                        attributes
        format               "granularsap.contacts"
        schema_version       1
        granularsap_version  version that wrote the file
        complete             0 while being written, 1 once every frame is in
        n_frames             frames fully written (the only frames to trust)
        parameters           JSON: source, mode, cutoff/radius/skin, frames, ...
        pair_index           "id": pairs hold particle ids, not row numbers
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

Interruption safety: the file is written as ``OUT.h5.partial`` with
``complete = 0``; frames are committed in batches (about once a second):
the datasets are extended and flushed first, then ``n_frames`` is raised and
the file flushed again.  Only when every frame is in is
``complete`` set to 1, the file closed and atomically renamed to ``OUT.h5``.
So ``OUT.h5`` either does not exist or is complete; a ``.partial`` file is
resumed from its last complete frame (rows past ``n_frames`` are discarded).
"""

from __future__ import annotations

import datetime
import json
import os
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


def pair_difference(a, b):
    """Rows of sorted-unique pair array ``a`` that are not in ``b`` (both (k, 2) int64)."""
    if len(a) == 0 or len(b) == 0:
        return a.copy()
    top = int(max(a.max(), b.max())) + 1
    if top < 3_000_000_000:
        ka = a[:, 0] * top + a[:, 1]
        kb = b[:, 0] * top + b[:, 1]
        return a[~np.isin(ka, kb, assume_unique=True)]
    dt = np.dtype([("i", np.int64), ("j", np.int64)])  # pragma: no cover - huge ids
    va = np.ascontiguousarray(a).view(dt).ravel()
    vb = np.ascontiguousarray(b).view(dt).ravel()
    return a[~np.isin(va, vb)]


class ContactsWriter:
    """Append frames to a contacts file; see the module docstring for the schema.

    Parameters
    ----------
    path : str or os.PathLike
        Final name of the file (written as ``path + '.partial'`` until complete).
    parameters : dict
        JSON-serialisable description of the run; a resumed run must match it.
    distances : bool
        Store a distance for every pair.
    clumps : bool
        Store clump pairs too.
    resume : bool
        If a ``.partial`` file with the same parameters exists, continue it.
        Otherwise it is replaced.
    commit_seconds : float
        Queued frames are written and made durable (``n_frames`` raised,
        file flushed) at least this often; 0 commits every frame.  An
        interruption loses at most the frames queued since the last commit.

    Attributes
    ----------
    n_frames : int
        Frames in the file so far (after a resume, those already there).
    resumed : bool
    """

    def __init__(self, path, parameters, *, distances=False, clumps=False, resume=True,
                 commit_seconds=1.0):
        self.h5py = _h5py()
        self.path = os.fspath(path)
        self.tmp = partial_path(self.path)
        self.parameters = json.loads(json.dumps(parameters))
        self.distances = bool(distances)
        self.clumps = bool(clumps)
        self.resumed = False
        self.discarded_reason = None
        self._prev = None
        self.file = None
        self.commit_seconds = float(commit_seconds)
        self._buffer = []
        self._buffered_pairs = 0
        self._last_commit = time.monotonic()
        if resume and os.path.exists(self.tmp):
            self._try_resume()
        if self.file is None:
            self._create()

    # ---- setup
    def _create(self):
        h5 = self.h5py
        from .._version import __version__

        f = h5.File(self.tmp, "w")
        self.file = f
        f.attrs["format"] = FORMAT_NAME
        f.attrs["schema_version"] = SCHEMA_VERSION
        f.attrs["granularsap_version"] = __version__
        f.attrs["complete"] = np.int8(0)
        f.attrs["n_frames"] = np.int64(0)
        f.attrs["parameters"] = json.dumps(self.parameters, sort_keys=True)
        f.attrs["pair_index"] = "id"
        f.attrs["created"] = _now()
        f.attrs["timing"] = json.dumps({})
        g = f.create_group("frames")
        for name, (dtype, shape, _) in _PER_FRAME.items():
            g.create_dataset(name, shape=(0, *shape), maxshape=(None, *shape), dtype=dtype,
                             chunks=(1024, *shape), **_COMPRESSION)
        offsets = ["contact_offset", "born_offset", "died_offset"]
        if self.clumps:
            offsets.append("clump_offset")
        for name in offsets:
            g.create_dataset(name, data=np.zeros(1, np.int64), maxshape=(None,), chunks=(1024,),
                             **_COMPRESSION)
        pair_groups = [("contacts", "pairs"), ("events", "born"), ("events", "died")]
        if self.clumps:
            pair_groups.append(("clumps", "pairs"))
        for grp, name in pair_groups:
            f.require_group(grp).create_dataset(name, shape=(0, 2), maxshape=(None, 2),
                                                dtype=np.int64, chunks=(32768, 2), **_COMPRESSION)
        if self.distances:
            f["contacts"].create_dataset("distances", shape=(0,), maxshape=(None,),
                                         dtype=np.float64, chunks=(65536,), **_COMPRESSION)
        f.flush()
        self.n_frames = 0

    def _try_resume(self):
        h5 = self.h5py
        try:
            f = h5.File(self.tmp, "r+")
        except OSError as exc:  # an unreadable partial file: start over
            self.discarded_reason = f"unreadable partial file ({exc})"
            return
        try:
            old = json.loads(f.attrs.get("parameters", "null"))
            ok = (f.attrs.get("format") == FORMAT_NAME
                  and int(f.attrs.get("schema_version", -1)) == SCHEMA_VERSION
                  and old == self.parameters
                  and ("distances" in f["contacts"]) == self.distances
                  and ("clumps" in f) == self.clumps)
        except (KeyError, ValueError, OSError) as exc:
            ok = False
            self.discarded_reason = f"damaged partial file ({exc})"
        if not ok:
            f.close()
            self.discarded_reason = self.discarded_reason or "partial file from a different run"
            return
        n = int(f.attrs["n_frames"])
        g = f["frames"]
        for name in _PER_FRAME:
            g[name].resize(n, axis=0)
        for off, grp, name in self._offset_table():
            g[off].resize(n + 1, axis=0)
            f[grp][name].resize(int(g[off][n]), axis=0)
        if self.distances:
            f["contacts/distances"].resize(int(g["contact_offset"][n]), axis=0)
        f.flush()
        self.file = f
        self.n_frames = n
        self.resumed = True
        if n:
            lo, hi = g["contact_offset"][n - 1:n + 1]  # previous frame, for births/deaths
            self._prev = f["contacts/pairs"][lo:hi]

    def _offset_table(self):
        table = [("contact_offset", "contacts", "pairs"), ("born_offset", "events", "born"),
                 ("died_offset", "events", "died")]
        if self.clumps:
            table.append(("clump_offset", "clumps", "pairs"))
        return table

    @property
    def done_indices(self):
        """Trajectory frame numbers already in the file."""
        return self.file["frames/index"][: self.n_frames]

    # ---- writing
    @staticmethod
    def _extend(ds, arr):
        n = ds.shape[0]
        ds.resize(n + len(arr), axis=0)
        if len(arr):
            ds[n:] = arr
        return n + len(arr)

    def append(self, res: FrameResult):
        """Queue one frame; frames are committed in batches (see ``commit_seconds``)."""
        pairs = np.ascontiguousarray(res.pairs, dtype=np.int64).reshape(-1, 2)
        if self._prev is None:
            born = died = np.empty((0, 2), np.int64)
        else:
            born = pair_difference(pairs, self._prev)
            died = pair_difference(self._prev, pairs)
        self._prev = pairs
        self._buffer.append((res, pairs, born, died))
        self._buffered_pairs += len(pairs)
        if (time.monotonic() - self._last_commit >= self.commit_seconds
                or self._buffered_pairs >= 4_000_000):
            self.commit()

    def commit(self):
        """Write the queued frames, then raise ``n_frames`` and flush.

        Data first, the ``n_frames`` attribute last: rows past ``n_frames``
        (from a commit cut short) are ignored and dropped on resume.
        """
        self._last_commit = time.monotonic()
        if not self._buffer:
            return
        f = self.file
        g = f["frames"]
        n = self.n_frames
        batch = self._buffer
        m = len(batch)
        cols = {
            "index": [r.index for r, *_ in batch],
            "step": [-1 if r.step is None else r.step for r, *_ in batch],
            "time": [np.nan if r.time is None else r.time for r, *_ in batch],
            "n_particles": [r.n_particles for r, *_ in batch],
            "cell": [r.cell for r, *_ in batch],
            "pbc": [r.pbc for r, *_ in batch],
            "n_contacts": [len(p) for _, p, _, _ in batch],
            "n_born": [len(b) for _, _, b, _ in batch],
            "n_died": [len(d) for _, _, _, d in batch],
        }
        for name, values in cols.items():
            ds = g[name]
            ds.resize(n + m, axis=0)
            ds[n:n + m] = np.asarray(values, dtype=ds.dtype)
        blocks = {"contacts": 1, "born": 2, "died": 3}
        for off, grp, name in self._offset_table():
            if grp == "clumps":
                parts = [np.asarray(r.clump_pairs, dtype=np.int64).reshape(-1, 2)
                         for r, *_ in batch]
            else:
                k = blocks[grp if grp != "events" else name]
                parts = [item[k] for item in batch]
            ds = f[grp][name]
            base = ds.shape[0]
            ends = base + np.cumsum([len(p) for p in parts])
            self._extend(ds, np.concatenate(parts) if parts else np.empty((0, 2), np.int64))
            g[off].resize(n + m + 1, axis=0)
            g[off][n + 1:n + m + 1] = ends
        if self.distances:
            self._extend(f["contacts/distances"],
                         np.concatenate([np.asarray(r.distances, dtype=np.float64).ravel()
                                         for r, *_ in batch]))
        f.flush()
        f.attrs["n_frames"] = np.int64(n + m)  # these frames are trusted from here on
        f.flush()
        self.n_frames = n + m
        self._buffer = []
        self._buffered_pairs = 0

    def set_timing(self, timing: dict):
        self.file.attrs["timing"] = json.dumps(timing, sort_keys=True)

    def finish(self, timing=None):
        """Mark the file complete, close it and rename it to its final name."""
        self.commit()
        if timing is not None:
            self.set_timing(timing)
        self.file.attrs["finished"] = _now()
        self.file.attrs["complete"] = np.int8(1)
        self.file.flush()
        self.file.close()
        self.file = None
        os.replace(self.tmp, self.path)

    def close(self):
        """Close without marking complete (the ``.partial`` file stays resumable)."""
        if self.file is not None:
            try:
                self.commit()
                self.file.flush()
            finally:
                self.file.close()
                self.file = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


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
        self.file = h5.File(path, "r")
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
