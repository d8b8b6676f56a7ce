"""``granularsap bench dem-loop``: a DEM time loop, granularsap against LAMMPS on one pour.

The pour is that of ``examples/dem_hertz_mindlin.py``: polydisperse spheres
(radii 0.5 to 1) falling from a jittered lattice in a square column with four
side walls onto a floor, Hertz-Mindlin contacts with tangential springs
(``pair_style granular hertz/material ... tangential mindlin``), gravity,
velocity Verlet with rotation, ``dt`` 5e-4, a Verlet margin (LAMMPS's
neighbour skin) of 0.2.

1. LAMMPS runs the pour from the column: ``pair_style granular`` with the
   example's coefficients, ``fix wall/gran granular`` for the floor
   (``zplane``) and the sides, ``neighbor 0.2 bin``, ``neigh_modify delay 0
   every 1 check yes``, ``package omp T`` / ``suffix omp`` when the build has
   OPENMP (the neighbour build is then threaded; ``pair granular`` has no
   threaded variant), LAMMPS's defaults otherwise (atom sort every 1000 steps).
   It first settles the pour for ``--settle`` steps (untimed), then runs
   ``--steps`` more in one ``run``, timed by its own timers: the ``Neigh``,
   ``Pair``, ``Modify`` and ``Comm`` sections of that run's breakdown, per step.
2. granularsap steps the example's ``Pour`` from the state LAMMPS had at the
   start of that timed run (positions, velocities, spins, by atom id) for the
   same number of steps, re-ordering the grains spatially every 1000 steps as
   LAMMPS does, and records each step's ``search_seconds``: the grain
   ``ContactSearch.update`` with ids, ``ContactSearch.carry`` of the springs,
   ``WallSearch.update`` (four planes and the floor as a triangle mesh) and
   ``WallSearch.carry``.  Min, median and mean per step; the contact law and
   the integration are not in the figure.

LAMMPS's ``Neigh`` is the neighbour-list builds only (it re-tests no pair on
the steps between builds: ``pair granular`` computes every listed pair's
distance in ``Pair``), and it keeps the contact history inside ``fix
NEIGH_HISTORY`` (counted in ``Modify``, with the walls and the integration).
The ratio printed is granularsap's mean search + history per step over
LAMMPS's ``Neigh`` per step, and over ``Neigh + Pair``; then the same for
granularsap's grain contacts alone (LAMMPS's ``fix wall/gran`` loops over the
atoms in ``Modify``, outside ``Neigh``).

The pour's definition lives in the example, which ships with a source
checkout (like ``data/``): the runner loads ``examples/dem_hertz_mindlin.py``
from the checkout that holds this package, or from the current directory.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: grains of the default and the --quick run
SIZES, QUICK_SIZES = (2_000, 10_000), (1_000,)
#: timed steps, and untimed settling steps before them (default, --quick)
STEPS, QUICK_STEPS = 1_000, 200
SETTLE, QUICK_SETTLE = 10_000, 2_000
#: the timed steps run as this many equal runs (both codes), each timed on its own
CHUNKS = 10
#: LAMMPS's default atom sort interval, used for granularsap's re-ordering too
SORT_EVERY = 1000
#: the Verlet margin of both codes (LAMMPS: neighbor 0.2 bin)
MARGIN = 0.2
EXAMPLE = Path("examples") / "dem_hertz_mindlin.py"


def load_example(path=None):
    """The example module that defines the pour (``Pour``, ``initial_column``, ...).

    Looks in the checkout that holds this package, then under the current
    directory, unless ``path`` is given.

    Raises
    ------
    FileNotFoundError
        When the example is in neither place (an installed wheel without a
        checkout).
    """
    if path is None:
        here = Path(__file__).resolve().parents[2] / EXAMPLE
        path = here if here.is_file() else Path.cwd() / EXAMPLE
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"dem-loop steps the pour of {EXAMPLE}, which is not at {path}; "
                                "run it from a source checkout of granularsap")
    name = "granularsap_bench_dem_example"
    if name in sys.modules and getattr(sys.modules[name], "__file__", None) == str(path):
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module


def _log_breakdown(path):
    """``({section: seconds}, neighbour list builds)`` of the last run in a LAMMPS log."""
    with open(path) as fh:
        lines = fh.read().splitlines()
    head = max((k for k, line in enumerate(lines) if line.startswith("Section |")), default=None)
    if head is None:
        raise RuntimeError(f"LAMMPS wrote no timer breakdown to {path}")
    sections = {}
    for line in lines[head + 2:]:
        cols = [c.strip() for c in line.split("|")]
        if len(cols) < 3 or not cols[0]:
            break
        sections[cols[0]] = float(cols[2])
    builds = None
    for line in lines[head:]:
        if line.startswith("Neighbor list builds"):
            builds = int(line.split("=")[1])
    return sections, builds


#: the two settings the loop runs in, each code in its own way of doing it
SETTINGS = {
    "verlet": "a kept Verlet list (LAMMPS: neighbor 0.2 bin, check yes; granularsap: "
              "rebuild_margin 0.2)",
    "list": "a kept neighbour list (LAMMPS: neighbor 0.2 bin, check yes, the verlet run; "
            "granularsap: ContactList, rebuild_margin 0.2: the list rebuilt when a grain moved "
            "half the margin, the springs moved at its rebuilds; the separations of the listed "
            "pairs are the contact law's, as LAMMPS computes them in Pair)",
    "rebuild": "rebuilt every step (LAMMPS: neighbor 0.2 bin, every 1 delay 0 check no; "
               "granularsap: rebuild_margin 0)",
}
#: what LAMMPS's Modify section holds in this pour (src/verlet.cpp stamps each as MODIFY)
MODIFY_HOLDS = ("fix wall/gran x3 (walls: their contacts and history), nve/sphere, gravity, "
                "NEIGH_HISTORY (history remap on list builds)")
#: repeats of the single-frame rebuild (the bench's lammps-rebuild and granularsap-steady)
FRAME_REPEATS = 5


class LammpsPour:
    """The example's pour in one LAMMPS instance (``pair_style granular``).

    ``check=True``: LAMMPS's Verlet list (``neigh_modify delay 0 every 1 check
    yes``); ``check=False``: the list rebuilt on every step (``check no``).
    """

    def __init__(self, example, positions, velocities, radii, width, *, n_threads, dt,
                 check=True, omegas=None):
        import lammps_bridge

        self.folder = tempfile.mkdtemp(prefix="granularsap-bench-dem-")
        self.log = os.path.join(self.folder, "log.lammps")
        self.lmp = lammps_bridge.new_lammps(cmdargs=["-log", self.log, "-screen", "none"],
                                            quiet=False)
        self.omp = bool(self.lmp.has_package("OPENMP"))
        self.n = len(radii)
        material = example.Material()
        model = material.lammps()
        top = float(positions[:, 2].max() + 4.0 * float(radii.max()))
        w = float(width)
        cmds = [f"package omp {int(n_threads)}", "suffix omp"] if self.omp else []
        cmds += ["units lj", "atom_style sphere", "atom_modify map array", "boundary f f f",
                 "comm_modify vel yes",
                 f"region box block 0 {w!r} 0 {w!r} -1.0 {top!r} units box", "create_box 1 box",
                 "pair_style granular", f"pair_coeff * * {model}",
                 f"neighbor {MARGIN!r} bin",
                 f"neigh_modify delay 0 every 1 check {'yes' if check else 'no'}",
                 f"timestep {float(dt)!r}"]
        try:
            for c in cmds:
                self.lmp.command(c)
            n = self.n
            created = self.lmp.create_atoms(n, list(range(1, n + 1)), [1] * n,
                                            np.asarray(positions, float).ravel().tolist(),
                                            v=np.asarray(velocities, float).ravel().tolist())
            if created != n:
                raise RuntimeError(f"LAMMPS created {created} of {n} grains")
            tag = self._tags()
            mass = material.density * 4.0 / 3.0 * np.pi * radii ** 3
            self.lmp.numpy.extract_atom("radius", nelem=n)[:n] = radii[tag]
            self.lmp.numpy.extract_atom("rmass", nelem=n)[:n] = mass[tag]
            if omegas is not None:
                self.lmp.numpy.extract_atom("omega", nelem=n)[:n] = np.asarray(omegas)[tag]
            for c in [f"fix floor all wall/gran granular {model} zplane 0.0 NULL",
                      f"fix side_x all wall/gran granular {model} xplane 0.0 {w!r}",
                      f"fix side_y all wall/gran granular {model} yplane 0.0 {w!r}",
                      "fix move all nve/sphere",
                      f"fix gravity all gravity {-float(example.GRAVITY[2])!r} vector 0 0 -1",
                      "compute contacts all contact/atom", "thermo 0"]:
                self.lmp.command(c)
        except Exception:
            self.close()
            raise

    def _tags(self):
        n = self.lmp.extract_setting("nlocal")
        return np.asarray(self.lmp.numpy.extract_atom("id", nelem=n)[:n], dtype=np.int64) - 1

    def run(self, steps, *, timed, pre=True):
        """Run ``steps``; when ``timed``, return ``({section: seconds}, list builds)``.

        ``pre=False`` continues the previous run without LAMMPS's set-up (``run N pre
        no``: no extra neighbour build between two timed runs).
        """
        command = f"run {int(steps)}" + ("" if pre else " pre no")
        if not timed:
            self.lmp.command("log none")
            self.lmp.command(command)
            return None
        self.lmp.command(f"log {self.log}")
        self.lmp.command(command)
        self.lmp.command("log none")
        return _log_breakdown(self.log)

    def timed_runs(self, bounds):
        """The timed steps as consecutive runs over ``bounds``: per-step sections of each
        run, of all, and the list builds."""
        sections, builds, chunks = {}, 0, []
        for c, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
            part, builds = self.run(b - a, timed=True, pre=c == 0)
            # the timers restart with every run; the count of list builds runs on
            # from the first run's set-up (runs with pre no do not reset it)
            chunks.append({k.lower(): v / (b - a) for k, v in part.items()})
            for k, v in part.items():
                sections[k.lower()] = sections.get(k.lower(), 0.0) + v
        steps = bounds[-1] - bounds[0]
        return {k: v / steps for k, v in sections.items()}, chunks, builds

    def state(self):
        """(positions, velocities, spins) of the grains in id order."""
        n = self.lmp.extract_setting("nlocal")
        order = np.argsort(self._tags())
        out = []
        for name in ("x", "v", "omega"):
            out.append(np.array(self.lmp.numpy.extract_atom(name, nelem=n)[:n], dtype=float)[order])
        return tuple(out)

    def contacts(self):
        """Grain-grain contacts now (``compute contact/atom``, summed and halved)."""
        self.lmp.command("run 0 post no")
        counts = self.lmp.numpy.extract_compute("contacts", 1, 1)  # per-atom vector
        return int(round(float(np.sum(counts[: self.n])) / 2))

    def close(self):
        if getattr(self, "lmp", None) is not None:
            self.lmp.close()
            self.lmp = None
        shutil.rmtree(self.folder, ignore_errors=True)


def run_granularsap(example, positions, velocities, omegas, radii, width, steps, *, n_threads,
                    dt, ids=None, margin=MARGIN, sort_every=None, neighbor_list=False):
    """Step the example's pour ``steps`` times, the grains put in spatial order every
    ``sort_every`` steps (default ``SORT_EVERY``); per-step search + history
    seconds and stats.  ``neighbor_list``: the grains through a ``ContactList``
    (the separations of its pairs timed apart, ``separation_seconds``)."""
    sort_every = SORT_EVERY if sort_every is None else sort_every
    floor = example.floor_mesh(width)
    pour = example.Pour(positions, velocities, radii, width, floor, dt=dt,
                        rebuild_margin=margin, n_threads=n_threads, ids=ids, omegas=omegas,
                        neighbor_list=neighbor_list)
    grains = pour.contacts if neighbor_list else pour.search
    seconds = np.empty(steps)
    walls = np.empty(steps)
    separations = np.zeros(steps)
    rebuilt = np.zeros(steps, bool)
    for k in range(steps):
        if k and k % sort_every == 0:
            pour.reorder(pour.spatial_order())
        pour.step()
        seconds[k] = pour.search_seconds
        walls[k] = pour.wall_seconds
        separations[k] = pour.separation_seconds
        rebuilt[k] = bool(grains.stats.get("rebuilt"))
    rebuilds = int(rebuilt.sum())
    stats = grains.stats.get("search", {}) if neighbor_list else grains.stats
    out = {"seconds": seconds, "wall_seconds": walls, "rebuilt": rebuilt, "rebuilds": rebuilds,
           "contacts": len(pour.pairs), "wall_contacts": len(pour.wall_spring),
           "path": stats.get("path")}
    if neighbor_list:
        out["separations_mean"] = float(separations.mean())
        out["listed"] = len(pour.history)
    return out


def _warm_identity_rest(n_threads):
    """Compile the contact identity's second pass (a call with new and ended pairs
    that the first pass leaves), which the timed steps reach at a list rebuild
    once contacts have come and gone, but a few untimed steps of a settled pour
    need not."""
    from ..identity import PairIdentity

    track = PairIdentity(n_threads=n_threads)
    track.update(np.array([[0, 1], [1, 2], [2, 3], [3, 4]], np.int64), 5)
    track.update(np.array([[0, 1], [2, 3], [0, 4], [3, 4]], np.int64), 5)


def frame_rebuild(positions, radii, *, n_threads, repeats=FRAME_REPEATS, lammps=True):
    """One frame of the pour searched as the rest of the bench does it.

    ``lammps-rebuild`` (LAMMPS ``neighbor 0.0 bin``, ``check no``, ``run 10``:
    its ``(Neigh + Comm) / 10``) and ``granularsap-steady`` (a kept
    ``ContactSearch`` rebuilding every call), after one untimed call each;
    the min and median over ``repeats`` and whether the two found the same pairs.
    """
    from .peers import GranularSAPSteady, LammpsRebuild
    from .workloads import Workload

    n = len(radii)
    wl = Workload(name="dem-loop-frame", label=f"dem-loop frame, {n} grains", kind="contacts",
                  n=n, frames=[np.ascontiguousarray(positions, dtype=float)],
                  radii=np.asarray(radii, dtype=float))
    out = {}
    peer = GranularSAPSteady()
    peer.setup(wl, n_threads)
    ours = peer.run(0)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        ours = peer.run(0)
        times.append(time.perf_counter() - t0)
    out["granularsap_steady"] = {"min": min(times), "median": float(np.median(times)),
                                 "pairs": len(ours)}
    if lammps:
        peer = LammpsRebuild()
        peer.setup(wl, n_threads)
        try:
            theirs = peer.run(0)
            neigh, comm = [], []
            for _ in range(repeats):
                theirs = peer.run(0)
                s = peer.last_stats()["seconds"]
                neigh.append(s["neigh"])
                comm.append(s["comm"])
            total = [a + b for a, b in zip(neigh, comm, strict=True)]
            best = int(np.argmin(total))
            out["lammps_rebuild"] = {"min": total[best], "median": float(np.median(total)),
                                     "neigh": neigh[best], "comm": comm[best],
                                     "pairs": len(theirs)}
            out["same_pairs"] = bool(len(ours) == len(theirs) and np.array_equal(
                np.unique(ours, axis=0), np.unique(theirs, axis=0)))
        finally:
            peer.close()
    return out


def _granularsap_figures(gs, bounds):
    s = gs.pop("seconds")
    w = gs.pop("wall_seconds")
    built = gs.pop("rebuilt")
    pairs = list(zip(bounds[:-1], bounds[1:], strict=True))
    means = [float(s[a:b].mean()) for a, b in pairs]
    grains = [float((s[a:b] - w[a:b]).mean()) for a, b in pairs]
    g = s - w
    # the grains' time split as LAMMPS's timers split its own: the steps that built
    # the list (its Neigh) and the steps that kept it (its check is in Other)
    return {"mean": float(s.mean()), "min": float(s.min()), "median": float(np.median(s)),
            "grains_mean": float(g.mean()), "grains_median": float(np.median(g)),
            "grains_builds": float(g[built].sum() / len(g)) if len(g) else 0.0,
            "grains_kept": float(g[~built].sum() / len(g)) if len(g) else 0.0,
            "walls_mean": float(w.mean()), "chunk_means": means, "chunk_grains": grains, **gs}


def _ratio(a, b):
    return a / b if b > 0 else float("inf")


def dem_loop(n, *, steps=STEPS, settle=SETTLE, n_threads=1, seed=0, example=None, lammps=True,
             progress=None):
    """Run the dem-loop comparison for ``n`` grains; a dict of figures (seconds per step).

    ``out["settings"]["verlet"]`` and ``out["settings"]["rebuild"]`` hold each
    setting's ``granularsap`` figures (``grains_mean``: the grain search + its
    history, ``walls_mean``: the wall search + its history, ``mean``: both),
    ``lammps`` (its timer sections per step), list builds, contact counts and
    the ratios; ``out["frame"]`` the single-frame rebuild of :func:`frame_rebuild`.
    """
    say = progress or (lambda msg: None)
    ex = example or load_example()
    dt = 5e-4
    positions, velocities, radii, width = ex.initial_column(int(n), seed)
    omegas = np.zeros_like(positions)
    out = {"n": int(n), "steps": int(steps), "settle": int(settle), "threads": int(n_threads),
           "seed": seed, "dt": dt, "rebuild_margin": MARGIN, "width": float(width),
           "modify_holds": MODIFY_HOLDS, "settings": {k: {"what": v} for k, v in SETTINGS.items()}}
    # the timed steps in CHUNKS runs of equal length: LAMMPS's timers per run, and
    # granularsap's steps over the same ranges (the fastest run of each is robust to load)
    bounds = np.linspace(0, steps, min(CHUNKS, steps) + 1).round().astype(int).tolist()
    why = None
    if lammps:
        try:
            import lammps_bridge  # noqa: F401
        except ImportError as exc:
            why = f"{type(exc).__name__}: {exc}"
    else:
        why = "not asked for"
    if why is None:
        system = LammpsPour(ex, positions, velocities, radii, width, n_threads=n_threads, dt=dt)
        try:
            out["lammps_omp"] = system.omp
            if settle:
                say(f"  LAMMPS settles the pour: {settle} steps")
                system.run(settle, timed=False)
            positions, velocities, omegas = system.state()
            say(f"  LAMMPS, Verlet list: {steps} timed steps in {len(bounds) - 1} runs")
            per_step, chunks, builds = system.timed_runs(bounds)
            out["settings"]["verlet"].update(lammps=per_step, lammps_chunks=chunks,
                                             lammps_builds=builds,
                                             lammps_contacts=system.contacts())
        finally:
            system.close()
        # the same state rebuilt every step (its history starts empty, as granularsap's)
        say(f"  LAMMPS, rebuilt every step: {steps} timed steps")
        system = LammpsPour(ex, positions, velocities, radii, width, n_threads=n_threads, dt=dt,
                            check=False, omegas=omegas)
        try:
            per_step, chunks, builds = system.timed_runs(bounds)
            out["settings"]["rebuild"].update(lammps=per_step, lammps_chunks=chunks,
                                              lammps_builds=builds,
                                              lammps_contacts=system.contacts())
        finally:
            system.close()
    else:
        out["lammps_missing"] = why
        out["settle"] = 0  # LAMMPS settles the pour: without it, the timed steps start unsettled
        if settle:
            say(f"  LAMMPS not available ({why}): granularsap times the pour from the column")
    say("  one frame of the pour, as the bench's lammps-rebuild and granularsap-steady")
    out["frame"] = frame_rebuild(positions, radii, n_threads=n_threads, lammps=why is None)
    if "lammps" in out["settings"]["verlet"]:  # one LAMMPS run for both kept lists
        out["settings"]["list"].update({k: v for k, v in out["settings"]["verlet"].items()
                                        if k != "what"})
    for name, margin, listed in (("verlet", MARGIN, False), ("list", MARGIN, True),
                                 ("rebuild", 0.0, False)):
        say(f"  granularsap, rebuild_margin {margin}{', ContactList' if listed else ''}: "
            f"{steps} steps")
        # untimed: compile (or load from the cache) what this pour's searches use,
        # a re-ordering of the grains included (the timed steps have them), a
        # Verlet list rebuilt on grains in the same rows (a margin rebuilt every
        # step: the identity matches pairs by rows) and the identity's second pass
        run_granularsap(ex, positions, velocities, omegas, radii, width, 4,
                        n_threads=n_threads, dt=dt, margin=margin, sort_every=2,
                        neighbor_list=listed)
        if margin:
            run_granularsap(ex, positions, velocities, omegas, radii, width, 3,
                            n_threads=n_threads, dt=dt, margin=1e-12 * margin,
                            sort_every=steps + 1, neighbor_list=listed)
        _warm_identity_rest(n_threads)
        gs = run_granularsap(ex, positions, velocities, omegas, radii, width, steps,
                             n_threads=n_threads, dt=dt, margin=margin, neighbor_list=listed)
        s = out["settings"][name]
        s["granularsap"] = g = _granularsap_figures(gs, bounds)
        if "lammps" not in s:
            continue
        lam = s["lammps"]
        neigh = lam.get("neigh", 0.0)
        nm = neigh + lam.get("modify", 0.0)
        s["ratios"] = {"all_neigh": _ratio(g["mean"], neigh),
                       "grains_neigh": _ratio(g["grains_mean"], neigh),
                       "all_neigh_modify": _ratio(g["mean"], nm),
                       "all_neigh_modify_pair": _ratio(g["mean"], nm + lam.get("pair", 0.0))}
        # the fastest of the runs of each code (a shared machine disturbs it less)
        fast_nm = min(c.get("neigh", 0.0) + c.get("modify", 0.0) for c in s["lammps_chunks"])
        s["fastest_chunk"] = {"granularsap": min(g["chunk_means"]),
                              "granularsap_grains": min(g["chunk_grains"]),
                              "lammps_neigh": min(c.get("neigh", 0.0) for c in s["lammps_chunks"]),
                              "lammps_neigh_modify": fast_nm}
    return out


def format_result(r):
    """The lines ``granularsap bench dem-loop`` prints for one result."""
    ms = 1e3
    start = f"after {r['settle']} of settling" if r["settle"] else "from the column"
    lines = [f"dem-loop N={r['n']}: {r['steps']} steps {start}, {r['threads']} thread(s); "
             "ms per step, means over the steps"]
    for name, s in r["settings"].items():
        g = s["granularsap"]
        lines.append(f" {name}: {s['what']}")
        lines.append(f"  granularsap: grains (search + history) {g['grains_mean'] * ms:.3f} "
                     f"(median {g['grains_median'] * ms:.3f}), walls (search + history) "
                     f"{g['walls_mean'] * ms:.3f}, both {g['mean'] * ms:.3f}; "
                     f"{g['rebuilds']} list rebuilds, {g['contacts']} contacts + "
                     f"{g['wall_contacts']} on walls at the end, path {g['path']}"
                     + (f"; {g['listed']} listed pairs, their separations (contact law) "
                        f"{g['separations_mean'] * ms:.3f}" if "listed" in g else ""))
        if "lammps" not in s:
            continue
        lam = s["lammps"]
        nm = lam.get("neigh", 0.0) + lam.get("modify", 0.0)
        words = ", ".join(f"{k.capitalize()} {lam[k] * ms:.3f}" for k in
                          ("neigh", "modify", "pair", "comm", "other") if k in lam)
        lines.append(f"  LAMMPS (its timers): {words}; Neigh + Modify {nm * ms:.3f}; "
                     f"{s['lammps_builds']} list builds, {s['lammps_contacts']} contacts at the "
                     f"end; {'OPENMP' if r.get('lammps_omp') else 'serial'}")
        if 0 < g["rebuilds"] < r["steps"]:
            lines.append(f"  the grains' mean split: steps that built the list "
                         f"{g['grains_builds'] * ms:.4f} (against LAMMPS's Neigh "
                         f"{lam.get('neigh', 0.0) * ms:.4f}), steps that kept it "
                         f"{g['grains_kept'] * ms:.4f} (against LAMMPS's Other "
                         f"{lam.get('other', 0.0) * ms:.4f}, which holds its check and more)")
        q = s["ratios"]
        lines.append(f"  ratios granularsap / LAMMPS: grains / Neigh {q['grains_neigh']:.2f}, "
                     f"grains + walls / Neigh {q['all_neigh']:.2f}, grains + walls / (Neigh + "
                     f"Modify) {q['all_neigh_modify']:.2f}, / (Neigh + Modify + Pair) "
                     f"{q['all_neigh_modify_pair']:.2f}")
        f = s["fastest_chunk"]
        k = len(s["lammps_chunks"])
        lines.append(f"  fastest of {k} runs of {r['steps'] // k} steps (each code's own): "
                     f"granularsap grains {f['granularsap_grains'] * ms:.3f}, both "
                     f"{f['granularsap'] * ms:.3f}; LAMMPS Neigh {f['lammps_neigh'] * ms:.3f}, "
                     f"Neigh + Modify {f['lammps_neigh_modify'] * ms:.3f}")
    if "lammps_missing" in r:
        lines.append(f"  LAMMPS: not run ({r['lammps_missing']})")
    fr = r.get("frame")
    if fr:
        g = fr["granularsap_steady"]
        text = (f" one frame (the pour's start), min of {FRAME_REPEATS}: granularsap-steady "
                f"{g['min'] * ms:.3f}")
        lam = fr.get("lammps_rebuild")
        if lam:
            text += (f", lammps-rebuild (Neigh + Comm of run 10, neighbor 0.0 bin, check no) "
                     f"{lam['min'] * ms:.3f} (Neigh {lam['neigh'] * ms:.3f}); ratio "
                     f"{_ratio(g['min'], lam['min']):.2f}; same pairs: {fr['same_pairs']}")
        lines.append(text)
    if "lammps_missing" not in r:
        lines.append(f"  LAMMPS's Modify holds: {r['modify_holds']}")
    return "\n".join(lines)


def wants_lammps(peers=None, exclude=None):
    """Whether ``--peers`` / ``--exclude`` leave LAMMPS in (any peer named ``lammps...``).

    >>> wants_lammps(), wants_lammps("granularsap,lammps"), wants_lammps("granularsap")
    (True, True, False)
    >>> wants_lammps(exclude="lammps-rebuild")
    False
    """
    def names(text):
        return [w for w in str(text or "").replace(",", " ").split() if w]

    if peers is not None and not any(w.startswith("lammps") for w in names(peers)):
        return False
    return not any(w.startswith("lammps") for w in names(exclude))


def run_dem_loop(args):
    """Entry point of ``granularsap bench dem-loop``; returns an exit code."""
    from .report import machine_description

    quick = bool(getattr(args, "quick", False))
    sizes = getattr(args, "dem_sizes", None) or (QUICK_SIZES if quick else SIZES)
    steps = getattr(args, "steps", None)
    steps = (QUICK_STEPS if quick else STEPS) if steps is None else steps
    settle = getattr(args, "settle", None)
    settle = (QUICK_SETTLE if quick else SETTLE) if settle is None else settle
    threads = getattr(args, "threads", None) or 1
    if steps < 1:
        raise ValueError(f"--steps must be at least 1, got {steps}")
    if settle < 0:
        raise ValueError(f"--settle must be at least 0, got {settle}")
    example = load_example()
    lammps = wants_lammps(getattr(args, "peers", None), getattr(args, "exclude", None))
    machine = machine_description()
    load = machine.get("load_average")
    print(f"machine: {machine['cpu_model']}, {machine['usable_cores']} usable cores, "
          f"{threads} thread(s)" + (f", load average {load[0]:.2f}" if load else ""), flush=True)
    results = []
    for n in sizes:
        t0 = time.perf_counter()
        r = dem_loop(n, steps=steps, settle=settle, n_threads=threads,
                     seed=getattr(args, "seed", 0) or 0, example=example, lammps=lammps,
                     progress=lambda msg: print(msg, flush=True))
        r["wall_seconds"] = time.perf_counter() - t0
        results.append(r)
        print(format_result(r), flush=True)
    if getattr(args, "json", None):
        with open(args.json, "w") as fh:
            json.dump({"schema": "granularsap-bench-dem-loop/2", "machine": machine,
                       "results": results}, fh, indent=1)
        print(f"wrote {args.json}")
    return 0
