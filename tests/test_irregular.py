"""``irregular`` (soft irregular shadow mapping): closed forms, the composition identity against
brute-force clipping, the umbra against Embree, the two overdraw optimisations, V's range."""

import functools

import numpy as np
import pytest

from softshadows._jit import py_callable
from softshadows.analytic import disk_halfplane_visibility
from softshadows.api import eye_view, render
from softshadows.methods.base import FrameContext, Timer
from softshadows.methods.ground_truth import BOUND_SAFETY, build_embree_scene, hit_points
from softshadows.methods.irregular import counted_faces, irregular_visibility
from softshadows.raster import rasterize
from softshadows.scene import builtin
from softshadows.scene import primitives as prim
from softshadows.scene.types import Camera, Mesh, RectLight, Scene, SphereLight

CAM = Camera((0.0, 6.0, 6.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0)
UP = np.array([0.0, 1.0, 0.0])


def _ground():
    return Mesh(*prim.plane(8.0, 8.0, 2, 2), role="receiver", name="ground")


def _ground_points(xs, zs):
    x, z = np.meshgrid(xs, zs)
    pts = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)
    return pts, np.tile(UP, (len(pts), 1))


def _eye_points(scene, w=64, h=48):
    """The method's default samples: ground truth's ray origins (hit point in float64, geometric
    normal, per-sample float error bound), as ``Irregular.run`` makes them."""
    view = eye_view(scene, w, h)
    g = rasterize(view, scene.flat.vertices, scene.flat.faces, cull="none")
    ctx = FrameContext(scene=scene, eye=g, eye_view=view, timer=Timer())
    _p, nrm, idx = ctx.points()
    pts, n, err_point, err_embree, _grazing, _own = hit_points(scene.flat, g, idx, nrm)
    return pts, n, idx, BOUND_SAFETY * (err_point + err_embree)


# ---------------------------------------------------------------------------------------------
# closed forms
# ---------------------------------------------------------------------------------------------
def test_straight_edge_sphere_light_matches_circular_segment():
    """A half-plane occluder (a huge quad with one edge x = 0 at y = 1) over the ground, sphere
    light: V on both sides of the edge (inner and outer penumbra) is the closed-form circular
    segment. Everything is float64 and exact (projection from p, Eq. 3), so the only error is
    rounding: acos near 1 loses ~sqrt(eps) ~ 1.5e-8 in the angle, hence 1e-7."""
    v, f = prim.quad((-20.0, 1.0, 0.0), (0.0, 0.0, 40.0), (40.0, 0.0, 0.0))
    light = SphereLight((0.2, 3.0, 0.1), 0.5)
    scene = Scene([_ground(), Mesh(v, f, role="occluder", name="half-plane")], light, CAM)
    pts, nrm = _ground_points(np.linspace(-1.0, 1.0, 81), np.linspace(-1.0, 1.0, 5))
    _v, _st, umbra, pen = irregular_visibility(scene, pts, nrm, offset=0.0, grid=32, bins=4, raw=True)
    got = 1.0 - (umbra + pen)
    want = disk_halfplane_visibility(pts, light.center, light.radius, (0.0, 1.0, 0.0), (0, 0, 1), (-1.0, 1.0, 0.0))
    pen = (want > 1e-3) & (want < 1 - 1e-3)
    assert (pen & (want < 0.45)).sum() > 40 and (pen & (want > 0.55)).sum() > 40  # both sides sampled
    np.testing.assert_allclose(got, want, atol=1e-7)


def test_square_rect_light_matches_closed_form():
    """The built-in ``square`` scene with its rect light: V is separable in closed form
    (builtin.square_visibility); the rectangle kernel clips exactly, so float64 rounding only."""
    scene = builtin.square("rect")
    pts, nrm = _ground_points(np.linspace(-1.3, 1.3, 53), np.linspace(-1.3, 1.3, 53))
    # off the symmetric lattice: a sample exactly on the line of the occluder's diagonal or edges
    # (through the light centre) is a tie that no float test resolves like the closed form
    pts[:, [0, 2]] += np.random.default_rng(0).uniform(-0.01, 0.01, (len(pts), 2))
    _v, _st, umbra, pen = irregular_visibility(scene, pts, nrm, offset=0.0, grid=32, bins=4, raw=True)
    got = 1.0 - (umbra + pen)
    want = builtin.square_visibility(pts)
    assert ((want > 0.01) & (want < 0.99)).sum() > 500
    np.testing.assert_allclose(got, want, atol=1e-9)


