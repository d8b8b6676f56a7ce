"""``Contacts``: granularsap contact search as an MDAnalysis analysis.

Re-exported as :class:`granularsap.mda.Contacts`.  The class declares itself
parallelizable (MDAnalysis >= 2.8 split-apply-combine), so
``run(backend="multiprocessing" | "dask", n_workers=N)`` splits the frames
between worker processes and merges per-frame results in frame order.

Changing particle counts: an ``UpdatingAtomGroup`` (``select_atoms(...,
updating=True)``) may hold a different number of atoms, 0 included, in every
frame, and ``Contacts`` follows it.  MDAnalysis itself cannot read a trajectory
file whose atom count changes (a LAMMPS dump of a pour, or of atoms lost
through an open boundary): its reader stops with "Number of atoms in
trajectory changed", and ``run`` then raises a ``ValueError`` that says so and
points at :func:`granularsap.io.iter_frames` and ``granularsap contacts``,
which read such dumps.
"""

from __future__ import annotations

import numpy as np

try:
    from MDAnalysis.analysis.backends import BackendMultiprocessing
    from MDAnalysis.analysis.base import AnalysisBase
    from MDAnalysis.analysis.results import ResultsGroup
except ImportError as exc:  # pragma: no cover - MDAnalysis is an optional dependency
    raise ImportError("granularsap.mda.analysis needs MDAnalysis: "
                      "pip install 'granularsap[mda]'") from exc

__all__ = ["Contacts"]


class _SpawnMultiprocessing(BackendMultiprocessing):
    """MDAnalysis's multiprocessing backend with "spawn" worker processes.

    The built-in backend forks; a process whose numba OpenMP/TBB thread pool
    is already running (any earlier granularsap call) must not fork (GNU
    OpenMP aborts the child), so workers are spawned instead.  As with any
    spawn-based pool, a script must guard its entry point with
    ``if __name__ == "__main__":``.
    """

    def apply(self, func, computations):
        import multiprocessing

        # close and join (not terminate, which `with Pool()` does): a terminated pool's
        # worker processes still hold its semaphores, and the resource tracker reports
        # them at exit as leaked
        pool = multiprocessing.get_context("spawn").Pool(processes=self.n_workers)
        try:
            out = pool.map(func, computations)
            pool.close()
        except BaseException:
            pool.terminate()
            raise
        finally:
            pool.join()
        return out


def _as_pbc(pbc):
    """``pbc`` of :class:`Contacts` as three bools: one bool for every axis, or one
    per axis (the rule of ``granularsap.Cell``'s ``pbc``).

    Examples
    --------
    >>> _as_pbc(True), _as_pbc([True, True, False])
    ((True, True, True), (True, True, False))
    """
    from ..cell import as_pbc

    return tuple(bool(f) for f in as_pbc(pbc))


