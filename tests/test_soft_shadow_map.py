"""Tests of ``soft-shadow-map`` (Atty et al. 2006) against closed forms and ground truth.

The analytic reference used throughout: a rectangle light and a rectangular occluder in parallel
planes, both axis-aligned. Seen from a receiver point p, the occluder projects through p onto the
light's plane as an axis-aligned rectangle, and
    V(p) = 1 - area(projection of the occluder through p onto the light plane  n  light) / area(light),
separable in the two axes. It is computed here, independently of the library.
"""

from __future__ import annotations

import inspect

import numpy as np
import pytest

import softshadows as ss
from softshadows._jit import py_callable
from softshadows.errors import SoftShadowsError
from softshadows.methods import soft_shadow_map as ssm
from softshadows.scene.types import Mesh, RectLight, Scene

OCC_Y, OCC_HALF, LIGHT_Y = 1.0, 0.5, 3.0  # the built-in ``square`` scene (documented in scene/builtin.py)


def closed_form_v(
    p, occ_half=(OCC_HALF, OCC_HALF), occ_y=OCC_Y, light_half=(0.5, 0.5), light_y=LIGHT_Y, light_center=(0.0, 0.0)
):
    """V at points p (K,3) below a horizontal occluder [-ox, ox] x [-oz, oz] at height occ_y, for a
    horizontal light of half sizes (lx, lz) at height light_y centered at (cx, cz)."""
    p = np.asarray(p, float)
    k = (light_y - p[:, 1]) / (occ_y - p[:, 1])  # projection scale from p onto the light plane
    cover = np.ones(len(p))
    for ax, oh, lh, c in (
        (0, occ_half[0], light_half[0], light_center[0]),
        (2, occ_half[1], light_half[1], light_center[1]),
    ):
        lo = p[:, ax] + (-oh - p[:, ax]) * k
        hi = p[:, ax] + (oh - p[:, ax]) * k
        cover *= np.clip(np.minimum(hi, c + lh) - np.maximum(lo, c - lh), 0.0, None)
    return 1.0 - cover / (4 * light_half[0] * light_half[1])


def ground_error(res, **cf):
    """Mean |V - V_closed| over ground pixels that are shadowed in either image."""
    pos = res.position.reshape(-1, 3)
    v = res.visibility.ravel()
    g = np.isfinite(v) & (np.abs(pos[:, 1]) < 1e-5)
    vc = closed_form_v(pos[g], **cf)
    sh = (vc < 1 - 1e-3) | (v[g] < 1 - 1e-3)
    assert sh.sum() > 200, "the test view must contain the shadow"
    return float(np.abs(v[g] - vc)[sh].mean())


# ---- building blocks ---------------------------------------------------------------------------
def test_round_half_is_ieee_binary16():
    """round_half must give exactly np.float16's value (ties to even, subnormals, overflow)."""
    rng = np.random.default_rng(1)
    x = np.concatenate(
        [
            rng.uniform(-2, 2, 4000),
            10.0 ** rng.uniform(-9, 5.5, 4000),
            np.array(
                [
                    1 + 2.0**-11,
                    1 + 3 * 2.0**-11,
                    2048 + 1,
                    0.5 + 1 / 2049,
                    65504,
                    65519,
                    65520,
                    2.0**-24,
                    2.0**-25,
                    3 * 2.0**-26,
                    6e-8,
                    0.0,
                ]
            ),
        ]
    )
    got = np.array([py_callable(ssm.round_half)(float(v)) for v in x])
    with np.errstate(over="ignore"):
        ref = x.astype(np.float16).astype(np.float64)
    np.testing.assert_array_equal(got, ref)
    # the paper's examples (Appendix A): 2048 + 1 = 2048 and 0.5 + 1/2049 = 0.5 in FP16; the second
    # holds only with truncation (round-to-nearest gives 0.5 + 2^-11), the "float16-rtz" mode
    assert (
        py_callable(ssm.round_half)(2048.0 + 1.0) == 2048.0
        and py_callable(ssm.round_half)(0.5 + 1 / 2049) == 0.5 + 2.0**-11
    )
    assert (
        py_callable(ssm.round_half)(2048.0 + 1.0, True) == 2048.0
        and py_callable(ssm.round_half)(0.5 + 1 / 2049, True) == 0.5
    )
    # truncation: never grows, and stays within one ulp (2^-10 relative, 2^-24 absolute) of nearest
    fin = np.abs(x) < 65504
    y = np.array([py_callable(ssm.round_half)(float(v), True) for v in x[fin]])
    assert np.all(np.abs(y) <= np.abs(x[fin]))
    assert np.all(np.abs(y - ref[fin]) <= np.abs(ref[fin]) * 2.0**-10 + 2.0**-24)


def test_occlusion_percentage_of_whole_square_is_closed_form():
    """One micro-patch that *is* the square occluder gives the closed form exactly (Sec. 4.2).
    Light frame of the square scene: right = +x, up = +z, depth = 3 - y."""
    rng = np.random.default_rng(2)
    p = np.c_[rng.uniform(-1.2, 1.2, 500), np.zeros(500), rng.uniform(-1.2, 1.2, 500)]
    zr = LIGHT_Y - p[:, 1]
    patch = (-0.5, 0.5, -0.5, 0.5, LIGHT_Y - OCC_Y)
    got = np.array(
        [ssm.occlusion_percentage_at(patch, x / z, y / z, z, 0.5, 0.5) for x, y, z in zip(p[:, 0], p[:, 2], zr)]
    )
    np.testing.assert_allclose(1 - got, closed_form_v(p), atol=1e-12)


