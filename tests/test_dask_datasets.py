"""granularsap.dask pairs datasets: Parquet paths and datasets.

Pairs datasets written with a trailing slash, replaced with ``overwrite=True``
(never a moment where PATH holds an incomplete dataset, never deleting a
directory that is not a pairs dataset), and read back with a damaged marker or
a missing domain file.
"""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

import granularsap

pytest.importorskip("dask.dataframe")
pytest.importorskip("pyarrow")
gdask = pytest.importorskip("granularsap.dask")

CELL = [6.0, 6.0, 6.0, 90, 90, 90]


def _frame():
    return np.random.default_rng(3).uniform(0, 6, (300, 3))


def _sorted(df):
    p = df[["i", "j"]].to_numpy().astype(np.int64)
    order = np.lexsort((p[:, 1], p[:, 0]))
    return p[order], df["distance"].to_numpy()[order]


def _assert_exact(df, x):
    pairs, d = granularsap.neighbor_pairs(x, 1.0, box=CELL)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    gp, gd = _sorted(df)
    np.testing.assert_array_equal(gp, pairs[order])
    assert np.array_equal(gd, d[order])


def test_trailing_slash_path(tmp_path):
    x = _frame()
    out = str(tmp_path / "pairs.parquet") + os.sep
    marker = gdask.write_pairs(out, x, 1.0, cell=CELL, domains=3)
    assert marker["domains"] == 3
    assert os.path.isfile(os.path.join(out, "_granularsap.json"))
    assert not os.path.exists(str(tmp_path / "pairs.parquet") + ".partial")
    _assert_exact(gdask.read_pairs(out).compute(), x)
    with pytest.raises(FileExistsError):
        gdask.write_pairs(out, x, 1.0, cell=CELL)


def test_overwrite_never_leaves_an_incomplete_dataset(tmp_path, monkeypatch):
    """Replacing a dataset interrupted while the old one is deleted: PATH holds a
    complete dataset (the old one moved aside in one rename first), never a
    marker next to missing domain files."""
    x = _frame()
    out = tmp_path / "pairs.parquet"
    gdask.write_pairs(out, x, 1.0, cell=CELL, domains=4)
    real_rmtree = shutil.rmtree

    def interrupted_rmtree(path, *args, **kwargs):
        if str(path).endswith(".partial") or not os.path.isdir(path):
            return real_rmtree(path, *args, **kwargs)
        os.remove(os.path.join(path, "domain-00000.parquet"))  # deleted half-way...
        raise KeyboardInterrupt  # ...and stopped

    monkeypatch.setattr(shutil, "rmtree", interrupted_rmtree)
    with pytest.raises(KeyboardInterrupt):
        gdask.write_pairs(out, x, 1.0, cell=CELL, domains=2, overwrite=True)
    monkeypatch.undo()
    _assert_exact(gdask.read_pairs(out).compute(), x)
    marker = json.loads((out / "_granularsap.json").read_text())
    assert sorted(n for n in os.listdir(out) if n.startswith("domain-")) == [
        f"domain-{k:05d}.parquet" for k in range(marker["domains"])]
    # the next write clears what the interrupted one left beside PATH
    gdask.write_pairs(out, x, 1.0, cell=CELL, domains=3, overwrite=True)
    assert os.listdir(tmp_path) == ["pairs.parquet"]
    _assert_exact(gdask.read_pairs(out).compute(), x)


def test_overwrite_refuses_a_directory_that_is_not_a_pairs_dataset(tmp_path):
    x = _frame()
    mine = tmp_path / "results"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    with pytest.raises(FileExistsError, match="not a granularsap pairs dataset"):
        gdask.write_pairs(mine, x, 1.0, cell=CELL, overwrite=True)
    assert (mine / "notes.txt").read_text() == "keep me"
    # an existing file or an empty directory is replaced
    (tmp_path / "f").write_text("x")
    gdask.write_pairs(tmp_path / "f", x, 1.0, cell=CELL, overwrite=True)
    (tmp_path / "empty").mkdir()
    gdask.write_pairs(tmp_path / "empty", x, 1.0, cell=CELL, overwrite=True)
    _assert_exact(gdask.read_pairs(tmp_path / "empty").compute(), x)


def test_read_refuses_damaged_marker_and_missing_domain_files(tmp_path):
    x = _frame()
    out = tmp_path / "pairs.parquet"
    gdask.write_pairs(out, x, 1.0, cell=CELL, domains=4)
    bad = tmp_path / "bad"
    shutil.copytree(out, bad)
    os.remove(bad / "domain-00001.parquet")  # a partial copy of the dataset
    with pytest.raises(ValueError, match="domain-00001.parquet"):
        gdask.read_pairs(bad)
    for text in ("{not json", "[1, 2]", '"granularsap.pairs/1"'):
        (bad / "_granularsap.json").write_text(text)
        with pytest.raises(ValueError, match="marker"):
            gdask.read_pairs(bad)
    _assert_exact(gdask.read_pairs(out).compute(), x)


@pytest.mark.parametrize("domains", [(1, 1, 2), (2, 1, 2)])
def test_open_axis_with_a_subnormal_extent(domains):
    """Particles on a plane but one, a subnormal distance off it: that open axis
    may be split, and no pair is lost (k / extent used to overflow to inf, and
    the particles on the plane got a NaN owner)."""
    x = np.random.default_rng(0).uniform(0, 5, (200, 3))
    x[:, 2] = 0.0
    x[5, 2] = 5e-324
    pairs, d = granularsap.neighbor_pairs(x, 0.7)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    ds = gdask.DomainSearch(x, cutoff=0.7, domains=domains)
    gp, gd = _sorted(ds.pairs().compute(scheduler="threads"))
    np.testing.assert_array_equal(gp, pairs[order])
    assert np.array_equal(gd, d[order])
    cn = ds.coordination_numbers().compute(scheduler="threads")
    np.testing.assert_array_equal(cn, np.bincount(pairs.ravel(), minlength=len(x)))
