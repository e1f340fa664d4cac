"""Tests of ``occlusion-textures`` (Eisemann & Décoret 2006) against closed forms, brute force and
ground truth.

Closed form used for the ``square`` scene (computed here, independently of the library): a point p
below a horizontal rectangular occluder and a parallel rectangular light sees the occluder project
through p onto the light's plane as an axis-aligned rectangle, and
    V(p) = 1 - area(projection of the occluder through p onto the light plane  n  light) / area(light),
separable in the two axes; V = 1 for points not below the occluder.
"""

from __future__ import annotations

import numpy as np
import pytest

import softshadows as ss
from softshadows.errors import SoftShadowsError
from softshadows.methods import occlusion_textures as ot
from softshadows.scene.builtin import BUILTIN
from softshadows.scene.types import Camera, Mesh, RectLight, Scene

RES = 96  # eye image size of the scene tests (small: 2 shared cores)
GT_SAMPLES = 256  # ground-truth noise: std <= 0.5/16 = 0.03 per pixel, ~0.001 on a mean over thousands


# ---- closed form ---------------------------------------------------------------------------------
def closed_form_v(p, scene):
    """V at points p (K,3) of a scene with one horizontal rectangular occluder and a horizontal
    rectangle light facing down (the ``square`` scene), from the scene's own geometry."""
    occ = [m for m in scene.meshes if m.role != "receiver"]
    assert len(occ) == 1
    ov = occ[0].vertices
    occ_y = float(ov[:, 1].mean())
    assert np.ptp(ov[:, 1]) < 1e-12, "occluder must be horizontal"
    lt = scene.light
    corners = lt.center + np.array([[-0.5, -0.5], [0.5, 0.5]]) @ np.stack([lt.u, lt.v])
    light_y = float(lt.center[1])
    p = np.asarray(p, float).reshape(-1, 3)
    below = p[:, 1] < occ_y - 1e-9
    k = np.where(below, (light_y - p[:, 1]) / np.where(below, occ_y - p[:, 1], 1.0), 1.0)
    cover = np.ones(len(p))
    for ax in (0, 2):
        olo, ohi = ov[:, ax].min(), ov[:, ax].max()
        llo, lhi = corners[:, ax].min(), corners[:, ax].max()
        lo = p[:, ax] + (olo - p[:, ax]) * k
        hi = p[:, ax] + (ohi - p[:, ax]) * k
        cover *= np.clip(np.minimum(hi, lhi) - np.maximum(lo, llo), 0.0, None)
    v = 1.0 - cover / lt.area
    return np.where(below, v, 1.0)


def square_errors(res, scene):
    """(MAE over pixels shadowed in either image, MAE over all surface pixels) against the closed form."""
    m = np.isfinite(res.visibility)
    v = res.visibility[m].astype(np.float64)
    vc = closed_form_v(res.position[m], scene)
    shadowed = (vc < 1 - 1e-3) | (v < 1 - 1e-3)
    e = np.abs(v - vc)
    return float(e[shadowed].mean()), float(e.mean())


@pytest.fixture(scope="module")
def square():
    return ss.load_scene("square")


@pytest.fixture(scope="module")
def square_results(square):
    return {f: ss.render(square, "occlusion-textures", RES, RES, filter=f) for f in ot.FILTERS}


# ---- the analytic case ---------------------------------------------------------------------------
def test_square_sat_matches_closed_form(square, square_results):
    # One planar occluder parallel to the light is the case the method is exact for (Sec. 3.1): its
    # slice texture is the occluder's characteristic function and SAT computes the box filter
    # exactly. What remains is texel discretization: a texel is ~0.011 world units on the occluder
    # plane (stats texel_size), i.e. the occluder's edges move by <= 1/2 texel, which shifts V by at
    # most ~0.011 * 2 (V falls from 1 to 0 over a 0.5-wide penumbra on the ground) -- 0.03 leaves room.
    res = square_results["sat"]
    mae_shadow, mae_all = square_errors(res, square)
    assert res.stats["slices_used"] == 1  # one planar occluder: one slice
    assert mae_shadow <= 0.03, mae_shadow
    assert mae_all <= 0.015, mae_all


