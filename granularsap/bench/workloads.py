"""Benchmark inputs, generated deterministically from a seed.

Every generator returns a :class:`Workload`: the arrays a neighbour search
needs and the question asked of them, in one of three kinds.

``cutoff``
    every pair with ``d <= cutoff`` (minimum image when ``box`` is set);
``contacts``
    every pair with ``d <= r_i + r_j`` (per-particle radii);
``boxes``
    every pair of overlapping closed axis-aligned boxes.

A trajectory is a workload with several ``frames`` of positions; the other
workloads have one.  The same ``(name, n, seed)`` always gives the same arrays,
so runs on different machines or days compare like with like.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: number density of the Lennard-Jones liquid (sigma = 1)
LJ_DENSITY = 0.8442
#: LJ cutoff 2.5 sigma plus a 0.3 sigma Verlet skin
LJ_CUTOFF = 2.8
#: volume fraction of the polydisperse granular packing
GRANULAR_PHI = 0.3
#: radii of the granular workload: lognormal (median 1, sigma 0.6) clipped to [R_MIN, 10 R_MIN]
R_MIN, R_MAX, R_SIGMA = 0.3, 3.0, 0.6
#: per-frame Gaussian displacement (per coordinate, sigma units) of the trajectory workload
STEP_SIGMA = 0.05


@dataclass
class Workload:
    """One benchmark input.

    Attributes
    ----------
    name : str
        Workload family (``md-liquid``, ``granular-polydisperse``, ...).
    label : str
        Human-readable description including size and parameters.
    kind : {"cutoff", "contacts", "boxes"}
        What is searched for (module docstring).
    n : int
        Number of particles or boxes.
    frames : list of (n, 3) ndarray of float64
        Positions (``cutoff``/``contacts``) or box centres (``boxes``); one
        entry except for trajectories.
    cutoff : float or None
        Distance cutoff (``cutoff`` kind).
    radii : (n,) ndarray or None
        Particle radii (``contacts`` kind).
    half_extents : (n, 3) ndarray or None
        Box half sides (``boxes`` kind): box = centre -/+ half_extents.
    box : (6,) ndarray or None
        Periodic cell in MDAnalysis form ``[lx, ly, lz, alpha, beta, gamma]``;
        None for open boundaries.
    params : dict
        The generator's parameters, stored in the JSON report.
    """

    name: str
    label: str
    kind: str
    n: int
    frames: list
    cutoff: float | None = None
    radii: np.ndarray | None = None
    half_extents: np.ndarray | None = None
    box: np.ndarray | None = None
    params: dict = field(default_factory=dict)

    @property
    def positions(self):
        """Positions (or box centres) of the first frame."""
        return self.frames[0]

    def boxes(self, frame=0):
        """``(lower, upper)`` of a ``boxes`` workload for one frame."""
        c = self.frames[frame]
        return c - self.half_extents, c + self.half_extents

    @property
    def orthorhombic(self):
        """True when the cell is absent or has right angles."""
        return self.box is None or bool(np.allclose(self.box[3:], 90.0))

    def search_radius(self):
        """The single cutoff a one-cutoff neighbour search needs to see every pair.

        ``cutoff`` for the cutoff kind, ``2 * max(radii)`` for contacts and
        the largest possible centre distance of two overlapping boxes for
        boxes; the exact test is applied afterwards as a filter.
        """
        if self.kind == "cutoff":
            return float(self.cutoff)
        if self.kind == "contacts":
            return 2.0 * float(self.radii.max()) if self.n else 0.0
        if self.n == 0:
            return 0.0
        return 2.0 * float(np.linalg.norm(self.half_extents.max(axis=0)))


def _cube(length):
    return np.array([length, length, length, 90.0, 90.0, 90.0])


def _check_n(n, minimum, name):
    n = int(n)
    if n < minimum:
        raise ValueError(f"{name} needs n >= {minimum} so that the periodic cell is wider "
                         f"than twice the cutoff, got n={n}")
    return n


def md_liquid(n, *, seed=0, periodic=True):
    """Uniform points at the LJ liquid density 0.8442, cutoff 2.8 (2.5 + 0.3 skin).

    Periodic cube by default; ``periodic=False`` gives the same points with
    open boundaries (``md-liquid-open``).
    """
    name = "md-liquid" if periodic else "md-liquid-open"
    n = _check_n(n, math.ceil(LJ_DENSITY * (2 * LJ_CUTOFF) ** 3) + 1, name)
    length = (n / LJ_DENSITY) ** (1.0 / 3.0)
    rng = np.random.default_rng([seed, 1])
    pos = rng.random((n, 3)) * length
    return Workload(
        name=name, label=f"{name} N={n}", kind="cutoff", n=n, frames=[pos],
        cutoff=LJ_CUTOFF, box=_cube(length) if periodic else None,
        params={"density": LJ_DENSITY, "cutoff": LJ_CUTOFF, "length": length,
                "periodic": periodic, "seed": seed},
    )


def md_liquid_open(n, *, seed=0):
    """:func:`md_liquid` without periodicity."""
    return md_liquid(n, seed=seed, periodic=False)


def granular_polydisperse(n, *, seed=0):
    """Polydisperse spheres in a periodic cube at volume fraction 0.3.

    Radii are lognormal (median 1, sigma 0.6) clipped to ``[0.3, 3.0]`` (a
    1:10 size ratio); centres are uniform (overlaps allowed: this is a broad
    phase input, not a packing).  Contacts are ``d <= r_i + r_j``.
    """
    n = int(n)
    if n < 8:
        raise ValueError(f"granular-polydisperse needs n >= 8, got n={n}")
    rng = np.random.default_rng([seed, 2])
    radii = np.clip(rng.lognormal(0.0, R_SIGMA, n), R_MIN, R_MAX)
    volume = float(np.sum(4.0 / 3.0 * np.pi * radii**3))
    length = (volume / GRANULAR_PHI) ** (1.0 / 3.0)
    if length <= 4.0 * radii.max():
        raise ValueError(f"granular-polydisperse needs a larger n: the cell {length:.3g} is not "
                         f"wider than twice the largest contact distance {2 * radii.max():.3g}")
    pos = rng.random((n, 3)) * length
    return Workload(
        name="granular-polydisperse", label=f"granular-polydisperse N={n}", kind="contacts",
        n=n, frames=[pos], radii=radii, box=_cube(length),
        params={"volume_fraction": GRANULAR_PHI, "r_min": R_MIN, "r_max": R_MAX,
                "lognormal_sigma": R_SIGMA, "length": length, "seed": seed},
    )


def paper_boxes(n, *, seed=0, density=0.35):
    """Uniform boxes of the paper's experiments (Capannini & Larsson, Section 7).

    Each side of each box is drawn independently from U(0.5, 1.5), so the
    mean volume is 1; the world cube's side is chosen so that the summed box
    volume over the world volume is ``density``; boxes lie inside the world.
    Open boundaries.
    """
    n = int(n)
    if not 0.0 < density:
        raise ValueError(f"density must be positive, got {density}")
    rng = np.random.default_rng([seed, 3])
    sides = rng.uniform(0.5, 1.5, (n, 3))
    world = (n / density) ** (1.0 / 3.0) if n else 1.0
    centres = sides / 2 + rng.random((n, 3)) * np.maximum(world - sides, 0.0)
    return Workload(
        name="paper-boxes", label=f"paper-boxes n={n} d={density:g}", kind="boxes", n=n,
        frames=[centres], half_extents=sides / 2,
        params={"density": density, "world": world, "sides": "U(0.5, 1.5) per axis",
                "seed": seed},
    )


def trajectory(n, *, seed=0, n_frames=50, step=STEP_SIGMA):
    """The md-liquid configuration moved by Gaussian steps for ``n_frames`` frames.

    Each frame displaces every particle by N(0, ``step``) per coordinate and
    wraps it back into the periodic cube.  Stateful engines may reuse work
    between frames; the others rebuild every frame.
    """
    base = md_liquid(n, seed=seed)
    n_frames = int(n_frames)
    if n_frames < 2:
        raise ValueError(f"a trajectory needs at least 2 frames, got {n_frames}")
    length = base.box[0]
    rng = np.random.default_rng([seed, 4])
    frames = [base.frames[0]]
    for _ in range(n_frames - 1):
        nxt = frames[-1] + rng.normal(0.0, step, (base.n, 3))
        nxt = np.mod(nxt, length)
        nxt[nxt >= length] = 0.0  # np.mod can round up to exactly length
        frames.append(nxt)
    base.name = "trajectory"
    base.label = f"trajectory N={base.n} x {n_frames} frames"
    base.frames = frames
    base.params.update(n_frames=n_frames, step_sigma=step)
    return base


#: files in data/ that are never trajectories
_NOT_DATA = {".py", ".sh", ".md", ".txt", ".in", ".mol", ".data", ".lmp", ".json", ".png",
             ".cfg", ".toml", ".yaml", ".yml", ".h5", ".hdf5", ".log"}


def data_files(directory):
    """Files of ``directory`` that look like trajectories (scripts and docs left out)."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    return sorted(p for p in directory.rglob("*")
                  if p.is_file() and p.suffix.lower() not in _NOT_DATA
                  and not p.name.startswith((".", "README", "LICENSE")))


