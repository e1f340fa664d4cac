"""Tests of the shared software rasterizer (analytic cases, small images)."""

from __future__ import annotations

import numpy as np
import pytest

from softshadows.raster import (
    Fragments,
    GBuffer,
    View,
    cull_mask,
    face_normals,
    facing,
    rasterize,
    rasterize_depth,
    rasterize_fragments,
)
from softshadows.raster.kernels import sample_bilinear, sample_nearest, view_project, view_unproject


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
def grid_plane(n, x0, x1, z0, z1, y=0.0, jitter=0.0, rng=None, flip_some=False):
    """(n+1)^2 vertices on the plane y = const, 2 triangles per cell, alternating diagonals.
    jitter: random in-plane displacement of interior vertices (fraction of a cell; <= 0.2 can never
    fold a triangle over its neighbour)."""
    xs = np.linspace(x0, x1, n + 1)
    zs = np.linspace(z0, z1, n + 1)
    X, Z = np.meshgrid(xs, zs, indexing="xy")
    if jitter:
        dx = (x1 - x0) / n
        dz = (z1 - z0) / n
        J = rng.uniform(-jitter, jitter, size=(2, n + 1, n + 1))
        J[:, 0, :] = J[:, -1, :] = J[:, :, 0] = J[:, :, -1] = 0
        X = X + J[0] * dx
        Z = Z + J[1] * dz
    V = np.stack([X.ravel(), np.full(X.size, y), Z.ravel()], axis=1)
    F = []
    for r in range(n):
        for c in range(n):
            a = r * (n + 1) + c
            b, d, e = a + 1, a + n + 1, a + n + 2
            if (r + c) % 2:
                F += [[a, b, e], [a, e, d]]
            else:
                F += [[a, b, d], [b, e, d]]
    F = np.array(F, dtype=np.int64)
    if flip_some:
        flip = rng.random(len(F)) < 0.5
        F[flip] = F[flip][:, ::-1]
    return V, F


def cube(center=(0.0, 0.0, 0.0), half=1.0):
    """Closed cube, outward-wound (cross(v1-v0, v2-v0) points outward)."""
    c = np.asarray(center, float)
    V = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half + c

    def idx(x, y, z):
        return (x > 0) * 4 + (y > 0) * 2 + (z > 0)

    F = []
    for axis in range(3):
        for s in (-1, 1):
            quad = []
            for u, w in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = [0, 0, 0]
                p[axis] = s
                p[(axis + 1) % 3] = u
                p[(axis + 2) % 3] = w
                quad.append(idx(*p))
            a, b, cc, d = quad
            tri = [[a, b, cc], [a, cc, d]]
            for t in tri:
                n = np.cross(V[t[1]] - V[t[0]], V[t[2]] - V[t[0]])
                if np.dot(n, V[t[0]] - c) < 0:
                    t.reverse()
                F.append(t)
    return V, np.array(F, dtype=np.int64)