def test_filter_error_ordering_on_square(square, square_results):
    # SAT is exact, N-Buffers interpolate between power-of-two boxes (small error), mipmaps filter
    # with dyadically aligned trilinear probes (blurry, blocky): the paper's Fig. 2 ranking.
    err = {f: square_errors(r, square)[0] for f, r in square_results.items()}
    assert err["sat"] <= err["nbuffers"] <= err["mipmap"], err
    assert err["mipmap"] > 2 * err["sat"], err  # the ranking is not a tie


def test_square_occluder_top_is_lit(square, square_results):
    # Points on the occluder itself are in the slice that contains them: that slice is skipped
    # (self-shadowing, Sec. 3.4), so the occluder's lit top face has V = 1, as in the closed form.
    res = square_results["nbuffers"]
    top = np.isfinite(res.visibility) & (np.abs(res.position[..., 1] - 1.0) < 1e-6)
    assert top.sum() > 50
    assert np.all(res.visibility[top] > 0.999)


# ---- building blocks: slicing, prefilters, kernel (against brute force) --------------------------
def test_slicing_view_contains_scene_and_is_fitted_to_light(square):
    flat = square.flat
    occ = flat.vertices[np.unique(flat.faces[flat.occluder])]
    pts = np.array([[3.9, 0.0, 3.9], [-3.9, 0.0, 2.0], [0.3, 0.0, -3.0]])  # far ground points to shade
    setup = ot.fit_slicing_view(square.light, occ, pts, 256, 16)
    sx, sy, _ = setup.view.project(np.concatenate([occ, pts]))
    assert np.all((sx >= 0) & (sx <= 256) & (sy >= 0) & (sy <= 256))  # the frustum contains the scene
    # fitted to the light: its corners project onto the corners of the texture (Fig. 5)
    lt = square.light
    corners = lt.center + np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]) @ np.stack([lt.u, lt.v])
    cx, cy, depth = setup.view.project(corners)
    assert np.allclose(sorted(set(np.round(cx, 6))), [0, 256]) and np.allclose(sorted(set(np.round(cy, 6))), [0, 256])
    assert np.allclose(depth, setup.d)  # the COP is d behind the light plane
    # the COP distance is (2% below) the largest that still contains the points
    farther = ot.fit_slicing_view(square.light, occ, pts, 256, 16, cop_distance=setup.d / 0.98 * 1.05)
    sx, sy, _ = farther.view.project(pts)
    assert not np.all((sx >= 0) & (sx <= 256) & (sy >= 0) & (sy <= 256))


def test_slice_scene_and_leak_fix(square):
    flat = square.flat
    occ_faces = flat.faces[flat.occluder]
    occ = flat.vertices[np.unique(occ_faces)]
    setup = ot.fit_slicing_view(square.light, occ, occ, 128, 8)
    tex, nfrag = ot.slice_scene(setup, flat.vertices, occ_faces)
    used = np.flatnonzero(tex.reshape(8, -1).any(1))
    assert len(used) == 1 and nfrag > 0
    k = used[0]
    # the marked texels are the occluder's projection: the centres of marked texels unproject onto
    # the occluder plane inside the square
    i, j = np.nonzero(tex[k])
    w = setup.view.unproject(j + 0.5, i + 0.5, np.full(len(i), setup.d + 2.0))
    assert np.all(np.abs(w[:, [0, 2]]) <= 0.5 + 1e-9)
    assert abs(len(i) - 1.0 / setup.view.pixel_size_at(setup.d + 2.0) ** 2) < 0.05 * len(i)  # area
    if k + 1 < 8:
        tex2, _ = ot.slice_scene(setup, flat.vertices, occ_faces, leak_fix=True)
        assert np.array_equal(tex2[k + 1], tex[k]) and np.array_equal(tex2[k], tex[k])  # Fig. 6


