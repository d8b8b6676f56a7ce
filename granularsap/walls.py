"""Contacts between spheres and walls: planes and triangle meshes.

:class:`WallSearch` finds, for a frame of spheres, every sphere in contact
with a list of walls (:class:`Plane` half-spaces and :class:`TriangleMesh`
surfaces), with the distance from the centre to the closest point of the
wall, that point and the contact normal; optionally, which contact of the
previous call each one continues (contact identity, for tangential history).

Algorithm (docs/walls.md):

* broad phase through the box engine: the boxes ``centre +- (r + skin)`` of
  the spheres against the boxes of the triangles (the cross-set query of
  :class:`granularsap.SweepAndPrune`, which keeps a static mesh's grid);
* narrow phase: the exact closest point of each candidate triangle
  (Ericson's ``ClosestPtPointTriangle``, ``kernels/triangles.py``), which
  also tells the feature it lies on: the face, an edge or a vertex;
* de-duplication for one sphere and one mesh as DEM codes do it: an edge or
  vertex point is dropped when a triangle having that edge or vertex is
  closer to the centre elsewhere (no local minimum of the distance); a face
  contact always counts; an edge contact counts when no triangle having that
  edge has a face contact with the sphere, once per edge; a vertex contact
  counts when no triangle having that vertex has a face or an edge contact
  with the sphere, once per vertex.  So a sphere resting on a flat tiling
  gets one contact wherever it rests, on a face, across an edge or over a
  vertex shared by any number of triangles.

Periodic cells: spheres are wrapped into the cell along periodic axes, and
every triangle that comes within reach of the cell gets the images (shifted
by cell vectors) that do, so a mesh crossing a periodic face is found from
both sides; points and normals are reported in the frame of each sphere's
given position.  Vertices that coincide modulo the periodic cell vectors are
one vertex for the de-duplication (a floor tiling a periodic cell has no
seam).
"""

from __future__ import annotations

import os
import warnings
from typing import NamedTuple

import numpy as np

from ._numba import num_threads
from ._validate import as_coords, as_scalar, as_vector, check_n_threads
from .boxes import SweepAndPrune
from .cell import Cell
from .identity import ContactIdentity
from .kernels import triangles as _tri

__all__ = ["Plane", "TriangleMesh", "WallContacts", "WallSearch"]

FACE, EDGE, VERTEX = 0, 1, 2
#: candidates below which one thread does the work unless n_threads asks otherwise
_PARALLEL_MIN = 32768
#: relative guard of the broad phase's boxes against rounding (the exact
#: distance test decides)
_GUARD = 1e-12
#: raw contacts of one sphere closer than this fraction of its reach r + skin
#: are at the same distance (the de-duplication's ties)
_TIE = 1e-9
#: resolution of the periodic identification of vertices, in cell lengths
_PERIODIC_TOL = 2.0 ** -33
#: a triangle whose doubled area is below this fraction of its longest edge
#: squared is degenerate (collinear or repeated vertices)
_DEGENERATE = 1e-12


