"""One frame over Dask (granularsap.dask): spatial domains give the single-machine answer.

The oracle is the single-machine engine (granularsap.neighbor_pairs /
sphere_contacts, itself checked against brute force elsewhere): the concatenated
partitions must hold the same pair set with the same float64 distances bit for
bit, every pair once.  Coordination numbers and histograms are checked against
NumPy computations on the single-machine pairs.
"""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

import granularsap
from granularsap import Cell

da = pytest.importorskip("dask.array")
pytest.importorskip("dask.dataframe")
distributed = pytest.importorskip("distributed")
gdask = pytest.importorskip("granularsap.dask")


# ------------------------------------------------------------------ frames
def _lattice_plus_random(n_side, spacing, n_random, seed):
    """An integer lattice (pairs exactly at the cutoff, particles exactly on the
    domain faces of an even split) plus random points."""
    g = np.arange(n_side) * spacing
    lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    rand = rng.uniform(0, n_side * spacing, (n_random, 3))
    x = np.concatenate([lattice, rand])
    return x[rng.permutation(len(x))]


def _frame(kind, seed=0):
    """(positions, cutoff or radii, cell, pbc) of one test frame."""
    rng = np.random.default_rng([seed, 7])
    if kind == "open":
        return _lattice_plus_random(7, 1.0, 700, seed) - 2.0, 1.0, None, None
    if kind == "orthorhombic":
        return _lattice_plus_random(6, 1.0, 700, seed), 1.0, Cell.from_dimensions(
            [6, 6, 6, 90, 90, 90]), None
    if kind == "triclinic":
        m = np.array([[7.0, 0, 0], [1.5, 6.5, 0], [-1.0, 0.8, 6.8]])
        s = rng.uniform(-0.3, 1.3, (1200, 3))  # unwrapped too
        s[:200, 0] = 0.5  # on a face of a 2-way split
        s[200:300, 2] = 0.0
        return s @ m, 1.3, Cell.from_matrix(m), None
    if kind == "mixed":
        x = _lattice_plus_random(6, 1.0, 600, seed)
        x[:, 1] *= 1.5  # the open axis spreads beyond the cell
        return x, 1.0, Cell.from_dimensions([6, 6, 6, 90, 90, 90]), (True, False, True)
    if kind == "polydisperse":
        m = np.array([[9.0, 0, 0], [2.0, 8.0, 0], [1.0, -1.5, 8.5]])
        x = rng.uniform(0, 1, (1500, 3)) @ m
        radii = np.clip(rng.lognormal(-1.0, 0.6, len(x)), 0.05, 1.0)
        return x, radii, Cell.from_matrix(m), None
    raise AssertionError(kind)


KINDS = ["open", "orthorhombic", "triclinic", "mixed", "polydisperse"]


def _single(x, reach, cell, pbc):
    if np.ndim(reach) == 0:
        pairs, d = granularsap.neighbor_pairs(x, reach, box=cell, pbc=pbc)
    else:
        pairs, d = granularsap.sphere_contacts(x, reach, box=cell, pbc=pbc,
                                               return_distances=True)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order], d[order]


def _search(x, reach, cell, pbc, **kw):
    if np.ndim(reach) == 0:
        return gdask.DomainSearch(x, cutoff=reach, cell=cell, pbc=pbc, **kw)
    radii = reach
    if isinstance(x, da.Array):
        radii = da.from_array(reach, chunks=x.chunks[0][::-1] if len(x.chunks[0]) > 1
                              else x.chunks[0])  # a chunking of its own
    return gdask.DomainSearch(x, radii=radii, cell=cell, pbc=pbc, **kw)


def _assert_same_pairs(df, pairs, d):
    assert list(df.columns) == ["i", "j", "distance"]
    assert [str(t) for t in df.dtypes] == ["int64", "int64", "float64"]
    got = df.to_numpy()
    gp = np.asarray(df[["i", "j"]].to_numpy(), dtype=np.int64)
    order = np.lexsort((gp[:, 1], gp[:, 0]))
    gp = gp[order]
    assert len(gp) == len(pairs), (len(gp), len(pairs))
    np.testing.assert_array_equal(gp, pairs)  # also: each pair exactly once
    gd = np.asarray(df["distance"].to_numpy())[order]
    assert np.array_equal(gd, d), "distances differ from the single-machine call"
    assert got.shape == (len(pairs), 3)


