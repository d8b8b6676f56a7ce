"""Trajectories whose particle count changes, made by LAMMPS itself.

``inflow``: ``fix pour`` into an empty box (the first frame has 0 atoms), then
the pile drains through the open bottom (atoms lost, back to 0).
``evaporate``: an LJ liquid in a triclinic periodic cell losing 60 atoms every
100 steps (``fix evaporate``) down to 0.  Both are generated into a temporary
directory by ``lammps_bridge.generate`` (about 1 s each).

The oracle reads the dump text with a few lines of numpy (no granularsap) and
finds every frame's contacts by brute force over all pairs and periodic images.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from granularsap.cli import main
from granularsap.io import ContactsFile, iter_frames

# ---------------------------------------------------------------- the oracle


def parse_dump(path):
    """Every frame of a LAMMPS text dump as a dict of numpy arrays (independent parser)."""
    with open(path) as fh:
        lines = fh.read().splitlines()
    frames, k = [], 0
    while k < len(lines):
        assert lines[k] == "ITEM: TIMESTEP"
        step = int(lines[k + 1])
        n = int(lines[k + 3])
        words = lines[k + 4].split()[3:]
        bounds = np.array([[float(v) for v in lines[k + 5 + a].split()] for a in range(3)])
        tri = "xy" in words
        flags = words[3:] if tri else words
        xy, xz, yz = bounds[:, 2] if tri else (0.0, 0.0, 0.0)
        xlo = bounds[0, 0] - min(0.0, xy, xz, xy + xz)
        xhi = bounds[0, 1] - max(0.0, xy, xz, xy + xz)
        ylo = bounds[1, 0] - min(0.0, yz)
        yhi = bounds[1, 1] - max(0.0, yz)
        cell = np.array([[xhi - xlo, 0, 0], [xy, yhi - ylo, 0],
                         [xz, yz, bounds[2, 1] - bounds[2, 0]]])
        names = lines[k + 8].split()[2:]
        rows = np.array([[float(v) for v in line.split()] for line in lines[k + 9:k + 9 + n]],
                        dtype=np.float64).reshape(n, len(names))
        cols = {name: rows[:, c] for c, name in enumerate(names)}
        frames.append({"step": step, "n": n, "ids": cols["id"].astype(np.int64),
                       "pos": np.column_stack([cols["x"], cols["y"], cols["z"]]),
                       "radius": cols.get("radius"), "cell": cell,
                       "pbc": np.array([f == "pp" for f in flags])})
        k += 9 + n
    return frames


def oracle_id_pairs(fr, *, cutoff=None, skin=0.0):
    """Sorted (k, 2) id pairs with d <= cutoff, or d <= r_i + r_j + skin, by brute force."""
    pos, ids = fr["pos"], fr["ids"]
    reps = [(-1, 0, 1) if p else (0,) for p in fr["pbc"]]
    shifts = np.array([a * fr["cell"][0] + b * fr["cell"][1] + c * fr["cell"][2]
                       for a in reps[0] for b in reps[1] for c in reps[2]])
    d = pos[None, :, None, :] + shifts[None, None] - pos[:, None, None, :]
    dist = np.sqrt((d * d).sum(axis=-1)).min(axis=-1)
    reach = cutoff if cutoff is not None else fr["radius"][:, None] + fr["radius"][None] + skin
    i, j = np.nonzero(np.triu(dist <= reach, k=1))
    pairs = np.sort(np.column_stack([ids[i], ids[j]]), axis=1).reshape(-1, 2)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order], dist[i, j][order]


def as_set(pairs):
    return {tuple(p) for p in np.asarray(pairs).reshape(-1, 2).tolist()}


# ---------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def dumps(tmp_path_factory):
    from lammps_bridge import generate

    out = tmp_path_factory.mktemp("changing")
    return {name: str(generate.generate(name, out, log=False)[0])
            for name in ("inflow", "evaporate")}


@pytest.fixture(scope="module")
def oracle(dumps):
    return {name: parse_dump(path) for name, path in dumps.items()}


def test_the_dumps_change_size_through_zero(oracle):
    counts = {name: [f["n"] for f in frames] for name, frames in oracle.items()}
    inflow, evap = counts["inflow"], counts["evaporate"]
    assert inflow[0] == 0 and max(inflow) == 300 and inflow[-1] == 0
    assert len(set(inflow)) >= 5  # inserted in batches, lost gradually
    assert evap[0] == 256 and evap[-1] == 0 and len(set(evap)) >= 5
    assert list(oracle["inflow"][0]["pbc"]) == [True, True, False]


# ---------------------------------------------------------------- reader


class TestReader:
    @pytest.mark.parametrize("name", ["inflow", "evaporate"])
    def test_frames_have_the_dump_counts_ids_and_positions(self, dumps, oracle, name):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no "loadtxt: input contained no data"
            frames = list(iter_frames(dumps[name]))
        assert len(frames) == len(oracle[name])
        for fr, want in zip(frames, oracle[name], strict=True):
            assert fr.n_particles == want["n"] and fr.step == want["step"]
            order = np.argsort(want["ids"])
            np.testing.assert_array_equal(fr.ids, want["ids"][order])
            np.testing.assert_array_equal(fr.positions, want["pos"][order])
            np.testing.assert_allclose(fr.cell, want["cell"], rtol=1e-15, atol=1e-15)

    def test_empty_frames_have_typed_empty_arrays(self, dumps):
        frames = list(iter_frames(dumps["inflow"]))
        for fr in (frames[0], frames[-1]):
            assert fr.n_particles == 0
            assert fr.positions.shape == (0, 3) and fr.positions.dtype == np.float64
            assert fr.positions.flags.c_contiguous
            assert fr.ids.shape == (0,) and fr.ids.dtype == np.int64
            assert fr.radius.shape == (0,) and fr.radius.dtype == np.float64
            assert fr.types.shape == (0,) and fr.types.dtype == np.int64
            assert set(fr.columns) == {"id", "type", "radius", "x", "y", "z"}
            assert all(len(c) == 0 for c in fr.columns.values())
            assert fr.cell.shape == (3, 3) and list(fr.pbc) == [True, True, False]

    def test_empty_frame_with_an_element_column_and_scaled_coordinates(self, tmp_path):
        path = tmp_path / "e.dump"
        path.write_text("ITEM: TIMESTEP\n5\nITEM: NUMBER OF ATOMS\n0\n"
                        "ITEM: BOX BOUNDS pp pp pp\n0 2\n0 3\n0 4\n"
                        "ITEM: ATOMS id element xs ys zs\n"
                        "ITEM: TIMESTEP\n6\nITEM: NUMBER OF ATOMS\n1\n"
                        "ITEM: BOX BOUNDS pp pp pp\n0 2\n0 3\n0 4\n"
                        "ITEM: ATOMS id element xs ys zs\n7 Ar 0.5 0.5 0.5\n")
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            empty, one = iter_frames(path)
        assert empty.positions.shape == (0, 3) and empty.positions.dtype == np.float64
        assert empty.types.dtype.kind == one.types.dtype.kind == "U"
        np.testing.assert_array_equal(one.positions, [[1.0, 1.5, 2.0]])

    def test_a_selection_of_empty_frames_only(self, dumps):
        (fr,) = iter_frames(dumps["evaporate"], frames=slice(6, 7))
        assert fr.n_particles == 0 and fr.step == 600

    def test_mdanalysis_cannot_read_changing_counts_and_says_so(self, dumps):
        pytest.importorskip("MDAnalysis")
        with pytest.raises(ValueError, match=r"evaporate\.dump: MDAnalysis cannot read a "
                                             r"trajectory whose atom count changes.*"
                                             r"format='lammps-dump'"):
            list(iter_frames(dumps["evaporate"], format="mdanalysis:LAMMPSDUMP"))


# ---------------------------------------------------------------- granularsap contacts


def check_file_against_oracle(path, frames, **crit):
    with ContactsFile(path) as cf:
        assert cf.complete and cf.n_frames == len(frames)
        np.testing.assert_array_equal(cf.n_particles, [f["n"] for f in frames])
        np.testing.assert_array_equal(cf.step, [f["step"] for f in frames])
        prev = None
        for k, fr in enumerate(frames):
            want, dist = oracle_id_pairs(fr, **crit)
            got = cf.pairs(k)
            assert got.shape[1:] == (2,) and got.dtype == np.int64
            np.testing.assert_array_equal(got, want)
            if "distances" in cf.file["contacts"]:
                np.testing.assert_allclose(cf.distances(k), dist, rtol=1e-12)
            if prev is not None:  # births and deaths by particle id, across count changes
                assert as_set(cf.born(k)) == as_set(want) - as_set(prev)
                assert as_set(cf.died(k)) == as_set(prev) - as_set(want)
            else:
                assert len(cf.born(k)) == len(cf.died(k)) == 0
            prev = want
        return cf.n_contacts.copy()


class TestContacts:
    def test_inflow_spheres_serial(self, dumps, oracle, tmp_path):
        out = tmp_path / "in.h5"
        assert main(["contacts", dumps["inflow"], "-o", str(out), "--skin", "0.05", "-q"]) == 0
        n = check_file_against_oracle(out, oracle["inflow"], skin=0.05)
        assert n.max() > 100 and n[0] == n[-1] == 0

    def test_inflow_spheres_two_dask_workers(self, dumps, oracle, tmp_path):
        pytest.importorskip("distributed")
        out = tmp_path / "w2.h5"
        assert main(["contacts", dumps["inflow"], "-o", str(out), "--skin", "0.05",
                     "--workers", "2", "-q"]) == 0
        check_file_against_oracle(out, oracle["inflow"], skin=0.05)

    def test_evaporate_cutoff_with_distances(self, dumps, oracle, tmp_path):
        out = tmp_path / "ev.h5"
        assert main(["contacts", dumps["evaporate"], "-o", str(out), "--cutoff", "1.2",
                     "--distances", "-q"]) == 0
        n = check_file_against_oracle(out, oracle["evaporate"], cutoff=1.2)
        assert n[0] > 500 and n[-1] == 0

    def test_a_run_of_empty_frames_only(self, dumps, oracle, tmp_path):
        out = tmp_path / "e.h5"
        assert main(["contacts", dumps["evaporate"], "-o", str(out), "--cutoff", "1.2",
                     "--frames", "5:", "-q"]) == 0
        check_file_against_oracle(out, oracle["evaporate"][5:], cutoff=1.2)

    def test_info_reports_particle_counts(self, dumps, oracle, tmp_path, capsys):
        out = tmp_path / "i.h5"
        assert main(["contacts", dumps["inflow"], "-o", str(out), "-q"]) == 0
        capsys.readouterr()
        assert main(["info", str(out), "--json"]) == 0
        s = json.loads(capsys.readouterr().out)
        counts = [f["n"] for f in oracle["inflow"]]
        assert s["n_particles"] == counts
        changes = int(np.count_nonzero(np.diff(counts)))
        assert s["particles_changed"] == changes
        assert s["empty_frames"] == counts.count(0)
        z = [2 * c / n if n else 0.0 for c, n in zip(s["n_contacts"], counts, strict=True)]
        np.testing.assert_allclose(s["coordination"], z)
        assert main(["info", str(out)]) == 0
        text = capsys.readouterr().out
        assert (f"particles:     min 0, mean {np.mean(counts):.4g}, max 300; first 0, last 0; "
                f"count changes at {changes} of {len(counts) - 1} transitions, "
                f"{counts.count(0)} frame{'' if counts.count(0) == 1 else 's'} empty") in text


class TestValidate:
    def test_inflow_partly_periodic_against_lammps_and_mdanalysis(self, dumps, capsys):
        # a pour in a pp pp ff box, empty at the start and at the end
        rc = main(["validate", dumps["inflow"], "--against", "lammps,mdanalysis"])
        out = capsys.readouterr().out
        assert rc in (0, 3), out  # 3: float32 ties with MDAnalysis only
        assert "NOT a tie" not in out
        rows = [line.split() for line in out.splitlines()[2:] if line[:5].strip().isdigit()]
        assert len(rows) > 10 and any(int(r[3]) > 100 for r in rows)
        for r in rows:  # granularsap, lammps, +0/-0: LAMMPS agrees exactly
            assert r[3] == r[4] and r[5] == "+0/-0"
