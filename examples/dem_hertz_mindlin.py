"""Pour polydisperse spheres onto a triangle-mesh floor: Hertz-Mindlin DEM with friction history.

Every time step asks granularsap for the sphere contacts (``ContactSearch``)
and the contacts with the walls (``WallSearch``: four side planes and a floor
read from an STL file), each with *identity*: which contact of the previous
step each contact continues.  That is what friction needs.  The tangential
force of Mindlin's model is a spring stretched by the sliding of the two
surfaces over the life of the contact, capped by Coulomb's law; its
stretch is the per-contact history, moved from one step to the next with one
gather per step::

    pairs, d, D = search.update(x, radii, ids=ids)
    spring = search.carry(spring)           # last step's springs, 0 for new contacts

With ``--neighbor-list`` the grains go through a ``ContactList`` instead,
as LAMMPS keeps them: the pairs within the contact distance plus the margin,
rebuilt only when a grain has moved more than half the margin, the springs
moved to the new rows at a rebuild only; the contact law computes every
listed pair's separation and leaves the pairs that do not touch (their
springs reset to 0)::

    listed, shifts = contacts.update(x, radii, ids=ids)
    history = contacts.carry(history)      # as it was, or moved at a rebuild
    d, D = contacts.separations(x)
    touch = d <= radii[listed[:, 0]] + radii[listed[:, 1]]

The contact law is that of LAMMPS's ``pair_style granular hertz/material E
damping nu tangential mindlin NULL 1.0 mu damping viscoelastic
limit_damping`` (and ``fix wall/gran granular`` with the same coefficients
for the walls), written in numpy from its documentation:

* contact radius ``a = sqrt(R_eff delta)`` for an overlap ``delta``;
* normal force ``4/3 E_eff a delta - eta_n0 m_eff a v_n``, never attractive;
* tangential spring ``xi``: turned into the tangent plane (length kept),
  stretched by ``v_t dt``; force ``-8 G_eff a xi - eta_n0 m_eff a v_t``,
  capped at ``mu`` times the normal force (then the spring is shortened to
  match the cap);
* velocity Verlet with rotation (solid spheres), gravity.

Every ``--sort-every`` steps the grains are re-ordered along the space-filling
order of their cells, as LAMMPS does for memory locality; the contacts still
keep their history because they are matched by the grains' ``ids``.

Run::

    python examples/dem_hertz_mindlin.py                # writes dem_hertz_mindlin.png here
    python examples/dem_hertz_mindlin.py none --n 3000 --steps 2000 --threads 2

It prints progress, the time per step spent in the contact search and the
history gather (min and median over the steps after the first 10), and
writes a PNG of the packing coloured by contact number (``none``: no PNG).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from granularsap import ContactList, ContactSearch, Plane, TriangleMesh, WallSearch

GRAVITY = np.array([0.0, 0.0, -10.0])
R_MIN, R_MAX = 0.5, 1.0       # radii drawn uniformly in [R_MIN, R_MAX]


@dataclass
class Material:
    """Coefficients of ``pair_style granular hertz/material ... tangential mindlin``."""

    young: float = 5.0e5            # E
    poisson: float = 0.3            # nu
    damping: float = 2.0e3          # eta_n0 of viscoelastic damping
    tangential_damping: float = 1.0  # x_gamma_t: eta_t = x_gamma_t * eta_n
    friction: float = 0.5           # mu
    density: float = 1.0

    @property
    def e_eff(self):
        """Effective Young's modulus of two grains (or a grain and a wall) of this material."""
        return self.young / (2.0 * (1.0 - self.poisson ** 2))

    @property
    def g_eff(self):
        """Effective shear modulus, as LAMMPS mixes it for a pair and for a wall."""
        return self.young / (4.0 * (2.0 - self.poisson) * (1.0 + self.poisson))

    def lammps(self):
        """The same model as LAMMPS coefficients (for ``pair_coeff`` and ``fix wall/gran``)."""
        return (f"hertz/material {self.young!r} {self.damping!r} {self.poisson!r} "
                f"tangential mindlin NULL {self.tangential_damping!r} {self.friction!r} "
                "damping viscoelastic limit_damping")


