"""Pairs datasets on Parquet: written by the workers, marked complete last, read
back only when complete."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np

from ._deps import dataframe

#: Name of the completion marker of a pairs dataset, written last.
MARKER = "_granularsap.json"


#: What a pairs dataset's marker says it is.
PAIRS_SCHEMA = "granularsap.pairs/1"


def remove_path(path):
    if os.path.isdir(path) and not os.path.islink(path):
        shutil.rmtree(path)
    elif os.path.lexists(path):
        os.remove(path)


def write_search_pairs(search, path, *, overwrite=False):
    # no trailing separator: PATH.partial and PATH.replaced are siblings of PATH
    path = os.path.normpath(os.fspath(path))
    if os.path.exists(path) and not overwrite:
        raise FileExistsError(f"{path} already exists; remove it or pass overwrite=True")
    if os.path.isdir(path) and os.listdir(path) and \
            not os.path.exists(os.path.join(path, MARKER)):
        raise FileExistsError(f"{path} is a directory that is not a granularsap pairs dataset "
                              f"(no {MARKER}); overwrite replaces only a pairs dataset, a "
                              "file or an empty directory")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise FileNotFoundError(f"output directory {parent} does not exist")
    partial = path + ".partial"
    replaced = path + ".replaced"  # an old dataset moved aside, being deleted
    remove_path(partial)
    remove_path(replaced)
    df = search.pairs()
    nd = search.n_domains
    width = max(5, len(str(nd - 1)))
    kwargs = {"write_index": False, "write_metadata_file": True,
              "name_function": lambda k: f"domain-{k:0{width}d}.parquet"}
    if search.client is not None:
        kwargs["compute_kwargs"] = {"scheduler": search.client}
    df.to_parquet(partial, **kwargs)
    import pyarrow.parquet as pq

    rows = int(pq.read_metadata(os.path.join(partial, "_metadata")).num_rows)
    marker = {"schema": PAIRS_SCHEMA, "complete": True, "n_pairs": rows,
              "n_particles": search.n, "domains": nd, "grid": list(search.grid),
              "columns": {"i": "int64", "j": "int64", "distance": "float64"},
              "mode": search.plan.kind, "cutoff": search.plan.cutoff if
              search.plan.kind == "cutoff" else None, "skin": search.plan.skin,
              "range": search.reach}
    with open(os.path.join(partial, MARKER), "w") as fh:
        json.dump(marker, fh, indent=1)
        fh.flush()
        os.fsync(fh.fileno())
    if os.path.lexists(path):
        # moved aside in one rename, so PATH never holds a half-deleted dataset
        os.replace(path, replaced)
    os.replace(partial, path)
    remove_path(replaced)
    return marker


def read_pairs(path):
    """Open a pairs dataset written by :func:`write_pairs`, refusing an incomplete one.

    A plain ``pandas.read_parquet(path)`` or ``dask.dataframe.read_parquet(path)``
    reads it too; this checks the completion marker first.

    Returns
    -------
    dask.dataframe.DataFrame
        One partition per domain file.
    """
    dd, _ = dataframe()
    path = os.fspath(path)
    marker = os.path.join(path, MARKER)
    if not os.path.exists(marker):
        raise ValueError(f"{path} is not a complete granularsap pairs dataset (no {MARKER}); "
                         "an interrupted write leaves only PATH.partial")
    try:
        with open(marker) as fh:
            meta = json.load(fh)
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: the marker {MARKER} is not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: the marker {MARKER} is not a JSON object")
    if meta.get("schema") != PAIRS_SCHEMA or not meta.get("complete"):
        raise ValueError(f"{path}: unknown or incomplete pairs dataset {meta.get('schema')!r}")
    files = sorted(f for f in os.listdir(path) if f.endswith(".parquet") and f[0] not in "._")
    nd = meta.get("domains")
    if isinstance(nd, int) and not isinstance(nd, bool):
        width = max(5, len(str(nd - 1)))
        want = [f"domain-{k:0{width}d}.parquet" for k in range(nd)]
        missing = sorted(set(want) - set(files))
        if missing:
            raise ValueError(f"{path} is incomplete: its marker names {nd} domain files and "
                             f"{len(missing)} are missing ({', '.join(missing[:3])}"
                             f"{', ...' if len(missing) > 3 else ''})")
        files = want
    _, pd = dataframe()
    meta = pd.DataFrame({"i": np.empty(0, np.int64), "j": np.empty(0, np.int64),
                         "distance": np.empty(0, np.float64)})
    return dd.from_map(read_part, [os.path.join(path, f) for f in files], meta=meta,
                       enforce_metadata=False)


def read_part(path):
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pandas()