def test_penumbra_extent_contains_every_occluded_texel():
    """Sec. 3.3: outside its extent a micro-patch occludes nothing, and the extent is not loose:
    every texel inside it (receivers on the virtual plane) is occluded. Brute force over the SSM."""
    from softshadows.raster import View

    sv = View.frame((0, 0, 0), (0, 0, 1), (0, 1, 0), (-0.6, 0.6, -0.4, 0.4), 0.1, 10.0, 90, 60)
    hx, hy, z_plane = 0.3, 0.2, 3.0
    rng = np.random.default_rng(3)
    c = rng.uniform(-0.3, 0.3, (20, 2))
    z = rng.uniform(0.8, 2.8, 20)
    size = rng.uniform(0.002, 0.05, 20)
    patches = np.c_[
        c[:, 0] * z - size * z, c[:, 0] * z + size * z, c[:, 1] * z - size * z / 1.5, c[:, 1] * z + size * z / 1.5, z
    ]
    ext = ssm.penumbra_extents(patches, hx, hy, z_plane, sv.params())
    jj, ii = np.meshgrid(np.arange(90), np.arange(60))
    ux = -0.6 + (jj + 0.5) * 1.2 / 90
    uy = 0.4 - (ii + 0.5) * 0.8 / 60
    for p, (i0, i1, j0, j1) in zip(patches, ext):
        occ = np.array([ssm.occlusion_percentage_at(p, a, b, z_plane, hx, hy) for a, b in zip(ux.ravel(), uy.ravel())])
        occ = occ.reshape(60, 90)
        inside = (ii >= i0) & (ii <= i1) & (jj >= j0) & (jj <= j1)
        assert occ[~inside].max(initial=0.0) == 0.0
        assert inside.sum() == 0 or occ[inside].min() > 0.0


def test_views_are_axis_aligned_with_the_light_and_of_its_aspect_ratio():
    sc = ss.load_scene("square").with_light(RectLight((0, 3, 0), (0, 0, 1.2), (-0.4, 0, 0)))
    ov, sv = ssm.compute_map_views(sc, 64, 32)
    for v in (ov, sv):
        l, r, b, t = v.window
        assert (r - l) / (t - b) == pytest.approx(1.2 / 0.4)
        np.testing.assert_allclose(v.right, [0, 0, 1], atol=1e-12)
        np.testing.assert_allclose(v.forward, [0, -1, 0], atol=1e-12)
        np.testing.assert_allclose(v.origin, [0, 3, 0])


# ---- the method against the closed form --------------------------------------------------------
def test_square_matches_closed_form_at_256():
    """Planar occluder parallel to the light: micro-patch back-projections tile the projected
    square exactly (no overlap/gap, Sec. 5.1.2), so the only errors are the occluder map's
    discretization (at most half a pixel per edge, ~0.002 in light units x 3 after projection)
    and the SSM's bilinear reconstruction of a piecewise-bilinear V (a 256^2 SSM over the
    penumbra): both well below 0.02, the issue's bound (measured ~0.002)."""
    sc = ss.load_scene("square")
    res = ss.render(sc, "soft-shadow-map", 96, 96, map_size=256, ssm_size=256)
    assert ground_error(res) <= 0.02
    assert res.stats["micro_patches"] > 0.8 * 256 * 256  # the map is fitted to the square


def test_rectangular_rotated_light_matches_closed_form():
    """Non-square light with u along z: maps of the light's aspect ratio and orientation."""
    base = ss.load_scene("square")
    light = RectLight((0.1, 3.0, 0.0), (0.0, 0.0, 0.5), (-1.0, 0.0, 0.0))  # u x v = -y
    sc = base.with_light(light)
    res = ss.render(sc, "soft-shadow-map", 96, 96, map_size=200, ssm_size=200)
    assert ground_error(res, light_half=(0.5, 0.25), light_center=(0.1, 0.0)) <= 0.02


def test_float16_accumulation_fails_at_high_resolution_float32_does_not():
    """Appendix A / Fig. 14: with FP16 blending a sum near 1 ignores additions below 2^-11, and
    each micro-patch of a 512^2 map hides ~(3/512)^2 ~ 3e-5 of the light here, so the shadow
    stays far too light; at 128^2 (~5e-4 per patch) it is only slightly off. float32 must not
    show this trend. Errors are measured in SSM space (the paper's metric) vs the closed form."""
    sc = ss.load_scene("square")

    def err(n, acc):
        s = ssm.compute_soft_shadow_map(sc, n, 40, accumulate=acc)
        H, W = s.occlusion.shape
        jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
        ok = np.isfinite(s.receiver_depth)
        p = s.view.unproject(jj[ok], ii[ok], s.receiver_depth[ok])
        vc, v = closed_form_v(p), 1 - s.occlusion[ok]
        sh = (vc < 1 - 1e-3) | (v < 1 - 1e-3)
        return float(np.abs(v - vc)[sh].mean())

    e16_128, e16_512 = err(128, "float16"), err(512, "float16")
    e32_128, e32_512 = err(128, "float32"), err(512, "float32")
    assert e16_512 > 2 * e16_128 and e16_512 > 0.1  # measured ~0.44 vs ~0.06
    assert e32_512 <= e32_128 + 1e-3  # float32 error does not grow with resolution
    assert e32_512 < 0.02


