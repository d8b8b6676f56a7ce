"""First run: one line on stderr when kernels compile; ``granularsap warmup``."""

from __future__ import annotations

import os
import subprocess
import sys

import numba
import pytest

from granularsap.cli import main
from granularsap.warmup import NOTICE, compile_notice

from ._iohelpers import lammps_cell, random_frames, write_dump


def fresh_kernel(module):
    """A new numba function that claims to live in ``module`` (compiled on first call)."""
    def add_one(x):
        return x + 1

    add_one.__module__ = module
    return numba.njit(add_one)


class TestCompileNotice:
    def test_once_for_our_kernels(self, capsys):
        with compile_notice() as counter:
            fresh_kernel("granularsap.kernels.fake")(1)
            fresh_kernel("granularsap.kernels.fake")(2.0)
        assert counter.count == 2
        assert capsys.readouterr().err == NOTICE + "\n"

    def test_silent_for_other_code_quiet_and_warm(self, capsys):
        kernel = fresh_kernel("granularsap.kernels.fake")
        with compile_notice() as counter:
            fresh_kernel("somebody_else")(1)
        assert counter.count == 0
        with compile_notice(quiet=True) as counter:
            kernel(1)
        assert counter.count == 1
        with compile_notice() as counter:
            kernel(3)  # compiled already: no event
        assert counter.count == 0
        assert capsys.readouterr().err == ""

    def test_warm_cli_run_says_nothing(self, tmp_path, capsys):
        dump = tmp_path / "w.dump"
        write_dump(dump, random_frames(30, 2, cell=lammps_cell(5, 5, 5)),
                   columns=("id", "radius", "x", "y", "z"))
        assert main(["contacts", str(dump), "-o", str(tmp_path / "a.h5"), "-q"]) == 0
        assert main(["contacts", str(dump), "-o", str(tmp_path / "b.h5")]) == 0
        assert "compiling" not in capsys.readouterr().err


class TestWarmupCommand:
    def test_reports_and_returns_zero(self, capsys):
        assert main(["warmup", "--only", "neighbor_pairs,sphere_contacts"]) == 0
        out = capsys.readouterr().out
        assert out.startswith("granularsap warmup: neighbor_pairs, sphere_contacts ready in ")
        assert "cache: " in out

    def test_unknown_function(self, capsys):
        assert main(["warmup", "--only", "kd_tree"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == ["granularsap warmup: error: unknown function 'kd_tree'; choose from "
                       "sphere_contacts, neighbor_pairs, clump_contacts, box_overlaps"]


@pytest.mark.slow
def test_cold_cache_says_so_once(tmp_path):
    """A real cold numba cache (NUMBA_CACHE_DIR empty): about 20 s of compiling."""
    dump = tmp_path / "c.dump"
    write_dump(dump, random_frames(60, 2, cell=lammps_cell(6, 6, 6)),
               columns=("id", "radius", "x", "y", "z"))

    def cli(*argv, cache):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
        env.pop("GRANULARSAP_NO_CACHE", None)
        return subprocess.run([sys.executable, "-m", "granularsap", *argv], env=env,
                              capture_output=True, text=True, timeout=600)

    cold = cli("contacts", str(dump), "-o", str(tmp_path / "a.h5"), cache=tmp_path / "c1")
    assert cold.returncode == 0, cold.stderr
    assert cold.stderr.count("compiling numba kernels") == 1
    assert cold.stderr.splitlines()[0] == NOTICE
    warm = cli("contacts", str(dump), "-o", str(tmp_path / "b.h5"), cache=tmp_path / "c1")
    assert warm.returncode == 0 and "compiling" not in warm.stderr
