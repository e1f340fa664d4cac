"""``penumbra-map`` (Wyman & Hansen 2003): the construction against an independent evaluation,
the umbra against ``hard``, the outer-penumbra profile, overlaps, contact, and sanity on every
built-in scene."""

import numpy as np
import pytest

import softshadows as ss
from softshadows.methods import penumbra_map as P
from softshadows.methods.shadowmap import build_shadow_map, fit_light_view, lookup_points
from softshadows.scene import Camera, Mesh, Scene, SphereLight
from softshadows.scene import primitives as prim
from softshadows.shading import facing_normals


# ---------------------------------------------------------------------------------------------
# an independent evaluation of the paper's cones and sheets
# ---------------------------------------------------------------------------------------------
def _window(view, pts):
    q = view.to_view(pts)
    return q[..., :2] / q[..., 2:3], q[..., 2]


def _texel_rays(view):
    """Unit-depth ray points (window coordinates) of every texel center of ``view``."""
    j, i = np.meshgrid(np.arange(view.width) + 0.5, np.arange(view.height) + 0.5)
    l, r, b, t = view.window
    return np.stack([l + j / view.width * (r - l), t - i / view.height * (t - b)], -1)


def _ray_plane_depth(view, w, p0, n):
    """View depth at which rays through window points w (..., 2) meet the plane (p0, n)."""
    d = view.right * w[..., :1] + view.up * w[..., 1:2] + view.forward  # world ray, depth 1
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.dot(np.asarray(p0) - view.origin, n) / (d @ n)
    return np.where(z > 0, z, np.inf)


def _smooth(i, bernstein=True):
    return i * i * (3 - 2 * i) if bernstein else i


