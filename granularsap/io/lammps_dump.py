"""Reader for LAMMPS text dumps (``dump atom`` / ``dump custom``).

Why our own reader: ASE's ``lammpsrun`` reader parses every line in Python
and keeps no radius/diameter or molecule column in a form we can rely on;
MDAnalysis's ``LAMMPSDUMP`` reader wants a separate topology for types and
radii, loads extra columns only on request, and stops at a truncated frame
without saying which line was bad.  This reader streams frame by frame (one
``numpy.loadtxt`` call per frame), keeps every column by name, reports rows in
id order, and on a truncated or corrupt frame raises :class:`DumpFormatError`
naming the file, the frame and the line, after yielding every good frame.

Supported headers: ``ITEM: TIMESTEP``, ``ITEM: TIME``, ``ITEM: UNITS``,
``ITEM: NUMBER OF ATOMS``, ``ITEM: BOX BOUNDS [xy xz yz] bx by bz`` (orthogonal
and restricted triclinic) and ``ITEM: BOX BOUNDS abc origin ...`` (general
triclinic), ``ITEM: ATOMS col1 col2 ...`` in any column order.  Coordinates
come from ``x y z`` (as written), ``xu yu zu`` (unwrapped), ``xs ys zs``
(scaled) or ``xsu ysu zsu`` (scaled unwrapped), preferred in that order
unless ``coordinates=`` says otherwise.
"""

from __future__ import annotations

import gzip
import io
import os
import re

import numpy as np

from ..cell import lammps_pbc
from ._frame import Frame

__all__ = ["DumpFormatError", "count_dump_frames", "iter_lammps_dump", "open_dump"]

COORDINATE_SETS = {
    "x": ("x", "y", "z"),
    "xu": ("xu", "yu", "zu"),
    "xs": ("xs", "ys", "zs"),
    "xsu": ("xsu", "ysu", "zsu"),
}
_SCALED = {"xs", "xsu"}
_INT_COLUMNS = {"id", "type", "mol", "molecule", "ix", "iy", "iz", "proc", "procp1"}


class DumpFormatError(ValueError):
    """A LAMMPS dump is truncated or malformed; the message names file, frame and line."""

    def __init__(self, path, frame, line, message):
        self.path, self.frame, self.line, self.message = path, frame, line, message
        super().__init__(f"{path}: frame {frame}, line {line}: {message}")

    def __reduce__(self):  # survives pickling (errors raised on Dask workers)
        return (type(self), (self.path, self.frame, self.line, self.message))


def is_gzip(path) -> bool:
    """True if ``path`` starts with the gzip magic bytes."""
    with open(path, "rb") as fh:
        return fh.read(2) == b"\x1f\x8b"


def open_dump(path):
    """Open a dump for binary reading; a gzip-compressed one (``dump custom/gz``,
    ``*.dump.gz``, found by its magic bytes) is decompressed on the fly."""
    return gzip.open(path, "rb") if is_gzip(path) else open(path, "rb")


def _chunks(fh, size=1 << 24):
    """The file's bytes in chunks; a cut gzip stream ends where its data does (the
    reader, not a byte scan, reports it as truncated)."""
    read = fh.read1 if isinstance(fh, gzip.GzipFile) else fh.read  # read1: keep data before a cut
    while True:
        try:
            chunk = read(size)
        except EOFError:
            return
        if not chunk:
            return
        yield chunk


def count_dump_frames(path) -> int:
    """Number of ``ITEM: TIMESTEP`` headers in a dump (a fast byte scan)."""
    count = 0
    tail = b""
    key = b"ITEM: TIMESTEP"
    with open_dump(path) as fh:
        for chunk in _chunks(fh):
            buf = tail + chunk
            count += buf.count(key)
            tail = buf[-(len(key) - 1):]
            count -= tail.count(key)  # never double count across chunks
    return count


class _Lines:
    """Line source that counts 1-based line numbers."""

    def __init__(self, fh):
        self.fh = fh
        self.lineno = 0
        self.cut = False  # a gzip stream that ends before its end marker

    def _readline(self):
        try:
            return self.fh.readline()
        except EOFError:
            self.cut = True
            return ""

    def next(self):
        line = self._readline()
        if not line:
            return None
        self.lineno += 1
        return line

    def take(self, n):
        lines = []
        for _ in range(n):
            line = self._readline()
            if not line:
                break
            lines.append(line)
        self.lineno += len(lines)
        return lines


