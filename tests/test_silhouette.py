"""Silhouette edges seen from a point: brute force and adjacency paths against an independent
reference and against geometry whose silhouette is known."""

import numpy as np
import pytest

from softshadows.errors import SoftShadowsError
from softshadows.geometry import silhouette as S
from softshadows.scene import builtin
from softshadows.scene import primitives as prim


def _reference(vertices, faces, point):
    """Independent, loop-based definition: weld by exact position, group triangles per edge, an
    edge is a silhouette if it has one triangle or triangles of both facings."""
    key_of = {}
    rep = np.empty(len(vertices), np.int64)
    for i, v in enumerate(map(tuple, vertices)):
        rep[i] = key_of.setdefault(v, i)
    edges = {}
    for _fi, (a, b, c) in enumerate(faces):
        pa, pb, pc = vertices[a], vertices[b], vertices[c]
        facing = float(np.dot(np.cross(pb - pa, pc - pa), np.asarray(point) - pa)) > 0
        for u, w in ((a, b), (b, c), (c, a)):
            e = tuple(sorted((int(rep[u]), int(rep[w]))))
            edges.setdefault(e, []).append(facing)
    return sorted(list(e) for e, f in edges.items() if len(f) == 1 or (any(f) and not all(f)))


def _both(v, f, p):
    b = S.silhouette_brute(v, f, p)
    a = S.silhouette_adjacency(S.build_adjacency(v, f), p)
    np.testing.assert_array_equal(b.edges, a.edges)
    np.testing.assert_array_equal(b.edge_faces, a.edge_faces)
    np.testing.assert_array_equal(b.boundary, a.boundary)
    np.testing.assert_array_equal(b.vertices, a.vertices)
    np.testing.assert_array_equal(b.degree, a.degree)
    return b


def test_box_from_above_and_from_a_corner():
    # 24-vertex box (flat faces do not share vertices): edges exist only after welding
    v, f = prim.box(1.0)
    top = _both(v, f, (0.0, 3.0, 0.0))  # straight above: the 4 top edges
    assert top.n_edges == 4 and np.all(top.degree == 2)
    assert np.allclose(v[top.edges][..., 1], 0.5)  # all at the top face
    corner = _both(v, f, (3.0, 3.0, 3.0))  # three faces visible: a hexagon
    assert corner.n_edges == 6 and corner.n_vertices == 6 and np.all(corner.degree == 2)
    assert not corner.boundary.any()
    for sil in (top, corner):  # every silhouette edge has one facing and one non-facing triangle
        assert np.all(sil.edge_faces >= 0)
        fr = S.facing(v, f, sil.point)
        assert fr[sil.edge_faces[:, 0]].all() and not fr[sil.edge_faces[:, 1]].any()
    # without welding each face's quad is its own open mesh: its 4 outer edges are boundaries
    raw = S.silhouette_brute(v, f, (3.0, 3.0, 3.0), weld=False)
    assert raw.n_edges == 24 and raw.boundary.all()


def test_open_quad_boundary_whatever_its_facing():
    v, f = prim.quad((0, 1, 0), (0, 0, 1), (1, 0, 0))
    for p in ((0, 3, 0), (0, -3, 0)):  # seen from the front and from the back
        sil = _both(v, f, p)
        assert sil.n_edges == 4 and sil.boundary.all() and np.all(sil.degree == 2)


def test_vertices_of_degree_three_and_more():
    # two triangles touching at one vertex (a bowtie): 6 boundary edges, the shared vertex has 4
    v = np.array([[0, 0, 0], [1, 0, 0.2], [1, 0, -0.2], [-1, 0, 0.2], [-1, 0, -0.2]], float)
    f = np.array([[0, 1, 2], [0, 3, 4]])
    sil = _both(v, f, (0, 2, 0))
    assert sil.n_edges == 6
    assert sil.degree[sil.vertices == 0][0] == 4 and sil.max_degree == 4 and sil.n_vertices_degree3 == 1
    # a non-manifold edge shared by three triangles (a fin on a quad), facings mixed
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0, 1], [0.5, 0, -1], [0.5, 1, 0.0]], float)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    sil = _both(v, f, (0.5, 2.0, 0.3))
    assert sil.edges.tolist() == _reference(v, f, (0.5, 2.0, 0.3))
    nm = [i for i, e in enumerate(sil.edges.tolist()) if e == [0, 1]]
    assert nm and np.all(sil.edge_faces[nm[0]] >= 0)  # both a facing and a non-facing triangle


def test_sphere_contour_is_the_tangent_circle():
    c = np.array([0.2, 1.0, -0.1])
    v, f = prim.icosphere(0.5, c, 3)
    p = np.array([1.0, 4.0, 0.5])
    sil = _both(v, f, p)
    assert np.all(sil.degree % 2 == 0)  # closed loops
    # contour points x satisfy (x - c).(p - x) = 0 up to the tessellation: on the sphere the
    # angle from the tangent cone is at most about one edge length (~0.06 rad at 3 subdivisions)
    x = v[sil.vertices]
    d = (x - c) / 0.5
    t = (p - x) / np.linalg.norm(p - x, axis=1, keepdims=True)
    assert np.max(np.abs(np.einsum("ij,ij->i", d, t))) < 0.1
    # the loop goes all the way around: 642 vertices, a contour of roughly 2*pi*r/edge ~ 50 edges
    assert 30 <= sil.n_edges <= 160


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bunny_matches_reference_from_random_points(seed):
    v, f = builtin._bunny_arrays()
    rng = np.random.default_rng(seed)
    p = rng.uniform(-3, 3, 3) + np.array([0, 3.0, 0])
    sil = _both(v, f, p)
    assert sil.edges.tolist() == _reference(v, f, p)
    assert sil.n_edges > 100
    # the paper's observation: vertices with 3+ silhouette edges are not rare on real models
    assert sil.n_vertices_degree3 > 0


def test_find_silhouette_dispatch_and_cache():
    v, f = builtin._bunny_arrays()
    v = v.copy()
    f = f.copy()
    adj1, built1 = S.cached_adjacency(v, f)
    adj2, built2 = S.cached_adjacency(v, f)
    assert built1 and not built2 and adj1 is adj2
    p = (0.5, 3.2, 0.4)
    a = S.find_silhouette(v, f, p, "adjacency")
    b = S.find_silhouette(v, f, p, "brute")
    np.testing.assert_array_equal(a.edges, b.edges)
    with pytest.raises(SoftShadowsError, match="silhouette method"):
        S.find_silhouette(v, f, p, "fast")


def test_empty_mesh():
    sil = S.silhouette_brute(np.zeros((0, 3)), np.zeros((0, 3), np.int64), (0, 1, 0))
    assert sil.n_edges == 0 and sil.max_degree == 0