def test_slice_scene_bounds_and_sparse_nbuffers(square):
    # slice_scene's bounds are occupied_bounds of its textures (leak fix too), and the N-Buffers
    # of a mostly empty texture (rows skipped outside the set texels' rows) match brute force
    flat = square.flat
    occ_faces = flat.faces[flat.occluder]
    occ = flat.vertices[np.unique(occ_faces)]
    setup = ot.fit_slicing_view(square.light, occ, occ, 64, 8)
    for leak in (False, True):
        b = np.empty((8, 4))
        tex, _ = ot.slice_scene(setup, flat.vertices, occ_faces, leak, b)
        np.testing.assert_array_equal(b, ot.occupied_bounds(tex))
    tex = np.zeros((3, 32, 32), np.uint8)
    tex[0, 12:15, 20:26] = 1
    tex[1, 31, 0] = 1
    nb = ot.prefilter_nbuffers(tex)
    pad = np.zeros((3, 96, 96))
    pad[:, :32, :32] = tex
    for lv in range(6):
        s = 1 << lv
        want = np.array(
            [[[pad[k, i : i + s, j : j + s].mean() for j in range(32)] for i in range(32)] for k in range(3)]
        )
        np.testing.assert_allclose(nb[:, lv], want, atol=1e-7)


def test_prefilters_against_brute_force():
    rng = np.random.default_rng(3)
    tex = (rng.random((2, 32, 32)) < 0.3).astype(np.uint8)
    # N-Buffers: level l = mean over the 2^l x 2^l box starting at the texel (zero outside)
    nb = ot.prefilter_nbuffers(tex)
    assert nb.shape == (2, 6, 32, 32)
    pad = np.zeros((2, 96, 96))
    pad[:, :32, :32] = tex
    for lv in range(6):
        s = 1 << lv
        for i, j in [(0, 0), (5, 17), (31, 31), (20, 3)]:
            assert np.isclose(nb[1, lv, i, j], pad[1, i : i + s, j : j + s].mean(), atol=1e-6)
    # mipmap pyramid: dyadic 2x2 averages
    pyr, offs, _sizes = ot.prefilter_mipmap(tex)
    lv2 = pyr[0, offs[2] : offs[2] + 64].reshape(8, 8)
    assert np.allclose(lv2, tex[0].reshape(8, 4, 8, 4).mean(axis=(1, 3)))
    # SAT: exact box filter over any real rectangle (integral of the piecewise-constant texture)
    sat = ot.prefilter_sat(tex)
    fine = np.repeat(np.repeat(tex[1].astype(float), 8, 0), 8, 1)  # 1/8-texel grid
    for x0, x1, y0, y1 in [(2.0, 9.0, 3.0, 11.0), (0.5, 30.25, 4.125, 6.875), (-3.0, 5.5, 29.0, 40.0)]:
        got = ot.lookup_sat(sat, 1, x0, x1, y0, y1)
        a = [int(round(c * 8)) for c in (x0, x1, y0, y1)]
        cl = [min(max(c, 0), 256) for c in a]
        want = fine[cl[2] : cl[3], cl[0] : cl[1]].sum() / ((a[1] - a[0]) * (a[3] - a[2]))
        assert np.isclose(got, want, atol=1e-9), (got, want)
    # N-Buffer lookup of an exact power-of-two box equals the box mean
    assert np.isclose(ot.lookup_nbuffers(nb, 0, 16, 4.0, 12.0, 8.0, 16.0), tex[0, 8:16, 4:12].mean(), atol=1e-6)


def test_kernel_rect_is_the_light_seen_from_p_on_the_slice_plane(square):
    # Eq. 4 in texture coordinates: project the light's corners through P onto the plane z = zs and
    # map them with the slicing view; kernel_rect must give the same rectangle.
    flat = square.flat
    occ = flat.vertices[np.unique(flat.faces[flat.occluder])]
    setup = ot.fit_slicing_view(square.light, occ, occ, 256, 4)
    lt = square.light
    corners = lt.center + np.array([[-0.5, -0.5], [0.5, 0.5]]) @ np.stack([lt.u, lt.v])
    sp = setup.params()
    for P in ([0.3, 0.0, -0.2], [-0.9, 0.4, 0.6]):
        P = np.array(P)
        zs = 1.7  # light-frame depth of the plane (y = 1.3)
        ys = lt.center[1] - zs
        t = (P[1] - ys) / (P[1] - corners[:, 1])
        q = P + (corners - P) * t[:, None]
        sx, sy, _ = setup.view.project(q)
        q_light = ot.to_light_frame(P[None], setup.frame)[0]
        x0, x1, y0, y1 = ot.kernel_rect(q_light[0], q_light[1], q_light[2], zs, sp)
        assert np.allclose([x0, x1], sorted(sx)) and np.allclose([y0, y1], sorted(sy))


