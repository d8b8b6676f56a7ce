"""Compare granularsap with one other neighbour search on your own kind of input.

Polydisperse spheres in a periodic cube: granularsap.sphere_contacts against
scipy's cKDTree, which takes one radius, so it is asked for twice the largest
particle radius and its candidates are filtered with d <= r_i + r_j (that
filter is part of its time, because its users have to run it too).

    python examples/benchmark_neighbours.py            # N = 20000
    python examples/benchmark_neighbours.py -n 100000

For every peer, every workload, memory, JSON and plots use the command:

    granularsap bench granular-polydisperse md-liquid --json bench.json --plot bench.png
"""

import argparse
import time

import numpy as np
from scipy.spatial import cKDTree

import granularsap


def median_seconds(fn, repeats=5):
    fn()  # warm-up: numba compiles (or loads its cache) on the first call
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def scipy_contacts(positions, radii, length):
    tree = cKDTree(positions, boxsize=length)
    pairs = tree.query_pairs(2.0 * radii.max(), output_type="ndarray")
    delta = positions[pairs[:, 1]] - positions[pairs[:, 0]]
    delta -= length * np.round(delta / length)  # minimum image
    d = np.sqrt(np.einsum("ij,ij->i", delta, delta))
    return pairs[d <= radii[pairs[:, 0]] + radii[pairs[:, 1]]]


def as_set(pairs):
    return {(int(i), int(j)) for i, j in np.sort(pairs, axis=1)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-n", type=int, default=20_000, help="number of spheres")
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    radii = np.clip(rng.lognormal(0.0, 0.6, args.n), 0.3, 3.0)  # a 1:10 size ratio
    length = (np.sum(4 / 3 * np.pi * radii**3) / 0.3) ** (1 / 3)  # volume fraction 0.3
    positions = rng.random((args.n, 3)) * length
    box = [length, length, length, 90.0, 90.0, 90.0]

    ours = granularsap.sphere_contacts(positions, radii, box=box)
    theirs = scipy_contacts(positions, radii, length)
    if as_set(ours) != as_set(theirs):  # always check before comparing times
        raise SystemExit(f"DISAGREEMENT: granularsap {len(ours)} pairs, scipy {len(theirs)}")

    t_ours = median_seconds(lambda: granularsap.sphere_contacts(positions, radii, box=box))
    t_theirs = median_seconds(lambda: scipy_contacts(positions, radii, length))
    print(f"N = {args.n}, {len(ours)} contacts (both agree)")
    print(f"granularsap.sphere_contacts  {t_ours:.4f} s")
    print(f"scipy cKDTree + filter       {t_theirs:.4f} s   ratio {t_theirs / t_ours:.2f}")


if __name__ == "__main__":
    main()
