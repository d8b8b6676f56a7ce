"""Smoke tests of the ``granularsap bench`` harness (tiny inputs, no timing assertions)."""

from __future__ import annotations

import json
import sys
import time
import types

import numpy as np
import pytest

from granularsap.bench import cli as bench_cli
from granularsap.bench import harness, peers, workloads
from granularsap.cli import main


def brute_pairs(workload, frame=0):
    """All pairs of a workload by the definition (minimum image, float64)."""
    n = workload.n
    i, j = np.triu_indices(n, k=1)
    pairs = np.stack([i, j], axis=1).astype(np.int64)
    return peers.exact_filter(workload, frame, pairs)


class Brute(peers.Peer):
    name = "brute"
    description = "O(n^2) definition"

    def run(self, frame):
        return brute_pairs(self.workload, frame)


class DropsOnePair(Brute):
    """A deliberately wrong adapter: loses one pair."""

    name = "wrong"

    def run(self, frame):
        return super().run(frame)[1:]


class SwapsOnePair(Brute):
    """Wrong in a way counts cannot see: same number of pairs, one different."""

    name = "wrong-same-count"

    def run(self, frame):
        pairs = super().run(frame).copy()
        pairs[0, 1] = next(j for j in range(self.workload.n)
                           if j > pairs[0, 0] and not np.any((pairs[:, 0] == pairs[0, 0])
                                                             & (pairs[:, 1] == j)))
        return pairs


class Fast(Brute):
    """Pairs computed in setup: runs take no time."""

    name = "granularsap"

    def setup(self, workload, n_threads):
        super().setup(workload, n_threads)
        self.pairs = brute_pairs(workload)

    def run(self, frame):
        return self.pairs


class Slow(Fast):
    """Every run takes 0.1 s."""

    name = "slow"

    def run(self, frame):
        time.sleep(0.1)
        return self.pairs


class NotInstalled(Brute):
    name = "not-installed"
    module = "granularsap_no_such_module_for_tests"


def _fake(name, base=Brute):
    return type(name.title().replace("-", ""), (base,), {"name": name})()


SMALL = {
    "md-liquid": lambda: workloads.md_liquid(300, seed=1),
    "md-liquid-open": lambda: workloads.md_liquid_open(300, seed=1),
    "granular-polydisperse": lambda: workloads.granular_polydisperse(400, seed=1),
    "paper-boxes": lambda: workloads.paper_boxes(300, seed=1, density=0.35),
}


class TestWorkloads:
    def test_same_seed_same_arrays(self):
        a = workloads.make("granular-polydisperse", 500, seed=3)
        b = workloads.make("granular-polydisperse", 500, seed=3)
        c = workloads.make("granular-polydisperse", 500, seed=4)
        np.testing.assert_array_equal(a.positions, b.positions)
        np.testing.assert_array_equal(a.radii, b.radii)
        assert not np.array_equal(a.positions, c.positions)

    def test_parameters(self):
        md = workloads.md_liquid(1000)
        assert md.n / np.prod(md.box[:3]) == pytest.approx(workloads.LJ_DENSITY)
        assert md.cutoff == 2.8 and workloads.md_liquid_open(1000).box is None
        gr = workloads.granular_polydisperse(2000)
        phi = np.sum(4 / 3 * np.pi * gr.radii**3) / np.prod(gr.box[:3])
        assert phi == pytest.approx(0.3)
        assert gr.radii.min() >= 0.3 and gr.radii.max() <= 3.0
        pb = workloads.paper_boxes(1000, density=0.2)
        lower, upper = pb.boxes()
        assert np.prod(upper - lower, axis=1).sum() / pb.params["world"] ** 3 \
            == pytest.approx(0.2, rel=0.05)
        tr = workloads.trajectory(300, n_frames=3)
        assert len(tr.frames) == 3 and np.all(tr.frames[2] < tr.box[0])

    def test_too_small_is_a_clear_error(self):
        with pytest.raises(ValueError, match="md-liquid needs n >= "):
            workloads.md_liquid(10)
        with pytest.raises(ValueError, match="unknown workload 'md'"):
            workloads.make("md", 100)

    @pytest.mark.parametrize("text, value", [("1e4", 10_000), ("2^18", 2**18),
                                             ("2**10", 1024), ("100k", 100_000), ("1M", 10**6),
                                             ("12345", 12345)])
    def test_sizes(self, text, value):
        assert bench_cli.parse_size(text) == value

    def test_bad_size(self):
        with pytest.raises(ValueError, match="cannot read size 'lots'"):
            bench_cli.parse_size("lots")


