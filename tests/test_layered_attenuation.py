"""Layered attenuation maps (Agrawala et al. 2000): convergence on the analytic square, the LDI's
layers against the square's closed-form visibility, counts once per viewpoint, the precompute
reused by the display, V in [0, 1] and close to ground truth on every built-in scene."""

import numpy as np
import pytest

import softshadows as ss
from softshadows.errors import SoftShadowsError
from softshadows.geometry.light_samples import light_sample_points, stratified_jittered
from softshadows.methods import layered_attenuation as la
from softshadows.scene import Camera
from softshadows.scene.builtin import (
    BUILTIN,
    GROUND_SIZE,
    SQUARE_LIGHT_Y,
    SQUARE_OCCLUDER_SIDE,
    SQUARE_OCCLUDER_Y,
    square_visibility,
)

SMALL = dict(ldi_size=128, samples=16)


def _ground_mae(res) -> float:
    pos = res.position
    m = ~np.isnan(res.visibility) & (pos[..., 1] < 1e-4)
    return float(np.abs(res.visibility[m] - square_visibility(pos[m].astype(float))).mean())


def test_square_converges_to_closed_form():
    """More light samples, less error: the fixed N x N set quantizes V to steps of about 1/N per
    axis across the penumbra (banding). Measured at 96x72 with a 256^2 LDI: MAE 0.0123 (16),
    0.0069 (256); what remains is mostly the splat's lighter shadow edge (about one LDI pixel per
    sample; with a 128^2 LDI it dominates: 0.013 at any sample count), hence the 0.009 bound."""
    sc = ss.load_scene("square")
    e16 = _ground_mae(ss.render(sc, "layered-attenuation", 96, 72, samples=16, ldi_size=256))
    e256 = _ground_mae(ss.render(sc, "layered-attenuation", 96, 72, samples=256, ldi_size=256))
    assert e256 < 0.7 * e16, (e16, e256)
    assert e256 < 0.009, e256


def _square_expected_layers(ldi, offsets_px):
    """Per LDI pixel (shifted by ``offsets_px``): (occluder seen along the center ray, ground point
    under it seen from at least one of the LDI's light samples), from the square's geometry."""
    v = ldi.view
    H, W = v.height, v.width
    jj, ii = np.meshgrid(np.arange(W) + 0.5 + offsets_px[0], np.arange(H) + 0.5 + offsets_px[1])
    h = SQUARE_OCCLUDER_SIDE / 2
    d_occ = SQUARE_LIGHT_Y - SQUARE_OCCLUDER_Y  # depth of the occluder's plane from the light
    p_occ = v.unproject(jj, ii, np.full(jj.shape, d_occ))
    on_occ = (np.abs(p_occ[..., 0]) <= h) & (np.abs(p_occ[..., 2]) <= h)
    g = v.unproject(jj, ii, np.full(jj.shape, SQUARE_LIGHT_Y))  # the ground point (y = 0)
    t = SQUARE_OCCLUDER_Y / SQUARE_LIGHT_Y  # where the segment g -> sample crosses y = 1
    seen = np.zeros(jj.shape, bool)
    for s in ldi.sample_points:
        c = g + (s - g) * t
        seen |= ~((np.abs(c[..., 0]) <= h) & (np.abs(c[..., 2]) <= h))
    seen &= (np.abs(g[..., 0]) <= GROUND_SIZE / 2) & (np.abs(g[..., 2]) <= GROUND_SIZE / 2)
    return on_occ, seen


