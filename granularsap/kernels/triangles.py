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

from .._numba import ijit, pjit, serial_twin

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


#: the serial builds (no thread-pool launch) for one thread
serial = SimpleNamespace(sphere_triangles=serial_twin(sphere_triangles),
                         triangle_boxes=serial_twin(triangle_boxes))
