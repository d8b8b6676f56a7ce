"""MDAnalysis's own distance arithmetic, to decide pairs at the cutoff as it does.

MDAnalysis computes from float32 coordinates, and each of its capped-distance
methods wraps coordinates and takes the minimum image in its own way, so the
methods disagree with each other about pairs within float32 rounding of the
cutoff.  The drop-ins in ``granularsap.mda`` find candidates with a slightly
wider cutoff and then decide every candidate with the arithmetic of the method
MDAnalysis would use (``method=None`` chooses like MDAnalysis does):

* ``bruteforce`` (``distance_array`` / ``self_distance_array``): float32
  differences; orthorhombic minimum image ``box * (s - round(s))`` with
  ``s = inverse_box * dx`` and a float32 inverse box; triclinic: coordinates
  wrapped by ``_triclinic_pbc`` (``apply_PBC``), then the 27-image search.
* ``nsgrid``: coordinates wrapped by ``apply_PBC``; float32 differences;
  orthorhombic "lazy" image (one box shift past half a box), triclinic
  27-image search; ``d**2 <= cutoff**2`` with the cutoff and its square in
  float32.
* ``pkdtree`` decides inside scipy's KD-tree; candidates keep granularsap's
  float64 minimum-image decision.

These are ports of MDAnalysis's ``calc_distances.h`` and ``nsgrid.pyx``
written with numpy; they need MDAnalysis only for ``apply_PBC`` and
``triclinic_vectors``.
"""

from __future__ import annotations

import numpy as np

#: Relative widening of the candidate search (float32 rounding is ~6e-8).
WIDEN = 1e-5


def _c_round(s):
    """C ``round``: halves away from zero (numpy rounds halves to even)."""
    r = np.trunc(s)
    frac = s - r
    return r + np.where(np.abs(frac) >= 0.5, np.sign(s), 0.0)


def _tri_min_image(dx, box9):
    """``minimum_image_triclinic`` of calc_distances.h, vectorised (double)."""
    b = box9.astype(np.float64)
    best = np.full(len(dx), np.finfo(np.float32).max, dtype=np.float64)
    out = np.zeros_like(dx)
    for ix in (-1, 0, 1):
        rx = dx[:, 0] + b[0] * ix
        for iy in (-1, 0, 1):
            ry0 = rx + b[3] * iy
            ry1 = dx[:, 1] + b[4] * iy
            for iz in (-1, 0, 1):
                rz0 = ry0 + b[6] * iz
                rz1 = ry1 + b[7] * iz
                rz2 = dx[:, 2] + b[8] * iz
                dsq = rz0 * rz0 + rz1 * rz1 + rz2 * rz2
                take = dsq < best
                best = np.where(take, dsq, best)
                out[take, 0] = rz0[take]
                out[take, 1] = rz1[take]
                out[take, 2] = rz2[take]
    return out


def _box_kind(box32):
    from MDAnalysis.lib.mdamath import triclinic_vectors

    if np.all(box32[3:] == 90.0):
        return "ortho", box32[:3].astype(np.float32)
    return "tri", triclinic_vectors(box32).astype(np.float32).ravel()


def choose_method(n_ref, n_conf, max_cutoff, box32, coords, method):
    """The method MDAnalysis's ``_determine_method(_self)`` would pick."""
    if method is not None:
        return str(method).lower()
    if n_conf is None:
        if n_ref < 100:
            return "bruteforce"
    else:
        if n_ref < 10 or n_conf < 10:
            return "bruteforce"
        if n_ref * n_conf >= 1e8:
            return "nsgrid"
    if box32 is None:
        size = coords.max(axis=0) - coords.min(axis=0)
    elif np.all(box32[3:] == 90.0):
        size = box32[:3]
    else:
        from MDAnalysis.lib.mdamath import triclinic_vectors

        tribox = triclinic_vectors(box32)
        size = tribox.max(axis=0) - tribox.min(axis=0)
    if n_conf is None:
        return "pkdtree" if max_cutoff < 0.03 * size.min() else "nsgrid"
    return "bruteforce" if np.any(max_cutoff > 0.3 * size) else "nsgrid"


def decide(ref32, conf32, a, b, box32, max_cutoff, method):
    """Distances (float64) and a keep-mask for candidates ``(ref[a], conf[b])``
    under MDAnalysis method ``method``; ``None`` if the method is not emulated."""
    if method not in ("bruteforce", "nsgrid"):
        return None
    if box32 is None:
        p = ref32[a]
        q = conf32[b]
        if method == "nsgrid":
            # _nsgrid_capped(_self) shift the coordinates into a pseudo-box first
            if conf32 is ref32:
                lmin = ref32.min(axis=0)
                boxsize = (ref32.max(axis=0) - lmin).max()
                shift = lmin - 0.1 * boxsize
            else:
                shift = np.concatenate([ref32, conf32]).min(axis=0) - 0.1 * max_cutoff
            p = p - shift
            q = q - shift
        dx = (q - p).astype(np.float64)
        d2 = (dx[:, 0] * dx[:, 0]) + (dx[:, 1] * dx[:, 1]) + (dx[:, 2] * dx[:, 2])
        if method == "nsgrid":
            c = np.float32(max_cutoff)
            return np.sqrt(d2), d2 <= np.float64(c * c)
        d = np.sqrt(d2)
        return d, d <= max_cutoff
    from MDAnalysis.lib.distances import apply_PBC

    kind, bx = _box_kind(box32)
    if method == "nsgrid" or kind == "tri":
        # wrapping is per coordinate: wrap each set once, then pick candidates
        same = conf32 is ref32
        ref32 = apply_PBC(ref32, box32).astype(np.float32)
        conf32 = ref32 if same else apply_PBC(conf32, box32).astype(np.float32)
    p = ref32[a]
    q = conf32[b]
    dx = (q - p).astype(np.float64)
    if kind == "tri":
        dx = _tri_min_image(dx, bx)
    elif method == "nsgrid":
        half = (np.float32(0.5) * bx).astype(np.float64)
        box64 = bx.astype(np.float64)
        dx = np.where(dx > half, dx - box64, np.where(dx <= -half, dx + box64, dx))
    else:
        inv = (1.0 / bx.astype(np.float64)).astype(np.float32).astype(np.float64)
        s = inv * dx
        dx = bx.astype(np.float64) * (s - _c_round(s))
    d2 = (dx[:, 0] * dx[:, 0]) + (dx[:, 1] * dx[:, 1]) + (dx[:, 2] * dx[:, 2])
    if method == "nsgrid":
        c = np.float32(max_cutoff)
        return np.sqrt(d2), d2 <= np.float64(c * c)
    d = np.sqrt(d2)
    return d, d <= max_cutoff