# ---- combination and leaks against ground truth --------------------------------------------------
@pytest.fixture(scope="module")
def spheres_gt():
    sc = ss.load_scene("spheres")
    return sc, ss.render(sc, "ground-truth", RES, RES, samples=GT_SAMPLES).visibility


def test_spheres_product_beats_max_and_sum(spheres_gt):
    # Overlapping occluders (Sec. 3.3): the probabilistic product (Eq. 5) lies between max (too
    # bright) and the clamped sum (too dark) and is closer to the truth than both.
    sc, gt = spheres_gt
    err = {}
    for c in ot.COMBINES:
        v = ss.render(sc, "occlusion-textures", RES, RES, combine=c).visibility
        m = np.isfinite(gt)
        err[c] = float(np.abs(v - gt)[m].mean())
    assert err["product"] < err["max"] and err["product"] < err["sum"], err
    mean = {
        c: float(np.nanmean(ss.render(sc, "occlusion-textures", RES, RES, combine=c).visibility))
        for c in ("max", "sum")
    }
    assert mean["max"] > mean["sum"]  # max brighter than sum, as the paper argues


def test_fence_leak_fix_reduces_leaks():
    # Light leaks = the method brighter than the truth inside the shadow of the thin bars, on the
    # ground. With 8 slices each bar layer falls in one slice, and the bars' sides let light slip
    # between the texel footprints; marking the next slice too (Fig. 6) closes them.
    sc = ss.load_scene("fence")
    g = ss.render(sc, "ground-truth", RES, RES, samples=GT_SAMPLES)
    ground = np.isfinite(g.visibility) & (np.abs(g.position[..., 1]) < 1e-6)
    shadow = ground & (g.visibility < 1 - 1e-3)
    leak = {}
    for fix in (False, True):
        v = ss.render(sc, "occlusion-textures", RES, RES, slices=8, leak_fix=fix).visibility
        leak[fix] = float(np.clip(v - g.visibility, 0, None)[shadow].mean())
    assert leak[False] > 0.01, leak  # there is a leak to fix (GT noise ~0.001 on this mean)
    assert leak[True] < 0.5 * leak[False], leak


# ---- self-shadowing: no seam across slice planes -------------------------------------------------
def _quad(x0, x1, z0, z1, y0, slope):
    v = np.array([[x0, 0, z0], [x1, 0, z0], [x1, 0, z1], [x0, 0, z1]], float)
    v[:, 1] = y0 + slope * v[:, 2]
    return v, np.array([[0, 2, 1], [0, 3, 2]])


@pytest.fixture(scope="module")
def ramp_scene():
    """A tilted ramp (role both, crosses ~10 slice planes) under a parallel roof plate covering
    x < 0 at a gap of about half a slice; light 1 x 1 at y = 3 facing down."""
    ramp = Mesh(*_quad(-1.5, 1.5, -1.5, 1.5, 0.5, 0.3), role="both", name="ramp")
    roof = Mesh(*_quad(-1.5, 0.0, -1.5, 1.5, 0.53, 0.3), role="occluder", name="roof")
    light = RectLight((0, 3, 0), (1, 0, 0), (0, 0, 1))
    return Scene([ramp, roof], light, Camera((0, 4, 4), (0, 0.5, 0)), "ramp")


def _ramp_line(x):
    z = np.arange(-1.2, 1.2, 5e-4)
    return np.stack([np.full_like(z, x), 0.5 + 0.3 * z, z], 1)


