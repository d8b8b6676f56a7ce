"""Trajectory readers: LAMMPS dumps (own reader) against ASE and MDAnalysis."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from granularsap.io import DumpFormatError, Frame, box_to_cell, cell_to_box, iter_frames
from granularsap.io.lammps_dump import dump_frame_index, iter_lammps_dump
from granularsap.io.pipeline import engine_cell

from ._iohelpers import lammps_cell, lammps_or_skip, random_frames, write_dump
from .oracles import brute_image_pairs, sort_pairs

DATA = os.path.join(os.path.dirname(__file__), os.pardir, "data")
TRICLINIC = lammps_cell(8.0, 7.0, 9.0, xy=1.5, xz=-1.0, yz=0.7)
ORTHO = lammps_cell(8.0, 7.0, 9.0)


def mda_universe(path, **kw):
    import MDAnalysis as mda

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # guessed masses, no dt
        return mda.Universe(path, format="LAMMPSDUMP", **kw)


def mda_frames(u):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return [(ts.frame, u.atoms.positions.copy(), ts.dimensions.copy(), u.atoms.ids.copy())
                for ts in u.trajectory]


class TestLammpsDumpAgainstPeers:
    @pytest.mark.parametrize("cell", [ORTHO, TRICLINIC], ids=["ortho", "triclinic"])
    def test_shuffled_rows_match_ase_and_mdanalysis(self, tmp_path, cell):
        import ase.io

        frames = random_frames(60, 3, cell=cell, seed=1)
        path = tmp_path / "t.dump"
        write_dump(path, frames, shuffle_seed=7)
        ours = list(iter_frames(path))
        assert [f.index for f in ours] == [0, 1, 2]
        assert [f.step for f in ours] == [0, 1000, 2000]
        ase_frames = ase.io.read(path, format="lammps-dump-text", index=":")
        for fr, ref, at in zip(ours, frames, ase_frames, strict=True):
            np.testing.assert_array_equal(fr.ids, np.arange(1, 61))
            np.testing.assert_allclose(fr.positions, ref["positions"], rtol=0, atol=1e-12)
            np.testing.assert_allclose(fr.positions, at.positions, rtol=0, atol=1e-12)
            np.testing.assert_allclose(fr.cell, at.cell[:], rtol=0, atol=1e-12)
            np.testing.assert_array_equal(fr.pbc, [True, True, True])
        for fr, (idx, pos, dims, ids) in zip(ours, mda_frames(mda_universe(path)), strict=True):
            assert fr.index == idx
            np.testing.assert_array_equal(fr.ids, ids)
            np.testing.assert_allclose(fr.positions, pos, atol=2e-5)  # MDAnalysis is float32
            np.testing.assert_allclose(fr.box, dims, rtol=2e-6)

    @pytest.mark.parametrize("cell", [ORTHO, TRICLINIC], ids=["ortho", "triclinic"])
    @pytest.mark.parametrize("coords", ["x", "xu", "xs", "xsu"])
    def test_coordinate_columns_and_any_order(self, tmp_path, cell, coords):
        rng = np.random.default_rng(3)
        fr = random_frames(40, 1, cell=cell, seed=2)[0]
        fr["image"] = rng.integers(-2, 3, (40, 3))
        names = {"x": "x y z", "xu": "xu yu zu", "xs": "xs ys zs", "xsu": "xsu ysu zsu"}
        columns = ["id", "type", "diameter", "mol", "ix", "iy", "iz", *names[coords].split()]
        columns = [columns[k] for k in rng.permutation(len(columns))]
        path = tmp_path / "c.dump"
        origin = (-1.0, 2.0, 0.5)
        fr["positions"] = fr["positions"] + origin
        write_dump(path, [fr], columns=columns, shuffle_seed=5, origin=origin)
        (got,) = iter_frames(path)
        expect = fr["positions"]
        if coords in ("xu", "xsu"):
            expect = expect + fr["image"] @ cell
        np.testing.assert_allclose(got.positions, expect, rtol=0, atol=1e-9)
        np.testing.assert_allclose(got.origin, origin)
        np.testing.assert_allclose(got.radius, fr["radius"], rtol=1e-15)
        np.testing.assert_array_equal(got.columns["ix"], fr["image"][:, 0])
        assert got.molecule is not None and got.molecule.dtype == np.int64

    def test_coordinates_keyword_chooses_columns(self, tmp_path):
        fr = random_frames(10, 1, cell=ORTHO, seed=4)[0]
        fr["image"] = np.ones((10, 3), int)
        path = tmp_path / "both.dump"
        write_dump(path, [fr], columns=("id", "x", "y", "z", "xu", "yu", "zu"))
        (wrapped,) = iter_frames(path)
        (unwrapped,) = iter_frames(path, coordinates="xu")
        np.testing.assert_allclose(unwrapped.positions - wrapped.positions,
                                   np.tile(ORTHO.sum(axis=0), (10, 1)), atol=1e-12)
        with pytest.raises(ValueError, match="unknown coordinates 'q'"):
            list(iter_frames(path, coordinates="q"))

    def test_boundary_flags_and_frame_slice(self, tmp_path):
        frames = random_frames(20, 6, cell=ORTHO, seed=5)
        path = tmp_path / "s.dump"
        write_dump(path, frames, pbc="pp ff fm")
        got = list(iter_frames(path, frames=slice(1, 6, 2)))
        assert [f.index for f in got] == [1, 3, 5]
        assert [f.step for f in got] == [1000, 3000, 5000]
        np.testing.assert_array_equal(got[0].pbc, [True, False, False])
        np.testing.assert_allclose(got[1].positions, frames[3]["positions"], atol=1e-12)

    def test_string_columns_and_units_items(self, tmp_path):
        path = tmp_path / "el.dump"
        path.write_text("ITEM: UNITS\nlj\nITEM: TIME\n0.5\nITEM: TIMESTEP\n7\n"
                        "ITEM: NUMBER OF ATOMS\n2\nITEM: BOX BOUNDS pp pp pp\n0 5\n0 5\n0 5\n"
                        "ITEM: ATOMS element id x y z\nC 2 1 1 1\nO 1 2 2 2\n")
        (fr,) = iter_frames(path)
        assert fr.step == 7 and fr.time == 0.5
        np.testing.assert_array_equal(fr.types, ["O", "C"])
        np.testing.assert_array_equal(fr.positions[0], [2, 2, 2])


class TestBundledData:
    @pytest.mark.parametrize("name", ["lj.dump", "pour.dump", "clumps.dump"])
    def test_bundled_dumps_match_mdanalysis(self, name):
        path = os.path.join(DATA, name)
        if not os.path.exists(path):
            pytest.skip(f"data/{name} not generated")
        ours = list(iter_frames(path, frames=slice(0, None, 5)))
        ref = mda_frames(mda_universe(path))[::5]
        assert len(ours) == len(ref) > 1
        for fr, (idx, pos, dims, ids) in zip(ours, ref, strict=True):
            assert fr.index == idx
            np.testing.assert_array_equal(fr.ids, ids)
            # MDAnalysis moves the box origin to 0; we keep LAMMPS's coordinates (as ASE does)
            np.testing.assert_allclose(fr.positions - fr.origin, pos, atol=5e-5)
            np.testing.assert_allclose(fr.box, dims, rtol=2e-6)
        if name != "lj.dump":
            assert ours[0].radius is not None and not ours[0].pbc.any()
        if name == "clumps.dump":
            assert ours[0].molecule is not None

    def test_mdanalysis_reader_without_dt_is_quiet(self):
        """MDAnalysis warns "Reader has no dt information" on every frame of a LAMMPS
        dump; iter_frames silences that warning (only it) and keeps MDAnalysis's
        time, the step number (dt = 1.0)."""
        path = os.path.join(DATA, "lj.dump")
        if not os.path.exists(path):
            pytest.skip("data/lj.dump not generated")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            got = list(iter_frames(path, "mdanalysis:LAMMPSDUMP", frames=slice(0, 3)))
            warnings.warn("a warning of the caller's own", UserWarning, stacklevel=1)
        messages = [str(w.message) for w in caught]
        assert not [m for m in messages if "dt information" in m], messages
        assert "a warning of the caller's own" in messages  # the caller's filters are back
        ours = list(iter_frames(path, frames=slice(0, 3)))
        assert len(got) == 3
        assert [f.time for f in got] == [float(f.step) for f in ours]
        assert [f.step for f in got] == [f.step for f in ours]

    def test_bundled_pour_matches_ase(self):
        import ase.io

        path = os.path.join(DATA, "pour.dump")
        if not os.path.exists(path):
            pytest.skip("data/pour.dump not generated")
        at = ase.io.read(path, format="lammps-dump-text", index=-1)
        fr = list(iter_frames(path))[-1]
        np.testing.assert_allclose(fr.positions, at.positions, atol=1e-12)
        np.testing.assert_allclose(fr.cell, at.cell[:], atol=1e-12)


class TestTruncatedAndCorrupt:
    def _dump(self, tmp_path, n=30, k=3):
        path = tmp_path / "t.dump"
        write_dump(path, random_frames(n, k, cell=ORTHO, seed=9),
                   columns=("id", "type", "radius", "x", "y", "z"))
        return path, path.read_text().splitlines(keepends=True)

    def test_truncated_inside_atom_rows(self, tmp_path):
        path, lines = self._dump(tmp_path)
        per_frame = 9 + 30
        cut = 2 * per_frame + 9 + 12  # 12 atom rows of frame 2
        path.write_text("".join(lines[:cut]))
        got = []
        with pytest.raises(DumpFormatError,
                           match=rf"t\.dump: frame 2, line {cut}: truncated: expected 30 atom "
                                 r"rows, got 12"):
            for fr in iter_frames(path):
                got.append(fr.index)
        assert got == [0, 1]

    def test_truncated_inside_header(self, tmp_path):
        path, lines = self._dump(tmp_path)
        path.write_text("".join(lines[:39 + 5]))
        got = []
        with pytest.raises(DumpFormatError, match=r"frame 1, line \d+: .*(header|BOX BOUNDS)"):
            for fr in iter_frames(path):
                got.append(fr.index)
        assert got == [0]

    def test_last_line_cut_mid_row(self, tmp_path):
        path, lines = self._dump(tmp_path)
        text = "".join(lines)
        path.write_text(text[: len(text) - len(lines[-1]) // 2 - 1])
        got = []
        with pytest.raises(DumpFormatError, match=rf"frame 2, line {len(lines)}: truncated: the "
                                                  r"file ends in the middle of atom row 30 of 30 "
                                                  r"\(no end of line\): expected 6 values on an "
                                                  r"atom row, got \d"):
            for fr in iter_frames(path):
                got.append(fr.index)
        assert got == [0, 1]

    @pytest.mark.parametrize("item", ["TIMESTEP", "NUMBER OF ATOMS", "BOX BOUNDS"])
    def test_cut_inside_a_header_value(self, tmp_path, item):
        # a number cut short (2000 -> 20) must not be read as a smaller one
        path, lines = self._dump(tmp_path)
        at = 39 + next(k for k in range(9) if lines[39 + k].startswith(f"ITEM: {item}")) + 1
        for keep in range(1, len(lines[at]) - 1):
            path.write_text("".join(lines[:at]) + lines[at][:keep])
            got = []
            with pytest.raises(DumpFormatError, match=rf"frame 1, line {at + 1}: truncated: the "
                                                      r"file ends in the middle of a header line"):
                for fr in iter_frames(path):
                    got.append(fr.index)
            assert got == [0]

    def test_corrupt_number(self, tmp_path):
        path, lines = self._dump(tmp_path)
        bad = 39 + 9 + 4  # 0-based line index in frame 1
        parts = lines[bad].split()
        parts[3] = "1.0e+x"
        lines[bad] = " ".join(parts) + "\n"
        path.write_text("".join(lines))
        with pytest.raises(DumpFormatError, match=rf"frame 1, line {bad + 1}: column 'x'"):
            list(iter_frames(path))

    def test_garbage_between_frames(self, tmp_path):
        """Anything but a header line after a frame's atom rows is that frame's error,
        found before the frame is given (a reader of that frame alone finds it too)."""
        path, lines = self._dump(tmp_path)
        lines.insert(39, "hello\n")
        path.write_text("".join(lines))
        got = []
        with pytest.raises(DumpFormatError,
                           match=r"frame 0, line 40: NUMBER OF ATOMS says 30 atom rows but "
                                 r"more rows follow: 'hello' after atom row 30"):
            for fr in iter_frames(path):
                got.append(fr.index)
        assert got == []

    def test_more_rows_than_number_of_atoms_is_that_frames_error(self, tmp_path):
        """One more atom row than NUMBER OF ATOMS says: an error of that frame, on the
        whole-file reader and on the reader of that frame alone (a Dask worker's)."""
        from granularsap.io.lammps_dump import dump_frame_index, iter_lammps_dump

        path, lines = self._dump(tmp_path)
        extra = lines[39 + 9 + 29].split()
        extra[0] = "999"
        lines.insert(39 + 9 + 30, " ".join(extra) + "\n")  # after frame 1's 30 rows
        path.write_text("".join(lines))
        want = (r"frame 1, line 79: NUMBER OF ATOMS says 30 atom rows but more rows follow: "
                r"'999 ")
        got = []
        with pytest.raises(DumpFormatError, match=want):
            for fr in iter_frames(path):
                got.append(fr.index)
        assert got == [0]
        offsets, starts = dump_frame_index(path)
        with pytest.raises(DumpFormatError, match=want):
            list(iter_lammps_dump(path, frames=slice(0, 1),
                                  start_at=(offsets[1], starts[1], 1)))
        # the last frame too: rows after it where the file should end
        path, lines = self._dump(tmp_path)
        path.write_text("".join(lines) + lines[-1])
        with pytest.raises(DumpFormatError, match=r"frame 2, line 118: NUMBER OF ATOMS says 30"):
            list(iter_frames(path))

    @pytest.mark.parametrize("with_id", [True, False])
    def test_blank_line_among_atom_rows_names_it(self, tmp_path, with_id):
        """A blank line inside a frame's atom rows (which numpy's loadtxt skips) is an
        error on its line, not one atom fewer."""
        path = tmp_path / "t.dump"
        cols = ("id", "type", "x", "y", "z") if with_id else ("type", "x", "y", "z")
        write_dump(path, random_frames(20, 2, cell=ORTHO, seed=3), columns=cols)
        lines = path.read_text().splitlines(keepends=True)
        lines.insert(9 + 5, "\n")  # frame 0: a blank line after its 5th atom row
        path.write_text("".join(lines))
        got = []
        with pytest.raises(DumpFormatError, match=rf"frame 0, line 15: expected {len(cols)} "
                                                  r"values on an atom row, got 0"):
            for fr in iter_frames(path):
                got.append(fr.index)
        assert got == []

    def test_ids_beyond_float_precision_are_read_exactly(self, tmp_path):
        """LAMMPS's 64-bit atom ids (-DLAMMPS_BIGBIG) above 2**53: read as integers."""
        path = tmp_path / "t.dump"
        write_dump(path, random_frames(5, 1, cell=ORTHO, seed=3), columns=("id", "x", "y", "z"))
        lines = path.read_text().splitlines(keepends=True)
        big = [2**53 + 1, 2**53 + 3, 2**63 - 1, 7, 2**53 + 2]
        for k, value in enumerate(big):
            parts = lines[9 + k].split()
            parts[0] = str(value)
            lines[9 + k] = " ".join(parts) + "\n"
        path.write_text("".join(lines))
        (fr,) = iter_frames(path)
        assert fr.ids.dtype == np.int64 and fr.ids.tolist() == sorted(big)
        parts = lines[9].split()
        parts[0] = str(2**63)
        lines[9] = " ".join(parts) + "\n"
        path.write_text("".join(lines))
        with pytest.raises(DumpFormatError, match=r"frame 0, line 10: column 'id': "
                                                  r"'9223372036854775808' is not an integer"):
            list(iter_frames(path))

    def test_fewer_rows_than_number_of_atoms_names_the_frame_and_the_missing_rows(self,
                                                                               tmp_path):
        """Issue 20: not "expected 6 values, got 2" on the next frame's TIMESTEP line."""
        path, lines = self._dump(tmp_path)
        del lines[39 + 9 + 20:39 + 9 + 30]  # frame 1 keeps 20 of its 30 atom rows
        path.write_text("".join(lines))
        got = []
        with pytest.raises(DumpFormatError,
                           match=r"t\.dump: frame 1, line 69: NUMBER OF ATOMS says 30 atom rows "
                                 r"but the frame has only 20 \(10 missing\): 'ITEM: TIMESTEP' "
                                 r"comes after atom row 20"):
            for fr in iter_frames(path):
                got.append(fr.index)
        assert got == [0]

    def test_duplicate_id_names_the_line_of_the_second_row(self, tmp_path):
        path, lines = self._dump(tmp_path)
        first, second = 39 + 9 + 3, 39 + 9 + 17  # 0-based: atom rows 4 and 18 of frame 1
        parts = lines[second].split()
        parts[0] = lines[first].split()[0]
        lines[second] = " ".join(parts) + "\n"
        path.write_text("".join(lines))
        dup = lines[first].split()[0]
        with pytest.raises(DumpFormatError,
                           match=rf"frame 1, line {second + 1}: duplicate atom id {dup} \(atom "
                                 rf"row 18; atom row 4, line {first + 1}, has it too\)"):
            list(iter_frames(path))

    def test_error_survives_pickling(self, tmp_path):
        import pickle

        err = DumpFormatError("a.dump", 3, 17, "truncated")
        back = pickle.loads(pickle.dumps(err))
        assert str(back) == str(err) == "a.dump: frame 3, line 17: truncated"
        assert (back.path, back.frame, back.line) == ("a.dump", 3, 17)

    def test_frame_index_reads_frames_independently(self, tmp_path):
        path, lines = self._dump(tmp_path)
        offsets, starts = dump_frame_index(path)
        assert list(starts) == [1, 40, 79]
        assert all(lines[k - 1].startswith("ITEM: TIMESTEP") for k in starts)
        everything = list(iter_frames(path))
        for k in (2, 0, 1):
            (fr,) = iter_lammps_dump(path, frames=slice(0, 1),
                                     start_at=(offsets[k], starts[k], k))
            assert fr.index == k and fr.step == everything[k].step
            np.testing.assert_array_equal(fr.positions, everything[k].positions)
        text = "".join(lines)
        path.write_text(text[:-40])
        offsets, starts = dump_frame_index(path)
        with pytest.raises(DumpFormatError, match=r"frame 2, line 117: truncated: .* expected 6 "
                                                  r"values"):
            list(iter_lammps_dump(path, start_at=(offsets[2], starts[2], 2)))

    def test_missing_file(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="nope.dump"):
            list(iter_frames(tmp_path / "nope.dump"))

    def test_unknown_format(self, tmp_path):
        path, _ = self._dump(tmp_path)
        with pytest.raises(ValueError, match="unknown format 'pdbx'"):
            list(iter_frames(path, format="pdbx"))


class TestAseAndMDAnalysisFiles:
    def test_ase_traj_and_extxyz(self, tmp_path):
        import ase
        import ase.io

        rng = np.random.default_rng(0)
        images = []
        for k in range(3):
            a = ase.Atoms("Ar20", positions=rng.uniform(0, 6, (20, 3)),
                          cell=[[6, 0, 0], [1, 6, 0], [0.5, 0.5, 6]], pbc=[True, True, k != 1])
            a.set_array("radius", rng.uniform(0.2, 0.4, 20))
            images.append(a)
        for name in ("t.traj", "t.extxyz"):
            path = tmp_path / name
            ase.io.write(path, images)
            ref = ase.io.read(path, index=":")
            got = list(iter_frames(path))
            assert len(got) == 3
            for fr, at in zip(got, ref, strict=True):
                np.testing.assert_allclose(fr.positions, at.positions, atol=0)
                np.testing.assert_allclose(fr.cell, at.cell[:], atol=0)
                np.testing.assert_array_equal(fr.pbc, at.pbc)
                np.testing.assert_array_equal(fr.ids, np.arange(20))
                if name.endswith("extxyz"):  # .traj keeps standard arrays only
                    np.testing.assert_allclose(fr.radius, at.arrays["radius"])
            assert [f.index for f in iter_frames(path, frames=slice(1, 3))] == [1, 2]
            assert [f.index for f in iter_frames(path, frames=slice(0, None, 2))] == [0, 2]
            # a frame's index is its place in the file: slices from the end, or
            # backwards, would need the file's frames counted first
            for sel in (slice(-2, None), slice(None, None, -1), slice(0, -1)):
                with pytest.raises(ValueError, match="frames must be a slice with "
                                                     "non-negative start/stop"):
                    list(iter_frames(path, frames=sel))

    def test_ase_slab_with_zero_vector(self, tmp_path):
        import ase
        import ase.io

        granularsap = pytest.importorskip("granularsap")
        rng = np.random.default_rng(2)
        a = ase.Atoms("Ar60", positions=rng.uniform(0, 6, (60, 3)),
                      cell=[[6, 0, 0], [0, 6, 0], [0, 0, 0]], pbc=[True, True, False])
        path = tmp_path / "slab.traj"
        ase.io.write(path, a)
        (fr,) = iter_frames(path)
        np.testing.assert_array_equal(fr.pbc, [True, True, False])
        assert fr.box is None and fr.cell is not None
        radii = np.full(60, 0.6)
        got = granularsap.sphere_contacts(fr.positions, radii, box=engine_cell(fr))
        want, _ = brute_image_pairs(fr.positions, 0.0, cell=np.diag([6.0, 6.0, 1.0]),
                                    pbc=(True, True, False), radii=radii)
        np.testing.assert_array_equal(sort_pairs(np.sort(got, axis=1)), sort_pairs(want))

    def test_ase_periodic_axis_without_a_vector_is_an_error(self, tmp_path):
        import ase
        import ase.io

        from granularsap.io import TrajectoryError

        rng = np.random.default_rng(3)
        slab = ase.Atoms("Ar8", positions=rng.uniform(0, 3, (8, 3)),
                         cell=[[3, 0, 0], [0, 3, 0], [0, 0, 0]], pbc=[True, True, False])
        nocell = ase.Atoms("Ar8", positions=rng.uniform(0, 3, (8, 3)), pbc=[True, False, True])
        path = tmp_path / "bad.traj"
        ase.io.write(path, [slab, nocell])
        frames = iter_frames(path)
        assert next(frames).pbc.tolist() == [True, True, False]  # the good frame first
        with pytest.raises(TrajectoryError, match=r"frame 1: periodic along cell vectors 0, 2"):
            next(frames)

    def test_dcd_with_topology(self, tmp_path):
        import MDAnalysis as mda

        rng = np.random.default_rng(1)
        n = 25
        u = mda.Universe.empty(n, trajectory=True, atom_resindex=np.zeros(n, int))
        u.add_TopologyAttr("names", ["C"] * n)
        u.add_TopologyAttr("ids", np.arange(1, n + 1))
        u.atoms.positions = rng.uniform(0, 10, (n, 3))
        u.dimensions = [10, 11, 12, 90, 80, 70]
        pdb = tmp_path / "t.pdb"
        dcd = tmp_path / "t.dcd"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            u.atoms.write(pdb)
            with mda.Writer(str(dcd), n) as w:
                for _ in range(3):
                    u.atoms.positions = rng.uniform(0, 10, (n, 3))
                    w.write(u.atoms)
            ref = mda.Universe(str(pdb), str(dcd))
            want = [(ref.atoms.positions.astype(float), ts.dimensions.copy())
                    for ts in ref.trajectory]
            got = list(iter_frames(dcd, topology=pdb))
        assert len(got) == 3
        for fr, (pos, dims) in zip(got, want, strict=True):
            np.testing.assert_array_equal(fr.positions, pos)
            np.testing.assert_allclose(fr.box, dims, rtol=1e-6)


class TestCells:
    @pytest.mark.parametrize("box", [[10, 11, 12, 90, 90, 90], [10, 11, 12, 70, 100, 80]])
    def test_box_cell_roundtrip(self, box):
        from MDAnalysis.lib.mdamath import triclinic_vectors

        cell = box_to_cell(box)
        np.testing.assert_allclose(cell, triclinic_vectors(np.array(box, np.float32)),
                                   rtol=1e-6, atol=1e-5)
        np.testing.assert_allclose(cell_to_box(cell), box, rtol=1e-12)

    @pytest.mark.parametrize("pbc", [(True, True, False), (False, True, False),
                                     (True, False, True)])
    def test_partly_periodic_engine_cell_equals_image_oracle(self, pbc):
        granularsap = pytest.importorskip("granularsap")
        rng = np.random.default_rng(4)
        cell = TRICLINIC
        pos = rng.uniform(0, 1, (80, 3)) @ cell
        radii = rng.uniform(0.3, 0.8, 80)
        fr = Frame(index=0, positions=pos, ids=np.arange(80), cell=cell, pbc=np.array(pbc))
        box = engine_cell(fr)
        got = granularsap.sphere_contacts(pos, radii, box=box)
        want, _ = brute_image_pairs(pos, 0.0, cell=cell, pbc=pbc, radii=radii)
        np.testing.assert_array_equal(sort_pairs(np.sort(got, axis=1)), sort_pairs(want))


@pytest.fixture(scope="module")
def lammps_dumps(tmp_path_factory):
    """Dumps written by LAMMPS itself: triclinic, wrapped/unwrapped/scaled, unsorted rows."""
    lmp = lammps_or_skip()
    d = tmp_path_factory.mktemp("lammps")
    files = {k: str(d / f"{k}.dump") for k in ("x", "xu", "xs", "all")}
    lmp.commands_string(f"""
        units lj
        atom_style sphere
        boundary p p p
        atom_modify map array sort 5 1.0
        region box prism 0 8 0 7 0 9 1.5 -1.0 0.7
        create_box 2 box
        create_atoms 1 random 150 4321 NULL
        set type 1 diameter 0.8
        velocity all create 3.0 4928
        pair_style zero 1.0
        pair_coeff * *
        fix 1 all nve/sphere
        dump d1 all custom 20 {files['x']} id type diameter x y z
        dump d2 all custom 20 {files['xu']} xu yu zu type id
        dump d3 all custom 20 {files['xs']} id xs ys zs radius
        dump d4 all custom 20 {files['all']} id type x y z xu yu zu ix iy iz
        run 60
    """)
    lmp.close()
    return files



@pytest.mark.lammps
class TestDumpsWrittenByLammps:
    """Dumps written by LAMMPS itself: triclinic, wrapped/unwrapped/scaled, unsorted rows."""

    def test_wrapped_matches_ase_and_mdanalysis(self, lammps_dumps):
        dumps = lammps_dumps
        import ase.io

        ours = list(iter_frames(dumps["x"]))
        assert len(ours) == 4
        ase_frames = ase.io.read(dumps["x"], format="lammps-dump-text", index=":")
        mda = mda_frames(mda_universe(dumps["x"]))
        for fr, at, (_, pos, dims, ids) in zip(ours, ase_frames, mda, strict=True):
            np.testing.assert_array_equal(fr.ids, np.arange(1, 151))
            np.testing.assert_array_equal(fr.ids, ids)
            np.testing.assert_allclose(fr.positions, at.positions, rtol=0, atol=1e-12)
            np.testing.assert_allclose(fr.cell, at.cell[:], rtol=0, atol=1e-12)
            np.testing.assert_allclose(fr.positions - fr.origin, pos, atol=5e-5)
            np.testing.assert_allclose(fr.box, dims, rtol=2e-6)
            np.testing.assert_allclose(fr.radius, 0.4)
        np.testing.assert_allclose(ours[0].cell, lammps_cell(8, 7, 9, 1.5, -1.0, 0.7),
                                   atol=1e-12)

    def test_unwrapped_and_scaled_agree_with_wrapped(self, lammps_dumps):
        dumps = lammps_dumps
        full = list(iter_frames(dumps["all"]))
        unwrapped = list(iter_frames(dumps["xu"]))
        scaled = list(iter_frames(dumps["xs"]))
        moved = False
        for fa, fu, fs in zip(full, unwrapped, scaled, strict=True):
            image = np.column_stack([fa.columns[k] for k in ("ix", "iy", "iz")])
            moved |= bool(np.any(image))
            np.testing.assert_allclose(fu.positions, fa.positions + image @ fa.cell,
                                       rtol=1e-5, atol=1e-4)  # %g: 6 digits
            np.testing.assert_allclose(fs.positions, fa.positions, rtol=1e-5, atol=1e-4)
            np.testing.assert_allclose(fs.radius, 0.4)
        assert moved  # some atoms crossed a boundary, so xu differs from x


def test_degenerate_box_bounds_name_the_file_and_line(tmp_path):
    import pathlib

    data = pathlib.Path(__file__).resolve().parent.parent / "data"
    lines = (data / "lj.dump").read_text().splitlines()
    first = next(k for k, line in enumerate(lines) if line.startswith("ITEM: BOX"))
    lines[first + 1] = "0 0 0"
    path = tmp_path / "bad.dump"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DumpFormatError, match=r"bad.dump: frame 0, line \d+: BOX BOUNDS do not "
                                              r"describe a cell: bounds give xhi"):
        list(iter_frames(path))