def _lammps_cell(bounds, tilt, general):
    """(cell rows, origin) from the three BOX BOUNDS lines (through ``Cell``)."""
    from ..cell import Cell

    if general:
        rows = np.array(bounds, dtype=np.float64)  # ax ay az ox / bx by bz oy / cx cy cz oz
        cell = Cell(rows[:, :3], False, origin=rows[:, 3])
    else:
        cell = Cell.from_lammps(bounds, tilt, "ff ff ff")
    return np.array(cell.matrix), np.array(cell.origin)


def _parse_atoms(lines, ncol, path, frame, first_line):
    """Parse atom rows into an (n, ncol) float array and a list of string columns."""
    if not lines:  # a frame with no atoms (a pour before its first insertion, all lost)
        return np.empty((0, ncol), dtype=np.float64), None
    try:
        data = np.loadtxt(lines, dtype=np.float64, ndmin=2, comments=None)
    except ValueError:
        data = None
    if data is not None and data.shape == (len(lines), ncol):  # (loadtxt skips blank lines)
        return data, None
    # slow path: locate the bad row, or fall back to string columns
    rows = []
    for k, line in enumerate(lines):
        if line.startswith("ITEM:"):  # the next item: this frame has fewer rows than it says
            raise DumpFormatError(
                path, frame, first_line + k,
                f"NUMBER OF ATOMS says {len(lines)} atom rows but the frame has only {k} "
                f"({len(lines) - k} missing): {line.strip()[:40]!r} comes after atom row {k}")
        parts = line.split()
        if len(parts) != ncol:
            what = f"expected {ncol} values on an atom row, got {len(parts)}"
            if k == len(lines) - 1 and not line.endswith("\n"):  # LAMMPS ends every line
                what = (f"truncated: the file ends in the middle of atom row {k + 1} of "
                        f"{len(lines)} (no end of line): {what}")
            raise DumpFormatError(path, frame, first_line + k, what)
        rows.append(parts)
    return None, np.array(rows, dtype=object)


def _to_float(col, path, frame, first_line, name):
    try:
        return col.astype(np.float64)
    except ValueError:
        for k, v in enumerate(col):
            try:
                float(v)
            except ValueError:
                raise DumpFormatError(path, frame, first_line + k,
                                      f"column {name!r}: {str(v)!r} is not a number") from None
        raise  # pragma: no cover


def dump_frame_index(path):
    """Byte offset and 1-based line number of the first header line of every frame.

    That is the ``ITEM: TIMESTEP`` line, or the ``ITEM: UNITS`` / ``ITEM: TIME``
    lines LAMMPS writes before it.

    A fast byte scan (no parsing), so that frames can be read independently,
    e.g. by Dask workers: ``iter_lammps_dump(path, start_at=(offset, line, index))``.

    Returns
    -------
    offsets, lines : (F,) ndarray of int64
    """
    key = b"ITEM: TIMESTEP"
    offsets, lines = [], []
    base = 0
    newlines = 0
    tail = b""
    nl = None  # the line end: b"\n" (and CRLF), or b"\r" in a file of CR line ends only
    with open_dump(path) as fh:
        for chunk in _chunks(fh):
            if nl is None:  # (as the reader's universal newlines take them)
                nl = b"\r" if b"\n" not in chunk and b"\r" in chunk else b"\n"
            buf = tail + chunk
            start = base - len(tail)
            pos = buf.find(key)
            prev, count = 0, newlines - tail.count(nl)
            while pos >= 0:
                if pos == 0 or buf[pos - 1:pos] == nl:
                    count += buf.count(nl, prev, pos)
                    prev = pos
                    if start + pos not in offsets[-1:]:
                        offsets.append(start + pos)
                        lines.append(count + 1)
                pos = buf.find(key, pos + 1)
            newlines += chunk.count(nl)
            base += len(chunk)
            tail = buf[-(len(key) - 1):]
        # LAMMPS writes ITEM: UNITS and ITEM: TIME (dump_modify units/time yes) before
        # ITEM: TIMESTEP: a frame starts at the first of them
        for k, off in enumerate(offsets):
            fh.seek(max(0, off - 1024))
            before = fh.read(off - max(0, off - 1024)).split(nl)[:-1]
            while len(before) >= 2 and (before[-2].startswith(b"ITEM: UNITS") or
                                        before[-2].rstrip() == b"ITEM: TIME"):
                offsets[k] -= len(before[-2]) + len(before[-1]) + 2
                lines[k] -= 2
                del before[-2:]
    return np.asarray(offsets, dtype=np.int64), np.asarray(lines, dtype=np.int64)