def test_no_seam_across_slice_planes(ramp_scene):
    # Dense points (0.5 mm apart) along the ramp cross every slice plane. With the paper's fade V is
    # continuous: consecutive values differ by little (the kernel moves by a fraction of a texel). The
    # hard skip of the containing slice (self_shadow="skip") makes V jump at the planes: the roof
    # part in the slice just above P switches from ignored to fully counted -- the test detects seams.
    sc = ramp_scene
    for x in (-0.75, 0.75):  # under the roof; in the open (ramp alone)
        pts = _ramp_line(x)
        v, st = ot.occlusion_visibility(sc.light, sc.flat, pts, filter="sat", self_shadow="fade")
        assert st["slices_used"] >= 10
        assert np.all(np.isfinite(v)) and np.abs(np.diff(v)).max() < 0.05, np.abs(np.diff(v)).max()
    v_skip, _ = ot.occlusion_visibility(sc.light, sc.flat, _ramp_line(-0.75), filter="sat", self_shadow="skip")
    assert np.abs(np.diff(v_skip)).max() > 0.5


def test_float32_points_with_nan_rows(ramp_scene):
    # The method passes the eye G-buffer's float32 positions (NaN where no surface) as they are:
    # the same V as the float64 points (float32 converts exactly), V = 1 on the NaN rows, which
    # stay out of the frustum fit.
    sc = ramp_scene
    p32 = _ramp_line(-0.75)[::40].astype(np.float32)
    v64, st64 = ot.occlusion_visibility(sc.light, sc.flat, p32.astype(np.float64))
    withnan = np.full((2 * len(p32), 3), np.nan, np.float32)
    withnan[::2] = p32
    v32, st32 = ot.occlusion_visibility(sc.light, sc.flat, withnan)
    np.testing.assert_array_equal(v32[::2], v64)
    assert np.all(v32[1::2] == 1.0) and v64.min() < 0.9
    assert st32["cop_distance"] == st64["cop_distance"]


def test_containing_slice_is_not_used(ramp_scene):
    # A lit planar surface does not shadow itself. Fading the containing slice out keeps the open
    # part of the ramp lit; using it (self_shadow="include", Fig. 7) shadows it by its own projection.
    sc = ramp_scene
    pts = _ramp_line(0.75)
    v_fade, _ = ot.occlusion_visibility(sc.light, sc.flat, pts, filter="sat")
    v_incl, _ = ot.occlusion_visibility(sc.light, sc.flat, pts, filter="sat", self_shadow="include")
    assert v_fade.min() > 0.95 and v_fade.mean() > 0.99
    assert v_incl.mean() < 0.5


# ---- robustness ---------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(BUILTIN))
def test_phases_and_stats_on_builtins(name):
    # (V finite and in [0,1] on every scene and variant: tests/test_api.py, for every method)
    sc = ss.load_scene(name)
    for kw in (
        {},
        {"filter": "mipmap", "combine": "sum", "leak_fix": True, "texture_size": 64, "slices": 4},
        {"filter": "sat", "combine": "max", "self_shadow": "include"},
    ):
        r = ss.render(sc, "occlusion-textures", 40, 40, **kw)
        assert {"slicing", "prefilter", "eye_pass"} <= set(r.timings)
        assert r.stats["slices_used"] >= 1 and f"prefilter_s_{r.params['filter']}" in r.stats


def test_sphere_light_through_equal_area_square():
    sc = ss.load_scene("spheres", light="sphere")
    r = ss.render(sc, "occlusion-textures", 40, 40)
    assert r.stats["light_approximation"] == "sphere as equal-area square"
    v = r.visibility[np.isfinite(r.visibility)]
    assert v.min() < 0.2 and v.max() == pytest.approx(1.0)


@pytest.mark.parametrize(
    "params",
    [
        {"filter": "box"},
        {"combine": "mean"},
        {"texture_size": 300},
        {"slices": 0},
        {"cop_distance": -1.0},
        {"self_shadow": "off"},
    ],
)
def test_bad_parameters_raise(square, params):
    with pytest.raises(SoftShadowsError):
        ss.render(square, "occlusion-textures", 16, 16, **params)


def test_non_rectangular_light_raises(square):
    sc = square.with_light(RectLight((0, 3, 0), (1, 0, 0), (0.5, 0, 1)))
    with pytest.raises(SoftShadowsError, match="orthogonal"):
        ss.render(sc, "occlusion-textures", 16, 16)
