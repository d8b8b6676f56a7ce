"""Trajectories written by LAMMPS during the test, read the way a user meets them.

Each test is a case of LAMMPS output a reader must handle:
a dump cut in the middle of its last line, ...  The answers are checked against
a brute force over lattice images written here (no granularsap inside).
"""

from __future__ import annotations

import itertools
import os
import socket
import subprocess
import sys

import numpy as np
import pytest

from ._iohelpers import lammps_or_skip

pytestmark = pytest.mark.lammps

CLI = [sys.executable, "-m", "granularsap"]


def _brute(pos, cell, pbc, cutoff):
    """Set of row pairs (i < j) within ``cutoff`` over the images +-2 of the periodic axes."""
    rng = [range(-2, 3) if p else range(1) for p in pbc]
    shifts = np.array(list(itertools.product(*rng)), float) @ cell
    out = set()
    for i in range(len(pos) - 1):
        d = pos[i + 1:, None, :] - pos[i] + shifts[None]
        dd = np.sqrt((d * d).sum(-1)).min(1)
        out.update((i, i + 1 + j) for j in np.nonzero(dd <= cutoff)[0])
    return out


@pytest.fixture(scope="module")
def lammps_run(tmp_path_factory):
    """A small LJ liquid in a triclinic ``p s p`` cell: 4 frames, 300 atoms, unsorted rows."""
    lmp = lammps_or_skip()
    d = tmp_path_factory.mktemp("lammps_dumps")
    dump = d / "psp.dump"
    lmp.commands_string(f"""
        units lj
        atom_style atomic
        boundary p s p
        region box prism 0 7 0 8 0 8 2.0 -1.5 1.0
        create_box 1 box
        create_atoms 1 random 300 4321 NULL overlap 0.8 maxtry 100
        mass 1 1.0
        pair_style lj/cut 2.5
        pair_coeff * * 1.0 1.0
        velocity all create 3.0 111 loop geom
        neighbor 0.8 bin
        neigh_modify every 20 delay 0 check no
        fix 1 all nve
        timestep 0.003
        dump d all custom 10 {dump} vx zs x ix type y id iy z
        run 30
    """)
    lmp.close()
    return d, dump


def _contacts(*args, cwd):
    return subprocess.run([*CLI, "contacts", *map(str, args), "-q"], capture_output=True,
                          text=True, cwd=cwd)


def test_dump_cut_inside_its_last_number_is_truncated(lammps_run):
    """A dump cut inside the last value of its last row is a truncated file.

    LAMMPS ends every line with a newline; a last row without one was cut
    short (``...0.9660169113`` -> ``...0.96601691``) and still has all its
    columns, so it used to be read as a complete frame with a wrong value.
    """
    from granularsap.io import DumpFormatError, iter_frames

    d, dump = lammps_run
    text = dump.read_bytes()
    assert text.endswith(b"\n")
    cut = d / "cut.dump"
    cut.write_bytes(text[:-3])                      # two digits and the newline gone
    n_frames = text.count(b"ITEM: TIMESTEP")
    good = []
    with pytest.raises(DumpFormatError, match=rf"frame {n_frames - 1}, line \d+: truncated"):
        for fr in iter_frames(cut):
            good.append(fr.index)
    assert good == list(range(n_frames - 1))
    out = d / "cut.h5"
    r = _contacts(cut, "-o", out, "--cutoff", "1.2", cwd=d)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "truncated" in r.stderr and "cut.dump" in r.stderr
    assert not out.exists() and os.path.isdir(f"{out}.partial")
    # the frames before the cut are kept; the frame that was cut is not
    from granularsap.io import ContactsFile

    with ContactsFile(f"{out}.partial", allow_incomplete=True) as cf:
        assert cf.n_frames == n_frames - 1
    # a header line cut short at the end of the file is truncated too, not an unknown item
    head = d / "head.dump"
    at = text.rindex(b"ITEM: BOX BOUNDS")
    head.write_bytes(text[:at + 12])
    with pytest.raises(DumpFormatError, match="truncated"):
        list(iter_frames(head))


