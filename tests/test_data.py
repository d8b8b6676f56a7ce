"""The bundled LAMMPS trajectories in data/: what they contain, and granularsap == LAMMPS
on every frame of every file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import granularsap
import lammps_bridge
from granularsap.io import iter_frames
from lammps_bridge import generate

DATA = Path(__file__).resolve().parent.parent / "data"
pytestmark = pytest.mark.lammps

#: file -> neighbour cutoff checked on every frame
CUTOFFS = {"pour.dump": 1.0, "lj.dump": 2.5, "clumps.dump": 1.0}


def _frames(name):
    return list(iter_frames(DATA / name))


@pytest.fixture(scope="module")
def frames():
    return {name: _frames(name) for name in CUTOFFS}


def _box(frame):
    return frame.cell if frame.cell is not None and np.all(frame.pbc) else None


def _sorted(pairs):
    pairs = np.sort(np.asarray(pairs, dtype=np.int64).reshape(-1, 2), axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


class TestContents:
    def test_pour(self, frames):
        fr = frames["pour.dump"]
        assert 18 <= len(fr) <= 25
        assert all(f.n_particles == 2000 for f in fr)
        assert not np.any(fr[0].pbc)
        diam = np.unique(2 * fr[-1].radius)
        assert len(diam) >= 3 and diam.max() / diam.min() >= 4.0
        # it fell and settled: the centre of mass went down and stopped moving
        z = [f.positions[:, 2].mean() for f in fr]
        assert z[-1] < 0.5 * z[0]
        assert abs(z[-1] - z[-2]) < 0.05

    def test_lj(self, frames):
        fr = frames["lj.dump"]
        assert 10 <= len(fr) <= 12
        assert all(f.n_particles == 2048 for f in fr)
        assert np.all(fr[0].pbc)
        cell = fr[0].cell
        assert np.count_nonzero(cell[np.tril_indices(3, -1)]) == 3  # xy, xz, yz tilts

    def test_clumps(self, frames):
        fr = frames["clumps.dump"]
        assert len(fr) >= 18
        last = fr[-1]
        sizes = np.bincount(last.molecule)[1:]
        assert set(sizes) == {2, 3, 4, 5}
        # the spheres of a clump overlap, and fix rigid/small kept every body rigid
        first = fr[0]
        for mol in np.unique(last.molecule)[:50]:
            sel = last.molecule == mol
            p, r = last.positions[sel], last.radius[sel]
            d = np.linalg.norm(p[:, None] - p[None], axis=-1)
            assert (d[0, 1:] < r[0] + r[1:]).any()
            p0 = first.positions[first.molecule == mol]
            d0 = np.linalg.norm(p0[:, None] - p0[None], axis=-1)
            np.testing.assert_allclose(d, d0, atol=2e-4)

    @pytest.mark.parametrize("name", ["pour", "lj", "clumps"])
    def test_committed_inputs_are_what_the_generator_writes(self, name, tmp_path):
        script = generate.write_inputs(name, tmp_path)
        assert script.read_text() == (DATA / f"{name}.in").read_text()
        for mol in tmp_path.glob("*.mol"):
            assert mol.read_text() == (DATA / mol.name).read_text()

    def test_generator_reproduces_clumps(self, tmp_path, capsys):
        # the cheapest system (3 s): LAMMPS really runs the committed script
        assert generate.main(["clumps", "--outdir", str(tmp_path)]) == 0
        assert "clumps: wrote" in capsys.readouterr().out
        new = list(iter_frames(tmp_path / "clumps.dump"))
        old = _frames("clumps.dump")
        assert len(new) == len(old)
        np.testing.assert_array_equal(new[0].molecule, old[0].molecule)
        np.testing.assert_allclose(new[0].positions, old[0].positions, atol=1e-4)

    def test_generator_errors(self, tmp_path):
        with pytest.raises(ValueError, match="unknown system 'sand'; choose one of"):
            generate.write_inputs("sand", tmp_path)

        class NoRigid:
            def has_package(self, name):
                return name != "RIGID"

        with pytest.raises(RuntimeError, match="needs the LAMMPS package.*RIGID"):
            generate._require_packages(NoRigid(), "clumps")

    def test_readme_describes_every_file(self):
        readme = (DATA / "README.md").read_text()
        for path in DATA.iterdir():
            if path.name != "README.md":
                assert path.name in readme, path.name


class TestGranularsapEqualsLammps:
    @pytest.mark.parametrize("name", list(CUTOFFS))
    def test_neighbor_pairs_every_frame(self, frames, name):
        cutoff = CUTOFFS[name]
        for frame in frames[name]:
            box = _box(frame)
            ours = granularsap.neighbor_pairs(frame.positions, cutoff, box=box,
                                              return_distances=False)
            ref = lammps_bridge.neighbor_pairs(frame.positions, cutoff, box)
            np.testing.assert_array_equal(_sorted(ours), ref,
                                          err_msg=f"{name} frame {frame.index}")

    @pytest.mark.parametrize("name", ["pour.dump", "clumps.dump"])
    def test_sphere_contacts_every_frame(self, frames, name):
        for frame in frames[name]:
            ours = granularsap.sphere_contacts(frame.positions, frame.radius, box=_box(frame))
            ref = lammps_bridge.sphere_contacts(frame.positions, frame.radius, box=_box(frame))
            np.testing.assert_array_equal(_sorted(ours), ref,
                                          err_msg=f"{name} frame {frame.index}")

    def test_clump_contacts_every_frame(self, frames):
        for frame in frames["clumps.dump"]:
            spheres, clumps = granularsap.clump_contacts(frame.positions, frame.radius,
                                                         frame.molecule)
            ref = lammps_bridge.sphere_contacts(frame.positions, frame.radius)
            mol = frame.molecule
            ref = ref[mol[ref[:, 0]] != mol[ref[:, 1]]]  # LAMMPS: exclude molecule/intra
            np.testing.assert_array_equal(_sorted(spheres), ref,
                                          err_msg=f"clumps frame {frame.index}")
            ref_clumps = np.unique(np.sort(mol[ref], axis=1), axis=0)
            np.testing.assert_array_equal(_sorted(clumps), ref_clumps)
