"""Fork safety: a process that ran granularsap's parallel kernels can fork.

numba's default layer on Linux, GNU OpenMP, kills a forked child ("fork()
called from a process already using GNU OpenMP, this is unsafe") and a
``multiprocessing`` pool then waits forever.  granularsap picks a fork-safe
layer at import unless the application chose one (granularsap/_numba.py).
Every fork below has a timeout, so a hang fails the test instead of blocking.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numba
import numpy as np
import pytest

import granularsap
from granularsap import _numba

from .oracles import sort_pairs

ROOT = Path(__file__).resolve().parents[1]
BOX = [10.0, 10.0, 10.0, 90.0, 90.0, 90.0]
TIMEOUT = 120


def _run(code, env_extra=None, timeout=TIMEOUT):
    """Run ``code`` in a fresh interpreter; return its last stdout line as JSON."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    env.setdefault("NUMBA_NUM_THREADS", "2")
    env.update(env_extra or {})
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


#: enough points that a frame with n_threads=2 runs the parallel kernels (small frames
#: run serial kernels whatever the thread count)
_POINTS = "np.random.default_rng(0).random((8000, 3)) * 10"

_FORK_AFTER_PARALLEL = f"""
    import json, multiprocessing
    import numba, numpy as np
    {{prelude}}
    import granularsap
    from granularsap import _numba
    pos = {_POINTS}

    def count(_):
        return len(granularsap.neighbor_pairs(pos, 1.0, box={BOX}, n_threads=2)[0])

    parent = count(0)  # a parallel kernel runs before the fork
    with multiprocessing.get_context("fork").Pool(2) as pool:
        children = pool.map_async(count, range(2)).get(timeout=60)
    print(json.dumps(dict(layer=numba.threading_layer(), set=_numba.THREADING_LAYER_SET,
                          parent=parent, children=children)))
"""


def _child_pairs(pos):
    return granularsap.neighbor_pairs(pos, 1.2, box=BOX, n_threads=2)[0]


def _min_image_pairs(pos, cutoff, length):
    """Brute force, cubic cell: every pair ``i < j`` with minimum image ``d <= cutoff``."""
    dx = pos[None, :, :] - pos[:, None, :]
    dx -= length * np.round(dx / length)
    i, j = np.nonzero(np.triu(np.sqrt((dx * dx).sum(axis=2)) <= cutoff, 1))
    return np.stack([i, j], axis=1)


def _expected_count():
    pos = np.random.default_rng(0).random((8000, 3)) * 10
    return len(granularsap.neighbor_pairs(pos, 1.0, box=BOX)[0])


class TestForkAfterParallelCall:
    def test_in_this_process(self):
        # the test process has run parallel kernels (below, and in other tests)
        # a frame large enough for the parallel kernels (small frames run serial ones)
        granularsap.neighbor_pairs(np.random.default_rng(2).random((8000, 3)) * 10, 1.0,
                                   box=BOX, n_threads=2)
        pos = np.random.default_rng(1).random((2000, 3)) * 10
        want = sort_pairs(granularsap.neighbor_pairs(pos, 1.2, box=BOX, n_threads=2)[0])
        if numba.threading_layer() == "omp":
            pytest.skip("the environment chose numba's OpenMP layer (NUMBA_THREADING_LAYER); "
                        "GNU OpenMP is not fork-safe")
        ctx = multiprocessing.get_context("fork")
        with ctx.Pool(2) as pool:
            got = pool.map_async(_child_pairs, [pos, pos]).get(timeout=60)
        for pairs in got:
            assert np.array_equal(sort_pairs(pairs), want)
        assert np.array_equal(want, sort_pairs(_min_image_pairs(pos, 1.2, BOX[0])))

    def test_default_picks_a_fork_safe_layer(self):
        out = _run(_FORK_AFTER_PARALLEL.format(prelude=""))
        assert out["set"] in ("tbb", "workqueue") and out["layer"] == out["set"]
        assert out["children"] == [out["parent"]] * 2 == [_expected_count()] * 2

    def test_workqueue_when_tbb_cannot_load(self):
        # tbbpool unimportable: the fallback is numba's built-in workqueue layer
        prelude = "import sys; sys.modules['numba.np.ufunc.tbbpool'] = None"
        out = _run(_FORK_AFTER_PARALLEL.format(prelude=prelude))
        assert out["set"] == "workqueue" and out["layer"] == "workqueue"
        assert out["children"] == [out["parent"]] * 2

    @pytest.mark.parametrize("layer", ["workqueue", "tbb"])
    def test_environment_choice_is_kept(self, layer):
        out = _run(_FORK_AFTER_PARALLEL.format(prelude=""), {"NUMBA_THREADING_LAYER": layer})
        assert out["set"] is None and out["layer"] == layer
        assert out["children"] == [out["parent"]] * 2


