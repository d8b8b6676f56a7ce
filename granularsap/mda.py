"""Drop-in replacements for ``MDAnalysis.lib.distances.capped_distance`` and
``self_capped_distance``.

Swap the import and nothing else changes::

    # from MDAnalysis.lib.distances import capped_distance, self_capped_distance
    from granularsap.mda import capped_distance, self_capped_distance

Arguments, return types (``int64`` pairs of shape ``(k, 2)``, ``float64``
distances of shape ``(k,)``), ``min_cutoff`` (exclusive) and ``max_cutoff``
(inclusive) follow MDAnalysis.  Like MDAnalysis, coordinates and the box are
rounded to float32 first (MDAnalysis's ``check_coords``) and the triclinic cell
matrix is built the way ``triclinic_vectors`` builds it.  The search is always
granularsap's Sweep and Prune, with the cutoff widened by 1e-5; when MDAnalysis is
installed every candidate is then decided with the arithmetic of the method
MDAnalysis would run (``method``, or MDAnalysis's own choice when it is None; see
``granularsap._mda_arith``), so pairs at the cutoff agree with MDAnalysis too.
``backend`` is accepted for signature compatibility and ignored.
``granularsap.mda.Contacts`` (the parallel ``AnalysisBase``) lives in
``granularsap.mda_analysis`` and is re-exported here on first access.

Differences: pairs of ``self_capped_distance`` always have ``i < j`` (MDAnalysis's
grid method returns some pairs as ``j, i``), row order is unspecified, and the
minimum image of a triclinic cell is the true nearest image (MDAnalysis searches
the 27 neighbouring images of the wrapped separation only).  MDAnalysis is not
needed to run these functions; AtomGroups are accepted wherever MDAnalysis
accepts them.
"""

from __future__ import annotations

import numpy as np

from . import _mda_arith, periodic
from ._validate import as_coords, as_scalar
from .particles import _search

__all__ = ["Contacts", "capped_distance", "self_capped_distance"]  # noqa: F822 (lazy)


def __getattr__(name):
    # Contacts (an MDAnalysis AnalysisBase, granularsap/mda_analysis.py) is imported
    # on first use so that the distance drop-ins work without MDAnalysis installed
    if name == "Contacts":
        from .mda_analysis import Contacts

        return Contacts
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

_PBC = np.ones(3, dtype=bool)


def _coords(x, name):
    if hasattr(x, "positions") and not isinstance(x, np.ndarray):
        x = x.positions
    arr = as_coords(x, name)
    # MDAnalysis computes from float32 coordinates (check_coords)
    return arr.astype(np.float32).astype(np.float64)


def _box(box):
    if box is None:
        return None
    arr = np.asarray(box)
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"box must be an array of real numbers, got dtype {arr.dtype}")
    if arr.shape != (6,):
        raise ValueError("box must be None or of the form [lx, ly, lz, alpha, beta, gamma], "
                         f"got shape {arr.shape}")
    box32 = arr.astype(np.float32)
    cell = periodic.as_cell(box32.astype(np.float64), "box")
    # MDAnalysis keeps the cell matrix in float32
    return cell.astype(np.float32).astype(np.float64)


def _cutoffs(max_cutoff, min_cutoff):
    max_cutoff = as_scalar(max_cutoff, "max_cutoff")
    if min_cutoff is not None:
        min_cutoff = as_scalar(min_cutoff, "min_cutoff", nonnegative=False)
    return max_cutoff, min_cutoff


def _mda_box32(box):
    """``(box32,)`` when MDAnalysis is importable (its arithmetic is then
    reproduced at the cutoff), else None."""
    try:
        import MDAnalysis.lib.distances  # noqa: F401
    except ImportError:
        return None
    return (None if box is None else np.asarray(box, dtype=np.float32),)


def _decide_like_mdanalysis(ref, conf, a, b, dist, box32, max_cutoff, method):
    """Re-decide candidates ``(ref[a], conf[b])`` with the arithmetic of the
    MDAnalysis method that would run (granularsap._mda_arith)."""
    ref32 = ref.astype(np.float32)
    conf32 = ref32 if conf is None else conf.astype(np.float32)
    chosen = _mda_arith.choose_method(len(ref32), None if conf is None else len(conf32),
                                      max_cutoff, box32, ref32 if conf is None else
                                      np.concatenate([ref32, conf32]), method)
    decided = _mda_arith.decide(ref32, conf32, a, b, box32, max_cutoff, chosen)
    if decided is None:  # pkdtree: decided inside scipy; keep float64 minimum image
        keep = dist <= max_cutoff
        return a[keep], b[keep], dist[keep]
    d, keep = decided
    return a[keep], b[keep], d[keep]


def _finish(i, j, dist, min_cutoff, return_distances):
    if min_cutoff is not None:
        keep = dist > min_cutoff
        i, j, dist = i[keep], j[keep], dist[keep]
    pairs = np.empty((len(i), 2), dtype=np.int64)
    pairs[:, 0] = i
    pairs[:, 1] = j
    dist = np.ascontiguousarray(dist, dtype=np.float64)
    return (pairs, dist) if return_distances else pairs