def direct_penumbra(view, w, zp, corners, lr, z_far, segments, bias, bernstein=True):
    """Penumbra intensity at window points ``w`` with surface depth ``zp`` from the cones and
    sheets of the closed silhouette polygon ``corners`` (world (N,3), in order), evaluated in
    closed form: a cone at each corner (regular ``segments``-gon cross-sections, vertices at
    angles 2 pi k / segments from the view's right axis, radius L_r (1/z_v - 1/z) in window
    units at depth z) and a ruled sheet along each edge from the edge to the outer common tangent
    of the two cones' far-plane circles. Per primitive the paper's fragment program, then the min."""
    wc, zc = _window(view, corners)
    out = np.ones(w.shape[:-1])
    eps = bias * (view.window[1] - view.window[0]) / view.width * zp
    centroid = wc.mean(axis=0)

    def program(zf, zv):
        ok = (zf < zp - eps) & (zf >= zv - 1e-9) & np.isfinite(zf)
        with np.errstate(divide="ignore", invalid="ignore"):
            i = np.clip((zf - zv) / (zp - zv), 0.0, 1.0)
        return np.where(ok, _smooth(i, bernstein), 1.0)

    # cones: the hit depth z solves L_r (1/z_v - 1/z) = (polygon "radius" along the direction)
    half = np.pi / segments
    for k in range(len(corners)):
        dvec = w - wc[k]
        s = np.linalg.norm(dvec, axis=-1)
        phi = np.arctan2(dvec[..., 1], dvec[..., 0])
        mid = (np.floor(phi / (2 * half)) * 2 + 1) * half  # middle angle of the facet containing phi
        s_eff = s * np.cos(phi - mid) / np.cos(half)
        with np.errstate(divide="ignore"):
            inv = 1.0 / zc[k] - s_eff / lr
            zf = np.where(inv > 1.0 / z_far, 1.0 / inv, np.inf)
        out = np.minimum(out, program(zf, zc[k]))
    # sheets: rulings from v(t) on the edge to F(t) on the far-plane tangent segment
    L = view.origin
    d = view.right * w[..., :1] + view.up * w[..., 1:2] + view.forward
    for k in range(len(corners)):
        i0, i1 = k, (k + 1) % len(corners)
        z0, z1 = zc[i0], zc[i1]
        a0, a1 = wc[i0] * z_far, wc[i1] * z_far  # far-plane points (view x, y)
        c0, c1 = (z_far - z0) * lr / z0, (z_far - z1) * lr / z1
        e = (a1 - a0) / np.linalg.norm(a1 - a0)
        left = np.array([-e[1], e[0]])
        cr = e[0] * (centroid - wc[i0])[1] - e[1] * (centroid - wc[i0])[0]
        out_n = -left if cr > 0 else left
        sa = (c0 - c1) / np.linalg.norm(a1 - a0)
        nrm = np.sqrt(1 - sa**2) * out_n + sa * e
        f0, f1 = a0 + c0 * nrm, a1 + c1 * nrm
        F0 = L + f0[0] * view.right + f0[1] * view.up + z_far * view.forward
        F1 = L + f1[0] * view.right + f1[1] * view.up + z_far * view.forward
        V0, V1 = corners[i0], corners[i1]
        # det[d, P(t) - L, D(t)] = 0 with P(t) = V0 + t (V1 - V0), D(t) = F0 - V0 + t (F1 - F0 - V1 + V0)
        p0, p1 = V0 - L, V1 - V0
        q0, q1 = F0 - V0, (F1 - F0) - (V1 - V0)

        def det(a, b):
            return np.einsum("...k,k->...", d, np.cross(a, b))

        A = det(p1, q1)
        B = det(p0, q1) + det(p1, q0)
        C = det(p0, q0)
        disc = B * B - 4 * A * C
        for sg in (-1.0, 1.0):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(np.abs(A) > 1e-14, (-B + sg * np.sqrt(np.maximum(disc, 0))) / (2 * A), -C / B)
            t = np.where(disc >= 0, t, np.nan)
            P_ = L + p0 + t[..., None] * p1
            D_ = q0 + t[..., None] * q1
            # L + lam d = P + u D: normal equations of the 3x2 system, Cramer's rule
            rhs = P_ - L
            dd = np.einsum("...k,...k->...", d, d)
            dD = np.einsum("...k,...k->...", d, D_)
            DD = np.einsum("...k,...k->...", D_, D_)
            dr = np.einsum("...k,...k->...", d, rhs)
            Dr = np.einsum("...k,...k->...", D_, rhs)
            with np.errstate(divide="ignore", invalid="ignore"):
                den = dd * DD - dD * dD
                lam = (dr * DD - dD * Dr) / den
                u = (dr * dD - dd * Dr) / den
            good = (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1) & (lam > 0)
            zf = np.where(good, lam, np.inf)  # d has unit depth: lam is the view depth
            out = np.minimum(out, program(zf, z0 + t * (z1 - z0)))
    return out


def _quad_scene(corner_sets, light, ground_size=8.0):
    meshes = [Mesh(*prim.plane(ground_size, ground_size, 1, 1), role="receiver", name="ground")]
    for c in corner_sets:
        meshes.append(Mesh(np.asarray(c, float), [[0, 1, 2], [0, 2, 3]], role="occluder", name="quad"))
    cam = Camera((0.0, 4.0, 3.0), (0.0, 0.5, 0.0), (0.0, 1.0, 0.0), 40.0)
    return Scene(meshes, light, cam, "quads")


def _passes(scene, map_size, base_view=None, **kw):
    lr = P.light_radius_of(scene.light)
    smp = P.shadow_map_pass(scene, map_size, lr, base_view=base_view)
    pm = P.render_penumbra_map(scene, smp, lr, **kw)
    return smp, pm


SQUARE = np.array([[-0.5, 1.0, -0.5], [0.5, 1.0, -0.5], [0.5, 1.0, 0.5], [-0.5, 1.0, 0.5]])