def test_two_pass_is_not_worse_on_thick_occluders():
    """Sec. 3.5: the back-face map adds the shadow of the occluders' far side. On thick occluders
    (spheres) the two-pass error vs ground truth must not exceed the one-pass error. Error over
    receiver (ground) pixels only: occluder pixels get V = 1 in both variants."""
    sc = ss.load_scene("spheres")
    gt = ss.render(sc, "ground-truth", 64, 64, samples=256)
    pos = gt.position.reshape(-1, 3)
    g = np.isfinite(gt.visibility.ravel()) & (np.abs(pos[:, 1]) < 1e-5)
    errs = []
    for two in (False, True):
        r = ss.render(sc, "soft-shadow-map", 64, 64, map_size=128, ssm_size=128, two_pass=two)
        errs.append(float(np.abs(r.visibility.ravel()[g] - gt.visibility.ravel()[g]).mean()))
        assert r.stats["micro_patches_" + ("back" if two else "nearest")] > 0
    assert errs[1] <= errs[0], errs


@pytest.mark.parametrize("light", ["rect", "sphere"])
@pytest.mark.parametrize("name", ["square", "spheres", "fence", "contact", "plant", "bunny"])
def test_roles_phases_and_stats_on_builtins(name, light):
    # (V finite and in [0,1] on every scene and variant: tests/test_api.py, for every method)
    sc = ss.load_scene(name, light=light)
    assert sc.has_roles
    for kw in ({}, {"two_pass": True, "accumulate": "float16", "map_size": 64}):
        r = ss.render(sc, "soft-shadow-map", 40, 32, ssm_size=64, **kw)
        assert r.stats["texels_touched"] > 0 and r.stats["micro_patches"] > 0
        for phase in ("occluder_map", "receiver_map", "soft_shadow_map", "eye_projection"):
            assert phase in r.timings


# ---- errors ------------------------------------------------------------------------------------
def test_rejects_no_roles_and_bad_params():
    sc = ss.load_scene("square")
    both = Scene([Mesh(m.vertices, m.faces, m.albedo, "both", m.name) for m in sc.meshes], sc.light, sc.camera, "x")
    with pytest.raises(SoftShadowsError, match="roles"):
        ss.render(both, "soft-shadow-map", 16, 16)
    with pytest.raises(SoftShadowsError, match="accumulate"):
        ss.render(sc, "soft-shadow-map", 16, 16, accumulate="float64")
    with pytest.raises(SoftShadowsError, match="map_size"):
        ss.render(sc, "soft-shadow-map", 16, 16, map_size=2)
    with pytest.raises(SoftShadowsError, match="ssm_size"):
        ss.render(sc, "soft-shadow-map", 16, 16, ssm_size=4)


@pytest.mark.parametrize(("light", "size"), [("rect", ssm.SSM_SIZE_RECT), ("sphere", ssm.SSM_SIZE_SPHERE)])
def test_default_ssm_size_depends_on_the_light(light, size):
    """``ssm_size=0`` (the default) is 256^2 with a rect light, 128^2 with a sphere light (the same
    error against ground truth on the built-in scenes: results page); the SSM made has that size."""
    sc = ss.load_scene("square", light=light)
    r = ss.render(sc, "soft-shadow-map", 24, 16, map_size=32)
    assert r.stats["ssm_size"] == size
    m = ssm.compute_soft_shadow_map(sc, 32)
    assert m.occlusion.shape == (size, size) and m.stats["ssm_size"] == size


@pytest.mark.parametrize(("light", "size"), [("rect", ssm.MAP_SIZE_RECT), ("sphere", ssm.MAP_SIZE_SPHERE)])
def test_default_map_size_depends_on_the_light(light, size):
    """``map_size=0`` (the default) is 256^2 with a rect light, 208^2 with a sphere light (the same
    error against ground truth on the built-in scenes: the method's page); the occluder map made
    has that size, and an explicit size is kept."""
    sc = ss.load_scene("square", light=light)
    r = ss.render(sc, "soft-shadow-map", 24, 16, ssm_size=32)
    assert r.stats["map_size"] == size
    m = ssm.compute_soft_shadow_map(sc, 0, 32)
    assert m.occluder_view.width == size and m.stats["map_size"] == size
    assert ssm.compute_soft_shadow_map(sc, 40, 32).occluder_view.width == 40


def test_mesh_of_role_both_does_not_shadow_itself():
    """A 'both' mesh next to proper roles: the square as both occluder and receiver must not be
    darkened by its own micro-patches (no self-shadowing), while the ground around it keeps its
    penumbra (the ground right under it is hidden from the light center by a receiver: a known
    limit, it reads the square's SSM value)."""
    sc = ss.load_scene("square")
    meshes = [sc.meshes[0], Mesh(sc.meshes[1].vertices, sc.meshes[1].faces, sc.meshes[1].albedo, "both", "sq")]
    sc2 = Scene(meshes, sc.light, sc.camera, "square-both")
    r = ss.render(sc2, "soft-shadow-map", 64, 64, map_size=128, ssm_size=128)
    pos = r.position.reshape(-1, 3)
    v = r.visibility.ravel()
    top = np.isfinite(v) & (np.abs(pos[:, 1] - OCC_Y) < 1e-5)
    # own micro-patches at the receiver's depth would give k = z_R/(z_R - z_O) -> inf, i.e. V ~ 0;
    # the only darkening allowed is the bilinear blend with the ground's texels at the border
    assert top.sum() > 20 and np.median(v[top]) == 1.0 and v[top].mean() > 0.97
    ground = np.isfinite(v) & (np.abs(pos[:, 1]) < 1e-5)
    assert (v[ground] < 0.8).sum() > 20


