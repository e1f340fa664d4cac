"""Silhouette edges and vertices of triangle meshes as seen from a point (e.g. a light's center).

After welding vertices that share a position, an edge is a silhouette edge seen from ``p`` when it
is a boundary edge or its adjacent triangles include both facing and non-facing ones (a triangle
``(a, b, c)`` faces ``p`` when ``((b - a) x (c - a)) . (p - a) > 0``); vertex degrees other than 2
are normal. :func:`silhouette_brute` (no state, a hash table of edges per call) and
:func:`silhouette_adjacency` (an :class:`EdgeAdjacency` built once by :func:`build_adjacency`) give
identical results; :func:`find_silhouette` dispatches and caches the adjacency per mesh. Inputs are
plain arrays: ``vertices`` (V,3) float64, ``faces`` (F,3) int64, ``point`` (3,).

Definition and the two paths in detail: ``docs/methods/penumbra-map.md`` (section "Silhouettes").
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from .._jit import frozen, kernel
from ..errors import SoftShadowsError

__all__ = [
    "EdgeAdjacency",
    "Silhouette",
    "build_adjacency",
    "facing",
    "facing_from_planes",
    "find_silhouette",
    "silhouette_adjacency",
    "silhouette_brute",
    "weld_vertices",
]


# ---------------------------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------------------------
@dataclass
class Silhouette:
    """Silhouette of a mesh seen from ``point``.

    edges:       (S,2) int64 vertex indices (welded representatives: the lowest input index of
                 each distinct position), ``edges[:,0] < edges[:,1]``, sorted lexicographically
    edge_faces:  (S,2) int64 one adjacent facing triangle and one adjacent non-facing triangle
                 (indices into ``faces``), -1 where there is none (boundary edges have one)
    boundary:    (S,) bool, the edge has exactly one adjacent triangle
    vertices:    (N,) int64 distinct silhouette vertex indices (sorted)
    degree:      (N,) int64 silhouette edges at each vertex
    """

    edges: np.ndarray
    edge_faces: np.ndarray
    boundary: np.ndarray
    vertices: np.ndarray
    degree: np.ndarray
    point: np.ndarray

    @property
    def n_edges(self) -> int:
        return int(len(self.edges))

    @property
    def n_vertices(self) -> int:
        return int(len(self.vertices))

    @property
    def max_degree(self) -> int:
        return int(self.degree.max()) if len(self.degree) else 0

    @property
    def n_vertices_degree3(self) -> int:
        """Vertices where three or more silhouette edges meet."""
        return int((self.degree >= 3).sum())

    def vertex_slot(self) -> np.ndarray:
        """(S,2) positions of each edge's endpoints in :attr:`vertices` (for per-vertex data)."""
        return np.searchsorted(self.vertices, self.edges)


@dataclass
class EdgeAdjacency:
    """Edge adjacency of a triangle mesh (after welding), built once, reused every frame.

    rep:        (V,) int64 welded representative of every input vertex
    edges:      (E,2) int64 representative vertex pairs, lo < hi, sorted lexicographically
    edge_faces: (3F,) int64 adjacent faces of all edges, grouped by edge (CSR)
    offsets:    (E+1,) int64 group starts in ``edge_faces``
    count:      (E,) int64 adjacent faces per edge (1 boundary, 2 manifold, >2 non-manifold)
    normals:    (F,3) float64 unnormalized face normals ``(b - a) x (c - a)``
    anchors:    (F,3) float64 first vertex of every face
    """

    rep: np.ndarray
    edges: np.ndarray
    edge_faces: np.ndarray
    offsets: np.ndarray
    count: np.ndarray
    normals: np.ndarray
    anchors: np.ndarray
    n_faces: int

    @property
    def n_edges(self) -> int:
        return int(len(self.edges))

    @property
    def n_boundary(self) -> int:
        return int((self.count == 1).sum())

    @property
    def n_nonmanifold(self) -> int:
        return int((self.count > 2).sum())


