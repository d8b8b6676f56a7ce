"""Frames whose pairs cannot fit in memory are refused at once, frames that fit never are.

The refusal rests on a lower bound of the pair count (``granularsap._memory``):
checked here against brute force on every cell kind, at exact ties, with every
image, and end to end under a real address-space limit in a child process.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import granularsap
from granularsap import NeighborSearch
from granularsap._memory import available_memory, bytes_per_pair, pair_lower_bound

from .oracles import brute_full_image_list, brute_image_pairs

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir)


def _cell(kind, rng):
    """(matrix, pbc) of a cell kind."""
    if kind == "open":
        return None, np.zeros(3, bool)
    if kind == "cube":
        m = np.diag([4.0, 4.0, 4.0])
    elif kind == "slab":
        m = np.diag([4.0, 5.0, 3.0])
    else:
        m = np.array([[4.0, 0, 0], [1.3, 3.7, 0], [-0.9, 1.1, 3.9]])
    pbc = np.array([True, True, kind != "slab"])
    return m, pbc


def _engine_view(x, matrix, pbc):
    """The fractional coordinates and full cell the search gives the estimate."""
    if matrix is None:
        return np.array(x, dtype=np.float64), np.eye(3)
    t = np.linalg.solve(matrix.T, x.T).T
    t[:, pbc] -= np.floor(t[:, pbc])
    return t, matrix


class TestLowerBound:
    @settings(max_examples=60)
    @given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 70),
           kind=st.sampled_from(["open", "cube", "slab", "triclinic"]),
           frac=st.floats(0.1, 0.49), lattice=st.booleans())
    def test_never_above_the_brute_force_count(self, seed, n, kind, frac, lattice):
        rng = np.random.default_rng(seed)
        matrix, pbc = _cell(kind, rng)
        widths = (granularsap.Cell(matrix, True).perpendicular_widths if matrix is not None
                  else np.full(3, 4.0))
        cutoff = frac * float(widths.min())
        if lattice:  # points on a grid of the cutoff's spacing: many pairs at d == cutoff
            grid = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3)
            x = grid[rng.permutation(len(grid))[:n]] * cutoff
        else:
            x = rng.uniform(0, 4.0, (n, 3))
        t, cell = _engine_view(x, matrix, pbc)
        lb, _ = pair_lower_bound(t, cell, pbc, cutoff, cells=4096)
        pairs, d = brute_image_pairs(x, cutoff, matrix, pbc)
        assert lb <= len(pairs)
        assert lb <= int(np.sum(d < cutoff))  # include_cutoff=False counts no tie either

    @settings(max_examples=30)
    @given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 25),
           kind=st.sampled_from(["cube", "slab", "triclinic"]), frac=st.floats(0.2, 1.6))
    def test_every_image_never_above_the_brute_force_count(self, seed, n, kind, frac):
        rng = np.random.default_rng(seed)
        matrix, pbc = _cell(kind, rng)
        cutoff = frac * 4.0
        x = rng.uniform(0, 4.0, (n, 3))
        t, cell = _engine_view(x, matrix, pbc)
        lb, _ = pair_lower_bound(t, cell, pbc, cutoff, all_images=True, cells=512)
        i, _, _, _ = brute_full_image_list(x, cutoff, matrix, pbc)
        assert 2 * lb <= len(i)  # the full list holds each image pair both ways

    @pytest.mark.parametrize("kind", ["open", "cube", "triclinic"])
    def test_close_to_the_count_on_a_dense_frame(self, kind):
        # a bound that said 0 would never refuse anything: it must hold most pairs
        rng = np.random.default_rng(7)
        matrix, pbc = _cell(kind, rng)
        x = rng.uniform(0, 4.0, (8000, 3))
        t, cell = _engine_view(x, matrix, pbc)
        lb, shape = pair_lower_bound(t, cell, pbc, 1.5)  # a 13 x 13 x 13 grid
        pairs = granularsap.neighbor_pairs(x, 1.5, box=matrix, return_distances=False)
        assert 0.25 * len(pairs) <= lb <= len(pairs), shape

    def test_bytes_per_pair_match_the_buffers_a_search_allocates(self):
        rng = np.random.default_rng(0)
        x = rng.uniform(0, 5, (3000, 3))
        for q in ("P", "Pd", "PdDS", "ijd"):
            s = NeighborSearch(1.0, quantities=q)
            s.update(x, box=[5, 5, 5, 90, 90, 90])
            out = sum(getattr(s._out, name).nbytes for name in "pdvs")
            assert out >= bytes_per_pair(q) * s.stats["pairs"]


class TestColumnBound:
    """The column plan's upper bound (what lets a search skip the lower bound) is
    never below the true pair count, whatever the cell, the clustering or the
    spread of radii (two levels: the wide stencil)."""

    @settings(max_examples=25, deadline=None)
    @given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 300),
           kind=st.sampled_from(["open", "cube", "slab", "triclinic"]),
           clustered=st.booleans(), spread=st.booleans())
    def test_never_below_the_brute_force_count(self, seed, n, kind, clustered, spread):
        rng = np.random.default_rng(seed)
        matrix, pbc = _cell(kind, rng)
        x = rng.uniform(0, 4.0, (n, 3))
        if clustered:
            x = x[:1] + 0.1 * (x - x[:1])
        rad = rng.uniform(0.05, 0.6 if spread else 0.15, n)
        if spread:
            rad[rng.random(n) < 0.9] = 0.05
        seen = []

        def spy(search, t, frame_cell, reach, labels=None, columns=None):
            seen.append(columns)

        box = None if matrix is None else granularsap.Cell(matrix, pbc)
        search = granularsap.ContactSearch(skin=0.05)
        search._small_max = 0  # the general path, which plans and checks
        search._levels = 0.05 if spread else False
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(granularsap._memory, "check_pair_memory", spy)
            search.update(x, rad, box)
        start, nb0, nb1, l0, l1 = seen[-1]
        bound = granularsap._memory.column_pair_bound(start, nb0, nb1, l0, l1,
                                                      bool(pbc[0]), bool(pbc[1]))
        pairs, _ = brute_image_pairs(x, 0.05, matrix, pbc, radii=rad)
        assert len(pairs) == search.stats["pairs"]
        assert bound >= len(pairs)


def _dense_size(avail, factor):
    """Particles in a unit cube whose pairs within 0.5 need ``factor`` x ``avail``
    bytes at 24 bytes per pair (0.5236 of all pairs are within 0.5)."""
    return int(math.ceil(math.sqrt(2.0 * factor * avail / (0.5236 * 24))))


class TestRefusal:
    def test_dense_frame_refused_within_seconds(self):
        # regression: 1e5 points in a unit cube with cutoff 0.5 swept for 96 s and then
        # failed to allocate 43.9 GiB; sized here to need 4x the memory there is
        avail = available_memory()
        if avail is None:
            pytest.skip("the system does not say how much memory is available")
        n = _dense_size(avail, 4.0)
        x = np.random.default_rng(1).uniform(0, 1, (n, 3))
        t0 = time.perf_counter()
        with pytest.raises(MemoryError, match=r"the pairs of this frame of \d+ particles "
                           r"\(NeighborSearch\) need at least .* pairs x 24 bytes "
                           r"\(quantities 'Pd'\) = .* GiB, more than the .* GiB of memory "
                           r"available; refused before searching"):
            granularsap.neighbor_pairs(x, 0.5, box=[1, 1, 1, 90, 90, 90])
        assert time.perf_counter() - t0 < 10

    def test_csr_layout_and_contacts_say_so(self):
        avail = available_memory()
        if avail is None:
            pytest.skip("the system does not say how much memory is available")
        n = _dense_size(avail, 4.0)
        x = np.random.default_rng(2).uniform(0, 1, (n, 3))
        with pytest.raises(MemoryError, match=r"layout='csr' holds every pair as well"):
            NeighborSearch(0.5, layout="csr").update(x, box=[1, 1, 1, 90, 90, 90])
        with pytest.raises(MemoryError, match=r"\(ContactSearch\) need at least"):
            granularsap.sphere_contacts(x, np.full(n, 0.25), box=[1, 1, 1, 90, 90, 90])
        # clumps of two spheres take out at most one pair each: still refused
        labels = np.arange(n) // 2
        with pytest.raises(MemoryError, match="need at least"):
            granularsap.ContactSearch().update(x, np.full(n, 0.25), [1, 1, 1, 90, 90, 90],
                                               clump_ids=labels)


_LIMITED = textwrap.dedent("""
    import resource, sys
    import numpy as np
    import granularsap
    from granularsap._memory import available_memory

    granularsap.neighbor_pairs(np.random.default_rng(0).uniform(0, 1, (500, 3)), 0.1)
    with open("/proc/self/statm") as fh:
        used = int(fh.read().split()[0]) * resource.getpagesize()
    limit = used + int(sys.argv[1])
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    assert available_memory() <= int(sys.argv[1])
    n, cutoff = int(sys.argv[2]), float(sys.argv[3])
    x = np.random.default_rng(3).uniform(0, 1, (n, 3))
    try:
        pairs, d = granularsap.neighbor_pairs(x, cutoff, box=[1, 1, 1, 90, 90, 90])
    except MemoryError as exc:
        print("refused", exc)
    else:
        print("pairs", len(pairs))