def _chunked(x, chunking):
    if chunking == "numpy":
        return x
    if chunking == "even":
        return da.from_array(x, chunks=(97, 3))
    n = len(x)
    sizes = (1, 40, 333, n - 374)  # irregular, with a one-row chunk
    return da.from_array(x, chunks=(sizes, (1, 2)))  # split along the columns too


def _coordination(pairs, n):
    return np.bincount(pairs[:, 0], minlength=n) + np.bincount(pairs[:, 1], minlength=n)


# -------------------------------------------------------- threaded scheduler
class TestCellKeyword:
    """``box=`` as in the core; ``cell=`` is its older name and still answers."""

    @pytest.mark.parametrize("kind", ["orthorhombic", "triclinic", "mixed"])
    def test_box_and_cell_give_the_single_machine_pairs(self, kind):
        x, reach, cell, pbc = _frame(kind)
        pairs, d = _single(x, reach, cell, pbc)
        for kw in ({"box": cell}, {"cell": cell}):
            df = gdask.neighbor_pairs(x, reach, pbc=pbc, domains=2, **kw)
            _assert_same_pairs(df.compute(scheduler="threads"), pairs, d)
            ds = gdask.DomainSearch(x, cutoff=reach, pbc=pbc, domains=2, **kw)
            assert int(ds.count_pairs().compute()) == len(pairs)

    def test_both_names_at_once_are_refused(self):
        x, reach, cell, _ = _frame("orthorhombic")
        with pytest.raises(TypeError, match=r"give the cell as box= \(cell= is its older "
                                             r"name\), not both"):
            gdask.DomainSearch(x, cutoff=reach, box=cell, cell=cell)

    def test_a_bad_cell_is_named_as_given(self):
        x = np.zeros((3, 3))
        with pytest.raises(ValueError, match=r"^box lengths must be positive"):
            gdask.count_pairs(x, 1.0, box=[8, 8, -8, 90, 90, 90])
        with pytest.raises(ValueError, match=r"^cell lengths must be positive"):
            gdask.count_pairs(x, 1.0, cell=[8, 8, -8, 90, 90, 90])