@pytest.mark.parametrize("tilt,subdiv", [(0.0, 64), (25.0, 64), (25.0, None)])
def test_penumbra_map_matches_direct_cone_sheet_evaluation(tilt, subdiv):
    """Every ground texel of the penumbra map equals the closed-form cones/sheets value. The light
    is off-center, so the silhouette vertices have different depths and the sheets are ruled,
    non-planar surfaces with Z_v varying along the edge; tilting the quad makes that stronger."""
    a = np.radians(tilt)
    rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    corners = (SQUARE - [0, 1, 0]) @ rot.T + [0, 1, 0]  # tilted about the x axis
    light = SphereLight((0.2, 3.0, 0.1), 0.35)
    scene = _quad_scene([corners], light)
    kw = dict(sheet_tolerance=0.0, sheet_max_subdiv=subdiv) if subdiv else {}  # None: the defaults
    smp, pm = _passes(scene, 192, **kw)
    assert pm.silhouette.n_edges == 4 and pm.stats["sheets_subdivided"] == 4
    view = smp.view
    w = _texel_rays(view)
    zp = _ray_plane_depth(view, w, (0, 0, 0), np.array([0.0, 1.0, 0.0]))
    # texels whose ray meets the occluder first, and a 4-texel rim around it, are not ground texels
    from matplotlib.path import Path

    occ_w, _ = _window(view, corners)
    px = (view.window[1] - view.window[0]) / view.width
    path = Path(occ_w)
    on_occ = path.contains_points(w.reshape(-1, 2), radius=-4 * px) | path.contains_points(
        w.reshape(-1, 2), radius=4 * px
    )
    ground = (~on_occ.reshape(zp.shape)) & np.isfinite(smp.surface_depth)
    ref = direct_penumbra(view, w, zp, corners, light.radius, pm.z_far, 16, bias=1.0)
    got = pm.intensity
    pen = ground & ((ref < 1) | (got < 1))
    assert pen.sum() > 5000  # a real penumbra band around the quad
    err = np.abs(got - ref)[pen]
    # What is left is discretization: k planar strips stand for the ruled sheet (bilinear twist:
    # depth off by ~ q/(4k) of the strip, Z_v interpolated linearly across converging rulings).
    # Measured: with 64 strips max 1e-3, with the defaults (tolerance 0.005, <= 16 strips)
    # max 3e-3 (tilt 25). Vertex snapping (1/256 px) and float32 depths add < 1e-4 here.
    # A bound 2x above the measured values, and a mean 10x below it.
    tol = 2e-3 if subdiv else 6e-3
    assert err.max() < tol, (np.sort(err)[-5:], err.mean())
    assert err.mean() < tol / 10


def test_eye_pass_outer_penumbra_is_monotonic_and_matches_direct_evaluation():
    scene = ss.load_scene("square", light="sphere")
    lr = scene.light.radius
    smp, pm = _passes(scene, 256)
    # ground points on the line z = 0 from x = 0 (under the occluder) outward across the x = +0.5 edge
    x = np.linspace(0.0, 1.6, 801)
    pts = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    nrm = np.tile([0.0, 1.0, 0.0], (len(x), 1))
    v, umbra = P.eye_pass(smp, pm, pts, nrm, 1.0, 1.0)
    # the hard shadow edge on the ground is at x = 0.5 * 3 / 2 = 0.75 (central projection)
    assert np.all(umbra[x < 0.74]) and not np.any(umbra[x > 0.76])
    out = ~umbra
    assert v[umbra].max() == 0.0
    # V rises monotonically from the hard-shadow edge outward ...
    assert np.all(np.diff(v[out]) >= 0)
    assert v[out][0] < 0.05 and v[-1] == 1.0
    # ... over the paper's outer penumbra width (z_P - z_v) L_r / z_v = 1 * lr / 2 (world, on the
    # ground, measured from the edge's shadow at x = 0.75), to within two texels
    texel = (smp.view.window[1] - smp.view.window[0]) / smp.view.width * 3.0
    lit = x[(v == 1.0) & out].min()
    assert abs((lit - 0.75) - lr / 2) < 2 * texel
    # ... and equals the direct evaluation at the texel the point falls in
    sx, sy, _ = smp.view.project(pts)
    inside = out & (sx < smp.view.width)  # beyond the map's border: V = 1 (checked above)
    assert inside.sum() > 100
    w = _texel_rays(smp.view)[np.floor(sy[inside]).astype(int), np.floor(sx[inside]).astype(int)]
    zp = _ray_plane_depth(smp.view, w, (0, 0, 0), np.array([0.0, 1.0, 0.0]))
    ref = direct_penumbra(smp.view, w, zp, SQUARE, lr, pm.z_far, 16, bias=1.0)
    # the light is centered: planar sheets, exact up to vertex snapping and float32 (< 1e-4 measured)
    np.testing.assert_allclose(v[inside], ref, atol=5e-4)
    # the linear option gives I itself, and Bernstein is 3I^2 - 2I^3 of it (min commutes)
    _, pm_lin = _passes(scene, 256, smoothstep="linear")
    m = pm_lin.intensity < 1
    np.testing.assert_allclose(pm.intensity[m], _smooth(pm_lin.intensity[m]), atol=1e-5)