def _read_last_frame(path):
    """(positions, box or None, radii or None) of the last frame of ``path``."""
    try:
        from granularsap.io import iter_frames
    except ImportError:
        iter_frames = None
    if iter_frames is not None:
        last = deque(iter_frames(path), maxlen=1)
        if not last:
            raise ValueError(f"{path} holds no frame")
        frame = last[0]
        pos = np.asarray(frame.positions, dtype=np.float64)
        radii = getattr(frame, "radius", None)
        cell, pbc = frame.cell, np.asarray(frame.pbc, dtype=bool)
        origin = getattr(frame, "origin", None)
    else:  # pragma: no cover - granularsap.io is part of the package
        import ase.io

        atoms = ase.io.read(str(path), index=-1)
        pos, radii = atoms.get_positions(), atoms.arrays.get("radius")
        cell, pbc, origin = np.asarray(atoms.cell), atoms.pbc, None
    if cell is None or not pbc.any():
        return pos, None, radii
    if not pbc.all():
        raise ValueError(f"{path}: mixed periodicity {pbc.tolist()} is not a benchmark input")
    if origin is not None:
        pos = pos - np.asarray(origin, dtype=np.float64)
    return pos, _cell_to_box(np.asarray(cell, dtype=np.float64)), radii


def _cell_to_box(cell):
    """MDAnalysis ``[lx, ly, lz, alpha, beta, gamma]`` of a (3, 3) cell (rows are vectors)."""
    lengths = np.linalg.norm(cell, axis=1)

    def angle(u, v):
        cos = np.dot(u, v) / (np.linalg.norm(u) * np.linalg.norm(v))
        return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))

    a, b, c = cell
    return np.array([*lengths, angle(b, c), angle(a, c), angle(a, b)])