class TestPeersAgreeWithDefinition:
    """Every installed peer adapter returns exactly the brute-force pairs."""

    @pytest.mark.parametrize("wl_name", list(SMALL))
    @pytest.mark.parametrize("peer_name", [p for p in peers.PEERS if p != "granularsap"])
    def test_peer(self, peer_name, wl_name):
        peer = peers.PEERS[peer_name]()
        why = peer.missing()
        if why:
            pytest.skip(f"{peer_name} not available: {why}")
        wl = SMALL[wl_name]()
        why = peer.unsupported(wl)
        if why:
            pytest.skip(why)
        peer.setup(wl, 2)
        got = peer.run(0)
        assert got.dtype == np.int64 and np.all(got[:, 0] < got[:, 1])
        assert harness.canonical(got, wl.n) == harness.canonical(brute_pairs(wl), wl.n)

    @pytest.mark.parametrize("peer_name", ["granularsap-steady", "granularsap-identity",
                                           "vesin-verlet"])
    def test_stateful_peer_over_a_trajectory(self, peer_name):
        wl = workloads.trajectory(300, n_frames=4, step=0.3)
        peer = peers.PEERS[peer_name]()
        if peer.missing():
            pytest.skip(f"{peer_name} not available: {peer.missing()}")
        peer.setup(wl, 2)
        last = None
        for f in range(4):
            got = peer.run(f)
            assert harness.canonical(got, wl.n) == harness.canonical(brute_pairs(wl, f), wl.n)
            if peer_name == "granularsap-identity":
                # each pair's previous row is the same pair in the last frame's result
                rows = peer.engine.previous_rows
                want = ([-1] * len(got) if last is None else
                        [last.get((int(a), int(b)), -1) for a, b in got])
                assert rows.tolist() == want
                assert f == 0 or 0 < (rows >= 0).sum() < len(got)  # pairs kept, pairs new
                last = {(int(a), int(b)): r for r, (a, b) in enumerate(got)}


