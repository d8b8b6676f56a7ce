"""Public entry points of the engine (interim brute-force version)."""

from __future__ import annotations

import numpy as np

from ._validate import as_coords, check_n_threads


def box_overlaps(lower, upper, *, n_threads=None):
    lower = as_coords(lower, "lower")
    upper = as_coords(upper, "upper")
    check_n_threads(n_threads)
    n = len(lower)
    out = []
    for i in range(n):
        j = np.arange(i + 1, n)
        ok = np.all((lower[i] <= upper[j]) & (lower[j] <= upper[i]), axis=1)
        out.append(np.stack([np.full(ok.sum(), i), j[ok]], axis=1))
    if not out:
        return np.empty((0, 2), np.int64)
    return np.concatenate(out).astype(np.int64)


class SweepAndPrune:
    def __init__(self, *, axes="auto", n_threads=None):
        self.n_threads = n_threads

    def update(self, lower, upper):
        return box_overlaps(lower, upper, n_threads=self.n_threads)