class TestThreaded:
    """No cluster given: Dask's threaded scheduler runs the domains."""

    @pytest.mark.parametrize("kind", KINDS)
    @pytest.mark.parametrize("domains", [1, 2, (2, 2, 2), (3, 1, 2), 7])
    def test_pairs_equal_single_machine(self, kind, domains):
        x, reach, cell, pbc = _frame(kind)
        pairs, d = _single(x, reach, cell, pbc)
        for chunking in ("numpy", "irregular"):
            ds = _search(_chunked(x, chunking), reach, cell, pbc, domains=domains)
            assert ds.pairs().npartitions == ds.n_domains
            _assert_same_pairs(ds.pairs().compute(scheduler="threads"), pairs, d)

    @pytest.mark.parametrize("kind", KINDS)
    def test_reductions_equal_numpy(self, kind):
        x, reach, cell, pbc = _frame(kind, seed=3)
        pairs, d = _single(x, reach, cell, pbc)
        ds = _search(_chunked(x, "even"), reach, cell, pbc, domains=(2, 2, 2)).persist()
        cn = ds.coordination_numbers()
        assert cn.chunks == ((97,) * (len(x) // 97) + ((len(x) % 97,) if len(x) % 97 else ()),)
        np.testing.assert_array_equal(cn.compute(), _coordination(pairs, len(x)))
        assert int(ds.count_pairs().compute()) == len(pairs)
        counts, edges = ds.distance_histogram(17)
        np.testing.assert_array_equal(counts.compute(), np.histogram(d, bins=edges)[0])
        assert edges[-1] == ds.reach
        edges = np.array([0.0, 0.5, 0.99, 1.0, 1.2])
        counts, _ = ds.distance_histogram(edges)
        np.testing.assert_array_equal(counts.compute(), np.histogram(d, bins=edges)[0])

    def test_faces_and_cutoff_ties_are_exercised(self):
        """The lattice frame really has pairs at exactly the cutoff and
        particles exactly on domain faces (else the tests above prove less)."""
        x, cutoff, cell, pbc = _frame("orthorhombic")
        pairs, d = _single(x, cutoff, cell, pbc)
        assert np.count_nonzero(d == cutoff) >= 3 * 6**3
        ds = gdask.DomainSearch(x, cutoff=cutoff, cell=cell, domains=(2, 3, 2))
        frac = cell.fractional(x)
        assert np.count_nonzero(np.isin(frac[:, 0], [0.0, 0.5])) >= 72
        df = ds.pairs().compute()
        _assert_same_pairs(df, pairs, d)

    def test_rdf_matches_numpy_normalisation(self):
        x, cutoff, cell, _ = _frame("orthorhombic", seed=5)
        pairs, d = _single(x, 2.5, cell, None)
        g, edges = gdask.radial_distribution(x, 2.5, bins=25, cell=cell, domains=3)
        n = len(x)
        shell = 4 / 3 * np.pi * (edges[1:] ** 3 - edges[:-1] ** 3)
        want = np.histogram(d, bins=edges)[0] / (n * (n - 1) / (2 * cell.volume) * shell)
        np.testing.assert_allclose(g.compute(), want, rtol=1e-15)
        with pytest.raises(ValueError, match="periodic on every axis"):
            gdask.radial_distribution(x, 2.5, cell=None)
        with pytest.raises(ValueError, match="at least 2 particles"):  # not a NaN g(r)
            gdask.radial_distribution(x[:1], 2.5, cell=cell)

    def test_clump_ids_excluded_like_single_machine(self):
        x, radii, cell, _ = _frame("polydisperse")
        ids = np.arange(len(x)) // 3
        pairs, d = granularsap.ContactSearch(quantities="Pd").update(x, radii, cell,
                                                                      clump_ids=ids)
        order = np.lexsort((pairs[:, 1], pairs[:, 0]))
        df = gdask.sphere_contacts(da.from_array(x, chunks=200), radii, cell=cell,
                                   clump_ids=ids, domains=4).compute()
        _assert_same_pairs(df, pairs[order], d[order])

    def test_empty_and_tiny_frames(self):
        for n in (0, 1, 2):
            x = np.arange(3 * n, dtype=float).reshape(n, 3) * 0.1
            df = gdask.neighbor_pairs(x, 1.0, cell=[5, 5, 5, 90, 90, 90]).compute()
            assert len(df) == (1 if n == 2 else 0)
            cn = gdask.coordination_numbers(x, 1.0, cell=[5, 5, 5, 90, 90, 90]).compute()
            np.testing.assert_array_equal(cn, [1, 1] if n == 2 else np.zeros(n))

    @pytest.mark.parametrize("n", [0, 1])
    @pytest.mark.parametrize("chunking", ["numpy", "dask"])
    def test_explicit_grid_on_an_open_frame_without_pairs(self, n, chunking):
        """0 or 1 particle has no pair whatever the grid: an explicit grid is
        honoured (no refusal about an axis "along which every particle has the
        same coordinate"), every domain is empty of pairs."""
        x = np.full((n, 3), 1.5)
        xs = x if chunking == "numpy" else da.from_array(x, chunks=(max(n, 1), 3))
        for domains in ((2, 1, 1), (1, 3, 2), (2, 2, 2)):
            ds = gdask.DomainSearch(xs, cutoff=1.0, domains=domains)
            assert ds.grid == domains and ds.n_domains == int(np.prod(domains))
            df = ds.pairs()
            assert df.npartitions == ds.n_domains
            assert len(df.compute()) == 0
            assert int(ds.count_pairs().compute()) == 0
            np.testing.assert_array_equal(ds.coordination_numbers().compute(), np.zeros(n))
            sizes = ds.domain_sizes()  # halo copies included
            assert len(sizes) == ds.n_domains and sizes[0] == n
            cs = gdask.DomainSearch(xs, radii=0.5, domains=domains)
            assert cs.grid == domains and len(cs.pairs().compute()) == 0

    def test_all_on_a_plane_open(self):
        x = np.random.default_rng(2).uniform(0, 5, (300, 3))
        x[:, 2] = 1.0
        pairs, d = _single(x, 0.7, None, None)
        for domains in (6, (2, 3, 1)):
            _assert_same_pairs(gdask.neighbor_pairs(x, 0.7, domains=domains).compute(),
                               pairs, d)
        with pytest.raises(ValueError, match="same coordinate"):
            gdask.DomainSearch(x, cutoff=0.7, domains=(1, 1, 2))

    def test_automatic_grid(self):
        x, cutoff, cell, _ = _frame("orthorhombic")
        ds = gdask.DomainSearch(x, cutoff=cutoff, cell=cell, particles_per_domain=100)
        assert ds.n_domains >= len(x) / 100
        assert ds.n_domains < 2 * -(-len(x) // 100) + 1
        assert sum(ds.domain_sizes()) >= len(x)
        _assert_same_pairs(ds.pairs().compute(), *_single(x, cutoff, cell, None))

    def test_errors_name_the_argument(self):
        x, cutoff, cell, _ = _frame("orthorhombic")
        with pytest.raises(ValueError, match="exceeds half the smallest perpendicular"):
            gdask.neighbor_pairs(x, 3.5, cell=cell)
        with pytest.raises(ValueError, match="exactly one of cutoff"):
            gdask.DomainSearch(x)
        bad = x.copy()
        bad[123, 1] = np.nan
        with pytest.raises(ValueError, match="positions must be finite.*row 123"):
            gdask.neighbor_pairs(bad, 1.0, cell=cell)
        with pytest.raises(ValueError, match=r"positions must be finite.*row 123"):
            gdask.neighbor_pairs(da.from_array(bad, chunks=50), 1.0, cell=cell)
        with pytest.raises(ValueError, match="positions must have shape"):
            gdask.neighbor_pairs(da.zeros((10, 2)), 1.0)
        with pytest.raises(ValueError, match="radii must be non-negative"):
            gdask.sphere_contacts(da.from_array(x, chunks=100),
                                  da.from_array(np.r_[np.ones(len(x) - 1), -1.0], chunks=100))
        rad = np.ones(len(x))
        rad[150] = np.nan
        with pytest.raises(ValueError, match=r"radii must be finite, got nan at index 150"):
            gdask.sphere_contacts(da.from_array(x, chunks=100), da.from_array(rad, chunks=100))
        with pytest.raises(ValueError, match="domains must be"):
            gdask.DomainSearch(x, cutoff=1.0, domains=(0, 1, 1))
        with pytest.raises(TypeError, match="client must be"):
            gdask.DomainSearch(x, cutoff=1.0, client=3)
        with pytest.raises(ValueError, match="bins must be"):
            gdask.DomainSearch(x, cutoff=1.0).distance_histogram([1.0, 0.5])


# --------------------------------------------------------------- Parquet
class TestParquet:
    def test_written_dataset_reads_back_without_granularsap(self, tmp_path):
        import pandas as pd

        x, radii, cell, _ = _frame("polydisperse")
        pairs, d = _single(x, radii, cell, None)
        out = tmp_path / "pairs.parquet"
        marker = gdask.write_pairs(out, da.from_array(x, chunks=400), radii=radii, cell=cell,
                                   domains=(2, 2, 1))
        assert marker["n_pairs"] == len(pairs) and marker["domains"] == 4
        assert not (tmp_path / "pairs.parquet.partial").exists()
        names = sorted(os.listdir(out))
        assert [n for n in names if n.startswith("domain-")] == [
            f"domain-{k:05d}.parquet" for k in range(4)]
        _assert_same_pairs(pd.read_parquet(out), pairs, d)       # plain pandas
        _assert_same_pairs(gdask.read_pairs(out).compute(), pairs, d)
        with pytest.raises(FileExistsError, match="already exists"):
            gdask.write_pairs(out, x, radii=radii, cell=cell)

    def test_interrupted_write_never_looks_complete(self, tmp_path):
        x, cutoff, cell, _ = _frame("orthorhombic")
        # a write stopped half-way leaves PATH.partial only, which read_pairs refuses
        ds = gdask.DomainSearch(x, cutoff=cutoff, cell=cell, domains=4)
        part = tmp_path / "q.partial"
        ds.pairs().to_parquet(part, write_index=False)  # what a killed write leaves
        with pytest.raises(ValueError, match="not a complete granularsap pairs dataset"):
            gdask.read_pairs(part)
        assert not (tmp_path / "q").exists()
        ds.write_pairs(tmp_path / "q")  # a later write replaces the leftover
        assert not part.exists()
        _assert_same_pairs(gdask.read_pairs(tmp_path / "q").compute(),
                           *_single(x, cutoff, cell, None))


# ----------------------------------------------------------- LocalCluster
@pytest.fixture(scope="module", params=[2, 3], ids=["2-workers", "3-workers"])
def client(request):
    with distributed.LocalCluster(n_workers=request.param, threads_per_worker=1,
                                  processes=True, dashboard_address=":0") as cluster, \
            distributed.Client(cluster, set_as_default=False) as c:
        c.wait_for_workers(request.param)
        yield c


class TestLocalCluster:
    @pytest.mark.parametrize("kind", KINDS)
    def test_pairs_and_reductions_on_cluster(self, client, kind):
        x, reach, cell, pbc = _frame(kind, seed=11)
        pairs, d = _single(x, reach, cell, pbc)
        n_workers = len(client.nthreads())
        chunkings = ("numpy", "even", "irregular")
        # every chunking on every cluster, each kind with two of them (keeps the suite short)
        first = (KINDS.index(kind) + n_workers) % 3
        for chunking in (chunkings[first], chunkings[(first + 1) % 3]):
            ds = _search(_chunked(x, chunking), reach, cell, pbc, client=client,
                         domains=None if chunking == "numpy" else (2, 1, 2))
            if chunking == "numpy":
                assert ds.n_domains == n_workers  # automatic: one per worker here
            else:
                ds.persist()
            df = client.compute(ds.pairs()).result()
            _assert_same_pairs(df, pairs, d)
            cn = client.compute(ds.coordination_numbers()).result()
            np.testing.assert_array_equal(cn, _coordination(pairs, len(x)))
            counts, edges = ds.distance_histogram(9)
            np.testing.assert_array_equal(client.compute(counts).result(),
                                          np.histogram(d, bins=edges)[0])

    def test_address_and_parquet_from_workers(self, client, tmp_path):
        x, cutoff, cell, _ = _frame("triclinic", seed=2)
        pairs, d = _single(x, cutoff, cell, None)
        ds = gdask.DomainSearch(da.from_array(x, chunks=300), cutoff=cutoff, cell=cell,
                                client=client.scheduler.address)
        try:
            assert ds.n_workers == len(client.nthreads())
            marker = ds.write_pairs(tmp_path / "w")
            assert marker["n_pairs"] == len(pairs)
            _assert_same_pairs(gdask.read_pairs(tmp_path / "w").compute(), pairs, d)
        finally:
            ds.client.close()


# ------------------------------------------------------------- killed worker
def _kill_once(block, marker):
    """Identity on a chunk; the first call anywhere kills its own worker process."""
    if block.size == 0:
        return block  # dask's meta inference in the test process
    try:
        distributed.get_worker()
    except ValueError:
        return block
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return block
    os.close(fd)
    os.kill(os.getpid(), signal.SIGKILL)
    return block  # pragma: no cover


class TestKilledWorker:
    def test_worker_killed_mid_computation(self, tmp_path):
        x, radii, cell, _ = _frame("polydisperse", seed=4)
        x = np.concatenate([x + v @ cell.matrix for v in np.eye(3)])  # unwrapped images
        radii = np.concatenate([radii] * 3)
        pairs, d = _single(x, radii, cell, None)
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      dashboard_address=":0") as cluster, \
                distributed.Client(cluster, set_as_default=False) as c:
            # 1. a worker dies while routing chunks (the task kills its own process)
            marker = str(tmp_path / "killed")
            pos = da.from_array(x, chunks=300).map_blocks(_kill_once, marker, dtype=float,
                                                          meta=np.empty((0, 3)))
            ds = gdask.DomainSearch(pos, radii=radii, cell=cell, client=c, domains=(2, 2, 1))
            assert os.path.exists(marker)  # the extent pass already lost a worker
            os.remove(marker)
            fut = [c.compute(ds.pairs()), c.compute(ds.coordination_numbers())]
            df, cn = (f.result(timeout=120) for f in fut)
            assert os.path.exists(marker)
            _assert_same_pairs(df, pairs, d)
            np.testing.assert_array_equal(cn, _coordination(pairs, len(x)))
            # 2. a worker process killed from outside while domains are searched
            killed = []
            for attempt in range(3):  # until a kill lands while a domain task runs
                c.wait_for_workers(2, timeout=30)
                ds = gdask.DomainSearch(da.from_array(x, chunks=250 + attempt), radii=radii,
                                        cell=cell, client=c, domains=6)
                fut = c.compute(ds.pairs())
                pids = c.run(os.getpid)

                def killer(fut=fut, pids=pids):
                    deadline = time.monotonic() + 20
                    while time.monotonic() < deadline and not fut.done():
                        for addr, keys in c.processing().items():
                            if addr in pids and any("domain_pairs" in str(k) for k in keys):
                                os.kill(pids[addr], signal.SIGKILL)
                                killed.append(addr)
                                return
                        time.sleep(0.001)

                t = threading.Thread(target=killer)
                t.start()
                df = fut.result(timeout=120)
                t.join()
                _assert_same_pairs(df, pairs, d)
                if killed:
                    break
            assert killed, "no worker was killed while a domain task ran"
            # 3. NumPy frame: its domains live once on the cluster; losing them
            #    either recomputes nothing wrong or raises, never a partial answer
            c.wait_for_workers(2, timeout=30)
            ds = gdask.DomainSearch(x, radii=radii, cell=cell, client=c, domains=4)
            fut = c.compute(ds.pairs())
            victim = next(addr for addr, keys in c.has_what().items() if keys)
            os.kill(c.run(os.getpid)[victim], signal.SIGKILL)
            try:
                df = fut.result(timeout=120)
            except Exception as exc:  # noqa: BLE001 - any clear error is acceptable
                assert str(exc) or type(exc).__name__
            else:
                _assert_same_pairs(df, pairs, d)


# ------------------------------------------------------------- command line
@pytest.fixture(scope="module")
def dump(tmp_path_factory):
    from ._iohelpers import lammps_cell, random_frames, write_dump

    path = tmp_path_factory.mktemp("domains") / "big.dump"
    cell = lammps_cell(12.0, 11.0, 10.0, xy=1.0, xz=0.5, yz=-0.5)
    write_dump(path, random_frames(700, 3, cell=cell, seed=5),
               columns=("id", "type", "radius", "x", "y", "z"), shuffle_seed=2)
    return path


class TestCommandLine:
    """`granularsap contacts --workers N` on large frames: spatial domains, same file."""

    def test_workers_split_large_frames_into_domains(self, dump, tmp_path, capsys):
        from granularsap.cli import main
        from granularsap.io import ContactParams, compute_contacts

        from .test_hdf5 import assert_same_contacts_file

        serial = tmp_path / "serial.h5"
        compute_contacts(dump, serial, ContactParams(skin=0.1, distances=True))
        out = tmp_path / "domains.h5"
        assert main(["contacts", str(dump), "-o", str(out), "--skin", "0.1", "--distances",
                     "--workers", "2", "--domain-particles", "700"]) == 0
        err = capsys.readouterr().err
        assert "frame of 700 particles (>= 700, the domain threshold): each frame is split " \
               "into 2 spatial domains" in err and "over 2 Dask workers" in err
        assert_same_contacts_file(out, serial)
        # below the threshold: one frame per worker, no such line
        out2 = tmp_path / "frames.h5"
        assert main(["contacts", str(dump), "-o", str(out2), "--skin", "0.1", "--distances",
                     "--workers", "2", "--domain-particles", "701"]) == 0
        assert "spatial domains" not in capsys.readouterr().err
        assert_same_contacts_file(out2, serial)

    def test_environment_threshold_on_existing_scheduler(self, client, tmp_path, monkeypatch):
        from ase import Atoms
        from ase.io import write

        from granularsap.io import ContactParams, compute_contacts

        from .test_hdf5 import assert_same_contacts_file

        rng = np.random.default_rng(9)
        cell = np.array([[9.0, 0, 0], [1.0, 8.5, 0], [0.5, -0.5, 8.0]])
        frames = [Atoms("Ar" * 500, positions=rng.uniform(0, 1, (500, 3)) @ cell, cell=cell,
                        pbc=(True, True, False)) for _ in range(2)]
        traj = tmp_path / "f.extxyz"
        write(traj, frames)
        serial = tmp_path / "s.h5"
        compute_contacts(traj, serial, ContactParams(cutoff=1.6, distances=True))
        monkeypatch.setenv("GRANULARSAP_DOMAIN_PARTICLES", "400")
        plans = []
        out = tmp_path / "d.h5"
        compute_contacts(traj, out, ContactParams(cutoff=1.6, distances=True),
                         scheduler=client.scheduler.address, on_plan=plans.append)
        assert len(plans) == 1 and "500 particles (>= 400" in plans[0]
        assert_same_contacts_file(out, serial)
        monkeypatch.setenv("GRANULARSAP_DOMAIN_PARTICLES", "many")
        with pytest.raises(ValueError, match="GRANULARSAP_DOMAIN_PARTICLES must be a positive"):
            compute_contacts(traj, tmp_path / "x.h5", ContactParams(cutoff=1.6),
                             scheduler=client.scheduler.address)


def test_docstring_examples():
    import doctest

    result = doctest.testmod(gdask, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0 and result.attempted > 0