# ---------------------------------------------------------------------------------------------
# building blocks
# ---------------------------------------------------------------------------------------------
def weld_vertices(vertices: np.ndarray) -> np.ndarray:
    """(V,) representative index of every vertex: the lowest index with exactly the same position
    (meshes with per-face vertices, like flat-shaded boxes, share edges only after welding).
    ``-0.0`` and ``0.0`` are the same position."""
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    if len(v) == 0:
        return np.zeros(0, np.int64)
    bits = (v + 0.0).view(np.int64)  # + 0.0 turns -0.0 into 0.0; then compare bit patterns
    return _weld_kernel(bits)


@kernel
def _mix(a, b, c):
    h = a * np.int64(-7046029254386353131) + b
    h = (h ^ (h >> np.int64(29))) * np.int64(-4658895280553007687) + c
    h = (h ^ (h >> np.int64(32))) * np.int64(-7046029254386353131)
    return h ^ (h >> np.int64(29))


@kernel
def _hash_table(min_size):
    """An empty open-addressing table (-1 = free) of a power-of-two size >= min_size, and its mask."""
    size = 16
    while size < min_size:
        size *= 2
    return np.full(size, -1, np.int64), size - 1


@kernel
def _weld_kernel(bits):
    n = bits.shape[0]
    table, mask = _hash_table(2 * n)
    rep = np.empty(n, np.int64)
    for i in range(n):
        a = bits[i, 0]
        b = bits[i, 1]
        c = bits[i, 2]
        h = _mix(a, b, c) & mask
        while True:
            j = table[h]
            if j < 0:
                table[h] = i
                rep[i] = i
                break
            if bits[j, 0] == a and bits[j, 1] == b and bits[j, 2] == c:
                rep[i] = j  # the first (lowest) index inserted with this position
                break
            h = (h + 1) & mask
    return rep


@kernel
def _edge_table(rep, faces, fr):
    """Every welded edge of the triangles once, in order of first appearance: (lo, hi, count of
    triangles, count of facing ones, lowest facing triangle, highest non-facing triangle)."""
    F = faces.shape[0]
    table, mask = _hash_table(6 * F)
    lo = np.empty(3 * F, np.int64)
    hi = np.empty(3 * F, np.int64)
    ca = np.zeros(3 * F, np.int64)
    cf = np.zeros(3 * F, np.int64)
    first = np.full(3 * F, -1, np.int64)
    last = np.full(3 * F, -1, np.int64)
    n = 0
    for f in range(F):
        for e in range(3):
            u = rep[faces[f, e]]
            w = rep[faces[f, (e + 1) % 3]]
            a = min(u, w)
            b = max(u, w)
            h = _mix(a, b, np.int64(0)) & mask
            while True:
                k = table[h]
                if k < 0:
                    k = n
                    table[h] = k
                    lo[k] = a
                    hi[k] = b
                    n += 1
                    break
                if lo[k] == a and hi[k] == b:
                    break
                h = (h + 1) & mask
            ca[k] += 1
            if fr[f]:
                cf[k] += 1
                if first[k] < 0:
                    first[k] = f
            else:
                last[k] = f
    return lo[:n], hi[:n], ca[:n], cf[:n], first[:n], last[:n]


def _face_planes(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices, dtype=np.float64)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    return np.cross(b - a, c - a), a


def facing_from_planes(normals, anchors, point) -> np.ndarray:
    """(F,) bool: whether each triangle of plane normal ``normals`` (F, 3) (unnormalized, as
    :func:`_face_planes` gives them) through ``anchors`` (F, 3) faces ``point``: the test of
    :func:`facing` (:func:`_facing_one`) on planes computed once (e.g. an adjacency's)."""
    p = np.asarray(point, dtype=np.float64).reshape(3)
    return _facing_planes_kernel(
        np.ascontiguousarray(normals, dtype=np.float64), np.ascontiguousarray(anchors, dtype=np.float64), p
    )


@kernel(inline=True)
def _facing_one(nx, ny, nz, ax, ay, az, p):
    """The facing test of one triangle; every path computes it with these operations in this order
    (so brute force and adjacency agree bit for bit)."""
    return nx * (p[0] - ax) + ny * (p[1] - ay) + nz * (p[2] - az) > 0.0