# ---- sphere light: micro-patches back-projected onto the facing disk ---------------------------
def _disk_cover_mc(poly2d, n=400_000, seed=0):
    """Monte Carlo area of (polygon n unit disk), independent of the library: uniform points in
    the unit disk, inside a convex polygon (counterclockwise or not) by edge signs."""
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.uniform(0, 1, n))
    a = rng.uniform(0, 2 * np.pi, n)
    x, y = r * np.cos(a), r * np.sin(a)
    signs = []
    for i in range(len(poly2d)):
        (ax, ay), (bx, by) = poly2d[i], poly2d[(i + 1) % len(poly2d)]
        signs.append((bx - ax) * (y - ay) - (by - ay) * (x - ax))
    signs = np.array(signs)
    inside = np.all(signs >= 0, axis=0) | np.all(signs <= 0, axis=0)
    return np.pi * inside.mean()


def test_polygon_disk_area_is_exact():
    from softshadows.analytic import circular_segment, polygon_disk_area

    def area(poly):
        poly = np.asarray(poly, float)
        return polygon_disk_area(poly[:, 0].copy(), poly[:, 1].copy(), len(poly), 1.0)

    big = [(-5, -5), (5, -5), (5, 5), (-5, 5)]
    assert area(big) == pytest.approx(np.pi, abs=1e-12)  # disk inside the polygon
    assert area(big[::-1]) == pytest.approx(np.pi, abs=1e-12)  # either orientation
    assert area([(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)]) == pytest.approx(1.0, abs=1e-12)
    assert area([(0.3, -9), (9, -9), (9, 9), (0.3, 9)]) == pytest.approx(float(circular_segment(0.3, 1.0)), abs=1e-12)
    assert area([(2, 2), (3, 2), (3, 3)]) == 0.0
    # random convex quadrilaterals straddling the circle against Monte Carlo (400k points: the
    # estimate's std is < sqrt(pi^2/4/4e5) ~ 2.5e-3; 1e-2 is 4 sigma)
    rng = np.random.default_rng(5)
    for k in range(6):
        c = rng.uniform(-1, 1, 2)
        ang = np.sort(rng.uniform(0, 2 * np.pi, 4))
        quad = c + rng.uniform(0.3, 1.2) * np.c_[np.cos(ang), np.sin(ang)]
        assert area(quad) == pytest.approx(_disk_cover_mc(quad, seed=k), abs=1e-2)


def test_quad_disk_area_small_matches_polygon_disk_area():
    """The branch-free small-quadrilateral overlap (series arctangents, used for patches across the
    circle) against the sector form: random small convex quads near the circle, both orientations;
    where it declines (ok False: a wide quad), it must be because a series argument is large."""
    from softshadows.analytic import polygon_disk_area, quad_disk_area_small

    rng = np.random.default_rng(11)
    n_ok = 0
    for k in range(400):
        ang0 = rng.uniform(0, 2 * np.pi)
        c = rng.uniform(0.9, 1.1) * np.array([np.cos(ang0), np.sin(ang0)])
        size = 0.2 if k % 50 == 0 else rng.uniform(0.002, 0.06)
        a = np.sort(rng.uniform(0, 2 * np.pi, 4))
        quad = c + size * np.c_[np.cos(a), np.sin(a)] * rng.uniform(0.5, 1.0, (4, 1))
        if k % 2:
            quad = quad[::-1]
        ref = polygon_disk_area(quad[:, 0].copy(), quad[:, 1].copy(), 4, 1.0)
        got, ok = py_callable(quad_disk_area_small)(*quad[:, 0], *quad[:, 1])
        if ok:
            n_ok += 1
            # both exact up to rounding: areas up to ~1e-2 computed from O(1) coordinates
            assert got == pytest.approx(ref, abs=1e-15)
    assert n_ok >= 380  # small quads take the fast form


def test_quad_disk_area_small32_matches_polygon_disk_area():
    """The float32 form of the small-quadrilateral overlap (the crossing pairs' batch) against the
    float64 sector form, on quads given in float32 (as the batch hands them over): it takes the
    same quads as the float64 form, and its error is a few float32 ulps of the O(size) terms
    (their sum cancels to the O(size^2) area): at most 16 ulps of the size, i.e. below 6e-8 for
    sizes up to 0.06, 2e-8 of the light after dividing by pi, far below the 1e-5 asked of V even
    summed over a texel's pairs."""
    from softshadows.analytic import polygon_disk_area, quad_disk_area_small, quad_disk_area_small32

    rng = np.random.default_rng(12)
    n_ok, worst = 0, 0.0
    for k in range(400):
        ang0 = rng.uniform(0, 2 * np.pi)
        c = rng.uniform(0.9, 1.1) * np.array([np.cos(ang0), np.sin(ang0)])
        size = 0.2 if k % 50 == 0 else rng.uniform(0.002, 0.06)
        a = np.sort(rng.uniform(0, 2 * np.pi, 4))
        quad = c + size * np.c_[np.cos(a), np.sin(a)] * rng.uniform(0.5, 1.0, (4, 1))
        quad = quad.astype(np.float32).astype(np.float64)  # the batch's float32 corners
        if k % 2:
            quad = quad[::-1]
        ref = polygon_disk_area(quad[:, 0].copy(), quad[:, 1].copy(), 4, 1.0)
        got, ok = py_callable(quad_disk_area_small32)(*quad[:, 0].astype(np.float32), *quad[:, 1].astype(np.float32))
        _, ok64 = py_callable(quad_disk_area_small)(*quad[:, 0], *quad[:, 1])
        assert isinstance(got, np.float32 | float)
        if ok:
            n_ok += 1
            worst = max(worst, abs(float(got) - ref) / size)
        if size < 0.1:
            assert ok == ok64
    assert n_ok >= 380
    assert worst <= 16 * 2.0**-24  # per unit of size: a few float32 ulps of each O(size) term