def test_umbra_is_hards_shadow():
    for name in ("bunny", "contact"):
        scene = ss.load_scene(name, light="sphere")
        res = ss.render(scene, "penumbra-map", 96, 96, map_size=512)
        hard = ss.render(scene, "hard", 96, 96, map_size=512)
        m = np.isfinite(res.visibility)
        assert np.all(res.visibility[m & (hard.visibility == 0)] == 0)
        assert res.stats["umbra_pixels"] == int((hard.visibility[m] == 0).sum())
        # the same test, point by point, against a shadow map built with hard's own functions
        pts = res.position[m].astype(np.float64)
        nrm = facing_normals(res.normal[m].astype(np.float64), pts, scene.camera.eye)
        smap = build_shadow_map(scene, fit_light_view(scene, 512))
        v_hard = lookup_points(smap, pts, nrm, 1.0, 1.0, 0)
        smp, pm = _passes(scene, 512)
        np.testing.assert_array_equal(smp.occluder_depth, smap.depth)
        _, umbra = P.eye_pass(smp, pm, pts, nrm, 1.0, 1.0)
        np.testing.assert_array_equal(umbra, v_hard == 0)
        assert umbra.sum() > 100


def test_eye_pass_over_the_gbuffer_is_the_per_point_pass():
    """The frame's eye pass runs straight over the eye G-buffer (``eye_lookups_image``,
    ``eye_gather``): V and the umbra/penumbra counts are, bit for bit, those of the per-point pass
    (``eye_pass``) at the gathered points, with the normals of either side (the bias uses |n.l|)."""
    for name, light in (("bunny", "rect"), ("contact", "sphere")):
        scene = ss.load_scene(name, light=light)
        res = ss.render(scene, "penumbra-map", 64, 48, map_size=256, texels="all")
        m = res.mask
        pts = res.position[m].astype(np.float64)
        nrm = res.normal[m].astype(np.float64)
        d = {p.name: p.default for p in ss.methods()["penumbra-map"].params}
        smp, pm = _passes(scene, 256, cone_segments=d["cone_segments"], sheet_tolerance=d["sheet_tolerance"])
        v, umbra = P.eye_pass(smp, pm, pts, nrm, 1.0, 1.0)
        np.testing.assert_array_equal(res.visibility[m], v)
        np.testing.assert_array_equal(v, P.eye_pass(smp, pm, pts, -nrm, 1.0, 1.0)[0])
        assert res.stats["umbra_pixels"] == umbra.sum() > 0
        assert res.stats["penumbra_pixels"] == ((v > 0) & (v < 1)).sum() > 0
        assert np.isnan(res.visibility[~m]).all()