@pytest.mark.parametrize("kept", range(1, len("ITEM: TIMESTEP\n")))
def test_dump_cut_in_the_next_frames_first_line_keeps_the_frame_before(lammps_run, kept):
    """A run killed while writing a frame's first line (``I`` ... ``ITEM: TIMESTE``) has
    every frame before it complete: they are all read, and the error is the cut
    frame's (a cut ``I`` to ``ITEM`` was taken for one atom row too many of the
    frame before, which was then lost)."""
    from granularsap.io import DumpFormatError, iter_frames

    d, dump = lammps_run
    text = dump.read_bytes()
    at = text.rindex(b"ITEM: TIMESTEP")
    n_frames = text.count(b"ITEM: TIMESTEP")
    cut = d / f"cut{kept}.dump"
    cut.write_bytes(text[:at + kept])
    good = []
    with pytest.raises(DumpFormatError, match=rf"frame {n_frames - 1}, line \d+: truncated"):
        for fr in iter_frames(cut):
            good.append(fr.index)
    assert good == list(range(n_frames - 1))
    # the reader of one frame (a Dask worker's) says the same of the frame before
    last = list(iter_frames(cut, frames=slice(n_frames - 2, n_frames - 1)))
    assert [fr.index for fr in last] == [n_frames - 2]


def _edit_row(text, frame, row, column, value):
    """``text`` with one value of atom row ``row`` of frame ``frame`` replaced."""
    lines = text.splitlines(keepends=True)
    starts = [k for k, line in enumerate(lines) if line.startswith("ITEM: ATOMS")]
    names = lines[starts[frame]].split()[2:]
    k = starts[frame] + 1 + row
    parts = lines[k].split()
    atom_id = int(parts[names.index("id")])
    parts[names.index(column)] = value
    lines[k] = " ".join(parts) + "\n"
    return "".join(lines), atom_id


@pytest.mark.parametrize("column, value, what", [("x", "nan", "non-finite position"),
                                                 ("z", "1e400", "non-finite position")])
def test_bad_number_in_a_dump_names_file_frame_and_particle(lammps_run, column, value, what):
    """A NaN (or an overflowing number) in frame 2 of a dump: the one-line error says where.

    It used to say only "positions must be finite, got NaN or inf in row 218",
    a row of the frame sorted by id, with neither the file nor the frame.
    """
    d, dump = lammps_run
    text, atom_id = _edit_row(dump.read_text(), 2, 17, column, value)
    bad = d / f"bad_{column}.dump"
    bad.write_text(text)
    r = _contacts(bad, "-o", d / "bad.h5", "--cutoff", "1.2", cwd=d)
    assert r.returncode == 2
    (line,) = r.stderr.splitlines()
    assert f"bad_{column}.dump: frame 2 (step 20): particle id {atom_id} has a {what}" in line


def test_negative_radius_in_a_dump_names_the_particle(lammps_run):
    from granularsap.io import ContactParams, compute_contacts

    d, dump = lammps_run
    text, atom_id = _edit_row(dump.read_text(), 1, 3, "type", "-2")
    bad = d / "neg.dump"
    bad.write_text(text)
    with pytest.raises(ValueError, match=rf"neg\.dump: frame 1 \(step 10\): particle id "
                                         rf"{atom_id} has radius -2"):
        compute_contacts(bad, d / "neg.h5", ContactParams(radius_column="type"))


