"""granularsap.mda_analysis.Contacts: an MDAnalysis analysis, equal on every backend."""

from __future__ import annotations

import numpy as np
import pytest

import granularsap

mda = pytest.importorskip("MDAnalysis")
from MDAnalysis.coordinates.memory import MemoryReader  # noqa: E402
from MDAnalysis.lib.distances import self_capped_distance  # noqa: E402

from granularsap.mda_analysis import Contacts  # noqa: E402

N_ATOMS, N_FRAMES = 300, 6


@pytest.fixture(scope="module")
def universe():
    rng = np.random.default_rng(5)
    coords = rng.uniform(0, 12, (N_FRAMES, N_ATOMS, 3)).astype(np.float32)
    dims = np.tile(np.array([12, 12, 12, 90, 90, 90], np.float32), (N_FRAMES, 1))
    dims[1::2, 3:] = [80, 95, 85]  # every other frame triclinic
    u = mda.Universe.empty(N_ATOMS, trajectory=False)
    u.add_TopologyAttr("radii", rng.uniform(0.3, 0.7, N_ATOMS))
    u.load_new(coords, format=MemoryReader, dimensions=dims, dt=1.0)
    return u


def sorted_pairs(p):
    p = np.sort(np.asarray(p, dtype=np.int64).reshape(-1, 2), axis=1)
    return p[np.lexsort((p[:, 1], p[:, 0]))]


class TestResults:
    def test_cutoff_equals_mdanalysis(self, universe):
        c = Contacts(universe.atoms, cutoff=1.5, return_distances=True).run()
        assert len(c.results.pairs) == N_FRAMES
        for k, ts in enumerate(universe.trajectory):
            ref, _ = self_capped_distance(universe.atoms.positions, 1.5, box=ts.dimensions)
            np.testing.assert_array_equal(c.results.pairs[k], sorted_pairs(ref))
            pos = universe.atoms.positions.astype(np.float64)
            want, dist = granularsap.neighbor_pairs(pos, 1.5, box=ts.dimensions)
            order = np.lexsort((want[:, 1], want[:, 0]))
            np.testing.assert_allclose(c.results.distances[k], dist[order], rtol=1e-12)
        np.testing.assert_array_equal(c.results.n_contacts, [len(p) for p in c.results.pairs])
        np.testing.assert_allclose(c.results.coordination,
                                   2 * c.results.n_contacts / N_ATOMS)

    def test_radii_and_skin_equal_sphere_contacts(self, universe):
        ag = universe.atoms[::2]
        c = Contacts(ag, radii="topology", skin=0.1).run(start=1, stop=6, step=2)
        np.testing.assert_array_equal(c.frames, [1, 3, 5])
        assert c.results.distances is None
        for k, ts in enumerate(universe.trajectory[1:6:2]):
            want = granularsap.sphere_contacts(ag.positions.astype(np.float64), ag.radii,
                                               skin=0.1, box=ts.dimensions)
            np.testing.assert_array_equal(c.results.pairs[k], sorted_pairs(want))

    def test_no_pbc(self, universe):
        c = Contacts(universe.atoms, radii=0.4, pbc=False).run(stop=1)
        want = granularsap.sphere_contacts(universe.atoms.positions.astype(np.float64),
                                           np.full(N_ATOMS, 0.4))
        np.testing.assert_array_equal(c.results.pairs[0], sorted_pairs(want))

    @pytest.mark.parametrize("pbc", [[True, True, False], (False, True, False),
                                     np.array([False, False, False]), [1, 0, 1]])
    def test_per_axis_pbc_equals_brute_force(self, universe, pbc):
        # frame 0 is orthorhombic (12 x 12 x 12): images along the periodic axes only
        c = Contacts(universe.atoms, cutoff=1.5, pbc=pbc).run(stop=1)
        flags = np.asarray(pbc, dtype=bool)
        pos = universe.trajectory[0].positions.astype(np.float64)
        d = pos[None, :, :] - pos[:, None, :]
        d[..., flags] -= 12.0 * np.round(d[..., flags] / 12.0)
        i, j = np.nonzero(np.triu(np.sqrt((d * d).sum(axis=-1)) <= 1.5, k=1))
        want = np.column_stack([i, j])
        assert len(want) > 100
        np.testing.assert_array_equal(c.results.pairs[0], want)

    @pytest.mark.parametrize("pbc, error", [("yes", TypeError), ([True, False], ValueError),
                                            (None, TypeError)])
    def test_bad_pbc_is_refused_by_name(self, universe, pbc, error):
        with pytest.raises(error, match="pbc must be a bool or three bools"):
            Contacts(universe.atoms, cutoff=1.5, pbc=pbc)


