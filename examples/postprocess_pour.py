"""Post-process the bundled LAMMPS granular pour: coordination number per frame.

Reads ``data/pour.dump`` (2000 polydisperse spheres poured into a box, written
by LAMMPS), finds every frame's sphere contacts (``d <= r_i + r_j + skin``,
radii from the dump's ``radius`` column) with granularsap, stores them in an
HDF5 file, then reads that file back with plain h5py to compute

* the mean coordination number Z (contacts per particle) of every frame, and
* the histogram of per-particle contact numbers in the last (settled) frame,
  split by particle size,

and draws both in one PNG.  The same HDF5 file can be summarised with
``granularsap info pour_contacts.h5``.

Run::

    python examples/postprocess_pour.py     # writes pour_contacts.h5, pour_coordination.png
    python examples/postprocess_pour.py --skin 0.01 --workers 2
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_DUMP = os.path.join(HERE, os.pardir, "data", "pour.dump")


def compute(dump, out, skin, workers):
    from granularsap.io import ContactParams, compute_contacts

    t0 = time.perf_counter()
    summary = compute_contacts(dump, out, ContactParams(skin=skin), overwrite=True,
                               resume=False, workers=workers)
    t = summary["timing"]
    print(f"{summary['frames']} frames in {time.perf_counter() - t0:.2f} s "
          f"(read {t['read']:.2f} s, contacts {t['compute']:.2f} s, write {t['write']:.2f} s)")


def coordination(out, dump):
    """Per-frame mean Z, and per-particle contact numbers + radii of the last frame."""
    import h5py

    from granularsap.io import iter_frames

    with h5py.File(out, "r") as f:  # plain h5py: the schema is documented in README.md
        assert f.attrs["complete"] == 1
        steps = f["frames/step"][:]
        n_particles = f["frames/n_particles"][:]
        offsets = f["frames/contact_offset"][:]
        z_mean = 2.0 * np.diff(offsets) / n_particles
        last = f["contacts/pairs"][offsets[-2]:offsets[-1]]  # particle ids
    frame = list(iter_frames(dump))[-1]
    rows = np.searchsorted(frame.ids, last)       # ids -> rows (frames are in id order)
    z = np.bincount(rows.ravel(), minlength=frame.n_particles)
    return steps, z_mean, z, frame.radius


def plot(steps, z_mean, z, radius, png):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.plot(steps, z_mean, marker="o")
    ax1.set_xlabel("timestep")
    ax1.set_ylabel("mean coordination number Z")
    ax1.set_title("granular pour: contacts per particle")
    bins = np.arange(z.max() + 2) - 0.5
    for r in np.unique(radius):
        sel = radius == r
        ax2.hist(z[sel], bins=bins, alpha=0.6, label=f"radius {r:g} (n={sel.sum()})")
    ax2.set_xlabel("contacts of a particle (last frame)")
    ax2.set_ylabel("particles")
    ax2.set_title(f"step {steps[-1]}: Z = {z.mean():.2f}")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dump", default=DEFAULT_DUMP, help="LAMMPS dump (default data/pour.dump)")
    parser.add_argument("--out", default="pour_contacts.h5", help="HDF5 contacts file")
    parser.add_argument("--png", default="pour_coordination.png", help="plot to write")
    parser.add_argument("--skin", type=float, default=0.0,
                        help="count pairs with d <= r_i + r_j + skin (default 0)")
    parser.add_argument("--workers", type=int, default=None,
                        help="distribute frames over a local Dask cluster of N processes")
    args = parser.parse_args(argv)
    if not os.path.exists(args.dump):
        raise SystemExit(f"{args.dump} not found; make it with "
                         "`python -m lammps_bridge.generate pour --outdir data`")
    compute(args.dump, args.out, args.skin, args.workers)
    steps, z_mean, z, radius = coordination(args.out, args.dump)
    for s, zm in zip(steps, z_mean, strict=True):
        print(f"step {s:6d}  Z = {zm:.3f}")
    for r in np.unique(radius):
        print(f"radius {r:g}: mean contacts {z[radius == r].mean():.2f} in the last frame")
    plot(steps, z_mean, z, radius, args.png)
    print(f"wrote {args.out} and {args.png}")


if __name__ == "__main__":
    main()