def test_overlapping_penumbrae_darkest_wins():
    light = SphereLight((0.0, 3.0, 0.0), 0.4)
    # a: x in [-0.9, 0.1] at y = 1 (hard shadow edge x = 0.15, penumbra to 0.35);
    # b: x in [0.2, 1.0] at y = 1.5 (hard shadow edge x = 0.4, penumbra to 0.0)
    a = SQUARE + [-0.4, 0.0, 0.0]
    b = (SQUARE - [0, 1, 0]) * [0.8, 1, 0.8] + [0.6, 1.5, 0.0]
    both = _quad_scene([a, b], light)
    base = fit_light_view(both, 256)
    kw = dict(base_view=base)
    res = {}
    for key, sc in (("a", _quad_scene([a], light)), ("b", _quad_scene([b], light)), ("ab", both)):
        smp, pm = _passes(sc, 256, **kw)
        res[key] = (smp, pm)
    # ground points between the two shadows
    g = np.stack(np.meshgrid(np.linspace(0.0, 0.5, 101), np.linspace(-0.5, 0.5, 101)), -1).reshape(-1, 2)
    pts = np.stack([g[:, 0], np.zeros(len(g)), g[:, 1]], 1)
    nrm = np.tile([0.0, 1.0, 0.0], (len(g), 1))
    v = {k: P.eye_pass(s, p, pts, nrm, 1.0, 1.0) for k, (s, p) in res.items()}
    va, vb, vab = v["a"][0], v["b"][0], v["ab"][0]
    free = ~(v["a"][1] | v["b"][1] | v["ab"][1])
    overlap = free & (va < 0.95) & (vb < 0.95)
    assert overlap.sum() > 50  # the two penumbrae do overlap here
    # the penumbra map keeps the darkest value per texel (the paper's depth-test trick)
    np.testing.assert_allclose(vab[free], np.minimum(va, vb)[free], atol=1e-4)
    # ... which is neither the product nor the sum of the two occlusions
    assert np.max(vab[overlap] - va[overlap] * vb[overlap]) > 0.05
    assert np.max(vab[overlap] - np.clip(va + vb - 1, 0, 1)[overlap]) > 0.05


def test_contact_penumbra_width_vanishes_at_contact():
    scene = ss.load_scene("contact", light="sphere")
    smp, pm = _passes(scene, 512)
    # the box's vertical silhouette edges at x = -0.5, z = +-0.3 stand on the ground; their shadow
    # boundary runs from the contact corner (-0.5, 0, 0.3) toward +x, at z > 0.3
    xs = np.linspace(-0.49, -0.1, 14)
    z = np.linspace(0.25, 0.9, 1301)
    texel = (smp.view.window[1] - smp.view.window[0]) / smp.view.width * 3.0  # world texel near the ground
    widths = []
    for x in xs:
        pts = np.stack([np.full_like(z, x), np.zeros_like(z), z], 1)
        nrm = np.tile([0.0, 1.0, 0.0], (len(z), 1))
        v, umbra = P.eye_pass(smp, pm, pts, nrm, 1.0, 1.0)
        pen = (~umbra) & (v < 1.0) & (z > 0.3)
        widths.append((z[pen].max() - z[pen].min()) if pen.any() else 0.0)
    widths = np.array(widths)
    # silhouette height h at the ground point x: the light at (-1.8, 3) projects (-0.5, h) to x
    h = 3.0 * (xs + 0.5) / (xs + 1.8)
    # outer penumbra ~ (z_P - z_v) L_r / z_v measured across the boundary: grows with h, -> 0
    assert widths[0] <= 3 * texel
    assert np.all(np.diff(widths) > -2 * texel)
    assert widths[-1] > 10 * widths[0] + texel
    assert np.corrcoef(h, widths)[0, 1] > 0.98


@pytest.mark.parametrize("light", ["sphere", "rect"])
def test_umbra_lit_pixels_and_stats_on_all_builtin_scenes(light):
    # (V finite and in [0,1] on every scene: tests/test_api.py, for every method)
    for name in ss.scene.builtin.builtin_scenes():
        scene = ss.load_scene(name, light=light)
        res = ss.render(scene, "penumbra-map", 40, 40, map_size=192)
        v = res.visibility[res.mask]
        assert v.min() == 0.0 and v.max() == 1.0, name  # an umbra and lit pixels in every scene
        st = res.stats
        assert st["silhouette_edges"] > 0 and st["cone_fragments"] + st["sheet_fragments"] > 0
        assert st["light_radius_equivalent"] == (light == "rect")
        assert np.isclose(st["light_radius"], scene.light.equivalent_radius)


