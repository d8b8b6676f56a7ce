"""Exact closest point of a triangle to a point, for sphere-wall contacts.

The narrow phase of :class:`granularsap.WallSearch`: for every candidate
(sphere, triangle) pair of the broad phase, the point of the triangle closest
to the sphere's centre, its distance and the Voronoi region of the triangle
it lies in (face, one of three edges, one of three vertices).

The closest point follows Ericson, *Real-Time Collision Detection* (2005),
section 5.1.5, ``ClosestPtPointTriangle``: the regions are tested in the order
vertex A, vertex B, edge AB, vertex C, edge AC, edge BC, face, with
barycentric quantities built from six dot products, so every test is a
sign test on exact-order float64 expressions and the closest point lies on
the feature the region names.  On a region boundary (a centre exactly above
an edge or a vertex) the lower-dimensional feature wins, because it is tested
first with non-strict inequalities.  Cost: a constant per candidate, no
square root but the distance's.

Region codes (:data:`FACE` ... :data:`VERTEX_C`): 0 face; 1, 2, 3 the edges
AB, BC, CA; 4, 5, 6 the vertices A, B, C.  The edge ``k`` (1-3) joins the
triangle's vertices ``k - 1`` and ``k % 3``.

Kernels take contiguous float64 arrays and scalars only (no validation).
"""

from __future__ import annotations

from types import SimpleNamespace

import numba
import numpy as np

from .._numba import ijit, jit, pjit, serial_twin

FACE = 0
EDGE_AB = 1
EDGE_BC = 2
EDGE_CA = 3
VERTEX_A = 4
VERTEX_B = 5
VERTEX_C = 6


@ijit
def closest_point(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Closest point ``(qx, qy, qz)`` of triangle ABC to P and its region code."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az, VERTEX_A
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz, VERTEX_B
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz, EDGE_AB
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz, VERTEX_C
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz, EDGE_CA
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz), EDGE_BC
    denom = 1.0 / (va + vb + vc)
    v = vb * denom
    w = vc * denom
    return (ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w, FACE)


@pjit
def sphere_triangles(cand, centres, tri, dist, point, region):
    """Closest points of the candidate pairs ``cand[k] = (sphere, triangle)``.

    centres : (n, 3) sphere centres; tri : (m, 3, 3) triangle vertices (rows
    A, B, C).  Writes ``dist[k]``, ``point[k]`` and ``region[k]`` (one slot
    per candidate, so the threads never share a write).
    """
    for k in numba.prange(cand.shape[0]):
        s = cand[k, 0]
        t = cand[k, 1]
        px, py, pz = centres[s, 0], centres[s, 1], centres[s, 2]
        qx, qy, qz, reg = closest_point(px, py, pz,
                                        tri[t, 0, 0], tri[t, 0, 1], tri[t, 0, 2],
                                        tri[t, 1, 0], tri[t, 1, 1], tri[t, 1, 2],
                                        tri[t, 2, 0], tri[t, 2, 1], tri[t, 2, 2])
        dx, dy, dz = px - qx, py - qy, pz - qz
        dist[k] = np.sqrt(dx * dx + dy * dy + dz * dz)
        point[k, 0] = qx
        point[k, 1] = qy
        point[k, 2] = qz
        region[k] = reg


@pjit
def triangle_boxes(tri, lower, upper):
    """Bounding boxes of the triangles ``tri`` (m, 3, 3) and the largest
    absolute coordinate (for the broad phase's rounding guard)."""
    m = tri.shape[0]
    big = np.zeros(m)
    for t in numba.prange(m):
        top = 0.0
        for ax in range(3):
            lo = min(tri[t, 0, ax], tri[t, 1, ax], tri[t, 2, ax])
            hi = max(tri[t, 0, ax], tri[t, 1, ax], tri[t, 2, ax])
            lower[t, ax] = lo
            upper[t, ax] = hi
            top = max(top, abs(lo), abs(hi))
        big[t] = top
    return big.max() if m else 0.0




