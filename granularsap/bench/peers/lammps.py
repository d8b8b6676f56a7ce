"""LAMMPS as a peer: its neighbour list through the Python module, and its own
neighbour build and ``run 0`` timed by LAMMPS's timers."""

from __future__ import annotations

import importlib
import importlib.metadata
import time

import numpy as np

from .base import CutoffPeer, Peer, cell_matrix, exact_filter, oriented


class LammpsPeer(CutoffPeer):
    """LAMMPS's own neighbour build, through lammps_bridge.neighbor_pairs."""

    name = "lammps"
    module = "lammps_bridge"
    dist = "lammps"
    description = "LAMMPS neighbour list via lammps_bridge.neighbor_pairs"

    def missing(self):
        why = super().missing()
        if why:
            return why
        import lammps_bridge

        if not hasattr(lammps_bridge, "neighbor_pairs"):
            return "lammps_bridge.neighbor_pairs is not part of this build"
        try:
            importlib.import_module("lammps")
        except Exception as exc:
            return f"{type(exc).__name__}: {exc}"
        return None

    def search(self, positions, radius, box):
        import lammps_bridge

        pairs = lammps_bridge.neighbor_pairs(positions, radius, box=box)
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        return oriented(pairs[:, 0], pairs[:, 1]), None


#: LAMMPS's neighbour entries carry "special" bond bits above this mask
_NEIGHMASK = 0x1FFFFFFF


#: relative enlargement of LAMMPS's cutoff before the exact test (LAMMPS keeps rsq <= cutneighsq)
_LAMMPS_WIDEN = 1e-8


#: steps of the self-timed run of ``lammps-rebuild`` (one neighbour build per step)
REBUILD_STEPS = 10


_LAMMPS_PROBE = {}


def _lammps_probe():
    """``{"missing": reason or None, "omp": has the OPENMP package}``, probed once."""
    if not _LAMMPS_PROBE:
        try:
            import lammps_bridge

            lmp = lammps_bridge.new_lammps()
        except Exception as exc:  # ImportError, or a library that does not load
            _LAMMPS_PROBE.update(missing=f"{type(exc).__name__}: {exc}", omp=False)
        else:
            _LAMMPS_PROBE.update(missing=None, omp=bool(lmp.has_package("OPENMP")))
            lmp.close()
    return _LAMMPS_PROBE


def _omp_words():
    if _lammps_probe()["omp"]:
        return "OPENMP package (package omp T, suffix omp)"
    return "serial: this LAMMPS build has no OPENMP package"


def _f(x):
    """A float as LAMMPS reads it back exactly."""
    return repr(float(x))


def log_sections(path):
    """``{section: avg seconds}`` of the last timer breakdown in a LAMMPS log file."""
    with open(path) as fh:
        lines = fh.read().splitlines()
    head = max((k for k, line in enumerate(lines) if line.startswith("Section |")), default=None)
    if head is None:
        raise RuntimeError(f"LAMMPS wrote no timer breakdown to {path}")
    out = {}
    for line in lines[head + 2:]:
        cols = [c.strip() for c in line.split("|")]
        if len(cols) < 3 or not cols[0]:
            break
        out[cols[0]] = float(cols[2])
    return out