def test_paths_and_options_agree():
    scene = ss.load_scene("bunny", light="sphere")
    _, ref = _passes(scene, 256, early_reject=False)
    _, fast = _passes(scene, 256, early_reject=True)
    _, adj = _passes(scene, 256, silhouettes="adjacency")
    # early rejection only drops fragments the fragment program discards; rounding of the
    # shortened triangles' snapped vertices may move a facet boundary across a texel center
    d = np.abs(fast.intensity - ref.intensity)
    assert np.mean(d > 1e-3) < 1e-3 and d.max() < 0.05
    assert fast.stats["cone_fragments"] < ref.stats["cone_fragments"]
    assert fast.stats["sheet_fragments"] < ref.stats["sheet_fragments"]
    # kept fragments: the coarse value test also skips pieces that could lower no texel (kept
    # fragments, but not darker than the map already is), so at most the reference's
    assert (
        0.9 * ref.stats["cone_fragments_kept"] <= fast.stats["cone_fragments_kept"] <= ref.stats["cone_fragments_kept"]
    )
    assert fast.stats["value_culled_tile_pieces"] > 0 and ref.stats["value_culled_tile_pieces"] == 0
    np.testing.assert_array_equal(adj.intensity, fast.intensity)  # same silhouette, same map
    assert fast.stats["silhouette_vertices_degree3plus"] > 0


@pytest.mark.parametrize("name,light", [("bunny", "sphere"), ("spheres", "rect"), ("contact", "sphere")])
def test_texels_read_gives_the_same_visibility(name, light):
    """``texels=read`` shades only the penumbra-map texels the eye pass reads: V must be bit for
    bit that of the whole map (``texels=all``), at far fewer fragments; the texels read are those
    of the eye points outside the umbra and inside the map."""
    scene = ss.load_scene(name, light=light)
    a = ss.render(scene, "penumbra-map", 72, 64, map_size=256, texels="read")
    b = ss.render(scene, "penumbra-map", 72, 64, map_size=256, texels="all")
    np.testing.assert_array_equal(a.visibility[a.mask], b.visibility[b.mask])
    sa, sb = a.stats, b.stats
    assert sb["texels_shaded"] == sb["penumbra_map_width"] * sb["penumbra_map_height"]
    n_out = int(a.mask.sum()) - sa["umbra_pixels"]  # eye points that read a texel (or none: outside)
    assert 0 < sa["texels_shaded"] <= n_out
    assert 0 < sa["cone_fragments"] < 0.5 * sb["cone_fragments"]
    # the lookups before pass 2 are those of pass 3
    smp = P.shadow_map_pass(scene, 256, P.light_radius_of(scene.light))
    ctx_pts = np.random.default_rng(2).uniform(-1.5, 1.5, size=(500, 3)) + [0, 0.5, 0]
    nrm = np.tile([0.0, 1.0, 0.0], (500, 1))
    look = P.eye_lookups(smp, ctx_pts, nrm, 1.0, 1.0)
    assert look.needed.sum() == len(np.unique(look.texel[(look.texel >= 0) & ~look.umbra]))


def test_parameters_and_stats():
    scene = ss.load_scene("square", light="sphere")
    with pytest.raises(ss.SoftShadowsError, match="smoothstep"):
        ss.render(scene, "penumbra-map", 16, 16, smoothstep="cubic")
    with pytest.raises(ss.SoftShadowsError, match="silhouettes"):
        ss.render(scene, "penumbra-map", 16, 16, silhouettes="fast")
    with pytest.raises(ss.SoftShadowsError, match="cone_segments"):
        ss.render(scene, "penumbra-map", 16, 16, cone_segments=2)
    m = ss.methods()["penumbra-map"]
    d = {p.name: p.default for p in m.params}
    assert d["map_size"] == 1024 and d["smoothstep"] == "bernstein" and d["silhouettes"] == "brute"
    res = ss.render(scene, "penumbra-map", 48, 48, map_size=128)
    for ph in ("shadow_map", "silhouettes", "penumbra_map", "eye_pass"):
        assert ph in res.timings
    st = res.stats
    assert st["silhouette_edges"] == 4 and st["silhouette_vertices"] == 4 and st["cones"] == 4
    assert st["sheets"] == 4 and st["sheet_fragments_kept"] > 0 and st["cone_fragments_kept"] > 0