def uv_sphere(nu=24, nv=12, radius=1.0, center=(0.0, 0.0, 0.0)):
    """Closed UV sphere, outward-wound, no degenerate faces (pole fans)."""
    th = np.linspace(0, np.pi, nv + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    V = np.stack([np.sin(T) * np.cos(P), np.cos(T), np.sin(T) * np.sin(P)], -1).reshape(-1, 3)
    V = np.concatenate([[[0, 1, 0]], V, [[0, -1, 0]]])
    top, bot = 0, len(V) - 1

    def ring(k, j):
        return 1 + k * nu + j % nu

    F = [[top, ring(0, j + 1), ring(0, j)] for j in range(nu)]
    for k in range(nv - 2):
        for j in range(nu):
            a, b, c, d = ring(k, j), ring(k, j + 1), ring(k + 1, j), ring(k + 1, j + 1)
            F += [[a, b, d], [a, d, c]]
    F += [[bot, ring(nv - 2, j), ring(nv - 2, j + 1)] for j in range(nu)]
    F = np.array(F, dtype=np.int64)
    c = np.asarray(center, float)
    V = V * radius + c
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    assert np.all(np.einsum("ij,ij->i", n, V[F[:, 0]] - c) > 0)
    return V, F


def pixel_rays(view):
    """Per pixel center: (origin (3,), direction (H,W,3) with unit forward component)."""
    i, j = np.mgrid[0 : view.height, 0 : view.width]
    p1 = view.unproject(j + 0.5, i + 0.5, np.ones(i.shape))
    if view.ortho:
        o = view.unproject(j + 0.5, i + 0.5, np.zeros(i.shape))
        return o, p1 - o
    return view.origin, p1 - view.origin


def analytic_plane_depth(view, p0, n):
    """View depth of the plane (p - p0).n = 0 through every pixel center (NaN if no hit in front)."""
    o, d = pixel_rays(view)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((p0 - o) @ n) / (d @ n)
    s = np.where(np.isfinite(s) & (s > 0), s, np.nan)
    return s, o + s[..., None] * d  # the forward component of d is 1: s is the depth


# ---------------------------------------------------------------------------------------------
# coverage: watertight, no double hits
# ---------------------------------------------------------------------------------------------
def _assert_exact_cover(view, V, F):
    fr = rasterize_fragments(view, V, F)
    assert isinstance(fr, Fragments)
    npx = view.width * view.height
    counts = np.bincount(fr.pixel, minlength=npx)
    assert counts.min() == 1 and counts.max() == 1, (np.sum(counts == 0), np.sum(counts > 1))
    assert len(fr) == npx


def _edge_test_coverage(view, V, F):
    """Reference coverage: every pixel center of every piece's bounding box tested against the
    piece's three edge functions, pixel by pixel (the float64 expressions and the top-left rule of
    the tile kernel), from the setup data of the rasterizer. Sorted (tri, pixel) pairs."""
    from softshadows.raster import rasterizer as R

    vp, W, H, verts, fcs, code, near = R._prepare(view, V, F, "none")
    fe = R._front_end(vp, W, H, verts, fcs, code, near)
    pairs = []
    for ct in np.unique(fe.bins):
        i0, i1, j0, j1 = fe.box[ct, [R.BOX_I0, R.BOX_I1, R.BOX_J0, R.BOX_J1]]
        i, j = np.mgrid[i0 : i1 + 1, j0 : j1 + 1]
        py = i + 0.5
        px = j + 0.5
        cov = np.ones(i.shape, bool)
        for k in range(3):
            ax, ay, dx, dy, sg, inc = fe.edges[ct, k, [R.E_AX, R.E_AY, R.E_DX, R.E_DY, R.E_SG, R.E_OWN]]
            r = dx * (py - ay)
            e = sg * (r - dy * (px - ax))
            cov &= ~((e < 0) | ((e == 0) & (inc == 0)))
        t = fe.tri[ct >> fe.shift]  # the face of the front-end triangle
        pairs += [(t, p) for p in (i[cov] * W + j[cov])]
    return sorted(pairs)


def _random_screen_triangles(rng, n, W, H, kind):
    """Screen-space triangles (sx, sy) of various kinds."""
    if kind == "grid":  # corners on pixel centers and pixel corners: edge functions exactly 0
        xy = rng.integers(-4, 2 * W + 4, size=(n, 3, 2)) * 0.5
    elif kind == "axis":  # axis-aligned edges (dy == 0 or dx == 0) through pixel centers
        a = rng.integers(0, 2 * W, size=(n, 2)) * 0.5
        b = a + rng.integers(-20, 21, size=(n, 2)) * 0.5
        xy = np.stack([a, np.stack([b[:, 0], a[:, 1]], 1), np.stack([a[:, 0], b[:, 1]], 1)], 1)
    elif kind == "sliver":  # long thin triangles
        a = rng.uniform(-W, 2 * W, size=(n, 2))
        d = rng.normal(size=(n, 2)) * 3 * W
        xy = np.stack([a, a + d, a + d * 1.001 + rng.normal(size=(n, 2)) * 0.3], 1)
    elif kind == "huge":  # edge functions far beyond 2^53 (rounded)
        xy = rng.uniform(-1e7, 1e7, size=(n, 3, 2))
        xy[: n // 4] *= 1e5
        xy[:, 0] = rng.uniform(0, W, size=(n, 2))
    else:
        xy = rng.uniform(-5, W + 5, size=(n, 3, 2))
    return xy.reshape(-1, 2)


def _screen_scene(xy, z, W, H, ortho, ortho_near, far):
    """Triangles given by screen positions ``xy`` (pixels, y down) and view depths ``z``, as world
    vertices seen by a W x H view along +z (near ``ortho_near`` when orthographic, 0.5 in
    perspective): (V, view, F), every three vertices a face. Orthographic: window (0, W, 0, H), right
    = -x, so x = -sx, y = H - sy; perspective: window (-1, 1, -1, 1) at depth 1."""
    if ortho:
        V = np.stack([-xy[:, 0], H - xy[:, 1], z], 1)
        view = View.frame([0, 0, 0], [0, 0, 1], [0, 1, 0], (0, W, 0, H), ortho_near, far, W, H, ortho=True)
    else:
        V = np.stack([(1 - 2 * xy[:, 0] / W) * z, (1 - 2 * xy[:, 1] / H) * z, z], 1)
        view = View.frame([0, 0, 0], [0, 0, 1], [0, 1, 0], (-1, 1, -1, 1), 0.5, far, W, H)
    return V, view, np.arange(len(V), dtype=np.int64).reshape(-1, 3)


@pytest.mark.parametrize("kind", ["grid", "axis", "sliver", "huge", "random"])
@pytest.mark.parametrize("ortho", [True, False])
def test_span_coverage_equals_pixel_edge_tests(kind, ortho):
    """The tile kernel finds each row's covered columns as one span: it must cover exactly the
    pixels the per-pixel edge tests (with the top-left rule) accept, bit for bit."""
    rng = np.random.default_rng(5 + len(kind))
    W, H = 83, 61
    n = 300
    xy = _random_screen_triangles(rng, n, W, H, kind)
    z = rng.uniform(1.0, 3.0, size=len(xy))
    V, view, F = _screen_scene(xy, z, W, H, ortho, 0.0, 10.0)
    fr = rasterize_fragments(view, V, F)
    got = sorted(zip(fr.tri.tolist(), fr.pixel.tolist()))
    assert len(got) > 0
    ref = _edge_test_coverage(view, V, F)
    assert got == ref
    # the pixel-by-pixel path of the kernel (for pieces whose edge functions might overflow)
    from softshadows.raster import rasterizer as R

    vp, W_, H_, verts, fcs, code, near = R._prepare(view, V, F, "none")
    fe = R._front_end(vp, W_, H_, verts, fcs, code, near)
    fe.zinfo[:, R.Z_ROBUST] = 0.0  # no piece is "robust"
    fr_scan = R._fragments(fe, W_, H_)
    ftri, fpix = fr_scan.tri, fr_scan.pixel
    assert sorted(zip(ftri.tolist(), fpix.tolist())) == ref
    # the depth-test paths see the same coverage
    _depth, tri = rasterize_depth(view, V, F)
    covered = np.zeros(W * H, bool)
    covered[fr.pixel] = True
    assert np.array_equal(tri.ravel() >= 0, covered)


@pytest.mark.parametrize("jitter", [0.0, 0.2])
def test_tessellated_plane_perspective_exact_cover(jitter):
    rng = np.random.default_rng(1)
    V, F = grid_plane(40, -6, 6, -10, 0, jitter=jitter, rng=rng, flip_some=True)
    view = View.look_at([0.3, 4.0, 0.5], [0.1, 0, -3.5], [0, 1, 0], 40, 72, 56)
    # the plane fills the whole view
    s, hit = analytic_plane_depth(view, np.zeros(3), np.array([0.0, 1.0, 0.0]))
    assert np.all(np.isfinite(s)) and np.all(np.abs(hit[..., 0]) < 5.5)
    assert np.all((hit[..., 2] > -9.5) & (hit[..., 2] < -0.5))
    _assert_exact_cover(view, V, F)


@pytest.mark.parametrize("jitter", [0.0, 0.2])
def test_tessellated_plane_ortho_exact_cover(jitter):
    rng = np.random.default_rng(2)
    V, F = grid_plane(40, -4, 4, -4, 4, jitter=jitter, rng=rng, flip_some=True)
    view = View.frame([0.1, 5, 0.2], [0.3, -1, 0.2], [0, 0, -1], (-1.2, 1.1, -1.0, 1.3), 0.1, 100, 61, 67, ortho=True)
    s, hit = analytic_plane_depth(view, np.zeros(3), np.array([0.0, 1.0, 0.0]))
    assert np.all(np.isfinite(s)) and np.all(np.abs(hit[..., 0]) < 3.5) and np.all(np.abs(hit[..., 2]) < 3.5)
    _assert_exact_cover(view, V, F)


def test_vertices_and_edges_exactly_on_pixel_centers():
    # ortho view in which every grid vertex and every diagonal passes exactly through pixel centers
    V, F = grid_plane(34, -1.5, 66.5, -66.5, 1.5, flip_some=True, rng=np.random.default_rng(3))
    # looking down -y: right = +x, up = -z, so sx = x and sy = 64 + z; the grid overhangs the window
    view = View.frame([0, 10, 0], [0, -1, 0], [0, 0, -1], (0.0, 64.0, 0.0, 64.0), 0.1, 100, 64, 64, ortho=True)
    sx, sy, _ = view.project(V)
    frac = np.concatenate([sx % 1.0, sy % 1.0])
    assert np.allclose(frac, 0.5)  # really on pixel centers
    fr = rasterize_fragments(view, V, F)
    counts = np.bincount(fr.pixel, minlength=64 * 64)
    assert counts.min() == 1 and counts.max() == 1
    # and the nearest-surface buffer has every pixel
    assert rasterize(view, V, F).mask.all()


def test_closed_sphere_watertight_and_silhouettes():
    """Curved closed mesh (vertex fans, silhouettes) from random views: the front faces cover every
    pixel at most once, the back faces cover exactly the same pixels, and without culling the
    nearest surface is always a front face (no back face wins on silhouette pixels)."""
    rng = np.random.default_rng(11)
    V0, F = uv_sphere(20, 11)
    for _ in range(24):
        r = rng.uniform(0.2, 5.0)
        c = rng.normal(size=3)
        V = V0 * r + c
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        eye = c + d * r * rng.uniform(1.2, 5.0)
        W, H = (int(x) for x in rng.integers(12, 40, size=2))
        if rng.random() < 0.3:
            view = View.frame(eye, c - eye, [0, 1, 0], (-0.9 * r, 1.1 * r, -r, 0.8 * r), 0.0, 1e3, W, H, ortho=True)
        else:
            view = View.look_at(
                eye, c + rng.normal(size=3) * 0.2 * r, [0, 1, 0], rng.uniform(25, 80), W, H, near=1e-3 * r
            )
        cnt = {}
        for cull in ("none", "back", "front"):
            fr = rasterize_fragments(view, V, F, cull=cull)
            cnt[cull] = np.bincount(fr.pixel, minlength=W * H)
        assert cnt["back"].max() <= 1 and cnt["back"].sum() > 0
        assert np.array_equal(cnt["back"], cnt["front"])
        assert np.array_equal(cnt["none"], cnt["back"] + cnt["front"])
        g = rasterize(view, V, F)
        gb = rasterize(view, V, F, cull="back")
        assert np.array_equal(g.tri_id, gb.tri_id)
        assert np.array_equal(g.mask.ravel(), cnt["back"] == 1)


def test_fragments_min_blend_equals_depth_test():
    rng = np.random.default_rng(4)
    V = rng.uniform(-1, 1, size=(60, 3)) + [0, 0, -4]
    F = rng.integers(0, 60, size=(40, 3))
    view = View.look_at([0, 0, 0], [0, 0, -4], [0, 1, 0], 50, 48, 40)
    g = rasterize(view, V, F)
    fr = rasterize_fragments(view, V, F)
    zmin = np.full(48 * 40, np.inf, np.float32)
    np.minimum.at(zmin, fr.pixel, fr.depth)
    assert np.array_equal(zmin.reshape(40, 48), g.depth)
    # every fragment's (pixel, tri) is unique and deterministic
    key = fr.pixel * 1000 + fr.tri
    assert len(np.unique(key)) == len(key)
    fr2 = rasterize_fragments(view, V, F)
    assert np.array_equal(fr.pixel, fr2.pixel) and np.array_equal(fr.tri, fr2.tri)


@pytest.mark.parametrize("ortho", [False, True])
def test_min_blend_penumbra_culling_is_exact(ortho):
    """rasterize_min_blend with the penumbra program against a per-fragment reference built from
    rasterize_fragments, with and without hierarchical culling of discarded fragments: the culled
    pass must give the same texels and the same kept counts, and must actually cull."""
    from softshadows.raster import rasterize_min_blend
    from softshadows.raster.programs import PROGRAM_PENUMBRA, penumbra_intensity

    rng = np.random.default_rng(11)
    n = 300
    V = rng.uniform(-1.2, 1.2, size=(3 * n, 3)) + [0, 0, -4]
    F = np.arange(3 * n).reshape(n, 3)
    if ortho:
        view = View.frame([0, 0, 0], [0, 0, -1], [0, 1, 0], (-1.2, 1.2, -1.0, 1.0), 0.5, 10, 96, 80, ortho=True)
    else:
        view = View.look_at([0, 0, 0], [0, 0, -4], [0, 1, 0], 40, 96, 80)
    # Z_P: a slanted surface through the geometry, empty (inf) on a block of texels
    yy, xx = np.mgrid[0:80, 0:96]
    zp = (3.2 + 0.02 * xx + 0.01 * yy).astype(np.float32)
    zp[10:30, 60:90] = np.inf
    za = rng.uniform(2.0, 3.5, size=(n, 3))
    za[: n // 2] = za[: n // 2, :1]  # half the triangles with a constant attribute (as cones)
    params = np.array([0.5, 0.01, 1.0])
    fr = rasterize_fragments(view, V, F)
    ref = np.ones(96 * 80, np.float32)
    kept = 0
    for pix, t, b, z in zip(fr.pixel, fr.tri, fr.bary, fr.depth):
        a = (1 - b[0] - b[1]) * za[t, 0] + b[0] * za[t, 1] + b[1] * za[t, 2]
        s = float(zp.ravel()[pix])
        v = penumbra_intensity(float(z), a, s, params[0] * params[1] * s, True)
        if v == v:
            kept += 1
            ref[pix] = min(ref[pix], v)
    ref = ref.reshape(80, 96)
    out = {}
    for cd in (False, True):
        o = np.ones((80, 96), np.float32)
        st = rasterize_min_blend(view, V, F, PROGRAM_PENUMBRA, za, zp, params, o, cull_discarded=cd)
        out[cd] = (o, st)

    def tot(st, k):
        return st[k + "_a"] + st[k + "_b"]

    assert np.array_equal(out[False][0], out[True][0])
    # the coarse value test also skips pieces whose kept fragments could darken no texel
    assert tot(out[True][1], "kept") <= tot(out[False][1], "kept")
    assert out[True][1]["culled_pieces"] > 0 and out[False][1]["culled_pieces"] == 0
    assert out[False][1]["value_culled_pieces"] == 0
    assert tot(out[True][1], "fragments") < tot(out[False][1], "fragments") == len(fr.pixel)
    assert abs(tot(out[False][1], "kept") - kept) <= 0.002 * len(fr.pixel)  # float32 depths in fr
    # fr stores float32 depths and barycentrics: the reference agrees to float32 precision
    assert np.abs(out[True][0] - ref).max() < 2e-3
    # a texel mask: the texels in it exactly as without, the others untouched, fewer fragments
    mask = rng.random((80, 96)) < 0.1
    mask[40:56, 0:48] = False  # whole tiles without a texel to shade
    for cd in (False, True):
        o = np.full((80, 96), 0.75, np.float32)
        o[mask] = 1.0
        st = rasterize_min_blend(view, V, F, PROGRAM_PENUMBRA, za, zp, params, o, cull_discarded=cd, mask=mask)
        assert np.array_equal(o[mask], out[cd][0][mask])
        assert np.all(o[~mask] == 0.75)
        assert 0 < tot(st, "fragments") < 0.25 * tot(out[cd][1], "fragments")


# ---------------------------------------------------------------------------------------------
# depth, position, barycentrics
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("ortho", [False, True])
def test_tilted_plane_depth_position_bary(ortho):
    rng = np.random.default_rng(5)
    n = np.array([0.3, 1.0, 0.45])
    n /= np.linalg.norm(n)
    p0 = np.array([0.0, -0.2, -3.0])
    # a jittered tessellation of the plane: build on y=0, then rotate onto the plane
    V, F = grid_plane(16, -12, 12, -12, 12, jitter=0.2, rng=rng, flip_some=True)
    a = np.cross([0, 1.0, 0], n)
    ang = np.arccos(n[1])
    a /= np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    R = np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K
    V = V @ R.T + p0
    if ortho:
        view = View.frame([0.2, 0.5, 2.0], [0, -0.1, -1], [0, 1, 0], (-1.0, 1.2, -0.8, 0.9), -1, 50, 40, 36, ortho=True)
    else:
        view = View.look_at([0.2, 0.5, 2.0], [0, -0.2, -3], [0, 1, 0], 35, 40, 36)
    g = rasterize(view, V, F)
    assert isinstance(g, GBuffer) and g.shape == (36, 40)
    s, hit = analytic_plane_depth(view, p0, n)
    assert np.all(np.isfinite(s))
    assert g.mask.all()
    np.testing.assert_allclose(g.depth, s, rtol=1e-5)
    # position is on the ray through the pixel center at the rasterized depth
    i, j = np.mgrid[0:36, 0:40]
    ray_p = view.unproject(j + 0.5, i + 0.5, g.depth.astype(np.float64))
    scale = np.abs(hit).max()
    np.testing.assert_allclose(g.position, ray_p, atol=1e-5 * scale)
    np.testing.assert_allclose(g.position, hit, atol=1e-4 * scale)
    # barycentrics of the original triangle reproduce the position
    tri = F[g.tri_id]
    b1, b2 = g.bary[..., 0:1].astype(float), g.bary[..., 1:2].astype(float)
    p_b = V[tri[..., 0]] * (1 - b1 - b2) + V[tri[..., 1]] * b1 + V[tri[..., 2]] * b2
    np.testing.assert_allclose(p_b, hit, atol=1e-4 * scale)
    assert np.all(g.bary >= 0) and np.all(g.bary.sum(-1) <= 1 + 1e-6)
    # normal: the unit face normal as wound
    fn = face_normals(V, F)[g.tri_id]
    np.testing.assert_allclose(g.normal, fn, atol=1e-6)
    np.testing.assert_allclose(np.abs(g.normal @ n), 1.0, atol=1e-6)


def test_background_values():
    view = View.look_at([0, 0, 3], [0, 0, 0], [0, 1, 0], 40, 24, 20)
    V = np.array([[-0.2, -0.2, 0], [0.2, -0.2, 0], [0, 0.2, 0]], float)
    g = rasterize(view, V, np.array([[0, 1, 2]]))
    bg = ~g.mask
    assert bg.any() and g.mask.any()
    assert np.all(np.isnan(g.position[bg])) and np.all(np.isnan(g.normal[bg]))
    assert np.all(np.isinf(g.depth[bg])) and np.all(g.tri_id[bg] == -1)
    assert np.array_equal(g.mask, g.tri_id >= 0)
    assert g.depth.dtype == np.float32 and g.tri_id.dtype == np.int32 and g.position.dtype == np.float32


# ---------------------------------------------------------------------------------------------
# near-plane clipping
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 3])
def test_ground_plane_behind_camera_clipped(n):
    V, F = grid_plane(n, -100, 100, -100, 100)
    V[:, 0] += 0.37
    view = View.look_at([0, 1, 0], [0.3, 0.2, -5], [0, 1, 0], 70, 64, 48, near=0.05, far=1e4)
    # some triangles are partly behind the camera
    z = view.to_view(V)[:, 2]
    assert (z[F] < view.near).any(axis=1).any() and (z[F] > view.near).any(axis=1).any()
    g = rasterize(view, V, F)
    s, hit = analytic_plane_depth(view, np.zeros(3), np.array([0.0, 1.0, 0.0]))
    inside = np.isfinite(s) & (np.abs(hit[..., 0] - 0.37) < 99) & (np.abs(hit[..., 2]) < 99)
    outside = ~np.isfinite(s) | (np.abs(hit[..., 0] - 0.37) > 101) | (np.abs(hit[..., 2]) > 101)
    assert inside.sum() > 500 and outside.sum() > 200
    assert g.mask[inside].all()
    assert not g.mask[outside].any()
    np.testing.assert_allclose(g.depth[inside], s[inside], rtol=1e-5)
    assert np.all(np.isfinite(g.position[g.mask])) and np.all(g.depth[g.mask] >= view.near)
    # barycentrics are with respect to the ORIGINAL triangle
    tri = F[g.tri_id[inside]]
    b = g.bary[inside].astype(float)
    p_b = V[tri[:, 0]] * (1 - b[:, :1] - b[:, 1:]) + V[tri[:, 1]] * b[:, :1] + V[tri[:, 2]] * b[:, 1:]
    np.testing.assert_allclose(p_b, hit[inside], atol=1e-3)
    # fragments: no cracks where the plane is seen
    fr = rasterize_fragments(view, V, F)
    counts = np.bincount(fr.pixel, minlength=64 * 48).reshape(48, 64)
    assert np.all(counts[inside] == 1) and np.all(counts[outside] == 0)


def test_far_plane_discards():
    V, F = grid_plane(2, -100, 100, -100, 100)
    view = View.look_at([0, 1, 0], [0, 0.8, -5], [0, 1, 0], 60, 40, 30, near=0.05, far=20.0)
    g = rasterize(view, V, F)
    s, _ = analytic_plane_depth(view, np.zeros(3), np.array([0.0, 1.0, 0.0]))
    assert g.mask.any()
    assert np.all(g.depth[g.mask] <= 20.0)
    assert not g.mask[np.isfinite(s) & (s > 20.5)].any()
    assert g.mask[np.isfinite(s) & (s < 19.5)].all()


# ---------------------------------------------------------------------------------------------
# culling, depth test, tie rule
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("mirror", [False, True])
def test_cube_culling(mirror):
    V, F = cube((0.1, -0.2, 0.0), 1.0)
    view = View.look_at([3.0, 2.5, 4.0], [0.1, -0.2, 0], [0, 1, 0], 40, 48, 40)
    if mirror:  # a left-handed frame (mirrored image): facing must not change
        view = View(
            view.origin, -view.right, view.up, view.forward, view.window, view.near, view.far, view.width, view.height
        )
    fac = facing(view, V, F)
    front = fac < 0
    assert front.sum() == 6  # three faces visible from this corner
    g0 = rasterize(view, V, F, cull="none")
    gb = rasterize(view, V, F, cull="back")
    gf = rasterize(view, V, F, cull="front")
    assert gb.mask.sum() > 200
    assert np.array_equal(g0.mask, gb.mask) and np.array_equal(gb.mask, gf.mask)
    m = gb.mask
    assert np.all(front[gb.tri_id[m]]) and not np.any(front[gf.tri_id[m]])
    assert np.array_equal(g0.tri_id, gb.tri_id) and np.array_equal(g0.depth, gb.depth)
    assert np.all(gf.depth[m] > gb.depth[m])
    # normals of visible surfaces face the eye for cull=back, away for cull=front
    to_p = gb.position[m] - view.origin
    assert np.all(np.einsum("ij,ij->i", gb.normal[m], to_p) < 0)
    to_p = gf.position[m] - view.origin
    assert np.all(np.einsum("ij,ij->i", gf.normal[m], to_p) > 0)
    assert np.array_equal(cull_mask(view, V, F, "back"), front)
    assert np.array_equal(cull_mask(view, V, F, "front"), fac > 0)
    with pytest.raises(ValueError):
        rasterize(view, V, F, cull="sideways")


def test_cube_culling_ortho():
    V, F = cube()
    view = View.frame([3, 3, 3], [-1, -1, -1], [0, 1, 0], (-2, 2, -2, 2), 0.1, 20, 32, 32, ortho=True)
    gb = rasterize(view, V, F, cull="back")
    gf = rasterize(view, V, F, cull="front")
    front = facing(view, V, F) < 0
    m = gb.mask
    assert m.sum() > 100 and np.array_equal(m, gf.mask)
    assert np.all(front[gb.tri_id[m]]) and not np.any(front[gf.tri_id[m]])
    assert np.all(gb.normal[m] @ view.forward < 0)


def test_nearest_wins_and_ties():
    view = View.look_at([0, 0, 5], [0, 0, 0], [0, 1, 0], 40, 40, 40)
    near_tri = np.array([[-1, -1, 0.5], [1, -1, 0.5], [0, 1, 0.5]], float)
    far_tri = np.array([[-1.2, -1.1, -0.5], [1.1, -1.2, -0.5], [0.1, 1.2, -0.5]], float)
    for order in (0, 1):
        V = np.concatenate([near_tri, far_tri] if order == 0 else [far_tri, near_tri])
        F = np.array([[0, 1, 2], [3, 5, 4]])  # second one wound the other way
        g = rasterize(view, V, F)
        near_id = 0 if order == 0 else 1
        both = rasterize_fragments(view, V, F)
        cnt = np.bincount(both.pixel, minlength=1600).reshape(40, 40)
        assert (cnt == 2).sum() > 100
        assert np.all(g.tri_id[cnt == 2] == near_id)
        np.testing.assert_allclose(g.depth[cnt == 2], 4.5, rtol=1e-6)
    # exact tie (same triangle twice): the smaller index wins
    V = np.concatenate([near_tri, near_tri])
    g = rasterize(view, V, np.array([[3, 4, 5], [0, 2, 1]]))
    assert g.mask.sum() > 100 and np.all(g.tri_id[g.mask] == 0)


def test_ties_go_to_the_smaller_index_when_drawn_front_to_back():
    """The depth pass draws a tile's pieces front to back (by nearest corner depth), not in index
    order, so the tie rule must be explicit. Two triangles on one tilted plane with the same edge
    vectors (so the same plane coefficients, exact in small integers: their depths are equal bit for
    bit where they overlap); face 1 lies nearer (smaller corner depths) and is drawn first, face 0
    must still win every shared pixel, in both dense modes."""
    W, H = 48, 40

    def tri(dx):
        xy = np.array([[12, 8], [40, 8], [12, 36]], float) + [dx, 0]
        return xy, 2.0 + xy[:, 0] / 8.0  # depth grows with the screen x: exact dyadic values

    xa, za = tri(0.0)
    xb, zb = tri(-8.0)  # face 1: 8 px to the left, nearer by 1.0
    V, view, F = _screen_scene(np.concatenate([xa, xb]), np.concatenate([za, zb]), W, H, True, 0.5, 20.0)
    fr = rasterize_fragments(view, V, F)
    cnt = np.bincount(fr.pixel, minlength=W * H).reshape(H, W)
    shared = cnt == 2
    assert shared.sum() > 100
    d_a = np.full(W * H, np.nan, np.float32)
    d_b = np.full(W * H, np.nan, np.float32)
    d_a[fr.pixel[fr.tri == 0]] = fr.depth[fr.tri == 0]
    d_b[fr.pixel[fr.tri == 1]] = fr.depth[fr.tri == 1]
    np.testing.assert_array_equal(d_a[shared.ravel()], d_b[shared.ravel()])  # exact ties
    g = rasterize(view, V, F)
    d, t = rasterize_depth(view, V, F)
    assert np.all(g.tri_id[shared] == 0) and np.all(t[shared] == 0)
    assert np.all(t[cnt == 1] == g.tri_id[cnt == 1]) and (t == 1).sum() > 50
    np.testing.assert_array_equal(d, g.depth)


def test_front_to_back_orders_by_depth_then_slot():
    """A tile's list comes out ordered by (nearest corner depth, piece slot), whether it is ranked by
    counting (up to ``_RANK_MAX`` pieces) or shell-sorted (longer, or a NaN key), with many ties:
    the order of np.lexsort; the NaN keys, which have no place in it, stay a permutation."""
    from softshadows._jit import py_callable
    from softshadows.raster.rasterizer import _RANK_MAX, Z_MIN, _front_to_back

    front_to_back = py_callable(_front_to_back)
    rng = np.random.default_rng(3)
    for n in (0, 1, 2, 7, 18, _RANK_MAX, _RANK_MAX + 1, 300):
        for nan in (False, True):
            zinfo = np.zeros((n + 5, Z_MIN + 1))
            zinfo[:, Z_MIN] = rng.integers(0, max(n // 3, 1), n + 5) * 0.25  # ties
            if nan and n:
                zinfo[rng.integers(0, n + 5, 2), Z_MIN] = np.nan
            slots = rng.permutation(n + 5)[:n].astype(np.int32)
            bins = np.concatenate([[-7], slots, [-9]]).astype(np.int32)  # its neighbours stay
            front_to_back(bins, 1, n, zinfo, np.empty((2, max(n, 1))))
            assert bins[0] == -7 and bins[-1] == -9
            got = bins[1:-1]
            assert sorted(got.tolist()) == sorted(slots.tolist())
            if not np.isnan(zinfo[slots, Z_MIN]).any():
                want = slots[np.lexsort((slots, zinfo[slots, Z_MIN]))]
                np.testing.assert_array_equal(got, want)


def test_copy_tile_row_is_a_slice_assignment():
    """``copy_tile_row`` stores exactly ``dst[di, dj:dj + TILE] = src[si, :TILE]`` (float64 to
    float32 rounded as numpy casts, including inf, NaN and values beyond float32) and nothing
    else."""
    from softshadows._jit import py_callable
    from softshadows.raster.rasterizer import TILE, copy_tile_row

    copy = py_callable(copy_tile_row)
    rng = np.random.default_rng(11)
    src = rng.normal(size=(5, TILE)) * 10.0 ** rng.integers(-40, 40, size=(5, TILE))
    src[1, :4] = [np.inf, -np.inf, np.nan, 1e300]
    for dtype in (np.float32, np.float64):
        dst = np.full((4, 3 * TILE + 5), 7.0, dtype)
        want = dst.copy()
        for di, dj, si in ((0, 0, 0), (3, 2 * TILE + 5, 1), (2, 7, 4)):
            copy(dst, di, dj, src, si)
            with np.errstate(over="ignore"):
                want[di, dj : dj + TILE] = src[si].astype(dtype)
        np.testing.assert_array_equal(dst, want)
    ints = rng.integers(-9, 9, size=(2, TILE)).astype(np.int32)
    dst = np.zeros((2, TILE + 3), np.int32)
    copy(dst, 1, 3, ints, 1)
    assert (dst[1, 3:] == ints[1]).all() and (dst[0] == 0).all() and (dst[1, :3] == 0).all()


def test_rasterize_depth_matches_rasterize():
    rng = np.random.default_rng(7)
    Vc, Fc = cube((0, 0.5, 0), 0.5)
    Vg, Fg = grid_plane(3, -5, 5, -5, 5)
    Vr = rng.uniform(-1, 1, size=(90, 3)) + [0, 1, 0]
    Fr = rng.integers(0, 90, size=(60, 3))
    V = np.concatenate([Vc, Vg, Vr])
    F = np.concatenate([Fc, Fg + len(Vc), Fr + len(Vc) + len(Vg)])
    for view in (
        View.look_at([2, 3, 4], [0, 0.3, 0], [0, 1, 0], 50, 50, 38),
        View.frame([0, 6, 0.5], [0.1, -1, 0], [0, 0, -1], (-3, 3, -2, 2), 0.5, 30, 45, 33, ortho=True),
    ):
        for cull in ("none", "back", "front"):
            g = rasterize(view, V, F, cull=cull)
            d, t = rasterize_depth(view, V, F, cull=cull)
            assert d.dtype == np.float32 and t.dtype == np.int32 and d.shape == (view.height, view.width)
            assert np.array_equal(d, g.depth) and np.array_equal(t, g.tri_id)


def test_degenerate_and_nonfinite_inputs():
    view = View.look_at([0, 0, 3], [0, 0, 0], [0, 1, 0], 40, 24, 20)
    V = np.array([[-1, -1, 0], [1, -1, 0], [0, 1, 0], [np.nan, 0, 0], [np.inf, 1, 1], [0.5, 0.5, 0]], float)
    F = np.array([[0, 1, 3], [3, 4, 0], [0, 0, 1], [0, 5, 5], [0, 1, 2], [2, 1, 4]])
    g = rasterize(view, V, F)
    assert g.mask.any() and set(np.unique(g.tri_id[g.mask])) == {4}
    _d, t = rasterize_depth(view, V, F)
    assert np.array_equal(t, g.tri_id)
    fr = rasterize_fragments(view, V, F)
    assert set(np.unique(fr.tri)) == {4}
    with pytest.raises(ValueError):
        rasterize(view, V, np.array([[0, 1, 6]]))
    empty = rasterize(view, V, np.zeros((0, 3), np.int64))
    assert not empty.mask.any() and np.all(np.isinf(empty.depth))
    assert len(rasterize_fragments(view, V, np.zeros((0, 3), np.int64))) == 0


def test_triangle_fully_behind_or_offscreen():
    view = View.look_at([0, 0, 0], [0, 0, -1], [0, 1, 0], 40, 16, 16)
    V = np.array(
        [
            [-1, -1, 1],
            [1, -1, 1],
            [0, 1, 1],  # behind
            [50, 50, -1],
            [52, 50, -1],
            [51, 52, -1],  # off screen
            [-1, -1, -2],
            [1, -1, -2],
            [0, 1, -2],
        ],
        float,
    )
    F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    g = rasterize(view, V, F)
    assert set(np.unique(g.tri_id[g.mask])) == {2}


# ---------------------------------------------------------------------------------------------
# device helpers
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("ortho", [False, True])
def test_view_project_unproject_helpers(ortho):
    view = View.frame([0.3, 1, 2], [0.1, -0.3, -1], [0, 1, 0], (-0.7, 0.5, -0.4, 0.6), 0.1, 100, 50, 40, ortho=ortho)
    vp = view.params()
    rng = np.random.default_rng(8)
    P = rng.uniform(-1, 1, size=(20, 3)) + [0, 0, -3]
    sx, sy, d = view.project(P)
    for k in range(len(P)):
        a = view_project(vp, *P[k])
        np.testing.assert_allclose(a, (sx[k], sy[k], d[k]), rtol=1e-12, atol=1e-12)
        w = view_unproject(vp, sx[k], sy[k], d[k])
        np.testing.assert_allclose(w, P[k], atol=1e-10)


def test_sampling_helpers():
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    assert sample_nearest(img, 0.5, 0.5, -1.0) == 0.0
    assert sample_nearest(img, 3.99, 2.01, -1.0) == 11.0
    assert sample_nearest(img, -5.0, 100.0, -1.0) == 8.0  # clamp to edge
    assert sample_nearest(img, np.nan, 1.0, -1.0) == -1.0
    assert sample_bilinear(img, 0.5, 0.5) == 0.0
    assert sample_bilinear(img, 1.0, 0.5) == pytest.approx(0.5)
    assert sample_bilinear(img, 1.5, 1.0) == pytest.approx(3.0)
    assert sample_bilinear(img, -3.0, -3.0) == 0.0
    assert sample_bilinear(img, 10.0, 10.0) == 11.0
    assert np.isnan(sample_bilinear(img, np.inf, 1.0))
    img2 = img.copy()
    img2[0, 1] = np.nan
    assert sample_bilinear(img2, 0.5, 0.5) == 0.0  # the NaN neighbour has zero weight


def test_outputs_do_not_depend_on_the_thread_count():
    """Tiles and setup chunks are dealt round-robin to one slot per thread: every output (G-buffer,
    depth, fragment order, min-blend) must be the same with 1 thread as with all of them."""
    import numba

    from softshadows.raster import rasterize_min_blend
    from softshadows.raster.programs import PROGRAM_ATTRIBUTE

    rng = np.random.default_rng(12)
    V, F = grid_plane(20, -3, 3, -9, -2, jitter=0.2, rng=rng)
    V2 = rng.uniform(-1, 1, size=(600, 3)) + [0, 0.5, -5]
    F2 = np.arange(600).reshape(200, 3) + len(V)
    V, F = np.concatenate([V, V2]), np.concatenate([F, F2])
    view = View.look_at([0, 2, 1], [0, 0, -5], [0, 1, 0], 50, 70, 52)
    ca = rng.random((len(F), 3))

    def run():
        g = rasterize(view, V, F)
        d, t = rasterize_depth(view, V, F)
        fr = rasterize_fragments(view, V, F)
        o = np.full((52, 70), np.inf, np.float32)
        rasterize_min_blend(view, V, F, PROGRAM_ATTRIBUTE, ca, np.zeros((52, 70), np.float32), np.zeros(1), o)
        return [g.depth, g.tri_id, g.position, d, t, fr.pixel, fr.tri, fr.depth, o]

    n = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = run()
    finally:
        numba.set_num_threads(n)
    for a, b in zip(one, run()):
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


@pytest.mark.parametrize("ortho", [True, False])
def test_small_triangle_rejection_agrees_with_full_setup(ortho):
    """The front end drops, before setup and binning, the faces that surely give no fragment (sub-pixel
    triangles between pixel centers, culled, beyond far, behind near). Every dropped face must be
    one whose full setup (``_setup_one``) gives no piece or pieces that cover no pixel center (the
    kernels' per-pixel test): then the outputs are those of a setup of every face, bit for bit (the
    setup of a face does not depend on the others)."""
    from softshadows.raster import rasterizer as R

    rng = np.random.default_rng(7)
    W, H, n = 64, 48, 3000
    # tiny triangles (about 0.05..0.6 px), some on pixel centers, plus larger ones and ones behind near
    c = rng.uniform(-2, W + 2, size=(n, 1, 2))
    xy = c + rng.uniform(-0.3, 0.3, size=(n, 3, 2)) * rng.choice([0.2, 1.0, 8.0], size=(n, 1, 1))
    xy[: n // 10] = np.round(xy[: n // 10] * 2) / 2
    z = rng.uniform(0.2, 3.0, size=(n, 3))
    xy, z = xy.reshape(-1, 2), z.reshape(-1)
    V, view, F = _screen_scene(xy, z, W, H, ortho, 0.5, 2.5)
    for cull in ("none", "back"):
        vp, W_, H_, verts, fcs, code, near = R._prepare(view, V, F, cull)
        fe = R._front_end(vp, W_, H_, verts, fcs, code, near)
        kept = np.zeros(n, bool)
        kept[fe.tri[: fe.box.shape[0] >> fe.shift]] = True  # fe.box: 1 << shift piece slots per front-end triangle
        dropped = np.nonzero(~kept)[0]
        assert n // 4 < len(dropped) < n  # the rejection does work here (most faces are sub-pixel)
        NC = np.empty(1, np.int32)
        box = np.empty((2, 4), np.int32)
        edges = np.empty((2, 3, R.E_WIDTH))
        zinfo = np.empty((2, 3))
        planes = np.zeros((1, R.PL_WIDTH))
        normals = np.zeros((1, 3), np.float32)
        vs = np.empty((len(verts), R._VS_WIDTH))  # the corners' view and snapped screen coordinates
        R._vertex_screen_slot(0, verts, vp, near, vs, 1)
        for t in dropped:
            R._setup_one(0, t, verts, fcs, vs, vp, near, code, NC, box, edges, zinfo, planes, normals, 1, True)
            for ct in range(NC[0]):  # pieces of a dropped face cover no pixel center (per-pixel test)
                i0, i1, j0, j1 = box[ct, [R.BOX_I0, R.BOX_I1, R.BOX_J0, R.BOX_J1]]
                i, j = np.mgrid[i0 : i1 + 1, j0 : j1 + 1]
                cov = np.ones(i.shape, bool)
                for k in range(3):
                    ax, ay, dx, dy, sg, inc = edges[ct, k, [R.E_AX, R.E_AY, R.E_DX, R.E_DY, R.E_SG, R.E_OWN]]
                    e = sg * (dx * ((i + 0.5) - ay) - dy * ((j + 0.5) - ax))
                    cov &= ~((e < 0) | ((e == 0) & (inc == 0)))
                assert not cov.any(), t


@pytest.mark.parametrize("ortho", [True, False])
def test_tiny_path_is_bit_identical_to_the_tile_pass(ortho, monkeypatch):
    """rasterize_depth draws the small triangles (bounding box of at most 9 pixel centers) directly
    (``_tiny_depth_slot``) and merges them into the tile pass's output. Both must give what the tile pass
    alone gives, bit for bit, including the tie rule (equal depth: the smaller face wins): here
    half of the small triangles lie on the plane of two big quads (exact depth ties), with face
    indices before and after the quads', and the others at random depths; culled both ways."""
    from softshadows.raster import rasterizer as R

    rng = np.random.default_rng(11)
    W, H, n = 64, 48, 2500
    c = rng.uniform(-2, W + 2, size=(n, 1, 2))
    xy = c + rng.uniform(-1.2, 1.2, size=(n, 3, 2))  # boxes of 0..9 pixel centers (and some more)
    xy[: n // 5] = np.round(xy[: n // 5] * 2) / 2  # corners on pixel centers and edges
    z = rng.uniform(0.6, 2.4, size=(n, 3))
    z[: n // 2] = 2.0  # on the quads' plane (a power of two: the plane depth is exactly 2.0)
    quads = np.array([[[-3, -3], [W + 3, -3], [W + 3, H + 3]], [[-3, -3], [W + 3, H + 3], [-3, H + 3]]], float)
    xy = np.concatenate([xy[: n // 4], quads, xy[n // 4 :]])  # the quads are faces n/4 and n/4 + 1
    z = np.concatenate([z[: n // 4], np.full((2, 3), 2.0), z[n // 4 :]])
    xy, z = xy.reshape(-1, 2), z.reshape(-1)
    V, view, F = _screen_scene(xy, z, W, H, ortho, 0.5, 2.5)
    for cull in ("none", "back"):
        vp, W_, H_, verts, fcs, code, near = R._prepare(view, V, F, cull)
        _fe, tiny = R._front_end(vp, W_, H_, verts, fcs, code, near, tiny=True)
        assert tiny is not None and len(tiny[1]) > n // 4  # many faces do take the tiny path
        monkeypatch.setattr(R, "TINY_PATH", True)
        d1, t1 = rasterize_depth(view, V, F, cull)
        monkeypatch.setattr(R, "TINY_PATH", False)
        d0, t0 = rasterize_depth(view, V, F, cull)
        np.testing.assert_array_equal(d1, d0)
        np.testing.assert_array_equal(t1, t0)
        if cull == "none":
            # ties were decided: the small faces on the plane before the quads (faces < q0) win some
            # of the quads' pixels, those after them (q0 + 2 .. n/2 + 1) none: the quads cover every
            # pixel and a tie goes to the smaller face
            q0 = n // 4
            at_plane = d1 == np.float32(2.0)
            assert (t1[at_plane] < q0).sum() > 20
            assert np.isin(t1[at_plane], [q0, q0 + 1]).sum() > 20
            assert not ((t1[at_plane] >= q0 + 2) & (t1[at_plane] < n // 2 + 2)).any()


@pytest.mark.parametrize("tiny", [True, False])
def test_depth_only_is_the_same_depth(tiny, monkeypatch):
    """``rasterize_depth(tri=False)`` writes no faces (None) and the same depths bit for bit as with
    them: whole tiles and the image's partial last row and column of tiles (70 x 45 pixels), big
    quads and small triangles (through the tiny path and through setup), both cull modes. The quads
    come twice (equal depths at every pixel they win: the depths-only tile pass keeps the first
    fragment where the full one keeps the smaller face, the same depth bits either way)."""
    from softshadows.raster import rasterizer as R

    rng = np.random.default_rng(5)
    W, H, n = 70, 45, 1500
    c = rng.uniform(-2, W + 2, size=(n, 1, 2))
    xy = c + rng.uniform(-4.0, 4.0, size=(n, 3, 2))
    z = rng.uniform(0.6, 2.4, size=(n, 3))
    quads = np.array([[[-3, -3], [W + 3, -3], [W + 3, H + 3]], [[-3, -3], [W + 3, H + 3], [-3, H + 3]]], float)
    xy = np.concatenate([quads, xy, quads]).reshape(-1, 2)
    z = np.concatenate([np.full((2, 3), 2.3), z, np.full((2, 3), 2.3)]).reshape(-1)
    V, view, F = _screen_scene(xy, z, W, H, False, 0.5, 2.5)
    monkeypatch.setattr(R, "TINY_PATH", tiny)
    for cull in ("none", "back"):
        d1, t1 = rasterize_depth(view, V, F, cull)
        d0, t0 = rasterize_depth(view, V, F, cull, tri=False)
        assert t0 is None and t1.shape == (H, W)
        if cull == "none":  # the quads cover every pixel, the small faces win many
            assert np.isfinite(d1).all() and (t1 >= 2).sum() > W * H // 4
        np.testing.assert_array_equal(d0, d1)


@pytest.mark.parametrize("ortho", [True, False])
def test_depth_only_tile_drawn_by_one_piece_is_the_same_depth(ortho):
    """A depths-only tile that one piece alone draws (``_sole_cover``: the other pieces binned to it
    cover none of its pixel centres) takes its depths straight from that piece's plane
    (``_depth_one_piece``): the same bits as the full depth pass of ``rasterize_depth(tri=True)``.
    A tilted quad larger than the image (its two triangles binned to every tile by their boxes, the
    diagonal crossing some tiles), small triangles in front of it in one corner, the image's partial
    last row and column of tiles; perspective and orthographic; the far plane cutting the quad."""
    rng = np.random.default_rng(11)
    W, H, n = 99, 77, 60
    quad = np.array([[[-5, -4], [W + 6, -3], [W + 4, H + 5]], [[-5, -4], [W + 4, H + 5], [-6, H + 3]]], float)
    zq = np.array([[1.1, 1.9, 2.9], [1.1, 2.9, 2.2]])  # tilted: every pixel's depth its own
    c = rng.uniform(0, 40, size=(n, 1, 2))
    xy = np.concatenate([quad, c + rng.uniform(-3.0, 3.0, size=(n, 3, 2))]).reshape(-1, 2)
    z = np.concatenate([zq, rng.uniform(0.7, 1.05, size=(n, 3))]).reshape(-1)
    V, view, F = _screen_scene(xy, z, W, H, ortho, 0.5, 2.6)  # far 2.6: the quad's far corner beyond it
    for cull in ("none", "back"):
        d1, _t1 = rasterize_depth(view, V, F, cull)
        d0, _t0 = rasterize_depth(view, V, F, cull, tri=False)
        np.testing.assert_array_equal(d0, d1)
        if cull == "none":
            assert np.isfinite(d1[:, :32]).all() and np.isinf(d1).any()  # the quad, cut by the far plane
            assert len(np.unique(d1[48:64, 48:64])) > 200  # a tile's own depths (no constant)


@pytest.mark.parametrize("kind", ["grid", "axis", "sliver", "huge", "random"])
@pytest.mark.parametrize("ortho", [True, False])
def test_min_blend_texel_lists_equal_row_passes(kind, ortho, monkeypatch):
    """With a texel mask, the min-blend shades a tile with few texels from a list of them
    (``_texel_list``, ``_blend_list``: coverage by the per-pixel edge tests, culling bounds over the
    list) instead of row by row (spans). Both must give the same values and the same counts
    (fragments, kept, culled pieces), bit for bit: on the coverage test cases (edge functions
    exactly 0, axis-aligned edges, slivers, edge functions that may overflow), with pieces clipped
    by the near plane (perspective), both programs, masks from sparse (every tile on the lists) to
    dense (tiles over MIN_BLEND_LIST_MAX on the row passes), with and without the coarse culling."""
    from softshadows.raster import rasterize_min_blend
    from softshadows.raster import rasterizer as R
    from softshadows.raster.programs import PROGRAM_ATTRIBUTE, PROGRAM_PENUMBRA

    rng = np.random.default_rng(17 + len(kind))
    W, H, n = 83, 61, 300
    xy = _random_screen_triangles(rng, n, W, H, kind)
    z = rng.uniform(0.3, 3.0, size=len(xy))  # near = 0.5: some faces cross it (two pieces)
    V, view, F = _screen_scene(xy, z, W, H, ortho, 0.0, 10.0)
    za = rng.uniform(0.3, 2.5, size=(n, 3))
    za[: n // 2] = za[: n // 2, :1]  # constant attributes (cones): the coarse value test applies
    zp = rng.uniform(0.5, 3.5, size=(H, W)).astype(np.float32)
    zp[rng.random((H, W)) < 0.1] = np.inf
    start = rng.uniform(0.2, 1.0, size=(H, W)).astype(np.float32)
    runs = 0
    for density in (0.03, 0.2, 0.8):
        mask = rng.random((H, W)) < density
        mask[16:32, 16:48] = density > 0.5  # whole tiles empty, or full (256 texels: row passes)
        for prog, params in ((PROGRAM_PENUMBRA, np.array([0.5, 0.01, 1.0])), (PROGRAM_ATTRIBUTE, np.zeros(1))):
            for cd in (False, True):
                res = []
                for lmax in (-1, 248):
                    monkeypatch.setattr(R, "MIN_BLEND_LIST_MAX", lmax)
                    o = start.copy()
                    st = rasterize_min_blend(
                        view, V, F, prog, za, zp, params, o, split=n // 3, cull_discarded=cd, mask=mask
                    )
                    res.append((o, st))
                np.testing.assert_array_equal(res[0][0], res[1][0])
                assert res[0][1] == res[1][1]
                runs += (res[0][0] != start).sum() > 0
    assert runs >= 10  # the passes do change texels (not a comparison of two untouched images)


def test_tile_row_bits_words_equal_bytes():
    """The texel mask's row bits per tile, read 8 texels a word (``_byte_bits``: any nonzero byte,
    not only 1; ``_bytes_at``: words straddled where a row does not start on a word) and texel by
    texel, against a loop over the texels; widths that are and are not multiples of 8 and of the
    tile, mask sizes that are not a multiple of 8 bytes (the last texels read one by one)."""
    from softshadows.raster import rasterizer as R

    rng = np.random.default_rng(3)
    for H, W in ((37, 40), (50, 64), (33, 77), (16, 8)):
        m = ((rng.random((H, W)) < 0.3) * rng.integers(1, 256, (H, W))).astype(np.uint8)
        ntx, nty = (W + R.TILE - 1) // R.TILE, (H + R.TILE - 1) // R.TILE
        ref = np.zeros((ntx * nty, R.TILE), np.int64)
        for i, j in zip(*np.nonzero(m)):
            ref[(i // R.TILE) * ntx + j // R.TILE, i % R.TILE] |= 1 << (j % R.TILE)
        for words in (m.reshape(-1)[: m.size // 8 * 8].view(np.uint64), R._E1U64):
            bits = np.empty_like(ref)
            anyt = np.empty(ntx * nty, np.uint8)
            R._tile_row_bits(m, words, R.TILE, ntx, nty, bits, anyt)
            np.testing.assert_array_equal(bits, ref)
            np.testing.assert_array_equal(anyt, (ref != 0).any(axis=1))


@pytest.mark.parametrize("ortho", [True, False])
def test_coarse_depth_test_bound_is_below_every_fragment_depth(ortho):
    """The depth pass skips a piece whose depth floor (``_piece_depth_floor``) is at or beyond the
    tile's farthest stored depth: exact only if that floor is at or below every depth the pass
    computes for the piece (after the clamp) at the pixel centers of its rectangle in the tile.
    Checked with the pass's own operations (numpy float64, no fused multiply-add) on random
    triangles, many of them steep (nearly edge-on) or crossing the near plane; the floor must be
    attained (equal to the smallest depth) for most pieces, or the test would skip little."""
    from softshadows._jit import py_callable
    from softshadows.raster import rasterizer as R

    view_window, tile_rect, piece_rect, depth_bounds, plane, depth_floor = (
        py_callable(f)
        for f in (R._view_window, R._tile_rect, R._piece_rect, R._depth_bounds, R._plane, R._piece_depth_floor)
    )

    rng = np.random.default_rng(11)
    W, H, n = 96, 64, 400
    xy = rng.uniform(-10, W + 10, size=(n, 3, 2))
    z = rng.uniform(0.6, 4.0, size=(n, 3))
    z[: n // 4] = rng.uniform(0.6, 0.65, size=(n // 4, 1)) * np.array([1.0, 1.0, 30.0])  # steep planes
    z[n // 4 : n // 3, 0] = 0.2  # one corner behind near: clipped pieces
    xy, z = xy.reshape(-1, 2), z.reshape(-1)
    V, view, F = _screen_scene(xy, z, W, H, ortho, 0.5, 50.0)
    vp, W_, H_, verts, fcs, code, near = R._prepare(view, V, F, "none")
    fe = R._front_end(vp, W_, H_, verts, fcs, code, near)
    vw = view_window(vp)
    _W, _H, vortho, _far, wl, wt, wsx, wsy = vw
    assert vortho == ortho
    checked = exact = 0
    for tile in range(fe.ntx * fe.nty):
        rect = tile_rect(tile // fe.ntx, tile % fe.ntx, fe.tile, W_, H_)
        for ct in fe.bins[fe.start[tile] : fe.start[tile + 1]]:
            i0, i1, j0, j1 = piece_rect(fe.box, ct, rect)
            if i0 > i1 or j0 > j1:
                continue
            zlo, zhi = depth_bounds(fe.zinfo, ct, ortho, near)
            pl = plane(fe.planes, ct >> fe.shift)
            floor = depth_floor(ortho, pl, (i0, i1, j0, j1), vw, zlo, zhi)
            pnx, pny, pnz, pd = pl
            i, j = np.mgrid[i0 : i1 + 1, j0 : j1 + 1]
            xw = wl + (j + 0.5) * wsx
            yw = wt - (i + 0.5) * wsy
            with np.errstate(divide="ignore", invalid="ignore"):  # _row_depth, then _frag_depth
                zf = (pd - pny * yw - pnx * xw) / pnz if ortho else pd / (pnx * xw + (pny * yw + pnz))
            zf = np.where(zf >= zlo, zf, zlo)
            zf = np.where(zf > zhi, zhi, zf)
            assert floor <= zf.min(), (ct, floor, zf.min())
            checked += 1
            exact += floor == zf.min()
    assert checked > 300
    assert exact > 0.9 * checked
