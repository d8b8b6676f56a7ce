"""Refuse at once a frame whose pairs cannot fit in memory.

A search holds every pair it finds in its output buffers.  A dense frame (say
1e5 points in a unit cube with a cutoff of 0.5: 2.6e9 pairs) would sweep for
minutes and then fail to allocate them; :func:`check_pair_memory` refuses it
before any pair is searched, with the pair count and the memory it needs.

The count is a *lower bound*, so a frame that fits is never refused:

1. a cheap upper bound first: ``n (n - 1) / 2`` pairs (times the images a
   range wider than the cell can reach).  If even that fits in the memory
   available, nothing more is done.  A search (minimum image) checks after
   planning its columns, which bound the pairs from above: every pair lies
   in two columns of the plan's stencil, so half the sum over columns of
   their particles times those of the stencil around them
   (:func:`column_pair_bound`, O(columns)) is at least the pair count; if
   that fits, nothing more is done; below a quarter of the memory read
   less than a second before, the memory is not even read again (a kept
   search's frames cost some 20 microseconds).  For more than 65,536
   particles, the
   bound of step 2 on every k-th particle (16,384 of them), scaled up by
   ``(n / m)^2``, estimates the pairs; under a sixteenth of the memory
   available (sparse frames: nearly all), nothing more is done either;
2. otherwise the particles are counted per cell of a grid laid over the
   (periodic or bounding) cell, about twelve cells per interaction range
   along each axis, at most ``n / 2`` (and 2**18) cells in all.  Two grid cells whose
   farthest points (corners of the two parallelepipeds) are within the range
   hold only pairs that are in, so ``sum over such offsets o of
   R(o) = sum_a n_a n_(a + o)`` (the grid's autocorrelation, one FFT) counts
   every such pair twice, plus each particle once with itself at ``o = 0``.
   The range used is shrunk by a relative 1e-6 so that rounding in the
   engine's own distance test cannot put a counted pair out.  Under the
   minimum image the range is under half of every width, so no pair is
   counted under two offsets; with every image, each image is a pair of its
   own, as the search returns them;
3. the bound times the bytes each pair takes in the output buffers the
   search allocates (by ``quantities`` and ``layout``) is compared with the
   memory available: ``MemAvailable`` plus free swap from ``/proc/meminfo``
   (``os.sysconf`` elsewhere), capped by a cgroup memory limit and
   ``RLIMIT_AS``.  More than that is a :class:`MemoryError` (a resource
   limit, not a wrong value: the same frame runs on a larger machine), raised
   in about the time of one pass over the positions.

With clump labels the pairs inside a clump are excluded, so the bound
subtracts, for every clump, all the pairs of its spheres.
"""

from __future__ import annotations

import itertools
import math
import os
import time

import numpy as np

from ._numba import jit
from .cell import widths_of

__all__ = ["available_memory", "bytes_per_pair", "check_pair_memory", "column_pair_bound",
           "pair_lower_bound"]

#: relative shrink of the range against rounding in the engine's distance test
_SHRINK = 1e-6
#: grid cells per interaction range along each axis, at best
_CELLS_PER_RANGE = 12
_MAX_CELLS = 1 << 18
#: particles of the quick estimate that decides whether the full bound is needed
_SAMPLE = 16384
#: at most this many cell offsets are tested
_MAX_OFFSETS = 4_000_000
#: a search's frame whose pairs are bounded from above by under 1/_ROOM_FACTOR
#: of the memory read less than _REREAD seconds ago does not read it again (a
#: read costs 0.1-0.2 ms beside running threads); (time, bytes) of the last read
_ROOM_FACTOR = 4
_REREAD = 1.0
_LAST_READ = [None]


def _read(path):
    """The bytes of a small file (``/proc``, ``/sys``), or None."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        return os.read(fd, 1 << 16)
    except OSError:
        return None
    finally:
        os.close(fd)


def _field_kib(text, name):
    """The value in KiB of ``name:`` in ``/proc/meminfo``'s ``text``, or None."""
    at = text.find(name)
    if at < 0:
        return None
    end = text.find(b"\n", at)
    try:
        return int(text[at + len(name):end if end >= 0 else None].split()[0])
    except (ValueError, IndexError):
        return None


def _meminfo():
    text = _read("/proc/meminfo")
    if text is None:
        return None
    avail = _field_kib(text, b"MemAvailable:")
    if avail is None:
        return None
    swap = _field_kib(text, b"SwapFree:")
    return (avail + (swap or 0)) * 1024