def test_worker_error_is_one_line(lammps_run):
    """With ``--workers``, a truncated dump is still one line on stderr.

    The local cluster's workers logged the failed task ("Compute Failed", the
    exception and a traceback) on the same terminal before the run's own line.
    """
    pytest.importorskip("distributed")
    d, dump = lammps_run
    text = dump.read_text()
    cut = d / "cut_workers.dump"
    cut.write_text(text[:text.rindex("ITEM: ATOMS") + 200])
    # a Dask cluster already running here holds the default dashboard port
    held = socket.socket()
    try:
        held.bind(("127.0.0.1", 8787))
        held.listen()
    except OSError:
        pass  # taken already: the case itself
    try:
        r = _contacts(cut, "-o", d / "w.h5", "--cutoff", "1.2", "--workers", "1", cwd=d)
    finally:
        held.close()
    assert r.returncode == 2
    assert r.stderr.splitlines() == [r.stderr.strip()], r.stderr
    assert "cut_workers.dump: frame 3, line" in r.stderr and "truncated" in r.stderr


def test_dump_with_time_and_units_items_read_by_workers(lammps_run):
    """``dump_modify time yes units yes``: LAMMPS writes ITEM: UNITS (first frame) and
    ITEM: TIME before ITEM: TIMESTEP.  Frames read from their byte offsets (``--workers``)
    started at TIMESTEP and lost their time: NaN in the file where a serial run has it."""
    import h5py

    from granularsap.io.lammps_dump import dump_frame_index, iter_lammps_dump

    pytest.importorskip("distributed")
    loader = pytest.importorskip("lammps_bridge._loader")
    d, _ = lammps_run
    dump = d / "timed.dump"
    lmp = loader.new_lammps()
    lmp.commands_string(f"""
        units lj
        atom_style atomic
        boundary p p s
        region box prism 0 6 0 6 0 7 3.0 -3.0 2.9
        create_box 1 box
        create_atoms 1 random 150 4321 NULL overlap 0.7 maxtry 100
        mass 1 1.0
        pair_style zero 1.0
        pair_coeff * *
        velocity all create 2.0 111
        fix 1 all nve
        timestep 0.003
        dump d all custom 10 {dump} id type x y z
        dump_modify d time yes units yes
        run 30
    """)
    lmp.close()
    offsets, lines = dump_frame_index(dump)
    text = dump.read_text().splitlines()
    assert text[0] == "ITEM: UNITS" and [text[k - 1] for k in lines[1:]] == ["ITEM: TIME"] * 3
    serial = [(f.step, f.time) for f in iter_lammps_dump(dump)]
    alone = [next(iter_lammps_dump(dump, frames=slice(0, 1), start_at=(o, n, k)))
             for k, (o, n) in enumerate(zip(offsets, lines, strict=True))]
    assert [(f.step, f.time) for f in alone] == serial == [(0, 0.0), (10, 0.03), (20, 0.06),
                                                           (30, 0.09)]
    for name, extra in (("s.h5", []), ("w.h5", ["--workers", "1"])):
        r = _contacts(dump, "-o", d / name, "--cutoff", "1.0", *extra, cwd=d)
        assert r.returncode == 0, r.stderr
    with h5py.File(d / "s.h5") as s, h5py.File(d / "w.h5") as w:
        np.testing.assert_array_equal(w["frames/time"][:], s["frames/time"][:])
        np.testing.assert_array_equal(w["contacts/pairs"][:], s["contacts/pairs"][:])


@pytest.fixture(scope="module")
def evaporating(tmp_path_factory):
    """LAMMPS ``fix evaporate`` in a triclinic cell, dumped plain and gzip-compressed
    (LAMMPS compresses a dump whose name ends in .gz)."""
    loader = pytest.importorskip("lammps_bridge._loader")
    lmp = loader.new_lammps()
    d = tmp_path_factory.mktemp("evaporate")
    lmp.commands_string(f"""
        units lj
        atom_style atomic
        boundary p p p
        region box prism 0 6 0 6 0 6 1.0 0.5 -0.5
        create_box 1 box
        create_atoms 1 random 200 2221 NULL overlap 0.8 maxtry 100
        mass 1 1.0
        pair_style lj/cut 2.5
        pair_coeff * * 1.0 1.0
        velocity all create 1.5 7
        fix 1 all nve
        fix e all evaporate 20 40 box 42
        timestep 0.003
        dump d1 all custom 20 {d / 'evap.dump'} id type x y z
        dump d2 all custom 20 {d / 'evap.dump.gz'} id type x y z
        run 100
    """)
    lmp.close()
    return d