class Contacts(AnalysisBase):
    """Contacts (or neighbour pairs) of an AtomGroup in every frame.

    Parameters
    ----------
    atomgroup : MDAnalysis.core.groups.AtomGroup
        Atoms to search (pairs are between atoms of this group only).
    cutoff : float, optional
        Neighbour pairs with ``d <= cutoff`` (:func:`granularsap.neighbor_pairs`).
    radii : float or (n,) array_like of float or "topology", optional
        Sphere contacts with ``d <= r_i + r_j + skin``
        (:func:`granularsap.sphere_contacts`); ``"topology"`` takes
        ``atomgroup.radii`` (in every frame, so it follows an
        ``UpdatingAtomGroup``).  Exactly one of ``cutoff`` and ``radii``.
    skin : float, optional
        Added to ``r_i + r_j`` (sphere contacts only).
    pbc : bool or three bools, optional
        Use the periodic box of each frame (default True; ignored when a
        frame has no box); three flags make it periodic along those axes only
        (``[True, True, False]``: a slab, periodic along x and y, as
        granularsap's ``pbc`` everywhere).
    return_distances : bool, optional
        Also keep each pair's distance.
    n_threads : int, optional
        Numba threads per frame.
    **kwargs
        Passed to :class:`MDAnalysis.analysis.base.AnalysisBase` (``verbose``).

    Attributes
    ----------
    results.pairs : list of (k, 2) ndarray of int64
        Per frame, pairs of indices into ``atomgroup`` as it is in that frame
        (``i < j``, rows sorted).
    results.distances : list of (k,) ndarray of float64
        Per frame, only with ``return_distances=True``.
    results.n_contacts : (n_frames,) ndarray of int64
    results.n_atoms : (n_frames,) ndarray of int64
        Atoms in ``atomgroup`` per frame (changes for an ``UpdatingAtomGroup``).
    results.coordination : (n_frames,) ndarray of float64
        Mean coordination number ``2 k / n`` per frame (0 for an empty frame).

    Examples
    --------
    >>> from granularsap.mda import Contacts                  # doctest: +SKIP
    >>> c = Contacts(u.atoms, cutoff=3.5).run(backend="multiprocessing", n_workers=2)
    >>> c.results.n_contacts                                  # doctest: +SKIP
    """

    _analysis_algorithm_is_parallelizable = True

    @classmethod
    def get_supported_backends(cls):
        return ("serial", "multiprocessing", "dask")

    def __init__(self, atomgroup, cutoff=None, radii=None, *, skin=0.0, pbc=True,
                 return_distances=False, n_threads=None, **kwargs):
        if not hasattr(atomgroup, "universe") or not hasattr(atomgroup, "positions"):
            raise TypeError(f"atomgroup must be an MDAnalysis AtomGroup, got "
                            f"{type(atomgroup).__name__}")
        super().__init__(atomgroup.universe.trajectory, **kwargs)
        self._radii_source = None  # "topology", a scalar, or None: the array given
        if (cutoff is None) == (radii is None):
            raise ValueError("give exactly one of cutoff and radii")
        n = len(atomgroup)
        if cutoff is not None:
            cutoff = float(cutoff)
            if not np.isfinite(cutoff) or cutoff < 0:
                raise ValueError(f"cutoff must be a finite non-negative number, got {cutoff}")
            if skin:
                raise ValueError("skin applies to sphere contacts (radii) only")
        else:
            if isinstance(radii, str):
                if radii != "topology":
                    raise ValueError(f"radii must be numbers or 'topology', got {radii!r}")
                if not hasattr(atomgroup, "radii"):
                    raise ValueError("radii='topology' but the topology has no radii")
                radii = np.asarray(atomgroup.radii, dtype=np.float64)
                self._radii_source = "topology"
            radii = np.asarray(radii, dtype=np.float64)
            if radii.ndim == 0:
                self._radii_source = self._radii_source or float(radii)
                radii = np.full(n, float(radii))
            if radii.shape != (n,):
                raise ValueError(f"radii must be a scalar or have shape ({n},), got "
                                 f"{radii.shape}")
            if not np.all(np.isfinite(radii)) or (n and radii.min() < 0):
                raise ValueError("radii must be finite and non-negative")
        if not np.isfinite(skin) or skin < 0:
            raise ValueError(f"skin must be a finite non-negative number, got {skin}")
        self.atomgroup = atomgroup
        self.cutoff = cutoff
        self.radii = radii
        self.skin = float(skin)
        self.pbc = _as_pbc(pbc)
        self.return_distances = bool(return_distances)
        self.n_threads = n_threads

    def _configure_backend(self, backend, n_workers, unsupported_backend=False):
        executor = super()._configure_backend(backend, n_workers,
                                              unsupported_backend=unsupported_backend)
        if type(executor) is BackendMultiprocessing:
            executor = _SpawnMultiprocessing(n_workers=executor.n_workers)
        return executor

    def run(self, *args, **kwargs):
        """Run the analysis (MDAnalysis ``AnalysisBase.run``, same arguments).

        Raises
        ------
        ValueError
            If MDAnalysis's reader meets a change of the atom count in the
            trajectory file, which MDAnalysis does not support.
        """
        try:
            return super().run(*args, **kwargs)
        except ValueError as exc:
            text = str(exc)
            if "atoms" not in text.lower() or "changed" not in text.lower():
                raise
            name = getattr(self._trajectory, "filename", None) or "the trajectory"
            raise ValueError(
                f"{name}: MDAnalysis cannot read a trajectory whose atom count changes "
                f"({text}); read it with granularsap.io.iter_frames (LAMMPS dumps of "
                "any size per frame, 0 included) and call granularsap.sphere_contacts or "
                "neighbor_pairs per frame, or run `granularsap contacts` on the file") from None

    def _prepare(self):
        self.results.pairs = []
        self.results.distances = []
        self.results.n_contacts = []
        self.results.n_atoms = []

    def _frame_radii(self, n):
        if self._radii_source == "topology":
            return np.asarray(self.atomgroup.radii, dtype=np.float64)
        if self._radii_source is not None:
            return np.full(n, self._radii_source, dtype=np.float64)
        if len(self.radii) != n:
            raise ValueError(
                f"radii has {len(self.radii)} values but atomgroup has {n} atoms in frame "
                f"{self._ts.frame} (an UpdatingAtomGroup changes size); give one radius "
                "for all or radii='topology'")
        return self.radii

    def _single_frame(self):
        import granularsap

        pos = self.atomgroup.positions.astype(np.float64).reshape(-1, 3)
        box = self._ts.dimensions if any(self.pbc) else None
        if box is not None and not np.all(np.asarray(box[:3]) > 0):
            box = None
        pbc = self.pbc if box is not None else None
        if self.cutoff is not None:
            out = granularsap.neighbor_pairs(pos, self.cutoff, box=box, pbc=pbc,
                                             n_threads=self.n_threads,
                                             return_distances=self.return_distances)
        else:
            out = granularsap.sphere_contacts(pos, self._frame_radii(len(pos)),
                                              skin=self.skin, box=box, pbc=pbc,
                                              n_threads=self.n_threads,
                                              return_distances=self.return_distances)
        pairs, dist = out if self.return_distances else (out, None)
        pairs = np.sort(np.asarray(pairs, dtype=np.int64).reshape(-1, 2), axis=1)
        order = np.lexsort((pairs[:, 1], pairs[:, 0]))
        self.results.pairs.append(pairs[order])
        if dist is not None:
            self.results.distances.append(np.asarray(dist, dtype=np.float64)[order])
        self.results.n_contacts.append(len(pairs))
        self.results.n_atoms.append(len(pos))

    def _get_aggregator(self):
        return ResultsGroup(lookup={
            "pairs": ResultsGroup.flatten_sequence,
            "distances": ResultsGroup.flatten_sequence,
            "n_contacts": ResultsGroup.flatten_sequence,
            "n_atoms": ResultsGroup.flatten_sequence,
        })

    def _conclude(self):
        self.results.n_contacts = np.asarray(self.results.n_contacts, dtype=np.int64)
        self.results.n_atoms = np.asarray(self.results.n_atoms, dtype=np.int64)
        n = self.results.n_atoms
        self.results.coordination = np.divide(2.0 * self.results.n_contacts, n,
                                              out=np.zeros(len(n)), where=n > 0)
        if not self.return_distances:
            self.results.distances = None