def dump_frame_pbc(path):
    """Periodicity ((3,) bool) of every frame of a dump, from its ``ITEM: BOX BOUNDS`` flags.

    For readers that do not keep them (MDAnalysis's ``LAMMPSDUMP``).
    """
    offsets, _ = dump_frame_index(path)
    out = []
    with open_dump(path) as fh:
        for off in offsets:
            fh.seek(int(off))
            pbc = np.ones(3, bool)  # old dumps without flags: written for periodic boxes
            for _ in range(16):
                line = fh.readline()
                if not line or line.startswith(b"ITEM: ATOMS"):
                    break
                if line.startswith(b"ITEM: BOX BOUNDS"):
                    flags = [w for w in line.split()[3:]
                             if w not in (b"xy", b"xz", b"yz", b"abc", b"origin")]
                    if flags:  # (flags of another kind: the reader names them)
                        try:
                            pbc = lammps_pbc([f.decode("ascii", "replace") for f in flags])
                        except ValueError:
                            pass
                    break
            out.append(pbc)
    return out


def iter_lammps_dump(path, *, frames=None, coordinates=None, start_at=None):
    """Yield :class:`Frame` objects from a LAMMPS text dump.

    Parameters
    ----------
    path : str or os.PathLike
    frames : slice, optional
        Frames to yield (non-negative start/stop); skipped frames are not parsed.
    coordinates : {"x", "xu", "xs", "xsu"}, optional
        Which coordinate columns to use; default the first present in that order.
    start_at : (int, int, int), optional
        ``(byte offset, line number, frame number)`` of a frame's first line
        (see :func:`dump_frame_index`): read from there, numbering frames from
        that frame number; ``frames`` then counts from it too.

    Yields
    ------
    Frame
        Rows in increasing ``id`` order.

    Raises
    ------
    DumpFormatError
        After the last good frame, if the file is truncated or malformed.
    """
    path = os.fspath(path)
    if coordinates is not None and coordinates not in COORDINATE_SETS:
        raise ValueError(f"unknown coordinates {coordinates!r}; choose one of "
                         f"{', '.join(map(repr, COORDINATE_SETS))}")
    sel = frames if frames is not None else slice(None)
    start, stop, step = sel.start or 0, sel.stop, sel.step or 1
    if start < 0 or (stop is not None and stop < 0) or step <= 0:
        raise ValueError(f"frames must be a slice with non-negative start/stop and positive "
                         f"step for a LAMMPS dump, got {sel}")
    with open_dump(path) as raw:
        first_index = 0
        if start_at is not None:
            raw.seek(int(start_at[0]))
            first_index = int(start_at[2])
        fh = io.TextIOWrapper(raw, encoding="utf-8", errors="replace")
        src = _Lines(fh)
        if start_at is not None:
            src.lineno = int(start_at[1]) - 1
        index = -1
        line = src.next()
        while line is not None:
            if not line.strip():
                line = src.next()
                continue
            index += 1
            if stop is not None and index >= stop:
                return
            frame_start = src.lineno
            header = {"timestep": None, "time": None, "natoms": None, "cell": None,
                      "pbc": np.zeros(3, bool), "origin": np.zeros(3)}

            def fail(msg, line_no=None, _index=first_index + index):
                raise DumpFormatError(path, _index, src.lineno if line_no is None else line_no,
                                      msg)

            def value():
                # a header item's value line; LAMMPS ends every line, so one without an
                # end of line is cut short (its number may have lost digits)
                val = src.next()
                if val is not None and not val.endswith("\n"):
                    fail("truncated: the file ends in the middle of a header line")
                return val

            # ---- header items up to ITEM: ATOMS
            first_line = index == 0 and start_at is None
            while True:
                if line is None:
                    fail("file ends inside the frame header (truncated)")
                text = line.strip()
                if _cut_item(line):
                    fail("truncated: the file ends in the middle of a header line")
                if not text.startswith("ITEM:"):
                    if first_line:
                        fail(f"not a LAMMPS text dump: expected 'ITEM: TIMESTEP' on its first "
                             f"line, got {text[:40]!r}")
                    fail(f"expected an 'ITEM:' line, got {text[:40]!r}")
                first_line = False
                if not line.endswith("\n"):  # LAMMPS ends every line: cut mid-line
                    fail("truncated: the file ends in the middle of a header line")
                item = text[5:].strip()
                if item.startswith("TIMESTEP"):
                    val = value()
                    try:
                        header["timestep"] = int(val.split()[0])
                    except (AttributeError, ValueError, IndexError):
                        fail("bad or missing TIMESTEP value")
                elif item.startswith("TIME"):
                    val = value()
                    try:
                        header["time"] = float(val.split()[0])
                    except (AttributeError, ValueError, IndexError):
                        fail("bad or missing TIME value")
                elif item.startswith("UNITS"):
                    value()
                elif item.startswith("NUMBER OF ATOMS"):
                    val = value()
                    try:
                        header["natoms"] = int(val.split()[0])
                    except (AttributeError, ValueError, IndexError):
                        fail("bad or missing NUMBER OF ATOMS value")
                    if header["natoms"] < 0:
                        fail(f"negative NUMBER OF ATOMS {header['natoms']}")
                elif item.startswith("BOX BOUNDS"):
                    words = item.split()[2:]
                    general = "abc" in words
                    triclinic = "xy" in words or general
                    flags = [w for w in words if w not in ("xy", "xz", "yz", "abc", "origin")]
                    flags_line = src.lineno
                    rows = []
                    for _ in range(3):
                        val = value()
                        try:
                            rows.append([float(v) for v in val.split()])
                        except (AttributeError, ValueError):
                            fail("bad or missing BOX BOUNDS line")
                    want = 4 if general else (3 if triclinic else 2)
                    if any(len(r) < want for r in rows):
                        fail(f"BOX BOUNDS lines need {want} numbers")
                    try:
                        if general:
                            cell, origin = _lammps_cell(rows, None, True)
                        else:
                            tilt = [r[2] for r in rows] if triclinic else [0.0, 0.0, 0.0]
                            cell, origin = _lammps_cell([r[:2] for r in rows], tilt, False)
                    except ValueError as exc:
                        fail(f"BOX BOUNDS do not describe a cell: {exc}")
                    header["cell"], header["origin"] = cell, origin
                    if flags:
                        try:
                            header["pbc"] = lammps_pbc(flags)
                        except ValueError as exc:
                            fail(f"BOX BOUNDS flags: {exc}", flags_line)
                    else:  # old dumps without flags: LAMMPS wrote them for periodic boxes
                        header["pbc"] = np.ones(3, bool)
                elif item.startswith("ATOMS"):
                    names = item.split()[1:]
                    break
                else:
                    fail(f"unknown dump item {item[:40]!r}")
                line = src.next()
            natoms = header["natoms"]
            if natoms is None:
                fail("ITEM: ATOMS before ITEM: NUMBER OF ATOMS")
            if len(set(names)) != len(names):
                fail(f"duplicate column names in ITEM: ATOMS {' '.join(names)}")
            first_row = src.lineno + 1
            selected = index >= start and (index - start) % step == 0
            if not selected:
                got = 0
                for _ in range(natoms):
                    if src.next() is None:
                        break
                    got += 1
                if got != natoms:
                    fail(f"truncated: expected {natoms} atom rows, got {got}")
                line = _after_rows(src, natoms, fail)
                continue
            rows = src.take(natoms)
            if len(rows) != natoms:
                fail(f"truncated: expected {natoms} atom rows, got {len(rows)}")
            frame = _build_frame(path, first_index + index, names, rows, header, coordinates,
                                 first_row, frame_start)
            if rows and not rows[-1].endswith("\n"):  # its last value may be cut short
                fail(f"truncated: the file ends in the middle of atom row {natoms} of {natoms} "
                     "(no end of line)")
            line = _after_rows(src, natoms, fail)
            yield frame
        if src.cut:
            raise DumpFormatError(path, first_index + index + 1, src.lineno,
                                  "truncated: the gzip-compressed file ends early")


