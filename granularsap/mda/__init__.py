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
granularsap's engine (``NeighborSearch``: ``update`` within one group, the
cross-set ``query`` of ``reference`` against a grid of ``configuration``),
with the cutoff widened by 1e-5; when MDAnalysis is
installed every candidate is then decided with the arithmetic of the method
MDAnalysis would run (``method``, or MDAnalysis's own choice when it is None; see
``granularsap.mda.arith``), so pairs at the cutoff agree with MDAnalysis too.
``backend`` is validated like MDAnalysis's (``'serial'``, ``'OpenMP'``,
``'distopia'``) and otherwise ignored; an unknown ``method`` raises a
``KeyError`` as in MDAnalysis (also a ``ValueError``, with a message naming
``method``).  ``granularsap.mda.Contacts`` (the parallel ``AnalysisBase``) lives
in ``granularsap.mda.analysis`` and is re-exported here on first access.

Cutoffs beyond half the smallest perpendicular cell width get one minimum
image per pair, as in MDAnalysis: the engine returns every image within range
(``periodic_images="all"``) and one row per pair is kept
(``arith.nearest_images``); past two images per pair on average every pair
is tested by a brute-force kernel instead (``arith.min_image_pairs``), in
memory proportional to the output.  Where MDAnalysis's own ``nsgrid`` choice
would raise "Cutoff ... too large for box", pairs at the cutoff are decided with
the arithmetic of MDAnalysis's ``bruteforce`` method.  ``capped_distance`` of a
group with itself (equal coordinates) decides each pair ``i < j`` once and
mirrors it.

Differences: pairs of ``self_capped_distance`` always have ``i < j`` (MDAnalysis's
grid method returns some pairs as ``j, i``), row order is unspecified, and the
minimum image of a triclinic cell is the true nearest image (MDAnalysis searches
the 27 neighbouring images of the wrapped separation only).  Coordinates beyond
the float32 range are refused with an error naming the argument (MDAnalysis
turns them into inf).  ``backend`` is checked for every method (MDAnalysis checks
it only on the paths that use it).  MDAnalysis is not needed to run these
functions; AtomGroups are accepted wherever MDAnalysis accepts them.  See
docs/dropins.md.
"""

from __future__ import annotations

import threading

import numpy as np

from .. import periodic
from .._validate import as_coords, as_scalar
from ..search import NeighborSearch
from . import arith

__all__ = ["Contacts", "FastNS", "capped_distance", "self_capped_distance"]  # noqa: F822 (lazy)


def __getattr__(name):
    # Contacts (an MDAnalysis AnalysisBase, granularsap/mda/analysis.py) is imported
    # on first use so that the distance drop-ins work without MDAnalysis installed
    if name == "Contacts":
        from .analysis import Contacts

        return Contacts
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")



_METHODS = ("bruteforce", "pkdtree", "nsgrid")
_BACKENDS = ("serial", "openmp", "distopia")
_F32_MAX = float(np.finfo(np.float32).max)


class _UnknownMethodError(KeyError, ValueError):
    """An unknown ``method``: a KeyError like MDAnalysis's, and a ValueError."""

    def __str__(self):
        return str(self.args[0])


class _MethodTypeError(TypeError, AttributeError):
    """A ``method`` that is not a string: MDAnalysis raises AttributeError."""


def _check_method(method):
    if method is None:
        return None
    if not isinstance(method, str):
        raise _MethodTypeError(f"method must be a string or None, got "
                               f"{type(method).__name__}")
    if method.lower() not in _METHODS:
        raise _UnknownMethodError(f"method must be one of 'bruteforce', 'nsgrid', 'pkdtree' "
                                  f"(any case) or None, got {method!r}")
    return method.lower()


def _check_backend(backend):
    if not isinstance(backend, str):
        raise TypeError(f"backend must be a string, got {type(backend).__name__}")
    if backend.lower() not in _BACKENDS:
        raise ValueError(f"backend must be one of 'serial', 'OpenMP', 'distopia' (any case), "
                         f"got {backend!r}")