# ------------------------------------------------------- fused contact kernels
# Staging rows (one per contact of one wall, before the merge over walls):
# int columns sphere, wall, element, feature, fid, fid2; float columns
# distance, normal (3), point (3).
STAGE_INT = 6
STAGE_FLOAT = 7


@jit
def plane_contacts(x, h, points, normals, walls, out_i, out_f, base):
    """Contacts of the spheres ``x`` (n, 3) with reach ``h`` (n,) and the
    planes ``points``/``normals`` (p, 3), wall indices ``walls`` (p,), one
    pass, sphere-major (then plane order).  Writes staging rows from ``base``
    while they fit in ``out_i``/``out_f``; returns the number of contacts."""
    n = x.shape[0]
    p = points.shape[0]
    cap = out_i.shape[0]
    k = 0
    for s in range(n):
        for j in range(p):
            nx, ny, nz = normals[j, 0], normals[j, 1], normals[j, 2]
            d = ((x[s, 0] - points[j, 0]) * nx + (x[s, 1] - points[j, 1]) * ny
                 + (x[s, 2] - points[j, 2]) * nz)
            if d <= h[s]:
                row = base + k
                if row < cap:
                    out_i[row, 0] = s
                    out_i[row, 1] = walls[j]
                    out_i[row, 2] = 0
                    out_i[row, 3] = 0
                    out_i[row, 4] = 0
                    out_i[row, 5] = -1
                    out_f[row, 0] = d
                    out_f[row, 1] = nx
                    out_f[row, 2] = ny
                    out_f[row, 3] = nz
                    out_f[row, 4] = x[s, 0] - d * nx
                    out_f[row, 5] = x[s, 1] - d * ny
                    out_f[row, 6] = x[s, 2] - d * nz
                k += 1
    return k


@pjit
def sphere_boxes(x, h, top, guard, lower, upper):
    """Broad-phase boxes ``x -+ pad`` of the spheres, ``pad = h + guard * (|h| +
    scale)`` with ``scale`` the largest absolute coordinate of ``x`` and ``top``."""
    n = x.shape[0]
    scale = top
    for s in range(n):
        for ax in range(3):
            scale = max(scale, abs(x[s, ax]))
    for s in numba.prange(n):
        pad = h[s] + guard * (abs(h[s]) + scale)
        for ax in range(3):
            lower[s, ax] = x[s, ax] - pad
            upper[s, ax] = x[s, ax] + pad


@jit
def kept_pairs_hold(x, x_built, h, h_built, margin):
    """Whether a broad phase built on ``x_built`` with reaches ``h_built`` (boxes
    grown by ``margin``) holds the pairs of ``x`` and ``h``: the reaches equal,
    and no coordinate differs by more than ``margin`` (NaN counts as moved).
    Rows alike.  No early exit: each loop is one vectorised reduction."""
    changed = 0
    for s in range(h.shape[0]):
        changed += h[s] != h_built[s]
    if changed:
        return False
    xf = x.reshape(-1)
    bf = x_built.reshape(-1)
    moved = 0
    for k in range(xf.shape[0]):
        moved += not abs(xf[k] - bf[k]) <= margin
    return moved == 0


@ijit
def _feature(region, t, corners, face_edges):
    """Kind (0 face, 1 edge, 2 vertex) and id (triangle, edge, vertex)."""
    if region == FACE:
        return 0, t
    if region <= EDGE_CA:
        return 1, face_edges[t, region - 1]
    return 2, corners[t, region - 4]


@ijit
def _has(table, t, value):
    return table[t, 0] == value or table[t, 1] == value or table[t, 2] == value


