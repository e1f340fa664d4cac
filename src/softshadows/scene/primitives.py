"""Procedural triangle meshes as plain ``(vertices, faces)`` arrays.

Every function returns ``vertices`` (N,3) float64 and ``faces`` (M,3) int64. Closed shapes have
outward normals; every triangle ``(a, b, c)`` is counter-clockwise seen from the side its normal
``(b - a) x (c - a)`` points to. Wrap the result in :class:`softshadows.scene.Mesh` to use it.

* :func:`plane`     - a tessellated horizontal rectangle facing +y (grounds)
* :func:`quad`      - one planar rectangle (two triangles) with normal along ``u x v``
* :func:`box`       - an axis-aligned box (24 vertices: flat faces do not share vertices)
* :func:`icosphere` - a subdivided icosahedron
* :func:`cylinder`  - a (capped) cylinder between two points
* :func:`ellipse_fans` - many small planar ellipses at once (the plant's leaves)
* :func:`merge`     - concatenate several ``(vertices, faces)`` pairs
"""

from __future__ import annotations

import numpy as np

__all__ = ["box", "cylinder", "ellipse_fans", "face_normals", "icosphere", "merge", "plane", "quad"]


def _v3(x, what: str = "vector") -> np.ndarray:
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.size != 3:
        raise ValueError(f"{what}: expected 3 numbers, got {x!r}")
    return a