# ---------------------------------------------------------------------------------------------
# the composition identity against brute-force clipping
# ---------------------------------------------------------------------------------------------
def _clip(P, a, b, c):
    """Polygon P (N,2) clipped to a x + b y + c >= 0 (Sutherland-Hodgman, vectorized)."""
    if len(P) == 0:
        return P
    f = P @ np.array([a, b]) + c
    Q, fq = np.roll(P, -1, axis=0), np.roll(f, -1)
    keep, cross = f >= 0, (f >= 0) != (fq >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(cross, f / (f - fq), 0.0)
    inter = P + t[:, None] * (Q - P)
    pts = np.stack([P, inter], axis=1).reshape(-1, 2)
    return pts[np.stack([keep, cross], axis=1).reshape(-1)]


def _area(P):
    if len(P) < 3:
        return 0.0
    x, y = P[:, 0], P[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _clip_convex(P, C):
    """P clipped by the convex counter-clockwise polygon C."""
    for i in range(len(C)):
        e = C[(i + 1) % len(C)] - C[i]
        P = _clip(P, -e[1], e[0], -(-e[1] * C[i, 0] + e[0] * C[i, 1]))
        if len(P) == 0:
            break
    return P


def _brute_force_occlusion(scene, pts, n_gon=4096):
    """Sum over counted triangles of area(projection from p onto the light's plane intersect light)
    / area(light): the disk (facing p) as an inscribed n-gon, the rectangle exactly."""
    light = scene.light
    occ, counted = counted_faces(scene.flat, light.center)
    tris = scene.flat.vertices[occ[counted]]  # (T,3,3)
    c = light.center
    out = np.zeros(len(pts))
    for k, p in enumerate(pts):
        if light.shape == "sphere":
            w = (c - p) / np.linalg.norm(c - p)
            e1 = np.cross(w, [1.0, 0.0, 0.0] if abs(w[0]) < 0.9 else [0.0, 0.0, 1.0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(w, e1)
            ang = np.linspace(0, 2 * np.pi, n_gon, endpoint=False)
            L2 = light.radius * np.stack([np.cos(ang), np.sin(ang)], axis=1)
            full = np.pi * light.radius**2
        else:
            w = light.normal * np.sign(np.dot(light.normal, c - p))
            e1 = light.u / np.linalg.norm(light.u)
            e2 = np.cross(w, e1)
            hu, hv = np.linalg.norm(light.u) / 2, np.linalg.norm(light.v) / 2
            L2 = np.array([[-hu, -hv], [hu, -hv], [hu, hv], [-hu, hv]])
            full = 4 * hu * hv
        Lh = np.dot(c - p, w)
        for T in tris:
            h = (T - p) @ w
            assert (h > 0).all() and (h < Lh).all()  # the test meshes lie between p and the light
            X = p + (T - p) * (Lh / h)[:, None] - c
            P = np.stack([X @ e1, X @ e2], axis=1)
            if (P[1, 0] - P[0, 0]) * (P[2, 1] - P[0, 1]) - (P[1, 1] - P[0, 1]) * (P[2, 0] - P[0, 0]) < 0:
                P = P[::-1]
            out[k] += _area(_clip_convex(L2, P)) / full
    return out


def _random_scene(seed, shape):
    rng = np.random.default_rng(seed)
    meshes = [_ground()]
    # open sheets: random triangles (both sides counted), some sharing an edge (a folded strip)
    v = rng.uniform([-0.8, 1.2, -0.8], [0.8, 1.9, 0.8], size=(6, 3))
    meshes.append(Mesh(v, [[0, 1, 2], [1, 3, 2], [3, 4, 5]], role="occluder", name="sheet"))
    # a closed solid: a jittered icosphere (light-facing side counted)
    sv, sf = prim.icosphere(0.3, (rng.uniform(-0.4, 0.4), 1.5, rng.uniform(-0.4, 0.4)), subdivisions=1)
    sv = sv + rng.normal(0, 0.02, sv.shape)
    meshes.append(Mesh(sv, sf, role="occluder", name="solid"))
    c = (rng.uniform(-0.3, 0.3), 3.0, rng.uniform(-0.3, 0.3))
    light = SphereLight(c, 0.45) if shape == "sphere" else RectLight(c, (0.9, 0, 0), (0, 0, 0.7))
    return Scene(meshes, light, CAM)


@pytest.mark.parametrize("shape", ["sphere", "rect"])
@pytest.mark.parametrize("seed", [1, 2])
def test_composition_identity_against_brute_force_clipping(seed, shape):
    """umbral count + signed penumbral sum = sum over counted triangles of the exact covered
    fraction of the light, at every sample, for both edge sets (all edges of every triangle, and
    adjacency silhouettes + folds). Tolerance: the disk reference is an inscribed 4096-gon, short
    of the disk by (2 pi / 4096)^2 / 6 = 4e-7 of its area, per overlapping triangle (< 25 here);
    the rectangle reference is exact (1e-9, rounding)."""
    scene = _random_scene(seed, shape)
    rng = np.random.default_rng(100 + seed)
    pts = np.c_[rng.uniform(-1.5, 1.5, 150), np.zeros(150), rng.uniform(-1.5, 1.5, 150)]
    nrm = np.tile(UP, (len(pts), 1))
    ref = _brute_force_occlusion(scene, pts)
    assert (ref > 0.02).sum() > 40 and ((ref > 0.02) & (ref < 0.98)).sum() > 20  # penumbrae sampled
    tol = 1e-5 if shape == "sphere" else 1e-9
    for sil in ("all-edges", "adjacency"):
        _v, _st, umbra, pen = irregular_visibility(
            scene, pts, nrm, offset=0.0, grid=16, bins=4, silhouettes=sil, raw=True
        )
        np.testing.assert_allclose(umbra + pen, ref, atol=tol, err_msg=sil)


# ---------------------------------------------------------------------------------------------
# umbra against Embree
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["square", "spheres", "bunny"])
def test_umbra_matches_embree_ray_to_light_centre(name):
    """(umbral count > 0) = Embree's ray from the offset sample to the light centre is occluded.
    Mismatches can only come from rays grazing a triangle edge (at a silhouette, where the count
    steps), where Embree's float32 test and our float64 point-in-triangle test round differently:
    allow 0.2% of the samples (at 64x48, 6 pixels), and require every mismatch to lie within one
    pixel of a step of our count (a sample whose eye-space neighbour has a different count)."""
    scene = builtin.build(name, "sphere")
    pts, nrm, idx, bound = _eye_points(scene)
    _v, _st, umbra, _pen = irregular_visibility(scene, pts, nrm, origin_bound=bound, raw=True)
    flat = scene.flat
    esc = build_embree_scene(flat.vertices, flat.faces[flat.occluder])
    org = (pts + bound[:, None] * nrm).astype(np.float32)  # ground truth's origins (its float32 bound)
    d = scene.light.center - org
    dist = np.linalg.norm(d, axis=1)
    hits = esc.run(org, (d / dist[:, None]).astype(np.float32), dists=dist.astype(np.float32), query="OCCLUDED")
    rt = np.asarray(hits) >= 0
    ours = umbra > 0
    assert ours.sum() > 50  # there is an umbra to compare
    bad = np.flatnonzero(rt != ours)
    assert len(bad) <= 0.002 * len(pts), f"{len(bad)} mismatches of {len(pts)}"
    img = np.full(64 * 48, -1)
    img[idx] = ours
    img = np.pad(img.reshape(48, 64), 1, constant_values=-1)
    for k in idx[bad]:
        i, j = k // 64 + 1, k % 64 + 1
        nb = img[i - 1 : i + 2, j - 1 : j + 2]
        assert (nb[nb >= 0] != img[i, j]).any(), f"mismatch at pixel {k} away from any umbra boundary"


# ---------------------------------------------------------------------------------------------
# the two overdraw optimisations
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,shape", [("bunny", "sphere"), ("spheres", "rect"), ("fence", "sphere")])
def test_optimisations_change_no_bit_and_cut_sample_tests(name, shape):
    scene = builtin.build(name, shape)
    pts, nrm, _idx, bound = _eye_points(scene)
    runs = {}
    for per_bin in (False, True):
        for wedge in (False, True):
            runs[per_bin, wedge] = irregular_visibility(
                scene, pts, nrm, origin_bound=bound, per_bin=per_bin, wedge=wedge
            )
    v0 = runs[False, False][0]
    for k, (v, _st) in runs.items():
        assert np.array_equal(v, v0), k
    tests = {k: st["penumbra_sample_tests"] for k, (_v, st) in runs.items()}
    assert tests[True, False] < tests[False, False]
    assert tests[False, True] < tests[False, False]
    assert tests[True, True] < min(tests[True, False], tests[False, True])
    assert runs[True, True][1]["quad_bin_pairs"] < runs[False, True][1]["quad_bin_pairs"]


# ---------------------------------------------------------------------------------------------
# the vectorized disk terms
# ---------------------------------------------------------------------------------------------
def test_atan2_upper_agrees_with_libm():
    """The branch-free atan2 of the disk term (Cephes' rational approximation, ~1e-16 relative)
    against math.atan2 over 16 decades of y/x, both signs of x and the zeros: within 4 units in the
    last place (Cephes documents 2; 4 leaves room for the final pi - t)."""
    from softshadows.analytic import atan2_upper

    rng = np.random.default_rng(7)
    y = np.abs(rng.standard_normal(20000)) * 10.0 ** rng.uniform(-8, 8, 20000)
    x = rng.standard_normal(20000) * 10.0 ** rng.uniform(-8, 8, 20000)
    y[:50], x[50:100] = 0.0, 0.0
    got = np.array([py_callable(atan2_upper)(a, b) for a, b in zip(y, x, strict=True)])
    want = np.arctan2(y, x)
    assert np.all(np.abs(got - want) <= 4 * np.spacing(np.maximum(want, np.finfo(float).tiny)))


def test_vectorized_disk_terms_equal_the_scalar_path_bit_for_bit():
    """``disk_edge_terms`` (every early exit a select) against ``sample_edge_term`` per sample, for
    edges with one and two counted triangles, at points all around the edge (endpoints behind p,
    lines missing the disk, triangles cancelling): the same float64 values, bit for bit, and enough
    of them nonzero that the comparison means something."""
    from numba import njit

    from softshadows.methods.irregular import _ROW, _TERM_ROWS, disk_edge_terms, sample_edge_term, sample_row

    @njit
    def both(pts, center, radius, ea, eb, tv_start, tv):
        n = pts.shape[0]
        scalar = np.empty((ea.shape[0], n))
        batch = np.empty((ea.shape[0], n))
        rw = np.empty((_ROW, n))
        cp = np.ascontiguousarray(pts.T)
        z = np.zeros(3)
        buf = np.zeros((4, 8))
        sc = np.empty((_TERM_ROWS, n))
        for j in range(n):
            sample_row(1, center, z, pts, j, rw, j)
        for e in range(ea.shape[0]):
            for j in range(n):
                scalar[e, j] = sample_edge_term(1, rw, j, z, z, radius, 0.0, 0.0, e, ea, eb, tv_start, tv, buf)
            out = np.full(n, np.nan)
            disk_edge_terms(cp, n, center, radius, e, ea, eb, tv_start, tv, sc, out)
            batch[e] = out  # every term, the early exits' exact zeros included
        return scalar, batch

    rng = np.random.default_rng(3)
    ne = 40
    ea, eb = rng.uniform(-1, 1, (ne, 3)), rng.uniform(-1, 1, (ne, 3))
    ntri = rng.integers(1, 3, ne)
    tv_start = np.concatenate([[0], np.cumsum(ntri)])
    tv = rng.uniform(-1, 1, (tv_start[-1], 3))
    pts = rng.uniform(-2, 2, (400, 3)) * [1.0, 0.5, 1.0] - [0.0, 1.0, 0.0]  # mostly below the edges
    center = np.array([0.0, 2.5, 0.0])
    scalar, batch = both(pts, center, 1.5, ea, eb, tv_start, tv)
    # equal floats are equal bits, but for the zeros' sign (-0.0 where the scalar path exits early
    # with 0.0, which adds nothing either way)
    assert np.all(np.isfinite(batch)) and np.array_equal(scalar, batch)
    assert np.count_nonzero(scalar) > 0.05 * scalar.size
    assert np.count_nonzero(scalar == 0) > 0.2 * scalar.size


def _rect_terms_both_paths(pts, center, nrm, lu, lv, hu, hv, ea, eb, tv_start, tv):
    """(scalar ``sample_edge_term``, ``rect_edge_terms``) of every edge at every point."""
    from numba import njit

    from softshadows.methods.irregular import _ROW, _TERM_ROWS, rect_edge_terms, sample_edge_term, sample_row

    @njit
    def both(pts, center, nrm, lu, lv, hu, hv, ea, eb, tv_start, tv):
        n = pts.shape[0]
        scalar = np.empty((ea.shape[0], n))
        batch = np.empty((ea.shape[0], n))
        rw = np.empty((_ROW, n))
        cp = np.ascontiguousarray(pts.T)
        buf = np.zeros((4, 8))
        sc = np.empty((_TERM_ROWS, n))
        out = np.empty(n)
        for j in range(n):
            sample_row(0, center, nrm, pts, j, rw, j)
        for e in range(ea.shape[0]):
            for j in range(n):
                scalar[e, j] = sample_edge_term(0, rw, j, lu, lv, 0.0, hu, hv, e, ea, eb, tv_start, tv, buf)
            out[:] = np.nan
            rect_edge_terms(cp, n, center, nrm, lu, lv, hu, hv, e, ea, eb, tv_start, tv, sc, out)
            batch[e] = out  # every term, the early exits' exact zeros included
        return scalar, batch

    return both(pts, center, nrm, lu, lv, hu, hv, ea, eb, tv_start, tv)


@pytest.mark.parametrize("case", ["random", "degenerate"])
def test_vectorized_rect_terms_agree_with_the_scalar_clipping(case):
    """``rect_edge_terms`` (the region's area from its boundary, branch-free) against
    ``sample_edge_term``'s Sutherland-Hodgman clipping (``_rect_term``), for edges with one and two
    counted triangles at points all around them (endpoints behind p, lines missing the light,
    triangles cancelling). "random": a tilted light and general positions. "degenerate": an
    axis-aligned light, axis-aligned edges and every coordinate a multiple of 1/8, so that edge
    lines project exactly parallel to the rectangle's sides and across it (6% of the pairs) and
    exactly onto a side's line (11%: an exact zero on both paths, the line-misses exit). Both compute the same area in float64 in different orders: terms are
    fractions in [0, 1] summed from O(1) coordinates, so they agree to a few hundred units in the
    last place of 1 (1e-13 here; measured 1e-14 at most). The zeros must agree too, except where
    the region has an area of rounding size."""
    rng = np.random.default_rng(5 if case == "random" else 6)
    q = (lambda a: np.round(a * 8) / 8) if case == "degenerate" else (lambda a: a)
    ne = 60
    ea, eb = q(rng.uniform(-1, 1, (ne, 3))), q(rng.uniform(-1, 1, (ne, 3)))
    if case == "degenerate":  # each edge along one axis
        axis = rng.integers(0, 3, ne)
        end = ea.copy()
        end[np.arange(ne), axis] = eb[np.arange(ne), axis]
        eb = end
    ntri = rng.integers(1, 3, ne)
    tv_start = np.concatenate([[0], np.cumsum(ntri)])
    tv = q(rng.uniform(-1, 1, (tv_start[-1], 3)))
    pts = q(rng.uniform(-2, 2, (400, 3)) * [1.0, 0.5, 1.0] - [0.0, 1.0, 0.0])  # mostly below the edges
    if case == "random":
        center = np.array([0.1, 2.5, -0.2])
        nrm = np.array([0.2, -1.0, 0.1]) / np.linalg.norm([0.2, -1.0, 0.1])
        lu = np.cross(nrm, [0.3, 0.0, 1.0])
        lu /= np.linalg.norm(lu)
        lv = np.cross(nrm, lu)
        hu, hv = 0.6, 0.45
    else:
        center, nrm = np.array([0.0, 2.5, 0.0]), np.array([0.0, -1.0, 0.0])
        lu, lv = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
        hu, hv = 0.625, 0.375
    scalar, batch = _rect_terms_both_paths(pts, center, nrm, lu, lv, hu, hv, ea, eb, tv_start, tv)
    assert np.all(np.isfinite(batch))
    np.testing.assert_allclose(batch, scalar, rtol=0, atol=1e-13)
    assert np.count_nonzero(scalar) > 0.02 * scalar.size
    assert np.count_nonzero(scalar == 0) > 0.2 * scalar.size
    assert np.count_nonzero((scalar == 0) != (batch == 0)) <= 1e-3 * scalar.size


@pytest.mark.parametrize("case", ["random", "degenerate"])
def test_rect_bound_keeps_every_nonzero_term(case):
    """The rectangle light's candidate bound (``rect_reach``: the edge's image swept by the light's
    image-plane box scaled by k = 1/z_min - 1/z) is exact and conservative: every (edge, point)
    whose term is nonzero passes it at the point's own k, as the penumbra pass tests each sample;
    and it rejects most of the zeros (it is not vacuous). The same random and degenerate edges,
    points and lights as the test above (the scalar clipping's terms)."""
    from softshadows.methods.irregular import _SLACK, rect_reach
    from softshadows.raster.view import light_frame

    rng = np.random.default_rng(5 if case == "random" else 6)
    q = (lambda a: np.round(a * 8) / 8) if case == "degenerate" else (lambda a: a)
    ne = 60
    ea, eb = q(rng.uniform(-1, 1, (ne, 3))), q(rng.uniform(-1, 1, (ne, 3)))
    if case == "degenerate":
        axis = rng.integers(0, 3, ne)
        end = ea.copy()
        end[np.arange(ne), axis] = eb[np.arange(ne), axis]
        eb = end
    ntri = rng.integers(1, 3, ne)
    tv_start = np.concatenate([[0], np.cumsum(ntri)])
    tv = q(rng.uniform(-1, 1, (tv_start[-1], 3)))
    pts = q(rng.uniform(-2, 2, (400, 3)) * [1.0, 0.5, 1.0] - [0.0, 1.0, 0.0])
    if case == "random":
        center = np.array([0.1, 2.5, -0.2])
        nrm = np.array([0.2, -1.0, 0.1]) / np.linalg.norm([0.2, -1.0, 0.1])
        lu = np.cross(nrm, [0.3, 0.0, 1.0])
        lu /= np.linalg.norm(lu)
        lv = np.cross(nrm, lu)
        hu, hv = 0.6, 0.45
    else:
        center, nrm = np.array([0.0, 2.5, 0.0]), np.array([0.0, -1.0, 0.0])
        lu, lv = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
        hu, hv = 0.625, 0.375
    scalar, _batch = _rect_terms_both_paths(pts, center, nrm, lu, lv, hu, hv, ea, eb, tv_start, tv)
    vr, vu, vf = light_frame(RectLight(center, 2 * hu * lu, 2 * hv * lv))
    assert np.allclose(vf, nrm)

    def image(x):
        d = x - center
        z = d @ vf
        return (d @ vr) / z, (d @ vu) / z, z

    ax, ay, az = image(ea)
    bx, by, bz = image(eb)
    px, py, pz = image(pts)
    qd = np.zeros((ne, 10))
    qd[:, 0], qd[:, 1], qd[:, 2], qd[:, 3] = ax, ay, bx, by
    qd[:, 7] = 1.0 / np.minimum(az, bz)
    qd[:, 8] = hu * abs(lu @ vr) + hv * abs(lv @ vr)
    qd[:, 9] = hu * abs(lu @ vu) + hv * abs(lv @ vu)
    reach = py_callable(rect_reach)
    front = (az > 0) & (bz > 0)  # the pass bins only edges in front of the light
    kept = nonzero = rejected_zeros = zeros = 0
    for e in np.flatnonzero(front):
        for j in np.flatnonzero(pz > 0):
            ok = reach(qd, e, px[j], px[j], py[j], py[j]) <= (qd[e, 7] - 1.0 / pz[j]) * (1.0 + _SLACK)
            if scalar[e, j] != 0.0:
                nonzero += 1
                kept += ok
            else:
                zeros += 1
                rejected_zeros += not ok
    assert nonzero > 500 and kept == nonzero
    assert rejected_zeros > 0.5 * zeros


@functools.cache
def _sphere_terms():
    """A compiled function: the scalar path's (``sample_edge_term``) sphere term of every edge at
    every point, (edges, points)."""
    from numba import njit

    from softshadows.methods.irregular import _ROW, sample_edge_term, sample_row

    @njit
    def terms(pts, center, radius, ea, eb, tv_start, tv):
        n = pts.shape[0]
        out = np.empty((ea.shape[0], n))
        rw = np.empty((_ROW, n))
        z = np.zeros(3)
        buf = np.zeros((4, 8))
        for j in range(n):
            sample_row(1, center, z, pts, j, rw, j)
        for e in range(ea.shape[0]):
            for j in range(n):
                out[e, j] = sample_edge_term(1, rw, j, z, z, radius, 0.0, 0.0, e, ea, eb, tv_start, tv, buf)
        return out

    return terms


def _edge_arc(ea, eb, e, center, radius):
    """(edge e's arc as ``_arc_setup`` writes it, r / dmin with the pass's margins), or None when
    the edge comes within the light's radius of its centre (the pass then skips the angular tests)."""
    from softshadows.methods.irregular import _QCOLS, _QN, _arc_setup, reach_ratio

    u = eb[e] - ea[e]
    tt = np.clip((center - ea[e]) @ u / (u @ u), 0.0, 1.0)
    dmin = float(np.linalg.norm(ea[e] + tt * u - center))
    if not dmin > radius:
        return None
    qd = np.zeros((len(ea), _QCOLS))
    py_callable(_arc_setup)(ea, eb, e, center, dmin, qd)
    return np.ascontiguousarray(qd[e, _QN : _QN + 15]), py_callable(reach_ratio)(qd, e, radius)


def test_disk_reach_in_arc_from_the_ends_cosines_is_arc_positions():
    """``disk_reach`` decides "inside the arc's wedge" from the ends' cosines (u . a^, u . b^ and
    a^ . b^) instead of ``arc_position``'s two wedge-plane products: the same keep as the test
    written with those products, at random unit directions and distances against random arcs
    (the two can differ only within rounding of a wedge plane, where both values of the test
    agree)."""
    from softshadows.methods.irregular import arc_position, disk_reach

    rng = np.random.default_rng(21)
    ne = 50
    center, radius = np.array([0.1, 2.5, -0.2]), 0.45
    ea = rng.uniform(-1, 1, (ne, 3)) * [1.0, 0.4, 1.0] + [0.0, 0.8, 0.0]
    eb = ea + rng.uniform(-0.6, 0.6, (ne, 3))
    pos, reach = py_callable(arc_position), py_callable(disk_reach)
    u = rng.normal(size=(400, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    iD = 1.0 / rng.uniform(2.0, 6.0, 400)
    both, kept = [0, 0], 0
    for e in range(ne):
        ar = _edge_arc(ea, eb, e, center, radius)
        if ar is None:
            continue
        arc, rdm = ar
        for (x, y, z), i_d in zip(u, iD):
            sn, inarc, ca, cb = pos(x, y, z, arc)  # the test as written before, with the products
            cm = max(ca, cb)
            s2 = sn * sn if inarc else 1.0 - cm * cm
            tt = rdm - radius * i_d * (1.0 - s2)
            want = (tt >= 0.0 and s2 <= tt * tt) or not (ca > 0.0 and cb > 0.0)
            assert bool(reach(x, y, z, i_d, radius, rdm, arc)) == want
            both[bool(inarc)] += 1
            kept += want
    assert min(both) > 500 and 0 < kept < sum(both)  # both sides of the wedge; both outcomes


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_disk_bound_keeps_every_nonzero_term(scale):
    """The sphere light's per-sample test (``disk_reach``: the angle at the light centre between the
    sample and the edge's arc, against r / dmin) is conservative: every (edge, point) whose term
    (``sample_edge_term``, the scalar path) is nonzero passes it, for edges with dmin > r (the pass
    uses it only for those); and it rejects most of the zeros (it is not vacuous). Random edges
    around a light, points below them, on the edges' lines, next to their ends and just past
    them (where the terms start), at three scene scales."""
    from softshadows.methods.irregular import disk_reach

    rng = np.random.default_rng(11)
    ne = 80
    center = np.array([0.1, 2.5, -0.2]) * scale
    radius = 0.45 * scale
    ea = rng.uniform(-1, 1, (ne, 3)) * scale
    eb = ea + rng.uniform(-0.3, 0.3, (ne, 3)) * scale
    ntri = rng.integers(1, 3, ne)
    tv_start = np.concatenate([[0], np.cumsum(ntri)])
    tv = rng.uniform(-1, 1, (tv_start[-1], 3)) * scale
    below = rng.uniform(-2, 2, (300, 3)) * [1.0, 0.5, 1.0] * scale - [0.0, 1.0 * scale, 0.0]
    # points on the lines from the light through the edges' points, past them, slightly off
    e_i = rng.integers(0, ne, 300)
    t = rng.uniform(-0.2, 1.2, 300)[:, None]
    x = ea[e_i] + t * (eb[e_i] - ea[e_i])
    along = center + (x - center) * rng.uniform(1.0, 2.0, 300)[:, None]
    along += rng.normal(0, 1e-3, (300, 3)) * scale
    pts = np.concatenate([below, along])
    got = _sphere_terms()(pts, center, radius, ea, eb, tv_start, tv)
    reach = py_callable(disk_reach)
    d = pts - center
    D = np.sqrt((d * d).sum(1))
    kept = nonzero = rejected_zeros = zeros = 0
    for e in range(ne):
        ar = _edge_arc(ea, eb, e, center, radius)
        if ar is None:
            continue
        arc, rdm = ar
        for j in range(len(pts)):
            iD = 1.0 / D[j]
            ok = reach(d[j, 0] * iD, d[j, 1] * iD, d[j, 2] * iD, iD, radius, rdm, arc)
            if got[e, j] != 0.0:
                nonzero += 1
                kept += bool(ok)
            else:
                zeros += 1
                rejected_zeros += not ok
    assert nonzero > 300 and kept == nonzero
    assert rejected_zeros > 0.5 * zeros


def _sphere_cell_setup(rng, ne):
    """A sphere light (centre, radius), a view from its centre (vp: right, up, forward) and ne
    random edges (a, b) around and below it: the cell-column tests' setting."""
    from softshadows.raster.view import VP_FORWARD, VP_RIGHT, VP_SIZE, VP_UP

    center, radius = np.array([0.1, 2.5, -0.2]), 0.45
    f = np.array([0.1, -1.0, 0.05])
    f /= np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    vp = np.zeros(VP_SIZE)
    vp[VP_RIGHT : VP_RIGHT + 3], vp[VP_UP : VP_UP + 3], vp[VP_FORWARD : VP_FORWARD + 3] = r, u, f
    ea = rng.uniform(-1, 1, (ne, 3)) * [1.0, 0.4, 1.0] + [0.0, 0.8, 0.0]
    eb = ea + rng.uniform(-0.3, 0.3, (ne, 3))
    return center, radius, vp, (r, u, f), ea, eb


def test_disk_cell_bound_keeps_every_nonzero_term():
    """The sphere's cell-column test (``disk_cell_reach``: the arc's angle to the cell's centre
    direction less the cell's half diagonal, against r / dmin at the farthest receivers) covers
    every sample of the cell whose term is nonzero, and its wedge entry lies at or before that
    sample's distance, as the penumbra pass uses it (the first slice tested is the entry's). Random
    edges around a light, a view from the light centre, cells of three sizes, samples on rays
    through random points of each cell at random distances; and it rejects most cells holding only
    zeros (it is not vacuous)."""
    from softshadows.methods.irregular import (
        _SLACK,
        cell_direction,
        disk_cell_reach,
    )

    rng = np.random.default_rng(12)
    ne = 60
    center, radius, vp, (r, u, f), ea, eb = _sphere_cell_setup(rng, ne)
    ntri = rng.integers(1, 3, ne)
    tv_start = np.concatenate([[0], np.cumsum(ntri)])
    tv = rng.uniform(-1, 1, (tv_start[-1], 3))
    reach = py_callable(disk_cell_reach)
    cdir = py_callable(cell_direction)
    covered = nonzero = empty_cells = rejected = 0
    for half in (0.005, 0.02, 0.06):  # half the cell's side (image-plane units)
        cells = rng.uniform(-0.8, 0.8, (150, 2))
        hd = np.hypot(half, half) * (1.0 + 1e-12)
        chd, shd = np.cos(hd), np.sin(hd) * (1.0 + 1e-12)
        # 12 samples per cell: random image points of the cell, random distances in [2, 6]
        img = cells[:, None, :] + rng.uniform(-half, half, (150, 12, 2))
        dirs = img[..., :1] * r + img[..., 1:] * u + f
        dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
        pts = (center + dirs * rng.uniform(2.0, 6.0, (150, 12, 1))).reshape(-1, 3)
        D = np.linalg.norm(pts - center, axis=1).reshape(150, 12)
        got = _sphere_terms()(pts, center, radius, ea, eb, tv_start, tv).reshape(ne, 150, 12)
        for e in range(ne):
            ar = _edge_arc(ea, eb, e, center, radius)
            if ar is None:
                continue
            arc, rdm = ar
            for c in range(150):
                mx, my, mz = cdir(cells[c, 0], cells[c, 1], vp)
                ok, entry = reach(mx, my, mz, chd, shd, arc, rdm, radius, 1.0 / D[c].max())
                nz = got[e, c] != 0.0
                if nz.any():
                    nonzero += int(nz.sum())
                    hit = (not ok) or (entry >= 0.0 and np.all(entry * (1.0 - _SLACK) <= D[c][nz]))
                    covered += int(nz.sum()) if hit else 0
                else:
                    empty_cells += 1
                    rejected += ok and entry < 0.0
    assert nonzero > 300 and covered == nonzero
    assert rejected > 0.5 * empty_cells


def test_disk_cells_reach_is_disk_cell_reach_for_every_cell():
    """``disk_cells_reach`` (the penumbra pass's per-(edge, bin) test of all the bin's cells at once,
    branch-free) gives ``disk_cell_reach``'s (applies, entry) bit for bit, cell by cell: random
    edges and cell directions around a light, cells of three sizes; the three outcomes (the quad
    decides, no entry, an entry) each occur."""
    from softshadows.methods.irregular import cell_direction, disk_cell_reach, disk_cells_reach

    rng = np.random.default_rng(13)
    ne = 40
    center, radius, vp, _frame, ea, eb = _sphere_cell_setup(rng, ne)
    reach, batch, cdir = py_callable(disk_cell_reach), py_callable(disk_cells_reach), py_callable(cell_direction)
    seen = set()
    n = 64
    for half in (0.005, 0.02, 0.06):
        hd = np.hypot(half, half) * (1.0 + 1e-12)
        chd, shd = np.cos(hd), np.sin(hd) * (1.0 + 1e-12)
        mdir = np.array([cdir(x, y, vp) for x, y in rng.uniform(-0.8, 0.8, (n, 2))]).T.copy()
        for e in range(ne):
            ar = _edge_arc(ea, eb, e, center, radius)
            if ar is None:
                continue
            arc, rdm = ar
            iDb = 1.0 / rng.uniform(2.0, 6.0)
            app, ent = np.full(n, np.nan), np.full(n, np.nan)
            batch(mdir, n, chd, shd, arc, rdm, radius, iDb, app, ent)
            for lc in range(n):
                ok, entry = reach(mdir[0, lc], mdir[1, lc], mdir[2, lc], chd, shd, arc, rdm, radius, iDb)
                assert (app[lc] != 0.0) == ok and ent[lc] == entry, (half, e, lc)
                seen.add("quad" if not ok else ("none" if entry < 0.0 else "entry"))
    assert seen == {"quad", "none", "entry"}


def test_rect_sector_area_against_exact_cases():
    """``rect_sector_area``: the area of [-1, 1] x [-0.5, 0.5] swept counter-clockwise from the +x
    axis, at the axes, the corners and in between (exact in binary: tolerance 0), and the swept
    area between two directions through opposite corners is half the rectangle."""
    from softshadows.analytic import rect_sector_area

    g = py_callable(rect_sector_area)
    cases = [
        ((1.0, 0.0), 0.0),
        ((1.0, 0.25), 0.125),  # the triangle (0,0), (1,0), (1,0.25)
        ((1.0, 0.5), 0.25),  # the first corner: half the quadrant
        ((0.5, 0.5), 0.375),  # meets the top at x = 0.5: 0.5 - the triangle to (0, 0.5)
        ((0.0, 3.0), 0.5),  # the +y axis: one quadrant
        ((-1.0, 0.5), 0.75),
        ((-2.0, 0.0), 1.0),  # the -x axis: two quadrants
        ((-1.0, -0.25), 1.125),
        ((0.0, -1.0), 1.5),
        ((1.0, -0.5), 1.75),
        ((4.0, -0.5), 1.9375),  # meets the right side at y = -0.125
    ]
    for (x, y), want in cases:
        assert g(1.0, 0.5, x, y) == want, (x, y)
    assert g(1.0, 0.5, -1.0, -0.5) - g(1.0, 0.5, 1.0, 0.5) == 1.0


def test_rect_beyond_segment_area_against_exact_cases():
    """``rect_beyond_segment_area`` on [-1, 1] x [-0.5, 0.5]: the part beyond a segment (or ray)
    P + t V, 0 <= t <= tmax, inside the angle it subtends at the centre, on cases whose area is
    known exactly: segments across the rectangle, partly inside, missing it with their line
    crossing it, along a side, and rays. Tolerance: a few units in the last place of the O(1)
    sector areas it subtracts."""
    from softshadows.analytic import rect_beyond_segment_area

    def area(px, py, vx, vy, tmax=1.0):
        return py_callable(rect_beyond_segment_area)(1.0, 0.5, px, py, vx, vy, tmax)

    inf = np.inf
    cases = [
        ((-2.0, 0.25, 4.0, 0.0), 0.5),  # y = 0.25 across: the strip above it
        ((0.5, -1.0, 0.0, 2.0), 0.5),  # x = 0.5 across: the strip right of it
        ((0.5, -0.25, 0.0, 0.5), 0.375),  # x = 0.5, |y| <= 0.25: x in [0.5, 1], |y| <= x / 2
        ((0.5, 0.25, 0.0, -0.5), 0.375),  # the same segment the other way round
        ((0.5, 0.0, 0.0, 1.0, inf), 0.25),  # the ray up x = 0.5 from y = 0: the first quadrant beyond it
        ((0.5, 0.0, 0.0, -1.0, inf), 0.25),  # the ray down
        ((1.5, -1.0, 0.0, 2.0), 0.0),  # outside, its line too
        ((1.5, -0.2, -0.2, 0.1), 0.0),  # x + 2y = 1.1 crosses the rectangle; the segment ends before it
        ((-1.0, 0.5, 2.0, 0.0), 0.0),  # along the top side: nothing beyond it
        ((0.5, 0.5, 0.5, -0.5), 0.125),  # from (0.5, 0.5) to (1, 0): the corner triangle beyond it
        ((0.0, 0.25, 1.0, 0.0, inf), 0.25),  # y = 0.25, x >= 0: [0, 1] x [0.25, 0.5]
    ]
    for args, want in cases:
        assert area(*args) == pytest.approx(want, abs=4e-16), args


# ---------------------------------------------------------------------------------------------
# range on every built-in scene
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("shape", ["rect", "sphere"])
@pytest.mark.parametrize("name", list(builtin.builtin_scenes()))
def test_visibility_finite_in_unit_interval(name, shape):
    r = render(builtin.build(name, shape), "irregular", 64, 48)
    v = r.visibility[r.mask]
    assert np.isfinite(v).all() and v.min() >= 0.0 and v.max() <= 1.0
    assert (v < 0.5).any()  # every built-in scene has a shadow in view


@pytest.mark.parametrize("threads,serial_places", [(1, True), (2, True), (2, False)])
def test_sort_samples_is_the_serial_counting_sort_whatever_the_threads(threads, serial_places, monkeypatch):
    """``sort_samples`` (the grid's counting sort and gather by the threads together; the places
    in one serial pass below ``_SERIAL_PLACES`` keys, else by the threads) gives the serial
    ``counting_sort``'s start and order (stable, negative keys dropped) and the samples in that
    order with their image position and distance in the view (the same bits as NumPy's same
    expressions), with one thread or two; keys repeat, some bins stay empty."""
    import numba

    from softshadows.methods import irregular as ir
    from softshadows.methods.irregular import counting_sort, sort_samples
    from softshadows.raster.view import VP_FORWARD, VP_ORIGIN, VP_RIGHT, VP_UP, View

    monkeypatch.setattr(ir, "_SERIAL_PLACES", 1 << 30 if serial_places else 0)

    rng = np.random.default_rng(7)
    n, n_keys = 5003, 97
    key = rng.integers(-5, n_keys, size=n).astype(np.int64)
    key[key == 13] = 14  # an empty bin
    pts = rng.standard_normal((n, 3)) + np.array([0.0, 0.0, 10.0])
    f = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    r = np.cross([0.0, 1.0, 0.0], f)
    r /= np.linalg.norm(r)
    vp = View(np.array([0.3, -0.1, 0.2]), r, np.cross(f, r), f, (-1, 1, -1, 1), 0.1, 100.0, 8, 8).params()
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        start, order, sx, sy, sp, sd = sort_samples(key, pts, vp, n_keys)
    finally:
        numba.set_num_threads(old)
    s_ref, o_ref = counting_sort(key, n_keys)
    np.testing.assert_array_equal(start, s_ref)
    np.testing.assert_array_equal(order, o_ref)
    d = pts[o_ref] - vp[VP_ORIGIN : VP_ORIGIN + 3]

    def dot(a):
        return d[:, 0] * a[0] + d[:, 1] * a[1] + d[:, 2] * a[2]

    z = dot(vp[VP_FORWARD : VP_FORWARD + 3])
    np.testing.assert_array_equal(sx, dot(vp[VP_RIGHT : VP_RIGHT + 3]) / z)
    np.testing.assert_array_equal(sy, dot(vp[VP_UP : VP_UP + 3]) / z)
    np.testing.assert_array_equal(sd, np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]))
    np.testing.assert_array_equal(sp, pts[o_ref])


@pytest.mark.parametrize("slices,nan_table", [(8, False), (3, False), (40, False), (8, True)])
@pytest.mark.parametrize("threads", [1, 2])
def test_sample_keys_are_the_cell_and_slice_of_numpys_expressions(slices, nan_table, threads):
    """The grid keys (``_sample_keys_slot``: cell column and row, then the slice, through a scratch
    in three loops) are (rx[cx] + ry[cy]) x slices + s with NumPy's same expressions for the cell
    and ``slice_of``'s slice (the largest s with sb[s] <= d; ``np.searchsorted``'s on a table without
    NaN), -1 behind the near plane: with the slice counted over the table (8 and 3 slices: tables
    of 8 and 4 entries), searched per sample (40 slices: a table of 64, past ``_COUNT_SLICES_MAX``;
    or a table with a NaN), with one thread or two, on more samples than a run (``_KEY_RUN``) with a
    short last chunk. Some samples lie exactly at a table entry's distance (slice s, not s - 1)."""
    import numba

    from softshadows.methods import irregular as ir
    from softshadows.raster.view import VP_B, VP_FORWARD, VP_L, VP_ORIGIN, VP_R, VP_RIGHT, VP_T, VP_UP, View

    rng = np.random.default_rng(11)
    n = ir._KEY_RUN + 777
    f = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    r = np.cross([0.0, 1.0, 0.0], f)
    r /= np.linalg.norm(r)
    o = np.array([0.3, -0.1, 0.2])
    vp = View(o, r, np.cross(f, r), f, (-0.5, 0.6, -0.4, 0.7), 0.1, 100.0, 8, 8).params()
    pts = o + rng.standard_normal((n, 3)) * 3.0 + 8.0 * f  # some outside the window: clamped cells
    pts[:40] = o - rng.random((40, 3)) * f  # behind the light: key -1
    d = pts - vp[VP_ORIGIN : VP_ORIGIN + 3]
    dist = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])  # the kernel's expression
    sb = ir.slice_bounds(6.0, 11.0, slices)
    # the table's entries moved to the distances of some samples in front (still increasing)
    at = 40 + np.argsort(dist[40:200])[np.linspace(5, 150, slices - 1).astype(int)]
    sb[1:slices] = dist[at]
    if nan_table:
        sb[slices - 2] = np.nan
    gx, gy, B = 24, 20, 4
    rx, ry = ir.cell_numbers(gx, gy, B, -(-gx // B))
    near = 0.1
    count = len(sb) <= ir._COUNT_SLICES_MAX and not np.isnan(sb).any()
    assert count == (slices <= 8 and not nan_table)
    key = np.full(n, -7, np.int64)
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        sc = np.empty((numba.get_num_threads(), ir._KEY_ROWS, ir._KEY_CHUNK))
        ir.run_threads(
            ir._sample_keys_slot, pts, vp, gx, gy, rx, ry, slices, sb, near, count, key, sc, ir.work_counter()
        )
    finally:
        numba.set_num_threads(old)

    def dot(a):
        return d[:, 0] * a[0] + d[:, 1] * a[1] + d[:, 2] * a[2]

    x, y, z = dot(vp[VP_RIGHT : VP_RIGHT + 3]), dot(vp[VP_UP : VP_UP + 3]), dot(vp[VP_FORWARD : VP_FORWARD + 3])
    ok = z > near
    with np.errstate(divide="ignore", invalid="ignore"):
        l, rr, b, t = vp[VP_L], vp[VP_R], vp[VP_B], vp[VP_T]
        cx = np.clip(np.floor(((x / z) - l) / (rr - l) * gx), 0.0, gx - 1.0)
        cy = np.clip(np.floor((t - (y / z)) / (t - b) * gy), 0.0, gy - 1.0)
    slice_of = py_callable(ir.slice_of)
    s = np.array([slice_of(float(v), sb) for v in dist])
    if not nan_table:
        np.testing.assert_array_equal(s, np.searchsorted(sb[: len(sb) - 1], dist, side="right") - 1)
        np.testing.assert_array_equal(s[at], np.arange(1, slices))  # d == sb[s]: slice s
    ref = (rx[np.where(ok, cx, 0).astype(np.int64)] + ry[np.where(ok, cy, 0).astype(np.int64)]) * slices + s
    ref = np.where(ok, ref, -1)
    assert ok[at].all() and not ok[:40].any()
    np.testing.assert_array_equal(key, ref)


def test_bound_median_is_the_median_of_every_64th_sample():
    """The statistic ``origin_bound_median`` (``bound_median``): np.median of every 64th bound, in
    sample order, the input untouched; 0 without samples."""
    from softshadows.methods.irregular import bound_median

    rng = np.random.default_rng(5)
    for n in (1, 63, 64, 65, 1000, 227_376):
        x = np.abs(rng.normal(3e-6, 1e-6, n))
        y = x.copy()
        assert bound_median(y) == np.median(x[::64])
        assert np.array_equal(y, x)
    assert bound_median(np.empty(0)) == 0.0


def test_median_in_place_is_numpys_median():
    """``median_in_place`` (one partition around the middle; the statistic ``origin_bound_median``)
    gives ``np.median``'s value exactly, for odd and even counts, ties and the bounds' magnitudes."""
    from softshadows.methods.irregular import median_in_place

    rng = np.random.default_rng(4)
    for n in (1, 2, 3, 4, 5, 10, 11, 1000, 1001):
        for x in (rng.normal(size=n), rng.integers(0, 5, n).astype(float), np.abs(rng.normal(3e-6, 1e-6, n))):
            want = np.median(x)
            y = x.copy()
            assert median_in_place(y) == want
            assert np.array_equal(np.sort(y), np.sort(x))  # a permutation of x


@pytest.mark.parametrize("light", ["rect", "sphere"])
def test_frame_is_the_same_whatever_the_threads(light):
    """The whole method (its work queues, the umbra count overlapping the silhouettes and quads on
    the calling thread, ``start_slots``) gives the same V bits and statistics with one thread as
    with two, at the defaults on `bunny`."""
    import numba

    scene = builtin.build("bunny", light)
    old = numba.get_num_threads()
    runs = []
    try:
        for t in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(t)
            runs.append(render(scene, "irregular", 96, 72))
    finally:
        numba.set_num_threads(old)
    a, b = runs
    assert np.array_equal(a.visibility, b.visibility, equal_nan=True)
    assert (a.visibility < 0.5).any() and ((a.visibility > 0.05) & (a.visibility < 0.95)).any()
    assert a.stats == b.stats


@pytest.mark.parametrize("scene_name", ["bunny", "plant"])
def test_error_bound_samples_are_ground_truths_ray_origins(scene_name):
    """``error_bound_samples`` (the default samples, straight from the G-buffer, by blocks, a
    point on the previous point's triangle reusing its corners) gives ground truth's ray origins
    bit for bit: ``hit_points`` of ``gather_points``' normals, moved along the normal by
    BOUND_SAFETY x (error bounds) + eps; and those bounds. ``plant``: many small triangles, so the
    triangle changes often between neighbouring pixels."""
    from softshadows.methods.irregular import error_bound_samples, offset_points

    scene = builtin.build(scene_name, "rect")
    view = eye_view(scene, 160, 120)
    g = rasterize(view, scene.flat.vertices, scene.flat.faces, cull="none")
    ctx = FrameContext(scene=scene, eye=g, eye_view=view, timer=Timer())
    _p, nrm, idx = ctx.points()
    hp, n, err_point, err_embree, _grazing, _own = hit_points(scene.flat, g, idx, nrm)
    bound = BOUND_SAFETY * (err_point + err_embree)
    eps = 1e-4
    want = offset_points(hp, n, eps, bound)
    got, got_bound, _bounds = error_bound_samples(ctx.flat, ctx.eye, ctx.pixels(), scene.camera.eye, eps, scene.light)
    assert len(got) > 1000
    assert np.array_equal(got_bound, bound)
    assert np.array_equal(got, want)
    tri = g.tri_id.ravel()[ctx.pixels()]
    assert 0.2 < np.mean(tri[1:] == tri[:-1]) < 1.0  # both paths of the corners' gather taken


@pytest.mark.parametrize("light", ["rect", "sphere"])
def test_error_bound_bounds_are_those_of_its_samples(light):
    """``error_bound_samples``' extent and window (the rectangle's frame; the sphere's toward a
    given point), folded from its blocks, are ``_extent``'s and ``_window_of``'s of the samples it
    returns, the same bits: the grid built from them is the grid built from the samples."""
    from softshadows.methods.irregular import _extent, _window_of, error_bound_samples
    from softshadows.raster.view import light_frame

    scene = builtin.build("bunny", light)
    view = eye_view(scene, 160, 120)
    g = rasterize(view, scene.flat.vertices, scene.flat.faces, cull="none")
    ctx = FrameContext(scene=scene, eye=g, eye_view=view, timer=Timer())
    idx = ctx.pixels()
    c = np.asarray(scene.light.center, float)
    pts, _bound, bounds = error_bound_samples(ctx.flat, ctx.eye, idx, scene.camera.eye, 0.0, scene.light)
    want = _extent(pts, c)
    assert len(pts) > 1000
    for a, b in zip(bounds.extent, want, strict=True):
        assert np.array_equal(np.asarray(a), np.asarray(b))
        assert np.array_equal(np.signbit(a), np.signbit(b))
    toward = None
    if light == "sphere":
        assert bounds.window is None  # no frame known before the samples: no window
        # with the point the sphere's frame looks toward (Irregular.run: the scene's box centre)
        lo_s, hi_s = scene.bounds()
        toward = (lo_s + hi_s) / 2
        pts2, _b, bounds = error_bound_samples(ctx.flat, ctx.eye, idx, scene.camera.eye, 0.0, scene.light, toward)
        assert np.array_equal(pts2, pts) and np.array_equal(bounds.toward, toward)
    r, u, f = light_frame(scene.light, toward=toward)
    lo, hi = want[0], want[1]
    near = 1e-6 * float(np.linalg.norm(hi - lo))
    assert bounds.window[6] > near  # every sample beyond the near plane: the window applies
    assert bounds.window[:6] == _window_of(pts, c, r, u, f, near)


def test_fold_extent_keeps_the_first_of_equal_values():
    """``fold_extent`` folds its rows in order as one pass over the samples would: of equal values
    (-0.0 and 0.0) the first is kept, d0 and d1 are the smallest and largest; 1 and 1 without
    samples."""
    from softshadows.methods.irregular import fold_extent

    part = np.array(
        [
            [0.0, 1.0, -0.0, 2.0, 0.0, 3.0, 5.0, 4.0],
            [-0.0, 0.5, 0.0, 1.5, -0.0, 4.0, 5.0, 6.0],
            [np.inf, np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf, 0.0],  # an empty run
        ]
    )
    lo, hi, d0, d1 = fold_extent(part, 7)
    assert lo.tolist() == [0.0, 0.5, 0.0] and not np.signbit(lo[0]) and np.signbit(lo[2])
    assert hi.tolist() == [0.0, 4.0, 5.0] and not np.signbit(hi[0])
    assert (d0, d1) == (1.5, 6.0)
    assert fold_extent(part[2:], 0)[2:] == (1.0, 1.0)


def test_an_error_while_the_umbrae_are_counted_leaves_the_threads_usable(monkeypatch):
    """An exception in the serial work that overlaps the umbra kernel (``start_umbrae``) reaches the
    caller as itself, the calling thread's thread count is restored (``calling_thread_only``), and
    the next frame renders the same V as before (the slot threads are free again)."""
    import numba

    from softshadows.methods import irregular as ir

    scene = builtin.build("bunny", "rect")
    want = render(scene, "irregular", 64, 48)
    threads = numba.get_num_threads()

    def broken(*a, **k):
        raise RuntimeError("quads")

    monkeypatch.setattr(ir, "build_penumbra_quads", broken)
    with pytest.raises(RuntimeError, match="quads"):
        render(scene, "irregular", 64, 48)
    monkeypatch.undo()
    assert numba.get_num_threads() == threads
    again = render(scene, "irregular", 64, 48)
    assert np.array_equal(again.visibility, want.visibility, equal_nan=True)


@pytest.mark.parametrize("threads", [1, 2])
def test_an_error_in_the_umbrae_set_up_reaches_the_caller(monkeypatch, threads):
    """The umbra count's triangle set-up runs on the first slot to start (a slot thread, or the
    calling thread when it has none, ``start_umbrae``): an exception there reaches the caller as
    itself from every slot (none waits for a set-up that failed), and the next frame renders the
    same V as before."""
    import numba

    from softshadows.methods import irregular as ir

    scene = builtin.build("bunny", "sphere")
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        want = render(scene, "irregular", 64, 48)
        calls = []

        def broken(*a, **k):
            calls.append(1)
            raise RuntimeError("set-up")

        monkeypatch.setattr(ir, "_triangle_setup", broken)
        with pytest.raises(RuntimeError, match="set-up"):
            render(scene, "irregular", 64, 48)
        assert calls == [1]  # made once, whatever the slots
        monkeypatch.undo()
        again = render(scene, "irregular", 64, 48)
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(again.visibility, want.visibility, equal_nan=True)


@pytest.mark.parametrize("light", ["rect", "sphere"])
def test_v_composed_in_the_penumbra_pass_is_eq4_of_its_counts(light):
    """The penumbra pass writes each bin's V as soon as its quads are done (step (e) inside step
    (d)), visiting the bins without quads too: V must be exactly clamp(1 - (umbra + pen)) of the
    per-sample counts and sums, 1 at samples outside the grid, in the eye image at each sample's
    pixel, 1 at pixels without a sample. `bunny` at 96x72 has lit, umbra and penumbra samples and
    bins with samples but no quads (checked)."""
    from softshadows.methods import irregular as ir

    scene = builtin.build("bunny", light)
    pts, nrm, idx, bound = _eye_points(scene, 96, 72)
    n_pix = 96 * 72
    v_img, _st = irregular_visibility(scene, pts, nrm, origin_bound=bound, pixels=idx, n_pixels=n_pix)
    v, _st, umbra, pen = irregular_visibility(scene, pts, nrm, origin_bound=bound, raw=True)
    want = np.where(np.isnan(umbra), 1.0, np.clip(1.0 - (umbra + pen), 0.0, 1.0)).astype(np.float32)
    assert np.array_equal(v, want)
    img = np.ones(n_pix, np.float32)
    img[idx] = want
    assert np.array_equal(v_img, img)
    assert (want == 0.0).any() and (want == 1.0).any() and ((want > 0.05) & (want < 0.95)).any()
    # bins holding samples but no quad: composed by the pass all the same
    g = ir.build_sample_grid(scene.light, ir.offset_points(pts, nrm, 0.0, bound), ir.GRID, ir.BINS, ir.SLICES)
    fc = ir.facing_and_counted(scene.flat, scene.light.center)
    box = ir.receivers_box(g.col_box)
    r = ir._light_params(scene.light)[1]
    edges, _s = ir.select_silhouette_edges(scene.flat, scene.light.center, "adjacency", True, box, r, fc)
    bl = ir.bin_penumbra_quads(g, ir.build_penumbra_quads(g, edges, scene.light, r), r, True)
    cells = g.bins * g.bins * g.slices
    every = ir.bins_by_work(bl[0], g.start, cells, also_empty=True)
    assert len(every) > len(ir.bins_by_work(bl[0], g.start, cells))
    assert sorted(every) == list(np.flatnonzero(np.diff(g.start[::cells]) > 0))


def test_flat_true_is_numpys_flatnonzero():
    """``FrameContext.pixels()``' ``flat_true`` (the eye mask's flat indices for ``irregular``'s
    samples, by ``compact_indices``): ``np.flatnonzero``, int64, for empty, short, 2-D and
    non-contiguous masks of every density; and ``pixels()`` of a rendered frame is it."""
    from softshadows.methods.base import flat_true

    rng = np.random.default_rng(3)
    for shape in [(0,), (1,), (7,), (8,), (9,), (33, 17), (512, 512)]:
        for p in (0.0, 0.3, 0.87, 1.0):
            m = rng.random(shape) < p
            got = flat_true(m)
            assert got.dtype == np.int64
            np.testing.assert_array_equal(got, np.flatnonzero(m))
    m = rng.random((40, 30)) < 0.5
    np.testing.assert_array_equal(flat_true(m[:, ::2]), np.flatnonzero(m[:, ::2]))
    scene = builtin.build("bunny", "rect")
    view = eye_view(scene, 64, 48)
    g = rasterize(view, scene.flat.vertices, scene.flat.faces, cull="none")
    ctx = FrameContext(scene=scene, eye=g, eye_view=view, timer=Timer())
    np.testing.assert_array_equal(ctx.pixels(), np.flatnonzero(g.mask))


@pytest.mark.parametrize("impl", ["scalar", "avx512"])
def test_compact_indices_packs_the_flagged_positions_in_order(impl):
    """``compact_indices`` (the penumbra pass's compaction of the reach tests' survivors): out[m:]
    gets base + q for every flagged q (flags 0 or 1), in order, and the count comes back, for
    lengths around the 8-flag chunks; both implementations (the AVX-512 one only on a host that
    has it) against a Python loop."""
    from softshadows import _jit

    if impl == "avx512" and not _jit.HAS_AVX512:
        pytest.skip("this host has no AVX-512 (the scalar loop is what runs here; tested above)")
    fn = py_callable(_jit._compact_indices_avx512 if impl == "avx512" else _jit._compact_indices_scalar)
    rng = np.random.default_rng(11)
    for n in (0, 1, 7, 8, 9, 15, 16, 17, 63, 64, 65, 200):
        for density in (0.0, 0.3, 1.0):
            keep = (rng.random(n) < density).astype(np.int8)
            base, m0 = int(rng.integers(0, 1000)), int(rng.integers(0, 5))
            out = np.full(m0 + n + 8, -7, np.int64)
            m = fn(keep, np.int64(n), np.int64(base), out, np.int64(m0))
            want = [base + q for q in range(n) if keep[q] != 0]
            assert m == m0 + len(want)
            assert out[m0:m].tolist() == want
            assert (out[:m0] == -7).all()  # nothing written before m