def test_sphere_accumulation_equals_per_pair_sum():
    """The sphere accumulation's shortcuts (row pass: cone test on corner heights, the inside area
    in closed form; crossing pairs in vectorized batches; narrowed extents) change nothing but
    float32 rounding: bunny at 24^2 maps against the plain sum, over every patch and texel, of the
    exact routine (``occlusion_percentage_disk``). Each texel sums up to ~500 terms of
    float32-rounded values (relative rounding 6e-8 each): 1e-5 is far above that and far below
    any term a shortcut could wrongly drop or add (a patch hides ~1e-3 of the light)."""
    sc = ss.load_scene("bunny", light="sphere")
    n = 24
    m = ssm.compute_soft_shadow_map(sc, n, n)
    ov, sv = ssm.compute_map_views(sc, n, n)
    rdepth, _ = ssm.compute_receiver_depth_map(sc, sv)
    od, om = ssm.compute_occluder_depth_map(sc, ov)
    patches, _ = ssm.discretize_occluders(od, om, ov.params())
    rd0 = np.where(np.isfinite(rdepth), rdepth, 0).astype(np.float32)
    F = ssm.disk_frames(rd0, sv.params(), sc.light.radius)
    sc8 = [np.empty(8) for _ in range(8)]
    ref = np.zeros((n, n))
    for i, j in zip(*np.nonzero(rd0 > 0)):
        for p in patches:
            if rd0[i, j] > p[4]:
                ref[i, j] += py_callable(ssm.occlusion_percentage_disk)(F, i, j, *p, *sc8)
    ref = np.clip(ref, 0, 1)
    assert ref.max() > 0.5  # the shadow is there
    assert np.abs(m.occlusion - ref).max() <= 1e-5


def test_refined_sphere_extents_contain_every_occluded_texel():
    """``refine_extents_sphere`` (local receiver depth, the facing disks' z range) keeps every texel
    a patch occludes, at receiver depths that vary over the map, and narrows the ranges."""
    from softshadows.raster import View

    sv = View.frame((0, 0, 0), (0, 0, 1), (0, 1, 0), (-0.6, 0.6, -0.4, 0.4), 0.1, 10.0, 90, 60)
    rho = 0.3
    jj, ii = np.meshgrid(np.arange(90), np.arange(60))
    ux = -0.6 + (jj + 0.5) * 1.2 / 90
    uy = 0.4 - (ii + 0.5) * 0.8 / 60
    depth = (2.2 + 0.8 * (ii / 59.0) + 0.1 * np.sin(jj / 7.0)).astype(np.float32)  # a tilted, wavy receiver
    depth[20:30, 40:50] = 0.0  # a hole: no receiver
    rng = np.random.default_rng(4)
    c = rng.uniform(-0.3, 0.3, (12, 2))
    z = rng.uniform(0.8, 2.0, 12)
    size = rng.uniform(0.002, 0.05, 12)
    patches = np.c_[c[:, 0] * z - size * z, c[:, 0] * z + size * z, c[:, 1] * z - size * z, c[:, 1] * z + size * z, z]
    ext0 = ssm.penumbra_extents_sphere(patches, rho, float(depth.max()), sv.params())
    pyr = ssm.max_pyramid(depth)
    ext = ssm.refine_extents_sphere(patches, ext0.copy(), rho, pyr[0], pyr[1], pyr[3], sv.params(), 3)
    area = lambda e: np.maximum(e[:, 1] - e[:, 0] + 1, 0) * np.maximum(e[:, 3] - e[:, 2] + 1, 0)  # noqa: E731
    assert area(ext).sum() < 0.8 * area(ext0).sum()
    seen = 0.0
    for p, (i0, i1, j0, j1) in zip(patches, ext):
        inside = (ii >= i0) & (ii <= i1) & (jj >= j0) & (jj <= j1)
        occ = np.array(
            [
                ssm.occlusion_percentage_disk_at(p, a, b, float(zr), rho) if zr > 0 else 0.0
                for a, b, zr in zip(ux.ravel(), uy.ravel(), depth.ravel())
            ]
        ).reshape(60, 90)
        assert occ[~inside].max(initial=0.0) <= 1e-12
        seen += occ.sum()
    assert seen > 1.0


