"""Pour rigid clumps (multi-sphere bodies) into a box: a small DEM in plain numpy.

Each body is a rigid clump of 2-4 overlapping spheres (dimers, bent trimers,
tetrahedra).  Every time step ``granularsap.clump_contacts`` finds the sphere
pairs between *different* clumps: its broad phase runs on one axis-aligned box
per clump, so the spheres of one body are never tested against each other.
Contact forces are linear spring-dashpots (normal) with a Coulomb-capped
viscous tangential force, applied at the contact point, so clumps translate
and rotate (isotropic moment of inertia, a simplification).

Run::

    python examples/dem_clumps.py                   # writes dem_clumps.png here
    python examples/dem_clumps.py out.png --clumps 800 --steps 2000

Prints progress and writes a PNG of the final packing coloured by each
clump's contact number (number of clumps it touches).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import granularsap

GRAVITY = np.array([0.0, 0.0, -10.0])
DENSITY = 1.0
K_NORMAL = 3.0e3
RESTITUTION = 0.4
MU = 0.5
R_SPHERE = (0.45, 0.75)   # sphere radii within a clump

SHAPES = {  # body-frame sphere centres in units of the sphere radius
    "dimer": np.array([[-0.6, 0, 0], [0.6, 0, 0]]),
    "trimer": np.array([[-0.9, -0.3, 0], [0.0, 0.35, 0], [0.9, -0.3, 0]]),
    "tetra": np.array([[0.6, 0.6, 0.6], [-0.6, -0.6, 0.6], [-0.6, 0.6, -0.6],
                       [0.6, -0.6, -0.6]]) / np.sqrt(2),
}


def damping_coefficient(mass_eff):
    ln_e = np.log(RESTITUTION)
    return -2.0 * ln_e * np.sqrt(mass_eff * K_NORMAL) / np.sqrt(np.pi ** 2 + ln_e ** 2)


def random_rotations(n, rng):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def rotate(rot, omega, dt):
    """Advance rotation matrices by angular velocities (world frame), Rodrigues formula."""
    theta = np.linalg.norm(omega, axis=1) * dt
    axis = omega / np.maximum(np.linalg.norm(omega, axis=1), 1e-300)[:, None]
    kx = np.zeros((len(omega), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2] = -axis[:, 2], axis[:, 1]
    kx[:, 1, 0], kx[:, 1, 2] = axis[:, 2], -axis[:, 0]
    kx[:, 2, 0], kx[:, 2, 1] = -axis[:, 1], axis[:, 0]
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    step = np.eye(3) + s * kx + (1 - c) * kx @ kx
    return step @ rot


def build_clumps(n_clumps, width, rng):
    """Clumps on a jittered lattice above the floor; returns body data and sphere data."""
    names = rng.choice(list(SHAPES), n_clumps)
    scale = rng.uniform(*R_SPHERE, n_clumps)
    body_offsets, sphere_radii, owner = [], [], []
    for c, (name, r) in enumerate(zip(names, scale, strict=True)):
        offs = SHAPES[name] * r
        offs = offs - offs.mean(axis=0)
        body_offsets.append(offs)
        sphere_radii.append(np.full(len(offs), r))
        owner.append(np.full(len(offs), c))
    body_offsets = np.concatenate(body_offsets)
    radii = np.concatenate(sphere_radii)
    owner = np.concatenate(owner)
    mass_s = DENSITY * 4.0 / 3.0 * np.pi * radii ** 3  # overlaps ignored: a demo
    mass = np.bincount(owner, mass_s)
    inertia = np.bincount(owner, mass_s * (0.4 * radii ** 2 +
                                           (2.0 / 3.0) * np.sum(body_offsets ** 2, axis=1)))
    spacing = 2.0 * (R_SPHERE[1] * 1.95) * 1.05  # largest clump fits in its lattice cell
    per_row = int(width // spacing)
    idx = np.arange(n_clumps)
    ix, iy, iz = idx % per_row, (idx // per_row) % per_row, idx // per_row ** 2
    com = np.stack([(ix + 0.5) * spacing, (iy + 0.5) * spacing, (iz + 0.5) * spacing + 1.0],
                   axis=1)
    vel = rng.normal(0.0, 0.2, (n_clumps, 3))
    vel[:, 2] -= 2.0
    omega = rng.normal(0.0, 1.0, (n_clumps, 3))
    rot = random_rotations(n_clumps, rng)
    return dict(com=com, vel=vel, omega=omega, rot=rot, mass=mass, inertia=inertia,
                offsets=body_offsets, radii=radii, owner=owner)


def sphere_state(s):
    arm = np.einsum("nij,nj->ni", s["rot"][s["owner"]], s["offsets"])
    pos = s["com"][s["owner"]] + arm
    vel = s["vel"][s["owner"]] + np.cross(s["omega"][s["owner"]], arm)
    return pos, vel, arm


def forces_and_torques(s, pos, vel, arm, pairs, width):
    radii, owner = s["radii"], s["owner"]
    n_c = len(s["com"])
    f_sphere = np.zeros_like(pos)
    i, j = pairs[:, 0], pairs[:, 1]
    dx = pos[j] - pos[i]
    dist = np.sqrt(np.einsum("ij,ij->i", dx, dx))
    overlap = radii[i] + radii[j] - dist
    normal = dx / np.maximum(dist, 1e-12)[:, None]
    v_rel = vel[j] - vel[i]
    v_n = np.einsum("ij,ij->i", v_rel, normal)
    m_i, m_j = s["mass"][owner[i]], s["mass"][owner[j]]
    gamma = damping_coefficient(m_i * m_j / (m_i + m_j))
    f_n = np.maximum(K_NORMAL * overlap - gamma * v_n, 0.0)
    v_t = v_rel - v_n[:, None] * normal
    speed_t = np.sqrt(np.einsum("ij,ij->i", v_t, v_t))
    f_t = v_t * (np.minimum(0.5 * gamma * speed_t, MU * f_n) / np.maximum(speed_t, 1e-12))[:,
                                                                                          None]
    f_on_j = f_n[:, None] * normal - f_t
    np.add.at(f_sphere, j, f_on_j)
    np.add.at(f_sphere, i, -f_on_j)
    # walls: floor z = 0 and sides x, y in [0, width]
    gamma_w = damping_coefficient(s["mass"][owner])
    for axis, plane, sign in ((2, 0.0, 1.0), (0, 0.0, 1.0), (0, width, -1.0),
                              (1, 0.0, 1.0), (1, width, -1.0)):
        ov = radii - sign * (pos[:, axis] - plane)
        hit = ov > 0
        if hit.any():
            f_sphere[hit, axis] += sign * np.maximum(
                K_NORMAL * ov[hit] - gamma_w[hit] * sign * vel[hit, axis], 0.0)
    force = np.zeros((n_c, 3))
    torque = np.zeros((n_c, 3))
    np.add.at(force, owner, f_sphere)
    np.add.at(torque, owner, np.cross(arm, f_sphere))
    return force, torque


def plot(path, pos, radii, owner, clump_pairs, width):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle

    n_c = owner.max() + 1
    z_clump = np.bincount(clump_pairs.ravel(), minlength=n_c)
    z = z_clump[owner]
    fig, (ax, axh) = plt.subplots(1, 2, figsize=(13, 4.2), gridspec_kw=dict(width_ratios=[2.4, 1]))
    slab = np.abs(pos[:, 1] - 0.5 * width) < 2.0
    order = np.argsort(pos[slab, 1])
    circles = [Circle((x, zz), r) for x, zz, r in
               zip(pos[slab, 0][order], pos[slab, 2][order], radii[slab][order], strict=True)]
    coll = PatchCollection(circles, cmap="plasma", edgecolor="k", linewidth=0.2)
    coll.set_array(z[slab][order])
    coll.set_clim(0, max(int(z_clump.max()), 1))
    ax.add_collection(coll)
    ax.set_xlim(0, width)
    ax.set_ylim(0, max(pos[:, 2].max() + 1.0, 1.0))
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("z")
    ax.set_title("rigid clumps: side view of the central slab")
    fig.colorbar(coll, ax=ax, label="clump contact number")
    axh.hist(z_clump, bins=np.arange(z_clump.max() + 2) - 0.5, color="tab:orange")
    axh.set_xlabel("clumps touched")
    axh.set_ylabel("clumps")
    axh.set_title(f"mean clump contact number {z_clump.mean():.2f}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", nargs="?", default="dem_clumps.png", help="PNG to write")
    parser.add_argument("--clumps", type=int, default=700, help="number of rigid bodies")
    parser.add_argument("--steps", type=int, default=2000, help="time steps")
    parser.add_argument("--width", type=float, default=30.0, help="box width")
    parser.add_argument("--seed", type=int, default=0)
    # a few thousand spheres: one thread is fastest (thread start-up per step costs more
    # than it saves); use more threads for systems of 1e5 spheres and up
    parser.add_argument("--threads", type=int, default=1, help="numba threads")
    args = parser.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    s = build_clumps(args.clumps, args.width, rng)
    m_min = DENSITY * 4.0 / 3.0 * np.pi * R_SPHERE[0] ** 3
    dt = np.pi * np.sqrt(0.5 * m_min / K_NORMAL) / 12.0
    print(f"{args.clumps} clumps, {len(s['radii'])} spheres, dt = {dt:.2e}, "
          f"{args.steps} steps")
    t0 = time.perf_counter()
    t_search = 0.0
    for step in range(1, args.steps + 1):
        pos, vel, arm = sphere_state(s)
        ts = time.perf_counter()
        pairs, clump_pairs = granularsap.clump_contacts(pos, s["radii"], s["owner"],
                                                        n_threads=args.threads)
        t_search += time.perf_counter() - ts
        force, torque = forces_and_torques(s, pos, vel, arm, pairs, args.width)
        s["vel"] += dt * (force / s["mass"][:, None] + GRAVITY)
        s["omega"] += dt * torque / s["inertia"][:, None]
        s["com"] += dt * s["vel"]
        s["rot"] = rotate(s["rot"], s["omega"], dt)
        if step % 250 == 0 or step == args.steps:
            ke = 0.5 * np.sum(s["mass"] * np.einsum("ij,ij->i", s["vel"], s["vel"]))
            print(f"step {step:5d}  t = {step * dt:6.3f}  sphere contacts {len(pairs):6d}  "
                  f"clump contacts {len(clump_pairs):6d}  kinetic energy {ke:10.3f}  "
                  f"{1e3 * (time.perf_counter() - t0) / step:5.1f} ms/step "
                  f"({1e3 * t_search / step:4.1f} in clump_contacts)", flush=True)

    pos, _, _ = sphere_state(s)
    pairs, clump_pairs = granularsap.clump_contacts(pos, s["radii"], s["owner"])
    assert np.all(s["owner"][pairs[:, 0]] != s["owner"][pairs[:, 1]])  # no intra-clump pairs
    z = np.bincount(clump_pairs.ravel(), minlength=args.clumps)
    print(f"final: {len(pairs)} sphere contacts between {len(clump_pairs)} clump pairs, "
          f"mean clump contact number {z.mean():.2f}")
    plot(args.output, pos, s["radii"], s["owner"], clump_pairs, args.width)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
