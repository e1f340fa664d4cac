"""Error metrics of a method's visibility V against ground truth V_ref, and region masks.

Every metric ignores background pixels (NaN in V_ref, i.e. no surface). Errors are signed as
``V - V_ref``: negative = the method is darker (more shadow) than the truth, positive = brighter.

:func:`compute_metrics` returns a dict:

* ``mae``, ``rmse``, ``max`` (max |dV|), ``bias`` (mean signed error);
* ``ssm_error`` — the measure of the soft-shadow-maps paper (Atty et al. 2006, section 5.2.1):
  sum of |dV| divided by the number of pixels that are in umbra or penumbra in *either* image
  (V < 1 - eps or V_ref < 1 - eps), i.e. the mean error over the actual soft shadow rather than
  over the whole image, which small shadows would dilute;
* the error split by ground-truth region: ``mae_umbra`` (V_ref <= eps), ``mae_penumbra``
  (eps < V_ref < 1 - eps), ``mae_lit`` (V_ref >= 1 - eps), and ``bias_*`` likewise;
  ``n_pixels``, ``n_umbra``, ``n_penumbra``, ``n_lit``, ``n_shadow`` (the ``ssm_error`` set);
  a region without pixels gives NaN;
* ``flip`` — NVIDIA FLIP (``flip_evaluator``, LDR mode, default 67 pixels per degree) between the
  shaded images, tone-mapped to sRGB in [0, 1] exactly as the PNGs are written
  (``shading.to_srgb8``); the per-pixel FLIP map is averaged over surface pixels only. Present
  only when both images are given.

``mask`` (optional (H,W) bool) restricts every metric to those pixels. :func:`receiver_pixels`
gives the pixels whose surface has role ``receiver`` or ``both``: methods that by design shade only
receivers (``Method.receivers_only``, e.g. the soft shadow map: no self-shadowing, V = 1 on
occluder-only geometry) are reported over all surface pixels (their limit) *and* over receiver
pixels only (their quality where they apply), under ``metrics["receivers"]``.

``eps = 1e-3`` (:data:`EPS`): ground truth V is a multiple of 1/N for N light samples (256 by
default, up to 1000 still resolves), so eps below 1/N makes "umbra" mean *no* sample reaches the
light and "lit" mean *every* sample does, while absorbing float32 rounding.
"""

from __future__ import annotations

import numpy as np

EPS = 1e-3


def _as2d(v, name):
    a = np.asarray(v, dtype=np.float64)
    if a.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array, got shape {a.shape}")
    return a


def region_masks(v_ref, eps: float = EPS) -> dict:
    """Boolean (H,W) masks of the ground-truth regions: ``umbra``, ``penumbra``, ``lit``, and
    ``surface`` (all non-background pixels)."""
    r = _as2d(v_ref, "v_ref")
    surf = np.isfinite(r)
    rr = np.where(surf, r, 0.5)
    umbra = surf & (rr <= eps)
    lit = surf & (rr >= 1.0 - eps)
    return {"umbra": umbra, "penumbra": surf & ~umbra & ~lit, "lit": lit, "surface": surf}


def signed_error_map(v, v_ref) -> np.ndarray:
    """(H,W) float32 ``V - V_ref``, NaN on background (or where either is not finite)."""
    a = _as2d(v, "v")
    r = _as2d(v_ref, "v_ref")
    if a.shape != r.shape:
        raise ValueError(f"shape mismatch: v {a.shape} vs v_ref {r.shape}")
    with np.errstate(invalid="ignore"):
        d = a - r
    d[~(np.isfinite(a) & np.isfinite(r))] = np.nan
    return d.astype(np.float32)


def _mean(x) -> float:
    return float(x.mean()) if x.size else float("nan")


