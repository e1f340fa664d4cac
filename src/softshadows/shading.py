"""Shading, kept apart from visibility (docs/design.md): image = unshadowed direct light x V + ambient.

Unshadowed direct light at p with normal n, from the light's center c:
    albedo * intensity * max(0, n.l) * max(0, -l.n_L) / r^2        (rect: the light's cosine too)
    albedo * intensity * max(0, n.l) / r^2                          (sphere)
with l = (c - p)/r. Normals are flipped to face the eye (two-sided surfaces). Ground truth's
``physical`` mode supplies its own per-pixel irradiance instead (the full area integral).
"""

from __future__ import annotations

import numpy as np
from PIL import Image

from ._jit import kernel, run_threads

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
    flat = scene.flat
    light = scene.light
    rect = light.shape == "rect"
    ln = light.normal if rect else np.zeros(3)
    albedo = flat.albedo.astype(np.float32)  # per mesh (a per-triangle table would grow with the triangles)
    use_shadowed = shadowed is not None
    sh = np.asarray(shadowed, np.float64) if use_shadowed else np.zeros((1, 1))
    img = np.empty(visibility.shape + (3,), np.float32)
    run_threads(
        _shade_slot,
        gbuf.position,
        gbuf.normal,
        gbuf.tri_id,
        visibility,
        albedo,
        flat.mesh_id,
        np.asarray(light.center, np.float64),
        ln,
        rect,
        light.intensity * _exposure(scene),
        np.asarray(scene.camera.eye, np.float64),
        AMBIENT,
        use_shadowed,
        sh,
        img,
    )
    return img


@kernel(nogil=True)
def _shade_slot(
    slot,
    position,
    normal,
    tri_id,
    vis,
    albedo,
    mesh_id,
    c,
    ln,
    rect,
    scale,
    eye,
    ambient,
    use_shadowed,
    shadowed,
    img,
    nslot,
):
    """The image ``img`` (H,W,3), row by row: the direct light of the row's pixels into scratch (the
    positions and normals first copied to one float64 array per coordinate; no branch, selects
    instead: LLVM vectorizes it), then each pixel's mesh (-1 where no surface, ``tri_id`` < 0), then
    the colours (black where no surface; the mesh lookup in a loop of its own: 1.3x). Every value is
    the same expression as a per-pixel loop's, so the same bits; 2x-2.5x faster than that loop. Run
    by ``run_slots``: slot ``slot`` of ``nslot`` takes the slot-th of ``nslot`` contiguous blocks of
    rows (every nslot-th row instead took a third more CPU time with two slots)."""
    H, W = vis.shape
    sc = np.empty((7, W))  # x, y, z, nx, ny, nz, then the direct light
    mid = np.empty(W, np.int64)  # the pixel's mesh, -1 where no surface
    # the light's normal read before the loops: LLVM then selects instead of branching on ``rect``
    # and vectorizes the direct light (loaded inside ``if rect``, the loop stayed scalar: 2x slower)
    ln0, ln1, ln2 = ln[0], ln[1], ln[2]
    for i in range(H * slot // nslot, H * (slot + 1) // nslot):
        if use_shadowed:
            for j in range(W):
                lit = shadowed[i, j]
                sc[6, j] = lit if np.isfinite(lit) else 0.0
        else:
            for j in range(W):
                for k in range(3):
                    sc[k, j] = position[i, j, k]
                    sc[3 + k, j] = normal[i, j, k]
            for j in range(W):
                px, py, pz = sc[0, j], sc[1, j], sc[2, j]
                nx, ny, nz = sc[3, j], sc[4, j], sc[5, j]
                # the normal turned toward the eye (a sign: the same products as negated components)
                f = -1.0 if nx * (eye[0] - px) + ny * (eye[1] - py) + nz * (eye[2] - pz) < 0.0 else 1.0
                dx, dy, dz = c[0] - px, c[1] - py, c[2] - pz
                r2 = dx * dx + dy * dy + dz * dz
                r = np.sqrt(r2)
                cp = ((f * nx) * dx + (f * ny) * dy + (f * nz) * dz) / r
                cp = 0.0 if cp < 0.0 else cp
                if rect:
                    cl = -(ln0 * dx + ln1 * dy + ln2 * dz) / r
                    cl = 0.0 if cl < 0.0 else cl
                    cp *= cl
                v = vis[i, j]
                v = v if np.isfinite(v) else 0.0
                sc[6, j] = scale * cp / r2 * v
        for j in range(W):
            t = tri_id[i, j]
            mid[j] = mesh_id[t if t >= 0 else 0] if t >= 0 else -1
            sc[6, j] += ambient
        for j in range(W):
            m = mid[j]
            for ch in range(3):
                x = albedo[m if m >= 0 else 0, ch] * sc[6, j]
                img[i, j, ch] = x if m >= 0 else 0.0


def _exposure(scene) -> float:
    """Scale so that a receiver straight below the light reads about 1 (scene-independent look):
    the light's height above the lowest point, squared, over its intensity."""
    lo, _hi = scene.bounds()
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
    """Write a linear image as an sRGB PNG, atomically (:func:`softshadows.io.atomic_path`)."""
    from .io import atomic_path

    data = Image.fromarray(to_srgb8(img))
    with atomic_path(path) as tmp:
        data.save(str(tmp), format="PNG")


def visibility_to_rgb(v: np.ndarray) -> np.ndarray:
    """V as a grey image (linear values written directly as display values), background dark blue."""
    out = np.empty(v.shape + (3,), np.float32)
    g = np.nan_to_num(v, nan=0.0)
    out[...] = g[..., None]
    out[np.isnan(v)] = (0.05, 0.05, 0.12)
    return out


def save_exr(path, channels: dict[str, np.ndarray]) -> None:
    """Write float32 channels (each (H,W)) to an OpenEXR file, atomically."""
    import OpenEXR

    from .io import atomic_path

    chans = {k: np.ascontiguousarray(v.astype(np.float32)) for k, v in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp, OpenEXR.File(header, chans) as f:
        try:
            f.write(str(tmp))
        except RuntimeError as exc:  # the OpenEXR binding reports I/O failures as RuntimeError
            raise OSError(" ".join(str(exc).split())) from None


def load_exr(path) -> dict[str, np.ndarray]:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        return {k: np.array(c.pixels) for k, c in f.channels().items()}
