"""Sphere contacts, neighbour pairs and rigid clumps (work in progress)."""


def sphere_contacts(positions, radii, *, skin=0.0, box=None, n_threads=None,
                    return_distances=False):
    raise NotImplementedError


def neighbor_pairs(positions, cutoff, *, box=None, n_threads=None, return_distances=True):
    raise NotImplementedError


def clump_contacts(positions, radii, clump_ids, *, skin=0.0, box=None, n_threads=None):
    raise NotImplementedError
