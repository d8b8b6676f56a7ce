"""The peers' own test suites, answered by granularsap's drop-ins.

ASE's neighbour-list tests (``ase.test.neighbor``, ``ase.test.test_cutoffs``,
the RDF test) and MDAnalysis's capped-distance, grid and neighbour-search
tests plus the RDF analyses on the serial and multiprocessing (forking)
backends (``MDAnalysisTests`` of the installed MDAnalysis version)
run in a separate pytest process with ``tests/_peer_plugin.py`` substituting
the drop-ins for ``ase.neighborlist.neighbor_list``/``primitive_neighbor_list``
and ``MDAnalysis.lib.distances.capped_distance``/``self_capped_distance``.  A
regression against the peers' own expectations fails here, naming the peer
test.  The ``ase.neighborlist`` doctests run in this process, one docstring
per test, so that the one documented difference is an xfail of its own.
"""

from __future__ import annotations

import doctest
import io
import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT = 300  # a hang (a fork gone wrong) fails instead of blocking CI


def _site(package):
    mod = pytest.importorskip(package)
    return Path(mod.__file__).resolve().parent.parent


def _run_peer(tmp_path, peers, package, targets, extra=()):
    """Run the peer's tests ``targets`` (paths under ``package``) with the drop-ins."""
    site = _site(package)
    ini = tmp_path / "pytest.ini"
    ini.write_text("[pytest]\nmarkers =\n    slow: peer marker\n")
    calls = tmp_path / "calls.json"
    junit = tmp_path / "junit.xml"
    # granularsap's own threading-layer choice (an OpenMP layer forced from
    # outside would make the multiprocessing backend hang, tests/test_fork.py)
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("PYTEST_") and k != "NUMBA_THREADING_LAYER"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    env["GRANULARSAP_PEERS"] = peers
    env["GRANULARSAP_PEER_CALLS"] = str(calls)
    env.setdefault("NUMBA_NUM_THREADS", "2")
    paths = [str(site / package / t) for t in targets]
    cmd = [sys.executable, "-m", "pytest", "-c", str(ini), "--rootdir", str(site),
           "--confcutdir", str(site), "-p", "tests._peer_plugin", "-p", "no:cacheprovider",
           "-q", "--no-header", "-rfE", f"--junitxml={junit}", *extra, *paths]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=TIMEOUT)
    failed = []
    total = 0
    if junit.exists():
        for case in ET.parse(junit).getroot().iter("testcase"):
            total += 1
            if case.find("failure") is not None or case.find("error") is not None:
                failed.append(f"{case.get('classname')}::{case.get('name')}")
    report = "\n".join(failed[:30]) + "\n" + proc.stdout[-4000:] + proc.stderr[-2000:]
    assert proc.returncode == 0 and not failed, report
    return total, json.loads(calls.read_text())


def test_ase_neighbor_tests(tmp_path):
    pytest.importorskip("ase")
    total, calls = _run_peer(tmp_path, "ase", "ase", [
        "test/neighbor", "test/test_cutoffs.py", "test/geometry/test_geometry_rdf.py"])
    assert total >= 40
    assert calls.get("ase.neighborlist.neighbor_list", 0) > 0
    assert calls.get("ase.neighborlist.primitive_neighbor_list", 0) > 0


def test_mdanalysis_distance_tests(tmp_path):
    pytest.importorskip("MDAnalysisTests")
    total, calls = _run_peer(tmp_path, "mdanalysis", "MDAnalysisTests", [
        "lib/test_distances.py", "lib/test_nsgrid.py", "lib/test_neighborsearch.py"],
        extra=["-k", "capped or Capped or test_issue or NeighborSearch or search"])
    assert total >= 2000
    assert calls.get("MDAnalysis.lib.distances.capped_distance", 0) > 1000
    assert calls.get("MDAnalysis.lib.distances.self_capped_distance", 0) > 100