def contact_law(material, dt, normal, overlap, r_eff, m_eff, v_rel, spring):
    """Hertz-Mindlin forces of ``k`` contacts between a body A and a body B.

    ``normal`` (k, 3): unit vectors from A to B; ``overlap`` (k,) >= 0;
    ``v_rel`` (k, 3): velocity of B's contact point relative to A's;
    ``spring`` (k, 3): each contact's tangential spring from the last step
    (zeros for a new contact).  Returns the force on B (k, 3), its tangential
    part (k, 3) and the springs of this step (k, 3).
    """
    a = np.sqrt(r_eff * overlap)                           # contact radius
    v_n = np.einsum("ij,ij->i", v_rel, normal)             # > 0: separating
    eta_n = material.damping * m_eff * a
    f_n = np.maximum(4.0 / 3.0 * material.e_eff * a * overlap - eta_n * v_n, 0.0)
    v_t = v_rel - v_n[:, None] * normal

    # turn the spring into the tangent plane of this step, keeping its length
    length = np.sqrt(np.einsum("ij,ij->i", spring, spring))
    spring = spring - np.einsum("ij,ij->i", spring, normal)[:, None] * normal
    turned = np.sqrt(np.einsum("ij,ij->i", spring, spring))
    spring *= np.divide(length, turned, out=np.zeros_like(length), where=turned > 0)[:, None]
    spring += dt * v_t

    k_t = 8.0 * material.g_eff * a
    eta_t = material.tangential_damping * eta_n
    f_t = -k_t[:, None] * spring - eta_t[:, None] * v_t
    size = np.sqrt(np.einsum("ij,ij->i", f_t, f_t))
    cap = material.friction * f_n
    slip = size > cap                                      # Coulomb: slide, shorten the spring
    f_t[slip] *= (cap[slip] / size[slip])[:, None]
    spring[slip] = -(f_t[slip] + eta_t[slip, None] * v_t[slip]) / k_t[slip, None]
    return f_n[:, None] * normal + f_t, f_t, spring


