"""coherent-raytrace (Agrawala et al. 2000, Sec. 5): the tracer's accelerations against the plain
hierarchical tracer ray by ray, the tracer against Embree, coherence-based sampling against tracing
every light cell, and V against closed forms and ground truth. Small images, 256^2 reference images."""

import numba
import numpy as np
import pytest

import softshadows as ss
from softshadows.methods import coherent_raytrace as cr
from softshadows.methods.ground_truth import build_embree_scene
from softshadows.scene import builtin

RES = 256  # reference depth images: small, so the tests stay fast (the method's default is 1024)


def _random_rays(scene, refs, n, seed):
    """n shadow rays from random visible surface points (eye-facing normal, the method's default
    origin offset in texels) to uniform random points of the rect light; also the Embree origins."""
    r = ss.render(scene, "hard", 64, 48)
    m = np.isfinite(r.visibility)
    pos, nrm = r.position[m], r.normal[m]
    rng = np.random.default_rng(seed)
    k = rng.integers(0, len(pos), n)
    eye = np.asarray(scene.camera.eye)
    nn = nrm[k] * np.sign(np.sum(nrm[k] * (eye - pos[k]), axis=1))[:, None]
    light = scene.light
    ab = rng.random((n, 2)) - 0.5
    dst = light.center + ab[:, :1] * light.u + ab[:, 1:] * light.v
    texel = refs.kpix[0] * np.abs((pos[k] - refs.vps[0, :3]) @ refs.vps[0, 9:12])
    offset = next(p.default for p in ss.methods()["coherent-raytrace"].params if p.name == "offset")
    org = pos[k] + offset * texel[:, None] * nn
    eps = 1e-4 * float(np.linalg.norm(np.ptp(scene.flat.vertices, axis=0)))  # ground truth's offset
    return org, dst, pos[k] + eps * nn


@pytest.fixture(scope="module", params=["bunny", "spheres"])
def traced(request):
    scene = ss.load_scene(request.param)
    refs = cr.ReferenceImages(scene, 4, RES, bias=1.0, gap=4.0, margin=0.02)
    org, dst, org_embree = _random_rays(scene, refs, 6000, seed=3)
    base, _, cnt = cr.trace_ray_batch(refs, org, dst, cr.F_BASELINE)
    return request.param, scene, refs, org, dst, org_embree, base, cnt


def test_exact_accelerations_leave_every_ray_unchanged(traced):
    name, _, refs, org, dst, _, base, cnt = traced
    # the test sees blocked rays (the fixture's scenes cast shadows on most of the image)
    assert 0.03 < base.mean() < 0.5, (name, base.mean())
    # no hierarchy at all (every pixel on the epipolar ray): the overlap test is exact
    linear, _, cl = cr.trace_ray_batch(refs, org, dst, 0)
    assert np.array_equal(linear, base), name
    assert cnt["leaves"] < cl["leaves"] / 10  # and it skips most of the leaves
    for flag in (cr.F_CLIP, cr.F_CONN, cr.F_RANK, cr.F_CLIP | cr.F_CONN | cr.F_RANK):
        b, _, c = cr.trace_ray_batch(refs, org, dst, cr.F_BASELINE | flag)
        assert np.array_equal(b, base), (name, flag, int((b != base).sum()))
        assert c["nodes"] <= cnt["nodes"], (name, flag)  # each one only removes work


def test_clear_miss_and_occlusion_intervals_change_a_bounded_fraction(traced):
    """Clear miss and occlusion intervals stop tracing a part of the ray that an earlier image saw
    in front of all geometry. On exact geometry that part cannot be blocked; with depth images a
    later image may still report a hit there: its floors-and-walls staircase (one texel, plus the
    bias) crosses the ray where the earlier image's does not. So the only possible change is
    blocked -> unblocked, for rays passing within about a texel of a surface. Measured at 256^2:
    <= 0.4% of the rays (plant, bunny, spheres); bound 1%."""
    name, _, refs, org, dst, _, base, _ = traced
    for flag in (cr.F_CLEAR, cr.F_INTERVALS, cr.F_CLEAR | cr.F_INTERVALS, cr.F_ALL):
        b, _, c = cr.trace_ray_batch(refs, org, dst, cr.F_BASELINE | flag)
        assert not np.any(b & ~base), (name, flag)  # never unblocked -> blocked
        changed = int((b != base).sum())
        assert changed <= 0.01 * len(b), (name, flag, changed)
        assert c["clear_misses"] > 0.5 * len(b)  # and most rays are decided by the first image


def test_single_rays_agree_with_embree(traced):
    """Disagreements come from the depth images' resolution (a blocker thinner than the gap/bias
    or a silhouette within a texel, the origin offset of a texel at contacts). Measured at
    256^2: 0.3% (bunny), 0.6% (spheres), 0.9% (plant); bound 2%."""
    name, scene, refs, org, dst, org_embree, _, _ = traced
    blocked, _, _ = cr.trace_ray_batch(refs, org, dst, cr.F_ALL)
    esc = build_embree_scene(scene.flat.vertices, scene.flat.faces[scene.flat.occluder])
    d = dst - org_embree
    dl = np.linalg.norm(d, axis=1)
    hits = esc.run(
        org_embree.astype(np.float32),
        (d / dl[:, None]).astype(np.float32),
        dists=(dl * (1 - 1e-6)).astype(np.float32),
        query="OCCLUDED",
    )
    emb = hits >= 0
    assert emb.mean() > 0.03
    assert np.mean(blocked != emb) <= 0.02, (name, np.mean(blocked != emb))