def flip_error(image, image_ref, mask=None) -> float:
    """Mean FLIP (LDR) between two linear RGB images (H,W,3), tone-mapped like the PNGs, over
    ``mask`` pixels (all if None)."""
    import flip_evaluator

    from .shading import to_srgb8

    test = to_srgb8(np.asarray(image, np.float32)).astype(np.float32) / 255.0
    ref = to_srgb8(np.asarray(image_ref, np.float32)).astype(np.float32) / 255.0
    if test.shape != ref.shape:
        raise ValueError(f"shape mismatch: image {test.shape} vs image_ref {ref.shape}")
    fmap, _, _ = flip_evaluator.evaluate(
        np.ascontiguousarray(ref), np.ascontiguousarray(test), "LDR", applyMagma=False, computeMeanError=False
    )
    fmap = np.asarray(fmap, np.float64)
    if fmap.ndim == 3:
        fmap = fmap[..., 0]
    if mask is not None and mask.any():
        return float(fmap[mask].mean())
    return float(fmap.mean())


def receiver_pixels(scene, width: int, height: int) -> np.ndarray:
    """(H,W) bool: eye pixels whose surface is a face of role ``receiver`` or ``both``."""
    from .api import eye_view
    from .raster import rasterize

    flat = scene.flat
    g = rasterize(eye_view(scene, width, height), flat.vertices, flat.faces, cull="none")
    return g.mask & flat.receiver[np.maximum(g.tri_id, 0)]


def compute_metrics(v, v_ref, image=None, image_ref=None, eps: float = EPS, mask=None) -> dict:
    """All metrics of ``v`` against ``v_ref`` (see the module docstring); over the ``mask``
    pixels only when given."""
    r = _as2d(v_ref, "v_ref")
    a = _as2d(v, "v")
    if mask is not None:
        m = np.asarray(mask, bool)
        if m.shape != r.shape:
            raise ValueError(f"shape mismatch: mask {m.shape} vs v_ref {r.shape}")
        r = np.where(m, r, np.nan)
        a = np.where(m, a, np.nan)
    d = signed_error_map(a, r)
    masks = region_masks(r, eps)
    surf = masks["surface"]
    valid = np.isfinite(d)
    ad = np.abs(d)
    out: dict = {}
    dv = d[valid].astype(np.float64)
    adv = ad[valid].astype(np.float64)
    out["n_pixels"] = int(valid.sum())
    out["n_nonfinite"] = int((surf & ~np.isfinite(a)).sum())  # method produced NaN/inf on a surface
    out["mae"] = _mean(adv)
    out["rmse"] = float(np.sqrt((dv * dv).mean())) if dv.size else float("nan")
    out["max"] = float(adv.max()) if adv.size else float("nan")
    out["bias"] = _mean(dv)
    with np.errstate(invalid="ignore"):
        shadow = valid & ((r < 1.0 - eps) | (a < 1.0 - eps))
    out["n_shadow"] = int(shadow.sum())
    out["ssm_error"] = float(ad[shadow].sum() / shadow.sum()) if shadow.any() else float("nan")
    for reg in ("umbra", "penumbra", "lit"):
        m = masks[reg] & valid
        out[f"n_{reg}"] = int(m.sum())
        out[f"mae_{reg}"] = _mean(ad[m].astype(np.float64))
        out[f"bias_{reg}"] = _mean(d[m].astype(np.float64))
    out["eps"] = float(eps)
    if image is not None and image_ref is not None:
        out["flip"] = flip_error(image, image_ref, surf)
    return out


# Metric keys shown in tables, in order, with a one-line meaning.
METRIC_HELP = {
    "mae": "mean |V - V_ref| over surface pixels",
    "rmse": "root mean square of V - V_ref",
    "max": "max |V - V_ref|",
    "bias": "mean V - V_ref (negative: darker than truth)",
    "ssm_error": "sum |dV| / #pixels in umbra or penumbra of either image (Atty et al. 2006)",
    "mae_umbra": "mean |dV| where V_ref = 0",
    "mae_penumbra": "mean |dV| where 0 < V_ref < 1",
    "mae_lit": "mean |dV| where V_ref = 1",
    "flip": "NVIDIA FLIP (LDR) between the shaded images, surface pixels",
}
