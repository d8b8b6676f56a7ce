"""``granularsap contacts`` and ``granularsap info`` end to end, and interruption."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import h5py
import numba
import numpy as np
import pytest

import granularsap
from granularsap.cli import main
from granularsap.io import ContactsFile, IncompleteFileError, iter_frames

from ._iohelpers import lammps_cell, random_frames, write_dump
from .test_hdf5 import assert_same_contacts_file

DATA = os.path.join(os.path.dirname(__file__), os.pardir, "data")


def data_file(name):
    path = os.path.join(DATA, name)
    if not os.path.exists(path):
        pytest.skip(f"data/{name} not generated")
    return path


def id_pairs(frame, pairs):
    ids = np.sort(frame.ids[np.asarray(pairs).reshape(-1, 2)], axis=1)
    return ids[np.lexsort((ids[:, 1], ids[:, 0]))]


class TestBundledData:
    def test_pour_spheres_equal_sphere_contacts(self, tmp_path, capsys):
        dump = data_file("pour.dump")
        out = tmp_path / "pour.h5"
        assert main(["contacts", dump, "-o", str(out), "--frames", "0:21:4", "-q"]) == 0
        frames = list(iter_frames(dump, frames=slice(0, 21, 4)))
        with ContactsFile(out) as cf:
            assert cf.n_frames == len(frames) == 6
            total = 0
            for k, fr in enumerate(frames):
                want = granularsap.sphere_contacts(fr.positions, fr.radius, box=None)
                np.testing.assert_array_equal(cf.pairs(k), id_pairs(fr, want))
                total += len(want)
            assert total > 0
            np.testing.assert_array_equal(cf.step, [f.step for f in frames])
        assert main(["info", str(out), "--json"]) == 0
        s = json.loads(capsys.readouterr().out)
        assert s["complete"] and s["frames"] == 6 and s["n_particles"] == [2000] * 6
        assert sum(s["n_contacts"]) == total
        np.testing.assert_allclose(s["coordination"], 2 * np.array(s["n_contacts"]) / 2000)

    def test_lj_cutoff_with_distances_equal_neighbor_pairs(self, tmp_path):
        dump = data_file("lj.dump")
        out = tmp_path / "lj.h5"
        assert main(["contacts", dump, "-o", str(out), "--cutoff", "2.5", "--frames", "0:3",
                     "--distances", "-q"]) == 0
        with ContactsFile(out) as cf:
            for k, fr in enumerate(iter_frames(dump, frames=slice(0, 3))):
                pairs, dist = granularsap.neighbor_pairs(fr.positions, 2.5, box=fr.box)
                ids = np.sort(fr.ids[pairs], axis=1)
                order = np.lexsort((ids[:, 1], ids[:, 0]))
                np.testing.assert_array_equal(cf.pairs(k), ids[order])
                np.testing.assert_allclose(cf.distances(k), dist[order], rtol=1e-12)

    def test_mdanalysis_format_leaves_stderr_quiet(self, tmp_path):
        """`--format mdanalysis:LAMMPSDUMP` on a dump (no dt in the file): no
        "Reader has no dt information" on stderr, even with every warning shown."""
        dump = data_file("lj.dump")
        out = tmp_path / "lj.h5"
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env = dict(os.environ, PYTHONWARNINGS="always",
                   PYTHONPATH=os.pathsep.join(filter(None, [root,
                                                            os.environ.get("PYTHONPATH")])))
        proc = subprocess.run([sys.executable, "-m", "granularsap", "contacts", dump, "-o",
                               str(out), "--cutoff", "1.5", "--frames", "0:3",
                               "--format", "mdanalysis:LAMMPSDUMP", "-q"],
                              capture_output=True, text=True, env=env, timeout=300)
        assert proc.returncode == 0, proc.stderr
        assert "dt information" not in proc.stderr, proc.stderr
        with ContactsFile(out) as cf:
            assert cf.n_frames == 3
            np.testing.assert_array_equal(cf.time, cf.step.astype(float))

    def test_clumps_equal_clump_contacts(self, tmp_path):
        dump = data_file("clumps.dump")
        out = tmp_path / "cl.h5"
        assert main(["contacts", dump, "-o", str(out), "--clumps", "--frames", "10:21:10",
                     "-q"]) == 0
        with ContactsFile(out) as cf:
            for k, fr in enumerate(iter_frames(dump, frames=slice(10, 21, 10))):
                sp, cp = granularsap.clump_contacts(fr.positions, fr.radius, fr.molecule)
                np.testing.assert_array_equal(cf.pairs(k), id_pairs(fr, sp))
                cp = np.sort(cp, axis=1)
                np.testing.assert_array_equal(cf.clump_pairs(k),
                                              cp[np.lexsort((cp[:, 1], cp[:, 0]))])


class TestOtherFormats:
    def test_ase_extxyz_partly_periodic(self, tmp_path):
        import ase
        import ase.io

        from .oracles import brute_image_pairs

        rng = np.random.default_rng(6)
        images = []
        for _ in range(3):
            a = ase.Atoms("Ar40", positions=rng.uniform(0, 6, (40, 3)),
                          cell=[[6, 0, 0], [1, 6, 0], [0, 0, 6]], pbc=[True, True, False])
            a.set_array("radius", rng.uniform(0.3, 0.6, 40))
            images.append(a)
        xyz = tmp_path / "t.extxyz"
        ase.io.write(xyz, images)
        out = tmp_path / "x.h5"
        assert main(["contacts", str(xyz), "-o", str(out), "--skin", "0.05", "-q"]) == 0
        with ContactsFile(out) as cf:
            assert cf.parameters["source_format"] == "ase"
            for k, at in enumerate(images):
                want, _ = brute_image_pairs(at.positions, 0.05, cell=at.cell[:], pbc=at.pbc,
                                            radii=at.arrays["radius"])
                np.testing.assert_array_equal(cf.pairs(k), want)  # ids are 0..n-1 here
        out2 = tmp_path / "c.h5"
        assert main(["contacts", str(xyz), "-o", str(out2), "--cutoff", "1.0",
                     "--format", "ase:extxyz", "-q"]) == 0
        with ContactsFile(out2) as cf:
            want, _ = brute_image_pairs(images[2].positions, 1.0, cell=images[2].cell[:],
                                        pbc=images[2].pbc)
            np.testing.assert_array_equal(cf.pairs(2), want)


class TestInfo:
    def test_text_summary_and_plot(self, tmp_path, capsys):
        dump = tmp_path / "s.dump"
        write_dump(dump, random_frames(50, 4, cell=lammps_cell(5, 5, 5), seed=2),
                   columns=("id", "type", "diameter", "x", "y", "z"))
        out = tmp_path / "s.h5"
        assert main(["contacts", str(dump), "-o", str(out), "--skin", "0.1"]) == 0
        err = capsys.readouterr()
        assert f"wrote {out}: 4 frames (4 this run" in err.out
        assert "time share: read" in err.out
        png = tmp_path / "s.png"
        assert main(["info", str(out), "--plot", str(png)]) == 0
        text = capsys.readouterr().out
        with ContactsFile(out) as cf:
            n = cf.n_contacts
            born, died = int(cf.n_born.sum()), int(cf.n_died.sum())
        assert "status:        complete" in text
        assert "frames:        4" in text
        assert f"contacts/frame: min {n.min()}, mean {n.mean():.4g}, max {n.max()}" in text
        assert f"coordination:  min {2 * n.min() / 50:g}" in text
        assert f"births/deaths: {born} born, {died} died over 3 transitions" in text
        assert "skin 0.1" in text
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


    def test_damaged_file_is_one_line_naming_it(self, tmp_path, capsys):
        """A file damaged after it was written (bytes of a compressed chunk changed):
        one line naming the file, exit status 2, not a traceback."""
        dump = tmp_path / "s.dump"
        write_dump(dump, random_frames(50, 4, cell=lammps_cell(5, 5, 5), seed=2),
                   columns=("id", "type", "diameter", "x", "y", "z"))
        out = tmp_path / "s.h5"
        assert main(["contacts", str(dump), "-o", str(out), "-q"]) == 0
        with h5py.File(out, "r") as f:
            d = f["frames/n_contacts"]
            assert d.compression is not None
            info = d.id.get_chunk_info(0)
            at, size = info.byte_offset, info.size
        data = bytearray(out.read_bytes())
        for k in range(at, at + size):
            data[k] ^= 0xFF
        out.write_bytes(bytes(data))
        capsys.readouterr()
        assert main(["info", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(
            f"granularsap info: error: {out}: damaged contacts file, HDF5 cannot read it"), err


class TestErrors:
    def test_one_line_errors_and_exit_codes(self, tmp_path, capsys):
        dump = tmp_path / "e.dump"
        write_dump(dump, random_frames(10, 2, cell=lammps_cell(5, 5, 5)),
                   columns=("id", "x", "y", "z"))
        out = str(tmp_path / "e.h5")
        cases = [
            (["contacts", str(tmp_path / "missing.dump"), "-o", out], "does not exist"),
            (["contacts", str(dump), "-o", out], "no radius or diameter column"),
            (["contacts", str(dump), "-o", out, "--cutoff", "1", "--clumps"],
             "cutoff mode takes no skin and no clumps"),
            (["contacts", str(dump), "-o", out, "--radius-column", "q"],
             "no per-particle column 'q'"),
            (["info", str(tmp_path / "none.h5")], "does not exist"),
        ]
        for argv, message in cases:
            assert main(argv) == 2, argv
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and message in err[0], err
        assert main(["contacts", str(dump), "-o", out, "--cutoff", "1", "-q"]) == 0
        assert main(["contacts", str(dump), "-o", out, "--cutoff", "1", "-q"]) == 2
        assert "already exists; use --force" in capsys.readouterr().err
        assert main(["contacts", str(dump), "-o", out, "--cutoff", "1", "-q", "-f"]) == 0

    def test_too_many_threads_names_the_option(self, tmp_path, capsys):
        """Issue 20: the error names --threads, not n_threads / NUMBA_NUM_THREADS."""
        dump = tmp_path / "e.dump"
        write_dump(dump, random_frames(10, 1, cell=lammps_cell(5, 5, 5)),
                   columns=("id", "radius", "x", "y", "z"))
        top = numba.config.NUMBA_NUM_THREADS
        assert main(["contacts", str(dump), "-o", str(tmp_path / "e.h5"), "--threads",
                     "1000"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"granularsap contacts: error: --threads 1000 is more than the {top} "
                       "threads numba can run here (the cores, or NUMBA_NUM_THREADS if set); "
                       f"give --threads 1 to {top}"]
        assert not (tmp_path / "e.h5.partial").exists()
        assert main(["contacts", str(dump), "-o", str(tmp_path / "e.h5"), "--threads",
                     str(top), "-q"]) == 0

    def test_threads_help_and_docs_give_the_same_default(self):
        from granularsap.cli import build_parser

        sub = build_parser()._subparsers._group_actions[0].choices["contacts"]
        (action,) = [a for a in sub._actions if "--threads" in a.option_strings]
        with open(os.path.join(DATA, os.pardir, "docs", "cli.md")) as fh:
            docs = fh.read()
        (row,) = [line for line in docs.splitlines() if line.startswith("| `--threads N` |")]
        assert row.split("|")[2].strip().replace("`", "") == " ".join(action.help.split())

    @pytest.mark.parametrize("json_out", [False, True], ids=["text", "json"])
    def test_info_into_a_closed_pipe_exits_quietly(self, tmp_path, json_out):
        """Issue 20: `granularsap info f.h5 | head -1` said "[Errno 32] Broken pipe", exit 2."""
        dump = tmp_path / "p.dump"
        write_dump(dump, random_frames(20, 3, cell=lammps_cell(5, 5, 5)),
                   columns=("id", "radius", "x", "y", "z"))
        out = tmp_path / "p.h5"
        assert main(["contacts", str(dump), "-o", str(out), "-q"]) == 0
        read, write = os.pipe()
        os.close(read)  # the reader is gone before the first line
        try:
            proc = subprocess.run([sys.executable, "-m", "granularsap", "info", str(out),
                                   *(["--json"] if json_out else [])],
                                  stdout=write, stderr=subprocess.PIPE, text=True, timeout=120)
        finally:
            os.close(write)
        assert proc.stderr == ""
        assert proc.returncode == 141  # 128 + SIGPIPE, as a shell reports `head`'s writer

    @pytest.mark.parametrize("frames", ["a:b", "-1:", "0:5:0", "1:2:3:4"])
    def test_bad_frames_is_a_usage_error(self, tmp_path, frames, capsys):
        with pytest.raises(SystemExit) as exc:
            main(["contacts", "x.dump", "-o", str(tmp_path / "x.h5"), "--frames", frames])
        assert exc.value.code == 2
        assert "--frames" in capsys.readouterr().err

    def test_truncated_dump_keeps_good_frames(self, tmp_path, capsys):
        dump = tmp_path / "t.dump"
        write_dump(dump, random_frames(20, 3, cell=lammps_cell(5, 5, 5)),
                   columns=("id", "radius", "x", "y", "z"))
        lines = dump.read_text().splitlines(keepends=True)
        dump.write_text("".join(lines[:-3]))
        out = tmp_path / "t.h5"
        assert main(["contacts", str(dump), "-o", str(out), "-q"]) == 2
        assert "frame 2, line" in capsys.readouterr().err
        assert not out.exists()
        with ContactsFile(out, allow_incomplete=True) as cf:
            assert cf.n_frames == 2 and not cf.complete


    def test_truncated_dump_says_how_to_finish_without_the_damaged_frame(self, tmp_path,
                                                                         capsys):
        """Issue 20: a rerun stops at the same frame, so the message says what to do."""
        dump = tmp_path / "t.dump"
        write_dump(dump, random_frames(20, 4, cell=lammps_cell(5, 5, 5)),
                   columns=("id", "radius", "x", "y", "z"))
        lines = dump.read_text().splitlines(keepends=True)
        dump.write_text("".join(lines[:-3]))  # frame 3 loses its last rows
        out = tmp_path / "t.h5"
        for _ in range(2):  # the first run and the rerun stop at frame 3 and say why
            assert main(["contacts", str(dump), "-o", str(out), "-q"]) == 2
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1
            assert re.search(r"frame 3, line \d+: truncated: .*; the 3 good frames before it are "
                             r"kept in .*t\.h5\.partial, but running the same command again "
                             r"stops here again: to finish .*t\.h5 without frame 3 and the "
                             r"frames after it, run it with --frames 0:3 ", err[0]), err
        assert main(["contacts", str(dump), "-o", str(out), "--frames", "0:3"]) == 0
        assert "resuming" in capsys.readouterr().err  # the 3 frames were not computed again
        ref = tmp_path / "ref.h5"
        assert main(["contacts", str(dump), "-o", str(ref), "--frames", "0:3", "-q"]) == 0
        assert_same_contacts_file(out, ref)

    def test_a_trajectory_written_again_at_the_same_size_starts_over(self, tmp_path,
                                                                    capsys):
        """A partial run of a trajectory since overwritten by another one of the same
        size (another run of the same simulation) is not resumed with the new frames."""
        dump = tmp_path / "t.dump"
        write_dump(dump, random_frames(20, 4, cell=lammps_cell(5, 5, 5)),
                   columns=("id", "radius", "x", "y", "z"))
        lines = dump.read_text().splitlines(keepends=True)
        dump.write_text("".join(lines[:-3]))  # the run stops at frame 3
        out = tmp_path / "t.h5"
        assert main(["contacts", str(dump), "-o", str(out), "-q"]) == 2
        # the other run: every x moved by 0.5 in its first decimal, each line its length
        text = dump.read_text().splitlines(keepends=True)
        for k, line in enumerate(text):
            parts = line.split(" ")
            if len(parts) == 5 and "." in parts[2]:
                dot = parts[2].index(".") + 1
                digit = (int(parts[2][dot]) + 5) % 10
                parts[2] = parts[2][:dot] + str(digit) + parts[2][dot + 1:]
                text[k] = " ".join(parts)
        text = "".join(text)
        assert len(text) == dump.stat().st_size and text != dump.read_text()
        stamp = dump.stat().st_mtime_ns
        dump.write_text(text)
        os.utime(dump, ns=(stamp + 10**9, stamp + 10**9))
        capsys.readouterr()
        assert main(["contacts", str(dump), "-o", str(out), "--frames", "0:3"]) == 0
        err = capsys.readouterr().err
        assert "starting over: partial run of a trajectory modified since" in err
        assert "resuming" not in err
        ref = tmp_path / "ref.h5"
        assert main(["contacts", str(dump), "-o", str(ref), "--frames", "0:3", "-q"]) == 0
        assert_same_contacts_file(out, ref)

    def test_another_start_or_step_still_starts_over(self, tmp_path, capsys):
        dump = tmp_path / "t.dump"
        write_dump(dump, random_frames(20, 4, cell=lammps_cell(5, 5, 5)),
                   columns=("id", "radius", "x", "y", "z"))
        lines = dump.read_text().splitlines(keepends=True)
        dump.write_text("".join(lines[:-3]))
        out = tmp_path / "t.h5"
        assert main(["contacts", str(dump), "-o", str(out), "-q"]) == 2
        assert main(["contacts", str(dump), "-o", str(out), "--frames", "1:3"]) == 0
        err = capsys.readouterr().err
        assert "starting over: partial run with different parameters" in err
        assert "resuming" not in err


def _frames_done(partial):
    try:
        return sum(n.endswith(".h5") for n in os.listdir(partial))
    except OSError:
        return -1


@pytest.fixture(scope="module")
def slow_dump(tmp_path_factory):
    path = tmp_path_factory.mktemp("slow") / "slow.dump"
    write_dump(path, random_frames(1500, 40, cell=lammps_cell(30, 30, 30), seed=3,
                                   radius=(0.4, 0.9)),
               columns=("id", "type", "radius", "x", "y", "z"))
    return path


class TestInterruption:
    @pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["kill", "term"])
    def test_killed_run_is_incomplete_then_resumes_to_same_file(self, tmp_path, slow_dump,
                                                                sig, capsys):
        out = tmp_path / "k.h5"
        partial = tmp_path / "k.h5.partial"
        cmd = [sys.executable, "-m", "granularsap", "contacts", str(slow_dump), "-o", str(out),
               "--commit-seconds", "0", "-q"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 120
        while _frames_done(partial) < 3:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.02)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
        if sig == signal.SIGTERM:
            assert proc.returncode == 130
            assert "run the same command again to resume" in err
        else:
            assert proc.returncode == -signal.SIGKILL
        assert not out.exists() and partial.exists()
        with pytest.raises(IncompleteFileError):
            ContactsFile(out)
        with ContactsFile(out, allow_incomplete=True) as cf:
            done = cf.n_frames
        assert 3 <= done < 40
        assert main(["info", str(out)]) == 1
        assert "INCOMPLETE" in capsys.readouterr().out
        # resume (same command, in process), then compare with an uninterrupted run
        assert main(["contacts", str(slow_dump), "-o", str(out)]) == 0
        assert f"resuming {out}.partial after {done} complete frames" in capsys.readouterr().err
        assert not partial.exists()
        ref = tmp_path / "ref.h5"
        assert main(["contacts", str(slow_dump), "-o", str(ref), "-q"]) == 0
        assert_same_contacts_file(out, ref)

    def test_resumed_file_timing_counts_every_run(self, tmp_path):
        """Issue 20: the timing of a resumed file is the sum over its runs, not the last."""
        from granularsap.io import ContactParams, compute_contacts

        dump = tmp_path / "r.dump"
        write_dump(dump, random_frames(400, 6, cell=lammps_cell(9, 9, 9), seed=5),
                   columns=("id", "radius", "x", "y", "z"))
        out = tmp_path / "r.h5"
        params = ContactParams()
        written = []
        with pytest.raises(KeyboardInterrupt):  # stopped after three committed frames
            compute_contacts(dump, out, params, commit_seconds=0,
                             should_stop=lambda: written.append(1) or len(written) == 3)
        first = {"read": 0.0, "compute": 0.0, "write": 0.0, "wall": 0.0}
        partial = tmp_path / "r.h5.partial"
        for name in sorted(os.listdir(partial)):
            if name.endswith(".h5"):
                with h5py.File(partial / name) as f:
                    seg = json.loads(f.attrs["timing"])
                for k in first:
                    first[k] += seg[k]
        assert first["compute"] > 0 and first["wall"] >= first["compute"]
        second = compute_contacts(dump, out, params)["timing"]
        assert second["frames_this_run"] == 3
        with ContactsFile(out) as cf:
            timing = cf.timing
        assert timing["runs"] == 2
        for k in ("read", "compute", "wall"):
            assert timing[k] == pytest.approx(first[k] + second[k], rel=1e-12), k
        # (the summary's write time includes the final assembly, the file's cannot)
        assert first["write"] < timing["write"] <= first["write"] + second["write"]

    def test_no_resume_starts_over(self, tmp_path, capsys):
        from granularsap.io import ContactParams, ContactsWriter, frame_contacts

        out = tmp_path / "n.h5"
        small = tmp_path / "small.dump"
        write_dump(small, random_frames(30, 3, cell=lammps_cell(6, 6, 6), seed=4),
                   columns=("id", "radius", "x", "y", "z"))
        assert main(["contacts", str(small), "-o", str(out), "-q"]) == 0
        with h5py.File(out, "r") as f:
            params = json.loads(f.attrs["parameters"])
        os.remove(out)
        w = ContactsWriter(out, params, commit_seconds=0)  # a run killed after one frame
        w.append(frame_contacts(next(iter_frames(small)), ContactParams()))
        w.close()
        assert main(["contacts", str(small), "-o", str(out), "--no-resume"]) == 0
        assert "resuming" not in capsys.readouterr().err
        with ContactsFile(out) as cf:
            assert cf.n_frames == 3


class TestExample:
    def test_postprocess_pour_example(self, tmp_path, capsys):
        import importlib.util

        dump = data_file("pour.dump")
        path = os.path.join(os.path.dirname(__file__), os.pardir, "examples",
                            "postprocess_pour.py")
        spec = importlib.util.spec_from_file_location("postprocess_pour", path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        out, png = tmp_path / "p.h5", tmp_path / "p.png"
        mod.main(["--dump", dump, "--out", str(out), "--png", str(png)])
        text = capsys.readouterr().out
        assert "step  40000  Z = " in text and png.exists()
        with ContactsFile(out) as cf:
            z_last = 2 * cf.n_contacts[-1] / cf.n_particles[-1]
        assert f"step  40000  Z = {z_last:.3f}" in text


class TestWithoutIds:
    """A trajectory without particle ids: pairs are row numbers, and the file says so."""

    def test_dump_without_id_column_warns_and_records_rows(self, tmp_path, capsys):
        cell = lammps_cell(8.0, 8.0, 8.0)
        frames = random_frames(60, 3, cell=cell, seed=3)
        with_ids, without = tmp_path / "ids.dump", tmp_path / "rows.dump"
        write_dump(with_ids, frames, columns=("id", "type", "x", "y", "z"))
        write_dump(without, frames, columns=("type", "x", "y", "z"))
        for dump, index in ((with_ids, "id"), (without, "row")):
            out = tmp_path / f"{dump.stem}.h5"
            assert main(["contacts", str(dump), "-o", str(out), "--cutoff", "1.5", "-q"]) == 0
            err = capsys.readouterr().err
            assert ("no particle ids" in err) == (index == "row")
            with h5py.File(out) as f:
                assert f.attrs["pair_index"] == index
        with ContactsFile(tmp_path / "ids.h5") as a, ContactsFile(tmp_path / "rows.h5") as b:
            for k in range(3):  # rows kept their order here, so the pairs agree
                np.testing.assert_array_equal(a.pairs(k), b.pairs(k))

    def test_resumed_run_keeps_the_row_index(self, tmp_path):
        cell = lammps_cell(8.0, 8.0, 8.0)
        dump = tmp_path / "rows.dump"
        write_dump(dump, random_frames(40, 4, cell=cell, seed=4), columns=("type", "x", "y", "z"))
        out = tmp_path / "rows.h5"
        from granularsap.io import ContactParams, compute_contacts

        params = ContactParams(cutoff=1.5)
        written, told = [], []
        with pytest.raises(KeyboardInterrupt):  # stopped after two committed frames
            compute_contacts(dump, out, params, commit_seconds=0, on_warning=told.append,
                             should_stop=lambda: written.append(1) or len(written) == 2)
        assert len(told) == 1
        compute_contacts(dump, out, params, on_warning=told.append)
        with h5py.File(out) as f:
            assert f.attrs["pair_index"] == "row" and f.attrs["n_frames"] == 4


def test_a_lammps_2d_run_with_z_searched_open(tmp_path, capsys):
    # LAMMPS `dimension 2` writes a periodic z one unit thick with every z = 0: the
    # range exceeds half that width, so the search refuses it unless told z is open
    rng = np.random.default_rng(8)
    cell = lammps_cell(12, 12, 1.0)
    frames = []
    for k in range(3):
        pos = np.column_stack([rng.uniform(0, 12, 150), rng.uniform(0, 12, 150),
                               np.zeros(150)])
        frames.append({"positions": pos, "cell": cell, "radius": np.full(150, 0.5),
                       "step": 100 * k, "ids": rng.permutation(150) + 1})
    path = tmp_path / "twod.dump"
    write_dump(path, frames, columns=("id", "type", "radius", "x", "y", "z"),
               origin=(0.0, 0.0, -0.5))
    out = tmp_path / "twod.h5"
    assert main(["contacts", str(path), "-o", str(out), "-q"]) == 2
    msg = capsys.readouterr().err
    assert "twod.dump: frame 0 (step 0)" in msg and "--open z" in msg
    assert main(["contacts", str(path), "-o", str(out), "-q", "--open", "z",
                 "--distances"]) == 0
    with ContactsFile(out) as cf:
        assert cf.parameters["open_axes"] == "z"
        assert cf.pbc.tolist() == [[True, True, False]] * 3
        for k, fr in enumerate(frames):
            # brute force in the plane: x and y periodic (12 wide), z open
            d = fr["positions"][:, None, :] - fr["positions"][None, :, :]
            d[..., :2] -= 12.0 * np.round(d[..., :2] / 12.0)
            dist = np.sqrt((d ** 2).sum(-1))
            i, j = np.nonzero(np.triu(dist <= 1.0, 1))
            want = np.sort(np.column_stack([fr["ids"][i], fr["ids"][j]]), axis=1)
            want = want[np.lexsort((want[:, 1], want[:, 0]))]
            np.testing.assert_array_equal(cf.pairs(k), want)
    assert main(["validate", str(path), "--open", "z", "--against", "mdanalysis"]) == 0
    assert "identical" in capsys.readouterr().out
    # every z 0: MDAnalysis's stand-in cell is 2 x the reach thick, which float32 must
    # not round below twice the cutoff (1.3 is 1.29999995 in float32)
    assert main(["validate", str(path), "--open", "z", "--against", "mdanalysis",
                 "--cutoff", "1.3"]) == 0
    assert "identical" in capsys.readouterr().out
    for bad in ("w", "zz", ""):
        with pytest.raises(SystemExit) as exc:
            main(["contacts", str(path), "-o", str(out), "--open", bad])
        assert exc.value.code == 2
        assert "--open" in capsys.readouterr().err
    for bad in ((3,), 2, (2, 2), (True,), "z"):
        with pytest.raises(ValueError, match="open_axes must be distinct axis numbers"):
            granularsap.io.ContactParams(cutoff=1.0, open_axes=bad)
        with pytest.raises(ValueError, match="open_axes must be distinct axis numbers"):
            granularsap.compare.compare_trajectory(path, open_axes=bad)


def test_a_dump_with_cr_line_ends_gives_every_frame_on_workers(tmp_path):
    # the workers read frames from byte offsets found by a scan for line starts;
    # with old Mac line ends (CR only) the scan found the first frame alone, and a
    # one-frame file was written as complete
    from granularsap.io.lammps_dump import dump_frame_index

    lf = tmp_path / "lf.dump"
    write_dump(lf, random_frames(40, 4, cell=lammps_cell(6, 6, 6), seed=4),
               columns=("id", "type", "radius", "x", "y", "z"))
    cr = tmp_path / "cr.dump"
    cr.write_bytes(lf.read_bytes().replace(b"\n", b"\r"))
    for a, b in zip(dump_frame_index(lf), dump_frame_index(cr), strict=True):
        np.testing.assert_array_equal(a, b)
    assert len(dump_frame_index(cr)[0]) == 4
    outs = []
    for name, extra in (("serial", []), ("workers", ["--workers", "2"])):
        out = tmp_path / f"{name}.h5"
        assert main(["contacts", str(cr), "-o", str(out), "-q", *extra]) == 0
        outs.append(out)
    with ContactsFile(outs[0]) as a, ContactsFile(outs[1]) as b:
        assert a.n_frames == b.n_frames == 4
        for k in range(4):
            np.testing.assert_array_equal(a.pairs(k), b.pairs(k))