@ijit
def _before(a, b, t, kind, f0, f1, shifts, cand):
    """Candidate ``a`` sorts before ``b`` (element, kind, fid, fid2, image shift)."""
    if t[a] != t[b]:
        return t[a] < t[b]
    if kind[a] != kind[b]:
        return kind[a] < kind[b]
    if f0[a] != f0[b]:
        return f0[a] < f0[b]
    if f1[a] != f1[b]:
        return f1[a] < f1[b]
    ia, ib = cand[a, 1], cand[b, 1]
    for ax in range(3):
        if shifts[ia, ax] != shifts[ib, ax]:
            return shifts[ia, ax] < shifts[ib, ax]
    return False


#: hash slots per candidate row: enough for a table per chunk of spheres, a
#: power of two at least twice the six edges and vertices of each triangle
#: in reach of its largest sphere (load <= 1/2); walls.py sizes the scratch with it
SLOTS = 24
#: chunks of spheres of the de-duplication (each with its own table)
_CHUNKS = 256
#: Fibonacci hashing's multiplier (2**64 / golden ratio, as a signed int64)
_GOLDEN = -7046029254386353131


@ijit
def _probe(table, start, mask, bits, key):
    """Slot of ``key`` in the open-addressing table ``table[start:start + mask
    + 1]`` (linear probing): its slot, or the empty one (-1) where it goes."""
    u = ((key * _GOLDEN) >> (64 - bits)) & mask
    while table[start + u] >= 0 and table[start + u] != key:
        u = (u + 1) & mask
    return u


@ijit
def _corner_slot(i, px, py, pz, tri, m, t, corners, f0, f1, dist, tol, hkey, hdist, hkind,
                 hedge, h0, mask, bits):
    """The edge point of row ``i`` at one of its edge's two vertices, within the tie
    tolerance: -2 when it is dropped there (a face contact around that vertex, a
    triangle around it closer by more than the tolerance, or another face or
    edge contact around it closer at all), else the vertex's slot, where it is
    reported once for the vertex; -1 when it is at neither vertex.  (A sphere
    resting on a flat tiling a hair from a vertex meets the triangles around
    the vertex at distances that differ by the square of that hair: the
    closest points of those its projection misses lie on their edges, within
    the tolerance of the one contact, a face or edge point of the triangle
    under it, or at the same distance when the hair's square rounds away.)"""
    for c in range(3):
        v = corners[t, c]
        if v != f0[i] and v != f1[i]:
            continue
        dx = px - tri[m, c, 0]
        dy = py - tri[m, c, 1]
        dz = pz - tri[m, c, 2]
        if np.sqrt(dx * dx + dy * dy + dz * dz) > dist[i] + tol:
            continue
        key = 2 * v + 1
        u = h0 + _probe(hkey, h0, mask, bits, key)
        if hkey[u] != key:
            continue
        if hkind[u] == 0 or hdist[u] < dist[i] - tol or hedge[u] < dist[i]:
            return np.int64(-2)
        return np.int64(u)
    return np.int64(-1)


