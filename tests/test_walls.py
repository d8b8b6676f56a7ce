"""Sphere-wall contacts (granularsap.walls) against a brute force over every triangle.

The oracle below is the definition written out: the closest point of a
triangle is the nearest of the projection on its plane (when it falls inside)
and the closest points of its three edge segments; the feature is the one
with the smallest dimension among those at the minimum distance; the
de-duplication is the rule of docs/walls.md as loops over dictionaries.
"""

from __future__ import annotations

import doctest
import itertools

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import granularsap
import granularsap.boxes
from granularsap import Cell, Plane, TriangleMesh, WallSearch, box_overlaps
from granularsap.kernels import triangles as tri_kernels

# ----------------------------------------------------------------- the oracle


def closest_on_triangle(p, a, b, c):
    """(distance, point, kind, local feature) by exact formulas, no sampling.

    kind 0 face (local 0), 1 edge (local 0 AB, 1 BC, 2 CA), 2 vertex (local
    0, 1, 2).  Features within a relative 1e-12 of the minimum distance tie,
    and the smallest dimension wins (a point exactly above an edge is on it).
    """
    p, a, b, c = (np.asarray(v, dtype=np.float64) for v in (p, a, b, c))
    options = []  # (distance, -dimension order, kind, local, point)
    n = np.cross(b - a, c - a)
    q = p - ((p - a) @ n) / (n @ n) * n
    # barycentric coordinates of q by sub-areas (signed along n)
    wa = np.cross(c - b, q - b) @ n
    wb = np.cross(a - c, q - c) @ n
    wc = np.cross(b - a, q - a) @ n
    if wa >= 0 and wb >= 0 and wc >= 0:
        options.append((float(np.linalg.norm(p - q)), 0, 0, q))
    corners = (a, b, c)
    for e in range(3):
        u, v = corners[e], corners[(e + 1) % 3]
        t = float(np.clip((p - u) @ (v - u) / ((v - u) @ (v - u)), 0.0, 1.0))
        if 0.0 < t < 1.0:
            pt = u + t * (v - u)
            options.append((float(np.linalg.norm(p - pt)), 1, e, pt))
    for k in range(3):
        options.append((float(np.linalg.norm(p - corners[k])), 2, k, corners[k]))
    best = min(o[0] for o in options)
    tol = 1e-12 * max(best, float(np.abs(np.concatenate((p, a, b, c))).max()))
    near = [o for o in options if o[0] <= best + tol]
    d, kind, local, pt = max(near, key=lambda o: o[1])
    return d, np.asarray(pt), kind, local


def oracle_contacts(x, radii, vertices, faces, skin=0.0, shifts=((0.0, 0.0, 0.0),),
                    vertex_key=None, combine=False):
    """Contacts of spheres with one mesh after the face / edge / vertex rule.

    Every triangle within reach gives its closest point; an edge (vertex)
    point is dropped when a triangle having that edge (vertex) is closer
    elsewhere, or when a triangle having it has a face contact (for a vertex:
    a face or an edge contact); each edge and vertex is kept once.

    ``shifts``: Cartesian translations of the mesh (its periodic images); the
    rule is applied per image, or over all images together with ``combine``
    (a mesh whose images join: vertices identified by ``vertex_key``).
    ``vertex_key``: the identity of each vertex (default: its exact
    coordinates).  Returns a dict keyed by (sphere, kind, feature, image) ->
    (element, distance, point) with feature the triangle, the sorted vertex
    pair or the vertex, each as keys.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertex_key is None:
        vertex_key = [tuple(v) for v in vertices]
    out = {}
    h = np.broadcast_to(np.asarray(radii, dtype=np.float64), (len(x),)) + skin
    tri = vertices[faces]
    centroid = tri.mean(axis=1)
    bound = np.linalg.norm(tri - centroid[:, None], axis=2).max(axis=1)

    def edge_of(t, e):
        u, v = vertex_key[faces[t][e]], vertex_key[faces[t][(e + 1) % 3]]
        return (min(u, v), max(u, v))

    def edges(t):
        return {edge_of(t, e) for e in range(3)}

    def corners(t):
        return {vertex_key[i] for i in faces[t]}

    for s in range(len(x)):
        groups = [[] for _ in ([0] if combine else shifts)]
        for si, shift in enumerate(shifts):
            raw = groups[0 if combine else si]
            # every triangle is looked at; those whose bounding sphere is out of
            # reach (|p - centroid| - bound > h: a lower bound of the distance)
            # are skipped without computing their closest point
            far = np.linalg.norm(x[s] - shift - centroid, axis=1) - bound > h[s] * (1 + 1e-6)
            for t, f in enumerate(faces):
                if far[t]:
                    continue
                a, b, c = (vertices[i] + shift for i in f)
                d, pt, kind, local = closest_on_triangle(x[s], a, b, c)
                if d <= h[s]:
                    raw.append((t, kind, local, d, pt, si))
        for gi, raw in enumerate(groups):
            face_tris = {r[0] for r in raw if r[1] == 0}
            touched = {r[0] for r in raw if r[1] in (0, 1)}
            blocked_e = {e for t in face_tris for e in edges(t)}
            blocked_v = {v for t in touched for v in corners(t)}
            tie = 1e-9 * h[s]
            for t, kind, local, d, pt, si in raw:
                if kind == 0:
                    key = (s, 0, t, si)
                elif kind == 1:
                    feat = edge_of(t, local)
                    # shadowed: a triangle with this edge is closer elsewhere
                    if feat in blocked_e or any(feat in edges(r[0]) and r[3] < d - tie
                                                for r in raw):
                        continue
                    key = (s, 1, feat, gi)
                else:
                    feat = vertex_key[faces[t][local]]
                    if feat in blocked_v or any(feat in corners(r[0]) and r[3] < d - tie
                                                for r in raw):
                        continue
                    key = (s, 2, feat, gi)
                if key not in out or t < out[key][0]:
                    out[key] = (t, d, pt)
    return out


def assert_matches(c, oracle, wall=0, *, rtol=1e-12, atol=1e-12):
    """WallContacts rows of ``wall`` equal the oracle's (element, feature, distance, point)."""
    rows = np.flatnonzero(c.wall == wall)
    got = sorted((int(c.sphere[i]), int(c.feature[i]), int(c.element[i])) for i in rows)
    want = sorted((k[0], k[1], v[0]) for k, v in oracle.items())
    assert got == want
    ref = {(k[0], k[1], v[0]): v for k, v in oracle.items()}
    for i in rows:
        _, d, pt = ref[(int(c.sphere[i]), int(c.feature[i]), int(c.element[i]))]
        np.testing.assert_allclose(c.distance[i], d, rtol=rtol, atol=atol)
        np.testing.assert_allclose(c.point[i], pt, rtol=rtol, atol=atol)


def grid_floor(nx, ny, z=0.0, step=1.0, origin=(0.0, 0.0)):
    """A flat floor of nx x ny squares, each split along its diagonal."""
    xs = origin[0] + step * np.arange(nx + 1)
    ys = origin[1] + step * np.arange(ny + 1)
    v = np.array([[x, y, z] for y in ys for x in xs])
    faces = []
    for j in range(ny):
        for i in range(nx):
            a = j * (nx + 1) + i
            b, c, d = a + 1, a + nx + 2, a + nx + 1
            faces += [[a, b, c], [a, c, d]]
    return v, np.array(faces)


