"""The command line on wrong input: exit 2, one line of our own, nothing left behind."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap

import h5py
import numpy as np
import pytest

from granularsap.cli import main
from granularsap.io import ContactsFile, TrajectoryError, iter_frames

from ._iohelpers import lammps_cell, random_frames, write_dump
from .test_hdf5 import assert_same_contacts_file

ROOT = os.path.join(os.path.dirname(__file__), os.pardir)


@pytest.fixture
def dump(tmp_path):
    path = tmp_path / "good.dump"
    write_dump(path, random_frames(40, 3, cell=lammps_cell(6, 6, 6), seed=1),
               columns=("id", "type", "radius", "x", "y", "z"))
    return path


def leftovers(directory, stem):
    return sorted(n for n in os.listdir(directory) if n.startswith(stem))


def one_error_line(capsys):
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err and "Warning" not in captured.err
    return lines[0]


def make_input(kind, tmp_path):
    """A file (or directory) that is not a usable trajectory, and what the message says."""
    if kind == "empty.dump":
        p = tmp_path / "empty.dump"
        p.write_bytes(b"")
        return p, [r"empty\.dump is empty \(0 bytes\); expected a trajectory"]
    if kind == "empty.xyz":
        p = tmp_path / "empty.xyz"
        p.write_bytes(b"")
        return p, [r"empty\.xyz is empty \(0 bytes\)"]
    if kind == "blank.dump":
        p = tmp_path / "blank.dump"
        p.write_text("\n  \n\n")
        return p, [r"blank\.dump: no frames: read as a LAMMPS text dump, guessed from the file "
                   r"name and content, it holds none"]
    if kind == "README.md":
        p = tmp_path / "README.md"
        shutil.copy(os.path.join(ROOT, "README.md"), p)
        return p, [r"README\.md: no frames: read as ASE format '[\w-]+', guessed", "expected a "
                   "trajectory: a LAMMPS text dump, or a file ASE or MDAnalysis reads"]
    if kind == "README.dump":
        p = tmp_path / "README.dump"
        shutil.copy(os.path.join(ROOT, "README.md"), p)
        return p, [r"README\.dump: frame 0, line 1: not a LAMMPS text dump: expected "
                   r"'ITEM: TIMESTEP' on its first line"]
    if kind == "binary.bin":
        p = tmp_path / "binary.bin"
        p.write_bytes(np.arange(1000, dtype=np.float64).tobytes())
        return p, [r"binary\.bin: not a trajectory: ASE could not read it as 'bin' \(guessed",
                   "UnknownFileTypeError"]
    if kind == "noise.dat":
        p = tmp_path / "noise.dat"
        p.write_bytes(np.random.default_rng(0).bytes(3000))
        return p, [r"noise\.dat: not a trajectory: ASE could not read it as"]
    if kind == "lammps.in":  # ASE guesses FHI-aims and warns about its plugin
        p = tmp_path / "pour.in"
        shutil.copy(os.path.join(ROOT, "data", "pour.in"), p)
        return p, [r"pour\.in: not a trajectory: ASE could not read it as 'aims'"]
    if kind == "directory":
        p = tmp_path / "somedir"
        p.mkdir()
        return p, [r"somedir: not a trajectory: ASE could not read it as 'bundletrajectory'"]
    if kind == "contacts.h5":
        p = tmp_path / "contacts.h5"
        d = tmp_path / "d.dump"
        write_dump(d, random_frames(10, 1, cell=lammps_cell(5, 5, 5)))
        assert main(["contacts", str(d), "-o", str(p), "--cutoff", "1", "-q"]) == 0
        return p, [r"contacts\.h5: not a trajectory.*it is an HDF5 file: `granularsap info` "
                   "reads contacts files"]
    raise AssertionError(kind)


KINDS = ["empty.dump", "empty.xyz", "blank.dump", "README.md", "README.dump", "binary.bin",
         "noise.dat", "lammps.in", "directory", "contacts.h5"]


class TestNotATrajectory:
    @pytest.mark.parametrize("kind", KINDS)
    def test_exit_2_one_line_nothing_written(self, kind, tmp_path, capsys):
        import re

        path, messages = make_input(kind, tmp_path)
        out = tmp_path / "out.h5"
        assert main(["contacts", str(path), "-o", str(out), "--cutoff", "1"]) == 2
        line = one_error_line(capsys)
        assert line.startswith("granularsap contacts: error: ")
        for m in messages:
            assert re.search(m, line), line
        assert leftovers(tmp_path, "out.h5") == []

    @pytest.mark.parametrize("kind", ["empty.dump", "README.md", "binary.bin", "directory"])
    def test_reader_raises_trajectory_error(self, kind, tmp_path):
        path, messages = make_input(kind, tmp_path)
        with pytest.raises(TrajectoryError, match=messages[0]):
            list(iter_frames(path))

    def test_no_third_party_warning_reaches_stderr(self, tmp_path):
        path, _ = make_input("lammps.in", tmp_path)
        proc = subprocess.run([sys.executable, "-m", "granularsap", "contacts", str(path),
                               "-o", str(tmp_path / "o.h5"), "--cutoff", "1"],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "not a trajectory" in lines[0], proc.stderr
        assert "FutureWarning" not in proc.stderr and "aims" in lines[0]

    def test_mdanalysis_format_error_is_ours(self, tmp_path, capsys):
        path, _ = make_input("README.md", tmp_path)
        out = tmp_path / "o.h5"
        assert main(["contacts", str(path), "-o", str(out), "--cutoff", "1",
                     "--format", "mdanalysis:DCD"]) == 2
        line = one_error_line(capsys)
        assert "README.md: not a trajectory MDAnalysis can read as format 'DCD'" in line


class TestFrameSelection:
    @pytest.mark.parametrize("workers", [None, 2], ids=["serial", "dask"])
    def test_range_beyond_the_file(self, dump, tmp_path, capsys, workers):
        if workers:
            pytest.importorskip("distributed")
        out = tmp_path / "o.h5"
        argv = ["contacts", str(dump), "-o", str(out), "--frames", "100:200"]
        assert main(argv + (["--workers", str(workers)] if workers else [])) == 2
        line = one_error_line(capsys)
        assert ("frames 100:200:1 selects no frame of " in line
                and "good.dump, which has 3 frames (read as a LAMMPS text dump" in line), line
        assert leftovers(tmp_path, "o.h5") == []

    def test_empty_range(self, dump, tmp_path, capsys):
        out = tmp_path / "o.h5"
        assert main(["contacts", str(dump), "-o", str(out), "--frames", "2:2"]) == 2
        assert "selects no frame: STOP must be greater than START" in one_error_line(capsys)
        assert leftovers(tmp_path, "o.h5") == []

    def test_ase_range_beyond_the_file(self, tmp_path, capsys):
        import ase
        import ase.io

        xyz = tmp_path / "t.extxyz"
        ase.io.write(xyz, [ase.Atoms("Ar2", positions=[[0, 0, 0], [1, 0, 0]])] * 2)
        out = tmp_path / "o.h5"
        assert main(["contacts", str(xyz), "-o", str(out), "--cutoff", "1",
                     "--frames", "5:"]) == 2
        line = one_error_line(capsys)
        assert "frames 5::1 selects no frame of" in line and "ASE format 'extxyz'" in line

    def test_a_complete_file_is_never_written_for_zero_frames(self, dump, tmp_path):
        from granularsap.io import ContactParams, compute_contacts

        out = tmp_path / "o.h5"
        with pytest.raises(TrajectoryError, match="selects no frame"):
            compute_contacts(dump, out, ContactParams(), frames=slice(7, None))
        assert leftovers(tmp_path, "o.h5") == []


class TestOutputPath:
    @pytest.mark.parametrize("force", [False, True], ids=["plain", "force"])
    def test_existing_directory_fails_before_the_first_frame(self, dump, tmp_path, capsys,
                                                             monkeypatch, force):
        import granularsap.io.pipeline as pipeline

        def no_frames_please(*args, **kwargs):
            raise AssertionError("a frame was computed")

        monkeypatch.setattr(pipeline, "frame_contacts", no_frames_please)
        target = tmp_path / "outdir"
        target.mkdir()
        argv = ["contacts", str(dump), "-o", str(target)] + (["-f"] if force else [])
        assert main(argv) == 2
        line = one_error_line(capsys)
        assert f"output {target} is a directory; give a file name, e.g. " in line
        assert leftovers(tmp_path, "outdir") == ["outdir"] and not os.listdir(target)

    def test_missing_output_directory(self, dump, tmp_path, capsys):
        out = tmp_path / "nowhere" / "o.h5"
        assert main(["contacts", str(dump), "-o", str(out)]) == 2
        assert f"output directory {tmp_path / 'nowhere'} does not exist" in one_error_line(capsys)
        assert not (tmp_path / "nowhere").exists()

    def test_tmp_name_taken_by_a_directory(self, dump, tmp_path, capsys):
        out = tmp_path / "o.h5"
        (tmp_path / "o.h5.tmp").mkdir()
        assert main(["contacts", str(dump), "-o", str(out)]) == 2
        assert "o.h5.tmp is a directory" in one_error_line(capsys)
        assert leftovers(tmp_path, "o.h5") == ["o.h5.tmp"]

    def test_library_refuses_a_directory(self, dump, tmp_path):
        from granularsap.io import ContactParams, compute_contacts

        with pytest.raises(IsADirectoryError, match="is a directory; give a file name"):
            compute_contacts(dump, tmp_path, ContactParams(), overwrite=True)


class TestInfoOnWrongFiles:
    @pytest.mark.parametrize("kind", ["text", "empty", "directory", "plain-hdf5"])
    def test_names_the_file(self, kind, tmp_path, capsys):
        path = tmp_path / f"x-{kind}"
        if kind == "text":
            shutil.copy(os.path.join(ROOT, "README.md"), path)
            want = f"{path} is not a granularsap contacts file: not an HDF5 file ("
        elif kind == "empty":
            path.write_bytes(b"")
            want = f"{path} is not a granularsap contacts file: not an HDF5 file (empty)"
        elif kind == "directory":
            path.mkdir()
            want = f"{path} is a directory, not a granularsap contacts file"
        else:
            h5py.File(path, "w").close()
            want = f"{path} is not a granularsap contacts file (format attribute None)"
        assert main(["info", str(path)]) == 2
        assert want in one_error_line(capsys)


KILL_DURING_ASSEMBLY = textwrap.dedent("""
    import os, signal, sys
    import granularsap.io.hdf5 as hdf5
    original = hdf5._assemble
    def assemble_then_die(h5py, paths, target, empty):
        original(h5py, paths, target, empty)
        target.file.flush()
        os.kill(os.getpid(), signal.SIGKILL)  # before 'complete' is set and the rename
    hdf5._assemble = assemble_then_die
    from granularsap.cli import main
    sys.exit(main(sys.argv[1:]))
