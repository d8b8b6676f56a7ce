"""``path="auto"`` decides from the frame alone: the same input gets the same
``stats["path"]`` (and reason) in every process, with a cold or a warm numba cache,
with one thread or two, whatever came before."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import granularsap.search.chooser as search_module
from granularsap import ContactSearch, NeighborSearch

ROOT = Path(__file__).resolve().parents[1]

#: the frames of the check, built the same way in this process and in the children
FRAMES = textwrap.dedent("""
    import numpy as np
    import granularsap.search.chooser as search_module
    from granularsap import ContactSearch, NeighborSearch

    def frames():
        rng = np.random.default_rng(11)
        # a small frame (the serial two-call path)
        pos = rng.uniform(0.0, 10.0, (500, 3))
        yield "small", NeighborSearch, (1.5,), (pos, [10.0] * 3 + [90.0] * 3), {}
        # a general column frame: spread sizes at volume fraction 0.3 (the size
        # floor of the rule lowered, so that the frame stays small)
        n = 3000
        radii = np.clip(rng.lognormal(0.0, 0.6, n), 0.3, 3.0)
        length = (np.sum(4.0 / 3.0 * np.pi * radii ** 3) / 0.3) ** (1.0 / 3.0)
        pos = rng.uniform(0.0, length, (n, 3))
        yield "columns", ContactSearch, (), (pos, radii, [length] * 3 + [90.0] * 3), {
            "min_n": 1000}
        # crowded columns of tiny spheres sized for a few large ones: the sweep
        radii = np.where(rng.random(n) < 0.01, 3.0, 0.1)
        pos = rng.uniform(0.0, 24.0, (n, 3))
        yield "sweep", ContactSearch, (), (pos, radii, [24.0] * 3 + [90.0] * 3), {
            "min_n": 1000}

    def paths():
        out = {}
        for name, cls, args, frame, opts in frames():
            for n_threads in (1, 2):
                old = search_module.SWEEP_MIN_N
                search_module.SWEEP_MIN_N = opts.get("min_n", old)
                try:
                    s = cls(*args, quantities="Pd", n_threads=n_threads)
                    if name != "small":
                        s._small_max = 0
                        s._levels = False
                    s.update(*frame)
                    out[f"{name} {n_threads}"] = [s.stats["path"], s.stats["path_reason"]]
                finally:
                    search_module.SWEEP_MIN_N = old
        return out
""")


def _paths_here():
    space = {}
    exec(FRAMES, space)
    return space["paths"]()


def _paths_in_child(cache_dir):
    code = FRAMES + "\nimport json\nprint(json.dumps(paths()))\n"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir), PYTHONPATH=str(ROOT))
    env.pop("GRANULARSAP_NO_CACHE", None)
    proc = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT, capture_output=True,
                          text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_the_rule_picks_each_path():
    got = _paths_here()
    assert {k: v[0] for k, v in got.items()} == {
        "small 1": "columns", "small 2": "columns", "columns 1": "columns",
        "columns 2": "columns", "sweep 1": "sweep", "sweep 2": "sweep"}
    # the reasons depend on the frame only, not on the thread count
    for name in ("small", "columns", "sweep"):
        assert got[f"{name} 1"] == got[f"{name} 2"]
    assert "500 particles" in got["small 1"][1]
    assert "candidates per pair" in got["columns 1"][1]
    assert "per particle) on 3000 particles" in got["columns 1"][1]
    assert "not above 1000 per pair and 200 per particle" in got["columns 1"][1]
    assert "above 1000 per pair and 200 per particle, the paper's sweep" in got["sweep 1"][1]


@pytest.mark.slow
def test_same_paths_in_fresh_processes_cold_and_warm_cache(tmp_path):
    here = _paths_here()
    cold = _paths_in_child(tmp_path / "numba-cache")  # an empty cache: everything compiles
    assert any((tmp_path / "numba-cache").rglob("*.nbi"))
    warm = _paths_in_child(tmp_path / "numba-cache")  # the same cache, now filled
    assert cold == here
    assert warm == here


def test_a_search_keeps_no_history_of_its_choice():
    # the paper's sweep chosen for one frame, the column sweep for the next, and
    # back: each frame is decided by itself
    rng = np.random.default_rng(12)
    n = 3000
    sparse_r = np.where(rng.random(n) < 0.01, 3.0, 0.1)
    sparse_x = rng.uniform(0.0, 24.0, (n, 3))
    dense_x = rng.uniform(0.0, 24.0, (n, 3))
    dense_r = np.full(n, 1.0)
    box = [24.0] * 3 + [90.0] * 3
    old = search_module.SWEEP_MIN_N
    search_module.SWEEP_MIN_N = 1000
    try:
        s = ContactSearch(quantities="Pd")
        s._small_max = 0
        s._levels = False
        seen = []
        for x, r in ((sparse_x, sparse_r), (dense_x, dense_r), (sparse_x, sparse_r)):
            s.update(x, r, box)
            seen.append((s.stats["path"], s.stats["path_reason"]))
    finally:
        search_module.SWEEP_MIN_N = old
    assert [p for p, _ in seen] == ["sweep", "columns", "sweep"]
    assert seen[0] == seen[2]


def test_predicted_candidates_follow_the_measured_ones():
    # the prediction behind the rule is within 25 % of what the sweep then tests
    rng = np.random.default_rng(13)
    n = 4000
    radii = np.clip(rng.lognormal(0.0, 0.6, n), 0.3, 3.0)
    length = (np.sum(4.0 / 3.0 * np.pi * radii ** 3) / 0.3) ** (1.0 / 3.0)
    pos = rng.uniform(0.0, length, (n, 3))
    for search, args in ((ContactSearch(quantities="Pd", path="columns"),
                          (pos, radii, [length] * 3 + [90.0] * 3)),
                         (NeighborSearch(2.5, quantities="Pd", path="columns"),
                          (pos, [length] * 3 + [90.0] * 3))):
        search._small_max = 0
        search._levels = False
        search.update(*args)
        st = search.stats
        measured = st["candidates_tested"] / st["pairs"]
        assert 0.75 < st["predicted_cpp"] / measured < 1.25


def test_forced_and_all_image_paths_say_why():
    pos = np.random.default_rng(14).uniform(0.0, 6.0, (50, 3))
    s = NeighborSearch(1.0, path="sweep")
    s.update(pos, [6.0] * 3 + [90.0] * 3)
    assert s.stats["path"] == "sweep" and s.stats["path_reason"] == "path='sweep' given"
    s = NeighborSearch(4.0, periodic_images="all")
    s.update(pos, [6.0] * 3 + [90.0] * 3)
    assert s.stats["path"] == "columns" and "every periodic image" in s.stats["path_reason"]