def _int_column(rows, k, path, index, first_row, name):
    """Column ``k`` of the atom rows read as int64 from its text."""
    out = np.empty(len(rows), np.int64)
    for r, line in enumerate(rows):
        text = line.split()[k]
        try:
            out[r] = int(text)
        except (ValueError, OverflowError):
            raise DumpFormatError(path, index, first_row + r,
                                  f"column {name!r}: {text!r} is not an integer that fits "
                                  "in int64") from None
    return out


def _cut_item(line):
    """Whether ``line`` is the start of an ``ITEM:`` line cut by the end of the file
    (``I`` to ``ITEM``, no end of line): the next frame's header, truncated."""
    text = line.strip()
    return bool(text) and not line.endswith("\n") and "ITEM:".startswith(text)


def _after_rows(src, natoms, fail):
    """The first line after a frame's ``natoms`` atom rows that is not blank: the
    next frame's first header line, or None at the end of the file.  Anything
    else is one more atom row than NUMBER OF ATOMS says (or stray text), an
    error of this frame, found before it is yielded (so a reader of one frame,
    a Dask worker, finds it as the whole-file reader does)."""
    line = src.next()
    while line is not None and not line.strip():
        line = src.next()
    if line is not None and not line.lstrip().startswith("ITEM:") and not _cut_item(line):
        fail(f"NUMBER OF ATOMS says {natoms} atom rows but more rows follow: "
             f"{line.strip()[:40]!r} after atom row {natoms}")
    return line