class TestAgreement:
    def test_wrong_adapter_is_caught(self, capsys):
        wl = SMALL["granular-polydisperse"]()
        results = bench_cli.execute(
            [("granular-polydisperse", 400)],
            [_fake("granularsap"), _fake("scipy-like"), DropsOnePair(), SwapsOnePair()],
            build=lambda name, n: wl, repeats=1, n_threads=1, max_seconds=60,
            settings={})
        wres = results[0]
        assert wres.disagreements == ["wrong", "wrong-same-count"]
        by = {r.peer: r for r in wres.results}
        assert by["wrong"].agrees is False and by["wrong"].ratio is None
        assert by["wrong-same-count"].pairs == by["granularsap"].pairs
        assert by["wrong-same-count"].ratio is None
        assert by["scipy-like"].agrees and by["scipy-like"].ratio is not None
        out = capsys.readouterr().out
        assert "!!! DISAGREEMENT on granular-polydisperse N=400" in out
        assert "!!! wrong: " in out and "not reported as a win" in out
        assert "!!! wrong-same-count:" in out and "same count, different pairs" in out
        table = out[out.index("granular-polydisperse N=400  [contacts"):]
        assert "DISAGREES" in table

    def test_granularsap_disagreeing_gets_no_ratio(self):
        wl = SMALL["md-liquid"]()
        wrong_gsap = _fake("granularsap", DropsOnePair)
        res = [harness.run_peer(p, wl, repeats=1) for p in
               (wrong_gsap, _fake("peer-a"), _fake("peer-b"))]
        wres = harness.judge(harness.WorkloadResult(
            name=wl.name, label=wl.label, kind=wl.kind, n=wl.n, n_frames=1, params={},
            results=res))
        assert wres.disagreements == ["granularsap"]
        assert wres.reference is None and wres.speedup_vs_fastest is None
        assert all(r.ratio is None for r in wres.results)

    def test_trajectory_peer_stopped_early_agrees_on_the_frames_it_ran(self):
        def result(peer, frame_pairs, digest):
            return harness.PeerResult(peer=peer, description="", threads=1, status="ok",
                                      pairs=frame_pairs[0], digest=digest,
                                      frame_pairs=frame_pairs, seconds=1.0, times=[1.0])

        full = [5, 6, 7, 8]
        wres = harness.judge(harness.WorkloadResult(
            name="trajectory", label="t", kind="cutoff", n=10, n_frames=4, params={},
            results=[result("granularsap", full, "aa/zz"), result("peer-a", full, "aa/zz"),
                     result("stopped", full[:2], "aa"), result("wrong", [5, 9], "aa")]))
        by = {r.peer: r.agrees for r in wres.results}
        assert by == {"granularsap": True, "peer-a": True, "stopped": True, "wrong": False}
        assert wres.disagreements == ["wrong"]

    def test_tie_has_no_consensus(self):
        assert harness.find_consensus({"a": (1, "x"), "b": (2, "y")}) is None
        assert harness.find_consensus({"a": (1, "x"), "b": (1, "x"), "c": (2, "y")}) \
            == ["a", "b"]

    def test_small_frame_extension_measures_no_memory(self, monkeypatch):
        # the planned runs reset and read the memory high-water mark; the added runs
        # of a small frame do not (that slows the run after it)
        measured = []

        class Counting(harness._PeakRSS):
            def __enter__(self):
                measured.append(True)
                return super().__enter__()

        monkeypatch.setattr(harness, "_PeakRSS", Counting)
        res = harness.run_peer(Fast(), SMALL["md-liquid"](), repeats=3, small_runs=40)
        assert res.status == "ok"
        assert len(res.times) == 40
        assert len(measured) == 3  # the planned runs only (a stateless peer: no fresh call)
        if harness.MEMORY_METHOD:
            assert res.peak_rss_mb is not None

    def test_failing_peer_is_reported_not_fatal(self):
        class Raises(Brute):
            name = "raises"

            def run(self, frame):
                raise RuntimeError("boom")

        res = harness.run_peer(Raises(), SMALL["md-liquid"](), repeats=1)
        assert res.status == "error" and "RuntimeError: boom" in res.reason

    @pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS on Linux")
    def test_peer_outgrowing_the_machine_is_reported_not_killed(self):
        class Greedy(Brute):
            name = "greedy"

            def run(self, frame):  # more than the machine has: the OOM killer's case
                return np.empty(harness._available_bytes() // 8 * 2)

        with harness.MemoryCeiling() as ceiling:
            if not ceiling.budget:
                pytest.skip("the address-space limit cannot be set here")
        res = harness.run_peer(Greedy(), SMALL["md-liquid"](), repeats=1)
        assert res.status == "error" and "ran out of memory" in res.reason
        np.ones(2**28 // 8)  # the ceiling is lifted afterwards


class TestCommand:
    def test_missing_peer_is_skipped_with_a_message(self, capsys):
        wl = SMALL["md-liquid"]()
        results = bench_cli.execute(
            [("md-liquid", 300)], [_fake("granularsap"), NotInstalled()],
            build=lambda name, n: wl, repeats=1, n_threads=1, max_seconds=60, settings={})
        out = capsys.readouterr().out
        assert "skipping peer not-installed: not available (ModuleNotFoundError" in out
        assert [r.peer for r in results[0].results] == ["granularsap"]

    def test_slow_peer_is_left_out_at_larger_sizes(self, capsys):
        sizes = {300: SMALL["md-liquid"](), 400: workloads.md_liquid(400, seed=1)}
        results = bench_cli.execute(
            [("md-liquid", 300), ("md-liquid", 400)],
            [Fast(), Slow()], build=lambda name, n: sizes[n], repeats=1,
            n_threads=1, max_seconds=0.05, settings={})
        out = capsys.readouterr().out
        assert "slow                 left out: took" in out
        assert [r.peer for r in results[1].results] == ["granularsap"]
        assert "timed once" in results[0].results[1].note

    def test_peer_predicted_too_slow_is_left_out(self, capsys):
        sizes = {300: SMALL["md-liquid"](), 3000: workloads.md_liquid(3000, seed=1)}
        results = bench_cli.execute(
            [("md-liquid", 300), ("md-liquid", 3000)], [Fast(), Slow()],
            build=lambda name, n: sizes[n], repeats=1, n_threads=1, max_seconds=0.2,
            settings={})
        out = capsys.readouterr().out
        assert "slow                 left out: its warm-up would take about 1 s" in out
        assert [r.peer for r in results[0].results] == ["granularsap", "slow"]
        assert [r.peer for r in results[1].results] == ["granularsap"]

    def test_json_and_png_are_written(self, tmp_path, capsys):
        jpath, ppath = tmp_path / "bench.json", tmp_path / "bench.png"
        rc = main(["bench", "md-liquid", "paper-boxes", "trajectory", "--sizes", "300",
                   "--frames", "3", "--repeats", "1", "--threads", "1",
                   "--peers", "scipy-ckdtree,vesin", "--json", str(jpath), "--plot", str(ppath)])
        out = capsys.readouterr().out
        assert rc == 0, out
        doc = json.loads(jpath.read_text())
        assert doc["schema"] == "granularsap-bench/1"
        assert doc["machine"]["cpu_model"] and doc["machine"]["logical_cores"] >= 1
        assert "numpy" in doc["machine"]["versions"]
        labels = [w["label"] for w in doc["workloads"]]
        assert labels == ["md-liquid N=300", "paper-boxes n=300 d=0.35",
                          "trajectory N=300 x 3 frames"]
        for w in doc["workloads"]:
            names = [r["peer"] for r in w["results"]]
            assert names[:2] == ["granularsap", "granularsap-steady"]
            assert not w["disagreements"], w
        assert ppath.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert "peer/gsap" in out

    def test_no_workload(self, capsys):
        assert main(["bench"]) == 2
        assert "give at least one WORKLOAD" in capsys.readouterr().err

    def test_unknown_peer(self, capsys):
        assert main(["bench", "md-liquid", "--peers", "nope"]) == 2
        assert "unknown peer 'nope'" in capsys.readouterr().err

    def test_list(self, capsys):
        assert main(["bench", "--list"]) == 0
        out = capsys.readouterr().out
        assert "mda-nsgrid" in out and "freud-linkcell" in out

    def test_paper_dispatches_to_the_engine_benchmark(self, monkeypatch):
        seen = {}
        fake = types.ModuleType("granularsap.bench.paper")
        fake.run_paper = lambda args: seen.setdefault("quick", args.quick) and 0
        monkeypatch.setitem(sys.modules, "granularsap.bench.paper", fake)
        assert main(["bench", "paper", "--quick"]) == 0
        assert seen == {"quick": True}

    def test_paper_unavailable(self, monkeypatch, capsys):
        monkeypatch.setitem(sys.modules, "granularsap.bench.paper", None)
        assert main(["bench", "paper"]) == 1
        assert "unavailable" in capsys.readouterr().err

    def test_paper_is_run_on_its_own(self, capsys):
        assert main(["bench", "paper", "md-liquid"]) == 2
        assert "run 'paper' on its own" in capsys.readouterr().err


# ------------------------------------------------------- peers our goals are measured against


def _lammps_or_skip():
    why = peers.LammpsRebuild().missing()
    if why:
        pytest.skip(f"LAMMPS not available: {why}")


def _triclinic_liquid(n=2000):
    """md-liquid points in a skewed periodic cell (rows of MDAnalysis's cell vectors)."""
    base = workloads.md_liquid(n, seed=3)
    length = base.box[0]
    box = np.array([length, 1.1 * length, 0.95 * length, 80.0, 100.0, 70.0])
    return workloads.Workload(name="triclinic", label="triclinic", kind="cutoff", n=n,
                              frames=[1.3 * base.positions - 3.0], cutoff=2.8, box=box)


SMOKE = {
    "md-liquid": lambda: workloads.md_liquid(2000, seed=1),
    "md-liquid-open": lambda: workloads.md_liquid_open(2000, seed=1),
    "granular-polydisperse": lambda: workloads.granular_polydisperse(2000, seed=1),
}


def _run_all_frames(peer, wl):
    """Run ``peer`` over every frame; assert each equals the brute-force pairs."""
    peer.setup(wl, 2)
    try:
        for f in range(len(wl.frames)):
            got = peer.run(f)
            assert got.dtype == np.int64 and np.all(got[:, 0] < got[:, 1])
            assert harness.canonical(got, wl.n) == harness.canonical(brute_pairs(wl, f), wl.n)
    finally:
        peer.close()


class TestLammpsRebuild:
    """LAMMPS's own list, rebuilt every step and self-timed, equals the definition."""

    @pytest.mark.parametrize("wl_name", list(SMOKE))
    def test_agrees_and_times_itself(self, wl_name):
        _lammps_or_skip()
        wl = SMOKE[wl_name]()
        peer = peers.LammpsRebuild()
        _run_all_frames(peer, wl)
        stats = peer.last_stats()
        assert stats["list_entries"] >= stats["pairs"] == len(brute_pairs(wl))
        assert peer.last_seconds() == pytest.approx(stats["seconds"]["neigh"]
                                                    + stats["seconds"]["comm"])
        assert 0 < peer.last_seconds() < stats["seconds"]["run_wall"]

    def test_triclinic(self):
        _lammps_or_skip()
        _run_all_frames(peers.LammpsRebuild(), _triclinic_liquid())

    def test_trajectory_frames_are_scattered(self):
        _lammps_or_skip()
        _run_all_frames(peers.LammpsRebuild(), workloads.trajectory(2000, n_frames=3, step=0.3))

    def test_uses_the_bench_threads(self):
        _lammps_or_skip()
        peer = peers.LammpsRebuild()
        peer.setup(SMOKE["md-liquid"](), 2)
        try:
            assert peer.threads_used(2) == (2 if peer.omp else 1)
            assert ("OPENMP package" in peer.description) == peer.omp
        finally:
            peer.close()


class TestLammpsRun0:
    def test_trajectory(self):
        _lammps_or_skip()
        peer = peers.LammpsRun0()
        wl = workloads.trajectory(2000, n_frames=3, step=0.3)
        _run_all_frames(peer, wl)
        assert peer.last_seconds() > 0

    def test_single_frame_is_left_to_lammps_rebuild(self):
        assert "lammps-rebuild times one frame" in peers.LammpsRun0().unsupported(
            SMOKE["md-liquid"]())


class TestNumbaCellList:
    @pytest.mark.parametrize("wl_name", list(SMOKE))
    def test_agrees(self, wl_name):
        _run_all_frames(peers.NumbaCellList(), SMOKE[wl_name]())

    def test_trajectory_reuses_buffers(self):
        _run_all_frames(peers.NumbaCellList(), workloads.trajectory(2000, n_frames=3, step=0.3))

    @pytest.mark.parametrize("wl_name", ["md-liquid", "granular-polydisperse"])
    def test_distances_and_threads(self, wl_name):
        from granularsap.bench.celllist import CellList

        wl = SMOKE[wl_name]()
        kw = {"cutoff": wl.cutoff} if wl.kind == "cutoff" else {"radii": wl.radii}
        one = [a.copy() for a in CellList(n_threads=1).compute(wl.positions, box=wl.box[:3],
                                                                **kw)]
        two = CellList(n_threads=2)
        pairs, dist = two.compute(wl.positions, box=wl.box[:3], **kw)
        np.testing.assert_array_equal(pairs, one[0])
        np.testing.assert_array_equal(dist, one[1])
        np.testing.assert_allclose(dist, peers.pair_distances(wl.positions, pairs, wl.box),
                                   rtol=1e-12)
        assert two.stats["pairs"] == len(pairs) <= two.stats["candidates_tested"]

    def test_small_periodic_cell_is_a_clear_error(self):
        from granularsap.bench.celllist import CellList

        with pytest.raises(ValueError, match="a periodic cell needs at least 3 bins per axis"):
            CellList().compute(np.zeros((4, 3)), cutoff=2.8, box=[7.0, 7.0, 7.0])
        assert "at least 3 bins" in peers.NumbaCellList().unsupported(SMALL["md-liquid"]())


class TestLammpsLog:
    LOG = """Loop time of 0.2 on 1 procs for 10 steps with 2000 atoms

Section |  min time  |  avg time  |  max time  |%varavg| %total
---------------------------------------------------------------
Pair    | 0.0001     | 0.0001     | 0.0001     |   0.0 |  0.04
Neigh   | 0.15       | 0.15       | 0.15       |   0.0 | 85.53
Comm    | 0.01       | 0.01       | 0.01       |   0.0 |  1.87
Other   |            | 0.04       |            |       |  7.90

Nlocal:         2000 ave        2000 max        2000 min
"""

    def test_sections(self, tmp_path):
        path = tmp_path / "log.lammps"
        path.write_text(self.LOG)
        assert peers.log_sections(path) == {"Pair": 0.0001, "Neigh": 0.15, "Comm": 0.01,
                                             "Other": 0.04}

    def test_no_breakdown_is_a_clear_error(self, tmp_path):
        path = tmp_path / "log.lammps"
        path.write_text("run 0 post no\n")
        with pytest.raises(RuntimeError, match="LAMMPS wrote no timer breakdown"):
            peers.log_sections(path)


class _Stateful(Fast):
    """A stateful peer whose stats carry candidate counts."""

    name = "stateful"
    stateful = True
    setups = 0

    def setup(self, workload, n_threads):
        super().setup(workload, n_threads)
        self.setups += 1

    def last_stats(self):
        return {"candidates_tested": 3 * len(self.pairs), "pairs": len(self.pairs)}


class _WrongWhenFresh(_Stateful):
    name = "wrong-when-fresh"

    def run(self, frame):
        return self.pairs[1:] if self.setups == 2 else self.pairs


class _SelfTimed(Fast):
    name = "self-timed"

    def last_seconds(self):
        return 123.0


class TestFreshAndSteady:
    def test_stateful_peer_gets_a_fresh_call_on_a_new_setup(self):
        wl = SMALL["md-liquid"]()
        peer = _Stateful()
        res = harness.run_peer(peer, wl, repeats=2)
        assert peer.setups == 2 and res.fresh_seconds is not None and len(res.times) == 2
        assert res.candidates_per_pair == pytest.approx(3.0)
        stateless = harness.run_peer(Fast(), wl, repeats=2)
        assert stateless.fresh_seconds is None and stateless.candidates_per_pair is None

    def test_fresh_call_that_differs_disagrees(self):
        wl = SMALL["md-liquid"]()
        res = [harness.run_peer(p, wl, repeats=1) for p in (Fast(), _fake("peer-a"),
                                                            _WrongWhenFresh())]
        wres = harness.judge(harness.WorkloadResult(
            name=wl.name, label=wl.label, kind=wl.kind, n=wl.n, n_frames=1, params={},
            results=res))
        assert wres.disagreements == ["wrong-when-fresh"]
        assert "the fresh call found" in res[2].note

    def test_self_timed_peer_reports_its_own_time(self):
        res = harness.run_peer(_SelfTimed(), SMALL["md-liquid"](), repeats=2)
        assert res.self_timed and res.times == [123.0, 123.0] and res.seconds == 123.0
        assert res.cpu_seconds is None and len(res.wall_times) == 2

    def test_table_columns(self, capsys):
        wl = SMALL["md-liquid"]()
        bench_cli.execute([("md-liquid", 300)], [Fast(), _Stateful(), _SelfTimed()],
                          build=lambda name, n: wl, repeats=1, n_threads=1, max_seconds=60,
                          settings={})
        out = capsys.readouterr().out
        table = out[out.index("md-liquid N=300  [cutoff"):]
        assert "fresh s" in table and "steady s" in table and "cand/pair" in table
        rows = {line.split()[0]: line.split() for line in table.splitlines()[3:6]}
        assert rows["granularsap"][2] == "=" and rows["stateful"][2] != "="
        assert rows["stateful"][6] == "3.00" and rows["self-timed"][3] == "123*"
