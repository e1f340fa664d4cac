"""The OpenGL (llvmpipe) peer, ``softshadows.peer`` (issue 16): its ``pcss`` frame computes our
``pcss`` V at the defaults in GLSL, its shaded frames our shading of that V, and several peers
share one process. Skipped, with the reason printed, where moderngl or a GL 3.3 context is
missing (the peer is the optional ``[peer]`` extra; the ``hard`` frame is also checked by
``test_triangle_sweep.py``)."""

from __future__ import annotations

import numpy as np
import pytest

import softshadows as ss
from softshadows.peer import agreement, dv_stats, make_peer, method_defaults, peer_params, shading_agreement

W, H = 128, 96


def _peer(scene, method, shade=None):
    p = method_defaults(method)
    gl, why = make_peer(
        scene, W, H, p["map_size"], p["bias"], p["slope_bias"], method=method, shade=shade, **peer_params(method)
    )
    if gl is None:
        print(f"SKIP GL peer test: {why}")
        pytest.skip(why)
    return gl


@pytest.mark.parametrize("light", ["rect", "sphere"])
def test_gl_pcss_agrees_with_ours(light):
    scene = ss.load_scene("bunny", light)
    gl = _peer(scene, "pcss")
    try:
        v_gl = gl.frame()
    finally:
        gl.release()
    v = ss.render(scene, "pcss", W, H).visibility
    disagree, cover, n = agreement(v, v_gl, 0.02)
    mean_dv, _max_dv = dv_stats(v, v_gl)
    assert n > 0.4 * W * H and cover == 0.0
    # float32 (GL) against float64 (ours) on the same float32 map: rounding of the weights and radii
    # (~1e-5) everywhere, a discrete flip of a tap (~1/16) on isolated pixels only
    assert disagree < 0.005, disagree
    assert mean_dv < 1e-3, mean_dv
    assert np.any((v_gl > 0.05) & (v_gl < 0.95)), "no penumbra in the GL frame"


def test_peers_share_a_process():
    """Each frame makes its own context current: a hard and a pcss peer rendered alternately give
    the V each gives alone."""
    scene = ss.load_scene("bunny", "rect")
    hard = _peer(scene, "hard")
    v_hard = hard.frame()
    pcss = _peer(scene, "pcss")
    try:
        v_pcss = pcss.frame()
        assert np.array_equal(hard.frame(), v_hard, equal_nan=True)
        assert np.array_equal(pcss.frame(), v_pcss, equal_nan=True)
        assert agreement(ss.render(scene, "hard", W, H).visibility, v_hard)[0] < 0.005
    finally:
        hard.release()
        pcss.release()


@pytest.mark.parametrize(
    "method,light,shade", [("hard", "rect", "float"), ("hard", "sphere", "rgba8"), ("pcss", "sphere", "float"),
                           ("pcss", "rect", "rgba8")]
)  # fmt: skip
def test_shaded_gl_frame_is_our_shading_of_its_v(method, light, shade):
    """A shaded GL frame (forward for ``hard``, deferred for ``pcss``) has the V of the V-only
    frame, bit for bit (the same shader code before the colour), and its colour is our
    ``shading.shade`` of that V: float32 within 1e-4 relative (float32 GLSL against float64 on
    float32 inputs: ~1e-6), 8-bit within one step of ours clamped to [0, 1] (its rounding is half
    a step), on all but 1 % of the pixels (measured: 0.02-0.05 % here, 3-5 of ~10k; crease and
    silhouette pixels where the two rasterizers keep a different nearest triangle, so another
    normal). Black where no surface, as ours."""
    scene = ss.load_scene("bunny", light)
    plain, shaded = _peer(scene, method), _peer(scene, method, shade=shade)
    try:
        v = plain.frame()
        v_sh = shaded.frame()
        img = shaded.image
    finally:
        plain.release()
        shaded.release()
    assert np.array_equal(v_sh, v, equal_nan=True)
    assert img.dtype == (np.float32 if shade == "float" else np.uint8)
    off, n = shading_agreement(scene, v_sh, img)
    assert n > 0.4 * W * H and off < 0.01, off
    assert img.shape == (H, W, 3) and np.all(img[np.isnan(v_sh)] == 0)
    lit = (v_sh == 1.0) & (img.max(axis=2) > 0)
    assert lit.sum() > 0.2 * W * H  # (the colour is written, not only V)


def test_shade_kind_is_checked():
    with pytest.raises(ValueError, match="shade must be one of"):
        _peer(ss.load_scene("square", "rect"), "hard", shade="rgb16")


def test_peer_params_are_pcss_defaults():
    assert peer_params("hard") == {}
    assert peer_params("pcss") == {"search_samples": 16, "filter_samples": 16, "pattern": "poisson"}
    p = method_defaults("pcss") | {"search_samples": 8}
    assert peer_params("pcss", p)["search_samples"] == 8  # the parameters given, not the defaults
    with pytest.raises(ValueError, match="rotate off"):
        peer_params("pcss", p | {"rotate": True})
    with pytest.raises(ValueError, match="without PCF"):
        peer_params("hard", method_defaults("hard") | {"pcf": 2})


def test_make_peer_without_gl_says_why(monkeypatch):
    import softshadows.peer as peer_mod

    monkeypatch.setattr(peer_mod, "unavailable", lambda: "moderngl is not installed (pip install -e '.[peer]')")
    gl, why = peer_mod.make_peer(ss.load_scene("square", "rect"), 16, 16, 64, 1.0, 1.0, method="pcss")
    assert gl is None and why == "moderngl is not installed (pip install -e '.[peer]')"


def test_make_peer_without_a_context_says_why(monkeypatch):
    moderngl = pytest.importorskip("moderngl")

    def no_egl(**kw):
        raise RuntimeError("eglGetDisplay failed\nmore")

    monkeypatch.setattr(moderngl, "create_standalone_context", no_egl)
    for method in ("hard", "pcss"):
        gl, why = make_peer(ss.load_scene("square", "rect"), 16, 16, 64, 1.0, 1.0, method=method)
        assert gl is None and why == "cannot create an OpenGL context: eglGetDisplay failed"
