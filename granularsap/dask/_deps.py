"""The optional dependencies of granularsap.dask, imported when first needed."""

from __future__ import annotations


def need_distributed(what):
    try:
        import distributed
    except ImportError as exc:  # pragma: no cover - the dask extra installs it
        raise ImportError(f"{what} needs dask.distributed: pip install "
                          "'granularsap[dask]'") from exc
    return distributed


def dataframe():
    try:
        import dask.dataframe as dd
        import pandas as pd
    except ImportError as exc:  # pragma: no cover - the dask extra installs it
        raise ImportError("pairs as a Dask DataFrame need dask.dataframe and pandas: pip "
                          "install 'granularsap[dask]'") from exc
    return dd, pd
