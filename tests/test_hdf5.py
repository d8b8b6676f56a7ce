"""The contacts HDF5 file: schema, births/deaths, incomplete files and resume, contents."""

from __future__ import annotations

import json
import os

import h5py
import numpy as np
import pytest

from granularsap.io import (
    SCHEMA_VERSION,
    ContactParams,
    ContactsFile,
    ContactsWriter,
    IncompleteFileError,
    compute_contacts,
    iter_frames,
    read_contacts,
)
from granularsap.io.hdf5 import FrameResult, pair_difference, partial_path

from ._iohelpers import lammps_cell, random_frames, write_dump
from .oracles import brute_image_pairs, sort_pairs

CELL = lammps_cell(7.0, 6.0, 6.5, xy=1.0, xz=-0.5, yz=0.4)


def pair_set(p):
    return {tuple(r) for r in np.asarray(p).tolist()}


def fake_results(k=5, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for f in range(k):
        raw = rng.integers(1, 30, (40, 2))
        raw = raw[raw[:, 0] != raw[:, 1]]
        pairs = sort_pairs(np.unique(np.sort(raw, axis=1), axis=0))
        out.append(FrameResult(index=2 * f, step=100 * f, time=None, n_particles=30,
                               cell=np.eye(3) * 10, pbc=np.ones(3, bool), pairs=pairs,
                               distances=rng.uniform(0, 1, len(pairs))))
    return out


class TestSchema:
    def test_roundtrip_with_h5py_only(self, tmp_path):
        out = tmp_path / "x.h5"
        res = fake_results()
        w = ContactsWriter(out, {"mode": "test"}, distances=True)
        for r in res:
            w.append(r)
        w.finish({"read": 1.0})
        with h5py.File(out, "r") as f:
            a = f.attrs
            assert a["format"] == "granularsap.contacts"
            assert a["schema_version"] == SCHEMA_VERSION
            assert a["complete"] == 1 and a["n_frames"] == 5 and a["pair_index"] == "id"
            assert json.loads(a["parameters"]) == {"mode": "test"}
            assert "granularsap_version" in a and "created" in a and "finished" in a
            off = f["frames/contact_offset"][:]
            assert len(off) == 6 and off[0] == 0
            assert f["contacts/pairs"].compression == "gzip"
            assert f["contacts/pairs"].chunks is not None
            for k, r in enumerate(res):
                np.testing.assert_array_equal(f["contacts/pairs"][off[k]:off[k + 1]], r.pairs)
                np.testing.assert_array_equal(f["contacts/distances"][off[k]:off[k + 1]],
                                              r.distances)
            np.testing.assert_array_equal(f["frames/index"][:], [0, 2, 4, 6, 8])
            np.testing.assert_array_equal(f["frames/step"][:], [0, 100, 200, 300, 400])
            assert np.isnan(f["frames/time"][:]).all()
        pairs = read_contacts(out)
        assert all(np.array_equal(p, r.pairs) for p, r in zip(pairs, res, strict=True))

    def test_births_and_deaths_by_id(self, tmp_path):
        out = tmp_path / "b.h5"
        res = fake_results(4, seed=3)
        with ContactsWriter(out, {}) as w:
            for r in res:
                w.append(r)
            w.finish()
        with ContactsFile(out) as cf:
            assert cf.n_born[0] == cf.n_died[0] == 0
            for f in range(1, 4):
                prev, cur = pair_set(res[f - 1].pairs), pair_set(res[f].pairs)
                assert pair_set(cf.born(f)) == cur - prev
                assert pair_set(cf.died(f)) == prev - cur
                assert cf.n_born[f] == len(cur - prev) and cf.n_died[f] == len(prev - cur)

    @pytest.mark.parametrize("shuffled", [False, True])
    def test_pair_difference_is_set_difference(self, shuffled):
        rng = np.random.default_rng(8)
        a = sort_pairs(np.unique(np.sort(rng.integers(0, 50, (300, 2)), axis=1), axis=0))
        b = sort_pairs(np.unique(np.sort(rng.integers(0, 50, (300, 2)), axis=1), axis=0))
        if shuffled:
            b = b[rng.permutation(len(b))]
        got = pair_difference(a, b)
        assert pair_set(got) == pair_set(a) - pair_set(b)
        assert len(got) == len(pair_set(got))

    def test_pair_difference_large_ids(self):
        a = np.array([[1, 2], [5_000_000_000, 6_000_000_000]], dtype=np.int64)
        b = np.array([[1, 2]], dtype=np.int64)
        np.testing.assert_array_equal(pair_difference(a, b), a[1:])

    def test_not_a_contacts_file(self, tmp_path):
        p = tmp_path / "other.h5"
        with h5py.File(p, "w") as f:
            f.attrs["format"] = "something"
        with pytest.raises(ValueError, match="not a granularsap contacts file"):
            ContactsFile(p)

    def test_newer_schema_refused(self, tmp_path):
        out = tmp_path / "n.h5"
        w = ContactsWriter(out, {})
        w.append(fake_results(1)[0])
        w.finish()
        with h5py.File(out, "r+") as f:
            f.attrs["schema_version"] = SCHEMA_VERSION + 1
        with pytest.raises(ValueError, match="schema version 2; .* upgrade granularsap"):
            ContactsFile(out)


class TestIncompleteAndResume:
    def test_interrupted_writer_never_looks_complete(self, tmp_path):
        out = tmp_path / "i.h5"
        res = fake_results(6)
        w = ContactsWriter(out, {"a": 1}, commit_seconds=0)
        for r in res[:3]:
            w.append(r)
        w.close()  # as after Ctrl-C
        assert not out.exists()
        with pytest.raises(IncompleteFileError, match="interrupted; rerun the same command"):
            ContactsFile(out)
        with pytest.raises(IncompleteFileError, match="is an interrupted run"):
            ContactsFile(partial_path(out))
        with ContactsFile(out, allow_incomplete=True) as cf:
            assert not cf.complete and cf.n_frames == 3
            np.testing.assert_array_equal(cf.pairs(2), res[2].pairs)
        segments = sorted(os.listdir(partial_path(out)))
        assert segments == ["run.json", "seg-000000.h5", "seg-000001.h5", "seg-000002.h5"]
        for name in segments[1:]:
            with h5py.File(os.path.join(partial_path(out), name), "r") as f:
                assert f.attrs["complete"] == 0
                assert f.attrs["format"] != "granularsap.contacts"

    def test_resume_ignores_a_commit_cut_short(self, tmp_path):
        out = tmp_path / "r.h5"
        ref = tmp_path / "ref.h5"
        res = fake_results(6)
        with ContactsWriter(ref, {"a": 1}) as w:
            for r in res:
                w.append(r)
            w.finish()
        w = ContactsWriter(out, {"a": 1}, commit_seconds=0)
        for r in res[:3]:
            w.append(r)
        w.close()
        # a kill during the next commit leaves a half-written temporary segment
        (tmp_path / "r.h5.partial" / "seg-000003.h5.tmp").write_bytes(b"\x89HDF torn")
        w = ContactsWriter(out, {"a": 1})
        assert w.resumed and w.n_frames == 3
        np.testing.assert_array_equal(w.done_indices, [0, 2, 4])
        for r in res[3:]:
            w.append(r)
        w.finish()
        assert not (tmp_path / "r.h5.partial").exists()
        assert_same_contacts_file(out, ref)

    def test_other_parameters_start_over(self, tmp_path):
        out = tmp_path / "o.h5"
        w = ContactsWriter(out, {"a": 1}, commit_seconds=0)
        w.append(fake_results(1)[0])
        w.close()
        w = ContactsWriter(out, {"a": 2})
        assert not w.resumed and w.n_frames == 0
        assert "different parameters" in w.discarded_reason
        w.close()

    def test_unreadable_partial_starts_over(self, tmp_path):
        out = tmp_path / "u.h5"
        (tmp_path / "u.h5.partial").write_bytes(b"\x89HDF\r\n garbage")  # not a run directory
        w = ContactsWriter(out, {})
        assert not w.resumed and "unreadable" in w.discarded_reason
        w.append(fake_results(1)[0])
        w.finish()
        with ContactsFile(out) as cf:
            assert cf.complete and cf.n_frames == 1

    @pytest.mark.parametrize("resumed", [False, True])
    def test_finish_without_frames_writes_nothing(self, tmp_path, resumed):
        """A writer given no frame refuses to finish: no 0-frame file marked complete."""
        out = tmp_path / "e.h5"
        if resumed:  # a partial run with no committed segment: nothing to resume
            ContactsWriter(out, {"a": 1})
        w = ContactsWriter(out, {"a": 1})
        assert w.n_frames == 0
        with pytest.raises(ValueError, match=r"no frame was appended.*e\.h5 was not written"):
            w.finish()
        assert not out.exists() and not os.path.exists(partial_path(out))
        assert not os.path.exists(str(out) + ".tmp")
        with pytest.raises(FileNotFoundError):
            ContactsFile(out)


def assert_same_contacts_file(a, b):
    """Every dataset equal; the attributes that describe the run equal."""
    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        names_a, names_b = [], []
        fa.visit(names_a.append)
        fb.visit(names_b.append)
        assert sorted(names_a) == sorted(names_b)
        for name in names_a:
            if isinstance(fa[name], h5py.Dataset):
                np.testing.assert_array_equal(fa[name][()], fb[name][()], err_msg=name)
        for key in ("format", "schema_version", "complete", "n_frames", "parameters",
                    "pair_index"):
            assert fa.attrs[key] == fb.attrs[key], key


def oracle_pairs(frame, params):
    """Brute-force contacts of a frame, as sorted particle-id pairs (and distances)."""
    cell = frame.cell if frame.pbc.any() else None
    if params.cutoff is not None:
        p, d = brute_image_pairs(frame.positions, params.cutoff, cell=cell, pbc=frame.pbc)
    else:
        p, d = brute_image_pairs(frame.positions, params.skin, cell=cell, pbc=frame.pbc,
                                 radii=frame.radius)
    ids = frame.ids[p]
    order = np.lexsort((ids[:, 1], ids[:, 0]))
    return ids[order], d[order]


class TestContentsEqualOracle:
    @pytest.mark.parametrize("pbc", ["pp pp pp", "pp pp fm", "ff ff ff"])
    @pytest.mark.parametrize("params", [ContactParams(), ContactParams(skin=0.2),
                                        ContactParams(cutoff=1.3, distances=True)],
                             ids=["spheres", "skin", "cutoff"])
    def test_every_frame(self, tmp_path, pbc, params):
        dump = tmp_path / "t.dump"
        frames = random_frames(90, 3, cell=CELL, seed=11)
        for fr in frames:
            fr["ids"] = np.arange(90) * 3 + 7  # ids are not row numbers
        write_dump(dump, frames, columns=("id", "type", "radius", "x", "y", "z"),
                   shuffle_seed=2, pbc=pbc)
        out = tmp_path / "t.h5"
        compute_contacts(dump, out, params)
        with ContactsFile(out) as cf:
            assert cf.n_frames == 3
            for k, fr in enumerate(iter_frames(dump)):
                want, dist = oracle_pairs(fr, params)
                np.testing.assert_array_equal(cf.pairs(k), want)
                if params.distances:
                    np.testing.assert_allclose(cf.distances(k), dist, rtol=1e-12)
                assert cf.n_particles[k] == 90

    def test_clumps(self, tmp_path):
        dump = tmp_path / "c.dump"
        rng = np.random.default_rng(12)
        centres = rng.uniform(0, 1, (20, 3)) @ CELL
        frames = []
        for k in range(2):  # 20 rigid clumps of 3 spheres, moving a little
            offsets = rng.uniform(-0.4, 0.4, (20, 3, 3))
            pos = (centres[:, None, :] + offsets + 0.3 * k).reshape(60, 3)
            frames.append({"positions": pos, "cell": CELL, "radius": np.full(60, 0.35),
                           "mol": np.repeat(np.arange(1, 21), 3), "step": k})
        write_dump(dump, frames, columns=("id", "mol", "radius", "x", "y", "z"), shuffle_seed=1)
        out = tmp_path / "c.h5"
        compute_contacts(dump, out, ContactParams(clumps=True))
        with ContactsFile(out) as cf:
            for k, fr in enumerate(iter_frames(dump)):
                want, _ = oracle_pairs(fr, ContactParams())
                mol = dict(zip(fr.ids.tolist(), fr.molecule.tolist(), strict=True))
                keep = [mol[i] != mol[j] for i, j in want.tolist()]
                np.testing.assert_array_equal(cf.pairs(k), want[np.asarray(keep, bool)])
                clumps = {tuple(sorted((mol[i], mol[j]))) for i, j in want[keep].tolist()}
                assert pair_set(cf.clump_pairs(k)) == clumps

    def test_frames_selection_and_overwrite(self, tmp_path):
        dump = tmp_path / "s.dump"
        write_dump(dump, random_frames(30, 7, cell=CELL, seed=13),
                   columns=("id", "radius", "x", "y", "z"))
        out = tmp_path / "s.h5"
        compute_contacts(dump, out, ContactParams(), frames=slice(1, None, 3))
        with ContactsFile(out) as cf:
            np.testing.assert_array_equal(cf.index, [1, 4])
            np.testing.assert_array_equal(cf.step, [1000, 4000])
        with pytest.raises(FileExistsError, match="already exists"):
            compute_contacts(dump, out, ContactParams())
        compute_contacts(dump, out, ContactParams(radius=0.4), overwrite=True)
        with ContactsFile(out) as cf:
            assert cf.n_frames == 7 and cf.parameters["radius"] == 0.4

    def test_bad_parameters(self):
        with pytest.raises(ValueError, match="only one of cutoff, radius and radius_column"):
            ContactParams(cutoff=1.0, radius=1.0)
        with pytest.raises(ValueError, match="skin must be a finite non-negative number"):
            ContactParams(skin=-1.0)
        with pytest.raises(ValueError, match="cutoff mode takes no skin"):
            ContactParams(cutoff=1.0, skin=0.1)
        with pytest.raises(ValueError, match="distances are not available with clumps"):
            ContactParams(clumps=True, distances=True)

    def test_missing_radius_column(self, tmp_path):
        dump = tmp_path / "n.dump"
        write_dump(dump, random_frames(10, 1, cell=CELL), columns=("id", "x", "y", "z"))
        with pytest.raises(ValueError, match="has no radius or diameter column; give a cutoff"):
            compute_contacts(dump, tmp_path / "n.h5", ContactParams())
        with pytest.raises(KeyError, match="no per-particle column 'rad'"):
            compute_contacts(dump, tmp_path / "n.h5", ContactParams(radius_column="rad"))


class TestChangingParticleCounts:
    """The writer with frames of 0 particles and particles that come and go (by id)."""

    def frames(self):
        rng = np.random.default_rng(11)
        out, present = [], np.zeros(0, np.int64)
        for f, n_new in enumerate([0, 12, 8, 0, -15, -5, 0, 6]):
            if n_new > 0:  # insert particles with fresh ids
                top = present.max() + 1 if len(present) else 1
                present = np.concatenate([present, np.arange(top, top + n_new)])
            elif n_new < 0:  # lose some at random
                present = np.sort(rng.choice(present, len(present) + n_new, replace=False))
            if len(present) > 1:
                raw = rng.choice(present, (3 * len(present), 2))
                raw = raw[raw[:, 0] != raw[:, 1]]
                pairs = sort_pairs(np.unique(np.sort(raw, axis=1), axis=0))
            else:
                pairs = np.empty((0, 2), np.int64)
            out.append(FrameResult(index=f, step=10 * f, time=None,
                                   n_particles=len(present), cell=np.eye(3) * 9,
                                   pbc=np.ones(3, bool), pairs=pairs,
                                   distances=rng.uniform(0, 1, len(pairs))))
        return out

    @pytest.mark.parametrize("cut", [None, 1, 3, 6], ids=["whole", "resume1", "resume3",
                                                          "resume6"])
    def test_counts_and_births_deaths_by_id(self, tmp_path, cut):
        res = self.frames()
        counts = [r.n_particles for r in res]
        assert 0 in counts[1:-1] and counts[0] == 0 and max(counts) > 15
        out = tmp_path / "c.h5"
        w = ContactsWriter(out, {"mode": "test"}, distances=True, commit_seconds=0)
        for r in res[:cut]:
            w.append(r)
        if cut is not None:  # interrupted after `cut` frames (possibly after an empty one)
            w.close()
            w = ContactsWriter(out, {"mode": "test"}, distances=True, commit_seconds=0)
            assert w.resumed and w.n_frames == cut
            for r in res[cut:]:
                w.append(r)
        w.finish()
        with ContactsFile(out) as cf:
            np.testing.assert_array_equal(cf.n_particles, counts)
            np.testing.assert_array_equal(cf.n_contacts, [len(r.pairs) for r in res])
            for f, r in enumerate(res):
                got = cf.pairs(f)
                assert got.shape == (len(r.pairs), 2) and got.dtype == np.int64
                np.testing.assert_array_equal(got, r.pairs)
                np.testing.assert_array_equal(cf.distances(f), r.distances)
                prev = pair_set(res[f - 1].pairs) if f else pair_set(r.pairs)
                assert pair_set(cf.born(f)) == pair_set(r.pairs) - prev
                assert pair_set(cf.died(f)) == prev - pair_set(r.pairs)
