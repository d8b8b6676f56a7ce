"""Compile granularsap's numba kernels ahead of time, and say so when a run compiles.

granularsap's kernels are compiled by numba on first use and cached on disk
(``cache=True``): the first ``granularsap contacts`` on a fresh install spends
most of its time compiling, every later run loads the compiled code in a
fraction of a second.  ``granularsap warmup`` runs, on tiny inputs, what each
command and search runs, group by group (:data:`GROUPS`): the searches of
``granularsap contacts`` in every mode and the one-shot functions, on both
candidate paths (the column sweep and the paper's Sweep and Prune, either of
which ``path="auto"`` may take), with one thread and with two (the serial
kernels small inputs take and the parallel ones large inputs take), open,
periodic, triclinic and partly periodic; the stateful searches' Verlet lists
and other outputs; the boxes; the MDAnalysis and ASE drop-ins.  So the cache
is filled before the first real run (useful in a container image or before
starting many worker processes).

:func:`compile_notice` is how the command line notices a cold cache: it
listens to numba's ``numba:compile`` event (numba's documented event API),
which fires only when a kernel is really compiled, not when it is loaded from
the cache, and prints one line to stderr the first time a granularsap kernel
compiles.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time

__all__ = ["GROUPS", "compile_notice", "kernel_signatures", "warm_contacts", "warmup"]

#: the groups warmup compiles, in the order it runs them, with what each covers
GROUPS = {
    "contacts": "granularsap contacts (every mode), info and validate; sphere_contacts, "
                "neighbor_pairs, clump_contacts",
    "search": "NeighborSearch and ContactSearch beyond those: Verlet lists (rebuild_margin), "
              "vectors and shifts, layout='csr', periodic_images='all', identity=True "
              "(and ContactIdentity), cross-set queries (query), ContactList",
    "boxes": "box_overlaps and SweepAndPrune",
    "dropins": "granularsap.mda (capped_distance, self_capped_distance, FastNS, Contacts) "
               "and granularsap.ase (neighbor_list, NeighborList)",
}

#: older names accepted by ``--only``: the group that compiles what they use
ALIASES = {"sphere_contacts": "contacts", "neighbor_pairs": "contacts",
           "clump_contacts": "contacts", "box_overlaps": "boxes"}

#: kept for callers of the first version: the public functions of the contacts group
FUNCTIONS = ("sphere_contacts", "neighbor_pairs", "clump_contacts", "box_overlaps")

NOTICE = ("granularsap: compiling numba kernels on first use (once: seconds for one kind of "
          "frame; they are cached for the next runs; `granularsap warmup` compiles them ahead)")


def _ours(dispatcher):
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
    return module.split(".")[0] in ("granularsap", "lammps_bridge")


class _CompileCounter:
    """Counts compilations of granularsap kernels; calls ``on_first`` at the first one."""

    def __init__(self, on_first=None):
        from numba.core import event

        counter = self

        class Listener(event.Listener):
            def on_start(self, ev):
                disp = (ev.data or {}).get("dispatcher")
                if disp is not None and _ours(disp):
                    counter.seen()

            def on_end(self, ev):
                pass

        self.count = 0
        self._lock = threading.Lock()
        self._on_first = on_first
        self.listener = Listener()

    def seen(self):
        with self._lock:
            self.count += 1
            first = self.count == 1
        if first and self._on_first is not None:
            self._on_first()


@contextlib.contextmanager
def compile_notice(*, quiet=False, stream=None):
    """Within this context, say once on ``stream`` (stderr) when a kernel compiles.

    Yields the counter; ``.count`` is the number of kernel compilations seen.
    Nothing is printed when every kernel comes from the cache, or with
    ``quiet=True``.

    Examples
    --------
    >>> import granularsap
    >>> with compile_notice(quiet=True) as counter:
    ...     _ = granularsap.neighbor_pairs([[0.0, 0, 0], [1.0, 0, 0]], 1.5)
    >>> counter.count >= 0
    True
    """
    from numba.core import event

    def say():
        if not quiet:
            print(NOTICE, file=stream or sys.stderr, flush=True)

    counter = _CompileCounter(on_first=say)
    with event.install_listener("numba:compile", counter.listener):
        yield counter


def kernel_signatures():
    """Every compiled (or cache-loaded) signature of granularsap's kernels in this process.

    A set of ``(module.qualname, signature)``; what a workload adds to it is what
    it needed beyond what ran before (for tests of :func:`warmup`).

    Examples
    --------
    >>> import granularsap
    >>> _ = granularsap.neighbor_pairs([[0.0, 0, 0], [1.0, 0, 0]], 1.5)
    >>> any(name.startswith("granularsap.kernels.") for name, _ in kernel_signatures())
    True
    """
    import types

    from numba.core.dispatcher import Dispatcher

    found = set()

    def visit(v, depth=0):
        inner = getattr(type(v), "__slots__", None) and getattr(v, "_dispatcher", None)
        if isinstance(inner, Dispatcher):  # a parallel kernel's wrapper (_numba.pjit)
            v = inner
        if isinstance(v, Dispatcher):
            if _ours(v):
                name = f"{v.py_func.__module__}.{v.py_func.__qualname__}"
                found.update((name, str(sig)) for sig in v.signatures)
        elif isinstance(v, types.SimpleNamespace) and depth == 0:
            for w in vars(v).values():
                visit(w, 1)

    for name, mod in list(sys.modules.items()):
        if mod is not None and name.split(".")[0] in ("granularsap", "lammps_bridge"):
            for v in list(vars(mod).values()):
                visit(v)
    return found


def _inputs(seed=0, n=64):
    """Particles at one density (64 in a cell of side 4), radii, clumps of two, and the
    cells: none, orthorhombic, triclinic and partly periodic."""
    import numpy as np

    rng = np.random.default_rng(seed)
    length = 4.0 * (n / 64) ** (1 / 3)
    pos = rng.uniform(0.0, length, (n, 3))
    radii = rng.uniform(0.1, 0.3, n)
    clumps = np.repeat(np.arange(n // 2, dtype=np.int64), 2)
    boxes = [None, [length, length, length, 90.0, 90.0, 90.0],
             [length, length, length, 80.0, 95.0, 85.0],
             np.diag([length, length, 1000.0])]
    return pos, radii, clumps, boxes


def _threads():
    """(threads, particles): one thread on a tiny frame runs the serial kernels; two
    threads the parallel ones, which only frames with several chunks of work take (and
    the drop-ins and identity only from some 65,536 pairs on), hence 6,000 particles."""
    import numba

    return ((1, 64), (2, 6000)) if numba.config.NUMBA_NUM_THREADS >= 2 else ((1, 64),)


def _paths():
    return ("columns", "sweep")


def warm_contacts(modes=("spheres", "cutoff", "clumps")):
    """Compile what ``granularsap contacts`` runs per frame in the given modes.

    The ``contacts`` group of :func:`warmup`, for some modes only (what
    ``granularsap contacts --workers N`` compiles before starting its workers):
    its searches with and without distances, on both candidate paths, serial and
    parallel, open, periodic, triclinic and partly periodic, which the one-shot
    functions share.

    Parameters
    ----------
    modes : sequence of {"spheres", "cutoff", "clumps"}

    Examples
    --------
    >>> warm_contacts(modes=("cutoff",))
    """
    import numpy as np

    import granularsap

    pbcs = [None, None, None, (True, True, False)]
    for nt, n in _threads():
        pos, radii, clumps, boxes = _inputs(n=n)
        half = 0.5 * boxes[1][0]
        for path in _paths():
            for box, pbc in zip(boxes, pbcs, strict=True):
                for q in ("P", "Pd"):
                    if "cutoff" in modes:
                        granularsap.NeighborSearch(0.6, quantities=q, n_threads=nt,
                                                   path=path).update(pos, box, pbc=pbc)
                    if "spheres" in modes:
                        granularsap.ContactSearch(skin=0.05, quantities=q, n_threads=nt,
                                                  path=path).update(pos, radii, box, pbc=pbc)
                if "clumps" in modes:
                    granularsap.ContactSearch(skin=0.05, quantities="P", n_threads=nt,
                                              path=path).update(pos, radii, box, pbc=pbc,
                                                                clump_ids=clumps)
            # a range of exactly half the cell (two images of a pair tie: one is kept)
            granularsap.NeighborSearch(half if n < 1000 else 2.0, quantities="Pd",
                                       n_threads=nt, path=path).update(pos, boxes[1])
    from .io.hdf5 import pair_difference

    a = np.array([[1, 2], [3, 4]], np.int64)
    pair_difference(a, a[:1])


def _warm_search():
    """The stateful searches beyond the one-shot answers: a Verlet list kept and
    rebuilt, every output quantity, the CSR layout, every periodic image, contacts
    followed across calls."""
    import numpy as np

    import granularsap

    from ._memory import pair_lower_bound

    rng = np.random.default_rng(1)
    # the memory check's count of particles per cell, which only frames whose pairs
    # might not fit in memory take
    pair_lower_bound(rng.uniform(0, 1, (100, 3)), np.eye(3), np.ones(3, bool), 0.3)
    for nt, n in _threads():
        pos, radii, clumps, boxes = _inputs(n=n)
        for path in _paths():
            for box in boxes:
                for margin in (0.0, 0.2):
                    searches = [
                        (granularsap.NeighborSearch(0.6, rebuild_margin=margin,
                                                    quantities="PdDS", n_threads=nt,
                                                    path=path), False),
                        (granularsap.ContactSearch(skin=0.05, rebuild_margin=margin,
                                                   quantities="ijdDS", n_threads=nt,
                                                   path=path), True),
                        (granularsap.NeighborSearch(0.6, rebuild_margin=margin, layout="csr",
                                                    quantities="Pd", include_cutoff=False,
                                                    n_threads=nt, path=path), False),
                    ]
                    for search, spheres in searches:
                        x = pos.copy()
                        # first frame, a small move (the list is kept), a large one
                        for step in (0.0, 0.01, 0.5):
                            x = x + rng.normal(0.0, step, x.shape) if step else x
                            if spheres:
                                search.update(x, radii, box, clump_ids=clumps)
                            else:
                                search.update(x, box)
        for box in boxes[1:3]:
            for q in ("ijdDS", "PdD"):
                granularsap.NeighborSearch(2.5, periodic_images="all", quantities=q,
                                           n_threads=nt).update(pos, box)
                granularsap.ContactSearch(skin=0.3, periodic_images="all", quantities=q,
                                          n_threads=nt).update(pos, radii, box)
        _warm_identity(pos, radii, clumps, boxes, nt, rng)
        _warm_queries(pos, radii, nt)
        _warm_contact_list(pos, radii, boxes, nt, rng)


def _warm_contact_list(pos, radii, boxes, nt, rng):
    """ContactList: kept and rebuilt, its separations serial and (from 32,768 listed
    pairs on) parallel."""
    import numpy as np

    import granularsap

    big = rng.uniform(0.0, 10.0, (20_000, 3))
    for x, r, box in [(pos, radii, b) for b in boxes] + [(big, 0.15, [10, 10, 10, 90, 90, 90])]:
        cl = granularsap.ContactList(rebuild_margin=0.2, n_threads=nt)
        ids = np.arange(len(x)) + 1
        for step in (0.0, 0.01, 0.5):
            y = x + rng.normal(0.0, step, x.shape) if step else x
            cl.update(y, r, box, ids=ids)
            cl.separations(y)


def _warm_identity(pos, radii, clumps, boxes, nt, rng):
    """Contacts followed across calls (identity=True): ids dense and sparse, or rows;
    minimum image and every image; clump pairs; ContactIdentity's keys."""
    import numpy as np

    import granularsap

    n = len(pos)
    dense = np.arange(n, dtype=np.int64) + 100
    sparse = rng.permutation(n).astype(np.int64) * 1_000_003 + 2**40
    for box in boxes:
        for path in _paths():
            for ids in (dense, sparse, None):
                s = granularsap.ContactSearch(skin=0.05, quantities="PdD", identity=True,
                                              n_threads=nt, path=path)
                h = hc = None
                for step in (0.0, 0.02):
                    x = pos + rng.normal(0.0, step, pos.shape) if step else pos
                    out = s.update(x, radii, box, ids=ids, clump_ids=clumps)
                    h = np.zeros(len(out[0])) if h is None else s.carry(h, fill=-1.0)
                    hc = (np.zeros(len(s.clump_pairs)) if hc is None
                          else s.carry(hc, clumps=True))
                nb = granularsap.NeighborSearch(0.6, identity=True, n_threads=nt, path=path)
                for _ in range(2):
                    nb.update(pos, box, ids=ids)
        if box is not None:
            every = granularsap.NeighborSearch(2.5, periodic_images="all", quantities="PdS",
                                               identity=True, n_threads=nt)
            for _ in range(2):
                every.update(pos, box, ids=dense)
    # identity's parallel kernels run from 50,000 pairs on (whatever the frame's size);
    # the particles moved on the second call, so that pairs leave the cursor and
    # the hash table of pass 2 runs too
    big = rng.uniform(0.0, 10.0, (20_000, 3))
    big_ids = (np.arange(len(big), dtype=np.int64), rng.permutation(len(big)) * 1_000_003)
    moved = big + rng.normal(0.0, 0.05, big.shape)
    for ids in big_ids:
        s = granularsap.ContactSearch(skin=0.3, identity=True, n_threads=nt)
        nb = granularsap.NeighborSearch(0.6, periodic_images="all", identity=True,
                                        n_threads=nt)
        for x in (big, moved):
            s.update(x, 0.15, [10, 10, 10, 90, 90, 90], ids=ids,
                     clump_ids=np.arange(len(big)) // 2)
            nb.update(x, [10, 10, 10, 90, 90, 90], ids=ids)
    from .identity import ContactIdentity

    for rows in (n, 60_000):
        keys = np.stack([np.arange(rows), np.arange(rows) % 3, np.arange(rows) % 7], axis=1)
        track = ContactIdentity(n_threads=nt)
        track.update(keys)
        track.update(keys[::2])


def _warm_boxes():
    import granularsap

    for nt, n in _threads():
        # boxes take their parallel kernels from 32,768 boxes on
        pos, radii, _, _ = _inputs(n=n if n < 1000 else 40_000)
        lower, upper = pos - radii[:, None], pos + radii[:, None]
        granularsap.box_overlaps(lower, upper, n_threads=nt)
        for path in ("sequential", "parallel", "columns"):
            sap = granularsap.SweepAndPrune(path=path, n_threads=nt)
            sap.update(lower, upper)
            sap.update(lower + 0.01, upper + 0.01)  # temporal coherence: the kept order


def _slab(n, seed=1):
    """``n`` particles at the density of :func:`_inputs` in a cell 2.5 wide along x: a
    cutoff of 2 is beyond half of it (every image) with some 30 pairs a particle, not
    the millions a cutoff beyond half of a cube of the same particles would give."""
    import numpy as np

    width = 2.5
    length = float(np.sqrt(n / width))
    pos = np.random.default_rng(seed).uniform(0.0, (width, length, length), (n, 3))
    return pos, width, length


def _warm_queries(pos, radii, nt):
    """The engine's cross-set queries (``NeighborSearch.query``,
    ``ContactSearch.query``), which the drop-ins' cross searches and ASE's
    cutoffs many times the cell run: serial passes for a few query points,
    parallel ones for many (with two threads), in every kind of cell."""
    import numpy as np

    import granularsap

    side = 4.0 * (len(pos) / 64) ** (1 / 3)
    cells = (None, np.diag([side] * 3), granularsap.Cell.from_dimensions(
        [side, side, side, 80, 95, 85]), granularsap.Cell(np.diag([side] * 3),
                                                          pbc=(True, True, False)))
    for box in cells:
        for ref in (pos[:10], pos):
            granularsap.NeighborSearch(0.6, quantities="PdDS", n_threads=nt).query(
                ref, pos, box)
            granularsap.ContactSearch(skin=0.05, quantities="ijS", periodic_images="all",
                                      n_threads=nt).query(ref, radii[:len(ref)], pos, radii,
                                                          box)


def _warm_dropins():
    import numpy as np

    for nt, n in _threads():
        pos, radii, _, _ = _inputs(n=n)
        side = 4.0 * (n / 64) ** (1 / 3)
        cube = (side, side, side)
        if n <= 64:  # cutoffs below half the cell and beyond it
            frames = [(pos, cube, (1.5, 0.75 * side))]
        else:  # many pairs below half the cube; beyond half of a thin cell
            slab, width, length = _slab(n)
            frames = [(pos, cube, (1.5,)), (slab, (width, length, length), (2.0,))]
        try:
            from . import mda
        except ImportError:  # pragma: no cover - numpy-only install
            mda = None
        if mda is not None:
            for x, lengths, cuts in frames:
                x32 = x.astype(np.float32)
                for box in (None, np.array([*lengths, 90, 90, 90], np.float32),
                            np.array([*lengths, 80, 95, 85], np.float32)):
                    for cut in cuts:
                        for dist in (True, False):
                            mda.self_capped_distance(x32, cut, box=box,
                                                     return_distances=dist, n_threads=nt)
                            mda.capped_distance(x32[:20], x32, cut, min_cutoff=0.1, box=box,
                                                return_distances=dist, n_threads=nt)
            x32 = pos.astype(np.float32)
            ns = mda.FastNS(0.8, x32, np.array([*cube, 90, 90, 90], np.float32),
                            n_threads=nt)
            ns.self_search()
            ns.search(x32[:10])
            ns.search(x32)  # many query points: the parallel passes of a query
        _warm_queries(pos, radii, nt)
        try:
            from . import ase as gase
            from .ase.neighborlist import NeighborList
        except ImportError:  # pragma: no cover
            continue
        numbers = np.arange(len(pos)) % 3 + 1
        for pbc in ((True, True, True), (True, True, False), (False, False, False)):
            for x, lengths, cuts in frames:
                for cut in cuts:
                    gase.primitive_neighbor_list("ijdDS", pbc, np.diag(lengths), x, cut,
                                                 numbers=numbers, n_threads=nt)
            gase.primitive_neighbor_list("ijdDS", pbc, np.diag(cube), pos,
                                         {(1, 1): 0.5, (1, 2): 0.7}, numbers=numbers,
                                         n_threads=nt)
        try:
            import ase
        except ImportError:  # pragma: no cover
            continue
        atoms = ase.Atoms(numbers=numbers, positions=pos, cell=np.diag(cube), pbc=True)
        nl = NeighborList(radii, n_threads=nt)
        nl.update(atoms)
        atoms.positions += 0.01
        nl.update(atoms)
        nl.get_neighbors(0)


_WARM = {"contacts": warm_contacts, "search": _warm_search, "boxes": _warm_boxes,
         "dropins": _warm_dropins}


def resolve(names):
    """Group names for ``names`` (groups or older function names), in :data:`GROUPS` order."""
    chosen = set()
    for name in names:
        group = ALIASES.get(name, name)
        if group not in GROUPS:
            older = "; ".join(f"{', '.join(a for a in ALIASES if ALIASES[a] == g)} for {g}"
                              for g in GROUPS if g in ALIASES.values())
            raise ValueError(f"unknown group {name!r}; choose from {', '.join(GROUPS)} "
                             f"(or the older names {older})")
        chosen.add(group)
    return [g for g in GROUPS if g in chosen]


def warmup(groups=tuple(GROUPS), *, progress=None):
    """Compile (or load from the cache) the kernels of the given groups.

    Parameters
    ----------
    groups : sequence of str
        Names from :data:`GROUPS` (or the older function names of
        :data:`ALIASES`, which stand for their group).
    progress : callable, optional
        Called after each group with ``(group, seconds, compiled)``.

    Returns
    -------
    dict
        ``seconds`` spent, ``compiled`` (the number of kernel compilations, 0
        when everything came from the cache), ``groups`` (those run) and
        ``per_group`` (``{group: (seconds, compiled)}``).

    Examples
    --------
    >>> out = warmup(["boxes"])
    >>> out["groups"], out["compiled"] >= 0
    (['boxes'], True)
    """
    groups = resolve(groups)
    t0 = time.perf_counter()
    per_group = {}
    with compile_notice(quiet=True) as counter:
        for group in groups:
            t1, c1 = time.perf_counter(), counter.count
            _WARM[group]()
            per_group[group] = (time.perf_counter() - t1, counter.count - c1)
            if progress is not None:
                progress(group, *per_group[group])
    return {"seconds": time.perf_counter() - t0, "compiled": counter.count,
            "groups": groups, "per_group": per_group}


def cache_location():
    """Where numba keeps granularsap's compiled kernels (for messages)."""
    import os

    import numba

    from . import _numba

    if not _numba.CACHE:
        return "nowhere: the cache is off (GRANULARSAP_NO_CACHE)"
    if numba.config.CACHE_DIR:
        return os.fspath(numba.config.CACHE_DIR)
    here = os.path.dirname(os.path.abspath(__file__))
    return (f"__pycache__ folders under {here} (or numba's user cache if those are not "
            "writable); set NUMBA_CACHE_DIR to choose")
