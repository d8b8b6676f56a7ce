"""Pour polydisperse spheres into a box: a small DEM in plain numpy.

Every time step asks granularsap's ``ContactSearch`` for the exact contacts
(``d <= r_i + r_j``) with their distances and separation vectors.  The search
is kept across steps with a Verlet ``rebuild_margin``: it rebuilds its list only
when some sphere has moved more than half the margin, and otherwise re-tests
the kept candidates, so a step costs little more than the contacts themselves.  Contacts are linear
spring-dashpots (normal) with a Coulomb-capped viscous tangential force; the
spheres do not rotate, which keeps the script short.

Run::

    python examples/dem_pour.py                 # writes dem_pour.png here
    python examples/dem_pour.py out.png --n 3000 --steps 2500

Prints progress and writes a PNG of the final packing (a side view of a
central slab and the distribution of contact numbers), coloured by each
sphere's contact number.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import granularsap

# ---------------------------------------------------------------- parameters
GRAVITY = np.array([0.0, 0.0, -10.0])
DENSITY = 1.0
K_NORMAL = 3.0e3          # spring stiffness (force / length)
RESTITUTION = 0.4         # normal coefficient of restitution
MU = 0.5                  # Coulomb friction coefficient (tangential cap)
R_MIN, R_MAX = 0.4, 1.0   # radii drawn log-uniformly in [R_MIN, R_MAX]


def damping_coefficient(mass_eff):
    """Linear dashpot giving the requested restitution for a pair of mass ``mass_eff``."""
    ln_e = np.log(RESTITUTION)
    return -2.0 * ln_e * np.sqrt(mass_eff * K_NORMAL) / np.sqrt(np.pi ** 2 + ln_e ** 2)


def initial_column(n, width, rng):
    """Spheres on a jittered lattice above the box floor, no overlaps."""
    radii = np.exp(rng.uniform(np.log(R_MIN), np.log(R_MAX), n))
    spacing = 2.0 * R_MAX * 1.05
    per_row = int(width // spacing)
    idx = np.arange(n)
    ix, iy, iz = idx % per_row, (idx // per_row) % per_row, idx // per_row ** 2
    pos = np.stack([(ix + 0.5) * spacing, (iy + 0.5) * spacing, (iz + 0.5) * spacing + R_MAX],
                   axis=1)
    pos[:, :2] += rng.uniform(-0.02, 0.02, (n, 2)) * spacing
    vel = rng.normal(0.0, 0.2, (n, 3))
    vel[:, 2] -= 2.0  # poured: already moving down
    return pos, vel, radii


def pair_forces(pos, vel, radii, mass, pairs, dist, dx):
    """Spring-dashpot forces of the contacts ``pairs`` (distances ``dist``,
    vectors ``dx`` from ``i`` to ``j``); returns (forces, contact pairs)."""
    i, j = pairs[:, 0], pairs[:, 1]
    overlap = radii[i] + radii[j] - dist
    normal = dx / np.maximum(dist, 1e-12)[:, None]
    v_rel = vel[j] - vel[i]
    v_n = np.einsum("ij,ij->i", v_rel, normal)
    m_eff = mass[i] * mass[j] / (mass[i] + mass[j])
    gamma = damping_coefficient(m_eff)
    f_n = np.maximum(K_NORMAL * overlap - gamma * v_n, 0.0)  # no attraction
    v_t = v_rel - v_n[:, None] * normal
    speed_t = np.sqrt(np.einsum("ij,ij->i", v_t, v_t))
    f_t_mag = np.minimum(0.5 * gamma * speed_t, MU * f_n)
    f_t = v_t * (f_t_mag / np.maximum(speed_t, 1e-12))[:, None]
    f_on_j = f_n[:, None] * normal - f_t
    forces = np.zeros_like(pos)
    np.add.at(forces, j, f_on_j)
    np.add.at(forces, i, -f_on_j)
    return forces, np.stack([i, j], axis=1)


def wall_forces(pos, vel, radii, mass, width):
    """Floor z = 0 and side walls x, y in [0, width], same contact law."""
    forces = np.zeros_like(pos)
    gamma = damping_coefficient(mass)
    for axis, plane, sign in ((2, 0.0, 1.0), (0, 0.0, 1.0), (0, width, -1.0),
                              (1, 0.0, 1.0), (1, width, -1.0)):
        overlap = radii - sign * (pos[:, axis] - plane)
        hit = overlap > 0
        if hit.any():
            v_n = sign * vel[hit, axis]
            forces[hit, axis] += sign * np.maximum(K_NORMAL * overlap[hit] - gamma[hit] * v_n,
                                                   0.0)
    return forces


def plot(path, pos, radii, contacts, width, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle

    z = np.bincount(contacts.ravel(), minlength=len(pos))
    fig, (ax, axh) = plt.subplots(1, 2, figsize=(13, 4.2),
                                  gridspec_kw=dict(width_ratios=[2.4, 1]))
    slab = np.abs(pos[:, 1] - 0.5 * width) < 2.0 * R_MAX
    order = np.argsort(pos[slab, 1])  # draw back to front
    circles = [Circle((x, zz), r) for x, zz, r in
               zip(pos[slab, 0][order], pos[slab, 2][order], radii[slab][order], strict=True)]
    coll = PatchCollection(circles, cmap="viridis", edgecolor="k", linewidth=0.2)
    coll.set_array(z[slab][order])
    coll.set_clim(0, max(int(z.max()), 1))
    ax.add_collection(coll)
    ax.set_xlim(0, width)
    ax.set_ylim(0, max(pos[:, 2].max() + R_MAX, 1.0))
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("z")
    ax.set_title(f"{title}: side view of the central slab")
    fig.colorbar(coll, ax=ax, label="contact number")
    axh.hist(z, bins=np.arange(z.max() + 2) - 0.5, color="tab:blue")
    axh.set_xlabel("contact number")
    axh.set_ylabel("spheres")
    axh.set_title(f"mean contact number {z.mean():.2f}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", nargs="?", default="dem_pour.png", help="PNG to write")
    parser.add_argument("--n", type=int, default=2000, help="number of spheres")
    parser.add_argument("--steps", type=int, default=2000, help="time steps")
    parser.add_argument("--width", type=float, default=30.0, help="box width")
    parser.add_argument("--seed", type=int, default=0)
    # a few thousand spheres: one thread is fastest (thread start-up per step costs more
    # than it saves); use more threads for systems of 1e5 spheres and up
    parser.add_argument("--threads", type=int, default=1, help="numba threads")
    args = parser.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    pos, vel, radii = initial_column(args.n, args.width, rng)
    mass = DENSITY * 4.0 / 3.0 * np.pi * radii ** 3
    dt = np.pi * np.sqrt(0.5 * mass.min() / K_NORMAL) / 12.0  # 1/12 of a contact time
    # Verlet margin half the smallest radius: a sphere may move R_MIN / 4 before
    # the candidate list is rebuilt
    search = granularsap.ContactSearch(rebuild_margin=0.5 * R_MIN, quantities="PdD",
                                       n_threads=args.threads)
    print(f"{args.n} spheres, radii {R_MIN}-{R_MAX}, dt = {dt:.2e}, {args.steps} steps")

    t0 = time.perf_counter()
    t_search = 0.0
    rebuilds = 0
    contacts = np.empty((0, 2), np.int64)
    for step in range(1, args.steps + 1):
        ts = time.perf_counter()
        pairs, dist, dx = search.update(pos, radii)
        t_search += time.perf_counter() - ts
        rebuilds += search.stats["rebuilt"]
        forces, contacts = pair_forces(pos, vel, radii, mass, pairs, dist, dx)
        forces += wall_forces(pos, vel, radii, mass, args.width)
        vel += dt * (forces / mass[:, None] + GRAVITY)
        pos += dt * vel
        if step % 200 == 0 or step == args.steps:
            ke = 0.5 * np.sum(mass * np.einsum("ij,ij->i", vel, vel))
            print(f"step {step:5d}  t = {step * dt:6.3f}  contacts {len(contacts):6d}  "
                  f"rebuilds {rebuilds:5d}  kinetic energy {ke:10.3f}  "
                  f"top {pos[:, 2].max():6.2f}  "
                  f"{1e3 * (time.perf_counter() - t0) / step:5.1f} ms/step "
                  f"({1e3 * t_search / step:4.2f} in ContactSearch)", flush=True)

    # final contact list with the exact narrow phase of granularsap
    contacts, dist = granularsap.sphere_contacts(pos, radii, return_distances=True)
    z = np.bincount(contacts.ravel(), minlength=args.n)
    overlap = radii[contacts[:, 0]] + radii[contacts[:, 1]] - dist
    print(f"final: {len(contacts)} contacts, mean contact number {z.mean():.2f}, "
          f"largest overlap {overlap.max(initial=0.0) / R_MIN:.1%} of the smallest radius")
    plot(args.output, pos, radii, contacts, args.width, "poured spheres")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