class TestBackends:
    def test_reexported_by_granularsap_mda(self):
        import granularsap.mda

        assert granularsap.mda.Contacts is Contacts

    def test_declared_parallelizable(self, universe):
        c = Contacts(universe.atoms, cutoff=1.0)
        assert c.parallelizable
        assert set(Contacts.get_supported_backends()) == {"serial", "multiprocessing", "dask"}

    @pytest.mark.parametrize("backend", ["multiprocessing", "dask"])
    def test_identical_to_serial(self, universe, backend):
        if backend == "dask":
            pytest.importorskip("dask")
        kw = {"cutoff": 1.4, "return_distances": True}
        serial = Contacts(universe.atoms, **kw).run()
        par = Contacts(universe.atoms, **kw).run(backend=backend, n_workers=2)
        np.testing.assert_array_equal(par.frames, serial.frames)
        np.testing.assert_array_equal(par.results.n_contacts, serial.results.n_contacts)
        for a, b in zip(par.results.pairs, serial.results.pairs, strict=True):
            np.testing.assert_array_equal(a, b)
        for a, b in zip(par.results.distances, serial.results.distances, strict=True):
            np.testing.assert_array_equal(a, b)


def test_multiprocessing_backend_leaks_no_semaphore(tmp_path):
    """Issue 20: the resource tracker reported a leaked semaphore at exit."""
    import subprocess
    import sys
    import textwrap

    script = tmp_path / "mp.py"
    script.write_text(textwrap.dedent("""
        import numpy as np
        import MDAnalysis as mda
        from MDAnalysis.coordinates.memory import MemoryReader
        from granularsap.mda_analysis import Contacts

        if __name__ == "__main__":
            rng = np.random.default_rng(1)
            u = mda.Universe.empty(200, trajectory=False)
            u.load_new(rng.uniform(0, 10, (4, 200, 3)).astype(np.float32),
                       format=MemoryReader, dimensions=[10, 10, 10, 90, 90, 90], dt=1.0)
            c = Contacts(u.atoms, cutoff=1.2).run(backend="multiprocessing", n_workers=2)
            print(sum(len(p) for p in c.results.pairs))
    """))
    proc = subprocess.run([sys.executable, "-W", "default", str(script)], capture_output=True,
                          text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout) > 0
    assert "leaked" not in proc.stderr and "resource_tracker" not in proc.stderr, proc.stderr


class TestValidation:
    def test_errors(self, universe):
        ag = universe.atoms
        with pytest.raises(ValueError, match="exactly one of cutoff and radii"):
            Contacts(ag)
        with pytest.raises(ValueError, match="exactly one of cutoff and radii"):
            Contacts(ag, cutoff=1.0, radii=0.5)
        with pytest.raises(ValueError, match=r"radii must be a scalar or have shape \(300,\)"):
            Contacts(ag, radii=np.ones(3))
        with pytest.raises(ValueError, match="radii must be finite and non-negative"):
            Contacts(ag, radii=-1.0)
        with pytest.raises(ValueError, match="cutoff must be a finite non-negative number"):
            Contacts(ag, cutoff=float("nan"))
        with pytest.raises(ValueError, match="skin applies to sphere contacts"):
            Contacts(ag, cutoff=1.0, skin=0.1)
        with pytest.raises(ValueError, match="radii must be numbers or 'topology'"):
            Contacts(ag, radii="vdw")
        with pytest.raises(TypeError, match="atomgroup must be an MDAnalysis AtomGroup"):
            Contacts(np.zeros((3, 3)), cutoff=1.0)


def brute_pairs(pos, reach, box):
    """Pairs i < j with minimum-image distance <= reach (orthorhombic box), by brute force."""
    d = pos[None, :, :] - pos[:, None, :]
    if box is not None:
        d -= box[:3] * np.round(d / box[:3])
    dist = np.sqrt((d * d).sum(axis=-1))
    i, j = np.nonzero(np.triu(dist <= reach, k=1))
    return np.column_stack([i, j]).astype(np.int64).reshape(-1, 2)


