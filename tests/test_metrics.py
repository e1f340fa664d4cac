"""Metrics on small synthetic arrays with hand-computed values."""

import numpy as np
import pytest

from softshadows.metrics import EPS, compute_metrics, flip_error, region_masks, signed_error_map

NAN = np.nan


def _arrays():
    # ground truth: row 0 = umbra, penumbra, lit, background; row 1 = lit, lit, penumbra, umbra
    ref = np.array([[0.0, 0.5, 1.0, NAN], [1.0, 1.0, 0.25, 0.0]], np.float32)
    v = np.array([[0.1, 0.3, 1.0, NAN], [1.0, 0.6, 0.25, 0.0]], np.float32)
    return v, ref


def test_region_masks_by_hand():
    _, ref = _arrays()
    m = region_masks(ref)
    assert m["umbra"].tolist() == [[True, False, False, False], [False, False, False, True]]
    assert m["penumbra"].tolist() == [[False, True, False, False], [False, False, True, False]]
    assert m["lit"].tolist() == [[False, False, True, False], [True, True, False, False]]
    assert m["surface"].sum() == 7
    # eps: values within EPS of 0 or 1 count as umbra / lit, values just beyond do not
    m2 = region_masks(np.array([[EPS / 2, 1 - EPS / 2, 2 * EPS]]))
    assert m2["umbra"].tolist() == [[True, False, False]]
    assert m2["lit"].tolist() == [[False, True, False]]
    assert m2["penumbra"].tolist() == [[False, False, True]]


def test_signed_error_map_sign_and_background():
    v, ref = _arrays()
    d = signed_error_map(v, ref)
    assert np.isnan(d[0, 3])
    np.testing.assert_allclose(d[0, :3], [0.1, -0.2, 0.0], atol=1e-6)  # negative = darker than truth
    np.testing.assert_allclose(d[1], [0.0, -0.4, 0.0, 0.0], atol=1e-6)


def test_compute_metrics_hand_values():
    v, ref = _arrays()
    m = compute_metrics(v, ref)
    # 7 surface pixels, errors: +0.1, -0.2, 0, 0, -0.4, 0, 0
    assert m["n_pixels"] == 7
    assert m["mae"] == pytest.approx(0.7 / 7, abs=1e-6)
    assert m["rmse"] == pytest.approx(np.sqrt((0.01 + 0.04 + 0.16) / 7), abs=1e-6)
    assert m["max"] == pytest.approx(0.4, abs=1e-6)
    assert m["bias"] == pytest.approx(-0.5 / 7, abs=1e-6)
    # umbra or penumbra in either image: (0,0) (0,1) (1,1: V=0.6) (1,2) (1,3) -> 5 pixels, sum |d| = 0.7
    assert m["n_shadow"] == 5
    assert m["ssm_error"] == pytest.approx(0.7 / 5, abs=1e-6)
    # by ground-truth region
    assert (m["n_umbra"], m["n_penumbra"], m["n_lit"]) == (2, 2, 3)
    assert m["mae_umbra"] == pytest.approx(0.05, abs=1e-6)  # 0.1 and 0
    assert m["mae_penumbra"] == pytest.approx(0.1, abs=1e-6)  # 0.2 and 0
    assert m["mae_lit"] == pytest.approx(0.4 / 3, abs=1e-6)  # 0, 0.4, 0
    assert m["bias_lit"] == pytest.approx(-0.4 / 3, abs=1e-6)
    assert "flip" not in m


def test_identical_is_zero_and_empty_region_is_nan():
    ref = np.array([[1.0, 1.0], [NAN, 1.0]])
    m = compute_metrics(ref.copy(), ref)
    assert m["mae"] == 0 and m["max"] == 0 and m["bias"] == 0
    assert m["n_shadow"] == 0 and np.isnan(m["ssm_error"])
    assert np.isnan(m["mae_umbra"]) and m["n_umbra"] == 0


def test_nonfinite_method_pixels_are_counted():
    ref = np.array([[0.5, 1.0]])
    v = np.array([[NAN, 1.0]])
    m = compute_metrics(v, ref)
    assert m["n_nonfinite"] == 1 and m["n_pixels"] == 1


def _image(seed=0, h=40, w=48):
    rng = np.random.default_rng(seed)
    _y, x = np.mgrid[0:h, 0:w]
    base = 0.5 + 0.4 * np.sin(x / 5.0)[..., None] * np.array([1.0, 0.8, 0.6])
    return np.clip(base + 0.02 * rng.standard_normal((h, w, 3)), 0, 1).astype(np.float32)


def test_flip_self_zero_and_grows_with_perturbation():
    img = _image()
    assert flip_error(img, img) == pytest.approx(0.0, abs=1e-7)
    small = np.clip(img * 0.95, 0, 1)
    large = np.clip(img * 0.6, 0, 1)
    f_small, f_large = flip_error(small, img), flip_error(large, img)
    assert 0.0 < f_small < f_large
    # through compute_metrics, with a background mask
    v = np.ones(img.shape[:2])
    v[:, :4] = np.nan
    assert compute_metrics(v, v, img, img)["flip"] == pytest.approx(0.0, abs=1e-7)
    assert compute_metrics(v, v, large, img)["flip"] > 0.01


def test_shape_mismatch_raises():
    with pytest.raises(ValueError):
        compute_metrics(np.zeros((2, 2)), np.zeros((2, 3)))


def test_mask_restricts_every_metric():
    v_ref = np.array([[0.0, 0.5, 1.0], [1.0, np.nan, 0.2]])
    v = np.array([[0.1, 0.5, 0.7], [1.0, 0.3, 0.2]])
    mask = np.array([[True, True, False], [False, True, True]])
    m = compute_metrics(v, v_ref, mask=mask)
    # masked pixels with a surface: (0,0) err +0.1, (0,1) 0, (1,2) 0; (1,1) is background
    assert m["n_pixels"] == 3
    assert m["mae"] == pytest.approx(0.1 / 3)
    assert m["max"] == pytest.approx(0.1)
    assert m["n_umbra"] == 1 and m["n_lit"] == 0 and m["n_penumbra"] == 2
    full = compute_metrics(v, v_ref)
    assert full["max"] == pytest.approx(0.3) and full["n_pixels"] == 5


def test_receiver_pixels_are_the_receiver_faces():
    import softshadows as ss
    from softshadows.metrics import receiver_pixels

    sc = ss.load_scene("square")  # ground: receiver; square: occluder
    rec = receiver_pixels(sc, 48, 36)
    r = ss.render(sc, "hard", 48, 36)
    pos = r.position.reshape(-1, 3)[rec.ravel()]
    assert rec.sum() > 500 and np.all(np.abs(pos[:, 1]) < 1e-5)  # exactly the ground's pixels
    on_square = r.mask & ~rec
    assert on_square.sum() > 20
    assert np.allclose(r.position[on_square][:, 1], 1.0, atol=1e-5)