@kernel
def _facing_planes_kernel(n, a, p):
    out = np.empty(n.shape[0], np.bool_)
    for f in range(n.shape[0]):
        out[f] = _facing_one(n[f, 0], n[f, 1], n[f, 2], a[f, 0], a[f, 1], a[f, 2], p)
    return out


@kernel
def _facing_kernel(v, faces, p):
    """Facing of every triangle straight from the vertices: the normal as ``np.cross(b - a, c - a)``
    computes it, then :func:`_facing_one`."""
    out = np.empty(faces.shape[0], np.bool_)
    for f in range(faces.shape[0]):
        i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
        e1x = v[j, 0] - v[i, 0]
        e1y = v[j, 1] - v[i, 1]
        e1z = v[j, 2] - v[i, 2]
        e2x = v[k, 0] - v[i, 0]
        e2y = v[k, 1] - v[i, 1]
        e2z = v[k, 2] - v[i, 2]
        out[f] = _facing_one(
            e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x, v[i, 0], v[i, 1], v[i, 2], p
        )
    return out


def facing(vertices: np.ndarray, faces: np.ndarray, point) -> np.ndarray:
    """(F,) bool: triangle faces ``point`` (``((b-a) x (c-a)) . (point - a) > 0``)."""
    return _facing_kernel(
        frozen(np.ascontiguousarray(vertices, dtype=np.float64)),
        frozen(np.ascontiguousarray(faces, np.int64)),
        np.asarray(point, dtype=np.float64).reshape(3),
    )


def _edge_keys(rep, faces):
    f = rep[np.asarray(faces, np.int64)]
    a = f[:, [0, 1, 2]].ravel()
    b = f[:, [1, 2, 0]].ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    n = np.int64(max(len(rep), 1))
    return lo, hi, lo * n + hi


def _finish(edges, edge_faces, boundary, point) -> Silhouette:
    if len(edges):
        verts, deg = np.unique(edges.ravel(), return_counts=True)
    else:
        verts, deg = np.zeros(0, np.int64), np.zeros(0, np.int64)
    return Silhouette(
        edges.astype(np.int64).reshape(-1, 2),
        edge_faces.astype(np.int64).reshape(-1, 2),
        boundary.astype(bool),
        verts.astype(np.int64),
        deg.astype(np.int64),
        np.asarray(point, np.float64).reshape(3).copy(),
    )


# ---------------------------------------------------------------------------------------------
# brute force: everything from the raw triangles, every call
# ---------------------------------------------------------------------------------------------
def silhouette_brute(vertices: np.ndarray, faces: np.ndarray, point, weld: bool = True) -> Silhouette:
    """Silhouette seen from ``point`` with no precomputed connectivity: weld, list the 3F edges
    of all triangles, group equal edges in a hash table, test each group's facing mix."""
    faces = np.asarray(faces, np.int64)
    F = len(faces)
    if F == 0:
        return _finish(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, bool), point)
    rep = weld_vertices(vertices) if weld else np.arange(len(vertices), dtype=np.int64)
    fr = facing(vertices, faces, point)
    lo, hi, ca, cf, first, last = _edge_table(rep, faces, fr)
    sil = (ca == 1) | ((cf > 0) & (cf < ca))
    g = np.flatnonzero(sil)
    g = g[np.lexsort((hi[g], lo[g]))]  # canonical order: by (lo, hi)
    edges = np.stack([lo[g], hi[g]], axis=1)
    ef = np.stack([np.where(cf[g] > 0, first[g], -1), np.where(cf[g] < ca[g], last[g], -1)], axis=1)
    return _finish(edges, ef, ca[g] == 1, point)