def real_data(path, *, cutoff=LJ_CUTOFF):
    """The last frame of a trajectory file from data/.

    Particles with radii (granular dumps) are searched for contacts
    ``d <= r_i + r_j``; the others for pairs within ``cutoff``.  The last
    frame is used because in a pour or a relaxation it is the densest.
    """
    path = Path(path)
    pos, box, radii = _read_last_frame(path)
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    n = len(pos)
    common = dict(name="data", n=n, frames=[pos], box=box,
                  params={"path": str(path), "periodic": box is not None,
                          "box": None if box is None else box.tolist()})
    if radii is not None:
        radii = np.ascontiguousarray(radii, dtype=np.float64)
        return Workload(label=f"data {path.name} N={n} contacts", kind="contacts",
                        radii=radii, **common)
    common["params"]["cutoff"] = cutoff
    return Workload(label=f"data {path.name} N={n} cutoff={cutoff:g}", kind="cutoff",
                    cutoff=cutoff, **common)


#: workload name -> (generator, default sizes, --quick sizes)
WORKLOADS = {
    "md-liquid": (md_liquid, [10_000, 100_000, 1_000_000], [2_000, 10_000]),
    "md-liquid-open": (md_liquid_open, [10_000, 100_000, 1_000_000], [2_000, 10_000]),
    "granular-polydisperse": (granular_polydisperse, [10_000, 100_000, 1_000_000],
                              [2_000, 10_000]),
    "paper-boxes": (paper_boxes, [2**18, 2**19, 2**20], [2**12, 2**14]),
    "trajectory": (trajectory, [100_000], [5_000]),
}

#: every name the bench command accepts (``paper`` is the engine's own benchmark,
#: ``dem-loop`` a DEM time loop against LAMMPS: granularsap.bench.demloop, ``mda-capped``
#: the MDAnalysis drop-in against MDAnalysis: bench/mda_capped.py)
WORKLOAD_NAMES = [*WORKLOADS, "data", "paper", "dem-loop", "mda-capped"]


def make(name, n, *, seed=0, density=0.35, n_frames=50):
    """Build workload ``name`` with ``n`` particles/boxes."""
    if name not in WORKLOADS:
        raise ValueError(f"unknown workload {name!r}; choose one of {', '.join(WORKLOADS)}")
    gen = WORKLOADS[name][0]
    if name == "paper-boxes":
        return gen(n, seed=seed, density=density)
    if name == "trajectory":
        return gen(n, seed=seed, n_frames=n_frames)
    return gen(n, seed=seed)
