"""One writer per contacts file: a second run is refused at once, a killed run's lock dies.

Real processes throughout: ``python -m granularsap contacts`` runs started
together or while another holds the output, and a lock holder killed with
SIGKILL (the operating system must release its lock so the next run resumes).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from granularsap.cli import main
from granularsap.io import ContactsFile
from granularsap.io._lock import OutputBusyError, lock_path, output_lock

from ._iohelpers import lammps_cell, random_frames, write_dump
from .test_hdf5 import assert_same_contacts_file

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir)


@pytest.fixture(scope="module")
def long_dump(tmp_path_factory):
    """160 frames of 1,500 spheres: several seconds of work with a commit per frame."""
    path = tmp_path_factory.mktemp("lock") / "long.dump"
    write_dump(path, random_frames(1500, 160, cell=lammps_cell(30, 30, 30), seed=5,
                                   radius=(0.4, 0.9)),
               columns=("id", "type", "radius", "x", "y", "z"))
    return path


@pytest.fixture(scope="module")
def reference(long_dump, tmp_path_factory):
    """The contacts file of one uninterrupted run, alone."""
    ref = tmp_path_factory.mktemp("lockref") / "ref.h5"
    assert main(["contacts", str(long_dump), "-o", str(ref), "-q"]) == 0
    return ref


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([ROOT, env.get("PYTHONPATH", "")])
    return env


def _contacts(dump, out, *extra):
    cmd = [sys.executable, "-m", "granularsap", "contacts", str(dump), "-o", str(out), "-q",
           "--commit-seconds", "0", *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env())


def _segments(partial):
    try:
        return sum(n.endswith(".h5") for n in os.listdir(partial))
    except OSError:
        return 0


def _wait_for_segments(proc, partial, n):
    deadline = time.monotonic() + 120
    while _segments(partial) < n:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.02)


def _leftovers(out):
    return [p for p in (f"{out}.partial", f"{out}.tmp", lock_path(out)) if os.path.exists(p)]


class TestTwoWriters:
    def test_started_together_one_writes_the_other_is_refused(self, tmp_path, long_dump,
                                                              reference):
        out = tmp_path / "same.h5"
        procs = [_contacts(long_dump, out) for _ in range(2)]
        results = [(p.wait(timeout=300), *p.communicate()) for p in procs]
        codes = sorted(rc for rc, _, _ in results)
        assert codes == [0, 2], results
        (loser,) = [err for rc, _, err in results if rc == 2]
        lines = loser.strip().splitlines()
        assert len(lines) == 1, loser
        # the runs overlap (seconds of work each), so the loser meets the lock
        assert f"{out} is being written by another run (pid " in lines[0]
        with ContactsFile(out) as cf:
            assert cf.complete and cf.n_frames == 160
        assert_same_contacts_file(out, reference)
        assert _leftovers(out) == []

    def test_second_run_refused_at_once_while_the_first_goes_on(self, tmp_path, long_dump,
                                                                 reference):
        out = tmp_path / "busy.h5"
        first = _contacts(long_dump, out)
        _wait_for_segments(first, f"{out}.partial", 1)
        second = _contacts(long_dump, out)
        _, err = second.communicate(timeout=60)
        assert second.returncode == 2
        assert err.count("\n") == 1
        assert f"granularsap contacts: error: {out} is being written by another run " \
               f"(pid {first.pid})" in err
        assert first.poll() is None, "the refusal came too late to show it was at once"
        _, err = first.communicate(timeout=300)
        assert first.returncode == 0, err
        assert_same_contacts_file(out, reference)
        assert _leftovers(out) == []

    def test_killed_writer_releases_its_lock_and_the_next_run_resumes(self, tmp_path,
                                                                      long_dump, reference,
                                                                      capsys):
        out = tmp_path / "killed.h5"
        first = _contacts(long_dump, out)
        _wait_for_segments(first, f"{out}.partial", 3)
        first.send_signal(signal.SIGKILL)
        first.communicate(timeout=60)
        assert first.returncode == -signal.SIGKILL
        # the killed run never removed its lock file; the kernel released the lock itself
        assert os.path.exists(lock_path(out)) and not out.exists()
        with ContactsFile(out, allow_incomplete=True) as cf:
            done = cf.n_frames
        assert 3 <= done < 160
        assert main(["contacts", str(long_dump), "-o", str(out)]) == 0
        assert f"resuming {out}.partial after {done} complete frames" in capsys.readouterr().err
        assert_same_contacts_file(out, reference)
        assert _leftovers(out) == []


_HOLDER = """
import sys, time
from granularsap.io._lock import output_lock
with output_lock(sys.argv[1]):
    print("locked", flush=True)
    time.sleep(600)
"""


class TestLockHolder:
    def _holder(self, out):
        proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(out)], env=_env(),
                                stdout=subprocess.PIPE, text=True)
        assert proc.stdout.readline() == "locked\n"
        return proc

    def test_refusal_touches_nothing_and_the_holder_killed_frees_it(self, tmp_path,
                                                                    long_dump, reference,
                                                                    capsys):
        out = tmp_path / "held.h5"
        holder = self._holder(out)
        try:
            t0 = time.perf_counter()
            assert main(["contacts", str(long_dump), "-o", str(out), "-q"]) == 2
            assert time.perf_counter() - t0 < 5
            err = capsys.readouterr().err
            assert err == (f"granularsap contacts: error: {out} is being written by another "
                           f"run (pid {holder.pid}); wait for it to finish, or write to "
                           f"another file (lock {out}.lock)\n")
            assert not os.path.exists(f"{out}.partial") and not out.exists()
            with pytest.raises(OutputBusyError, match="is being written by another run"):
                with output_lock(out):
                    pass
        finally:
            holder.send_signal(signal.SIGKILL)
            holder.communicate(timeout=60)
        assert os.path.exists(lock_path(out))
        assert main(["contacts", str(long_dump), "-o", str(out), "-q"]) == 0
        assert_same_contacts_file(out, reference)
        assert _leftovers(out) == []

    def test_api_refuses_too(self, tmp_path, long_dump):
        from granularsap.io import ContactParams, compute_contacts

        out = tmp_path / "api.h5"
        holder = self._holder(out)
        try:
            with pytest.raises(OutputBusyError, match=r"api\.h5 is being written by another "
                                                      r"run \(pid \d+\)"):
                compute_contacts(long_dump, out, ContactParams(radius_column="radius"))
        finally:
            holder.send_signal(signal.SIGKILL)
            holder.communicate(timeout=60)


def _holder_pid(out):
    with open(lock_path(out)) as fh:
        return int(fh.read().split()[0])


class TestLockFile:
    def test_removed_on_release_and_taken_again(self, tmp_path):
        out = tmp_path / "x.h5"
        for _ in range(2):
            with output_lock(out):
                assert _holder_pid(out) == os.getpid()
            assert not os.path.exists(lock_path(out))

    def test_a_stale_lock_file_is_taken(self, tmp_path):
        out = tmp_path / "x.h5"
        with open(lock_path(out), "w") as fh:
            fh.write("999999 elsewhere\n")
        with output_lock(out):
            assert _holder_pid(out) == os.getpid()

    def test_lock_path_is_a_directory(self, tmp_path, long_dump):
        from granularsap.io import ContactParams, compute_contacts

        out = tmp_path / "d.h5"
        os.mkdir(lock_path(out))
        with pytest.raises(IsADirectoryError, match=r"d\.h5\.lock is a directory"):
            compute_contacts(long_dump, out, ContactParams(radius_column="radius"))