@pytest.fixture(scope="module")
def bunny_runs():
    scene = ss.load_scene("bunny")
    kw = dict(resolution=RES, seed=5)
    off = ss.render(scene, "coherent-raytrace", 80, 60, samples=256, coherence=False, **kw)
    on = ss.render(scene, "coherent-raytrace", 80, 60, samples=256, **kw)
    on4 = ss.render(scene, "coherent-raytrace", 80, 60, samples=1024, **kw)
    return off, on, on4


def test_coherence_changes_v_by_at_most_a_small_tolerance(bunny_runs):
    """Same jittered samples with and without coherence: V differs only where the prediction
    skipped a cell whose ray disagrees (a missed blocker or hole, Sec. 5.2.1). One cell is
    1/256 of V. Measured: mean 3e-5, worst pixel 2 cells. Bounds: mean 0.002, worst 0.05."""
    off, on, _ = bunny_runs
    m = np.isfinite(off.visibility)
    d = np.abs(off.visibility - on.visibility)[m]
    assert d.mean() <= 0.002 and d.max() <= 0.05, (d.mean(), d.max())
    # without coherence every cell is traced (or blocked by the point's own surface, self_sin)
    assert off.stats["rays_per_point"] + off.stats["self_blocked_per_point"] == pytest.approx(256)


def test_rays_per_point_below_half_and_sublinear(bunny_runs):
    """Paper: 79.86 and 88.74 rays of 256 (dragon, plant) and about 3x rays for 4x samples.
    Measured on bunny: 73 of 256, x2.5 for 1024."""
    _, on, on4 = bunny_runs
    r1, r4 = on.stats["rays_per_point"], on4.stats["rays_per_point"]
    assert r1 < 128, r1
    assert r4 < 4 * r1 * 0.9, (r1, r4)
    hist = on.stats["rays_per_point_hist"]
    assert sum(hist) == on.stats["points"]


def test_square_matches_closed_form():
    """Same bound as ground truth's at 256 samples (MAE 0.01); measured 0.0012 (ground truth 0.0011)."""
    scene = ss.load_scene("square")
    r = ss.render(scene, "coherent-raytrace", 64, 48, samples=256, resolution=RES, seed=1)
    pos = r.position.reshape(-1, 3)
    v = r.visibility.reshape(-1)
    g = np.isfinite(v) & (np.abs(pos[:, 1]) < 1e-4)
    assert g.sum() > 1000
    assert np.mean(np.abs(v[g] - builtin.square_visibility(pos[g]))) <= 0.01


@pytest.mark.parametrize("name", list(builtin.builtin_scenes()))
def test_v_finite_in_unit_interval_and_close_to_ground_truth(name):
    scene = ss.load_scene(name)
    r = ss.render(scene, "coherent-raytrace", 48, 36, samples=64, resolution=RES)
    g = ss.render(scene, "ground-truth", 48, 36, samples=64)
    m = np.isfinite(g.visibility)
    v = r.visibility[m]
    assert np.all(np.isfinite(v)) and v.min() >= 0.0 and v.max() <= 1.0
    assert np.array_equal(np.isfinite(r.visibility), m)
    # both are 64-sample estimates (noise ~0.02 per penumbra pixel, averaging down): MAE <= 0.02
    assert np.mean(np.abs(v - g.visibility[m])) <= 0.02, name


def test_sphere_light_is_rejected():
    with pytest.raises(ss.SoftShadowsError, match="rect"):
        ss.render(ss.load_scene("spheres", light="sphere"), "coherent-raytrace", 16, 16)


def test_output_independent_of_thread_count_and_precompute_cached():
    scene = ss.load_scene("spheres")
    kw = dict(samples=64, resolution=RES, seed=2)
    ss.render(scene, "coherent-raytrace", 48, 36, **kw)
    a = ss.render(scene, "coherent-raytrace", 48, 36, **kw)
    assert a.stats["precompute_reused"] and a.timings["precompute"] == 0.0  # built by the render before
    n = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        b = ss.render(scene, "coherent-raytrace", 48, 36, **kw)
    finally:
        numba.set_num_threads(n)
    assert np.array_equal(a.visibility, b.visibility, equal_nan=True)
    c = ss.render(scene.with_light(scene.light.scaled(1.5)), "coherent-raytrace", 48, 36, **kw)
    assert not c.stats["precompute_reused"] and c.timings["precompute"] > 0.0


def test_physical_irradiance_keeps_v_and_matches_ground_truth():
    scene = ss.load_scene("square")
    kw = dict(samples=64, seed=1)
    a = ss.render(scene, "coherent-raytrace", 48, 36, resolution=RES, **kw)
    b = ss.render(scene, "coherent-raytrace", 48, 36, resolution=RES, physical=True, **kw)
    g = ss.render(scene, "ground-truth", 48, 36, physical=True, **kw)
    assert np.array_equal(a.visibility, b.visibility, equal_nan=True)
    # same samples, same formula: the totals agree to the V error (measured 0.4%); bound 2%
    assert abs(np.nansum(b.image) / np.nansum(g.image) - 1.0) < 0.02
    assert not np.allclose(np.nan_to_num(a.image), np.nan_to_num(b.image), rtol=0.02)
