"""First run: one line on stderr when kernels compile; ``granularsap warmup``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numba
import pytest

from granularsap.cli import main
from granularsap.warmup import NOTICE, compile_notice, warmup

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
    def test_reports_each_group_and_returns_zero(self, capsys):
        assert main(["warmup", "--only", "boxes,neighbor_pairs"]) == 0
        cap = capsys.readouterr()
        # an older function name stands for its group; groups run in their own order
        assert cap.out.startswith("granularsap warmup: contacts, boxes ready in ")
        assert "cache: " in cap.out
        err = cap.err.strip().splitlines()
        assert len(err) == 3 and err[0].startswith("granularsap warmup: compiling contacts, "
                                                   "boxes into ")
        assert err[1].startswith("granularsap warmup: [1/2] contacts ready in ")
        assert err[2].startswith("granularsap warmup: [2/2] boxes ready in ")
        assert main(["warmup", "--only", "boxes", "-q"]) == 0
        assert capsys.readouterr() == ("", "")

    def test_unknown_group(self, capsys):
        assert main(["warmup", "--only", "kd_tree"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == ["granularsap warmup: error: unknown group 'kd_tree'; choose from "
                       "contacts, search, boxes, dropins (or the older names sphere_contacts, "
                       "neighbor_pairs, clump_contacts for contacts; box_overlaps for boxes)"]
        with pytest.raises(ValueError, match="unknown group 'x'; choose from contacts, "):
            warmup(["x"])
        assert main(["warmup", "--only", ","]) == 2
        assert "--only names no group" in capsys.readouterr().err


DATA = os.path.join(os.path.dirname(__file__), os.pardir, "data")

#: what each warmup group must cover: the commands and searches a user runs
WORKLOADS = {
    "contacts": """
        from granularsap.cli import main
        for argv in (["contacts", f"{data}/pour.dump", "-o", f"{tmp}/pour.h5"],
                     ["info", f"{tmp}/pour.h5"],
                     ["contacts", f"{data}/lj.dump", "-o", f"{tmp}/lj.h5", "--cutoff", "2.5",
                      "--distances"],
                     ["contacts", f"{data}/clumps.dump", "-o", f"{tmp}/cl.h5", "--clumps"],
                     ["contacts", f"{data}/pour.dump", "-o", f"{tmp}/p2.h5", "--skin", "0.1",
                      "--threads", "1", "--frames", "::5"]):
            assert main([*argv, "-q"] if argv[0] == "contacts" else argv) == 0
        x = rng.uniform(0, 30, (25_000, 3))     # above the size that takes parallel kernels
        box = [30, 30, 30, 90, 90, 90]
        granularsap.neighbor_pairs(x, 1.0, box=box)
        granularsap.neighbor_pairs(x, 1.0, box=box, return_distances=True)
        granularsap.sphere_contacts(x, rng.uniform(0.1, 0.5, len(x)), box=box)
        granularsap.sphere_contacts(x, 0.4, box=[30, 30, 30, 80, 95, 85],
                                    pbc=(True, True, False), return_distances=True)
        granularsap.clump_contacts(x, 0.4, np.arange(len(x)) // 3, box=box)
        for path in ("columns", "sweep"):
            granularsap.NeighborSearch(1.0, path=path).update(x, box)
            granularsap.ContactSearch(path=path).update(x[:500], 0.6, box)
    """,
    "search": """
        x = rng.uniform(0, 30, (25_000, 3))
        cell = granularsap.Cell.from_dimensions([30, 30, 30, 90, 90, 90])
        for path in ("columns", "sweep"):
            for n in (2_000, 25_000):
                y = x[:n].copy()
                search = granularsap.NeighborSearch(2.5, rebuild_margin=0.3, path=path)
                for step in range(4):
                    y += rng.normal(0, 0.05, y.shape)
                    search.update(y, cell)
                c = granularsap.ContactSearch(skin=0.05, quantities="PdD", path=path,
                                              rebuild_margin=0.1)
                c.update(y, rng.uniform(0.3, 0.6, n), cell)
                granularsap.NeighborSearch(2.5, layout="csr", path=path).update(y, cell)
                granularsap.NeighborSearch(2.5, quantities="ijdDS", path=path).update(
                    y, [30, 30, 30, 80, 95, 85])
        granularsap.NeighborSearch(16.0, periodic_images="all", quantities="ijdDS").update(
            x[:300], cell)
        for ids in (np.arange(len(x)) + 7, rng.permutation(len(x)) * 1_000_003 + 2**40):
            for n in (500, 25_000):                      # serial and parallel kernels
                y = x[:n].copy()
                s = granularsap.ContactSearch(skin=0.05, quantities="PdD", identity=True)
                age = None
                for step in range(3):
                    y += rng.normal(0, 0.02, y.shape)
                    pairs, d, vec = s.update(y, 0.5, cell, ids=ids[:n],
                                             clump_ids=np.arange(n) // 2)
                    age = np.zeros(len(pairs), int) if age is None else s.carry(age, -1) + 1
                nb = granularsap.NeighborSearch(1.0, identity=True)
                nb.update(y, cell, ids=ids[:n])
                nb.update(y + 0.01, cell, ids=ids[:n])
        from granularsap.identity import ContactIdentity
        track = ContactIdentity()
        track.update(np.array([[7, 0, 3], [8, 0, 3]]))
        track.update(np.array([[8, 0, 3], [9, 1, 0]]))
        ids = np.arange(len(x)) + 1
        for n in (500, 25_000):                          # serial and parallel separations
            y = x[:n].copy()
            cl = granularsap.ContactList(rebuild_margin=0.2)
            for step in range(3):
                y += rng.normal(0, 0.05, y.shape)
                cl.update(y, 0.4, cell, ids=ids[:n])
                cl.separations(y)
    """,
    "boxes": """
        x = rng.uniform(0, 30, (40_000, 3))        # above the count that takes parallel kernels
        r = rng.uniform(0.1, 0.4, (len(x), 1))
        granularsap.box_overlaps(x - r, x + r)
        granularsap.box_overlaps(x[:500] - r[:500], x[:500] + r[:500])
        sap = granularsap.SweepAndPrune()
        for step in range(3):
            x += rng.normal(0, 0.01, x.shape)
            sap.update(x - r, x + r)
        granularsap.SweepAndPrune(path="columns").update(x - r, x + r)
    """,
    "dropins": """
        import warnings
        import ase
        import MDAnalysis as mda
        from granularsap.mda import capped_distance, self_capped_distance, FastNS
        from granularsap.ase import neighbor_list, NeighborList
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            u = mda.Universe(f"{data}/lj.dump", format="LAMMPSDUMP")
        x, box = u.atoms.positions, u.dimensions
        for cut in (1.5, 5.0):
            self_capped_distance(x, cut, box=box)
            capped_distance(x[:200], x, cut, box=box, return_distances=False)
            capped_distance(x[:200], x, cut)
        FastNS(2.5, x, box).self_search()
        atoms = ase.Atoms("Ar" * len(x), positions=x, pbc=True,
                          cell=u.trajectory.ts.triclinic_dimensions)
        neighbor_list("ijdDS", atoms, 2.5)
        neighbor_list("ij", atoms, {("Ar", "Ar"): 3.0})
        nl = NeighborList([1.2] * len(atoms), self_interaction=False, bothways=True)
        nl.update(atoms)
        nl.get_neighbors(5)
    """,
}


@pytest.mark.skipif(os.environ.get("GRANULARSAP_NO_CACHE", "0") not in ("", "0"),
                    reason="without the compile cache every subprocess compiles everything")
@pytest.mark.parametrize("group", sorted(WORKLOADS))
def test_warmup_group_covers_what_its_commands_run(group, tmp_path):
    """After ``warmup([group])`` the group's commands need no kernel signature more.

    A fresh process runs the warmup, notes every kernel signature compiled or loaded
    from the cache, runs the workload and reports any signature it added (with a warm
    disk cache that is one the warmup never asked for; with a cold one, one it would
    have left to compile).
    """
    script = tmp_path / "w.py"
    script.write_text("\n".join([
        "import json",
        "import numpy as np",
        "import granularsap",
        "from granularsap.warmup import kernel_signatures, warmup",
        f"data, tmp = {os.path.abspath(DATA)!r}, {str(tmp_path)!r}",
        f"warmup([{group!r}])",
        "before = kernel_signatures()",
        "rng = np.random.default_rng(0)",
        textwrap.dedent(WORKLOADS[group]),
        "with open('missing.json', 'w') as fh:",
        "    json.dump(sorted(kernel_signatures() - before), fh)",
    ]))
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=900, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    missing = json.loads((tmp_path / "missing.json").read_text())
    assert missing == [], f"{group}: the warmup misses {len(missing)} signatures: {missing}"


@pytest.mark.slow
def test_cold_cache_says_so_once_and_warmup_contacts_covers_the_quick_start(tmp_path):
    """A real cold numba cache (NUMBA_CACHE_DIR empty): the notice once; after
    ``warmup --only contacts`` on another cold cache, the quick start compiles nothing."""
    dump = tmp_path / "c.dump"
    write_dump(dump, random_frames(60, 2, cell=lammps_cell(6, 6, 6)),
               columns=("id", "radius", "x", "y", "z"))

    def cli(*argv, cache):
        env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
        env.pop("GRANULARSAP_NO_CACHE", None)
        return subprocess.run([sys.executable, "-m", "granularsap", *argv], env=env,
                              capture_output=True, text=True, timeout=900)

    cold = cli("contacts", str(dump), "-o", str(tmp_path / "a.h5"), cache=tmp_path / "c1")
    assert cold.returncode == 0, cold.stderr
    assert cold.stderr.count("compiling numba kernels") == 1
    assert cold.stderr.splitlines()[0] == NOTICE
    warm = cli("contacts", str(dump), "-o", str(tmp_path / "b.h5"), cache=tmp_path / "c1")
    assert warm.returncode == 0 and "compiling" not in warm.stderr

    ahead = cli("warmup", "--only", "contacts", cache=tmp_path / "c2")
    assert ahead.returncode == 0, ahead.stderr
    assert "[1/1] contacts ready in" in ahead.stderr and "compiled" in ahead.stderr
    quick = cli("contacts", os.path.join(DATA, "pour.dump"), "-o", str(tmp_path / "p.h5"),
                cache=tmp_path / "c2")
    assert quick.returncode == 0, quick.stderr
    assert "compiling" not in quick.stderr
    again = cli("warmup", "--only", "contacts", cache=tmp_path / "c2")
    assert "nothing to compile: every kernel came from the cache" in again.stdout