@pytest.fixture(scope="module")
def slab():
    rng = np.random.default_rng(8)
    n, frames = 200, 6
    coords = rng.uniform(0, 10, (frames, n, 3)).astype(np.float32)
    coords[0, :, 2] += 20.0  # frame 0: nobody in the slab z < 5
    coords[3, :, 2] += 20.0  # frame 3: nobody either
    dims = np.tile(np.array([10, 10, 40, 90, 90, 90], np.float32), (frames, 1))
    u = mda.Universe.empty(n, trajectory=False)
    u.add_TopologyAttr("radii", rng.uniform(0.3, 0.6, n))
    u.load_new(coords, format=MemoryReader, dimensions=dims, dt=1.0)
    return u


class TestChangingSize:
    """An UpdatingAtomGroup changes size, to and from 0; MDAnalysis files cannot."""

    def expected(self, u, reach_of):
        out = []
        for ts in u.trajectory:
            sel = np.nonzero(u.atoms.positions[:, 2] < 5.0)[0]
            pos = u.atoms.positions[sel].astype(np.float64)
            reach = reach_of(u.atoms.radii[sel])
            out.append((len(sel), brute_pairs(pos, reach, ts.dimensions.astype(np.float64))))
        return out

    @pytest.mark.parametrize("kind", ["cutoff", "topology", "scalar"])
    def test_updating_atomgroup_equals_brute_force(self, slab, kind):
        ag = slab.select_atoms("prop z < 5.0", updating=True)
        if kind == "cutoff":
            c, reach = Contacts(ag, cutoff=1.2), (lambda r: 1.2)
        elif kind == "topology":
            c, reach = Contacts(ag, radii="topology", skin=0.05), \
                (lambda r: r[:, None] + r[None] + 0.05)
        else:
            c, reach = Contacts(ag, radii=0.5), (lambda r: 1.0)
        c.run()
        want = self.expected(slab, reach)
        np.testing.assert_array_equal(c.results.n_atoms, [n for n, _ in want])
        assert c.results.n_atoms[0] == c.results.n_atoms[3] == 0 and c.results.n_atoms.max() > 50
        for got, (_, pairs) in zip(c.results.pairs, want, strict=True):
            assert got.shape[1:] == (2,) and got.dtype == np.int64
            np.testing.assert_array_equal(got, sorted_pairs(pairs))
        z = [2 * len(p) / n if n else 0.0 for n, p in want]
        np.testing.assert_allclose(c.results.coordination, z)

    def test_updating_atomgroup_on_multiprocessing_equals_serial(self, slab):
        ag = slab.select_atoms("prop z < 5.0", updating=True)
        serial = Contacts(ag, radii="topology").run()
        par = Contacts(ag, radii="topology").run(backend="multiprocessing", n_workers=2)
        np.testing.assert_array_equal(par.results.n_atoms, serial.results.n_atoms)
        np.testing.assert_array_equal(par.results.coordination, serial.results.coordination)
        for a, b in zip(par.results.pairs, serial.results.pairs, strict=True):
            np.testing.assert_array_equal(a, b)

    def test_updating_atomgroup_with_a_radius_array_is_refused(self, slab):
        ag = slab.select_atoms("prop z < 5.0", updating=True)
        c = Contacts(ag, radii=np.full(len(ag), 0.4))
        with pytest.raises(ValueError, match=r"radii has 0 values but atomgroup has \d+ atoms "
                                             r"in frame 1 \(an UpdatingAtomGroup"):
            c.run()

    def test_empty_atomgroup(self, universe):
        c = Contacts(universe.atoms[[]], radii=0.5).run()
        assert [len(p) for p in c.results.pairs] == [0] * N_FRAMES
        assert all(p.shape == (0, 2) for p in c.results.pairs)
        np.testing.assert_array_equal(c.results.coordination, np.zeros(N_FRAMES))

    def test_lammps_dump_with_changing_counts_names_the_readers_that_can(self, tmp_path):
        from ._iohelpers import lammps_cell, write_dump

        rng = np.random.default_rng(1)
        cell = lammps_cell(6, 6, 6)
        path = tmp_path / "grow.dump"
        write_dump(path, [{"positions": rng.uniform(0, 6, (n, 3)), "cell": cell}
                          for n in (5, 8, 3)])
        with pytest.warns(UserWarning):  # MDAnalysis: guessed masses, no types ...
            u = mda.Universe(str(path), format="LAMMPSDUMP")
        c = Contacts(u.atoms, cutoff=1.0)
        with pytest.raises(ValueError, match=r"grow\.dump: MDAnalysis cannot read a trajectory "
                                             r"whose atom count changes.*granularsap contacts"):
            c.run()
