"""Trajectories written by LAMMPS during the test, read the way a user meets them.

Each test is a defect found on LAMMPS output the rest of the suite had not seen:
a dump cut in the middle of its last line, ...  The answers are checked against
a brute force over lattice images written here (no granularsap inside).
"""

from __future__ import annotations

import itertools
import os
import subprocess
import sys

import numpy as np
import pytest

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
    loader = pytest.importorskip("lammps_bridge._loader")
    try:
        lmp = loader.new_lammps()
    except ImportError as exc:
        pytest.skip(str(exc))
    d = tmp_path_factory.mktemp("unseen")
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