def tiled_floor(lower, upper, tiles):
    """A flat rectangle at z = 0 from ``lower`` to ``upper`` (x, y), ``tiles`` x ``tiles``
    squares of two triangles each: (vertices (v, 3), faces (f, 3))."""
    xs = np.linspace(lower[0], upper[0], tiles + 1)
    ys = np.linspace(lower[1], upper[1], tiles + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    vertices = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    corner = (np.arange(tiles)[:, None] * (tiles + 1) + np.arange(tiles)[None, :]).ravel()
    a, b, c, d = corner, corner + tiles + 1, corner + tiles + 2, corner + 1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return vertices, faces


def write_stl(path, vertices, faces, name="floor"):
    """Write a triangle mesh as ASCII STL (what CAD tools and meshing libraries read)."""
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    with open(path, "w") as fh:
        fh.write(f"solid {name}\n")
        for nrm, (p, q, r) in zip(normals, tri, strict=True):
            fh.write("facet normal {:.17g} {:.17g} {:.17g}\n outer loop\n".format(*nrm))
            for v in (p, q, r):
                fh.write("  vertex {:.17g} {:.17g} {:.17g}\n".format(*v))
            fh.write(" endloop\nendfacet\n")
        fh.write(f"endsolid {name}\n")


def initial_column(n, seed=0):
    """``n`` grains on a jittered lattice in a square column, falling: positions,
    velocities, radii and the column width."""
    rng = np.random.default_rng(seed)
    radii = rng.uniform(R_MIN, R_MAX, n)
    spacing = 2.1 * R_MAX
    per_row = max(2, int(round((n / 3.0) ** (1.0 / 3.0))))   # a column about 3x taller than wide
    width = per_row * spacing
    k = np.arange(n)
    ix, iy, iz = k % per_row, (k // per_row) % per_row, k // per_row ** 2
    pos = np.stack([ix + 0.5, iy + 0.5, iz + 0.5], axis=1) * spacing
    pos[:, 2] += 0.05 * R_MAX
    pos += rng.uniform(-0.04, 0.04, (n, 3)) * spacing
    vel = rng.normal(0.0, 0.5, (n, 3))
    vel[:, 2] -= 2.0
    return pos, vel, radii, width


class Pour:
    """The state of the pour and one time step of it.

    ``positions``, ``velocities``, ``omegas`` (n, 3), ``radii``, ``ids`` (n,):
    the grains (``ids`` label them whatever their row); ``search`` and
    ``walls``: the ``ContactSearch`` and the ``WallSearch`` (side planes, then
    the floor mesh), both with contact identity.  After each
    :meth:`contact_forces`: ``pairs`` and ``spring`` (the grain contacts and
    their tangential springs, row for row), ``wall_contacts`` and
    ``wall_spring``, and ``search_seconds``, the time of the two searches and
    the two history gathers (``wall_seconds`` of it for the walls).

    With ``neighbor_list=True`` the grains go through ``contacts``, a
    ``ContactList`` (LAMMPS's neighbour list with its skin), whose
    ``history`` holds a spring per listed pair (0 for those not touching);
    ``separation_seconds`` is the time of its separations (the contact law's
    part).
    """

    def __init__(self, positions, velocities, radii, width, floor, *, material=None,
                 dt=5e-4, rebuild_margin=0.2, n_threads=1, ids=None, omegas=None,
                 neighbor_list=False):
        self.material = material or Material()
        self.dt = float(dt)
        self.positions = np.array(positions, dtype=np.float64)
        self.velocities = np.array(velocities, dtype=np.float64)
        self.omegas = np.zeros_like(self.positions) if omegas is None else np.array(omegas)
        self.radii = np.array(radii, dtype=np.float64)
        self.ids = np.arange(len(self.radii)) if ids is None else np.array(ids)
        self.mass = self.material.density * 4.0 / 3.0 * np.pi * self.radii ** 3
        self.width = float(width)
        sides = [Plane(point=[0, 0, 0], normal=[1, 0, 0]),          # x = 0, facing +x
                 Plane(point=[width, 0, 0], normal=[-1, 0, 0]),     # x = width, facing -x
                 Plane(point=[0, 0, 0], normal=[0, 1, 0]),
                 Plane(point=[0, width, 0], normal=[0, -1, 0])]
        self.search = None if neighbor_list else ContactSearch(
            rebuild_margin=rebuild_margin, quantities="PdD", identity=True, n_threads=n_threads)
        self.contacts = (ContactList(rebuild_margin=rebuild_margin, n_threads=n_threads)
                         if neighbor_list else None)
        self.history = np.empty((0, 3))
        self.separation_seconds = 0.0
        self.walls = WallSearch([*sides, floor], identity=True, n_threads=n_threads,
                                rebuild_margin=rebuild_margin)
        self.pairs = np.empty((0, 2), np.int64)
        self.spring = np.empty((0, 3))
        self.wall_spring = np.empty((0, 3))
        self.search_seconds = self.wall_seconds = 0.0
        self.force, self.torque = self.contact_forces()

    def contact_forces(self):
        """Search, carry the springs, and return (force, torque) on every grain (n, 3)."""
        x, v, w, r, m = self.positions, self.velocities, self.omegas, self.radii, self.mass
        t0 = time.perf_counter()
        if self.contacts is None:
            pairs, dist, vec = self.search.update(x, r, ids=self.ids)
            spring = self.search.carry(self.spring)
        else:
            listed, _ = self.contacts.update(x, r, ids=self.ids)
            history = self.contacts.carry(self.history)
        t1 = time.perf_counter()
        c = self.walls.update(x, r, ids=self.ids)
        wall_spring = self.walls.carry(self.wall_spring)
        self.search_seconds = time.perf_counter() - t0
        self.wall_seconds = self.search_seconds - (t1 - t0)
        if self.contacts is not None:
            # the listed pairs that touch are the contacts (as pair granular sees them)
            t2 = time.perf_counter()
            dist, vec = self.contacts.separations(x)
            self.separation_seconds = time.perf_counter() - t2
            touch = dist <= r[listed[:, 0]] + r[listed[:, 1]]
            pairs, dist, vec, spring = listed[touch], dist[touch], vec[touch], history[touch]

        force = m[:, None] * GRAVITY
        torque = np.zeros_like(x)
        # grain-grain: A is the grain with the lower id, B the other, normal from A to B.
        # A spring is a vector from A's side to B's: ordering each contact by ids (not
        # rows) keeps its sign when the grains are re-ordered.
        i, j = pairs[:, 0], pairs[:, 1]
        swap = self.ids[i] > self.ids[j]
        i, j = np.where(swap, j, i), np.where(swap, i, j)
        vec = np.where(swap[:, None], -vec, vec)
        overlap = r[i] + r[j] - dist
        normal = vec / dist[:, None]
        arm_i, arm_j = r[i] - 0.5 * overlap, r[j] - 0.5 * overlap   # centre to contact point
        v_rel = v[j] - v[i] - np.cross(arm_i[:, None] * w[i] + arm_j[:, None] * w[j], normal)
        f, f_t, self.spring = contact_law(self.material, self.dt, normal, overlap,
                                          r[i] * r[j] / (r[i] + r[j]),
                                          m[i] * m[j] / (m[i] + m[j]), v_rel, spring)
        t = np.cross(normal, f_t)
        _add(force, j, f)
        _add(force, i, -f)
        _add(torque, i, -arm_i[:, None] * t)
        _add(torque, j, -arm_j[:, None] * t)
        # grain-wall: A = the wall (at rest), B = the grain, normal from the wall to the grain
        g, arm = c.sphere, c.distance
        v_rel = v[g] - arm[:, None] * np.cross(w[g], c.normal)
        f, f_t, self.wall_spring = contact_law(self.material, self.dt, c.normal, r[g] - arm,
                                               r[g], m[g], v_rel, wall_spring)
        _add(force, g, f)
        _add(torque, g, -arm[:, None] * np.cross(c.normal, f_t))
        self.pairs, self.wall_contacts = pairs, c
        if self.contacts is not None:  # the springs of listed pairs apart are reset
            self.history = np.zeros((len(listed), 3))
            self.history[touch] = self.spring
        return force, torque

    def kick(self):
        """Half a step of velocity Verlet on the velocities and spins."""
        half = 0.5 * self.dt
        self.velocities += half * self.force / self.mass[:, None]
        self.omegas += half * self.torque / (0.4 * self.mass * self.radii ** 2)[:, None]

    def step(self):
        """One time step: kick, drift, contact forces, kick (``fix nve/sphere``)."""
        self.kick()
        self.positions += self.dt * self.velocities
        self.force, self.torque = self.contact_forces()
        self.kick()

    def reorder(self, order):
        """Put the grains in row order ``order``; contacts keep their history (by ``ids``)."""
        for name in ("positions", "velocities", "omegas", "radii", "ids", "mass", "force",
                     "torque"):
            setattr(self, name, getattr(self, name)[order])

    def spatial_order(self):
        """Rows sorted by the cell (of side 2 R_MAX) each grain is in, z then y then x."""
        cell = np.floor(self.positions / (2.0 * R_MAX)).astype(np.int64)
        return np.lexsort((cell[:, 0], cell[:, 1], cell[:, 2]))


def _add(out, rows, values):
    """``out[rows] += values`` with repeated rows summed (np.add.at, but faster)."""
    for k in range(3):
        out[:, k] += np.bincount(rows, weights=values[:, k], minlength=len(out))


def floor_mesh(width, path=None):
    """The floor: a tiled square one grain wider than the column on every side, as STL.

    Writes it to ``path`` (a temporary file when None) and reads it back, as
    one reads a floor from CAD.
    """
    tiles = max(2, int(np.ceil((width + 4 * R_MAX) / (2.0 * R_MAX))))
    vertices, faces = tiled_floor([-2 * R_MAX, -2 * R_MAX], [width + 2 * R_MAX] * 2, tiles)
    if path is None:
        with tempfile.TemporaryDirectory() as folder:
            path = os.path.join(folder, "floor.stl")
            write_stl(path, vertices, faces)
            return TriangleMesh.read(path)
    write_stl(path, vertices, faces)
    return TriangleMesh.read(path)


def plot(path, pour, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle

    pos, radii, width = pour.positions, pour.radii, pour.width
    z = np.bincount(pour.pairs.ravel(), minlength=len(pos))
    fig, (ax, axh) = plt.subplots(1, 2, figsize=(12, 5), gridspec_kw=dict(width_ratios=[1.6, 1]))
    slab = np.abs(pos[:, 1] - 0.5 * width) < 2.0 * R_MAX
    order = np.argsort(pos[slab, 1])
    circles = [Circle((x, zz), rr) for x, zz, rr in
               zip(pos[slab, 0][order], pos[slab, 2][order], radii[slab][order], strict=True)]
    coll = PatchCollection(circles, cmap="viridis", edgecolor="k", linewidth=0.2)
    coll.set_array(z[slab][order])
    coll.set_clim(0, max(int(z.max(initial=0)), 1))
    ax.add_collection(coll)
    ax.set_xlim(0, width)
    ax.set_ylim(0, max(pos[slab, 2].max(initial=0) + R_MAX, 1.0))
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("z")
    ax.set_title(f"{title}: central slab")
    fig.colorbar(coll, ax=ax, label="contact number")
    axh.hist(z, bins=np.arange(z.max(initial=0) + 2) - 0.5, color="tab:blue")
    axh.set_xlabel("contact number")
    axh.set_ylabel("grains")
    axh.set_title(f"mean contact number {z.mean():.2f}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", nargs="?", default="dem_hertz_mindlin.png",
                        help="PNG to write, or 'none'")
    parser.add_argument("--n", type=int, default=2000, help="number of grains")
    parser.add_argument("--steps", type=int, default=2000, help="time steps")
    parser.add_argument("--threads", type=int, default=1, help="numba threads of the searches")
    parser.add_argument("--dt", type=float, default=5e-4, help="time step")
    parser.add_argument("--rebuild-margin", type=float, default=0.2,
                        help="Verlet margin of the grain search (LAMMPS's neighbor skin)")
    parser.add_argument("--neighbor-list", action="store_true",
                        help="grains through a ContactList (LAMMPS's neighbour list: history "
                             "moved at its rebuilds only) instead of a ContactSearch")
    parser.add_argument("--sort-every", type=int, default=500,
                        help="re-order the grains spatially every this many steps (0: never)")
    parser.add_argument("--floor", default=None,
                        help="STL file to write the floor to (default: a temporary file)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.n < 1 or args.steps < 1:
        parser.error("--n and --steps must be at least 1")

    pos, vel, radii, width = initial_column(args.n, args.seed)
    pour = Pour(pos, vel, radii, width, floor_mesh(width, args.floor), dt=args.dt,
                rebuild_margin=args.rebuild_margin, n_threads=args.threads,
                neighbor_list=args.neighbor_list)
    print(f"{args.n} grains, radii {R_MIN}-{R_MAX}, column {width:.1f} wide, dt {args.dt:g}, "
          f"{args.steps} steps, {args.threads} thread(s)")
    cost = []
    t0 = time.perf_counter()
    for step in range(1, args.steps + 1):
        if args.sort_every and step % args.sort_every == 0:
            pour.reorder(pour.spatial_order())
        pour.step()
        cost.append(pour.search_seconds)
        if step % 200 == 0 or step == args.steps:
            ke = 0.5 * np.sum(pour.mass * np.einsum("ij,ij->i", pour.velocities,
                                                    pour.velocities))
            sliding = np.sqrt(np.einsum("ij,ij->i", pour.spring, pour.spring))
            print(f"step {step:5d}  contacts {len(pour.pairs):6d} + {len(pour.wall_spring):4d} "
                  f"on walls  longest spring {sliding.max(initial=0):.2e}  "
                  f"kinetic energy {ke:9.2f}  "
                  f"{1e3 * (time.perf_counter() - t0) / step:6.2f} ms/step, search + history "
                  f"{1e3 * np.mean(cost):.3f} ms", flush=True)
    steady = np.array(cost[10:] or cost)
    print(f"search + history per step (steps after the first 10): min "
          f"{1e3 * steady.min():.3f} ms, median {1e3 * np.median(steady):.3f} ms, "
          f"mean {1e3 * steady.mean():.3f} ms")
    if args.output.lower() != "none":
        plot(args.output, pour, f"{args.n} grains after {args.steps} steps")
        print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