def face_normals(vertices, faces) -> np.ndarray:
    """Unit geometric normals ``(b - a) x (c - a)`` of the faces, as wound."""
    v = np.asarray(vertices, float)
    f = np.asarray(faces)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def merge(*parts) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate ``(vertices, faces)`` pairs into one pair (face indices are offset)."""
    vs, fs, off = [], [], 0
    for v, f in parts:
        vs.append(np.asarray(v, np.float64))
        fs.append(np.asarray(f, np.int64) + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def plane(
    size_x: float, size_z: float, nx: int = 1, nz: int = 1, y: float = 0.0, center=(0.0, 0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal ``size_x`` by ``size_z`` rectangle split into ``nx`` by ``nz`` cells (2 triangles
    each), facing +y. It spans ``center.x +- size_x/2``, ``center.z +- size_z/2`` at height
    ``center.y + y``."""
    nx, nz = int(nx), int(nz)
    if nx < 1 or nz < 1:
        raise ValueError(f"plane: nx and nz must be >= 1, got {nx}, {nz}")
    c = _v3(center, "plane center")
    xs = np.linspace(-size_x / 2.0, size_x / 2.0, nx + 1) + c[0]
    zs = np.linspace(-size_z / 2.0, size_z / 2.0, nz + 1) + c[2]
    X, Z = np.meshgrid(xs, zs, indexing="ij")  # vertex (i, j) -> index i*(nz+1) + j
    verts = np.stack([X.ravel(), np.full(X.size, c[1] + y), Z.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(nx), np.arange(nz), indexing="ij")
    a = (i * (nz + 1) + j).ravel()  # (x_i, z_j)
    b = a + 1  # (x_i, z_j+1)
    c_ = a + (nz + 1)  # (x_i+1, z_j)
    d = c_ + 1  # (x_i+1, z_j+1)
    # (+z) x (+x) = +y, so (a, b, c) faces up.
    faces = np.concatenate([np.stack([a, b, c_], 1), np.stack([c_, b, d], 1)])
    return verts, faces.astype(np.int64)


def quad(center, u, v) -> tuple[np.ndarray, np.ndarray]:
    """The rectangle ``center +- u/2 +- v/2`` (u, v full edge vectors) as two triangles whose
    normal is ``normalize(u x v)``."""
    c, u, v = _v3(center, "quad center"), _v3(u, "quad u"), _v3(v, "quad v")
    verts = np.array([c - u / 2 - v / 2, c + u / 2 - v / 2, c + u / 2 + v / 2, c - u / 2 + v / 2])
    return verts, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


def box(size=1.0, center=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box of edge lengths ``size`` (a number or 3 numbers) centered at ``center``:
    6 faces x 4 vertices, 12 triangles, outward normals."""
    s = _v3(size, "box size") / 2.0
    c = _v3(center, "box center")
    verts, faces = [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            a1, a2 = np.zeros(3), np.zeros(3)
            a1[(axis + 1) % 3] = 1.0
            a2[(axis + 2) % 3] = 1.0
            # a1 x a2 = +axis; swap for the negative side so that e1 x e2 = n.
            e1, e2 = (a1, a2) if sign > 0 else (a2, a1)
            qv, qf = quad(c + n * s, 2 * e1 * s, 2 * e2 * s)
            faces.append(qf + 4 * len(verts))
            verts.append(qv)
    return np.concatenate(verts), np.concatenate(faces)


def icosphere(radius: float = 1.0, center=(0.0, 0.0, 0.0), subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Sphere from an icosahedron subdivided ``subdivisions`` times (20 * 4**subdivisions triangles)."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array(
        [
            [-1, t, 0],
            [1, t, 0],
            [-1, -t, 0],
            [1, -t, 0],
            [0, -1, t],
            [0, 1, t],
            [0, -1, -t],
            [0, 1, -t],
            [t, 0, -1],
            [t, 0, 1],
            [-t, 0, -1],
            [-t, 0, 1],
        ],
        dtype=np.float64,
    )
    f = np.array(
        [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ],
        dtype=np.int64,
    )
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(int(subdivisions)):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        mid = v[uniq[:, 0]] + v[uniq[:, 1]]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inv.reshape(3, -1) + len(v)  # midpoints of edges 01, 12, 20 of each face
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        f = np.concatenate(
            [
                np.stack([a, m[0], m[2]], 1),
                np.stack([b, m[1], m[0]], 1),
                np.stack([c, m[2], m[1]], 1),
                np.stack([m[0], m[1], m[2]], 1),
            ]
        )
        v = np.concatenate([v, mid])
    return v * float(radius) + _v3(center, "icosphere center"), f


def _perpendicular(d: np.ndarray) -> np.ndarray:
    a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    p = np.cross(d, a)
    return p / np.linalg.norm(p)


def cylinder(radius: float, p0, p1, segments: int = 16, caps: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Cylinder of ``radius`` from point ``p0`` to point ``p1`` with ``segments`` sides;
    ``caps`` closes both ends (outward normals)."""
    p0, p1 = _v3(p0, "cylinder p0"), _v3(p1, "cylinder p1")
    axis = p1 - p0
    length = np.linalg.norm(axis)
    if length <= 0 or radius <= 0 or segments < 3:
        raise ValueError("cylinder: needs radius > 0, p0 != p1 and segments >= 3")
    d = axis / length
    e1 = _perpendicular(d)
    e2 = np.cross(d, e1)  # (e1, e2, d) right-handed
    ang = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ring = radius * (np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2)
    n = segments
    verts = [p0 + ring, p1 + ring]
    k = np.arange(n)
    k1 = (k + 1) % n
    # bottom ring k, top ring n + k; (k, k1, n+k): e_tangent x d = outward.
    faces = [np.stack([k, k1, n + k], 1), np.stack([k1, n + k1, n + k], 1)]
    if caps:
        verts += [p0[None], p1[None]]
        cb, ct = 2 * n, 2 * n + 1
        faces += [
            np.stack([np.full(n, cb), k1, k], 1),  # faces -d
            np.stack([np.full(n, ct), n + k, n + k1], 1),
        ]  # faces +d
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64)


def ellipse_fans(
    centers, major, normals, length, width, segments: int = 6, cup: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """K small ellipses at once, each a fan of ``segments`` triangles around its center.

    ``centers`` (K,3); ``major`` (K,3) direction of the long axis; ``normals`` (K,3) the side the
    triangles face (made orthogonal to ``major``); ``length``/``width`` (K,) full axis lengths;
    ``cup`` moves each center vertex along its normal by ``cup * width`` (a slightly cupped leaf).
    """
    c = np.asarray(centers, float).reshape(-1, 3)
    k = len(c)
    d = np.asarray(major, float).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    n = np.asarray(normals, float).reshape(-1, 3)
    s = np.cross(n, d)
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    n = np.cross(d, s)  # unit, orthogonal to d and s; d x s = n
    L = np.broadcast_to(np.asarray(length, float), (k,))[:, None]
    W = np.broadcast_to(np.asarray(width, float), (k,))[:, None]
    ang = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    rim = (
        c[:, None, :]
        + (L / 2)[..., None] * np.cos(ang)[None, :, None] * d[:, None, :]
        + (W / 2)[..., None] * np.sin(ang)[None, :, None] * s[:, None, :]
    )  # (K, S, 3)
    mid = c + cup * W * n
    stride = segments + 1
    verts = np.concatenate([mid[:, None, :], rim], axis=1).reshape(-1, 3)
    base = (np.arange(k) * stride)[:, None]
    j = np.arange(segments)[None, :]
    faces = np.stack([np.broadcast_to(base, (k, segments)), base + 1 + j, base + 1 + (j + 1) % segments], -1)
    return verts, faces.reshape(-1, 3).astype(np.int64)