def _build_frame(path, index, names, rows, header, coordinates, first_row, frame_start):
    ncol = len(names)
    data, strings = _parse_atoms(rows, ncol, path, index, first_row)
    columns = {}
    for k, name in enumerate(names):
        if data is not None:
            col = data[:, k] if name != "element" or len(data) else np.empty(0, dtype=str)
        else:
            col = strings[:, k]
            if name not in ("element",):
                try:
                    col = _to_float(col, path, index, first_row, name)
                except DumpFormatError:
                    if name in _INT_COLUMNS or name in ("x", "y", "z") or name.startswith("x"):
                        raise
                    col = col.astype(str)
            else:
                col = col.astype(str)
        if name in _INT_COLUMNS and col.dtype.kind == "f":
            if len(col) and not np.abs(col).max() < 2.0**53:
                # beyond the integers a float64 holds exactly (LAMMPS's 64-bit tags):
                # the column's text, read as integers
                col = _int_column(rows, k, path, index, first_row, name)
            else:
                ints = col.astype(np.int64)
                if not np.array_equal(ints, col):
                    raise DumpFormatError(path, index, first_row,
                                          f"column {name!r} is not integer")
                col = ints
        columns[name] = col
    if coordinates is None:
        coordinates = next((c for c, cols in COORDINATE_SETS.items()
                            if all(n in columns for n in cols)), None)
        if coordinates is None:
            raise DumpFormatError(path, index, first_row - 1,
                                  "no coordinate columns (x y z, xu yu zu, xs ys zs or "
                                  f"xsu ysu zsu) in ITEM: ATOMS {' '.join(names)}")
    cols = COORDINATE_SETS[coordinates]
    if not all(n in columns for n in cols):
        raise DumpFormatError(path, index, first_row - 1,
                              f"coordinates={coordinates!r} needs columns {' '.join(cols)}")
    positions = np.column_stack([columns[n] for n in cols]).astype(np.float64)
    cell = header["cell"]
    if coordinates in _SCALED:
        if cell is None:
            raise DumpFormatError(path, index, first_row - 1, "scaled coordinates without a box")
        positions = header["origin"] + positions @ cell
    n = len(rows)
    ids = columns.get("id")
    ids = np.arange(1, n + 1, dtype=np.int64) if ids is None else ids
    uniq, first_at = np.unique(ids, return_index=True)
    if len(uniq) != n:
        seen = np.zeros(n, bool)
        seen[first_at] = True
        k = int(np.flatnonzero(~seen)[0])  # the first row whose id an earlier row has
        earlier = int(np.flatnonzero(ids[:k] == ids[k])[0])
        raise DumpFormatError(path, index, first_row + k,
                              f"duplicate atom id {int(ids[k])} (atom row {k + 1}; atom row "
                              f"{earlier + 1}, line {first_row + earlier}, has it too)")
    radius = None
    if "radius" in columns:
        radius = _to_float(columns["radius"], path, index, first_row, "radius")
    elif "diameter" in columns:
        radius = 0.5 * _to_float(columns["diameter"], path, index, first_row, "diameter")
    mol = columns.get("mol", columns.get("molecule"))
    types = columns.get("type", columns.get("element"))
    frame = Frame(index=index, positions=np.ascontiguousarray(positions), ids=ids, cell=cell,
                  pbc=header["pbc"], origin=header["origin"], step=header["timestep"],
                  time=header["time"], types=types, radius=radius, molecule=mol,
                  columns=columns, source=path, ids_given="id" in columns)
    return frame.sorted_by_id()


_DUMP_START = re.compile(r"^\s*ITEM:")


def looks_like_dump(path) -> bool:
    """True if the file's first non-blank line starts with ``ITEM:``."""
    try:
        with io.TextIOWrapper(open_dump(path), encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.strip():
                    return bool(_DUMP_START.match(line))
    except (OSError, UnicodeDecodeError, EOFError):
        return False
    return False