def self_capped_distance(reference, max_cutoff, min_cutoff=None, box=None, method=None,
                         return_distances=True, backend="serial", *, n_threads=None):
    """Pairs within ``reference`` with ``min_cutoff < d <= max_cutoff``.

    Drop-in for ``MDAnalysis.lib.distances.self_capped_distance``.

    Parameters
    ----------
    reference : (n, 3) or (3,) array_like of float, or AtomGroup
    max_cutoff : float
        Inclusive upper cutoff.
    min_cutoff : float, optional
        Exclusive lower cutoff.
    box : (6,) array_like of float, optional
        ``[lx, ly, lz, alpha, beta, gamma]``; minimum image convention.
    method : str, optional
        MDAnalysis's method whose arithmetic decides pairs at the cutoff.
    backend : str, optional
        Accepted for compatibility; ignored.
    return_distances : bool, optional
    n_threads : int, optional
        numba threads (granularsap extension).

    Returns
    -------
    pairs : (k, 2) ndarray of int64
        ``i < j``, row order unspecified.
    distances : (k,) ndarray of float64
        Only if ``return_distances``.

    Examples
    --------
    >>> from granularsap.mda import self_capped_distance
    >>> pairs, d = self_capped_distance([[0, 0, 0], [1, 0, 0], [9, 0, 0]], 2.0,
    ...                                 box=[10, 10, 10, 90, 90, 90])
    >>> sorted(pairs.tolist()), sorted(d.tolist())
    ([[0, 1], [0, 2], [1, 2]], [1.0, 1.0, 2.0])
    """
    from ._validate import check_n_threads

    pos = _coords(reference, "reference")
    max_cutoff, min_cutoff = _cutoffs(max_cutoff, min_cutoff)
    cell = _box(box)
    n_threads = check_n_threads(n_threads)
    emulate = _mda_box32(box) if len(pos) > 1 else None
    reach = max_cutoff * (1.0 + _mda_arith.WIDEN) if emulate is not None else max_cutoff
    rad = np.full(len(pos), 0.5 * reach)
    a, b, _, dist, _ = _search(pos, rad, 0.0, cell, _PBC, n_threads=n_threads,
                               minimum_image="reduce", what="max_cutoff")
    if emulate is not None:
        a, b, dist = _decide_like_mdanalysis(pos, None, a, b, dist, emulate[0], max_cutoff,
                                             method)
    return _finish(a, b, dist, min_cutoff, return_distances)


def capped_distance(reference, configuration, max_cutoff, min_cutoff=None, box=None,
                    method=None, return_distances=True, backend="serial", *, n_threads=None):
    """Pairs ``(i, j)`` of ``reference[i]`` and ``configuration[j]`` within the cutoffs.

    Drop-in for ``MDAnalysis.lib.distances.capped_distance``.

    Parameters
    ----------
    reference : (n, 3) or (3,) array_like of float, or AtomGroup
    configuration : (m, 3) or (3,) array_like of float, or AtomGroup
    max_cutoff : float
        Inclusive upper cutoff.
    min_cutoff : float, optional
        Exclusive lower cutoff.
    box : (6,) array_like of float, optional
    method : str, optional
        MDAnalysis's method whose arithmetic decides pairs at the cutoff.
    backend : str, optional
        Accepted for compatibility; ignored.
    return_distances : bool, optional
    n_threads : int, optional

    Returns
    -------
    pairs : (k, 2) ndarray of int64
        Column 0 indexes ``reference``, column 1 ``configuration``.
    distances : (k,) ndarray of float64
        Only if ``return_distances``.

    Examples
    --------
    >>> from granularsap.mda import capped_distance
    >>> pairs, d = capped_distance([[0, 0, 0]], [[1, 0, 0], [0, 0, 0], [5, 0, 0]], 2.0)
    >>> sorted(pairs.tolist())
    [[0, 0], [0, 1]]
    """
    from ._validate import check_n_threads

    ref = _coords(reference, "reference")
    conf = _coords(configuration, "configuration")
    max_cutoff, min_cutoff = _cutoffs(max_cutoff, min_cutoff)
    cell = _box(box)
    n_threads = check_n_threads(n_threads)
    n = len(ref)
    if n == 0 or len(conf) == 0:
        return _finish(np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0),
                       min_cutoff, return_distances)
    # the smaller set gets boxes of half-width max_cutoff, the other set points
    # (zero-size boxes): a cross pair is in range iff d <= max_cutoff + 0, and the
    # larger set produces no pairs among itself in the broad phase
    emulate = _mda_box32(box)
    reach = max_cutoff * (1.0 + _mda_arith.WIDEN) if emulate is not None else max_cutoff
    pos = np.concatenate([ref, conf])
    rad = np.zeros(len(pos))
    if n <= len(conf):
        rad[:n] = reach
    else:
        rad[n:] = reach
    a, b, _, dist, _ = _search(pos, rad, 0.0, cell, _PBC, n_threads=n_threads,
                               minimum_image="reduce", what="max_cutoff", split=n,
                               reach_max=reach)
    b = b - n
    if emulate is not None:
        a, b, dist = _decide_like_mdanalysis(ref, conf, a, b, dist, emulate[0], max_cutoff,
                                             method)
    return _finish(a, b, dist, min_cutoff, return_distances)
