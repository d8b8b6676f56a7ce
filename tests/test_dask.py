"""Frames distributed with dask.distributed give the same file as a serial run."""

from __future__ import annotations

import numpy as np
import pytest

from granularsap.cli import main
from granularsap.io import ContactParams, ContactsFile, compute_contacts

from ._iohelpers import lammps_cell, random_frames, write_dump
from .test_hdf5 import assert_same_contacts_file

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def dump(tmp_path_factory):
    path = tmp_path_factory.mktemp("dask") / "d.dump"
    cell = lammps_cell(12.0, 11.0, 10.0, xy=1.0, xz=0.5, yz=-0.5)
    write_dump(path, random_frames(400, 9, cell=cell, seed=21),
               columns=("id", "type", "radius", "x", "y", "z"), shuffle_seed=3)
    return path


@pytest.fixture(scope="module")
def serial(dump, tmp_path_factory):
    out = tmp_path_factory.mktemp("dask_serial") / "serial.h5"
    compute_contacts(dump, out, ContactParams(skin=0.1, distances=True))
    return out


class TestDask:
    def test_local_cluster_two_workers_equals_serial(self, dump, serial, tmp_path):
        out = tmp_path / "w2.h5"
        assert main(["contacts", str(dump), "-o", str(out), "--skin", "0.1", "--distances",
                     "--workers", "2", "-q"]) == 0
        assert_same_contacts_file(out, serial)
        with ContactsFile(out) as cf:
            np.testing.assert_array_equal(cf.index, np.arange(9))
            assert cf.n_contacts.sum() > 0

    def test_truncated_dump_on_workers(self, dump, tmp_path, capsys):
        bad = tmp_path / "bad.dump"
        text = dump.read_text()
        bad.write_text(text[: len(text) - 100])
        out = tmp_path / "bad.h5"
        assert main(["contacts", str(bad), "-o", str(out), "--workers", "2", "-q"]) == 2
        assert "bad.dump: frame 8, line" in capsys.readouterr().err
        with ContactsFile(out, allow_incomplete=True) as cf:
            assert cf.n_frames == 8 and not cf.complete

    def test_existing_scheduler_equals_serial(self, dump, serial, tmp_path):
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster:
            out = tmp_path / "sched.h5"
            compute_contacts(dump, out, ContactParams(skin=0.1, distances=True, n_threads=1),
                             scheduler=cluster.scheduler_address)
            assert_same_contacts_file(out, serial)
            # a serial run stopped after 4 frames, resumed on the cluster
            out2 = tmp_path / "part.h5"
            count = []
            with pytest.raises(KeyboardInterrupt):
                compute_contacts(dump, out2, ContactParams(skin=0.1, distances=True),
                                 commit_seconds=0,
                                 should_stop=lambda: count.append(1) or len(count) >= 4)
            with ContactsFile(out2, allow_incomplete=True) as cf:
                assert cf.n_frames == 4
            summary = compute_contacts(dump, out2, ContactParams(skin=0.1, distances=True),
                                       scheduler=cluster.scheduler_address)
            assert summary["resumed_from"] == 4
            assert_same_contacts_file(out2, serial)