class _LammpsSystem:
    """One LAMMPS instance holding a workload's particles, set up as its users do.

    ``units lj``; a box equal to the workload's cell (orthorhombic ``block`` or
    restricted triclinic ``prism``, the form of MDAnalysis's cell vectors) or,
    for open boundaries, a fixed (``f``) box around the particles; ``pair_style
    zero`` at the cutoff for points, ``atom_style sphere`` with per-atom
    diameters and ``pair_style gran/hooke`` for contacts (LAMMPS's size-based
    list, ``rsq <= (r_i + r_j + skin)^2``); ``neighbor 0.0 bin`` (contacts: a
    skin of 1e-8 of the largest contact distance) and ``neigh_modify every 1
    delay 0 check no``; ``package omp T`` and ``suffix omp`` when the build has
    the OPENMP package.  The cutoff is widened by a relative 1e-8 and the list
    is filtered with the workload's exact test, as ``lammps_bridge`` does.
    """

    def __init__(self, workload, n_threads):
        import shutil
        import tempfile
        import weakref

        import lammps_bridge

        self.wl = workload
        folder = tempfile.mkdtemp(prefix="granularsap-bench-lammps-")
        self._cleanup = weakref.finalize(self, shutil.rmtree, folder, ignore_errors=True)
        self.log = f"{folder}/log.lammps"
        self.lmp = lammps_bridge.new_lammps(cmdargs=["-log", self.log, "-screen", "none"],
                                            quiet=False)
        self.omp = bool(self.lmp.has_package("OPENMP"))
        self.sphere = workload.kind == "contacts"
        self.frame = None
        try:
            self._build(n_threads)
        except Exception:
            self.close()
            raise

    def _build(self, n_threads):
        wl, lmp = self.wl, self.lmp
        reach = wl.search_radius()
        cmds = [f"package omp {int(n_threads)}", "suffix omp"] if self.omp else []
        cmds += ["units lj", "atom_style sphere" if self.sphere else "atom_style atomic",
                 "atom_modify map array"]
        if wl.box is None:
            pos = wl.frames[0]
            lo = (pos.min(axis=0) if wl.n else np.zeros(3)) - reach - 1.0
            hi = (pos.max(axis=0) if wl.n else np.zeros(3)) + reach + 1.0
            self.h = None
            cmds += ["boundary f f f", "region box block " + " ".join(
                f"{_f(a)} {_f(b)}" for a, b in zip(lo, hi, strict=True)) + " units box"]
        else:
            h = self.h = cell_matrix(wl.box)
            if abs(h[1, 0]) + abs(h[2, 0]) + abs(h[2, 1]) > 0:
                region = (f"region box prism 0 {_f(h[0, 0])} 0 {_f(h[1, 1])} 0 {_f(h[2, 2])} "
                          f"{_f(h[1, 0])} {_f(h[2, 0])} {_f(h[2, 1])} units box")
            else:
                region = (f"region box block 0 {_f(h[0, 0])} 0 {_f(h[1, 1])} 0 {_f(h[2, 2])} "
                          "units box")
            cmds += ["boundary p p p", region]
        cmds += ["create_box 1 box"]
        if self.sphere:
            skin = _LAMMPS_WIDEN * max(reach, 1e-300)
            cmds += ["comm_modify vel yes", "pair_style gran/hooke 1.0 0.0 0.0 0.0 0.0 0",
                     "pair_coeff * *", f"neighbor {_f(skin)} bin"]
            self.style = "gran/hooke"
        else:
            cmds += ["mass 1 1.0", f"pair_style zero {_f(wl.cutoff * (1.0 + _LAMMPS_WIDEN))}",
                     "pair_coeff * *", "neighbor 0.0 bin"]
            self.style = "zero"
        cmds += ["neigh_modify every 1 delay 0 check no"]
        for c in cmds:
            lmp.command(c)
        n = wl.n
        x = self._wrapped(0)
        created = lmp.create_atoms(n, list(range(1, n + 1)), [1] * n, x.ravel().tolist())
        if created != n:
            raise RuntimeError(f"LAMMPS created {created} of {n} atoms")
        if self.sphere:
            tag = self._tags()
            lmp.numpy.extract_atom("radius", nelem=n)[:n] = wl.radii[tag]
            lmp.numpy.extract_atom("rmass", nelem=n)[:n] = 1.0
        self.frame = 0

    def _wrapped(self, frame):
        """Positions of ``frame`` wrapped into the cell (unchanged inside it)."""
        pos = self.wl.frames[frame]
        if self.h is None:
            return pos
        if self.wl.orthorhombic:
            lengths = np.diag(self.h)
            return pos - lengths * np.floor(pos / lengths)
        frac = pos @ np.linalg.inv(self.h)
        return (frac - np.floor(frac)) @ self.h

    def _tags(self):
        n = self.lmp.extract_setting("nlocal")
        return np.asarray(self.lmp.numpy.extract_atom("id", nelem=n)[:n], dtype=np.int64) - 1

    def scatter(self, frame, *, force=False):
        """Write ``frame``'s positions into LAMMPS's own (possibly re-sorted) atom order."""
        if frame == self.frame and not force:
            return
        n = self.lmp.extract_setting("nlocal")
        x = self.lmp.numpy.extract_atom("x", nelem=n)
        x[:n] = self._wrapped(frame)[self._tags()]
        self.frame = frame

    def run(self, command, *, timers=True):
        """Run ``command``; with ``timers``, in a fresh log, returning ``{section: seconds}``
        of LAMMPS's timer breakdown."""
        if not timers:
            self.lmp.command(command)
            return {}
        self.lmp.command(f"log {self.log}")
        self.lmp.command(command)
        self.lmp.command("log none")
        return log_sections(self.log)

    def pairs(self):
        """(pairs with i < j filtered exactly, entries of LAMMPS's list) of the current frame."""
        lmp = self.lmp
        nlocal = lmp.extract_setting("nlocal")
        nall = nlocal + lmp.extract_setting("nghost")
        tag = np.asarray(lmp.numpy.extract_atom("id", nelem=nall)[:nall], dtype=np.int64) - 1
        style = self.style
        if self.omp and lmp.has_style("pair", style + "/omp"):
            style += "/omp"  # what ``suffix omp`` made of it
        idx = lmp.find_pair_neighlist(style, reqid=0)
        if idx < 0:
            raise RuntimeError(f"LAMMPS has no neighbour list for pair style {self.style}")
        nl = lmp.numpy.get_neighlist(idx)
        ii, jj = [np.empty(0, np.int64)], [np.empty(0, np.int64)]
        for k in range(len(nl)):
            i, neigh = nl.get(k)
            ii.append(np.full(len(neigh), i, dtype=np.int64))
            jj.append(np.asarray(neigh, dtype=np.int64) & _NEIGHMASK)
        ti, tj = tag[np.concatenate(ii)], tag[np.concatenate(jj)]
        entries = len(ti)
        keep = ti != tj
        pairs = oriented(ti[keep], tj[keep])
        code = np.unique(pairs[:, 0] * max(self.wl.n, 1) + pairs[:, 1])
        pairs = np.stack([code // max(self.wl.n, 1), code % max(self.wl.n, 1)], axis=1)
        return exact_filter(self.wl, self.frame, pairs), entries

    def close(self):
        if getattr(self, "lmp", None) is not None:
            self.lmp.close()
            self.lmp = None
        self._cleanup()


class _LammpsSelfTimed(Peer):
    """Shared set-up of the LAMMPS peers that report LAMMPS's own time."""

    module = "lammps"
    dist = "lammps"
    kinds = ("cutoff", "contacts")
    threaded = True

    def missing(self):
        return _lammps_probe()["missing"]

    def threads_used(self, n_threads):
        return n_threads if getattr(self, "omp", True) else 1

    def setup(self, workload, n_threads):
        super().setup(workload, n_threads)
        self.close()
        self.system = _LammpsSystem(workload, n_threads)
        self.omp = self.system.omp
        self.seconds = None
        self.stats = None
        self.cache = None

    def _pairs(self, frame):
        """The exact pairs of ``frame`` from LAMMPS's list (kept while the frame repeats)."""
        if self.cache is None or self.cache[0] != frame:
            pairs, entries = self.system.pairs()
            self.cache = (frame, pairs, entries)
        return self.cache[1], self.cache[2]

    def last_seconds(self):
        return self.seconds

    def last_stats(self):
        return self.stats

    def note(self):
        if not self.stats:
            return None
        where = f" on frame {self.cache[0]}" if len(self.workload.frames) > 1 else ""
        return f"LAMMPS list{where}: {self.stats['list_entries']} entries"

    def close(self):
        system = getattr(self, "system", None)
        if system is not None:
            system.close()
            self.system = None


class LammpsRebuild(_LammpsSelfTimed):
    """LAMMPS's own neighbour list rebuilt every step, timed by LAMMPS's timers.

    ``run 10`` with ``neigh_modify every 1 delay 0 check no`` rebuilds the list
    on every step; the figure is the ``Neigh`` plus ``Comm`` sections of
    LAMMPS's timer breakdown (binning, the list build, ghost atoms) divided by
    the 10 steps.  The pairs are read back from the list after the run
    (untimed) and filtered with the exact test.
    """

    name = "lammps-rebuild"

    @property
    def description(self):
        return (f"LAMMPS neighbor 0.0 bin, rebuilt every step: (Neigh + Comm) / {REBUILD_STEPS} "
                f"of its timers in run {REBUILD_STEPS}; {_omp_words()}")

    def run(self, frame):
        self.system.scatter(frame)
        t0 = time.perf_counter()
        sections = self.system.run(f"run {REBUILD_STEPS}")
        wall = time.perf_counter() - t0
        neigh, comm = sections.get("Neigh", 0.0), sections.get("Comm", 0.0)
        self.seconds = (neigh + comm) / REBUILD_STEPS
        pairs, entries = self._pairs(frame)
        self.stats = {"list_entries": int(entries), "pairs": len(pairs),
                      "seconds": {"neigh": neigh / REBUILD_STEPS, "comm": comm / REBUILD_STEPS,
                                  "run_wall": wall / REBUILD_STEPS},
                      "omp": self.omp}
        return pairs


class LammpsRun0(_LammpsSelfTimed):
    """One running LAMMPS instance answering each trajectory frame with ``run 0``.

    Per frame the new positions are written into LAMMPS's atom array (in its
    own order, through the numpy views) and ``run 0 post no`` builds the list;
    the time is measured around those two in Python, which is what a user
    post-processing a trajectory in LAMMPS pays.  Reading the list back into
    numpy is not timed.
    """

    name = "lammps-run0"
    stateful = True

    @property
    def description(self):
        return f"LAMMPS run 0 per frame on one instance: scatter positions + run 0; {_omp_words()}"

    def unsupported(self, workload):
        why = super().unsupported(workload)
        if why is None and len(workload.frames) < 2:
            return "run 0 per frame is for trajectories (lammps-rebuild times one frame)"
        return why

    def run(self, frame):
        t0 = time.perf_counter()
        self.system.scatter(frame, force=True)
        self.system.run("run 0 post no", timers=False)
        self.seconds = time.perf_counter() - t0
        self.cache = None
        pairs, entries = self._pairs(frame)
        self.stats = {"list_entries": int(entries), "pairs": len(pairs), "omp": self.omp}
        return pairs