def hexagon_fan():
    """Six triangles around the origin (a vertex shared by six)."""
    ang = np.arange(6) * np.pi / 3
    v = np.vstack(([0.0, 0.0, 0.0], np.stack((np.cos(ang), np.sin(ang), np.zeros(6)), 1)))
    faces = np.array([[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    return v, faces


def bumpy_mesh(rng, n=5):
    """A non-flat height field (shared edges and vertices, ridges and valleys)."""
    v, faces = grid_floor(n, n)
    v[:, 2] = rng.uniform(-0.4, 0.4, len(v))
    return v, faces


# ----------------------------------------------------------------- the kernel


class TestClosestPoint:
    def test_random_triangles_against_the_definition(self):
        rng = np.random.default_rng(1)
        out = np.empty(3)
        for _ in range(3000):
            a, b, c, p = rng.normal(size=(4, 3)) * rng.uniform(0.1, 10)
            d, pt, kind, local = closest_on_triangle(p, a, b, c)
            qx, qy, qz, region = tri_kernels.closest_point.py_func(*p, *a, *b, *c)
            out[:] = qx, qy, qz
            np.testing.assert_allclose(out, pt, rtol=1e-9, atol=1e-9 * np.abs(p).max())
            want = {0: tri_kernels.FACE, 1: (tri_kernels.EDGE_AB, tri_kernels.EDGE_BC,
                                                tri_kernels.EDGE_CA)[local],
                    2: (tri_kernels.VERTEX_A, tri_kernels.VERTEX_B,
                        tri_kernels.VERTEX_C)[local]}[kind]
            assert region == want

    @pytest.mark.parametrize("p, region", [
        ((0.25, 0.25, 1.0), tri_kernels.FACE),
        ((0.5, 0.0, 1.0), tri_kernels.EDGE_AB),   # exactly above an edge
        ((0.5, 0.5, -2.0), tri_kernels.EDGE_BC),
        ((0.0, 0.5, 0.0), tri_kernels.EDGE_CA),
        ((0.0, 0.0, 3.0), tri_kernels.VERTEX_A),  # exactly above a vertex
        ((2.0, -1.0, 0.0), tri_kernels.VERTEX_B),
        ((-1.0, 2.0, 0.5), tri_kernels.VERTEX_C),
    ])
    def test_ties_go_to_the_lower_dimension(self, p, region):
        got = tri_kernels.closest_point.py_func(*p, 0, 0, 0, 1, 0, 0, 0, 1, 0)
        assert got[3] == region


# ----------------------------------------------------------------- exact features


class TestFeatures:
    def test_face_contact_exactly_touching_counts(self):
        v, f = grid_floor(2, 2)
        walls = WallSearch([TriangleMesh(v, f)])
        c = walls.update([[0.75, 0.25, 0.5], [0.75, 0.25, -0.5], [0.75, 0.25, 0.5000001]], 0.5)
        assert c.sphere.tolist() == [0, 1]
        assert c.feature.tolist() == [0, 0]
        assert c.distance.tolist() == [0.5, 0.5]
        assert c.normal.tolist() == [[0, 0, 1], [0, 0, -1]]  # two-sided
        assert c.point.tolist() == [[0.75, 0.25, 0.0], [0.75, 0.25, 0.0]]

    def test_edge_shared_by_two_triangles_once(self):
        v, f = grid_floor(2, 2)
        mesh = TriangleMesh(v, f)
        # above the diagonal of square (0, 0) (triangles 0 and 1), above the
        # edge x = 1 between squares (0, 0) and (1, 0) (triangles 0 and 3)
        x = np.array([[0.5, 0.5, 0.25], [1.0, 0.25, 0.25]])
        c = WallSearch([mesh]).update(x, 0.25)
        assert c.sphere.tolist() == [0, 1]
        assert c.feature.tolist() == [1, 1]
        assert c.element.tolist() == [0, 0]  # the lowest triangle with that edge
        assert c.point.tolist() == [[0.5, 0.5, 0.0], [1.0, 0.25, 0.0]]
        assert_matches(c, oracle_contacts(x, 0.25, v, f))

    def test_vertex_shared_by_six_triangles_once(self):
        v, f = hexagon_fan()
        mesh = TriangleMesh(v, f)
        x = np.array([[0.0, 0.0, 0.3], [0.0, 0.0, -0.3]])
        c = WallSearch([mesh]).update(x, 0.3)
        assert c.sphere.tolist() == [0, 1]
        assert c.feature.tolist() == [2, 2]
        assert c.element.tolist() == [0, 0]
        assert c.distance.tolist() == [0.3, 0.3]
        assert c.normal.tolist() == [[0, 0, 1], [0, 0, -1]]
        assert_matches(c, oracle_contacts(x, 0.3, v, f))

    def test_vertex_of_a_grid_shared_by_six(self):
        # an interior vertex of the diagonal-split grid has six triangles
        v, f = grid_floor(2, 2)
        mesh = TriangleMesh(v, f)
        centre = np.flatnonzero((v == [1.0, 1.0, 0.0]).all(1))[0]
        assert (f == centre).any(axis=1).sum() == 6
        c = WallSearch([mesh]).update([[1.0, 1.0, 0.125]], 0.125)
        assert c.feature.tolist() == [2]
        assert c.point.tolist() == [[1.0, 1.0, 0.0]]

    def test_a_sphere_over_an_edge_of_a_ridge_touches_both_faces(self):
        # two faces meeting at a ridge (roof): a sphere above the ridge line
        # with a reach covering both slopes gets two face contacts, no edge
        v = np.array([[0, 0, 0], [2, 0, 0], [0, 1, 1], [2, 1, 1], [0, 2, 0], [2, 2, 0.0]])
        f = np.array([[0, 1, 3], [0, 3, 2], [2, 3, 5], [2, 5, 4]])
        x = np.array([[1.0, 1.0, 1.5], [1.0, 1.0, 0.5]])
        c = WallSearch([TriangleMesh(v, f)]).update(x, [0.6, 0.9])
        assert_matches(c, oracle_contacts(x, [0.6, 0.9], v, f))
        assert c.feature[c.sphere == 0].tolist() == [1]      # above the ridge: the edge
        assert set(c.feature[c.sphere == 1].tolist()) == {0}  # under it: the two slopes

    def test_duplicated_stl_vertices_share_edges(self):
        # every triangle with its own copies of the vertices (an STL soup)
        v, f = grid_floor(2, 1)
        soup = v[f].reshape(-1, 3)
        mesh = TriangleMesh(soup, np.arange(len(soup)).reshape(-1, 3))
        x = [[1.0, 0.5, 0.25], [0.5, 0.5, 0.25], [1.0, 1.0, 0.25]]
        c = WallSearch([mesh]).update(x, 0.25)
        assert c.feature.tolist() == [1, 1, 2]  # the shared side, a diagonal, a corner
        ref = WallSearch([TriangleMesh(v, f)]).update(x, 0.25)
        for a, b in zip(c, ref, strict=True):
            np.testing.assert_array_equal(a, b)
        assert len(mesh.edges) == 9  # 4 squares' sides x 2 - the shared side + 2 diagonals


def unit_cube():
    """The cube [0, 1]^3 as 12 triangles (each square split along a diagonal)."""
    v = np.array(list(itertools.product((0.0, 1.0), repeat=3)))
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = [f for a, b, c, d in quads for f in ((a, b, c), (a, c, d))]
    return v, np.array(faces)


class TestConvexMesh:
    def test_one_contact_outside_a_cube(self):
        # outside a convex surface the closest point is unique: one contact per
        # sphere, at q = clip(p, 0, 1), on a face, an edge or a corner of the cube
        rng = np.random.default_rng(13)
        v, f = unit_cube()
        x = rng.uniform(-0.6, 1.6, (3000, 3))
        x = x[(np.abs(x - 0.5) > 0.5).any(axis=1)]  # outside
        q = np.clip(x, 0, 1)
        d = np.linalg.norm(x - q, axis=1)
        c = WallSearch([TriangleMesh(v, f)]).update(x, 0.4)
        want = np.flatnonzero(d <= 0.4)
        assert c.sphere.tolist() == want.tolist()
        np.testing.assert_allclose(c.point, q[want], atol=1e-12)
        np.testing.assert_allclose(c.distance, d[want], rtol=1e-12, atol=1e-15)
        outside = (np.abs(x[want] - 0.5) > 0.5).sum(axis=1)  # 1 face, 2 edge, 3 corner
        assert (c.feature[outside == 2] == 1).all() and (c.feature[outside == 3] == 2).all()
        assert set(c.feature[outside == 1].tolist()) <= {0, 1}  # 1: on a face's diagonal

    @pytest.mark.parametrize("p, feature", [((0.5, 0.5, 1.25), 1),   # over a face diagonal
                                            ((0.25, 0.5, 1.25), 0),
                                            ((1.25, 0.5, 1.25), 1),  # beyond a cube edge
                                            ((1.25, 1.25, 1.25), 2),  # beyond a corner
                                            ((-0.25, 0.0, 0.0), 2)])  # in line with an edge
    def test_exact_features_of_a_cube(self, p, feature):
        v, f = unit_cube()
        c = WallSearch([TriangleMesh(v, f)]).update([p], 0.5)
        assert c.feature.tolist() == [feature]
        assert c.point.tolist() == [np.clip(p, 0, 1).tolist()]


class TestFlatTilings:
    @settings(max_examples=60, deadline=None)
    @given(st.lists(st.tuples(st.integers(1, 63), st.integers(1, 63), st.integers(-8, 8)),
                    min_size=1, max_size=12),
           st.sampled_from([0.125, 0.25, 0.5]))
    def test_one_contact_wherever_a_sphere_rests(self, cells, r):
        # dyadic positions over a 4 x 4 tiling: face, edge and vertex ties are exact
        v, f = grid_floor(4, 4)
        x = np.array([[i / 16, j / 16, k / 16] for i, j, k in cells])
        c = WallSearch([TriangleMesh(v, f), Plane([0, 0, 0], [0, 0, 1])]).update(x, r)
        m = c.wall == 0
        touching = np.flatnonzero(np.abs(x[:, 2]) <= r)
        assert c.sphere[m].tolist() == touching.tolist()
        np.testing.assert_array_equal(c.distance[m], np.abs(x[touching, 2]))
        np.testing.assert_array_equal(c.point[m][:, :2], x[touching, :2])
        assert_matches(c, oracle_contacts(x, r, v, f))

    @pytest.mark.parametrize("hair", [1e-4, 1e-5, 1e-6, 1e-8, 1e-12])
    @pytest.mark.parametrize("diagonal", [False, True])
    def test_one_contact_a_hair_from_a_vertex(self, hair, diagonal):
        # around an interior vertex the triangles the sphere's projection misses
        # meet it at distances a hair's square apart: their closest points round
        # onto their edges, within the tie tolerance of the one contact
        v, f = grid_floor(4, 4)
        if diagonal:  # the other diagonal in every square: six triangles per vertex
            f = np.concatenate([np.stack([q[:, 0], q[:, 1], q[:, 3]], 1) for q in (
                np.array([[a, b, c, d] for a, b, c in f[0::2] for d in [c - 1]]),)] + [
                np.stack([q[:, 1], q[:, 2], q[:, 3]], 1) for q in (
                    np.array([[a, b, c, c - 1] for a, b, c in f[0::2]]),)])
        angles = np.linspace(0.0, 2.0 * np.pi, 72, endpoint=False)
        x = np.column_stack((2.0 + hair * np.cos(angles), 2.0 + hair * np.sin(angles),
                             np.full(72, 0.2)))
        c = WallSearch([TriangleMesh(v, f)]).update(x, 0.3)
        flat = WallSearch([Plane([0, 0, 0], [0, 0, 1])]).update(x, 0.3)
        assert c.sphere.tolist() == list(range(72))
        np.testing.assert_array_equal(c.distance, flat.distance)

    def test_coplanar_tiling_with_rotated_frame(self):
        rng = np.random.default_rng(4)
        v, f = grid_floor(6, 6, step=0.5)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        vr = v @ q.T + [1.0, -2.0, 0.5]
        local = np.column_stack((rng.uniform(0.2, 2.8, 300), rng.uniform(0.2, 2.8, 300),
                                 rng.uniform(-0.4, 0.4, 300)))
        x = local @ q.T + [1.0, -2.0, 0.5]
        c = WallSearch([TriangleMesh(vr, f)]).update(x, 0.3)
        want = np.flatnonzero(np.abs(local[:, 2]) <= 0.3)
        # near 0.3 a rounding may fall either way: compare away from the threshold
        clear = np.abs(np.abs(local[:, 2]) - 0.3) > 1e-9
        got = set(c.sphere.tolist())
        assert {s for s in want if clear[s]} <= got
        assert all(clear[s] is np.False_ or s in set(want) for s in got)
        assert len(got) == len(c.sphere)  # one contact per sphere
        np.testing.assert_allclose(c.distance, np.abs(local[c.sphere, 2]), atol=1e-12)


# ----------------------------------------------------------------- random meshes


class TestRandom:
    @pytest.mark.parametrize("n_threads", [1, 2])
    @pytest.mark.parametrize("seed", [0, 1, 2])
    def test_bumpy_mesh_against_brute_force(self, seed, n_threads):
        rng = np.random.default_rng(seed)
        v, f = bumpy_mesh(rng)
        x = np.column_stack((rng.uniform(-0.5, 5.5, (150, 2)), rng.uniform(-1, 1, 150)))
        r = rng.uniform(0.05, 0.6, 150)
        c = WallSearch([TriangleMesh(v, f)], skin=0.05, n_threads=n_threads).update(x, r)
        assert_matches(c, oracle_contacts(x, r, v, f, skin=0.05), rtol=1e-9, atol=1e-9)
        # the normal points from the point to the centre, unit length
        d = x[c.sphere] - c.point
        np.testing.assert_allclose(c.normal * c.distance[:, None], d, atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(c.normal, axis=1), 1.0)

    @settings(max_examples=50, deadline=None)
    @given(st.lists(st.integers(-4, 4), min_size=16, max_size=16),
           st.lists(st.tuples(st.integers(-4, 28), st.integers(-4, 28), st.integers(-8, 8)),
                    min_size=1, max_size=8),
           st.sampled_from([0.25, 0.5, 0.75]))
    def test_dyadic_height_fields(self, heights, cells, r):
        # exact ties everywhere: centres above edges and vertices, equal distances
        v, f = grid_floor(3, 3)
        v[:, 2] = np.array(heights) / 8
        x = np.array([[i / 8, j / 8, k / 8] for i, j, k in cells])
        oracle = oracle_contacts(x, r, v, f)
        tri = v[f]
        for p in x:  # no distance within rounding of the contact distance
            d = [closest_on_triangle(p, *t)[0] for t in tri]
            assume(all(abs(di - r) > 1e-9 for di in d))
        c = WallSearch([TriangleMesh(v, f)]).update(x, r)
        assert_matches(c, oracle, rtol=1e-12, atol=1e-12)

    def test_triangle_soup_against_brute_force(self):
        rng = np.random.default_rng(7)
        v = rng.uniform(0, 4, (60, 3))
        f = rng.integers(0, 60, (40, 3))
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        x = rng.uniform(-0.5, 4.5, (200, 3))
        c = WallSearch([TriangleMesh(v, f)]).update(x, 0.4)
        assert_matches(c, oracle_contacts(x, 0.4, v, f), rtol=1e-9, atol=1e-9)

    def test_threads_give_the_same_result(self):
        rng = np.random.default_rng(3)
        v, f = bumpy_mesh(rng, 12)
        x = np.column_stack((rng.uniform(0, 12, (4000, 2)), rng.uniform(-1, 1, 4000)))
        one = WallSearch([TriangleMesh(v, f)], n_threads=1).update(x, 0.3)
        two = WallSearch([TriangleMesh(v, f)], n_threads=2).update(x, 0.3)
        for a, b in zip(one, two, strict=True):
            np.testing.assert_array_equal(a, b)


def uv_sphere(m=8, radius=1.0):
    """A closed latitude-longitude sphere mesh (2 m (m - 1) triangles)."""
    v = [[0.0, 0.0, radius], [0.0, 0.0, -radius]]
    for i in range(1, m):
        th = np.pi * i / m
        for j in range(m):
            ph = 2 * np.pi * j / m
            v.append([radius * np.sin(th) * np.cos(ph), radius * np.sin(th) * np.sin(ph),
                      radius * np.cos(th)])
    ring = lambda i, j: 2 + (i - 1) * m + j % m  # noqa: E731
    f = [[0, ring(1, j), ring(1, j + 1)] for j in range(m)]
    f += [[1, ring(m - 1, j + 1), ring(m - 1, j)] for j in range(m)]
    for i in range(1, m - 1):
        for j in range(m):
            f += [[ring(i, j), ring(i + 1, j), ring(i + 1, j + 1)],
                  [ring(i, j), ring(i + 1, j + 1), ring(i, j + 1)]]
    return np.array(v), np.array(f)


def _rows(c):
    """The contacts as tuples (sphere, wall, element, feature, distance, normal, point)."""
    return [(int(c.sphere[i]), int(c.wall[i]), int(c.element[i]), int(c.feature[i]),
             float(c.distance[i]), *c.normal[i].tolist(), *c.point[i].tolist())
            for i in range(len(c.sphere))]


class TestFusedPaths:
    """Planes only, meshes only, both in any order, growing and empty outputs."""

    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_walls_in_any_order_equal_one_search_per_wall(self, n_threads):
        rng = np.random.default_rng(11)
        v, f = bumpy_mesh(rng, 6)
        v2, f2 = grid_floor(3, 3, z=0.7, step=2.0)
        walls = [TriangleMesh(v, f), Plane([0, 0, 0], [1, 0, 0]), TriangleMesh(v2, f2),
                 Plane([0, 0, 0.2], [0, 0, 1]), Plane([6, 0, 0], [-1, 0.5, 0])]
        x = np.column_stack((rng.uniform(-0.5, 6.5, (600, 2)), rng.uniform(-1, 1.5, 600)))
        r = rng.uniform(0.05, 0.5, 600)
        c = WallSearch(walls, skin=0.02, n_threads=n_threads).update(x, r)
        want = []
        for w, wall in enumerate(walls):
            alone = WallSearch([wall], skin=0.02, n_threads=n_threads).update(x, r)
            want += [(s, w, *rest) for s, _, *rest in _rows(alone)]
        want.sort(key=lambda t: t[:2])  # stable: each wall's own order within
        assert len(want) > 100  # staging and outputs grow past their first size
        assert _rows(c) == want
        for wall in (0, 2):
            vv, ff = (v, f) if wall == 0 else (v2, f2)
            assert_matches(c, oracle_contacts(x, r, vv, ff, skin=0.02), wall=wall,
                           rtol=1e-9, atol=1e-9)

    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_planes_only(self, n_threads):
        rng = np.random.default_rng(4)
        planes = [Plane(rng.normal(size=3), rng.normal(size=3)) for _ in range(5)]
        x = rng.normal(size=(2000, 3)) * 2
        r = rng.uniform(0, 0.5, 2000)
        c = WallSearch(planes, skin=0.1, n_threads=n_threads).update(x, r)
        want = []
        for s in range(len(x)):
            for w, p in enumerate(planes):
                d = (x[s] - p.point) @ p.normal
                if d <= r[s] + 0.1:
                    want.append((s, w, d))
        assert [(int(a), int(b)) for a, b in zip(c.sphere, c.wall, strict=True)] == [
            t[:2] for t in want]
        np.testing.assert_allclose(c.distance, [t[2] for t in want], rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(c.normal, np.array([planes[w].normal for w in c.wall]))
        np.testing.assert_allclose(c.point, x[c.sphere] - c.distance[:, None] * c.normal,
                                   atol=1e-12)

    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_many_contacts_of_one_sphere(self, n_threads):
        # a sphere filling a closed mesh touches every face (its kept rows are
        # sorted by a merge sort past a few), one outside touches a few
        v, f = uv_sphere(10)
        x = np.array([[0.0, 0.0, 0.0], [1.3, 0.2, 0.1], [0.01, -0.02, 0.03]])
        r = np.array([1.0, 0.45, 0.99])
        c = WallSearch([TriangleMesh(v, f)], n_threads=n_threads).update(x, r)
        assert np.sum(c.sphere == 0) > 50 and np.sum(c.sphere == 2) > 16
        assert_matches(c, oracle_contacts(x, r, v, f), rtol=1e-9, atol=1e-9)
        assert _rows(c) == sorted(_rows(c), key=lambda t: t[:4])

    def test_empty_parts(self):
        v, f = grid_floor(2, 2)
        walls = WallSearch([Plane([0, 0, -5], [0, 0, 1]), TriangleMesh(v, f),
                            Plane([0, 0, 5], [0, 0, -1])], identity=True)
        far = [[1.0, 1.0, 2.0]]  # no plane, no triangle in reach
        assert all(len(a) == 0 for a in walls.update(far, 0.1))
        c = walls.update([[1.0, 1.0, 0.05], [9.0, 9.0, 4.95]], 0.1)  # mesh, then a plane
        assert c.sphere.tolist() == [0, 1] and c.wall.tolist() == [1, 2]
        assert walls.previous_rows.tolist() == [-1, -1]
        assert all(len(a) == 0 for a in walls.update(far, 0.1))
        assert walls.ended_rows.tolist() == [0, 1]

    def test_results_survive_the_next_call(self):
        # outputs are double-buffered: valid and unchanged until the call after next
        v, f = grid_floor(4, 4)
        walls = WallSearch([Plane([0, 0, 0], [1, 0, 0]), TriangleMesh(v, f)])
        rng = np.random.default_rng(5)
        first = walls.update(rng.uniform(0, 4, (50, 3)) * [1, 1, 0.1], 0.3)
        kept = [a.copy() for a in first]
        second = walls.update(rng.uniform(0, 4, (400, 3)) * [1, 1, 0.1], 0.3)  # grows
        for a, b in zip(first, kept, strict=True):
            np.testing.assert_array_equal(a, b)
        assert not np.shares_memory(first.sphere, second.sphere)


# ----------------------------------------------------------------- planes


class TestPlanes:
    def test_signed_distance_and_spheres_behind(self):
        p = Plane(point=[0, 0, 1], normal=[0, 0, 3])
        x = np.array([[0.0, 0, 1.5], [2, 3, 0.0], [0, 0, 2.6], [1, 1, 1.0]])
        c = WallSearch([p], skin=0.1).update(x, 0.5)
        assert c.sphere.tolist() == [0, 1, 3]  # 1 is behind the plane: still in contact
        assert c.distance.tolist() == [0.5, -1.0, 0.0]
        assert c.normal.tolist() == [[0, 0, 1]] * 3
        assert c.point.tolist() == [[0, 0, 1], [2, 3, 1], [1, 1, 1]]
        assert c.feature.tolist() == [0, 0, 0] and c.element.tolist() == [0, 0, 0]

    def test_tilted_plane_against_the_definition(self):
        rng = np.random.default_rng(2)
        n = rng.normal(size=3)
        p = Plane(rng.normal(size=3), n)
        x = rng.normal(size=(500, 3)) * 3
        r = rng.uniform(0, 1, 500)
        c = WallSearch([p]).update(x, r)
        d = (x - p.point) @ (n / np.linalg.norm(n))
        assert c.sphere.tolist() == np.flatnonzero(d <= r).tolist()
        np.testing.assert_allclose(c.distance, d[c.sphere], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(c.point @ p.normal, p.point @ p.normal, atol=1e-12)

    def test_moved_plane(self):
        p = Plane([0, 0, 0], [0, 0, 1])
        walls = WallSearch([p])
        assert walls.update([[0, 0, 1.0]], 0.5).sphere.tolist() == []
        p.point = [0, 0, 0.5]
        assert walls.update([[0, 0, 1.0]], 0.5).sphere.tolist() == [0]

    def test_plane_in_partly_periodic_cell(self):
        cell = Cell.from_dimensions([4, 4, 10, 90, 90, 90], pbc=(True, True, False))
        c = WallSearch([Plane([0, 0, 0], [0, 0, 1])]).update([[9.0, -3.0, 0.2]], 0.5, cell)
        assert c.point.tolist() == [[9.0, -3.0, 0.0]]  # in the frame of the given position

    def test_plane_crossing_a_periodic_axis_is_refused(self):
        cell = Cell.from_dimensions([4, 4, 10, 90, 90, 90], pbc=(True, True, False))
        walls = WallSearch([Plane([0, 0, 0], [1, 0, 1])])
        with pytest.raises(ValueError, match=r"walls\[0\] is a Plane .* not perpendicular "
                                             r"to periodic cell vector 0"):
            walls.update([[1.0, 1.0, 1.0]], 0.5, cell)


# ----------------------------------------------------------------- periodic cells


def _image_shifts(cell, pbc, m=2):
    ranges = [range(-m, m + 1) if p else range(1) for p in pbc]
    return [np.array(s, float) @ cell for s in itertools.product(*ranges)]


class TestPeriodic:
    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_mesh_crossing_a_periodic_face(self, n_threads):
        rng = np.random.default_rng(5)
        L = 6.0
        cell = np.diag([L, L, 8.0])
        # a bumpy 3 x 3 patch from x = 4.5 to 7.5: it crosses the face x = L
        v, f = bumpy_mesh(rng, 3)
        v[:, 0] += 4.5
        v[:, 1] += 1.0
        x = np.column_stack((rng.uniform(-2, 8, 400), rng.uniform(0, 5, 400),
                             rng.uniform(-1, 1, 400)))
        r = rng.uniform(0.1, 0.5, 400)
        c = WallSearch([TriangleMesh(v, f)], n_threads=n_threads).update(
            x, r, cell, pbc=(True, False, False))
        oracle = oracle_contacts(x, r, v, f, shifts=_image_shifts(cell, (True, False, False)))
        assert_matches(c, oracle, rtol=1e-9, atol=1e-9)
        # found from both sides of the face, for spheres given in and out of the cell
        xs = x[c.sphere, 0]
        assert (xs < 1.5).any() and (xs > 4.5).any() and (xs < 0).any() and (xs > L).any()

    def test_triclinic_partly_periodic(self):
        rng = np.random.default_rng(6)
        cell = np.array([[5.0, 0, 0], [1.5, 4.0, 0], [0, 0, 9.0]])
        pbc = (True, True, False)
        v, f = bumpy_mesh(rng, 3)
        v[:, :2] += [3.5, 2.5]
        x = np.column_stack((rng.uniform(-3, 9, (500, 2)), rng.uniform(-1, 1, 500)))
        r = rng.uniform(0.1, 0.5, 500)
        c = WallSearch([TriangleMesh(v, f)]).update(x, r, cell, pbc=pbc)
        assert_matches(c, oracle_contacts(x, r, v, f, shifts=_image_shifts(cell, pbc)),
                       rtol=1e-9, atol=1e-9)

    @settings(max_examples=40, deadline=None)
    @given(st.lists(st.tuples(st.integers(-40, 80), st.integers(-40, 80), st.integers(-6, 6)),
                    min_size=1, max_size=10))
    def test_floor_tiling_a_periodic_cell_has_no_seam(self, cells):
        # a 4 x 4 floor filling the periodic x-y cell: a sphere resting on the
        # seam (x = 0 = 4 or y = 0 = 4) gets one contact, as on a plane
        v, f = grid_floor(4, 4)
        cell = Cell.from_dimensions([4, 4, 10, 90, 90, 90], pbc=(True, True, False))
        x = np.array([[i / 8, j / 8, k / 16] for i, j, k in cells])
        c = WallSearch([TriangleMesh(v, f), Plane([0, 0, 0], [0, 0, 1])]).update(
            x, 0.25, cell)
        m = c.wall == 0
        touching = np.flatnonzero(np.abs(x[:, 2]) <= 0.25)
        assert c.sphere[m].tolist() == touching.tolist()
        np.testing.assert_array_equal(c.distance[m], np.abs(x[touching, 2]))
        np.testing.assert_array_equal(c.point[m], np.column_stack((x[touching, :2],
                                                                     np.zeros(len(touching)))))

    def test_seam_a_hair_from_a_vertex(self):
        # on the seam (x = 0 = 4) a hair from the vertex (0, 2) = (4, 2), and around it
        v, f = grid_floor(4, 4)
        cell = Cell.from_dimensions([4, 4, 10, 90, 90, 90], pbc=(True, True, False))
        angles = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
        ring = np.column_stack((4.0 + 1e-7 * np.cos(angles), 2.0 + 1e-7 * np.sin(angles),
                                np.full(24, 0.2)))
        x = np.concatenate([[[3.999999999, 2.0, 0.2], [-1e-12, 3.0, 0.2], [4.0, 2.0, 0.2]],
                            ring])
        c = WallSearch([TriangleMesh(v, f)]).update(x, 0.3, cell)
        assert c.sphere.tolist() == list(range(len(x)))
        np.testing.assert_allclose(c.distance, 0.2, rtol=0, atol=1e-15)

    def test_seam_edge_and_corner(self):
        v, f = grid_floor(4, 4)
        cell = Cell.from_dimensions([4, 4, 10, 90, 90, 90], pbc=(True, True, False))
        x = [[0.0, 0.5, 0.25], [4.0, 2.5, 0.25], [0.0, 0.0, 0.25], [8.0, -4.0, 0.25]]
        c = WallSearch([TriangleMesh(v, f)]).update(x, 0.25, cell)
        assert c.sphere.tolist() == [0, 1, 2, 3]
        assert c.feature.tolist() == [1, 1, 2, 2]
        assert c.point.tolist() == [[0.0, 0.5, 0], [4.0, 2.5, 0], [0, 0, 0], [8.0, -4.0, 0]]


# ----------------------------------------------------------------- moving geometry


class TestMoving:
    def test_vertices_argument_equals_a_fresh_mesh(self):
        rng = np.random.default_rng(8)
        v, f = bumpy_mesh(rng)
        mesh = TriangleMesh(v, f)
        walls = WallSearch([Plane([0, 0, -5], [0, 0, 1]), mesh])
        x = np.column_stack((rng.uniform(0, 5, (300, 2)), rng.uniform(-1, 1, 300)))
        for step in range(4):
            moved = v + [0.1 * step, 0, 0.05 * np.sin(step)]
            moved[:, 2] += rng.uniform(-0.05, 0.05, len(v))
            got = walls.update(x, 0.3, vertices=[None, moved])
            want = WallSearch([Plane([0, 0, -5], [0, 0, 1]), TriangleMesh(moved, f)]).update(
                x, 0.3)
            for a, b in zip(got, want, strict=True):
                np.testing.assert_array_equal(a, b)
            assert_matches(got, oracle_contacts(x, 0.3, moved, f), wall=1, rtol=1e-9,
                           atol=1e-9)
        np.testing.assert_array_equal(mesh.vertices, v)  # for that call only

    def test_vertices_setter_moves_the_mesh(self):
        v, f = grid_floor(2, 2)
        mesh = TriangleMesh(v, f)
        walls = WallSearch([mesh])
        assert len(walls.update([[1.0, 1.0, 1.0]], 0.5).sphere) == 0
        mesh.vertices = v + [0, 0, 0.5]
        assert walls.update([[1.0, 1.0, 1.0]], 0.5).distance.tolist() == [0.5]
        # a single mesh takes the array itself
        assert walls.update([[1.0, 1.0, 1.0]], 0.5, vertices=v).sphere.tolist() == []


# ----------------------------------------------------------------- identity


def _oracle_keys(x, r, v, f, ids, **kwargs):
    """Identity keys of the oracle's contacts, in the search's row order."""
    got = oracle_contacts(x, r, v, f, **kwargs)
    rows = sorted(((k[0], v_[0], k[1]), (ids[k[0]], k[1], k[2])) for k, v_ in got.items())
    return [key for _, key in rows]


class TestIdentity:
    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_rolling_over_a_tiled_floor_against_a_dict(self, n_threads):
        v, f = grid_floor(4, 2)
        walls = WallSearch([TriangleMesh(v, f)], identity=True, n_threads=n_threads)
        prev_keys = prev_ages = None
        history = None
        seen_kinds = set()
        ids_all = np.array([10, 20, 30])
        for step in range(40):
            # sphere 10 rolls along the diagonal lines, 20 along y = 1 (edges and
            # vertices), 30 joins at step 10 and leaves at step 30
            x = np.array([[0.25 + step / 16, 0.25 + step / 32, 0.25],
                          [0.125 + step / 16, 1.0, 0.25],
                          [2.0, 0.5 + step / 64, 0.25]])
            keep = [0, 1] if not 10 <= step < 30 else [0, 1, 2]
            x, ids = x[keep], ids_all[keep]
            c = walls.update(x, 0.25, ids=ids)
            keys = _oracle_keys(x, 0.25, v, f, ids)
            # the oracle's edge/vertex keys are coordinates; the search's rows
            # must be those contacts, in order
            assert [(int(ids[s]), int(k)) for s, k in zip(c.sphere, c.feature, strict=True)] == [
                (key[0], key[1]) for key in keys]
            seen_kinds.update(c.feature.tolist())
            if prev_keys is None:
                want_prev = [-1] * len(keys)
                want_ended = []
            else:
                index = {key: i for i, key in enumerate(prev_keys)}
                want_prev = [index.get(key, -1) for key in keys]
                want_ended = sorted(set(range(len(prev_keys))) - set(want_prev))
            assert walls.previous_rows.tolist() == want_prev
            assert walls.ended_rows.tolist() == want_ended
            # a history (steps in contact) carried by one gather
            history = np.ones(len(keys)) if history is None else walls.carry(history) + 1
            ages = {}
            if prev_keys is not None:
                ages = {key: a for key, a in zip(prev_keys, prev_ages, strict=True)}
            want_ages = [ages.get(key, 0) + 1 for key in keys]
            assert history.tolist() == want_ages
            prev_keys, prev_ages = keys, want_ages
        assert seen_kinds == {0, 1, 2}

    def test_rolling_across_a_periodic_face_against_a_dict(self):
        # a floor tiling a periodic cell; spheres roll across x = 4 = 0 and the
        # script wraps one of them back every few steps: identity by triangle,
        # periodic edge and periodic vertex, whatever the frame of the position
        L = 4.0
        v, f = grid_floor(4, 4)
        cell = Cell.from_dimensions([L, L, 10, 90, 90, 90], pbc=(True, True, False))
        key = [tuple(np.mod(p, [L, L, np.inf])) for p in v]
        shifts = _image_shifts(np.diag([L, L, 10.0]), (True, True, False), m=1)
        walls = WallSearch([TriangleMesh(v, f)], identity=True)
        prev = None
        ids = np.array([5, 9])
        for step in range(48):
            x = np.array([[3.0 + step / 16, 0.5 + step / 64, 0.25],
                          [3.5 + step / 32, 1.0, 0.25]])
            if step % 3 == 0:
                x[0, 0] -= L * np.floor(x[0, 0] / L)  # the script wraps sphere 5
            c = walls.update(x, 0.25, cell, ids=ids)
            keys = _oracle_keys(x, 0.25, v, f, ids, shifts=shifts, vertex_key=key,
                                combine=True)
            assert [(int(ids[s]), int(k)) for s, k in zip(c.sphere, c.feature, strict=True)] \
                == [(k[0], k[1]) for k in keys]
            if prev is not None:
                index = {k: i for i, k in enumerate(prev)}
                assert walls.previous_rows.tolist() == [index.get(k, -1) for k in keys]
                assert walls.ended_rows.tolist() == sorted(
                    set(range(len(prev))) - {index[k] for k in keys if k in index})
            prev = keys

    def test_wrapping_a_sphere_keeps_its_contact(self):
        v, f = grid_floor(4, 4)
        cell = Cell.from_dimensions([4, 4, 10, 90, 90, 90], pbc=(True, True, False))
        walls = WallSearch([TriangleMesh(v, f)], identity=True)
        walls.update([[3.9, 1.2, 0.2]], 0.25, cell)
        walls.update([[4.1, 1.2, 0.2]], 0.25, cell)   # crossed the face, given unwrapped
        assert walls.previous_rows.tolist() == [-1]  # rolled onto the next triangle
        walls.update([[4.1, 1.2, 0.2]], 0.25, cell)
        walls.update([[0.1, 1.2, 0.2]], 0.25, cell)   # the script wrapped it
        assert walls.previous_rows.tolist() == [0]

    def test_first_call_and_carry_fill(self):
        walls = WallSearch([Plane([0, 0, 0], [0, 0, 1])], identity=True)
        assert walls.previous_rows is None  # as ContactSearch before its first call
        with pytest.raises(ValueError, match="carry needs a previous update"):
            walls.carry(np.zeros(0))
        walls.update([[0, 0, 0.1], [0, 0, 5]], 0.5)
        assert walls.previous_rows.tolist() == [-1] and walls.ended_rows.tolist() == []
        h = np.array([[1.0, 2.0, 3.0]])
        walls.update([[0, 0, 0.2], [0, 0, 0.3]], 0.5)
        np.testing.assert_array_equal(walls.carry(h, fill=-1.0), [[1, 2, 3], [-1, -1, -1]])
        out = np.empty((2, 3))
        assert walls.carry(h, out=out) is out
        with pytest.raises(ValueError, match=r"history must have one row per contact of the "
                                             r"previous call's result \(1 rows\)"):
            walls.carry(np.zeros(3))

    def test_previous_rows_survive_the_next_call(self):
        # as the searches' results: valid and unchanged until the call after next
        walls = WallSearch([Plane([0, 0, 0], [0, 0, 1])], identity=True)
        walls.update([[0, 0, 0.1], [1, 0, 0.1]], 0.5)
        walls.update([[1, 0, 0.1], [2, 0, 0.1], [0, 0, 0.1]], 0.5, ids=[1, 2, 0])
        rows = walls.previous_rows
        kept = rows.copy()
        walls.update([[5, 0, 0.1]], 0.5, ids=[7])
        np.testing.assert_array_equal(rows, kept)

    def test_identity_off(self):
        walls = WallSearch([Plane([0, 0, 0], [0, 0, 1])])
        walls.update([[0, 0, 0.1]], 0.5)
        with pytest.raises(ValueError, match=r"contact identity needs WallSearch\(\.\.\., "
                                             r"identity=True\)"):
            _ = walls.previous_rows
        with pytest.raises(ValueError, match="contact identity needs"):
            walls.carry(np.zeros(1))


# ----------------------------------------------------------------- files


class TestRebuildMargin:
    """A mesh's broad phase kept within ``rebuild_margin`` gives the contacts of a
    margin of 0, row for row and bit for bit."""

    @staticmethod
    def _walk(periodic, n_threads, margin, steps=40, seed=3):
        rng = np.random.default_rng(seed)
        L = 5.0
        v, f = bumpy_mesh(rng, 5)
        mesh = TriangleMesh(v, f)
        walls = WallSearch([Plane([0, 0, -1.5], [0, 0, 1]), mesh], identity=True,
                           n_threads=n_threads, rebuild_margin=margin)
        cell = Cell.from_dimensions([L, L, 10, 90, 90, 90], pbc=(True, True, False)) \
            if periodic else None
        n = 300
        # (in a periodic cell a sphere wrapped across a face needs the pairs of
        # other images: a rebuild; these stay clear of the faces, yet within
        # reach of the images of the triangles across them)
        lo, hi = (0.45, 4.55) if periodic else (-0.5, 5.5)
        x = np.column_stack((rng.uniform(lo, hi, n), rng.uniform(lo, hi, n),
                             rng.uniform(-0.6, 0.8, n)))
        r = rng.uniform(0.1, 0.45, n)
        ids = rng.permutation(n) + 100
        out = []
        for step in range(steps):
            x += rng.normal(0.0, 0.01, x.shape)
            if step == 25:  # radii change: the kept pairs cannot serve
                r = r * 1.01
            if step == 30:  # a sphere jumps farther than any margin
                x[7] += [0.0, 0.0, 0.9]
            if step == 35:  # the rows re-ordered (a script sorting its spheres in space)
                order = np.argsort(x[:, 0], kind="stable")
                x, r, ids = x[order], r[order], ids[order]
            c = walls.update(x, r, cell, ids=ids)
            out.append((_rows(c), walls.previous_rows.tolist(), walls.ended_rows.tolist(),
                        walls.stats["rebuilt"]))
        return out

    @pytest.mark.parametrize("n_threads", [1, 2])
    @pytest.mark.parametrize("periodic", [False, True])
    def test_kept_pairs_give_the_contacts_of_no_margin(self, periodic, n_threads):
        plain = self._walk(periodic, n_threads, 0.0)
        kept = self._walk(periodic, n_threads, 0.15)
        for step, (a, b) in enumerate(zip(plain, kept, strict=True)):
            assert a[:3] == b[:3], step
        assert all(a[3] for a in plain)  # a margin of 0 builds every call
        rebuilt = [b[3] for b in kept]
        assert rebuilt[0] and rebuilt[25] and rebuilt[30] and rebuilt[35]
        assert rebuilt.count(False) >= 20  # the kept pairs served most calls
        rows = [row for a in plain for row in a[0]]
        assert {row[3] for row in rows if row[1] == 1} == {0, 1, 2}  # faces, edges, vertices

    def test_moving_vertices_build_every_call(self):
        rng = np.random.default_rng(8)
        v, f = bumpy_mesh(rng, 3)
        x = np.column_stack((rng.uniform(0, 3, 50), rng.uniform(0, 3, 50),
                             rng.uniform(-0.3, 0.5, 50)))
        plain = WallSearch([TriangleMesh(v, f)])
        kept = WallSearch([TriangleMesh(v, f)], rebuild_margin=0.5)
        for step in range(4):
            moved = v + [0.0, 0.0, 0.05 * step]
            a = plain.update(x, 0.3, vertices=moved)
            b = kept.update(x, 0.3, vertices=moved)
            assert _rows(a) == _rows(b)
            assert kept.stats["rebuilt"]

    def test_planes_only_have_no_broad_phase(self):
        walls = WallSearch([Plane([0, 0, 0], [0, 0, 1])], rebuild_margin=0.2)
        walls.update([[0.0, 0.0, 0.1]], 0.2)
        assert walls.stats["rebuilt"] is False

    def test_margin_argument(self):
        with pytest.raises(ValueError, match="rebuild_margin must be non-negative"):
            WallSearch([Plane([0, 0, 0], [0, 0, 1])], rebuild_margin=-0.1)
        with pytest.raises(ValueError, match="rebuild_margin must be finite"):
            WallSearch([Plane([0, 0, 0], [0, 0, 1])], rebuild_margin=float("inf"))


class TestRead:
    @pytest.mark.parametrize("name, kwargs", [("floor.stl", {"binary": True}),
                                              ("floor-ascii.stl", {"binary": False}),
                                              ("floor.obj", {}), ("floor.vtk", {}),
                                              ("floor.vtu", {})])
    def test_formats(self, tmp_path, name, kwargs):
        meshio = pytest.importorskip("meshio")
        v, f = grid_floor(3, 2, step=0.5)
        path = tmp_path / name
        meshio.write(path, meshio.Mesh(v, [("triangle", f)]), **kwargs)
        mesh = TriangleMesh.read(path)
        ref = TriangleMesh(v, f)
        assert len(mesh) == len(f)
        assert len(mesh.edges) == len(ref.edges)
        x = np.array([[0.5, 0.5, 0.1], [0.25, 0.25, 0.1], [0.7, 0.3, 0.1]])
        a = WallSearch([mesh]).update(x, 0.1)
        b = WallSearch([ref]).update(x, 0.1)
        assert a.feature.tolist() == b.feature.tolist() == [2, 1, 0]
        np.testing.assert_allclose(a.point, b.point, rtol=0, atol=1e-6)  # STL is float32

    def test_no_triangles(self, tmp_path):
        meshio = pytest.importorskip("meshio")
        path = tmp_path / "lines.vtk"
        meshio.write(path, meshio.Mesh(np.eye(3), [("line", np.array([[0, 1], [1, 2]]))]))
        with pytest.raises(ValueError, match=r"has no triangles \(cell types: \['line'\]\)"):
            TriangleMesh.read(path)

    def test_missing_file(self, tmp_path):
        with pytest.raises(FileNotFoundError, match="no mesh file at"):
            TriangleMesh.read(tmp_path / "nothing.stl")


# ----------------------------------------------------------------- errors


class TestErrors:
    def test_bad_vertices_and_faces(self):
        with pytest.raises(ValueError, match=r"vertices must have shape \(n, 3\), got \(4, 2\)"):
            TriangleMesh(np.zeros((4, 2)), [[0, 1, 2]])
        with pytest.raises(ValueError, match=r"faces must have shape \(f, 3\)"):
            TriangleMesh(np.eye(3), [[0, 1]])
        with pytest.raises(ValueError, match=r"faces must index the 3 vertices \(0 to 2\), got "
                                             r"faces\[0, 2\] = 3"):
            TriangleMesh(np.eye(3), [[0, 1, 3]])
        with pytest.raises(ValueError, match=r"faces\[0, 0\] = -1"):
            TriangleMesh(np.eye(3), [[-1, 1, 2]])
        with pytest.raises(TypeError, match="faces must be integers"):
            TriangleMesh(np.eye(3), [[0, 1, 2.5]])
        with pytest.raises(ValueError, match="faces must not be empty"):
            TriangleMesh(np.eye(3), np.empty((0, 3), int))
        with pytest.raises(ValueError, match="vertices must be finite"):
            TriangleMesh([[0, 0, 0], [1, 0, np.nan], [0, 1, 0]], [[0, 1, 2]])

    def test_degenerate_triangles_refused_or_dropped(self):
        v = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]]
        with pytest.raises(ValueError, match=r"faces: triangle 1 is degenerate \(zero area"):
            TriangleMesh(v, [[0, 1, 2], [0, 1, 3]])     # collinear
        with pytest.raises(ValueError, match="triangle 0 is degenerate"):
            TriangleMesh(v, [[0, 0, 2]])                 # repeated vertex
        mesh = TriangleMesh(v, [[0, 1, 2], [0, 1, 3], [1, 1, 2]], degenerate="drop")
        assert mesh.faces.tolist() == [[0, 1, 2]]
        with pytest.raises(ValueError, match="every triangle is degenerate"):
            TriangleMesh(v, [[0, 1, 3]], degenerate="drop")
        with pytest.raises(ValueError, match="degenerate must be 'raise' or 'drop'"):
            TriangleMesh(v, [[0, 1, 2]], degenerate="keep")
        mesh = TriangleMesh(v, [[0, 1, 2]])
        with pytest.raises(ValueError, match="vertices: triangle 0 is degenerate"):
            mesh.vertices = [[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 0, 0]]

    def test_moved_vertices(self):
        v, f = grid_floor(1, 1)
        walls = WallSearch([Plane([0, 0, 0], [0, 0, 1]), TriangleMesh(v, f)])
        with pytest.raises(ValueError, match=r"vertices\[1\] must have the mesh's shape "
                                             r"\(4, 3\)"):
            walls.update([[0, 0, 0.0]], 0.1, vertices=[None, v[:3]])
        with pytest.raises(ValueError, match=r"vertices\[0\] is given for a Plane"):
            walls.update([[0, 0, 0.0]], 0.1, vertices=[v, None])
        two = WallSearch([TriangleMesh(v, f), TriangleMesh(v, f)])
        with pytest.raises(ValueError, match="one entry per wall"):
            two.update([[0, 0, 0.0]], 0.1, vertices=v)

    def test_search_arguments(self):
        plane = Plane([0, 0, 0], [0, 0, 1])
        with pytest.raises(ValueError, match="walls must hold at least one"):
            WallSearch([])
        with pytest.raises(TypeError, match=r"walls\[1\] must be a Plane or a TriangleMesh, "
                                            r"got str"):
            WallSearch([plane, "floor.stl"])
        with pytest.raises(ValueError, match="skin must be non-negative"):
            WallSearch([plane], skin=-1)
        with pytest.raises(TypeError, match="identity must be True or False"):
            WallSearch([plane], identity="yes")
        with pytest.raises(ValueError, match="n_threads must be between"):
            WallSearch([plane], n_threads=0)
        walls = WallSearch([plane])
        with pytest.raises(ValueError, match=r"positions must have shape \(n, 3\)"):
            walls.update(np.zeros((3, 2)), 0.1)
        with pytest.raises(ValueError, match="radii must be non-negative"):
            walls.update(np.zeros((2, 3)), [0.1, -0.1])
        with pytest.raises(ValueError, match="ids must be unique, got 4 more than once"):
            walls.update(np.zeros((2, 3)), 0.1, ids=[4, 4])
        with pytest.raises(ValueError, match=r"ids must have shape \(2,\)"):
            walls.update(np.zeros((2, 3)), 0.1, ids=[4])
        with pytest.raises(TypeError, match="ids must be integers"):
            walls.update(np.zeros((2, 3)), 0.1, ids=[4.0, 5.0])
        # ids found unique once are not sorted again while equal: the same array
        # changed in place to repeat an id is still refused
        ids = np.array([3, 9])
        walls.update(np.zeros((2, 3)), 0.1, ids=ids)
        walls.update(np.zeros((2, 3)), 0.1, ids=ids)
        ids[1] = 3
        with pytest.raises(ValueError, match="ids must be unique, got 3 more than once"):
            walls.update(np.zeros((2, 3)), 0.1, ids=ids)

    def test_plane_arguments(self):
        with pytest.raises(ValueError, match=r"normal must be a non-zero vector"):
            Plane([0, 0, 0], [0, 0, 0])
        with pytest.raises(ValueError, match=r"point must have shape \(3,\), got \(2,\)"):
            Plane([0, 0], [0, 0, 1])
        with pytest.raises(ValueError, match="normal must be finite"):
            Plane([0, 0, 0], [0, np.inf, 1])

    def test_empty_frames(self):
        v, f = grid_floor(1, 1)
        walls = WallSearch([TriangleMesh(v, f), Plane([0, 0, 0], [0, 0, 1])], identity=True)
        c = walls.update(np.empty((0, 3)), 0.1)
        assert all(len(a) == 0 for a in c)
        assert c.normal.shape == (0, 3) and c.sphere.dtype == np.int64
        assert walls.previous_rows.tolist() == []
        # contacts, none, contacts again: every row ends, then every row is new
        walls.update([[0.5, 0.25, 0.1]], 0.2)
        walls.update(np.empty((0, 3)), 0.2)
        assert walls.previous_rows.tolist() == [] and walls.ended_rows.tolist() == [0, 1]
        assert walls.carry(np.ones(2)).shape == (0,)
        walls.update([[0.5, 0.25, 0.1]], 0.2)
        assert walls.previous_rows.tolist() == [-1, -1] and walls.ended_rows.tolist() == []


# ----------------------------------------------------------------- cross-set boxes


def brute_cross(la, ua, lb, ub):
    la, ua, lb, ub = (np.asarray(a, float).reshape(-1, 3) for a in (la, ua, lb, ub))
    ov = ((la[:, None, :] <= ub[None]) & (lb[None] <= ua[:, None, :])).all(-1)
    return np.argwhere(ov).astype(np.int64).reshape(-1, 2)


class TestCrossBoxes:
    @pytest.mark.parametrize("n_threads", [1, 2])
    @pytest.mark.parametrize("seed", [0, 1])
    def test_random_against_brute_force(self, seed, n_threads):
        rng = np.random.default_rng(seed)
        la = rng.uniform(0, 10, (700, 3))
        lb = rng.uniform(0, 10, (400, 3))
        ua = la + rng.uniform(0, 1, la.shape)
        ub = lb + rng.exponential(0.5, lb.shape)
        got = box_overlaps(la, ua, lb, ub, n_threads=n_threads)
        np.testing.assert_array_equal(got, brute_cross(la, ua, lb, ub))
        assert got.dtype == np.int64

    @settings(max_examples=80, deadline=None)
    @given(st.lists(st.tuples(*[st.integers(0, 4)] * 3, *[st.integers(0, 2)] * 3),
                    min_size=0, max_size=20),
           st.lists(st.tuples(*[st.integers(0, 4)] * 3, *[st.integers(0, 2)] * 3),
                    min_size=0, max_size=20))
    def test_touching_integer_boxes(self, a, b):
        # integer corners: many boxes touch exactly (closed boxes count)
        a = np.array(a, float).reshape(-1, 6)
        b = np.array(b, float).reshape(-1, 6)
        la, ua = a[:, :3], a[:, :3] + a[:, 3:]
        lb, ub = b[:, :3], b[:, :3] + b[:, 3:]
        want = brute_cross(la, ua, lb, ub)
        np.testing.assert_array_equal(box_overlaps(la, ua, lb, ub), want)
        np.testing.assert_array_equal(box_overlaps(la, ua, lb, ub, n_threads=2), want)
        # swapping the sets swaps the columns
        swapped = box_overlaps(lb, ub, la, ua)
        np.testing.assert_array_equal(swapped[:, ::-1][np.lexsort((swapped[:, 0],
                                                                   swapped[:, 1]))], want)

    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_big_boxes_in_both_sets(self, n_threads):
        # a few boxes spanning most of the grid go to the sweep, the rest to the
        # grid; pairs between the two kinds are found once
        rng = np.random.default_rng(11)
        la = rng.uniform(0, 20, (2000, 3))
        ua = la + rng.uniform(0, 0.5, la.shape)
        lb = rng.uniform(0, 20, (1500, 3))
        ub = lb + rng.uniform(0, 0.5, lb.shape)
        for lo, hi in ((la, ua), (lb, ub)):
            hi[:8] = lo[:8] + rng.uniform(5, 20, (8, 3))
        hi_a = ua.copy()
        hi_a[8:12, 0] += 19.0  # long along one axis only
        got = box_overlaps(la, hi_a, lb, ub, n_threads=n_threads)
        np.testing.assert_array_equal(got, brute_cross(la, hi_a, lb, ub))
        assert len(got) > 1000

    @pytest.mark.parametrize("n_big", [3, 20])
    def test_one_thread_query_in_one_pass(self, n_big, monkeypatch):
        # one thread runs the query in one serial pass (grid_query): more pairs
        # than its first guess of room (it runs again with room), a few big
        # boxes of B tested against every box of A (beyond _FUSED_BIG: the
        # general passes), a box of A visiting too many cells (the general
        # passes); the rows are those of two threads and the brute force
        from granularsap.kernels import cross

        calls = []
        real = cross.grid_query
        monkeypatch.setattr(cross, "grid_query", lambda *a: calls.append(1) or real(*a))
        rng = np.random.default_rng(21)
        lb = rng.uniform(0, 10, (4000, 3))
        ub = lb + rng.uniform(0, 0.3, lb.shape)
        ub[:n_big] = lb[:n_big] + 8.0
        la = rng.uniform(0, 10, (200, 3))
        ua = la + 0.2
        ua[:6] = la[:6] + 3.0  # some 100 boxes of B each: beyond 2 n + 64 rows
        big_a = ua.copy()
        big_a[0] = la[0] + 10.0  # visits the whole grid
        plan = granularsap.boxes._cross_grid_plan(la, ua, lb, ub)
        spans = np.empty(len(lb), np.int64)
        cross.spans(lb, ub, plan[0], plan[2], plan[3], spans)
        assert (spans > granularsap.boxes._CROSS_MAX_SPAN).sum() == n_big
        for hi_a, fused in ((ua, n_big <= 16), (big_a, False)):
            want = brute_cross(la, hi_a, lb, ub)
            assert len(want) > 2 * len(la) + 64
            calls.clear()
            np.testing.assert_array_equal(box_overlaps(la, hi_a, lb, ub, n_threads=1), want)
            assert len(calls) == (2 if fused else 0 if n_big > 16 else 1)
            np.testing.assert_array_equal(box_overlaps(la, hi_a, lb, ub, n_threads=2), want)

    @pytest.mark.parametrize("scale", [1e-300, 1.0, 1e300])
    def test_points_and_extreme_coordinates(self, scale):
        rng = np.random.default_rng(12)
        a = rng.integers(-3, 4, (300, 3)).astype(float) * scale
        b = rng.integers(-3, 4, (200, 3)).astype(float) * scale
        # points (zero-size boxes) against unit boxes: touching counts
        want = brute_cross(a, a, b, b + scale)
        np.testing.assert_array_equal(box_overlaps(a, a, b, b + scale), want)
        np.testing.assert_array_equal(box_overlaps(a, a, b, b), brute_cross(a, a, b, b))

    def test_every_axis_can_be_the_sweep(self):
        rng = np.random.default_rng(9)
        for axis in range(3):
            la = rng.uniform(0, 1, (300, 3))
            la[:, axis] *= 100  # spread along this axis: it becomes the sweep axis
            lb = rng.uniform(0, 1, (200, 3))
            lb[:, axis] *= 100
            ua, ub = la + 0.3, lb + 0.3
            assert granularsap.boxes._cross_axis(la, ua, lb, ub) == axis
            np.testing.assert_array_equal(box_overlaps(la, ua, lb, ub),
                                          brute_cross(la, ua, lb, ub))

    @pytest.mark.parametrize("n_threads", [1, 2])
    def test_kept_second_set_across_frames(self, n_threads):
        # SweepAndPrune keeps the second set's grid while it does not change;
        # every frame equals the brute force whether it was kept or rebuilt
        rng = np.random.default_rng(14)
        engine = granularsap.SweepAndPrune(n_threads=n_threads)
        lb = rng.uniform(0, 10, (500, 3))
        ub = lb + rng.uniform(0, 0.6, lb.shape)
        la = rng.uniform(0, 10, (800, 3))
        kept = []
        for frame in range(11):
            la = la + rng.normal(0, 0.05, la.shape)
            # the first set's boxes grow past a power of two from frame 8: the
            # grid's cells (and the kept plan) follow, then stay again
            ua = la + (0.4 if frame < 8 else 1.5)
            if frame == 5:
                lb = lb + 0.01  # the second set moved: binned again
                ub = ub + 0.01
            got = engine.update(la, ua, lb, ub)
            np.testing.assert_array_equal(got, brute_cross(la, ua, lb, ub))
            kept.append(engine.stats["second_set_kept"])
            assert engine.stats["path"] == "cross"
        assert kept == [False, True, True, True, True, False, True, True, False, True, True]
        # and the engine still answers within one set
        within = engine.update(la, ua)
        within = within[np.lexsort((within[:, 1], within[:, 0]))]
        ref = box_overlaps(la, ua)
        np.testing.assert_array_equal(within, ref[np.lexsort((ref[:, 1], ref[:, 0]))])
        with pytest.raises(ValueError, match="upper_b was given without lower_b"):
            engine.update(la, ua, upper_b=ub)

    def test_errors_name_the_second_set(self):
        ok = np.zeros((2, 3))
        with pytest.raises(ValueError, match="lower_b must not exceed upper_b, got "
                                             "lower_b=1.0 > upper_b=0.0 at box 1, axis 2"):
            box_overlaps(ok, ok, [[0, 0, 0], [0, 0, 1.0]], [[0, 0, 0], [0, 0, 0.0]])
        with pytest.raises(ValueError, match=r"lower_b must have shape \(n, 3\)"):
            box_overlaps(ok, ok, np.zeros((2, 2)), np.zeros((2, 2)))
        with pytest.raises(ValueError, match="lower_b and upper_b must have the same number"):
            box_overlaps(ok, ok, np.zeros((2, 3)), np.zeros((3, 3)))
        with pytest.raises(ValueError, match="upper_b must be finite, got NaN or inf in row 0"):
            box_overlaps(ok, ok, np.zeros((1, 3)), [[np.nan, 0, 0]])
        with pytest.raises(ValueError, match="lower_b was given without upper_b"):
            box_overlaps(ok, ok, np.zeros((1, 3)))
        with pytest.raises(ValueError, match="upper_b was given without lower_b"):
            box_overlaps(ok, ok, upper_b=np.zeros((1, 3)))
        with pytest.raises(TypeError, match="lower_b must be an array of real numbers"):
            box_overlaps(ok, ok, [["a", "b", "c"]], np.zeros((1, 3)))

    def test_empty_sets(self):
        z = np.empty((0, 3))
        one = np.zeros((1, 3))
        for args in ((z, z, one, one), (one, one, z, z), (z, z, z, z)):
            got = box_overlaps(*args)
            assert got.shape == (0, 2) and got.dtype == np.int64


def test_docstring_examples():
    result = doctest.testmod(granularsap.walls,
                             optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0 and result.attempted > 0


@pytest.mark.parametrize("how", ["attribute", "per call"])
def test_moved_vertices_meet_across_periodic_faces_where_they_are_now(how):
    """Which vertices meet across a periodic face is found again when the mesh's
    vertices move: a seam row raised into a step gives the contacts a fresh mesh
    of the moved vertices gives (an edge contact at the step), and back."""
    L = 4.0
    g = np.linspace(0, L, 3)
    X, Y = np.meshgrid(g, g, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(9)])
    a = np.array([0, 1, 3, 4])
    F = np.concatenate([np.stack((a, a + 3, a + 4), 1), np.stack((a, a + 4, a + 1), 1)])
    cell = Cell(np.diag([L, L, 20.0]), pbc=[True, True, False])
    raised = V.copy()
    raised[V[:, 0] == L, 2] = 0.3  # the x = L row raised: a step at the seam
    x = np.array([[0.05, 1.0, 0.45], [2.0, 2.0, 0.4]])
    mesh = TriangleMesh(V, F)
    search = WallSearch([mesh])
    for verts in (V, raised, V, raised):
        if how == "attribute":
            mesh.vertices = verts
            got = search.update(x, 0.5, cell)
        else:
            got = search.update(x, 0.5, cell, vertices=verts)
        want = WallSearch([TriangleMesh(verts, F)]).update(x, 0.5, cell)
        for name in ("sphere", "element", "feature", "distance", "normal", "point"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert 1 in want.feature.tolist()  # the raised row's edge: the contact at the step