def test_disk_occlusion_of_whole_square_is_closed_form():
    """One micro-patch that *is* the square occluder, the sphere light's disk facing each point:
    the fragment program gives the closed form (projection onto the facing disk, exact overlap)."""
    from softshadows.analytic import disk_polygon_occluder_visibility

    rho = 0.56
    rng = np.random.default_rng(2)
    p = np.c_[rng.uniform(-1.5, 1.5, 300), np.zeros(300), rng.uniform(-1.5, 1.5, 300)]
    zr = LIGHT_Y - p[:, 1]
    patch = (-0.5, 0.5, -0.5, 0.5, LIGHT_Y - OCC_Y)
    got = np.array(
        [ssm.occlusion_percentage_disk_at(patch, x / z, y / z, z, rho) for x, y, z in zip(p[:, 0], p[:, 2], zr)]
    )
    sq = [[-0.5, OCC_Y, -0.5], [0.5, OCC_Y, -0.5], [0.5, OCC_Y, 0.5], [-0.5, OCC_Y, 0.5]]
    ref = disk_polygon_occluder_visibility(p, sq, [0, LIGHT_Y, 0], rho)
    np.testing.assert_allclose(1 - got, ref, atol=1e-9)
    assert np.sum((ref > 0.05) & (ref < 0.95)) > 50  # points in the penumbra


def test_disk_occlusion_clips_patch_parts_behind_the_disk():
    """A patch crossing the plane of the disk facing p: only its part in front of the disk hides
    anything. p straight below the light (disk horizontal), patch [-2, 0] x [-2, 2] at depth 0.5
    in a light frame seen at an angle: compared with the same patch cut at the disk's plane."""
    rho = 0.5
    # receiver point p at projective (0.4, 0) depth 2: w = p/|p| is tilted, so the patch plane
    # z = 0.05 crosses the disk's plane; the part of the patch with w.q <= 0 must not count
    got = ssm.occlusion_percentage_disk_at((-3.0, 3.0, -3.0, 3.0, 0.05), 0.4, 0.0, 2.0, rho)
    p = np.array([0.8, 0.0, 2.0])
    w = p / np.linalg.norm(p)
    # the cut patch: x from the line w.q = 0 (at z = 0.05: x = -0.05 wz/wx) to 3
    x_cut = -0.05 * w[2] / w[0]
    kept = ssm.occlusion_percentage_disk_at((x_cut + 1e-12, 3.0, -3.0, 3.0, 0.05), 0.4, 0.0, 2.0, rho)
    assert got == pytest.approx(kept, abs=1e-9)
    assert 0.0 < got < 1.0


def test_penumbra_extent_sphere_contains_every_occluded_texel():
    """Outside its extent a micro-patch hides nothing of any facing disk (receivers on the virtual
    plane and nearer)."""
    from softshadows.raster import View

    sv = View.frame((0, 0, 0), (0, 0, 1), (0, 1, 0), (-0.6, 0.6, -0.4, 0.4), 0.1, 10.0, 90, 60)
    rho, z_plane = 0.3, 3.0
    rng = np.random.default_rng(3)
    c = rng.uniform(-0.3, 0.3, (12, 2))
    z = rng.uniform(0.8, 2.8, 12)
    size = rng.uniform(0.002, 0.05, 12)
    patches = np.c_[c[:, 0] * z - size * z, c[:, 0] * z + size * z, c[:, 1] * z - size * z, c[:, 1] * z + size * z, z]
    ext = ssm.penumbra_extents_sphere(patches, rho, z_plane, sv.params())
    jj, ii = np.meshgrid(np.arange(90), np.arange(60))
    ux = -0.6 + (jj + 0.5) * 1.2 / 90
    uy = 0.4 - (ii + 0.5) * 0.8 / 60
    seen = 0.0
    for p, (i0, i1, j0, j1) in zip(patches, ext):
        inside = (ii >= i0) & (ii <= i1) & (jj >= j0) & (jj <= j1)
        for zr in (z_plane, 0.5 * (p[4] + z_plane)):
            occ = np.array([ssm.occlusion_percentage_disk_at(p, a, b, zr, rho) for a, b in zip(ux.ravel(), uy.ravel())])
            occ = occ.reshape(60, 90)
            assert occ[~inside].max(initial=0.0) <= 1e-12  # 0 up to the sectors' rounding
            seen += occ.sum()
    assert seen > 1.0  # the patches do hide light at texels (inside their extents)


def test_square_sphere_light_matches_closed_form():
    """``square`` with its sphere light (same center, equal area: rho = 1/sqrt(pi)): V on the
    ground against the closed form 1 - area(disk facing p n square projected from p)/(pi rho^2).
    As for the rect light the errors are the occluder map's discretization and the SSM's bilinear
    reconstruction. At 128 the occluder window's pixel edges fall mid-way across the square's
    edges, so the discretized square is up to half a pixel larger: measured MAE 2.5e-3, -0.010 over
    the penumbra, the same as the rect light's (-0.011) at 128 (2e-4 at 256); bounded here by 0.005
    over ground pixels and 0.02 over the penumbra."""
    from softshadows.analytic import disk_polygon_occluder_visibility

    sc = ss.load_scene("square", light="sphere")
    res = ss.render(sc, "soft-shadow-map", 96, 72, map_size=128, ssm_size=128)
    pos = res.position.reshape(-1, 3)
    v = res.visibility.ravel()
    g = np.isfinite(v) & (np.abs(pos[:, 1]) < 1e-5)
    sq = [[-0.5, OCC_Y, -0.5], [0.5, OCC_Y, -0.5], [0.5, OCC_Y, 0.5], [-0.5, OCC_Y, 0.5]]
    ref = disk_polygon_occluder_visibility(pos[g], sq, sc.light.center, sc.light.radius)
    pen = (ref > 0.01) & (ref < 0.99)
    assert pen.sum() > 200
    err = np.abs(v[g] - ref)
    assert err.mean() <= 0.005 and err[pen].mean() <= 0.02, (err.mean(), err[pen].mean())


