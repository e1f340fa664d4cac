"""Shadow maps from the light's center, shared by ``hard``, ``pcss`` and ``penumbra-map``.

* :func:`fit_light_view` — a perspective (or orthographic) view from the light's center whose
  window covers the occluders (a receiver point outside the window cannot be shadowed, because
  the segment from it to the light center crosses no occluder), square pixels, near/far fitted.
* :func:`build_shadow_map` — occluder depths with the shared rasterizer (``rasterize_depth``).
* :func:`shadow_lookup` — the Williams test with constant and slope-scaled bias and optional
  percentage-closer filtering, as a Numba kernel over an image of eye points (``lookup_image``:
  straight over the eye G-buffer; ``lookup_points``: over gathered points).

Bias is expressed in *texels*: the world size of one shadow-map texel at the point's depth, so
that the same defaults work on scenes of any scale. The effective depth offset is
``texel * (bias + slope_bias * tan(theta))`` with theta the angle between the surface normal
and the direction to the light (tan clamped to 10), the software equivalent of
``glPolygonOffset(slope, constant)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jit import kernel, row_stride, run_threads
from ..raster import View, rasterize_depth
from ..raster.kernels import view_project
from ..raster.view import VP_L, VP_ORIGIN, VP_ORTHO, VP_R, VP_W, light_view
from ..scene.types import light_key


@dataclass
class ShadowMap:
    view: View
    depth: np.ndarray  # (H,W) float32 view depth of the nearest occluder, +inf where none
    tri_id: np.ndarray | None  # (H,W) int32 index into the faces that were rasterized (None: not made)

    @property
    def vp(self) -> np.ndarray:
        return self.view.params()


def occluder_faces(scene, which: str = "occluder") -> np.ndarray:
    """Boolean face mask: ``occluder`` (roles both|occluder), ``receiver`` or ``all``."""
    flat = scene.flat
    if which == "occluder":
        return flat.occluder
    if which == "receiver":
        return flat.receiver
    return np.ones(len(flat.faces), bool)


def fit_light_view(
    scene, size: int, which: str = "occluder", ortho: bool = False, height: int | None = None, margin: float = 0.02
) -> View:
    """View from the light's center covering the vertices of the selected faces (square pixels).
    Computed once per geometry, light and arguments (a pass over every selected vertex; cached on
    ``scene.flat``, whose geometry does not change)."""
    flat = scene.flat
    light = scene.light

    def compute():
        mask = occluder_faces(scene, which)
        pts = flat.vertices[flat.face_vertices(which if mask.any() else "all")]
        return light_view(light, pts, size, height or size, ortho=ortho, margin=margin, square_pixels=True)

    return flat.cached(("fit_light_view", light_key(light), size, which, bool(ortho), height, margin), compute)


def build_shadow_map(
    scene, view: View, faces_mask: np.ndarray | None = None, cull: str = "none", tri: bool = True
) -> ShadowMap:
    """Rasterize the selected faces (default: occluders) into a depth map from ``view``; with
    ``tri=False`` the depths only (``tri_id`` None: ``rasterize_depth(tri=False)``)."""
    flat = scene.flat
    if faces_mask is None:
        faces_mask = flat.occluder
    faces = flat.faces_where(faces_mask)  # cached for the role masks
    depth, tri = rasterize_depth(view, flat.vertices, faces, cull=cull, tri=tri)
    return ShadowMap(view, depth, tri)


@kernel(inline=True)
def texel_world_size(vp, depth):
    """World size of one texel (x) at a view depth."""
    s = (vp[VP_R] - vp[VP_L]) / vp[VP_W]
    if vp[VP_ORTHO] == 0.0:
        s *= depth
    return s


@kernel(inline=True)
def receiver_offset(vp, px, py, pz, nx, ny, nz, depth, bias, slope_bias):
    """Depth offset (world units) for the shadow test at a point with normal n."""
    lx, ly, lz = vp[VP_ORIGIN] - px, vp[VP_ORIGIN + 1] - py, vp[VP_ORIGIN + 2] - pz
    ln = np.sqrt(lx * lx + ly * ly + lz * lz)
    c = abs(nx * lx + ny * ly + nz * lz) / max(ln, 1e-30)
    c = min(max(c, 1e-3), 1.0)
    tan = min(np.sqrt(1.0 - c * c) / c, 10.0)
    return texel_world_size(vp, depth) * (bias + slope_bias * tan)


@kernel(inline=True)
def biased_light_depth(vp, px, py, pz, nx, ny, nz, bias, slope_bias):
    """The shadow test's lookup for one point: (ok, sx, sy, zt) with (sx, sy) its continuous texel
    coordinates in the map of ``vp`` and ``zt`` its depth minus the bias; ``ok`` is False when the
    point is behind the light's view or projects to a non-finite texel (such a point is lit).
    A texel shadows the point when its stored depth is < zt. Shared by every shadow-map method."""
    sx, sy, z = view_project(vp, px, py, pz)
    if not (z > 0.0) or not (np.isfinite(sx) and np.isfinite(sy)):
        return False, 0.0, 0.0, 0.0
    off = receiver_offset(vp, px, py, pz, nx, ny, nz, z, bias, slope_bias)
    return True, sx, sy, z - off


@kernel(inline=True)
def biased_light_row(vp, position, normal, mask, i, bias, slope_bias, sc):
    """:func:`biased_light_depth` of every pixel of row ``i`` of an image of points (``position``,
    ``normal``: (H,W,3) C-contiguous, ``mask``: (H,W) True where a surface is), into ``sc`` (10, W):
    rows 0-5 the row's positions and normals copied to one float64 array per coordinate (the
    G-buffer interleaves them: as rows of 3 the next loop ran 1.7x slower; read through the row's
    flat view, the copy is vectorized, the lookups 0.89x), then sx, sy, zt (NaN where the
    lookup is not ``ok`` or there is no surface: no stored depth is below it) and 1.0 / 0.0 for
    ``ok`` and a surface. The second loop has no branch and no gather: LLVM vectorizes it."""
    W = mask.shape[1]
    prow = position[i].reshape(3 * W)
    nrow = normal[i].reshape(3 * W)
    for j in range(W):
        sc[0, j] = prow[3 * j]
        sc[1, j] = prow[3 * j + 1]
        sc[2, j] = prow[3 * j + 2]
        sc[3, j] = nrow[3 * j]
        sc[4, j] = nrow[3 * j + 1]
        sc[5, j] = nrow[3 * j + 2]
    for j in range(W):
        ok, sx, sy, zt = biased_light_depth(
            vp, sc[0, j], sc[1, j], sc[2, j], sc[3, j], sc[4, j], sc[5, j], bias, slope_bias
        )
        hit = ok & mask[i, j]
        sc[6, j] = sx
        sc[7, j] = sy
        sc[8, j] = zt if hit else np.nan
        sc[9, j] = 1.0 if hit else 0.0


@kernel(nogil=True)
def shadow_lookup_slot(slot, vp, depth_map, position, normal, mask, bias, slope_bias, pcf_radius, out, nslot):
    """V per surface pixel of an image of points (``position``, ``normal``: (H,W,3), ``mask``:
    (H,W) True where a surface is) into ``out`` (H,W): 1 lit, 0 shadowed; with ``pcf_radius`` r >
    0, the fraction of lit tests over the (2r+1)^2 texels around the point (percentage-closer
    filtering). Pixels without a surface get 1. The normal's sign does not matter (the bias uses
    |n.l|). Run by ``run_slots``: slot ``slot`` of ``nslot`` takes every ``nslot``-th row.

    Per row, the projections and biased depths of :func:`biased_light_row`, then the depth tests
    (a point that is not ``ok`` or has no surface has ``zt`` = NaN, which no stored depth is below:
    lit)."""
    Hm, Wm = depth_map.shape
    H, W = mask.shape
    sc = np.empty((10, row_stride(W)))  # x, y, z, nx, ny, nz, then sx, sy, zt, ok (row_stride: 10 rows)
    for i in range(slot, H, nslot):
        biased_light_row(vp, position, normal, mask, i, bias, slope_bias, sc)
        if pcf_radius == 0:
            for j in range(W):
                ci = int(np.floor(sc[6, j]))
                ri = int(np.floor(sc[7, j]))
                shadowed = ri >= 0 and ri < Hm and ci >= 0 and ci < Wm and depth_map[ri, ci] < sc[8, j]
                out[i, j] = 0.0 if shadowed else 1.0
        else:
            for j in range(W):
                zt = sc[8, j]
                ci = int(np.floor(sc[6, j]))
                ri = int(np.floor(sc[7, j]))
                lit = 0
                cnt = 0
                for dr in range(-pcf_radius, pcf_radius + 1):
                    r = ri + dr
                    for dc in range(-pcf_radius, pcf_radius + 1):
                        c = ci + dc
                        cnt += 1
                        if r < 0 or r >= Hm or c < 0 or c >= Wm or not (depth_map[r, c] < zt):
                            lit += 1
                out[i, j] = lit / cnt


def shadow_lookup(vp, depth_map, position, normal, mask, bias, slope_bias, pcf_radius) -> np.ndarray:
    """:func:`shadow_lookup_slot` over the whole image, one slot per thread: V (H,W) float32."""
    out = np.empty(mask.shape, np.float32)
    position = np.ascontiguousarray(position)  # (biased_light_row reads a row as a flat view)
    normal = np.ascontiguousarray(normal)
    run_threads(shadow_lookup_slot, vp, depth_map, position, normal, mask, bias, slope_bias, pcf_radius, out)
    return out


def lookup_image(
    smap: ShadowMap, position: np.ndarray, normal: np.ndarray, mask: np.ndarray, bias: float, slope_bias: float,
    pcf_radius: int = 0,
) -> np.ndarray:  # fmt: skip
    """V (H,W) float32 of the surface pixels of a G-buffer (``position``, ``normal``: (H,W,3),
    ``mask``: (H,W)) straight from the image, 1 where no surface: the same values as
    :func:`lookup_points` on ``gather_points`` of it."""
    return shadow_lookup(smap.vp, smap.depth, position, normal, mask, float(bias), float(slope_bias), int(pcf_radius))


def lookup_points(
    smap: ShadowMap, pts: np.ndarray, nrm: np.ndarray, bias: float, slope_bias: float, pcf_radius: int = 0
) -> np.ndarray:
    """V (K,) float32 of K points (``pts``, ``nrm``: (K,3)): the same test as :func:`lookup_image`."""
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    nrm = np.ascontiguousarray(nrm, dtype=np.float64)
    k = len(pts)
    mask = np.ones((k, 1), np.bool_)
    return lookup_image(smap, pts.reshape(k, 1, 3), nrm.reshape(k, 1, 3), mask, bias, slope_bias, pcf_radius).reshape(k)