# ---------------------------------------------------------------------------------------------
# fast path: edge adjacency built once
# ---------------------------------------------------------------------------------------------
def build_adjacency(vertices: np.ndarray, faces: np.ndarray, weld: bool = True) -> EdgeAdjacency:
    """Welded edge -> adjacent faces table (CSR) plus face planes, for :func:`silhouette_adjacency`."""
    faces = np.asarray(faces, np.int64)
    F = len(faces)
    rep = weld_vertices(vertices) if weld else np.arange(len(vertices), dtype=np.int64)
    n, a = _face_planes(vertices, faces)
    if F == 0:
        z = np.zeros(0, np.int64)
        return EdgeAdjacency(rep, np.zeros((0, 2), np.int64), z, np.zeros(1, np.int64), z, n, a, 0)
    lo, hi, key = _edge_keys(rep, faces)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    start = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    offsets = np.r_[start, len(ks)].astype(np.int64)
    edges = np.stack([lo[order][start], hi[order][start]], axis=1)
    edge_faces = (order // 3).astype(np.int64)
    return EdgeAdjacency(rep, edges, edge_faces, offsets, np.diff(offsets), n, a, F)


def silhouette_adjacency(adj: EdgeAdjacency, point) -> Silhouette:
    """Silhouette seen from ``point`` from a prebuilt :class:`EdgeAdjacency`: one plane test per
    face, one segmented sum of facing flags per edge."""
    if adj.n_faces == 0:
        return _finish(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, bool), point)
    fr = facing_from_planes(adj.normals, adj.anchors, point)
    frc = fr[adj.edge_faces]
    cf = np.add.reduceat(frc.astype(np.int64), adj.offsets[:-1])
    ca = adj.count
    sil = (ca == 1) | ((cf > 0) & (cf < ca))
    idx = np.flatnonzero(sil)
    s = adj.offsets[idx]
    c = ca[idx]
    f0 = adj.edge_faces[s]
    f1 = adj.edge_faces[s + c - 1]
    front = np.where(fr[f0], f0, np.where(fr[f1], f1, -1))
    back = np.where(~fr[f0], f0, np.where(~fr[f1], f1, -1))
    # non-manifold edges (>2 faces): the first facing / last non-facing face, as the brute path
    for j in np.flatnonzero(c > 2):
        grp = adj.edge_faces[s[j] : s[j] + c[j]]
        fg = fr[grp]
        front[j] = grp[fg][0] if fg.any() else -1
        back[j] = grp[~fg][-1] if (~fg).any() else -1
    return _finish(adj.edges[idx], np.stack([front, back], axis=1), c == 1, point)


# ---------------------------------------------------------------------------------------------
# dispatch with a per-mesh adjacency cache
# ---------------------------------------------------------------------------------------------
_CACHE: dict = {}


def cached_adjacency(vertices: np.ndarray, faces: np.ndarray) -> tuple[EdgeAdjacency, bool]:
    """(adjacency, built_now): reuse the adjacency of the same (identical, alive) arrays."""
    key = (id(vertices), id(faces))
    hit = _CACHE.get(key)
    if hit is not None:
        wv, wf, shape_v, shape_f, adj = hit
        if wv() is vertices and wf() is faces and vertices.shape == shape_v and faces.shape == shape_f:
            return adj, False
    adj = build_adjacency(vertices, faces)
    try:
        for k in [k for k, h in _CACHE.items() if h[0]() is None or h[1]() is None]:
            del _CACHE[k]
        _CACHE[key] = (weakref.ref(vertices), weakref.ref(faces), vertices.shape, faces.shape, adj)
    except TypeError:  # arrays that do not support weak references: no caching
        pass
    return adj, True


def find_silhouette(
    vertices: np.ndarray, faces: np.ndarray, point, method: str = "adjacency", adjacency: EdgeAdjacency | None = None
) -> Silhouette:
    """Silhouette of ``(vertices, faces)`` seen from ``point``; ``method`` is ``brute`` or
    ``adjacency`` (uses ``adjacency`` if given, else a cached one for these arrays)."""
    if method == "brute":
        return silhouette_brute(vertices, faces, point)
    if method == "adjacency":
        if adjacency is None:
            adjacency, _ = cached_adjacency(vertices, faces)
        return silhouette_adjacency(adjacency, point)
    raise SoftShadowsError(f"silhouette method must be 'brute' or 'adjacency', got {method!r}")