def test_disk_facing_frame_is_orthonormal_and_faces_the_point():
    """The frame shared by ground truth and the sphere path (analytic.disk_facing_frame): w = p/|p|,
    e1, e2 orthonormal and right-handed (e2 = w x e1), |p| returned, on both branches of the helper
    axis (|w_x| < 0.9 and >= 0.9). Each value is a few float64 operations: 1e-14 is ~50 ulps."""
    from softshadows.analytic import disk_facing_frame

    rng = np.random.default_rng(3)
    pts = np.vstack([rng.normal(size=(50, 3)) * 5, [[3.0, 0.1, -0.2], [-7.0, 0.0, 0.0]]])
    for p in pts:
        f = np.array(py_callable(disk_facing_frame)(*p))
        w, e1, e2, n = f[0:3], f[3:6], f[6:9], f[9]
        assert abs(n - np.linalg.norm(p)) <= 1e-14 * n
        assert np.allclose(w, p / np.linalg.norm(p), atol=1e-14, rtol=0)
        m = np.array([w, e1, e2])
        assert np.allclose(m @ m.T, np.eye(3), atol=1e-14, rtol=0)
        assert np.allclose(np.cross(w, e1), e2, atol=1e-14, rtol=0)


def test_disk_frames32_rounds_the_float64_frames():
    """The float32 planes the row pass reads, now made from the receiver depths directly, are
    the float64 frames (:func:`disk_frames`: w, |p|, kappa, sqrt(1 + kappa^2)) rounded to float32,
    bit for bit: the same arithmetic, one rounding."""
    sc = ss.load_scene("bunny", light="sphere")
    _ov, sv = ssm.compute_map_views(sc, 32, 48)
    rdepth, _ = ssm.compute_receiver_depth_map(sc, sv)
    rd0 = np.where(np.isfinite(rdepth), rdepth, 0).astype(np.float32)
    assert (rd0 > 0).sum() > 500  # receivers are there
    f64 = ssm.disk_frames(rd0, sv.params(), sc.light.radius)
    f32 = ssm.disk_frames32(rd0, sv.params(), sc.light.radius)
    assert np.array_equal(f32, f64[[0, 1, 2, 9, 10, 11]].astype(np.float32).transpose(1, 0, 2))  # (H, 6, W)


def _sphere_extent_reference(x0, x1, y0, y1, z, rho, lzb, z_max, svp):
    """:func:`ssm._sphere_extent` as first written: each of the 32 corner shadows divided by z_max."""
    from softshadows.raster.view import VP_B, VP_H, VP_L, VP_R, VP_T, VP_W

    l, r, b, t = svp[VP_L], svp[VP_R], svp[VP_B], svp[VP_T]
    dxs, dys = (r - l) / svp[VP_W], (t - b) / svp[VP_H]
    if not (z < z_max):
        return 1.0, 0.0, 1.0, 0.0
    if not z > lzb:
        x_lo, x_hi, y_lo, y_hi = l, r, b, t
    else:
        xs, ys = [x0 / z, x1 / z], [y0 / z, y1 / z]
        for c in range(8):
            lx = rho if (c & 1) else -rho
            ly = rho if (c & 2) else -rho
            lz = lzb if (c & 4) else -lzb
            s = (z_max - lz) / (z - lz)
            xs += [(lx + (q - lx) * s) / z_max for q in (x0, x1)]
            ys += [(ly + (q - ly) * s) / z_max for q in (y0, y1)]
        x_lo, x_hi, y_lo, y_hi = min(xs), max(xs), min(ys), max(ys)
    fj0 = max(np.ceil((x_lo - l) / dxs - 0.5), 0.0)
    fj1 = min(np.floor((x_hi - l) / dxs - 0.5), svp[VP_W] - 1.0)
    fi0 = max(np.ceil((t - y_hi) / dys - 0.5), 0.0)
    fi1 = min(np.floor((t - y_lo) / dys - 0.5), svp[VP_H] - 1.0)
    return fi0, fi1, fj0, fj1


def test_sphere_extent_divides_once_with_the_same_bounds():
    """Dividing the min / max by z_max once (and one s per light depth) gives the texel ranges of
    dividing each of the 32 shadows: division by a positive number is monotone and correctly
    rounded. Random patches, light sizes and depths, including patches near the light box."""
    rng = np.random.default_rng(7)
    sv = ssm.View.frame((0, 0, 0), (0, 0, 1), (0, 1, 0), (-1.3, 1.1, -0.9, 1.2), 1e-3, 10.0, 96, 80)
    svp = sv.params()
    n_diff = 0
    for _ in range(4000):
        rho = rng.uniform(0.05, 1.0)
        z = rng.uniform(0.5 * rho, 6.0)
        x0, y0 = rng.uniform(-2, 2, 2) * z
        w, h = rng.uniform(1e-3, 0.1, 2) * z
        lzb = rho * rng.uniform(0.0, 1.0)
        z_max = z * rng.uniform(0.8, 3.0)
        got = py_callable(ssm._sphere_extent)(x0, x0 + w, y0, y0 + h, z, rho, lzb, z_max, svp)
        ref = _sphere_extent_reference(x0, x0 + w, y0, y0 + h, z, rho, lzb, z_max, svp)
        n_diff += tuple(float(v) for v in got) != tuple(float(v) for v in ref)
    assert n_diff == 0