def test_mdanalysis_nsgrid_tests_with_fastns_substituted(tmp_path):
    # the class itself: MDAnalysis.lib.nsgrid.FastNS (and every module-level binding of
    # it, MDAnalysis's own capped_distance grid paths included) is granularsap's
    pytest.importorskip("MDAnalysisTests")
    total, calls = _run_peer(tmp_path, "mdanalysis-fastns", "MDAnalysisTests",
                             ["lib/test_nsgrid.py"])
    assert total >= 30  # 34 in MDAnalysisTests 2.11
    assert calls.get("MDAnalysis.lib.nsgrid.FastNS", 0) >= 30


def test_ase_calculator_tests_with_neighborlist_substituted(tmp_path):
    # ASE's calculators that build an ase.neighborlist.NeighborList (Lennard-Jones,
    # Morse, EAM, EMT, Tersoff) and its NeighborList tests, on granularsap's class
    pytest.importorskip("ase")
    total, calls = _run_peer(tmp_path, "ase-neighborlist", "ase", [
        "test/calculator/test_lj.py", "test/calculator/test_morse.py",
        "test/calculator/test_eam.py", "test/calculator/test_tersoff.py",
        "test/neighbor/test_neighbor_initialization.py"])
    assert total >= 10
    assert calls.get("ase.neighborlist.NeighborList", 0) > 5


def test_mdanalysis_rdf_tests_serial_and_multiprocessing(tmp_path):
    # the multiprocessing backend forks after granularsap ran parallel kernels;
    # the dask backend's runs (client_InterRDF1, client_InterRDF_s1: a minute
    # of cluster start-ups, no fork of this process) are left out for time
    pytest.importorskip("MDAnalysisTests")
    total, calls = _run_peer(tmp_path, "mdanalysis", "MDAnalysisTests", [
        "analysis/test_rdf.py", "analysis/test_rdf_s.py"],
        extra=["-k", "not client_InterRDF1 and not client_InterRDF_s1"])
    assert total >= 80
    assert calls.get("MDAnalysis.lib.distances.capped_distance", 0) > 0


# ---------------------------------------------------------------------------
# ase.neighborlist doctests, one docstring per test

def _ase_doctests():
    try:
        import ase.neighborlist
    except ImportError:
        return {}
    finder = doctest.DocTestFinder()
    return {t.name: t for t in finder.find(ase.neighborlist) if t.examples}


_DOCTESTS = _ase_doctests()
_STRICTER = ("the example passes two per-atom cutoffs for a one-atom crystal; ASE ignores "
             "the surplus entry, granularsap requires one cutoff per atom "
             "(docs/dropins.md)")
_DOCTEST_XFAIL = {
    "ase.neighborlist.NewPrimitiveNeighborList": _STRICTER,
    "ase.neighborlist.NewPrimitiveNeighborList.get_neighbors": _STRICTER,
    "ase.neighborlist.PrimitiveNeighborList.get_neighbors": _STRICTER,  # same example
}


@pytest.mark.parametrize("name", [
    pytest.param(name, marks=pytest.mark.xfail(reason=_DOCTEST_XFAIL[name], strict=True,
                                               raises=ValueError))
    if name in _DOCTEST_XFAIL else name
    for name in sorted(_DOCTESTS)])
def test_ase_neighborlist_doctest(name, monkeypatch):
    import ase.neighborlist

    import granularsap.ase

    test = _DOCTESTS[name]
    globs = dict(test.globs)
    for attr in ("neighbor_list", "primitive_neighbor_list"):
        monkeypatch.setattr(ase.neighborlist, attr, getattr(granularsap.ase, attr))
        globs[attr] = getattr(granularsap.ase, attr)
    test = doctest.DocTest(test.examples, globs, test.name, test.filename, test.lineno,
                           test.docstring)
    runner = doctest.DebugRunner(verbose=False)
    with np.printoptions(legacy="1.13"):
        try:
            runner.run(test, out=io.StringIO().write)
        except doctest.UnexpectedException as exc:
            raise exc.exc_info[1].with_traceback(exc.exc_info[2]) from None
        except doctest.DocTestFailure as exc:
            pytest.fail(f"{name}: expected {exc.example.want!r}, got {exc.got!r}")