""")


class TestUnderAnAddressSpaceLimit:
    """A child process with ``RLIMIT_AS`` 1.5 GiB above what it uses: the frame that
    fits runs (though all its n (n - 1) / 2 pairs would not fit), the one that does
    not is refused by the estimate, not by a failed allocation."""

    ROOM = 3 << 29  # 1.5 GiB

    def _run(self, n, cutoff):
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([ROOT, env.get("PYTHONPATH", "")])
        out = subprocess.run([sys.executable, "-c", _LIMITED, str(self.ROOM), str(n),
                              str(cutoff)], capture_output=True, text=True, env=env,
                             timeout=600)
        assert out.returncode == 0, out.stderr
        return out.stdout

    def test_dense_but_fitting_frame_runs(self):
        # 30,000 points, cutoff 0.2: 1.5e7 pairs, 0.35 GiB of outputs, where all
        # 4.5e8 pairs would need 10 GiB: the bound is computed and lets it through
        n, cutoff = 30000, 0.2
        assert n * (n - 1) / 2 * 24 > 4 * self.ROOM
        expect = n * (n - 1) / 2 * 4 / 3 * math.pi * cutoff ** 3
        words = self._run(n, cutoff).split()
        assert words[0] == "pairs", words
        assert abs(int(words[1]) - expect) < 0.02 * expect

    def test_frame_beyond_the_limit_is_refused(self):
        # cutoff 0.45: 2e8 pairs, 4.5 GiB
        out = self._run(30000, 0.45)
        assert out.startswith("refused the pairs of this frame of 30000 particles"), out
        assert "more than the 1.5 GiB of memory available" in out or \
            "GiB of memory available" in out
