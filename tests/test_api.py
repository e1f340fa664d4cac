"""The shared interface: every method on every built-in scene and light shape."""

import numpy as np
import pytest

import softshadows as ss
from softshadows.scene.builtin import BUILTIN

# the ground truth is tested in test_ground_truth.py; here it runs with few samples to stay fast
FAST = {
    "ground-truth": {"samples": 4},
    "layered-attenuation": {"samples": 16, "ldi_size": 128},
    "coherent-raytrace": {"samples": 16, "resolution": 256},
}

#: non-default settings each method must also keep finite and in [0,1] (its other code paths)
VARIANTS = {
    "penumbra-map": [{"map_size": 192}],
    "soft-shadow-map": [{"ssm_size": 64}, {"two_pass": True, "accumulate": "float16", "map_size": 64, "ssm_size": 64}],
    "occlusion-textures": [
        {"filter": "mipmap", "combine": "sum", "leak_fix": True, "texture_size": 64, "slices": 4},
        {"filter": "sat", "combine": "max", "self_shadow": "include"},
    ],
}


def _cases():
    """(method, scene, light, params) for every registered method (new methods join automatically)."""
    out = []
    for name in ss.methods():
        for params in [FAST.get(name, {})] + VARIANTS.get(name, []):
            for scene_name in BUILTIN:
                for light in ("rect", "sphere"):
                    tag = ",".join(f"{k}={v}" for k, v in params.items()) or "defaults"
                    out.append(pytest.param(name, scene_name, light, params, id=f"{name}-{scene_name}-{light}-{tag}"))
    return out


@pytest.mark.parametrize(("name", "scene_name", "light", "params"), _cases())
def test_v_finite_in_unit_interval_nan_on_background_and_deterministic(name, scene_name, light, params):
    scene = ss.load_scene(scene_name, light=light)
    m = ss.methods()[name]
    if light not in m.light_shapes:
        with pytest.raises(ss.SoftShadowsError, match=name):
            ss.render(scene, name, 8, 8, **params)
        return
    a = ss.render(scene, name, 40, 30, seed=5, **params)
    v, mask = a.visibility, a.mask
    assert mask.sum() > 100
    assert np.all(np.isfinite(v[mask]))
    assert np.all(np.isnan(v[~mask]))
    assert v[mask].min() >= 0.0 and v[mask].max() <= 1.0
    assert np.all(np.isfinite(a.image))
    b = ss.render(scene, name, 40, 30, seed=5, **params)
    assert np.array_equal(a.visibility, b.visibility, equal_nan=True)


def test_unknown_method_and_parameter_name_the_valid_ones():
    scene = ss.load_scene("square")
    with pytest.raises(ValueError, match="ground-truth"):
        ss.render(scene, "nope", 8, 8)
    with pytest.raises(ValueError, match="map_size"):
        ss.render(scene, "hard", 8, 8, mapsize=3)
    with pytest.raises(ValueError, match="samples"):
        ss.render(scene, "ground-truth", 8, 8, samples="many")
    with pytest.raises(ValueError, match="width"):
        ss.render(scene, "hard", 0, 8)


def test_hard_shadow_matches_ground_truth_umbra_and_lit():
    """hard = a point light at the center: compare with ground truth from a tiny light."""
    scene = ss.load_scene("spheres")
    small = scene.with_light(scene.light.scaled(1e-3))
    gt = ss.render(small, "ground-truth", 64, 48, samples=1).visibility
    hd = ss.render(scene, "hard", 64, 48).visibility
    m = np.isfinite(gt)
    # silhouette pixels can differ by one shadow-map texel; everything else must agree
    assert np.mean(np.abs(gt[m] - hd[m])) < 0.03


def test_hard_eye_pass_over_the_gbuffer_is_the_per_point_test():
    """hard's lookup straight over the G-buffer's images (lookup_image) gives, bit for bit, the
    per-point test on the gathered points with eye-facing normals (lookup_points), with and
    without PCF: the bias uses |n.l|, so the normal's side does not matter."""
    from softshadows.methods.shadowmap import build_shadow_map, fit_light_view, lookup_points

    for name, light in (("bunny", "rect"), ("contact", "sphere")):
        scene = ss.load_scene(name, light=light)
        smap = build_shadow_map(scene, fit_light_view(scene, 256))
        for pcf in (0, 2):
            res = ss.render(scene, "hard", 64, 48, map_size=256, pcf=pcf)
            m = res.mask
            pts = res.position[m].astype(np.float64)
            nrm = res.normal[m].astype(np.float64)
            v = lookup_points(smap, pts, nrm, 1.0, 1.0, pcf)
            np.testing.assert_array_equal(res.visibility[m], v)
            np.testing.assert_array_equal(v, lookup_points(smap, pts, -nrm, 1.0, 1.0, pcf))
            assert np.isnan(res.visibility[~m]).all()
            assert 0 < (v < 1).sum() < len(v)  # both lit and shadowed pixels


def test_hard_pcf_softens_only_edges():
    scene = ss.load_scene("square")
    a = ss.render(scene, "hard", 64, 48).visibility
    b = ss.render(scene, "hard", 64, 48, pcf=2, map_size=256).visibility
    m = np.isfinite(a)
    assert set(np.unique(a[m])) <= {0.0, 1.0}
    frac = (b[m] > 0) & (b[m] < 1)
    assert frac.any() and frac.mean() < 0.2