@pjit
def mesh_select(cand, x, h, tie, tri, rows, shifts, corners, face_edges, edges,
                tlo, thi, top, guard, dist, point, region, elem, kind, fid, f0, f1, gstart,
                offsets, order, hkey, hdist, hkind, hbest, hedge):
    """Narrow phase and de-duplication of one mesh, per sphere.

    ``cand`` (k, 2): (sphere, image triangle) pairs sorted by sphere (the
    cross-set query's order).  Per candidate it writes the closest point
    (``dist``, ``point``, ``region``), its triangle ``elem`` and feature
    (``kind``: 0 face, 1 edge, 2 vertex, -1 out of reach or dropped; ``fid``,
    ``f0``, ``f1``), unless the sphere's box (``sphere_boxes``'s, from ``top``
    and ``guard``) misses the triangle's (``tlo``, ``thi``): then only ``kind``
    is written, -1 (the candidates of a kept broad phase, grown by its margin,
    are mostly such pairs); per sphere (a group of rows) the kept rows, sorted by
    element, kind, feature and image shift, into ``order`` from the group's
    first row.  Returns the number of groups ``g`` (``gstart[:g + 1]`` their
    rows) and of kept contacts (``offsets[:g + 1]`` their exclusive prefix
    sums).  ``hkey``, ``hdist``, ``hkind``, ``hbest``, ``hedge``: scratch,
    ``SLOTS`` slots per candidate.  The rule (docs/walls.md): an edge or vertex point counts when no
    triangle around it is closer (by more than ``tie * h``) and none has a
    face contact (a vertex: nor an edge contact), once per edge or vertex
    (its lowest triangle, then image); an edge point within ``tie * h`` of
    one of its vertices counts as that vertex for the face and closer-triangle
    rules, and only if no other face or edge contact around the vertex is
    closer, and once per vertex (``_corner_slot``).  Cost linear in the candidates (a
    hash table per sphere) plus the sort of each sphere's kept rows.
    """
    k = cand.shape[0]
    g = 0
    for i in range(k):
        if i == 0 or cand[i, 0] != cand[i - 1, 0]:
            gstart[g] = i
            g += 1
    gstart[g] = k
    # the groups in a fixed number of chunks, each with its own hash table
    # (sized for its largest group), reused group after group
    chunks = min(g, _CHUNKS)
    table = np.empty(chunks + 1, np.int64)
    table[0] = 0
    for c in range(chunks):
        big = 0
        for q in range(c * g // chunks, (c + 1) * g // chunks):
            big = max(big, gstart[q + 1] - gstart[q])
        size = 16
        while size < 12 * big:
            size *= 2
        table[c + 1] = table[c] + size
    for ch in numba.prange(chunks):
        h0 = table[ch]
        for q in range(ch * g // chunks, (ch + 1) * g // chunks):
            a = gstart[q]
            b = gstart[q + 1]
            s = cand[a, 0]
            px, py, pz = x[s, 0], x[s, 1], x[s, 2]
            reach = h[s]
            tol = tie * reach
            # the box of sphere_boxes (its scale bounded below by this sphere's)
            pad = reach + guard * (abs(reach) + max(top, max(abs(px), max(abs(py), abs(pz)))))
            hits = 0
            for i in range(a, b):
                m = cand[i, 1]
                if ((px + pad < tlo[m, 0]) | (px - pad > thi[m, 0])
                        | (py + pad < tlo[m, 1]) | (py - pad > thi[m, 1])
                        | (pz + pad < tlo[m, 2]) | (pz - pad > thi[m, 2])):
                    kind[i] = -1  # every point of the triangle is out of reach
                    continue
                qx, qy, qz, reg = closest_point(px, py, pz,
                                                tri[m, 0, 0], tri[m, 0, 1], tri[m, 0, 2],
                                                tri[m, 1, 0], tri[m, 1, 1], tri[m, 1, 2],
                                                tri[m, 2, 0], tri[m, 2, 1], tri[m, 2, 2])
                dx, dy, dz = px - qx, py - qy, pz - qz
                d = np.sqrt(dx * dx + dy * dy + dz * dz)
                dist[i] = d
                point[i, 0] = qx
                point[i, 1] = qy
                point[i, 2] = qz
                region[i] = reg
                t = rows[m]
                elem[i] = t
                kd, fi = _feature(reg, t, corners, face_edges)
                kind[i] = kd if d <= reach else -1
                hits += d <= reach
                fid[i] = fi
                if kd == 1:
                    f0[i] = edges[fi, 0]
                    f1[i] = edges[fi, 1]
                else:
                    f0[i] = fi
                    f1[i] = -1
            # a hash table of the group's edges and vertices (those of every
            # triangle in reach), in its own slots of the scratch: the closest
            # distance and the lowest contact kind of the triangles around each,
            # and the row that reports it
            bits = 4
            while (1 << bits) < 12 * hits:
                bits += 1
            mask = (1 << bits) - 1
            for u in range(h0, h0 + mask + 1):
                hkey[u] = -1
            for j in range(a, b):
                kj = kind[j]
                if kj < 0:
                    continue
                tj = elem[j]
                own = region[j] - 1  # the slot of its own feature goes to region[j]
                for c in range(6):
                    key = 2 * face_edges[tj, c] if c < 3 else 2 * corners[tj, c - 3] + 1
                    u = h0 + _probe(hkey, h0, mask, bits, key)
                    near = dist[j] if kj < 2 else np.inf
                    if hkey[u] < 0:
                        hkey[u] = key
                        hdist[u] = dist[j]
                        hkind[u] = kj
                        hbest[u] = -1
                        hedge[u] = near
                    else:
                        hdist[u] = min(hdist[u], dist[j])
                        hkind[u] = min(hkind[u], kj)
                        hedge[u] = min(hedge[u], near)
                    if c == own:
                        region[j] = u
            # 1 and 2: an edge or vertex point shadowed (a closer triangle around
            # it) or blocked (a face, for a vertex a face or an edge, contact of a
            # triangle around it) is dropped; 3: the lowest triangle, then image,
            # of the others reports each edge and vertex
            for i in range(a, b):
                kd = kind[i]
                if kd <= 0:
                    continue
                u = region[i]
                if hdist[u] < dist[i] - tol or hkind[u] < kd:
                    continue
                if kd == 1:
                    corner = _corner_slot(i, px, py, pz, tri, cand[i, 1], elem[i], corners,
                                          f0, f1, dist, tol, hkey, hdist, hkind, hedge, h0,
                                          mask, bits)
                    if corner == -2:
                        continue
                    if corner >= 0:  # reported once per vertex, as a vertex point is
                        u = corner
                        region[i] = u
                c = hbest[u]
                if c < 0 or elem[i] < elem[c] or (elem[i] == elem[c] and cand[i, 1] < cand[c, 1]):
                    hbest[u] = i
            kept = 0
            for i in range(a, b):
                kd = kind[i]
                if kd < 0:
                    continue
                if kd > 0 and hbest[region[i]] != i:
                    continue
                order[a + kept] = i
                kept += 1
            # the kept rows in output order
            if kept <= 16:
                for u in range(a + 1, a + kept):
                    v = order[u]
                    w = u - 1
                    while w >= a and _before(v, order[w], elem, kind, f0, f1, shifts, cand):
                        order[w + 1] = order[w]
                        w -= 1
                    order[w + 1] = v
            else:  # bottom-up merge sort through the group's hash slots
                src, dst = order, hkey
                so, do = a, h0
                width = 1
                while width < kept:
                    for lo in range(0, kept, 2 * width):
                        mid = min(lo + width, kept)
                        hi = min(lo + 2 * width, kept)
                        p, r2, o = lo, mid, lo
                        while p < mid and r2 < hi:
                            if _before(src[so + r2], src[so + p], elem, kind, f0, f1, shifts, cand):
                                dst[do + o] = src[so + r2]
                                r2 += 1
                            else:
                                dst[do + o] = src[so + p]
                                p += 1
                            o += 1
                        while p < mid:
                            dst[do + o] = src[so + p]
                            p += 1
                            o += 1
                        while r2 < hi:
                            dst[do + o] = src[so + r2]
                            r2 += 1
                            o += 1
                    src, dst = dst, src
                    so, do = do, so
                    width *= 2
                if so != a:
                    for u in range(kept):
                        order[a + u] = hkey[h0 + u]
            offsets[q] = kept
    total = 0
    for q in range(g):
        c = offsets[q]
        offsets[q] = total
        total += c
    offsets[g] = total
    return g, total


@pjit
def mesh_fill(cand, x, tri, dist, point, elem, kind, f0, f1, gstart, offsets, order,
              groups, wall, delta, out_i, out_f, base):
    """Staging rows of the kept contacts of :func:`mesh_select` from ``base``;
    ``delta`` (n, 3): given minus wrapped position of each sphere (periodic
    cells; empty otherwise)."""
    shifted = delta.shape[0] > 0
    for q in numba.prange(groups):
        a = gstart[q]
        row = base + offsets[q]
        for u in range(a, a + offsets[q + 1] - offsets[q]):
            i = order[u]
            s = cand[i, 0]
            m = cand[i, 1]
            d = dist[i]
            out_i[row, 0] = s
            out_i[row, 1] = wall
            out_i[row, 2] = elem[i]
            out_i[row, 3] = kind[i]
            out_i[row, 4] = f0[i]
            out_i[row, 5] = f1[i]
            out_f[row, 0] = d
            if d > 0.0:
                for ax in range(3):
                    out_f[row, 1 + ax] = (x[s, ax] - point[i, ax]) / d
            else:  # the centre on the triangle: its normal
                ux = tri[m, 1, 0] - tri[m, 0, 0]
                uy = tri[m, 1, 1] - tri[m, 0, 1]
                uz = tri[m, 1, 2] - tri[m, 0, 2]
                vx = tri[m, 2, 0] - tri[m, 0, 0]
                vy = tri[m, 2, 1] - tri[m, 0, 1]
                vz = tri[m, 2, 2] - tri[m, 0, 2]
                nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
                norm = np.sqrt(nx * nx + ny * ny + nz * nz)
                out_f[row, 1] = nx / norm
                out_f[row, 2] = ny / norm
                out_f[row, 3] = nz / norm
            for ax in range(3):
                out_f[row, 4 + ax] = point[i, ax] + delta[s, ax] if shifted else point[i, ax]
            row += 1


@jit
def merge_walls(st_i, st_f, bounds, skey, sphere, wall, element, feature, distance,
                normal, point, keys):
    """The staging parts ``bounds[p]:bounds[p + 1]`` (each sorted by sphere,
    then wall, then within a wall) merged into the outputs, sorted by sphere
    and wall; ``keys`` (k, 6) the identity keys when it has rows (``skey``:
    the sphere ids, or empty for rows), the last column the rank among equal
    keys (a feature touched in several periodic images)."""
    parts = bounds.shape[0] - 1
    cur = bounds[:-1].copy()
    k = bounds[parts] - bounds[0]
    ident = keys.shape[0] > 0
    ids = skey.shape[0] > 0
    for o in range(k):
        best = -1
        for p in range(parts):
            c = cur[p]
            if c == bounds[p + 1]:
                continue
            if best < 0:
                best = p
                continue
            b = cur[best]
            if st_i[c, 0] < st_i[b, 0] or (st_i[c, 0] == st_i[b, 0] and st_i[c, 1] < st_i[b, 1]):
                best = p
        r = cur[best]
        cur[best] = r + 1
        sphere[o] = st_i[r, 0]
        wall[o] = st_i[r, 1]
        element[o] = st_i[r, 2]
        feature[o] = st_i[r, 3]
        distance[o] = st_f[r, 0]
        for ax in range(3):
            normal[o, ax] = st_f[r, 1 + ax]
            point[o, ax] = st_f[r, 4 + ax]
        if ident:
            keys[o, 0] = skey[st_i[r, 0]] if ids else st_i[r, 0]
            keys[o, 1] = st_i[r, 1]
            keys[o, 2] = st_i[r, 3]
            keys[o, 3] = st_i[r, 4]
            keys[o, 4] = st_i[r, 5]
            rank = 0
            if o > 0 and (keys[o, 0] == keys[o - 1, 0] and keys[o, 1] == keys[o - 1, 1]
                          and keys[o, 2] == keys[o - 1, 2] and keys[o, 3] == keys[o - 1, 3]
                          and keys[o, 4] == keys[o - 1, 4]):
                rank = keys[o - 1, 5] + 1
            keys[o, 5] = rank
    return k


#: the serial builds (no thread-pool launch) for one thread
serial = SimpleNamespace(sphere_triangles=serial_twin(sphere_triangles),
                         triangle_boxes=serial_twin(triangle_boxes),
                         sphere_boxes=serial_twin(sphere_boxes),
                         mesh_select=serial_twin(mesh_select),
                         mesh_fill=serial_twin(mesh_fill))