class TestApplicationChoice:
    def test_numba_config_set_before_import_is_kept(self):
        out = _run(f"""
            import json, numba, numpy as np
            numba.config.THREADING_LAYER = "omp"
            import granularsap
            from granularsap import _numba
            granularsap.neighbor_pairs({_POINTS}, 1.0, n_threads=2)
            print(json.dumps([numba.threading_layer(), _numba.THREADING_LAYER_SET]))
        """)
        assert out == ["omp", None]

    def test_environment_omp_is_kept(self):
        out = _run(f"""
            import json, numba, numpy as np
            import granularsap
            from granularsap import _numba
            granularsap.neighbor_pairs({_POINTS}, 1.0, n_threads=2)
            print(json.dumps([numba.threading_layer(), _numba.THREADING_LAYER_SET]))
        """, {"NUMBA_THREADING_LAYER": "omp"})
        assert out == ["omp", None]

    def test_numba_config_set_after_import_still_wins(self):
        out = _run(f"""
            import json, numba, numpy as np
            import granularsap
            numba.config.THREADING_LAYER = "workqueue"
            granularsap.neighbor_pairs({_POINTS}, 1.0, n_threads=2)
            print(json.dumps(numba.threading_layer()))
        """)
        assert out == "workqueue"

    def test_layer_recorded_in_this_process(self):
        assert _numba.THREADING_LAYER_SET in (None, "tbb", "workqueue")
        if "NUMBA_THREADING_LAYER" in os.environ:
            assert _numba.THREADING_LAYER_SET is None


def test_workqueue_concurrent_threads_do_not_abort():
    # workqueue aborts the process when two threads launch parallel regions at
    # once; granularsap serialises its kernels under that layer
    out = _run(f"""
        import json, threading, numpy as np
        import granularsap
        pos = {_POINTS}
        counts = []

        def work():
            for _ in range(15):
                counts.append(len(granularsap.neighbor_pairs(pos, 1.0, box={BOX})[0]))

        threads = [threading.Thread(target=work) for _ in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        print(json.dumps(sorted(set(counts))))
    """, {"NUMBA_THREADING_LAYER": "workqueue"})
    assert out == [_expected_count()]


def test_mdanalysis_multiprocessing_backend_with_granularsap_distances():
    # MDAnalysis's multiprocessing backend forks; InterRDF answered by
    # granularsap's capped_distance must give the serial MDAnalysis result
    pytest.importorskip("MDAnalysis")
    out = _run("""
        import json
        import numpy as np
        import MDAnalysis as mda
        import MDAnalysis.lib.distances as mdadist
        from MDAnalysis.analysis.rdf import InterRDF
        from MDAnalysis.coordinates.memory import MemoryReader
        import granularsap.mda as gmda

        rng = np.random.default_rng(0)
        frames = (np.round(rng.random((6, 300, 3)) * 12 * 64) / 64).astype(np.float32)
        u = mda.Universe.empty(300, trajectory=True)
        u.load_new(frames, format=MemoryReader,
                   dimensions=np.array([12, 12, 12, 90, 90, 90], np.float32))
        a, b = u.atoms[:150], u.atoms[150:]
        want = InterRDF(a, b, nbins=40, range=(0.0, 4.0)).run().results.count
        mdadist.capped_distance = gmda.capped_distance
        # one parallel granularsap call in the parent before the pool forks
        gmda.capped_distance(a.positions, b.positions, 4.0, box=u.dimensions)
        got = InterRDF(a, b, nbins=40, range=(0.0, 4.0)).run(
            backend="multiprocessing", n_workers=2).results.count
        print(json.dumps([want.tolist(), got.tolist()]))
    """)
    want, got = out
    assert sum(want) > 0 and got == want