def test_square_depth_complexity():
    """Two layers (occluder, then ground) exactly where the ground under the occluder is seen
    from part of the light (its penumbra seen through the occluder's edge); one elsewhere; the
    ground in the umbra (hidden from every sample) is not stored. Pixels within 1.5 px of a
    boundary of the expected classes are skipped (the 2x2 splat and rasterization coverage)."""
    sc = ss.load_scene("square")
    ldi = la.precompute(sc, samples=16, ldi_size=256)  # the penumbra band under the occluder: ~8 px
    cls = []
    for off in [(dx, dy) for dx in (-1.5, 0, 1.5) for dy in (-1.5, 0, 1.5)]:
        occ, seen = _square_expected_layers(ldi, off)
        cls.append(occ * 2 + seen)
    cls = np.stack(cls)
    stable = (cls == cls[4]).all(axis=0).reshape(-1)
    expected = (cls[4] // 2 + cls[4] % 2).reshape(-1)  # occluder and/or ground seen
    umbra = (cls[4] == 2).reshape(-1) & stable
    pen = (cls[4] == 3).reshape(-1) & stable
    assert umbra.sum() > 500 and pen.sum() > 300, (umbra.sum(), pen.sum())
    n = ldi.nlayers
    bad = stable & (n != expected)
    assert bad.sum() == 0, f"{bad.sum()} of {stable.sum()} pixels have the wrong number of layers"
    # umbra: the one layer is the occluder (depth 2), no ground layer (depth 3) at all
    d = ldi.depth
    assert np.allclose(d[0, umbra], SQUARE_LIGHT_Y - SQUARE_OCCLUDER_Y, atol=1e-3)
    assert np.allclose(d[0, pen], SQUARE_LIGHT_Y - SQUARE_OCCLUDER_Y, atol=1e-3)
    assert np.allclose(d[1, pen], SQUARE_LIGHT_Y, atol=1e-3)
    st = ldi.stats()
    assert st["ldi_max_layers"] == 2 and st["ldi_total_layers"] == int(n.sum())
    # the Fig. 10 curve: grows as samples see more of the occluder's penumbra, ends at the LDI's value
    # (one view alone has about one layer per pixel: two only where the 2x2 splats of an edge overlap)
    c = ldi.complexity
    assert c[0] < 1.02 and c[-1] > c[0] + 0.005 and c[-1] == pytest.approx(st["ldi_avg_depth_complexity"])


def test_counts_once_per_viewpoint():
    """Every layer is incremented at most once per light sample, although the 2x2 splat touches
    each pixel up to 4 times per view: no count exceeds the samples, and the layers seen from
    every sample (the occluder's interior, lit ground far from the shadow) reach exactly N."""
    sc = ss.load_scene("square")
    ldi = la.precompute(sc, samples=16, ldi_size=128)
    assert ldi.count.max() == 16
    v = ldi.view
    jj, ii = np.meshgrid(np.arange(v.width) + 0.5, np.arange(v.height) + 0.5)
    g = v.unproject(jj, ii, np.full(jj.shape, SQUARE_LIGHT_Y))
    ag = np.abs(g)
    # penumbra ends at 1.0; the ground at 4.0 (its edge is seen from part of the light)
    far = (((ag[..., 0] > 1.3) | (ag[..., 2] > 1.3)) & (ag[..., 0] < 3.8) & (ag[..., 2] < 3.8)).reshape(-1)
    far &= (ldi.nlayers == 1) & np.isfinite(ldi.depth[0])
    assert far.sum() > 1000
    assert np.all(ldi.count[0, far] == 16)
    inner = (np.abs(g[..., 0]) < 0.3 * 1.5) & (np.abs(g[..., 2]) < 0.3 * 1.5)  # occluder interior
    assert np.all(ldi.count[0, inner.reshape(-1)] == 16)


def test_projective_warp_matches_disparity():
    """Eq. 3 (disparity) and the general reprojection give the same LDI up to float rounding at
    splat boundaries (the views are parallel)."""
    sc = ss.load_scene("spheres")
    a = la.precompute(sc, warp="disparity", **SMALL)
    b = la.precompute(sc, warp="projective", **SMALL)
    same = (a.nlayers == b.nlayers) & np.all(a.count == b.count, axis=0)
    assert same.mean() > 0.995, same.mean()
    both = np.isfinite(a.depth) & np.isfinite(b.depth) & same[None, :]
    assert np.abs(a.depth[both] - b.depth[both]).max() < 1e-3


def test_display_reuses_precompute():
    """Two cameras, one precompute: the same V, bit for bit, as two full renders, and the
    precompute phase is 0 when reused."""
    sc = ss.load_scene("bunny")
    cam_b = Camera((-1.5, 2.5, 2.0), (0.0, 0.4, 0.0), (0.0, 1.0, 0.0), 45.0)
    scenes = [sc, sc.with_camera(cam_b)]
    la.clear_cache()
    ldi = la.precompute(sc, **SMALL)
    shown = [la.display(ldi, s, 64, 48) for s in scenes]
    full = []
    for s in scenes:
        la.clear_cache()
        full.append(ss.render(s, "layered-attenuation", 64, 48, warmup=False, **SMALL))
    for d, f in zip(shown, full, strict=True):
        assert d.timings["precompute"] == 0.0 and d.stats["ldi_reused"]
        assert f.timings["precompute"] > 0.0 and not f.stats["ldi_reused"]
        np.testing.assert_array_equal(d.visibility, f.visibility)
    assert not np.array_equal(np.isnan(shown[0].visibility), np.isnan(shown[1].visibility))
    # render() reuses it too while geometry, light and precompute parameters are unchanged ...
    r = ss.render(scenes[1], "layered-attenuation", 64, 48, **SMALL)
    assert r.timings["precompute"] == 0.0
    # ... and not when one of them changes
    r = ss.render(scenes[1], "layered-attenuation", 64, 48, warmup=False, epsilon=3.0, **SMALL)
    assert r.timings["precompute"] > 0.0
    r = ss.render(scenes[1].with_light(sc.light.scaled(1.2)), "layered-attenuation", 64, 48, warmup=False, **SMALL)
    assert r.timings["precompute"] > 0.0
    with pytest.raises(SoftShadowsError, match="differs"):
        la.display(ldi, ss.load_scene("square"), 64, 48)


# MAE against ground truth (both 16 samples, 64x48, 128^2 LDI), measured on 2026-12-01. The bound
# is 1.5x: thread count does not change V (the LDI is built deterministically); the margin covers
# changes of the rasterizer's edge rules. The large ones are the paper's artifacts: the splat
# lightens thin-bar shadows (fence), faces oblique to the light are undersampled (contact; with
# the sphere light also the disk-facing-the-scene approximation).
MEASURED_MAE = {
    ("square", "rect"): 0.0134, ("square", "sphere"): 0.015,
    ("spheres", "rect"): 0.0229, ("spheres", "sphere"): 0.031,
    ("fence", "rect"): 0.0673, ("fence", "sphere"): 0.0645,
    ("contact", "rect"): 0.0467, ("contact", "sphere"): 0.0892,
    ("plant", "rect"): 0.0348, ("plant", "sphere"): 0.0349,
    ("bunny", "rect"): 0.0229, ("bunny", "sphere"): 0.0287,
}  # fmt: skip


@pytest.mark.parametrize("light", ["rect", "sphere"])
@pytest.mark.parametrize("name", list(BUILTIN))
def test_builtin_scenes_range_and_error(name, light):
    """V finite in [0, 1] on every built-in scene, with shadows, and near ground truth."""
    sc = ss.load_scene(name, light=light)
    r = ss.render(sc, "layered-attenuation", 64, 48, **SMALL)
    v = r.visibility[r.mask]
    assert np.all(np.isfinite(v)) and v.min() >= 0.0 and v.max() <= 1.0
    assert (v < 0.5).any() and (v > 0.99).any()
    gt = ss.render(sc, "ground-truth", 64, 48, samples=16).visibility[r.mask]
    assert np.abs(v - gt).mean() < 1.5 * MEASURED_MAE[name, light]


def test_stratified_samples():
    ab = stratified_jittered(4, seed=3)
    cells = np.floor(ab * 4).astype(int)
    assert len({(a, b) for a, b in cells}) == 16  # one point per cell
    np.testing.assert_array_equal(ab, stratified_jittered(4, seed=3))
    sc = ss.load_scene("square")
    p = light_sample_points(sc.light, 4, 3)
    assert np.allclose(p[:, 1], SQUARE_LIGHT_Y) and np.abs(p[:, [0, 2]]).max() <= 0.5


def test_bad_samples():
    with pytest.raises(SoftShadowsError, match="perfect square"):
        ss.render(ss.load_scene("square"), "layered-attenuation", 32, 24, samples=10)


def test_ldi_independent_of_thread_count():
    """The banded parallel insertion gives the same LDI with 1 thread (one band) as with more
    (bands per thread): each pixel's insertions happen in the same order."""
    import numba

    sc = ss.load_scene("plant")
    n0 = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = la.precompute(sc, **SMALL)
    finally:
        numba.set_num_threads(n0)
    b = la.precompute(sc, **SMALL)
    np.testing.assert_array_equal(a.nlayers, b.nlayers)
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_array_equal(a.depth, b.depth)