@pytest.mark.parametrize("name", ["bunny", "spheres", "contact"])
def test_border_holds_every_cone(name):
    """The bordered map is sized from each occluder vertex's own cone reach: no cone or sheet may
    reach its outermost texels (they stay white) unless the border was clipped, and a map grown
    by 32 more texels on every side holds no darker texel outside the original extent."""
    scene = ss.load_scene(name, light="sphere")
    smp, pm = _passes(scene, 192, early_reject=False)
    assert not smp.border_clipped
    I = pm.intensity
    ring = np.concatenate([I[0], I[-1], I[:, 0], I[:, -1]])
    assert np.all(ring == 1.0)
    # the same texel grid grown by 32 texels: nothing darker than white falls outside
    v = smp.view
    l, r, b, t = v.window
    s = (r - l) / v.width
    g = 32
    big = P.View(
        v.origin,
        v.right,
        v.up,
        v.forward,
        (l - g * s, r + g * s, b - g * s, t + g * s),
        v.near,
        v.far,
        v.width + 2 * g,
        v.height + 2 * g,
        False,
    )
    zp = np.full((big.height, big.width), np.inf, np.float32)
    zp[g : g + v.height, g : g + v.width] = smp.surface_depth
    # receivers outside the original extent: rasterize them into the margin
    flat = scene.flat
    only = flat.receiver & ~flat.occluder
    if only.any():
        d, _ = P.rasterize_depth(big, flat.vertices, np.ascontiguousarray(flat.faces[only]))
        inner = np.zeros_like(zp, bool)
        inner[g : g + v.height, g : g + v.width] = True
        zp = np.where(inner, zp, d)
    smp_big = P.ShadowMapPass(smp.hard_view, big, tuple(x + g for x in smp.border), smp.occluder_depth, zp)
    pm_big = P.render_penumbra_map(scene, smp_big, P.light_radius_of(scene.light), early_reject=False)
    outside = np.ones_like(pm_big.intensity, bool)
    outside[g : g + v.height, g : g + v.width] = False
    assert np.all(pm_big.intensity[outside] == 1.0)