def _coords(x, name):
    if hasattr(x, "positions") and not isinstance(x, np.ndarray):
        x = x.positions
    # MDAnalysis takes one (3,) coordinate, and booleans as numbers
    arr = as_coords(x, name, single_row=True, allow_bool=True)
    # MDAnalysis computes from float32 coordinates (check_coords)
    big = np.abs(arr) > _F32_MAX
    if big.any():
        row = int(np.flatnonzero(big.any(axis=1))[0])
        val = float(arr[row][big[row]][0])
        raise ValueError(f"{name} must be within float32 range (|x| <= {_F32_MAX:.4g}; "
                         f"MDAnalysis computes in float32), got {val!r} in row {row}")
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
    MDAnalysis method that would run (granularsap.mda.arith).

    Where MDAnalysis's nsgrid would raise "Cutoff ... too large for box" (its
    own limit, ``arith.nsgrid_refuses``; a cutoff of exactly half the box
    runs), the drop-in answers with the arithmetic of MDAnalysis's bruteforce
    method instead.
    """
    ref32 = ref.astype(np.float32)
    conf32 = ref32 if conf is None else conf.astype(np.float32)
    chosen = arith.choose_method(len(ref32), None if conf is None else len(conf32),
                                      max_cutoff, box32, ref32 if conf is None else
                                      np.concatenate([ref32, conf32]), method)
    if chosen == "nsgrid" and box32 is not None and arith.nsgrid_refuses(max_cutoff,
                                                                              box32):
        chosen = "bruteforce"
    if chosen == "pkdtree":
        # decided inside scipy: the float64 minimum image decides; MDAnalysis then
        # computes the distances (and applies min_cutoff to them) with calc_bonds,
        # whose arithmetic is bruteforce's.  A pair whose calc_bonds distance is
        # beyond max_cutoff (a tie in float32, or calc_bonds' image in a skewed
        # cell) is not returned: every distance stays within the cutoffs
        keep = dist <= max_cutoff
        a, b = a[keep], b[keep]
        d, keep = arith.decide(ref32, conf32, a, b, box32, max_cutoff, "bruteforce")
        return a[keep], b[keep], d[keep]
    decided = arith.decide(ref32, conf32, a, b, box32, max_cutoff, chosen)
    d, keep = decided
    return a[keep], b[keep], d[keep]


def _beyond_half_cell(cell, reach):
    """True if ``reach`` exceeds half the smallest perpendicular width of ``cell``:
    one pair then has several images in range, and the search returns every one
    of them (``periodic_images="all"``) before the nearest is kept."""
    return cell is not None and reach > 0.5 * float(periodic.perpendicular_widths(cell).min())


#: the last search of each thread, kept for its next call (same range and images):
#: its buffers and its record sizes are reused (an RDF calls once per frame); one
#: that holds more than this many bytes is not kept
_SEARCHES = threading.local()
_KEEP_BYTES = 256 << 20


def _search(kind, reach, images, n_threads):
    """A NeighborSearch (``kind="neighbor"``) for one call: this thread's last one
    when it has the same settings (its buffers, and a configuration's grid that
    comes back, are reused)."""
    key = (kind, reach, images, n_threads)
    last = getattr(_SEARCHES, "last", None)
    if last is not None and last[0] == key:
        return last[1]
    search = NeighborSearch(reach, periodic_images=images, n_threads=n_threads)
    _SEARCHES.last = (key, search)
    return search


#: beyond this many images per pair in range on average (the volume of the range
#: over the cell's), every pair is tested directly (``arith.min_image_pairs``):
#: nearly all pairs are in range then, and the engine's list of every image would
#: outgrow the answer
_IMAGES_PER_PAIR = 2.0


def _many_images(cell, reach):
    volume = abs(float(np.linalg.det(cell)))
    return 4.0 / 3.0 * np.pi * reach ** 3 > _IMAGES_PER_PAIR * volume


def _brute(ref, conf, cell, reach, n_threads):
    """Pairs by brute-force minimum image, every pair tested (memory: the output)."""
    from .._numba import num_threads

    with num_threads(n_threads) as threads:
        return arith.min_image_pairs(ref, conf, cell, reach * (1.0 + 1e-12), threads)


def _let_go_if_large(search):
    """Keep no search whose buffers are large (the caller still holds its results)."""
    last = getattr(_SEARCHES, "last", None)
    if last is not None and last[1] is search and search.nbytes > _KEEP_BYTES:
        _SEARCHES.last = None


def _self_candidates(pos, cell, reach, n_threads, any_image=False):
    """``(a, b, d)``: pairs ``a < b`` of ``pos`` whose minimum-image distance
    ``d <= reach``, whatever the cutoff (beyond half the cell: every image within
    reach from the engine, then the nearest per pair, or with ``any_image`` the
    first, when MDAnalysis's arithmetic will decide and give the distance)."""
    if _beyond_half_cell(cell, reach):
        if _many_images(cell, reach):
            a, b, d = _brute(pos, None, cell, reach, n_threads)
            keep = d <= reach
            return a[keep], b[keep], d[keep]
        search = _search("neighbor", reach, "all", n_threads)
        pairs, dist = search.update(pos, cell)
        _let_go_if_large(search)
        return arith.nearest_images(pairs, dist, len(pos), len(pos), drop_diagonal=True,
                                         any_image=any_image)
    search = _search("neighbor", reach, "minimum", n_threads)
    pairs, dist = search.update(pos, cell)
    _let_go_if_large(search)
    return pairs[:, 0], pairs[:, 1], dist


def _cross_candidates(ref, conf, cell, reach, n_threads, any_image=False):
    """``(a, b, d)``: pairs of ``ref[a]`` and ``conf[b]`` within ``reach`` (minimum
    image), from the engine's cross-set query (``NeighborSearch.query``: a grid
    of ``conf`` visited by the points of ``ref``); beyond half the cell every
    image within reach, then the nearest per pair (or with ``any_image`` the
    first)."""
    n, m = len(ref), len(conf)
    beyond = _beyond_half_cell(cell, reach)
    if beyond and _many_images(cell, reach):
        a, b, d = _brute(ref, conf, cell, reach, n_threads)
        keep = d <= reach
        return a[keep], b[keep], d[keep]
    search = _search("neighbor", reach, "all" if beyond else "minimum", n_threads)
    pairs, dist = search.query(ref, conf, cell)
    _let_go_if_large(search)
    if beyond:
        return arith.nearest_images(pairs, dist, n, m, any_image=any_image)
    return pairs[:, 0], pairs[:, 1], dist


def _finish(i, j, dist, min_cutoff, return_distances):
    if min_cutoff is not None:
        keep = dist > min_cutoff
        i, j, dist = i[keep], j[keep], dist[keep]
    pairs = np.empty((len(i), 2), dtype=np.int64)
    pairs[:, 0] = i
    pairs[:, 1] = j
    dist = np.array(dist, dtype=np.float64)  # never a view of a kept search's buffer
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
    method : {'bruteforce', 'nsgrid', 'pkdtree'}, optional
        MDAnalysis's method whose arithmetic decides pairs at the cutoff (any
        case, as in MDAnalysis).
    backend : str, optional
        ``'serial'``, ``'OpenMP'`` or ``'distopia'`` (any case); checked, then
        ignored.
    return_distances : bool, optional
    n_threads : int, optional
        numba threads (granularsap extension).

    Returns
    -------
    pairs : (k, 2) ndarray of int64
        ``i < j``, row order unspecified.
    distances : (k,) ndarray of float64
        Only if ``return_distances``.

    Raises
    ------
    KeyError
        Unknown ``method`` (as MDAnalysis; the exception is also a ValueError).
    ValueError
        Bad shapes, NaN/inf or beyond-float32 coordinates, a negative cutoff,
        an invalid box or an unknown ``backend``.
    TypeError
        Non-numeric input, a ``method`` or ``backend`` that is not a string.

    Examples
    --------
    >>> from granularsap.mda import self_capped_distance
    >>> pairs, d = self_capped_distance([[0, 0, 0], [1, 0, 0], [9, 0, 0]], 2.0,
    ...                                 box=[10, 10, 10, 90, 90, 90])
    >>> sorted(pairs.tolist())  # the pair (0, 2) across the boundary
    [[0, 1], [0, 2], [1, 2]]
    >>> [round(x, 6) for x in sorted(d.tolist())]  # MDAnalysis's float32 rounding
    [1.0, 1.0, 2.0]
    """
    from .._validate import check_n_threads

    pos = _coords(reference, "reference")
    max_cutoff, min_cutoff = _cutoffs(max_cutoff, min_cutoff)
    cell = _box(box)
    method = _check_method(method)
    _check_backend(backend)
    n_threads = check_n_threads(n_threads)
    emulate = _mda_box32(box) if len(pos) > 1 else None
    reach = max_cutoff * (1.0 + arith.WIDEN) if emulate is not None else max_cutoff
    a, b, dist = _self_candidates(pos, cell, reach, n_threads, any_image=emulate is not None)
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
    method : {'bruteforce', 'nsgrid', 'pkdtree'}, optional
        MDAnalysis's method whose arithmetic decides pairs at the cutoff (any
        case, as in MDAnalysis).
    backend : str, optional
        ``'serial'``, ``'OpenMP'`` or ``'distopia'`` (any case); checked, then
        ignored.
    return_distances : bool, optional
    n_threads : int, optional

    Returns
    -------
    pairs : (k, 2) ndarray of int64
        Column 0 indexes ``reference``, column 1 ``configuration``.
    distances : (k,) ndarray of float64
        Only if ``return_distances``.

    Raises
    ------
    KeyError, ValueError, TypeError
        As :func:`self_capped_distance`.

    Examples
    --------
    >>> from granularsap.mda import capped_distance
    >>> pairs, d = capped_distance([[0, 0, 0]], [[1, 0, 0], [0, 0, 0], [5, 0, 0]], 2.0)
    >>> sorted(pairs.tolist())
    [[0, 0], [0, 1]]
    """
    from .._validate import check_n_threads

    ref = _coords(reference, "reference")
    conf = _coords(configuration, "configuration")
    given_cutoff = max_cutoff  # its type decides MDAnalysis's rounding without a box
    max_cutoff, min_cutoff = _cutoffs(max_cutoff, min_cutoff)
    cell = _box(box)
    method = _check_method(method)
    _check_backend(backend)
    n_threads = check_n_threads(n_threads)
    n = len(ref)
    if n == 0 or len(conf) == 0:
        return _finish(np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0),
                       min_cutoff, return_distances)
    emulate = _mda_box32(box)
    reach = max_cutoff * (1.0 + arith.WIDEN) if emulate is not None else max_cutoff
    # the same coordinates twice (an RDF of a group with itself): the pairs i < j
    # of one set, decided once and mirrored (MDAnalysis's arithmetic gives (j, i)
    # the distance of (i, j) exactly: float32 differences and the image search
    # are symmetric), plus every (i, i) at distance 0
    mirror = n == len(conf) and np.array_equal(ref, conf)
    any_image = emulate is not None
    if mirror:
        a, b, dist = _self_candidates(ref, cell, reach, n_threads, any_image)
    else:
        a, b, dist = _cross_candidates(ref, conf, cell, reach, n_threads, any_image)
    if emulate is not None:
        a, b, dist = _decide_like_mdanalysis(ref, conf, a, b, dist, emulate[0], given_cutoff,
                                             method)
    else:
        keep = dist <= max_cutoff
        a, b, dist = a[keep], b[keep], dist[keep]
    if mirror:
        diag = np.arange(n, dtype=np.int64)
        a, b = np.concatenate([a, b, diag]), np.concatenate([b, a, diag])
        dist = np.concatenate([dist, dist, np.zeros(n)])
    return _finish(a, b, dist, min_cutoff, return_distances)


from .fastns import FastNS  # noqa: E402  (stateful drop-in; no MDAnalysis import)
