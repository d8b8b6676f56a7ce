"""granularsap validate: exit codes, the per-frame table, ties reported as ties."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import granularsap
from granularsap.cli import main

from .oracles import brute_image_pairs

DATA = Path(__file__).resolve().parent.parent / "data"
pytestmark = pytest.mark.lammps


def _write_dump(path, frames, *, bounds="ff ff ff", box=((0, 10), (0, 10), (0, 10)),
                radius=None):
    """A minimal LAMMPS text dump: frames is a list of (n, 3) arrays."""
    lines = []
    for step, pos in enumerate(frames):
        lines += ["ITEM: TIMESTEP", str(step), "ITEM: NUMBER OF ATOMS", str(len(pos)),
                  f"ITEM: BOX BOUNDS {bounds}"]
        lines += [f"{lo} {hi}" for lo, hi in box]
        cols = "id type x y z" + (" radius" if radius is not None else "")
        lines.append(f"ITEM: ATOMS {cols}")
        for k, (x, y, z) in enumerate(pos):
            extra = f" {float(radius[k])!r}" if radius is not None else ""
            lines.append(f"{k + 1} 1 {float(x)!r} {float(y)!r} {float(z)!r}{extra}")
    path.write_text("\n".join(lines) + "\n")
    return str(path)


class TestBundledData:
    @pytest.mark.parametrize("args", [
        ["data/lj.dump", "--cutoff", "2.5"],
        ["data/pour.dump"],                      # radii from the radius column
        ["data/pour.dump", "--cutoff", "1.2"],
        ["data/clumps.dump", "--radius-column", "radius", "--skin", "0.1"],
    ])
    def test_exits_zero_against_lammps(self, args, capsys):
        args = [str(DATA / Path(args[0]).name), *args[1:]]
        assert main(["validate", *args, "--against", "lammps"]) == 0
        out = capsys.readouterr().out
        assert "identical" in out
        assert "granularsap" in out.splitlines()[1] and "lammps" in out.splitlines()[1]

    def test_lj_identical_to_mdanalysis_and_lammps(self, capsys):
        assert main(["validate", str(DATA / "lj.dump"), "--cutoff", "2.5",
                     "--frames", "0:11:5"]) == 0
        out = capsys.readouterr().out
        rows = [line.split() for line in out.splitlines()[2:5]]
        assert [r[0] for r in rows] == ["0", "5", "10"]
        for r in rows:  # granularsap, lammps, +0/-0, mdanalysis, +0/-0, 0 ties
            assert r[3] == r[4] == r[6] and r[5] == r[7] == "+0/-0" and r[8] == "0"

    def test_float32_ties_with_mdanalysis_are_reported(self, capsys):
        # the settled pour has contacts within 1e-7 of r_i + r_j; MDAnalysis rounds to float32
        rc = main(["validate", str(DATA / "pour.dump"), "--frames", "12:13",
                   "--against", "mdanalysis"])
        out = capsys.readouterr().out
        assert rc == 3
        assert "tie: |d - reach|" in out and "NOT a tie" not in out
        assert "0 differing pair(s) beyond rounding" in out
        assert main(["validate", str(DATA / "pour.dump"), "--frames", "12:13",
                     "--against", "mdanalysis", "--allow-ties"]) == 0


class TestDifferencesAreCaught:
    def test_perturbed_pair_list_fails(self, monkeypatch, capsys):
        real = granularsap.neighbor_pairs

        def drop_one(*args, **kwargs):
            pairs = real(*args, **kwargs)
            return pairs[1:]

        monkeypatch.setattr(granularsap, "neighbor_pairs", drop_one)
        rc = main(["validate", str(DATA / "lj.dump"), "--cutoff", "2.5", "--frames", "3:5"])
        out = capsys.readouterr().out
        assert rc == 1
        assert out.count("+0/-1") == 4  # both frames, both references
        assert "lammps only" in out and "mdanalysis only" in out and "NOT a tie" in out

    def test_extra_pair_fails(self, monkeypatch, capsys):
        real = granularsap.sphere_contacts

        def add_one(*args, **kwargs):
            pairs = real(*args, **kwargs)
            return np.vstack([pairs, [[0, 1999]]])

        monkeypatch.setattr(granularsap, "sphere_contacts", add_one)
        rc = main(["validate", str(DATA / "pour.dump"), "--frames", "20",
                   "--against", "lammps"])
        assert rc == 1
        assert "granularsap only" in capsys.readouterr().out

    def test_tie_at_exact_cutoff_is_reported_as_tie(self, tmp_path, monkeypatch, capsys):
        # d == 2.5 exactly in float64; a backend using LAMMPS's pair-style test
        # (rsq < cutsq, strict) drops it: that is a tie, not a bug
        pos = np.array([[1.0, 1.0, 1.0], [2.5, 3.0, 1.0], [8.0, 8.0, 8.0]])
        dump = _write_dump(tmp_path / "tie.dump", [pos])
        real = granularsap.neighbor_pairs

        def strict(positions, cutoff, **kwargs):
            pairs = real(positions, cutoff, **kwargs)
            d = np.linalg.norm(positions[pairs[:, 1]] - positions[pairs[:, 0]], axis=1)
            return pairs[d < cutoff]

        monkeypatch.setattr(granularsap, "neighbor_pairs", strict)
        rc = main(["validate", dump, "--cutoff", "2.5", "--against", "lammps"])
        out = capsys.readouterr().out
        assert rc == 3
        assert "pair (0, 1) lammps only: d = 2.5, reach = 2.5 (tie" in out
        assert "1 tie(s) at the cutoff" in out
        assert main(["validate", dump, "--cutoff", "2.5", "--against", "lammps",
                     "--allow-ties"]) == 0


class TestUsage:
    def test_without_cutoff_or_radii_the_default_cutoff(self, tmp_path, capsys):
        """Issue 20: `validate data/lj.dump --against lammps,mdanalysis` (the README's
        command) exited 2 asking for --cutoff."""
        pos = np.array([[1.0, 1, 1], [3.4, 1, 1], [6.0, 1, 1]])  # 2.4 apart, then 2.6
        dump = _write_dump(tmp_path / "a.dump", [pos])
        assert main(["validate", dump, "--against", "lammps"]) == 0
        out = capsys.readouterr().out
        assert out.startswith(f"granularsap validate: {dump}: neighbour pairs d <= 2.5 (no "
                              "radius column and no --cutoff: the default 2.5, Lennard-Jones's "
                              "usual 2.5 sigma); against lammps\n")
        assert "1 frame(s): identical" in out
        assert main(["validate", dump, "--cutoff", "2.6", "--against", "lammps"]) == 0
        assert "d <= 2.6; against" in capsys.readouterr().out

    def test_unknown_radius_column(self, tmp_path, capsys):
        dump = _write_dump(tmp_path / "a.dump", [np.zeros((2, 3))])
        assert main(["validate", dump, "--radius-column", "diam"]) == 2
        assert "no per-particle column 'diam'" in capsys.readouterr().err

    def test_unknown_reference(self, capsys):
        with pytest.raises(SystemExit) as exc:
            main(["validate", "x.dump", "--cutoff", "1", "--against", "lammps,gromacs"])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "unknown reference 'gromacs'; choose from lammps, mdanalysis" in err

    def test_negative_cutoff(self, capsys):
        with pytest.raises(SystemExit):
            main(["validate", "x.dump", "--cutoff", "-1"])
        assert "expected a finite number >= 0" in capsys.readouterr().err

    def test_missing_file(self, capsys):
        assert main(["validate", "no-such.dump", "--cutoff", "1"]) == 2
        assert "does not exist" in capsys.readouterr().err

    def test_mixed_periodicity_pairs_across_periodic_faces_only(self, tmp_path, capsys):
        # a pair across the periodic x face (d = 1), none across the open z face
        # (z = 0.5 and 9.5 would be 1 apart through it)
        pos = np.array([[0.5, 5.0, 0.5], [9.5, 5.0, 0.5], [5.0, 5.0, 9.5]])
        dump = _write_dump(tmp_path / "m.dump", [pos], bounds="pp pp ff")
        assert main(["validate", dump, "--cutoff", "1.5"]) == 0
        out = capsys.readouterr().out
        row = out.splitlines()[2].split()  # granularsap, lammps, diff, mdanalysis, diff
        assert row[3] == row[4] == row[6] == "1" and row[5] == row[7] == "+0/-0"
        assert "identical" in out


@pytest.mark.parametrize("bounds, flags", [
    ("xy xz yz pp pp ff", (True, True, False)),
    ("xy xz yz pp ff pp", (True, False, True)),
    ("xy xz yz ff pp ff", (False, True, False)),
])
def test_triclinic_mixed_periodicity_matches_both_references(tmp_path, capsys, bounds, flags):
    # LAMMPS dump bounds of a triclinic box: xlo_bound xhi_bound xy, ... ; the cell is
    # a = (lx, 0, 0), b = (xy, ly, 0), c = (xz, yz, lz)
    rng = np.random.default_rng(7)
    lx, ly, lz, xy, xz, yz = 9.0, 8.0, 10.0, 1.5, -2.0, 1.0
    cell = np.array([[lx, 0, 0], [xy, ly, 0], [xz, yz, lz]])
    frac = rng.random((300, 3))
    frac[:, [not f for f in flags]] *= 1.3  # beyond the box along the open axes
    pos = frac @ cell
    xlo, ylo, zlo = 0.0, 0.0, 0.0
    box = ((xlo + min(0, xy, xz, xy + xz), xlo + lx + max(0, xy, xz, xy + xz), xy),
           (ylo + min(0, yz), ylo + ly + max(0, yz), xz), (zlo, zlo + lz, yz))
    lines = ["ITEM: TIMESTEP", "0", "ITEM: NUMBER OF ATOMS", str(len(pos)),
             f"ITEM: BOX BOUNDS {bounds}"]
    lines += [f"{float(lo)!r} {float(hi)!r} {float(t)!r}" for lo, hi, t in box]
    lines.append("ITEM: ATOMS id type x y z")
    lines += [f"{k + 1} 1 {x!r} {y!r} {z!r}" for k, (x, y, z) in enumerate(pos.tolist())]
    dump = tmp_path / "tri.dump"
    dump.write_text("\n".join(lines) + "\n")
    assert main(["validate", str(dump), "--cutoff", "1.7"]) == 0
    out = capsys.readouterr().out
    row = out.splitlines()[2].split()
    expected = len(brute_image_pairs(pos, 1.7, cell, flags)[0])
    assert expected > 50
    assert row[3] == row[4] == row[6] == str(expected) and row[5] == row[7] == "+0/-0"


@pytest.mark.parametrize("pbc", [(True, True, False), (True, False, False),
                                 (False, True, False), (False, True, True)])
def test_periodic_stand_in_keeps_the_pairs(pbc):
    from granularsap.compare import periodic_stand_in

    rng = np.random.default_rng(3)
    cell = np.array([[6.0, 0.0, 0.0], [1.0, 5.0, 0.0], [-1.5, 2.0, 7.0]])
    pos = rng.random((120, 3)) * 9.0 - 1.0
    reach = 1.9
    stand_in = periodic_stand_in(pos, cell, pbc, reach)
    assert np.linalg.det(stand_in) > 0
    for k in range(3):
        if pbc[k]:
            assert np.array_equal(stand_in[k], cell[k])
    # every image of the stand-in against the partly periodic cell
    expected = brute_image_pairs(pos, reach, cell, pbc)[0]
    found = brute_image_pairs(pos, reach, stand_in)[0]
    np.testing.assert_array_equal(found, expected)
    assert len(expected) > 20

    def test_radius_column_with_skin(self, tmp_path, capsys):
        pos = np.array([[1.0, 1.0, 1.0], [2.0, 1.0, 1.0], [5.0, 5.0, 5.0]])
        dump = _write_dump(tmp_path / "r.dump", [pos, pos + 0.5], radius=[0.5, 0.4, 0.3])
        assert main(["validate", dump, "--skin", "0.1"]) == 0
        out = capsys.readouterr().out
        assert "sphere contacts d <= r_i + r_j + 0.1 (radii: radius)" in out


def test_ase_slab_with_a_zero_open_vector_matches_both_references(tmp_path, capsys):
    # ASE writes a slab's open axis as a zero cell vector
    from ase import Atoms
    from ase.io import write

    rng = np.random.default_rng(0)
    cell = np.array([[6.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, -1.5, 7.0]])
    pos = rng.uniform(0.0, 5.0, (60, 3))
    path = tmp_path / "slab.extxyz"
    write(path, Atoms("Ar60", positions=pos, cell=cell, pbc=[True, False, True]))
    assert main(["validate", str(path), "--cutoff", "2.0"]) == 0
    row = capsys.readouterr().out.splitlines()[2].split()
    expected = len(brute_image_pairs(pos, 2.0, cell, (True, False, True))[0])
    assert expected > 100
    assert row[3] == row[4] == row[6] == str(expected) and row[5] == row[7] == "+0/-0"