""")


class TestKillDuringAssembly:
    def test_rerun_cleans_the_torn_tmp_and_resumes_to_the_same_file(self, tmp_path, capsys):
        dump = tmp_path / "a.dump"
        write_dump(dump, random_frames(200, 12, cell=lammps_cell(9, 9, 9), seed=5),
                   columns=("id", "type", "radius", "x", "y", "z"))
        out = tmp_path / "a.h5"
        argv = ["contacts", str(dump), "-o", str(out), "--skin", "0.05", "--commit-seconds",
                "0", "-q"]
        proc = subprocess.run([sys.executable, "-c", KILL_DURING_ASSEMBLY, *argv],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == -signal.SIGKILL, proc.stderr
        tmp = tmp_path / "a.h5.tmp"
        assert tmp.exists() and not out.exists() and (tmp_path / "a.h5.partial").is_dir()
        with h5py.File(tmp, "r") as f:  # torn: not marked complete
            assert f.attrs["complete"] == 0
        with open(tmp, "r+b") as fh:  # and damaged, as a kill in mid-write may leave it
            fh.seek(os.path.getsize(tmp) // 2)
            fh.write(b"\0" * 4096)
        assert main(["info", str(out)]) == 1  # the committed frames are still there
        assert "INCOMPLETE" in capsys.readouterr().out
        assert main(argv[:-1]) == 0
        assert f"resuming {out}.partial after 12 complete frames" in capsys.readouterr().err
        assert leftovers(tmp_path, "a.h5") == ["a.h5"]
        with ContactsFile(out) as cf:
            assert cf.complete and cf.n_frames == 12
        ref = tmp_path / "ref.h5"
        assert main(["contacts", str(dump), "-o", str(ref), "--skin", "0.05", "-q"]) == 0
        assert_same_contacts_file(out, ref)


class TestValidateOnWrongInput:
    def test_empty_file_and_empty_selection(self, dump, tmp_path, capsys):
        path, messages = make_input("empty.dump", tmp_path)
        assert main(["validate", str(path), "--cutoff", "1", "--against", "mdanalysis"]) == 2
        assert "empty.dump is empty (0 bytes)" in one_error_line(capsys)
        assert main(["validate", str(dump), "--cutoff", "1", "--against", "mdanalysis",
                     "--frames", "50:60"]) == 2
        captured = capsys.readouterr()
        assert captured.out == ""
        assert captured.err.strip() == ("granularsap validate: error: --frames selects no "
                                        f"frame of {dump}")


def test_quick_start_outputs_are_ignored_by_git():
    if shutil.which("git") is None or not os.path.isdir(os.path.join(ROOT, ".git")):
        pytest.skip("not a git clone")
    names = ["pour-contacts.h5", "pour-contacts.png", "bench.json", "bench-md.json",
             "out.h5.partial/seg-000000.h5", "out.h5.tmp", "pour_contacts.h5", "dem_pour.png"]
    proc = subprocess.run(["git", "check-ignore", "--no-index", *names], cwd=ROOT,
                          capture_output=True, text=True, timeout=30)
    assert sorted(proc.stdout.split()) == sorted(names), proc.stdout


@pytest.mark.parametrize("bad", ["narrow cell", "far particle"])
def test_a_frame_the_search_refuses_is_named_and_the_frames_before_kept(tmp_path, capsys,
                                                                        bad):
    # a compressing run whose box shrinks below twice the range, or a particle thrown
    # far out: the engine's error names the file, the frame, its step and the particle
    frames = random_frames(30, 4, cell=lammps_cell(6, 6, 6), seed=3)
    frames[3]["step"] = 777
    ids = np.arange(30) + 101
    for f in frames:
        f["ids"] = ids
    if bad == "narrow cell":
        frames[3]["cell"] = lammps_cell(6, 6, 1.5)
        frames[3]["positions"] = frames[3]["positions"] * [1, 1, 0.25]
    else:
        frames[3]["positions"] = frames[3]["positions"].copy()
        frames[3]["positions"][5] = [1e300, 1.0, 1.0]
    path = tmp_path / "run.dump"
    write_dump(path, frames, columns=("id", "type", "radius", "x", "y", "z"))
    out = tmp_path / "run.h5"
    assert main(["contacts", str(path), "-o", str(out), "-q"]) == 2
    msg = one_error_line(capsys)
    assert "run.dump: frame 3 (step 777): " in msg
    from granularsap.io import ContactParams, FrameError, compute_contacts

    with pytest.raises(FrameError) as err:  # the same from Python, with its parts
        compute_contacts(path, tmp_path / "py.h5", ContactParams())
    assert (err.value.frame, err.value.step, err.value.source) == (3, 777, str(path))
    if bad == "far particle":
        assert "(row 5 is particle id 106)" in msg
    else:
        assert "smallest perpendicular cell width" in msg and "--open z" in msg
        assert "periodic_images" not in msg  # (not an option of the command line)
    assert "the 3 good frames before it are kept" in msg and "--frames 0:3" in msg
    # frames split into spatial domains over Dask workers: refused alike
    assert main(["contacts", str(path), "-o", str(tmp_path / "dom.h5"), "-q",
                 "--workers", "2", "--domain-particles", "10"]) == 2
    msg = one_error_line(capsys)
    assert "run.dump: frame 3 (step 777): " in msg and "--frames 0:3" in msg
    assert "periodic_images" not in msg
    if bad == "far particle":
        assert "(row 5 is particle id 106)" in msg
    assert main(["contacts", str(path), "-o", str(out), "-q", "--frames", "0:3"]) == 0
    with ContactsFile(out) as f:
        assert f.n_frames == 3
    # and validate names it alike
    assert main(["validate", str(path), "--against", "mdanalysis"]) == 2
    assert "run.dump: frame 3 (step 777): " in capsys.readouterr().err


def test_mdanalysis_asked_for_a_dump_names_the_format_that_reads_it(tmp_path, capsys):
    path = os.path.join(ROOT, "data", "lj.dump")
    out = tmp_path / "lj.h5"
    args = ["contacts", path, "-o", str(out), "--cutoff", "2.5", "-q", "--frames", "0:2"]
    assert main(args + ["--format", "mdanalysis"]) == 2
    assert "--format mdanalysis:LAMMPSDUMP" in one_error_line(capsys)
    assert main(args + ["--format", "mdanalysis:LAMMPSDUMP"]) == 0