def test_queue_crossings_takes_the_flagged_texels_in_order():
    """The queue walks each 8-texel block's flagged bytes by their lowest set bit: it must take
    exactly the flagged texels of ``[0, nl)`` of its row's flags (here the second row of a band's
    flag buffer), in column order, and ignore stale flags past ``nl`` (left by a longer row) and
    the other row's flags."""
    from numba import njit

    W = 64
    rd = np.arange(2 * W, dtype=np.float32).reshape(2, W) + 1.0
    buf = np.zeros(2 * W, np.bool_)
    flags = buf[W:]
    rng = np.random.default_rng(3)
    queue = njit(lambda f, nl, base, Q, rows, cols: ssm._queue_crossings(
        rd, f.view(np.uint64), W // 8, 1, base, nl, 0.1, 0.2, 0.3, 0.4, 0.5, Q, rows, cols, 2
    ))  # fmt: skip
    for nl, base in ((64, 0), (37, 5), (8, 40), (3, 0), (16, 48)):
        buf[:W] = True  # the other row's
        flags[:] = rng.random(W) < 0.3
        flags[nl:] = True  # stale
        Q, rows, cols = np.zeros((6, 80)), np.full(80, -1), np.full(80, -1)
        m = queue(buf, nl, base, Q, rows, cols)
        want = base + np.flatnonzero(flags[:nl])
        assert m == 2 + len(want)
        assert np.array_equal(cols[2:m], want) and np.all(rows[2:m] == 1)
        assert np.array_equal(Q[5, 2:m], rd[1, want].astype(np.float64))
        assert np.all(Q[0, 2:m] == 0.1) and np.all(Q[4, 2:m] == 0.5)


@pytest.mark.parametrize("threads,serial_below", [(1, 1 << 20), (2, 1 << 20), (2, 0)])
def test_bin_patches_by_band_lists_every_patch_of_every_band_in_order(threads, serial_below, monkeypatch):
    """``bin_patches_by_band`` (offsets and each patch's bands in one pass, lists filled on the
    calling thread or, above ``_SERIAL_BAND_ENTRIES`` entries, by the threads, each its own run of
    bands): per band, exactly the patches whose extent meets it, in patch order, with one thread or
    two; empty extents and empty bands included."""
    import numba

    monkeypatch.setattr(ssm, "_SERIAL_BAND_ENTRIES", serial_below)

    rng = np.random.default_rng(3)
    n, rows, band_rows = 3000, 97, 4
    i0 = rng.integers(0, rows, n)
    i1 = np.minimum(i0 + rng.integers(-3, 30, n), 59)  # some empty (i0 > i1)
    i1[i0 >= 60] = -1  # the bands from row 60 on stay empty
    ext = np.stack([i0, i1, np.zeros(n), np.zeros(n)], 1).astype(np.int32)
    n_bands = (rows + band_rows - 1) // band_rows
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        ptr, idx = ssm.bin_patches_by_band(ext, n_bands, band_rows)
    finally:
        numba.set_num_threads(old)
    assert len(ptr) == n_bands + 1 and ptr[0] == 0 and ptr[-1] == len(idx)
    for b in range(n_bands):
        want = [k for k in range(n) if i0[k] <= i1[k] and i0[k] // band_rows <= b <= i1[k] // band_rows]
        assert idx[ptr[b] : ptr[b + 1]].tolist() == want
    assert ptr[15] == ptr[-1] and ptr[14] < ptr[15]  # bands 15-24 empty, band 14 not


@pytest.mark.parametrize("light", ["rect", "sphere"])
def test_accumulation_is_the_same_bits_whatever_the_slots(light, monkeypatch):
    """Each band's sums (its patches in draw order, the sphere's crossing queue included) are its
    own, whichever slot sums it, so one slot and three slots give the same soft shadow map bit for
    bit, and every band is summed once (a band taken twice or skipped would change the sums).
    ``spheres``: several occluders, shadows in many bands."""
    name = "accumulate_soft_shadow_map_sphere" if light == "sphere" else "accumulate_soft_shadow_map"
    fn = getattr(ssm, name)
    seen = {}

    def capture(*args):
        seen["args"] = args
        return fn(*args)

    monkeypatch.setattr(ssm, name, capture)
    ss.render(ss.load_scene("spheres", light=light), "soft-shadow-map", 64, 48)
    args = seen["args"]
    ssm_at = list(inspect.signature(fn).parameters).index("ssm")
    outs = []
    for nslot in (1, 3):
        a = list(args)
        a[ssm_at] = np.zeros_like(args[ssm_at])
        a[-1] = nslot
        touched = fn(*a)
        outs.append((a[ssm_at], touched))
    (s1, t1), (s3, t3) = outs
    assert s1.any() and (s1 > 0.99).any()  # a real shadow, umbra included
    np.testing.assert_array_equal(s1, s3)
    np.testing.assert_array_equal(t1, t3)