def test_gzipped_dump_is_read_as_a_lammps_dump(evaporating):
    """A gzip-compressed LAMMPS dump went to ASE, which numbers particles 0..n-1 by row:
    the pairs were not LAMMPS ids, births and deaths of an evaporating system were wrong
    (rows renumbered as atoms left) and radius/mol columns were lost; exit status 0."""
    import h5py

    from granularsap.io import iter_frames

    d = evaporating
    plain, packed = d / "evap.dump", d / "evap.dump.gz"
    assert packed.read_bytes()[:2] == b"\x1f\x8b"
    for a, b in zip(iter_frames(plain), iter_frames(packed), strict=True):
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_array_equal(a.positions, b.positions)
        assert a.step == b.step and b.source.endswith(".gz")
    runs = {"plain": (plain, []), "gz": (packed, []), "gz-workers": (packed, ["--workers", "1"])}
    for name, (src, extra) in runs.items():
        r = _contacts(src, "-o", d / f"{name}.h5", "--cutoff", "1.4", *extra, cwd=d)
        assert r.returncode == 0, r.stderr
    with h5py.File(d / "plain.h5") as p:
        want = {k: p[k][()] for k in ("contacts/pairs", "events/born", "events/died",
                                      "frames/n_particles")}
        assert len(set(want["frames/n_particles"])) > 2  # the count does change
    for name in ("gz", "gz-workers"):
        with h5py.File(d / f"{name}.h5") as g:
            for k, v in want.items():
                np.testing.assert_array_equal(g[k][()], v, err_msg=f"{name}: {k}")
            assert '"source_format": "lammps-dump"' in g.attrs["parameters"]
    # a gzip file cut short: the good frames, then a one-line truncation error
    data = packed.read_bytes()
    for keep, where in ((len(data) - 4, "ends early"), (len(data) * 2 // 3, "truncated")):
        cut = d / "cut.dump.gz"
        cut.write_bytes(data[:keep])
        r = _contacts(cut, "-o", d / "cut.h5", "--cutoff", "1.4", "--no-resume", cwd=d)
        assert r.returncode == 2 and where in r.stderr and r.stderr.count("\n") == 1, r.stderr


def test_missing_topology_names_the_option(lammps_run):
    """``--topology`` naming no file: the error said only "[Errno 2] No such file or
    directory: 'system.pdb'", from deep inside MDAnalysis."""
    d, dump = lammps_run
    r = _contacts(dump, "-o", d / "t.h5", "--cutoff", "1.0", "--topology", "system.pdb", cwd=d)
    assert r.returncode == 2
    assert r.stderr == "granularsap contacts: error: --topology system.pdb does not exist\n"
    assert not list(d.glob("t.h5*"))


def test_mdanalysis_reader_keeps_lammps_boundary_flags(lammps_run):
    """``format="mdanalysis:LAMMPSDUMP"`` on a ``p s p`` dump: MDAnalysis keeps no boundary
    flags, so every frame came out periodic in y too, and contacts across the open
    y walls were added (2109 pairs instead of 1927 on a 600-atom frame)."""
    pytest.importorskip("MDAnalysis")
    import granularsap
    from granularsap.io import iter_frames
    from granularsap.io.pipeline import engine_cell

    d, dump = lammps_run
    own = list(iter_frames(dump))
    mda = list(iter_frames(dump, "mdanalysis:LAMMPSDUMP"))
    assert len(mda) == len(own)
    for a, b in zip(own, mda, strict=True):
        assert a.pbc.tolist() == b.pbc.tolist() == [True, False, True]
        pa = a.ids[granularsap.neighbor_pairs(a.positions, 1.2, box=engine_cell(a),
                                              return_distances=False)]
        pb = b.ids[granularsap.neighbor_pairs(b.positions, 1.2, box=engine_cell(b),
                                              return_distances=False)]
        assert {tuple(sorted(p)) for p in pa.tolist()} == {tuple(sorted(p)) for p in pb.tolist()}
        want = _brute(a.positions, a.cell, a.pbc, 1.2)
        assert {tuple(sorted(p)) for p in a.ids[np.array(sorted(want))].tolist()} == \
            {tuple(sorted(p)) for p in pa.tolist()}


def test_half_written_contacts_file_is_refused_by_name(lammps_run):
    """A contacts file cut short (a torn ``OUT.h5.tmp`` of a run killed while assembling,
    a copy cut mid-way): ``read_contacts`` and ``granularsap info`` refused it with h5py's
    bare "Unable to synchronously open file (...)", naming no file."""
    from granularsap.io import read_contacts

    d, dump = lammps_run
    out = d / "whole.h5"
    r = _contacts(dump, "-o", out, "--cutoff", "1.2", cwd=d)
    assert r.returncode == 0, r.stderr
    data = out.read_bytes()
    torn = d / "torn.h5.tmp"
    torn.write_bytes(data[:len(data) // 2])
    with pytest.raises(ValueError, match=r"torn\.h5\.tmp is not a readable granularsap contacts "
                                         r"file: a damaged HDF5 file .*rerun the same command"):
        read_contacts(torn)
    r = subprocess.run([*CLI, "info", str(torn)], capture_output=True, text=True, cwd=d)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "torn.h5.tmp" in r.stderr


def _pour_frames(k):
    """The first ``k`` frames of the bundled pour (2000 spheres, a radius column)."""
    from pathlib import Path

    text = (Path(__file__).parent.parent / "data" / "pour.dump").read_text()
    starts = [m for m in range(len(text)) if text.startswith("ITEM: TIMESTEP", m)][:k + 1]
    return text[:starts[k]] if len(starts) > k else text


def test_text_in_the_radius_column_names_file_frame_and_line(tmp_path):
    # the reader keeps a column it cannot read as numbers as text (an element
    # column); the radius (or diameter) column must be numbers: a DumpFormatError
    # naming where, so that the contacts command keeps the frames before it
    from granularsap.io import DumpFormatError, iter_frames

    text, atom_id = _edit_row(_pour_frames(3), 2, 5, "radius", "abc")
    bad = tmp_path / "bad.dump"
    bad.write_text(text)
    line = text.splitlines().index(next(x for x in text.splitlines()
                                        if x.startswith(f"{atom_id} ") and "abc" in x)) + 1
    with pytest.raises(DumpFormatError, match=rf"bad\.dump: frame 2, line {line}: column "
                                              r"'radius': 'abc' is not a number"):
        list(iter_frames(bad))
    r = _contacts(bad, "-o", tmp_path / "bad.h5", "--cutoff", "1.0", cwd=tmp_path)
    assert r.returncode == 2
    (msg,) = r.stderr.splitlines()
    assert "frame 2" in msg and "--frames 0:2" in msg


def test_unknown_boundary_flags_in_a_dump_are_named(tmp_path):
    from granularsap.io import DumpFormatError, iter_frames
    from granularsap.io.lammps_dump import dump_frame_pbc

    text = _pour_frames(2).replace("ITEM: BOX BOUNDS ff ff ff", "ITEM: BOX BOUNDS pp xx pp", 1)
    bad = tmp_path / "flags.dump"
    bad.write_text(text)
    with pytest.raises(DumpFormatError, match=r"flags\.dump: frame 0, line 5: BOX BOUNDS "
                                              r"flags: boundary flag 'xx'"):
        list(iter_frames(bad))
    good = tmp_path / "good.dump"
    good.write_text(_pour_frames(2).replace("BOX BOUNDS ff ff ff", "BOX BOUNDS pp fs pp", 1))
    assert [p.tolist() for p in dump_frame_pbc(good)] == [[True, False, True],
                                                          [False, False, False]]