def test_straight_edge_inherent_error_is_at_least_hards():
    """The paper's model on a straight edge (benchmarks/penumbra_map_edge.py, the doc's plot):
    the hard shadow is kept as the umbra, so in the inner penumbra (true V < 1/2) penumbra-map is
    0 exactly like hard, and outside it the method starts from 0 where the truth is 1/2. Its mean
    error over the true penumbra is therefore at least hard's (measured 0.234 vs 0.215 at
    192x144). Hard's own error there is the mean occluded fraction of a disk cut by a chord swept
    uniformly across it, 2/(3 pi) = 0.212 (about: the chord's offset is nearly linear in x on a
    ground parallel to the occluder; 0.01 covers that and the pixel sampling)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
    import penumbra_map_edge as pme

    _, vt, vh, vp = pme.edge_profiles(96, 72)
    e = pme.errors(vt, vh, vp)
    assert e["n_inner"] > 100 and e["n_outer"] > 100
    inner = (vt > 1e-3) & (vt < 0.5)
    assert np.all(vh[inner] == 0.0) and np.all(vp[inner] == 0.0)  # the same umbra
    assert e["hard:penumbra"] == pytest.approx(2 / (3 * np.pi), abs=0.01)
    assert e["penumbra-map:penumbra"] >= e["hard:penumbra"]
    assert e["penumbra-map:outer"] >= e["hard:outer"]


@pytest.mark.parametrize("shape", [(37, 51), (64, 64), (1, 9), (10, 1)])
def test_zmax_pyramid_levels_and_the_occluder_minimum(shape):
    """``build_zmax_pyramid``: Z_P becomes, in place, the minimum with the occluder map at its
    position (NaN wins, as ``np.minimum``), and every cell of every level is the 2x2 maximum of the
    level below (odd edges: the cells there), with empty texels (inf, NaN, negative) as 0."""
    rng = np.random.default_rng(7)
    h, w = shape
    zp = rng.uniform(1.0, 5.0, shape).astype(np.float32)
    zp[rng.random(shape) < 0.2] = np.inf
    zp[rng.random(shape) < 0.02] = np.nan
    oh, ow = max(h // 2, 1), max(w // 3, 1)
    occ = rng.uniform(0.5, 3.0, (oh, ow)).astype(np.float32)
    occ[rng.random((oh, ow)) < 0.3] = np.inf
    occ[rng.random((oh, ow)) < 0.05] = np.nan
    at = (h - oh, w - ow) if h > 1 else (0, 0)
    ref = zp.copy()
    sl = (slice(at[0], at[0] + oh), slice(at[1], at[1] + ow))
    ref[sl] = np.minimum(ref[sl], occ)
    data, offs, ws, hs = P.build_zmax_pyramid(zp, occ, at)
    np.testing.assert_array_equal(zp, ref)
    lev = np.where(np.isfinite(ref), np.maximum(ref, 0.0), 0.0).astype(np.float32)
    assert len(offs) > 1 and ws[-1] == hs[-1] == 1
    for L in range(1, len(offs)):
        ph, pw = lev.shape
        pad = np.zeros((ph + ph % 2, pw + pw % 2), np.float32)  # the values are >= 0: zero padding is neutral
        pad[:ph, :pw] = lev
        lev = pad.reshape(pad.shape[0] // 2, 2, pad.shape[1] // 2, 2).max(axis=(1, 3))
        assert lev.shape == (hs[L], ws[L])
        np.testing.assert_array_equal(data[offs[L] : offs[L] + hs[L] * ws[L]].reshape(lev.shape), lev)
    assert P.pyramid_max((data, offs, ws, hs)) == lev.max()


@pytest.mark.parametrize("texels", ["read", "all"])
def test_frame_is_the_same_whatever_the_threads(texels):
    """The eye lookups on the slot threads while pass 2 builds its cones and sheets on the calling
    thread alone (``start_eye_lookups``, ``calling_thread_only``) give the same V bits and
    statistics with one thread as with two (the texel marks are idempotent stores)."""
    import numba

    from softshadows.scene import builtin

    scene = builtin.build("bunny", "rect")
    old = numba.get_num_threads()
    runs = []
    try:
        for t in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(t)
            runs.append(ss.render(scene, "penumbra-map", 128, 96, texels=texels))
    finally:
        numba.set_num_threads(old)
    a, b = runs
    assert np.array_equal(a.visibility, b.visibility, equal_nan=True)
    assert ((a.visibility > 0.05) & (a.visibility < 0.95)).any()
    assert a.stats == b.stats


def test_an_error_while_the_lookups_run_leaves_the_threads_usable(monkeypatch):
    """An exception while pass 2 builds its cones (the eye lookups running on the slot threads)
    reaches the caller as itself, the thread count is restored, and the next frame renders the same
    V as before."""
    import numba

    from softshadows.scene import builtin

    scene = builtin.build("bunny", "sphere")
    want = ss.render(scene, "penumbra-map", 64, 48)
    threads = numba.get_num_threads()

    def broken(*a, **k):
        raise RuntimeError("cones")

    monkeypatch.setattr(P, "build_cones", broken)
    with pytest.raises(RuntimeError, match="cones"):
        ss.render(scene, "penumbra-map", 64, 48)
    monkeypatch.undo()
    assert numba.get_num_threads() == threads
    again = ss.render(scene, "penumbra-map", 64, 48)
    assert np.array_equal(again.visibility, want.visibility, equal_nan=True)