def _vector3(x, name, *, unit=False):
    arr = np.asarray(x)
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"{name} must be 3 real numbers, got dtype {arr.dtype}")
    if arr.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {arr.shape}")
    arr = np.array(arr, dtype=np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    if unit:
        norm = float(np.sqrt(arr @ arr))
        if not norm > 0 or not np.isfinite(norm):
            raise ValueError(f"{name} must be a non-zero vector, got {arr.tolist()}")
        arr = arr / norm
    arr.flags.writeable = False
    return arr


class Plane:
    """A flat wall: the half-space behind a plane.

    The solid is the side the normal points away from; spheres live on the
    side it points to.  A sphere is in contact when the signed distance of its
    centre to the plane, ``(x - point) . normal``, is at most ``r + skin``.
    Spheres whose centre is *behind* the plane (negative distance: a sphere
    pushed through it) still count, with that negative distance, so that an
    overlap ``r - distance`` keeps pushing them out instead of losing them.

    Parameters
    ----------
    point : (3,) array_like of float
        Any point of the plane.
    normal : (3,) array_like of float
        Direction of the open side; normalised to unit length.

    Raises
    ------
    ValueError
        Wrong shape, NaN or inf, or a zero normal.

    Notes
    -----
    Move a plane between calls by setting :attr:`point` or :attr:`normal`.
    In a periodic cell the normal must be perpendicular to every periodic
    cell vector (a floor under x-y periodic walls), else
    :meth:`WallSearch.update` refuses it.

    Examples
    --------
    >>> from granularsap import Plane
    >>> floor = Plane(point=[0, 0, 0], normal=[0, 0, 2])
    >>> floor.normal.tolist()
    [0.0, 0.0, 1.0]
    """

    def __init__(self, point, normal):
        self.point = point
        self.normal = normal

    @property
    def point(self):
        """(3,) float64, read-only: a point of the plane."""
        return self._point

    @point.setter
    def point(self, value):
        self._point = _vector3(value, "point")

    @property
    def normal(self):
        """(3,) float64, read-only: the unit normal, towards the open side."""
        return self._normal

    @normal.setter
    def normal(self, value):
        self._normal = _vector3(value, "normal", unit=True)

    def __repr__(self):
        return f"Plane(point={self._point.tolist()}, normal={self._normal.tolist()})"


def _as_faces(faces, nv):
    arr = np.asarray(faces)
    if arr.dtype.kind not in "iu":
        if arr.dtype.kind == "f" and arr.size and np.isfinite(arr).all() and np.all(
                arr == np.round(arr)):
            arr = arr.astype(np.int64)
        elif arr.size == 0 and arr.dtype.kind == "f":
            arr = arr.astype(np.int64)
        else:
            raise TypeError(f"faces must be integers (vertex indices), got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"faces must have shape (f, 3) (three vertex indices per triangle), "
                         f"got {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError("faces must not be empty: a mesh needs at least one triangle")
    arr = np.ascontiguousarray(arr, dtype=np.int64)
    bad = (arr < 0) | (arr >= nv)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise ValueError(f"faces must index the {nv} vertices (0 to {nv - 1}), got "
                         f"faces[{int(row)}, {int(col)}] = {int(arr[row, col])}")
    return arr


def _check_degenerate(tri, name):
    """ValueError naming the first zero-area triangle of ``tri`` (f, 3, 3)."""
    ab = tri[:, 1] - tri[:, 0]
    ac = tri[:, 2] - tri[:, 0]
    bc = tri[:, 2] - tri[:, 1]
    area2 = np.linalg.norm(np.cross(ab, ac), axis=1)
    longest = np.maximum(np.maximum((ab * ab).sum(1), (ac * ac).sum(1)), (bc * bc).sum(1))
    bad = ~(area2 > _DEGENERATE * longest)
    if bad.any():
        t = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{name}: triangle {t} is degenerate (zero area: repeated or collinear vertices "
            f"{tri[t].tolist()}); remove it, or build the mesh with "
            "TriangleMesh(..., degenerate='drop')")


def _adjacency(vid, faces):
    """Vertex ids of each face's corners, the unique edges (pairs of vertex
    ids, smaller first) and each face's edge ids (AB, BC, CA)."""
    cv = vid[faces]
    f = len(faces)
    ends = np.concatenate((cv[:, [0, 1]], cv[:, [1, 2]], cv[:, [2, 0]]))
    ends.sort(axis=1)
    edges, inverse = np.unique(ends, axis=0, return_inverse=True)
    face_edges = np.ascontiguousarray(inverse.reshape(3, f).T, dtype=np.int64)
    return np.ascontiguousarray(cv), np.ascontiguousarray(edges, dtype=np.int64), face_edges


class TriangleMesh:
    """A wall made of triangles (two-sided: spheres may touch either side).

    Parameters
    ----------
    vertices : (v, 3) array_like of float
        Vertex positions.
    faces : (f, 3) array_like of int
        Three vertex indices per triangle.
    degenerate : {"raise", "drop"}
        What to do with zero-area triangles (repeated or collinear vertices,
        which have no normal): refuse them (default) or leave them out (the
        faces kept are :attr:`faces`, and contacts report rows of it).

    Raises
    ------
    ValueError
        Wrong shapes, NaN or inf, indices out of range, no faces, or a
        degenerate triangle with ``degenerate="raise"``.
    TypeError
        Non-numeric vertices or non-integer faces.

    Notes
    -----
    Vertices with exactly the same coordinates are one vertex for the
    de-duplication of edge and vertex contacts (an STL file repeats every
    vertex once per triangle); the vertex and edge adjacency is built once,
    here.  :attr:`vertex_ids` maps each vertex to its representative (the
    lowest index with those coordinates) and :attr:`edges` lists the edges
    as pairs of representatives.

    Move the mesh between calls by setting :attr:`vertices` (same topology),
    or for one call with ``WallSearch.update(..., vertices=...)``.

    Examples
    --------
    >>> from granularsap import TriangleMesh
    >>> square = TriangleMesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]],
    ...                       [[0, 1, 2], [0, 2, 3]])
    >>> square.edges.tolist()       # the diagonal 0-2 is shared
    [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]
    """

    def __init__(self, vertices, faces, *, degenerate="raise"):
        if degenerate not in ("raise", "drop"):
            raise ValueError(f"degenerate must be 'raise' or 'drop', got {degenerate!r}")
        verts = as_coords(vertices, "vertices", allow_empty=False).copy()  # the mesh's own
        faces = _as_faces(faces, len(verts)).copy()
        if degenerate == "drop":
            tri = verts[faces]
            ab = tri[:, 1] - tri[:, 0]
            ac = tri[:, 2] - tri[:, 0]
            bc = tri[:, 2] - tri[:, 1]
            area2 = np.linalg.norm(np.cross(ab, ac), axis=1)
            longest = np.maximum(np.maximum((ab * ab).sum(1), (ac * ac).sum(1)),
                                 (bc * bc).sum(1))
            faces = np.ascontiguousarray(faces[area2 > _DEGENERATE * longest])
            if len(faces) == 0:
                raise ValueError("faces: every triangle is degenerate (zero area)")
        _check_degenerate(verts[faces], "faces")
        verts.flags.writeable = False
        faces.flags.writeable = False
        self._vertices = verts
        self._faces = faces
        # exact duplicates are one vertex: the lowest index with those coordinates
        _, first, inverse = np.unique(verts + 0.0, axis=0, return_index=True,
                                      return_inverse=True)
        self._vid = np.ascontiguousarray(first[inverse.reshape(-1)], dtype=np.int64)
        self._vid.flags.writeable = False
        self._corners, self._edges, self._face_edges = _adjacency(self._vid, faces)
        for a in (self._corners, self._edges, self._face_edges):
            a.flags.writeable = False
        self._periodic = None

    @classmethod
    def read(cls, path, *, file_format=None, degenerate="raise"):
        """A mesh from a file: STL (binary or ASCII), OBJ, VTK, VTU, PLY, OFF, ...

        Read with meshio (optional dependency: ``pip install
        "granularsap[mesh]"``); every triangle cell block of the file is
        used.  Vertices an STL file repeats per triangle are merged by
        meshio, and exact duplicates left by any format are one vertex here.

        Parameters
        ----------
        path : str or os.PathLike
            The mesh file.
        file_format : str, optional
            meshio's format name when the extension does not tell it
            (``"stl"``, ``"obj"``, ``"vtk"``, ...).
        degenerate : {"raise", "drop"}
            As for :class:`TriangleMesh`.

        Returns
        -------
        TriangleMesh

        Raises
        ------
        ImportError
            meshio is not installed.
        ValueError
            The file has no triangles, or a degenerate one (``degenerate="raise"``).
        FileNotFoundError
            No file at ``path``.

        Examples
        --------
        >>> import os, tempfile
        >>> import numpy as np, meshio
        >>> from granularsap import TriangleMesh
        >>> path = os.path.join(tempfile.mkdtemp(), "triangle.stl")
        >>> pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
        >>> meshio.write(path, meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2]]))]))
        >>> TriangleMesh.read(path).faces.tolist()
        [[0, 1, 2]]
        """
        try:
            import meshio
        except ImportError as exc:  # pragma: no cover - meshio is in the test extra
            raise ImportError("TriangleMesh.read needs meshio; install it with "
                              "pip install 'granularsap[mesh]' (or pip install meshio)") from exc
        path = os.fspath(path)
        if not os.path.exists(path):
            raise FileNotFoundError(f"no mesh file at {path!r}")
        with warnings.catch_warnings():
            # meshio's binary-STL size check overflows a uint32 on ASCII files
            # (NumPy 2 warns; the check is then false, as it should be)
            warnings.filterwarnings("ignore", "overflow encountered", RuntimeWarning)
            mesh = meshio.read(path, file_format=file_format)
        blocks = [np.asarray(c.data) for c in mesh.cells if c.type == "triangle"]
        if not blocks:
            kinds = sorted({c.type for c in mesh.cells})
            raise ValueError(f"{path!r} has no triangles (cell types: {kinds or 'none'}); "
                             "a TriangleMesh needs triangle cells")
        return cls(np.asarray(mesh.points)[:, :3], np.concatenate(blocks),
                   degenerate=degenerate)

    # -------------------------------------------------------------- properties
    @property
    def vertices(self):
        """(v, 3) float64, read-only: vertex positions; set it to move the mesh."""
        return self._vertices

    @vertices.setter
    def vertices(self, value):
        verts = self._checked_vertices(value, "vertices")
        if verts is value or (isinstance(value, np.ndarray) and np.shares_memory(verts, value)):
            verts = verts.copy()  # the mesh's own copy: the caller's array stays writable
        verts.flags.writeable = False
        self._vertices = verts

    def _checked_vertices(self, value, name):
        verts = as_coords(value, name)
        if verts.shape != self._vertices.shape:
            raise ValueError(f"{name} must have the mesh's shape {self._vertices.shape} (same "
                             f"vertices, moved), got {verts.shape}")
        _check_degenerate(verts[self._faces], name)
        return verts

    @property
    def faces(self):
        """(f, 3) int64, read-only: vertex indices of each triangle."""
        return self._faces

    @property
    def vertex_ids(self):
        """(v,) int64, read-only: each vertex's representative (lowest index with
        the same coordinates)."""
        return self._vid

    @property
    def edges(self):
        """(e, 2) int64, read-only: the unique edges as pairs of representative
        vertex ids, smaller first, sorted."""
        return self._edges

    @property
    def face_edges(self):
        """(f, 3) int64, read-only: rows of :attr:`edges` of each triangle's edges
        AB, BC and CA."""
        return self._face_edges

    def __len__(self):
        return len(self._faces)

    def __repr__(self):
        return f"TriangleMesh({len(self._vertices)} vertices, {len(self._faces)} faces)"

    def _periodic_adjacency(self, verts, cell):
        """Adjacency with vertices that coincide modulo the periodic cell vectors
        identified (kept for the last cell and vertices: which vertices meet
        across a periodic face depends on where they are)."""
        got = self._periodic
        if (got is not None and got[0] == cell
                and (got[2] is verts or np.array_equal(got[2], verts))):
            return got[1]
        s = cell.fractional(verts)
        pbc = cell.pbc
        q = s.copy()
        q[:, pbc] = np.round(np.mod(s[:, pbc], 1.0) / _PERIODIC_TOL)
        q[:, pbc] = np.mod(q[:, pbc], 1.0 / _PERIODIC_TOL)
        # exact duplicates stay one vertex whatever their rounding
        q = q[self._vid]
        _, first, inverse = np.unique(q + 0.0, axis=0, return_index=True, return_inverse=True)
        vid = np.ascontiguousarray(self._vid[first[inverse.reshape(-1)]], dtype=np.int64)
        adj = _adjacency(vid, self._faces)
        # the last cell and vertices only (a deforming cell or a moving mesh: one entry)
        self._periodic = (cell, adj, verts if not verts.flags.writeable else verts.copy())
        return adj


class WallContacts(NamedTuple):
    """Sphere-wall contacts of one :meth:`WallSearch.update` call (k rows).

    Attributes
    ----------
    sphere : (k,) int64
        Row of the sphere in the positions given.
    wall : (k,) int64
        Index of the wall in the :class:`WallSearch`'s list.
    element : (k,) int64
        Triangle (row of the mesh's faces) for a mesh, 0 for a plane.
    feature : (k,) int64
        0 face, 1 edge, 2 vertex (a plane's contacts are faces).
    distance : (k,) float64
        From the centre to the closest point (signed for a plane: negative
        behind it).  Contact means ``distance <= r + skin``.
    normal : (k, 3) float64
        Unit vector from the closest point towards the centre (a plane's
        normal; a triangle's normal when the centre lies on it).
    point : (k, 3) float64
        The closest point of the wall, in the frame of the sphere's given
        position (its periodic image nearest to it).

    Examples
    --------
    >>> from granularsap import Plane, WallSearch
    >>> c = WallSearch([Plane([0, 0, 0], [0, 0, 1])]).update([[1.0, 2.0, 0.4]], 0.5)
    >>> c._fields
    ('sphere', 'wall', 'element', 'feature', 'distance', 'normal', 'point')
    >>> c.point.tolist(), float(0.5 - c.distance[0])  # closest point, overlap
    ([[1.0, 2.0, 0.0]], 0.09999999999999998)
    """

    sphere: np.ndarray
    wall: np.ndarray
    element: np.ndarray
    feature: np.ndarray
    distance: np.ndarray
    normal: np.ndarray
    point: np.ndarray


#: columns of an identity key: sphere (id or row), wall, feature kind, feature
#: id (triangle, or smaller vertex of an edge, or vertex), second vertex of an
#: edge (else -1), and the rank among equal keys of one call (periodic images)
_KEY_COLUMNS = 6
#: empty stand-ins for optional kernel arguments (no ids, no shift, no keys)
_NO_IDS = np.empty(0, np.int64)
_NO_ROWS3 = np.empty((0, 3))
_NO_KEYS = np.empty((0, _KEY_COLUMNS), np.int64)


def _as_ids(ids, n, checked=None):
    """``ids`` as (n,) int64, checked unique; ``checked``: ids found unique before
    (equal ids are not sorted again: a time loop passes the same ids every step)."""
    arr = np.asarray(ids)
    if arr.dtype.kind not in "iu":
        raise TypeError(f"ids must be integers, got dtype {arr.dtype}")
    if arr.shape != (n,):
        raise ValueError(f"ids must have shape ({n},) (one per sphere), got {arr.shape}")
    arr = np.ascontiguousarray(arr, dtype=np.int64)
    if checked is not None and checked.shape == arr.shape and np.array_equal(checked, arr):
        return checked
    if n > 1:
        srt = np.sort(arr)
        dup = np.flatnonzero(srt[1:] == srt[:-1])
        if len(dup):
            raise ValueError(f"ids must be unique, got {int(srt[dup[0]])} more than once")
    return arr


class WallSearch:
    """Contacts between spheres and a list of walls, frame after frame.

    Parameters
    ----------
    walls : sequence of Plane and TriangleMesh
        The walls; contacts name them by their index in this list.
    skin : float
        Contact when ``distance <= r + skin`` (as ``ContactSearch``'s skin).
    identity : bool
        Keep, after each call, the row of each contact in the previous call's
        result (:attr:`previous_rows`), the rows that ended
        (:attr:`ended_rows`) and :meth:`carry` for history arrays.
    n_threads : int, optional
        Numba threads for each call; ``None`` uses numba's setting (one
        thread for small frames).  Results do not depend on it.
    rebuild_margin : float
        Keep each mesh's broad phase (the sphere-triangle pairs whose boxes,
        grown by this margin, overlap) from call to call while no sphere has
        moved by more than the margin along any axis since it was built, and
        the mesh, the cell, the radii and the sphere count are the same (a
        mesh wall's Verlet list, as LIGGGHTS keeps one); every call still
        tests each kept pair exactly, so the contacts are those of a margin of
        0.  ``stats["rebuilt"]`` says whether a call built it again.

    Raises
    ------
    TypeError
        A wall that is neither a Plane nor a TriangleMesh.
    ValueError
        No walls, or a negative skin or rebuild margin.

    Notes
    -----
    Identity (matched by :class:`granularsap.identity.ContactIdentity` on
    integer keys): a contact continues when it has the same sphere (by
    ``ids``, by row without), the same wall and the same feature: the
    triangle for a face contact, the edge (its two vertices) for an edge
    contact, the vertex for a vertex contact, so a sphere rolling from one
    triangle onto the next starts a new contact (a history per triangle, as
    LIGGGHTS's mesh walls keep it).
    A sphere wrapped back into the cell by the caller keeps its contacts
    (under the minimum image a feature touches a sphere once); when a sphere
    touches two periodic images of one feature (a reach over half the cell),
    they are told apart by their rank in the order of their lattice shifts
    relative to the sphere's position.

    Examples
    --------
    >>> import numpy as np
    >>> from granularsap import Plane, TriangleMesh, WallSearch
    >>> ramp = TriangleMesh([[0, 0, 0], [4, 0, 0], [0, 4, 0], [4, 4, 0]],
    ...                     [[0, 1, 2], [1, 3, 2]])
    >>> walls = WallSearch([Plane([0, 0, -1], [0, 0, 1]), ramp], identity=True)
    >>> c = walls.update([[2.0, 2.0, 0.5], [1.0, 1.0, 3.0]], [0.6, 0.5])
    >>> c.sphere.tolist(), c.wall.tolist(), c.feature.tolist()  # over the shared edge
    ([0], [1], [1])
    >>> c.distance.tolist(), c.normal.tolist()
    ([0.5], [[0.0, 0.0, 1.0]])
    >>> walls.update([[2.5, 2.0, 0.5], [1.0, 1.0, 3.0]], [0.6, 0.5]).element.tolist()
    [1]
    >>> walls.previous_rows.tolist(), walls.ended_rows.tolist()
    ([-1], [0])
    """

    def __init__(self, walls, *, skin=0.0, identity=False, n_threads=None, rebuild_margin=0.0):
        if isinstance(walls, (Plane, TriangleMesh)):
            walls = [walls]
        walls = list(walls)
        if not walls:
            raise ValueError("walls must hold at least one Plane or TriangleMesh")
        for i, w in enumerate(walls):
            if not isinstance(w, (Plane, TriangleMesh)):
                raise TypeError(f"walls[{i}] must be a Plane or a TriangleMesh, got "
                                f"{type(w).__name__}")
        #: the walls, in the order contacts name them (a tuple: fixed for the search)
        self.walls = tuple(walls)
        self._planes = [w for w, wall in enumerate(self.walls) if isinstance(wall, Plane)]
        self._wid = np.asarray(self._planes, np.int64)
        self._n_faces = sum(len(w.faces) for w in self.walls if isinstance(w, TriangleMesh))
        self._plane_cache = None  # (cell, the planes' points and normals, arrays)
        self.skin = as_scalar(skin, "skin")
        self.rebuild_margin = as_scalar(rebuild_margin, "rebuild_margin")
        if not isinstance(identity, (bool, np.bool_)):
            raise TypeError(f"identity must be True or False, got {type(identity).__name__}")
        self.identity = bool(identity)
        self.n_threads = check_n_threads(n_threads)
        self._geo = {}
        self._engines = {}
        #: per mesh, the broad phase kept with ``rebuild_margin``: (geometry, the
        #: reaches, the wrapped positions it was built on, its pairs)
        self._kept = {}
        # kept work arrays: staging rows, scratch, double-buffered outputs, keys
        self._st_i = np.empty((16, _tri.STAGE_INT), np.int64)
        self._st_f = np.empty((16, _tri.STAGE_FLOAT))
        self._work = {}
        self._out = [None, None]
        self._flip = 0
        self._keys = np.empty((0, _KEY_COLUMNS), np.int64)
        self._ids_checked = None  # the last ids found unique
        # contacts matched across calls by their integer keys (granularsap.identity)
        self._tracker = ContactIdentity(n_threads=self.n_threads) if self.identity else None
        #: per call: spheres, candidates tested, contacts, threads
        self.stats = {}

    # ------------------------------------------------------------ identity
    def _identity_state(self):
        if self._tracker is None:
            raise ValueError("contact identity needs WallSearch(..., identity=True)")
        return self._tracker

    @property
    def previous_rows(self):
        """(k,) int64: row of each contact of the last call in the call before
        it, or -1 for a new contact (``identity=True``; None before the first
        call)."""
        return self._identity_state().previous_rows

    @property
    def ended_rows(self):
        """(m,) int64: rows of the call before the last whose contacts did not
        continue, ascending (``identity=True``)."""
        return self._identity_state().ended_rows

    def carry(self, history, fill=0.0, out=None):
        """A history array of the previous call's contacts, moved to the last's rows.

        As ``ContactSearch.carry`` (one gather, by
        :class:`granularsap.identity.ContactIdentity`).

        Parameters
        ----------
        history : (k_prev, ...) array_like
            One row per contact of the previous call.
        fill : scalar or array_like, optional
            Value of the rows of new contacts (default 0).
        out : (k, ...) ndarray, optional
            Where to write (same dtype, not overlapping ``history``).

        Returns
        -------
        (k, ...) ndarray
            ``history[previous_rows]``, ``fill`` where ``previous_rows == -1``;
            the dtype of ``history``.

        Raises
        ------
        ValueError
            No ``identity=True``, no call yet, or ``history`` without one row per
            contact of the previous call.

        Examples
        --------
        >>> from granularsap import Plane, WallSearch
        >>> walls = WallSearch([Plane([0, 0, 0], [0, 0, 1])], identity=True)
        >>> walls.update([[0, 0, 0.4], [3, 0, 0.1]], 0.5, ids=[10, 11]).sphere.tolist()
        [0, 1]
        >>> ages = np.array([5, 7])             # one per contact of that call
        >>> c = walls.update([[3, 0, 0.2], [6, 0, 0.3]], 0.5, ids=[11, 12])  # 10 left
        >>> walls.previous_rows.tolist(), walls.carry(ages, fill=0).tolist()
        ([1, -1], [7, 0])
        """
        return self._identity_state().carry(history, fill, out)

    # ------------------------------------------------------------ update
    def update(self, positions, radii, box=None, *, pbc=None, ids=None, vertices=None):
        """Sphere-wall contacts of one frame.

        Parameters
        ----------
        positions : (n, 3) array_like of float
            Sphere centres.
        radii : float or (n,) array_like of float
            Sphere radii (non-negative).
        box : None, (6,) or (3, 3) array_like of float, or Cell, optional
            The cell; None for open boundaries.
        pbc : bool or (3,) sequence of bool, optional
            Periodicity (default: the box's own).
        ids : (n,) array_like of int, optional
            Unique sphere ids for contact identity (rows otherwise), so that
            insertions and deletions keep the other spheres' contacts.
        vertices : (v, 3) array_like, or sequence with one entry per wall, optional
            Vertex positions of the meshes for this call (same topology): one
            array when the search has a single mesh, else a list with an array
            or None (unchanged) per wall.

        Returns
        -------
        WallContacts
            Rows sorted by sphere, wall, element and feature.  The arrays are
            the search's own, double-buffered: valid and unchanged until the
            call after next (copy them to keep them longer).

        Raises
        ------
        ValueError
            Wrong shapes, NaN or inf, negative radii, non-unique ids, a plane not
            perpendicular to the periodic axes, moved vertices of another shape
            or making a degenerate triangle.
        """
        x = as_coords(positions, "positions")
        n = len(x)
        r = as_vector(radii, "radii", n)
        cell = Cell.coerce(box, pbc=pbc, name="box")
        if cell is not None and not cell.any_periodic:
            cell = None
        if ids is None:
            sphere_key = np.arange(n, dtype=np.int64)
        else:
            # (a copy kept: the caller's array may change before the next call)
            sphere_key = _as_ids(ids, n, self._ids_checked)
            if sphere_key is not self._ids_checked:
                sphere_key = self._ids_checked = sphere_key.copy()
        verts = self._vertices_for(vertices)
        threads = self.n_threads
        if threads is None and n + self._n_faces < _PARALLEL_MIN:
            threads = 1
        # one thread setting for the whole call (the meshes, their broad phase and
        # the identity), set and restored once
        with num_threads(threads) as used:
            return self._update(x, n, r, cell, ids, sphere_key, verts, used)

    def _update(self, x, n, r, cell, ids, sphere_key, verts, threads):
        """The call on validated inputs, under its thread count ``threads``."""
        h = r + self.skin
        if cell is not None:
            xw = np.ascontiguousarray(cell.wrap(x))
            delta = x - xw  # given minus wrapped position (whole cell vectors)
        else:
            xw, delta = x, _NO_ROWS3
        # every wall writes staging rows (sorted by sphere within its part), then
        # one pass merges the parts into the outputs
        bounds = [0]
        tested = 0
        rebuilt = False
        planes = self._planes
        if planes:
            pts, nrm = self._plane_arrays(planes, cell)
            wid = self._wid
            k = _tri.plane_contacts(x, h, pts, nrm, wid, self._st_i, self._st_f, 0)
            if k > len(self._st_i):
                self._grow_stage(k, 0)
                _tri.plane_contacts(x, h, pts, nrm, wid, self._st_i, self._st_f, 0)
            bounds.append(k)
            tested += n * len(planes)
        for w, wall in enumerate(self.walls):
            if isinstance(wall, TriangleMesh):
                part, built = self._mesh(w, wall, verts[w], xw, h, cell, delta, threads,
                                         bounds)
                tested += part
                rebuilt |= built
        k = bounds[-1]
        self._flip ^= 1
        out = self._out[self._flip]
        if out is None or len(out[0]) < k:
            size = max(k, 2 * (0 if out is None else len(out[0])), 16)
            out = self._out[self._flip] = (
                np.empty(size, np.int64), np.empty(size, np.int64), np.empty(size, np.int64),
                np.empty(size, np.int64), np.empty(size), np.empty((size, 3)),
                np.empty((size, 3)))
        keys = self._keys
        if self.identity and len(keys) < k:
            keys = self._keys = np.empty((max(k, 2 * len(keys)), _KEY_COLUMNS), np.int64)
        _tri.merge_walls(self._st_i, self._st_f, np.asarray(bounds, np.int64),
                         _NO_IDS if ids is None else sphere_key, *out,
                         keys if self.identity else _NO_KEYS)
        result = WallContacts(*(a[:k] for a in out))
        self.stats = {"spheres": n, "candidates_tested": int(tested), "contacts": k,
                      "rebuilt": rebuilt}
        if self.identity:
            self._tracker.update(keys[:k])
        return result

    def _grow_stage(self, need, keep):
        """Staging rows for ``need`` contacts, the first ``keep`` rows kept."""
        size = max(need, 2 * len(self._st_i))
        st_i = np.empty((size, _tri.STAGE_INT), np.int64)
        st_f = np.empty((size, _tri.STAGE_FLOAT))
        st_i[:keep] = self._st_i[:keep]
        st_f[:keep] = self._st_f[:keep]
        self._st_i, self._st_f = st_i, st_f

    def _scratch(self, name, shape, dtype=np.float64):
        """A kept work array with at least ``shape[0]`` rows (grown by doubling)."""
        got = self._work.get(name)
        if got is None or len(got) < shape[0]:
            rows = max(shape[0], 2 * (0 if got is None else len(got)), 16)
            got = self._work[name] = np.empty((rows, *shape[1:]), dtype)
        return got

    def _select_work(self, k):
        """The work arrays of ``mesh_select`` for ``k`` candidate pairs, kept (grown
        by doubling): distances and points (k,), nine int64 arrays (k + 1,) (region,
        element, kind, feature id, f0, f1, group starts, offsets, order) and the
        feature table of ``SLOTS`` rows per pair (key, closest distance, lowest
        kind, reporting row, closest face or edge contact)."""
        got = self._work.get("select")
        if got is None or got[0] < k:
            cap = max(k, 2 * (0 if got is None else got[0]), 16)
            slots = _tri.SLOTS * cap
            got = self._work["select"] = (
                cap, np.empty(cap), np.empty((cap, 3)),
                [np.empty(cap + 1, np.int64) for _ in range(9)],
                (np.empty(slots, np.int64), np.empty(slots), np.empty(slots, np.int64),
                 np.empty(slots, np.int64), np.empty(slots)))
        return got[1:]

    def _plane_arrays(self, planes, cell):
        """Points and normals (p, 3) of the planes, checked against the cell; kept
        while the planes' points and normals (read-only arrays, new ones when set)
        and the cell are the same."""
        given = [(self.walls[w].point, self.walls[w].normal) for w in planes]
        got = self._plane_cache
        if (got is not None and (got[0] is cell or (cell is not None and got[0] == cell))
                and all(a is b and c is d for (a, c), (b, d) in zip(got[1], given,
                                                                     strict=True))):
            return got[2], got[3]
        pts, nrm = self._plane_rows(planes, cell)
        self._plane_cache = (cell, given, pts, nrm)
        return pts, nrm

    def _plane_rows(self, planes, cell):
        pts = np.empty((len(planes), 3))
        nrm = np.empty((len(planes), 3))
        for j, w in enumerate(planes):
            plane = self.walls[w]
            pts[j] = plane.point
            nrm[j] = plane.normal
            if cell is not None:
                self._check_plane(w, plane, cell)
        return pts, nrm

    def _vertices_for(self, vertices):
        """The vertices of each mesh for this call (None for planes)."""
        current = [w.vertices if isinstance(w, TriangleMesh) else None for w in self.walls]
        if vertices is None:
            return current
        meshes = [i for i, w in enumerate(self.walls) if isinstance(w, TriangleMesh)]
        per_wall = isinstance(vertices, (list, tuple)) and len(vertices) == len(self.walls) and all(
            v is None or np.ndim(v) == 2 for v in vertices)
        if per_wall:
            given = list(vertices)
        elif len(meshes) == 1:
            given = [None] * len(self.walls)
            given[meshes[0]] = vertices
        else:
            raise ValueError(f"vertices must be a sequence with one entry per wall "
                             f"({len(self.walls)}: an array or None each) when the search "
                             f"has {len(meshes)} meshes")
        for i, v in enumerate(given):
            if v is None:
                continue
            if i not in meshes:
                raise ValueError(f"vertices[{i}] is given for a Plane; use None for planes "
                                 "(move a plane by setting its point or normal)")
            current[i] = self.walls[i]._checked_vertices(v, f"vertices[{i}]")
        return current

    @staticmethod
    def _check_plane(w, plane, cell):
        n = plane.normal
        m = cell.matrix[cell.pbc]
        lengths = np.linalg.norm(m, axis=1)
        off = np.abs(m @ n) > 1e-12 * lengths
        if off.any():
            axis = int(np.flatnonzero(cell.pbc)[np.flatnonzero(off)[0]])
            raise ValueError(
                f"walls[{w}] is a Plane with normal {n.tolist()} that is not perpendicular "
                f"to periodic cell vector {axis}; a half-space wall needs the periodic "
                "axes parallel to it (make that axis open with pbc, or use a mesh)")

    def _images(self, tri, cell, hmax):
        """Triangle rows and integer lattice shifts of every image within reach of
        the cell (the triangle itself with a zero shift in an open cell)."""
        f = len(tri)
        if cell is None:
            return np.arange(f, dtype=np.int64), np.zeros((f, 3), np.int64)
        s = cell.fractional(tri.reshape(-1, 3)).reshape(f, 3, 3)
        lo, hi = s.min(axis=1), s.max(axis=1)
        widths = cell.perpendicular_widths
        ranges = []
        for c in range(3):
            if not cell.pbc[c]:
                ranges.append((np.zeros(f, np.int64), np.zeros(f, np.int64)))
                continue
            reach = hmax / widths[c] * (1.0 + 1e-9) + 1e-9
            a = np.ceil(-hi[:, c] - reach).astype(np.int64)
            b = np.floor(1.0 - lo[:, c] + reach).astype(np.int64)
            ranges.append((a, np.maximum(b, a - 1)))
        counts = np.ones(f, np.int64)
        for a, b in ranges:
            counts *= b - a + 1
        rows = np.repeat(np.arange(f, dtype=np.int64), counts)
        # the image's position within its triangle's block, decoded axis by axis
        local = np.arange(len(rows), dtype=np.int64) - np.repeat(np.cumsum(counts) - counts,
                                                                  counts)
        shifts = np.zeros((len(rows), 3), np.int64)
        for c in range(3):
            a, b = ranges[c]
            span = (b - a + 1)[rows]
            shifts[:, c] = a[rows] + local % span
            local //= span
        return rows, shifts

    def _geometry(self, w, mesh, verts, cell, hmax, threads):
        """Image triangles (m, 3, 3), their rows and shifts, boxes and largest
        coordinate; kept while the vertices (same array), cell and reach are."""
        key = (cell, hmax)
        got = self._geo.get(w)
        # the mesh's own vertices are read-only (a new array when set): kept while
        # the same; vertices given for one call are never kept
        if got is not None and got[0] is verts and verts is mesh.vertices and got[1] == key:
            return got[2]
        tri = verts[mesh.faces]  # (f, 3, 3)
        rows, shifts = self._images(tri, cell, hmax)
        if cell is not None:
            itri = tri[rows] + (shifts.astype(np.float64) @ cell.full_matrix)[:, None, :]
        else:
            itri = tri
        itri = np.ascontiguousarray(itri)
        tlo = np.empty((len(itri), 3))
        thi = np.empty((len(itri), 3))
        kern = _tri if threads > 1 else _tri.serial
        top = float(kern.triangle_boxes(itri, tlo, thi))
        geo = (rows, shifts, itri, tlo, thi, top)
        self._geo[w] = (verts, key, geo)
        return geo

    def _mesh(self, w, mesh, verts, xw, h, cell, delta, threads, bounds):
        """Staging rows of one mesh's contacts (appended; ``bounds`` gets the
        part's end); returns the number of candidates tested and whether the
        broad phase was built (not kept).  ``threads``: the thread count
        ``update`` put in force."""
        n = len(xw)
        if cell is not None:
            corners, edges, face_edges = mesh._periodic_adjacency(verts, cell)
        else:
            corners, edges, face_edges = mesh._corners, mesh._edges, mesh._face_edges
        margin = self.rebuild_margin
        hmax = float(h.max()) if n else 0.0
        geo = self._geometry(w, mesh, verts, cell, hmax + margin, threads)
        rows, shifts, itri, tlo, thi, top = geo
        base = bounds[-1]
        if n == 0 or len(itri) == 0:
            self._kept.pop(w, None)
            bounds.append(base)
            return 0, False
        kern = _tri if threads > 1 else _tri.serial
        kept = self._kept.get(w)
        if (kept is not None and kept[0] is geo and len(kept[2]) == n
                and _tri.kept_pairs_hold(xw, kept[2], h, kept[1], margin)):
            # every box of this call lies in its box grown by the margin at the
            # build (and the guard of the boxes covers the rounding): the kept
            # pairs hold this call's
            cand = kept[3]
            built = False
        else:
            lo = self._scratch("lower", (n, 3))
            hi = self._scratch("upper", (n, 3))
            lo, hi = lo[:n], hi[:n]
            kern.sphere_boxes(xw, h + margin if margin else h, top, _GUARD, lo, hi)
            engine = self._engines.get(w)
            if engine is None:
                engine = self._engines[w] = SweepAndPrune()
            engine.n_threads = threads
            # the engine keeps the triangles' grid while they do not move; its
            # pairs come sorted by sphere
            cand = engine.update(lo, hi, tlo, thi)
            built = True
            if margin:
                self._kept[w] = (geo, h.copy(), np.array(xw), cand.copy())
        k = len(cand)
        if k == 0:
            bounds.append(base)
            return 0, built
        dist, point, ints, table = self._select_work(k)
        groups, total = kern.mesh_select(cand, xw, h, _TIE, itri, rows, shifts, corners,
                                         face_edges, edges, tlo, thi, top, _GUARD, dist, point,
                                         *ints, *table)
        if base + total > len(self._st_i):
            self._grow_stage(base + total, base)
        _, elem, kind, _, f0, f1, gstart, offsets, order = ints
        kern.mesh_fill(cand, xw, itri, dist, point, elem, kind, f0, f1, gstart, offsets,
                       order, groups, w, delta, self._st_i, self._st_f, base)
        bounds.append(base + total)
        return k, built