#: cgroup (limit, usage) files; a pair whose limit file is missing is dropped
#: (it does not appear while the process runs), so later calls skip it
_CGROUP_FILES = [("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                 ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                  "/sys/fs/cgroup/memory/memory.usage_in_bytes")]


def _cgroup_room():
    """Bytes left under this process's cgroup memory limit, or None."""
    for pair in list(_CGROUP_FILES):
        limit_path, usage_path = pair
        limit = _read(limit_path)
        if limit is None:
            if not os.path.exists(limit_path):
                _CGROUP_FILES.remove(pair)
            continue
        usage = _read(usage_path)
        try:
            usage = int(usage.strip())
        except (AttributeError, ValueError):
            continue
        limit = limit.strip()
        if limit.isdigit() and int(limit) < 1 << 60:
            return max(0, int(limit) - usage)
    return None


def _address_space_room():
    """Bytes left under ``RLIMIT_AS`` (``ulimit -v``), or None."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (ImportError, OSError, ValueError):
        return None
    if soft == resource.RLIM_INFINITY or soft < 0:
        return None
    try:
        with open("/proc/self/statm") as fh:
            used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        used = 0
    return max(0, soft - used)


def available_memory():
    """Bytes this process can still allocate, as far as the system says, or None.

    ``MemAvailable + SwapFree`` from ``/proc/meminfo`` (else free physical
    pages from ``os.sysconf``), capped by the cgroup memory limit and by
    ``RLIMIT_AS``.

    Examples
    --------
    >>> m = available_memory()
    >>> m is None or m >= 0
    True
    """
    avail = _meminfo()
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, OSError, ValueError):
            avail = None
    for room in (_cgroup_room(), _address_space_room()):
        if room is not None:
            avail = room if avail is None else min(avail, room)
    return avail


def bytes_per_pair(quantities, layout="pairs"):
    """Bytes of output buffers a search allocates per pair it returns.

    The pair buffer (two int64) always, 8 for ``'d'``, 24 each for ``'D'`` and
    ``'S'``; ``layout="csr"`` adds its neighbour column (and distances).

    Examples
    --------
    >>> bytes_per_pair("Pd"), bytes_per_pair("PdDS"), bytes_per_pair("Pd", "csr")
    (24, 72, 40)
    """
    per = 16 + 8 * ("d" in quantities) + 24 * ("D" in quantities) + 24 * ("S" in quantities)
    if layout == "csr":
        per += 8 + 8 * ("d" in quantities)
    return per


@jit
def _cell_counts(t, lo, inv, shape, periodic, counts):
    """Particles per grid cell: ``counts[a, b, c] += 1`` for each row of ``t``."""
    for i in range(t.shape[0]):
        a = np.empty(3, np.int64)
        for c in range(3):
            u = (t[i, c] - lo[c]) * inv[c]
            k = np.int64(math.floor(u)) if u == u else 0
            if periodic[c]:
                k %= shape[c]
            k = min(max(k, 0), shape[c] - 1)
            a[c] = k
        counts[a[0], a[1], a[2]] += 1.0


@jit
def _window_sums(occ, axis, layers, periodic, out):
    """``out[a, b]`` = the sum of ``occ`` over ``2 * layers + 1`` cells along ``axis``
    centred on ``(a, b)``: wrapped along a periodic axis (a cell reached twice counts
    twice), cut at the ends of an open one."""
    n0, n1 = occ.shape
    size = n0 if axis == 0 else n1
    other = n1 if axis == 0 else n0
    for b in range(other):
        for a in range(size):
            s = 0.0
            for o in range(-layers, layers + 1):
                u = a + o
                if periodic:
                    u %= size
                elif u < 0 or u >= size:
                    continue
                s += occ[u, b] if axis == 0 else occ[b, u]
            if axis == 0:
                out[a, b] = s
            else:
                out[b, a] = s


@jit
def column_pair_bound(start, nb0, nb1, layers0, layers1, pbc0, pbc1):
    """An upper bound on the pairs of a column plan: ``start`` the first row of
    each of ``nb0 * nb1`` columns (and the end), every pair within range being
    in two columns at most ``layers0``, ``layers1`` columns apart (the plan's wide
    stencil).  Half the sum over columns of its particles times those of its
    stencil (itself included), so each pair counts at least once."""
    occ = np.empty((nb0, nb1))
    for c in range(nb0 * nb1):
        occ[c // nb1, c % nb1] = start[c + 1] - start[c]
    l0 = layers0 if not pbc0 else min(layers0, nb0)
    l1 = layers1 if not pbc1 else min(layers1, nb1)
    rows = np.empty((nb0, nb1))
    _window_sums(occ, np.int64(0), l0, pbc0, rows)
    near = np.empty((nb0, nb1))
    _window_sums(rows, np.int64(1), l1, pbc1, near)
    total = 0.0
    for a in range(nb0):
        for b in range(nb1):
            total += occ[a, b] * near[a, b]
    return 0.5 * total


def _grid(t, cell, pbc, reach, n, cells):
    """(lo, span, shape): a grid over the periodic cell and the particles' open extent."""
    lo = np.zeros(3)
    span = np.ones(3)
    for c in range(3):
        if not pbc[c]:
            lo[c] = float(t[:, c].min())
            span[c] = float(t[:, c].max()) - lo[c]
    length = np.linalg.norm(cell, axis=1) * span
    budget = int(min(_MAX_CELLS, max(64, n // 2))) if cells is None else int(cells)
    side = reach / _CELLS_PER_RANGE
    while True:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            ratio = np.where(length > 0, length / side, 1.0)
        shape = np.maximum(1, np.floor(np.minimum(ratio, float(_MAX_CELLS)))).astype(np.int64)
        if int(np.prod(shape)) <= budget:
            return lo, span, shape
        side *= 1.25


def pair_lower_bound(t, cell, pbc, reach, *, all_images=False, cells=None, widths=None):
    """A number of pairs within ``reach`` that the frame has at least.

    Parameters
    ----------
    t : (n, 3) array of float
        Fractional coordinates: in ``[0, 1]`` along periodic axes, any value
        along open ones (``positions = t @ cell``).
    cell : (3, 3) array of float
        Cell vectors as rows (open axes completed by any independent vectors).
    pbc : (3,) array of bool
    reach : float
        Pairs with ``d <= reach`` are counted.
    all_images : bool
        Count every periodic image of a pair within ``reach`` (a particle with
        its own images too) instead of one per pair.
    widths : (3,) array of float, optional
        The perpendicular widths of ``cell`` when the caller holds them.

    Returns
    -------
    (int, tuple)
        The bound and the grid shape it was counted on.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.random.default_rng(0).uniform(0, 1, (4000, 3))
    >>> lb, shape = pair_lower_bound(t, np.eye(3), np.ones(3, bool), 0.3)
    >>> 0 < lb <= 4000 * 3999 // 2
    True
    """
    t = np.ascontiguousarray(t, dtype=np.float64)
    cell = np.asarray(cell, dtype=np.float64)
    pbc = np.array(pbc, dtype=bool)  # writable: the one signature of _cell_counts
    n = len(t)
    if n < 2 or not reach > 0:
        return 0, (1, 1, 1)
    reach = reach * (1.0 - _SHRINK)
    lo, span, shape = _grid(t, cell, pbc, reach, n, cells)
    with np.errstate(divide="ignore"):
        inv = np.where(span > 0, shape / span, 0.0)
    counts = np.zeros(tuple(shape))
    _cell_counts(t, lo, inv, shape, pbc, counts)
    # edge vectors of one grid cell, and its widths between opposite faces: an
    # offset o has a corner pair at least (|o_c| + 1) widths apart along axis c
    edge = cell * (span / shape)[:, None]
    widths = (widths_of(cell) if widths is None else widths) * span / shape
    kmax = np.zeros(3, np.int64)
    for c in range(3):
        if widths[c] > 0:
            kmax[c] = int(min(reach / widths[c], 1e7))
        if not pbc[c]:
            kmax[c] = min(kmax[c], shape[c] - 1)
        elif not all_images:
            kmax[c] = min(kmax[c], shape[c])  # more would be a second image of a pair
    if np.prod(2.0 * kmax + 1) > _MAX_OFFSETS:
        return 0, tuple(int(s) for s in shape)  # a range of many cells: no bound
    axes = [np.arange(-k, k + 1) for k in kmax]
    o = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3).astype(np.float64)
    far = np.zeros(len(o))
    for e in itertools.product((-1.0, 1.0), repeat=3):
        far = np.maximum(far, np.linalg.norm((o + np.array(e)) @ edge, axis=1))
    inside = o[far <= reach].astype(np.int64)
    if len(inside) == 0:
        return 0, tuple(int(s) for s in shape)
    # autocorrelation R(o) = sum_a n_a n_(a+o): circular along periodic axes,
    # zero-padded along open ones
    size = [int(s) if pbc[c] else 2 * int(s) for c, s in enumerate(shape)]
    spec = np.fft.rfftn(counts, s=size, axes=(0, 1, 2))
    corr = np.fft.irfftn(spec * np.conj(spec), s=size, axes=(0, 1, 2))
    idx = tuple(np.mod(inside[:, c], size[c]) for c in range(3))
    total = float(np.rint(corr[idx]).clip(min=0).sum())
    bound = (total * (1.0 - 1e-9) - n) / 2.0
    return max(0, int(bound)), tuple(int(s) for s in shape)


def _gib(b):
    return f"{b / 2 ** 30:.3g} GiB"


def check_pair_memory(search, t, frame_cell, reach, labels=None, columns=None):
    """Raise :class:`MemoryError` when a frame's pairs cannot fit in memory.

    Called once per build of a search, before any pair is searched (see the
    module docstring for the bound), after its column plan (``columns``).

    Parameters
    ----------
    search : NeighborSearch or ContactSearch
        Its ``quantities``, ``layout`` and ``periodic_images`` (read only).
    t : (n, 3) array of float
        The search's wrapped fractional coordinates (:func:`pair_lower_bound`).
    frame_cell : granularsap.geometry.FrameCell
        The frame's resolved cell (its matrix, pbc and widths).
    reach : float
        The smallest range of any pair (``2 * min(radii) + skin``; the cutoff).
    labels : (n,) array of int, optional
        Clump labels: pairs inside a clump are not pairs.
    columns : tuple, optional
        ``(start, nb0, nb1, layers0, layers1)`` of the search's column plan
        (``column_pair_bound``): under the minimum image, when that upper
        bound on the pairs fits in the memory available, so does the lower
        bound, and nothing more is computed (module docstring, step 1).

    Raises
    ------
    MemoryError
        Even a lower bound on the pairs needs more memory than is available.

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import NeighborSearch
    >>> from granularsap.geometry import FrameCell
    >>> t = np.random.default_rng(0).uniform(0, 1, (100, 3))
    >>> check_pair_memory(NeighborSearch(0.4), t, FrameCell.of(np.eye(3), True), 0.4)
    """
    n = len(t)
    # what the kernels write (contact identity with every image adds shifts)
    quantities = getattr(search, "_computed", search.quantities)
    layout = search.layout
    all_images = search.periodic_images == "all"
    what = type(search).__name__
    if n < 2 or not reach > 0:
        return
    per = bytes_per_pair(quantities, layout)
    upper = n * (n - 1) / 2.0
    cell, pbc, width = frame_cell.matrix, frame_cell.pbc, frame_cell.widths
    if all_images and pbc.any():
        images = np.prod([2 * math.ceil(reach / width[c]) + 1 if pbc[c] else 1
                          for c in range(3)])
        upper = n * (n + 1) / 2.0 * images
    bound_above = None
    if columns is not None and not all_images:
        # every pair (so every pair the lower bound counts) is in two columns of
        # the plan's wide stencil: an upper bound in O(columns)
        start, nb0, nb1, layers0, layers1 = columns
        bound_above = column_pair_bound(start, int(nb0), int(nb1), int(layers0),
                                        int(layers1), bool(pbc[0]), bool(pbc[1]))
        upper = min(upper, bound_above)
        last = _LAST_READ[0]
        if (last is not None and time.monotonic() - last[0] < _REREAD
                and upper * per * _ROOM_FACTOR <= last[1]):
            return  # far under what was available a moment ago
    avail = available_memory()
    if avail is not None:
        _LAST_READ[0] = (time.monotonic(), avail)
    if avail is None or upper * per <= avail:
        return
    if n > 4 * _SAMPLE:
        # a quick look first: the bound of every k-th particle, scaled up by
        # (n / m)^2 (an estimate of the pairs, not a bound).  Far under the
        # memory available, the full bound is not worth its pass over every
        # particle; the refusal below only ever rests on the full bound
        step = n // _SAMPLE
        sample = t[::step]
        m = len(sample)
        est, _ = pair_lower_bound(sample, cell, pbc, reach, all_images=all_images,
                                  widths=width)
        if est * (n / m) ** 2 * per * 16 < avail:
            return
    bound, shape = pair_lower_bound(t, cell, pbc, reach, all_images=all_images,
                                    widths=width)
    if labels is not None and bound:
        _, sizes = np.unique(labels, return_counts=True)
        if all_images:
            return  # images inside a clump are excluded too: no simple bound
        bound = max(0, bound - int((sizes * (sizes - 1) // 2).sum()))
    need = bound * per
    if need <= avail:
        return
    grid = "x".join(str(s) for s in shape)
    csr = ("; layout='csr' holds every pair as well (a half list by particle)"
           if layout == "csr" else "")
    raise MemoryError(
        f"the pairs of this frame of {n} particles ({what}) need at least {bound:.3g} pairs x "
        f"{per} bytes (quantities {quantities!r}) = {_gib(need)}, more than the "
        f"{_gib(avail)} of memory available; refused before searching (the count is a lower "
        f"bound from the particles per cell of a {grid} grid){csr}. Use a smaller range or "
        "fewer particles, or granularsap.dask (count_pairs, coordination_numbers, "
        "distance_histogram, write_pairs) to reduce or stream the pairs domain by domain")
