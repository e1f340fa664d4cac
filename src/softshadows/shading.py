"""Shading, kept apart from visibility (DESIGN.md): image = unshadowed direct light x V + ambient.

Unshadowed direct light at p with normal n, from the light's center c:
    albedo * intensity * max(0, n.l) * max(0, -l.n_L) / r^2        (rect: the light's cosine too)
    albedo * intensity * max(0, n.l) / r^2                          (sphere)
with l = (c - p)/r. Normals are flipped to face the eye (two-sided surfaces). Ground truth's
``physical`` mode supplies its own per-pixel irradiance instead (the full area integral).
"""
from __future__ import annotations

import numpy as np
from PIL import Image

AMBIENT = 0.04


def facing_normals(normal: np.ndarray, position: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """Flip normals (..,3) so they face the eye."""
    d = eye - position
    s = np.sign(np.einsum("...k,...k->...", normal, d))
    s[s == 0] = 1.0
    return normal * s[..., None]


def unshadowed(light, position: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Unshadowed direct irradiance-like term (H,W) (without albedo); NaN stays NaN."""
    d = light.center - position
    r2 = np.einsum("...k,...k->...", d, d)
    r = np.sqrt(r2)
    ldir = d / r[..., None]
    cos_p = np.clip(np.einsum("...k,...k->...", normal, ldir), 0.0, None)
    term = light.intensity * cos_p / r2
    if light.shape == "rect":
        cos_l = np.clip(-(ldir @ light.normal), 0.0, None)
        term = term * cos_l
    return term


def shade(scene, gbuf, visibility: np.ndarray, shadowed: np.ndarray | None = None) -> np.ndarray:
    """Linear RGB image (H,W,3) float32; background black. ``shadowed``: (H,W) direct light that
    already includes visibility (ground truth's physical mode); otherwise unshadowed x V."""
    H, W = visibility.shape
    img = np.zeros((H, W, 3), np.float32)
    m = gbuf.mask
    if not m.any():
        return img
    flat = scene.flat
    tri = gbuf.tri_id[m]
    albedo = flat.albedo[flat.mesh_id[tri]]
    if shadowed is None:
        pos = gbuf.position[m].astype(np.float64)
        nrm = facing_normals(gbuf.normal[m].astype(np.float64), pos, scene.camera.eye)
        # normalized so that a point straight below the light at its height above the ground reads ~1
        direct = unshadowed(scene.light, pos, nrm) * _exposure(scene)
        lit = direct * np.nan_to_num(visibility[m], nan=0.0)
    else:
        lit = np.nan_to_num(shadowed[m], nan=0.0)
    img[m] = (albedo * lit[:, None] + AMBIENT * albedo).astype(np.float32)
    return img


def _exposure(scene) -> float:
    """Scale so that the brightest unshadowed receiver is about 1 (scene-independent look)."""
    lo, hi = scene.bounds()
    ground_y = lo[1]
    h = max(scene.light.center[1] - ground_y, 1e-6)
    return h * h / scene.light.intensity if scene.light.intensity > 0 else 1.0


def exposure(scene) -> float:
    return _exposure(scene)


def to_srgb8(img: np.ndarray) -> np.ndarray:
    """Linear float RGB -> tone-mapped (clamp) sRGB uint8."""
    x = np.clip(np.nan_to_num(img, nan=0.0), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (np.clip(s, 0, 1) * 255 + 0.5).astype(np.uint8)


def save_png(path, img: np.ndarray) -> None:
    Image.fromarray(to_srgb8(img)).save(str(path))


def visibility_to_rgb(v: np.ndarray) -> np.ndarray:
    """V as a grey image (linear values written directly as display values), background dark blue."""
    out = np.empty(v.shape + (3,), np.float32)
    g = np.nan_to_num(v, nan=0.0)
    out[...] = g[..., None]
    out[np.isnan(v)] = (0.05, 0.05, 0.12)
    return out


def save_exr(path, channels: dict[str, np.ndarray]) -> None:
    """Write float32 channels (each (H,W)) to an OpenEXR file."""
    import OpenEXR

    chans = {k: np.ascontiguousarray(v.astype(np.float32)) for k, v in channels.items()}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, chans) as f:
        f.write(str(path))


def load_exr(path) -> dict[str, np.ndarray]:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        return {k: np.array(c.pixels) for k, c in f.channels().items()}
