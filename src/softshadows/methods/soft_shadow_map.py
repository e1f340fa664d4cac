"""``soft-shadow-map``: Soft Shadow Maps (Atty, Holzschuch, Lapierre, Hasenfratz, Hansen, Sillion,
Computer Graphics Forum 2006), rectangle lights.

The occluders, seen from the light's center, are replaced by one *micro-patch* per occluder-map
pixel: a rectangle parallel to the light at that pixel's depth covering the pixel's footprint.
For every micro-patch, the fraction of the light it hides is computed at every texel of a second
projective texture, the *soft shadow map* (SSM), inside the patch's penumbra extent, and summed.
The SSM is then projected onto the scene from the light. Both inner and outer penumbrae come out.

Steps (paper Fig. 4), one function each, in this order:

1. :func:`compute_map_views` — the occluder map and the SSM/receiver map are perspective views
   from the light's center C_L along its normal, axis-aligned with the rectangle (``right`` along
   ``u``) and with the light's aspect ratio (Sec. 3.2), so every micro-patch is axis-aligned with
   the light and similar to it. The occluder map covers the occluders; the SSM covers their
   largest possible shadow (occluder window grown by the widest penumbra), clipped to the receivers.
2. :func:`compute_receiver_depth_map` — receiver depths at the SSM texels ("Compute depth map of
   receivers"); faces with ``Mesh.role`` in ``receiver|both``.
3. :func:`compute_occluder_depth_map` — occluder depths ("Compute depth map of occluders"); faces
   with role ``occluder|both``. One pass: the nearest surface. Two-pass variant (Sec. 3.5): the
   closest front faces, and separately the furthest back faces.
4. :func:`discretize_occluders` — "Retrieve depth of occluder / compute micro-patch" (Sec. 3.2):
   each non-empty pixel -> the rectangle ``[x0, x1] x [y0, y1]`` at depth ``z_O`` in the light frame.
5. :func:`penumbra_extents` — "Compute extent of penumbra" (Sec. 3.3): ratio r = LL'/PP', apex
   ``O = C_L + r/(1+r) (C_P - C_L)``, and the axis-aligned rectangle where the pyramid meets the
   SSM's virtual plane: ``C_L C_R = z_R/z_O' C_L O``, ``RR' = LL' (z_R - z_O')/z_O'`` (z_O' the
   apex depth); converted into a range of SSM texels.
6. :func:`occlusion_percentage` — the fragment program (Sec. 3.4/4.2): the micro-patch projected
   back from the receiver point of a texel (receiver depth map) onto the light, as the interval
   ``[a, b] x [c, d]`` in the light's ``[0, 1]^2`` coordinates; the occluded fraction is the product
   of the two interval overlaps with ``[0, 1]`` (the ``MOV_SAT / SUB / MUL`` of the paper).
7. :func:`accumulate_soft_shadow_map` — "Add to current percentage in soft shadow map": the GPU's
   additive blending, done race-free in parallel: the SSM is split into bands of rows, the
   micro-patches are binned by band (:func:`bin_patches_by_band`) in occluder-map order (the draw
   order), and each band is summed by one thread in that order. ``accumulate="float16"`` rounds
   the running sum to half precision after every addition (:func:`round_half`, IEEE binary16,
   round-to-nearest-even, np.float16 semantics), which reproduces the FP16 blending failure of
   Fig. 14 / Appendix A; ``float32`` (default) adds in single precision like FP32 blending, and
   evaluates the fragment program in float32 too, as a GPU fragment program does (16 vector lanes;
   within 5e-6 of float64 arithmetic on the built-in scenes). The bands are dealt round-robin to
   the threads so that a shadow in a few bands does not leave a thread idle.
   The sum is clamped to [0, 1] at the end (:func:`clamp_soft_shadow_map`).
8. :func:`merge_two_pass` — two-pass variant: one SSM per occluder map, merged by max (Sec. 3.5).
9. :func:`project_soft_shadow_map` — "Project soft shadow map on the scene": each eye pixel on a
   receiver is projected into the SSM and read with bilinear filtering; V = 1 - occlusion.

Parameters (``Param`` defaults):

* ``map_size`` = 256: occluder map N x N pixels (paper: 128 typical, 256 for small penumbrae,
  "above 200 pixels does not bring an improvement", Sec. 5.2.3/6.2.2).
* ``ssm_size`` = 256: soft shadow map N x N texels (the paper does not give it; keeping it fixed
  while the occluder map changes is what makes the cost linear in occluder-map pixels, Sec. 6.2.2).
* ``two_pass`` = false: front-face and back-face occluder maps merged by max (Sec. 3.5).
* ``accumulate`` = float32 | float16 | float16-rtz: float16 rounds the running sum to the nearest
  half (np.float16), float16-rtz truncates it, the rule Appendix A states (``X + e = X if
  e < 2^-10 X``); both reproduce the paper's FP16 blending failure.
* ``margin`` = 0.02: fraction added around the occluders in the occluder map's window.

Statistics: ``micro_patches`` (all passes), ``micro_patches_front``/``_back``, ``texels_touched``
(fragment-program invocations: texels inside penumbra extents), ``texels_per_patch``,
``occluded_texels`` (SSM texels with occlusion > 0), map sizes, ``fp16_safe`` (Appendix A's
Eq. 4 holds for every micro-patch over the farthest receiver), and per-phase times
``occluder_map``, ``receiver_map``, ``penumbra_extents``, ``soft_shadow_map``, ``eye_projection``.

Deviations from the paper (see the README):

* CPU/Numba instead of GPU fragment programs; blending is the banded, ordered sum above.
* The paper intersects the pyramid with *one* virtual plane. Receivers have different depths, so
  we place that plane at the farthest receiver depth of the receiver map: the extent (a rectangle
  in projective SSM coordinates whose size grows with depth) then contains the true penumbra of
  every receiver. The occluded fraction at each texel uses that texel's own receiver depth, so
  this costs evaluations of zero-valued texels, not accuracy.
* Two-pass back map: the furthest back-facing fragment per pixel (all fragments with front faces
  culled, max depth), the software equivalent of a GREATER depth test.
* A mesh of role ``both`` never shadows itself (the paper computes no self-shadowing); scenes
  without roles are refused with a one-line error (the split is the algorithm's premise, Sec. 3.1).

Known limits (the paper's, kept): no self-shadowing; eye pixels on occluder-only geometry get
V = 1 (the paper shades only receivers); the shadow of the *discretized* occluder seen from C_L
(silhouette parts visible only from other light points are missing, Sec. 5.1.1); overlaps/gaps
between neighbouring micro-patch back-projections (Sec. 5.1.2); receivers are not shadowed by
other receivers, and a receiver point farther from the light than the receiver map's surface at
its texel reads that surface's value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np
from numba import prange

from .._jit import kernel
from ..errors import SoftShadowsError
from ..raster import View, rasterize_depth, rasterize_fragments
from ..raster.kernels import sample_bilinear, view_project
from ..raster.view import VP_B, VP_H, VP_L, VP_R, VP_T, VP_W, light_view
from .base import Method, MethodOutput, Param, register

BAND_ROWS = 2  # SSM rows per accumulation band (one thread sums one band)
FP16_MAX = 65504.0


# ---- 1. the light-aligned views ---------------------------------------------------------------
def light_half_extents(light, view: View) -> tuple[float, float]:
    """Half sizes (hx, hy) of the rectangle light along the view's right and up axes."""
    hx = 0.5 * abs(float(np.dot(light.u, view.right)))
    hy = 0.5 * abs(float(np.dot(light.v, view.up)))
    return hx, hy


def _with_aspect(window, aspect: float) -> tuple:
    """Grow ``window`` (l, r, b, t) about its center so that width / height == aspect."""
    l, r, b, t = window
    w, h = r - l, t - b
    cx, cy = (l + r) / 2, (b + t) / 2
    if w < h * aspect:
        w = h * aspect
    else:
        h = w / aspect
    return (cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2)


def _face_vertices(flat, mask) -> np.ndarray:
    return flat.vertices[np.unique(flat.faces[mask])]


def compute_map_views(scene, map_size: int, ssm_size: int, margin: float = 0.02) -> tuple[View, View]:
    """(occluder-map view, SSM/receiver-map view), both from the light center along its normal,
    axis-aligned with the light and of its aspect ratio (square maps of N x N pixels)."""
    light, flat = scene.light, scene.flat
    occ_pts = _face_vertices(flat, flat.occluder)
    rec_pts = _face_vertices(flat, flat.receiver)
    ov = light_view(light, occ_pts, map_size, map_size, margin=margin)
    hx, hy = light_half_extents(light, ov)
    aspect = hx / hy
    ov = View(
        ov.origin, ov.right, ov.up, ov.forward, _with_aspect(ov.window, aspect), ov.near, ov.far, map_size, map_size
    )
    rv = light_view(light, rec_pts, ssm_size, ssm_size, margin=0.0)
    # Widest penumbra around the occluder window (projective units): a point at depth z_P, seen
    # from any light point, lands within hx (1/z_P - 1/z_R) of its central projection at depth z_R.
    zo = ov.to_view(occ_pts)[:, 2]
    zo_min = max(float(zo[zo > ov.near * 0.5].min()) if np.any(zo > ov.near * 0.5) else ov.near, 1e-9)
    zr_max = rv.far
    l, r, b, t = ov.window
    px, py = (r - l) / map_size, (t - b) / map_size
    mx = max(hx * (1.0 / zo_min - 1.0 / zr_max), 0.0) + 2 * px
    my = max(hy * (1.0 / zo_min - 1.0 / zr_max), 0.0) + 2 * py
    rl, rr, rb, rt = rv.window
    win = (max(l - mx, rl), min(r + mx, rr), max(b - my, rb), min(t + my, rt))
    if not (win[1] > win[0] and win[3] > win[2]):  # occluders' shadow misses the receivers
        win = rv.window
    win = _with_aspect(win, aspect)
    sv = View(rv.origin, rv.right, rv.up, rv.forward, win, rv.near, rv.far, ssm_size, ssm_size)
    return ov, sv


# ---- 2. receiver depth map ---------------------------------------------------------------------
def compute_receiver_depth_map(scene, view: View) -> tuple[np.ndarray, np.ndarray]:
    """(depth (H,W) float32 +inf where empty, mesh id (H,W) int32 -1 where empty) of receivers."""
    flat = scene.flat
    idx = np.flatnonzero(flat.receiver)
    depth, tri = rasterize_depth(view, flat.vertices, np.ascontiguousarray(flat.faces[idx]), cull="none")
    mesh = np.where(tri >= 0, flat.mesh_id[idx][np.maximum(tri, 0)], -1).astype(np.int32)
    return np.ascontiguousarray(depth, dtype=np.float32), mesh


# ---- 3. occluder depth map ---------------------------------------------------------------------
@kernel
def _max_depth_per_pixel(pixel, depth, tri, n_pix):
    out = np.full(n_pix, -np.inf, np.float32)
    who = np.full(n_pix, -1, np.int32)
    for k in range(pixel.shape[0]):
        p = pixel[k]
        if depth[k] > out[p]:
            out[p] = depth[k]
            who[p] = tri[k]
    for p in range(n_pix):
        if who[p] < 0:
            out[p] = np.inf
    return out, who


def compute_occluder_depth_map(scene, view: View, side: str = "nearest") -> tuple[np.ndarray, np.ndarray]:
    """(depth (H,W) float32 +inf where empty, mesh id (H,W) int32) of the occluders.

    ``side``: ``nearest`` (one pass: the usual depth buffer, no culling), ``front`` (closest
    front-facing faces) or ``back`` (furthest back-facing faces), the two maps of Sec. 3.5."""
    flat = scene.flat
    idx = np.flatnonzero(flat.occluder)
    faces = np.ascontiguousarray(flat.faces[idx])
    if side == "back":
        fr = rasterize_fragments(view, flat.vertices, faces, cull="front")
        d, tri = _max_depth_per_pixel(
            np.asarray(fr.pixel, np.int64),
            np.asarray(fr.depth, np.float32),
            np.asarray(fr.tri, np.int32),
            view.width * view.height,
        )
        depth, tri = d.reshape(view.height, view.width), tri.reshape(view.height, view.width)
    else:
        depth, tri = rasterize_depth(view, flat.vertices, faces, cull="back" if side == "front" else "none")
    mesh = np.where(tri >= 0, flat.mesh_id[idx][np.maximum(tri, 0)], -1).astype(np.int32)
    return np.ascontiguousarray(depth, dtype=np.float32), mesh


# ---- 4. micro-patches --------------------------------------------------------------------------
@kernel
def discretize_occluders(depth, mesh, ovp):
    """Each non-empty occluder-map pixel -> a micro-patch parallel to the light at its depth,
    covering the pixel's footprint: rows ``[x0, x1, y0, y1, z_O]`` in the light frame (x along
    ``right``, y along ``up``, z = depth), in occluder-map (row-major, draw) order; and its mesh id."""
    H, W = depth.shape
    l, r, b, t = ovp[VP_L], ovp[VP_R], ovp[VP_B], ovp[VP_T]
    dx = (r - l) / W
    dy = (t - b) / H
    n = 0
    for i in range(H):
        for j in range(W):
            if depth[i, j] < np.inf:
                n += 1
    patches = np.empty((n, 5), np.float64)
    pmesh = np.empty(n, np.int32)
    k = 0
    for i in range(H):
        for j in range(W):
            z = float(depth[i, j])
            if z < np.inf:
                patches[k, 0] = (l + j * dx) * z
                patches[k, 1] = (l + (j + 1) * dx) * z
                patches[k, 2] = (t - (i + 1) * dy) * z
                patches[k, 3] = (t - i * dy) * z
                patches[k, 4] = z
                pmesh[k] = mesh[i, j]
                k += 1
    return patches, pmesh


# ---- 5. penumbra extents -----------------------------------------------------------------------
@kernel(inline=True)
def _pyramid_section(c_p, h_p, z_p, h_l, z_plane):
    """One axis of Sec. 3.3: patch center ``c_p`` and half size ``h_p`` at depth ``z_p``, light half
    size ``h_l`` centered on C_L = 0. Returns the (lo, hi) interval where the pyramid of apex
    O = C_L + r/(1+r) (C_P - C_L), r = LL'/PP', meets the plane at depth ``z_plane``."""
    rr = h_l / h_p
    s = rr / (1.0 + rr)
    z_apex = s * z_p
    c_apex = s * c_p
    c_r = z_plane / z_apex * c_apex  # C_L C_R = z_R / z_O C_L O
    half = h_l * (z_plane - z_apex) / z_apex  # RR' / 2 = (LL' / 2)(z_R - z_O) / z_O
    return c_r - half, c_r + half


@kernel
def penumbra_extents(patches, hx, hy, z_plane, svp):
    """Per micro-patch, the SSM texels ``[i0, i1] x [j0, j1]`` (inclusive; empty when i0 > i1)
    whose centers lie in the patch's penumbra rectangle on the virtual plane at depth ``z_plane``."""
    n = patches.shape[0]
    out = np.empty((n, 4), np.int32)
    l, r, b, t = svp[VP_L], svp[VP_R], svp[VP_B], svp[VP_T]
    W = svp[VP_W]
    H = svp[VP_H]
    dxs = (r - l) / W
    dys = (t - b) / H
    for k in range(n):
        z = patches[k, 4]
        out[k, 0] = 1
        out[k, 1] = 0
        out[k, 2] = 1
        out[k, 3] = 0
        if not (z < z_plane):
            continue
        x_lo, x_hi = _pyramid_section(
            0.5 * (patches[k, 0] + patches[k, 1]), 0.5 * (patches[k, 1] - patches[k, 0]), z, hx, z_plane
        )
        y_lo, y_hi = _pyramid_section(
            0.5 * (patches[k, 2] + patches[k, 3]), 0.5 * (patches[k, 3] - patches[k, 2]), z, hy, z_plane
        )
        # projective SSM coordinates -> texel index ranges (texel centers at half-integers)
        fj0 = math.ceil((x_lo / z_plane - l) / dxs - 0.5)
        fj1 = math.floor((x_hi / z_plane - l) / dxs - 0.5)
        fi0 = math.ceil((t - y_hi / z_plane) / dys - 0.5)
        fi1 = math.floor((t - y_lo / z_plane) / dys - 0.5)
        fj0 = max(fj0, 0.0)
        fi0 = max(fi0, 0.0)
        fj1 = min(fj1, W - 1.0)
        fi1 = min(fi1, H - 1.0)
        if fj0 > fj1 or fi0 > fi1:
            continue
        out[k, 0] = int(fi0)
        out[k, 1] = int(fi1)
        out[k, 2] = int(fj0)
        out[k, 3] = int(fj1)
    return out


# ---- 6. the fragment program: percentage of occlusion ------------------------------------------
@kernel(inline=True)
def _sat(x):
    """Clamp to [0, 1] (the SAT modifier); written as selects so that loops vectorize."""
    x = x if x > 0.0 else 0.0
    return x if x < 1.0 else 1.0


_F0 = np.float32(0.0)
_F1 = np.float32(1.0)
_FH = np.float32(0.5)


@kernel(inline=True)
def _sat32(x):
    x = x if x > _F0 else _F0
    return x if x < _F1 else _F1


@kernel(inline=True)
def _occlusion_percentage32(k, a0, a1, c0, c1):
    """:func:`occlusion_percentage` in float32 arithmetic (the precision of a GPU fragment program;
    16 lanes per vector instead of 8)."""
    a = _sat32(k * a0 + _FH)
    b = _sat32(k * a1 + _FH)
    c = _sat32(k * c0 + _FH)
    d = _sat32(k * c1 + _FH)
    return (b - a) * (d - c)


@kernel(inline=True)
def occlusion_percentage(k, a0, a1, c0, c1):
    """Fraction of the light hidden by one micro-patch at one receiver point (Sec. 3.4, 4.2).

    The back-projection from the receiver point p (depth z_R) through the patch (depth z_O) onto
    the light plane maps a patch coordinate x to ``p_x + (x - p_x) k`` with ``k = z_R/(z_R - z_O)``.
    With the patch ``[x0, x1] x [y0, y1]``, p = (u_x z_R, u_y z_R, z_R) for the texel's projective
    coordinates (u_x, u_y), and the light ``[-hx, hx] x [-hy, hy]`` mapped to ``[0, 1]^2``, the
    projected patch is ``[a, b] x [c, d]`` with ``a = k a0 + 1/2``, ``a0 = (x0 - u_x z_O)/(2 hx)``
    (and likewise b from x1, c and d from y0, y1 and hy). The occluded fraction is the product of
    the two interval overlaps with [0, 1]: ``(sat(b) - sat(a)) (sat(d) - sat(c))``. k = 0 gives 0."""
    a = _sat(k * a0 + 0.5)
    b = _sat(k * a1 + 0.5)
    c = _sat(k * c0 + 0.5)
    d = _sat(k * c1 + 0.5)
    return (b - a) * (d - c)


def occlusion_percentage_at(patch, ux, uy, z_r, hx, hy) -> float:
    """Reference form of :func:`occlusion_percentage` for one patch ``(x0, x1, y0, y1, z_O)`` and
    one receiver point (projective ``ux, uy`` and depth ``z_r``); 0 unless z_O < z_r."""
    x0, x1, y0, y1, zo = (float(v) for v in patch)
    if not z_r > zo:
        return 0.0
    k = z_r / (z_r - zo)
    return float(
        occlusion_percentage(
            k,
            (x0 - ux * zo) / (2 * hx),
            (x1 - ux * zo) / (2 * hx),
            (y0 - uy * zo) / (2 * hy),
            (y1 - uy * zo) / (2 * hy),
        )
    )


# ---- 7. accumulation into the soft shadow map --------------------------------------------------
@kernel(inline=True)
def round_half(x, toward_zero=False):
    """Round a float to an IEEE binary16 value, returned as float64. Default: nearest, ties to
    even, exactly ``float(np.float16(x))`` (overflow -> inf). ``toward_zero``: truncate the
    mantissa instead, the rule Appendix A states (``X + e = X if e < 2^-10 X``; ``0.5 + 1/2049 = 0.5``),
    overflow -> 65504."""
    if x == 0.0 or not math.isfinite(x):
        return x
    _m, e = math.frexp(x)  # x = m 2^e, 0.5 <= |m| < 1
    if e < -13:
        e = -13  # subnormal range: fixed spacing 2^-24
    ulp = math.ldexp(1.0, e - 11)
    if toward_zero:
        y = math.trunc(x / ulp) * ulp
        return y if abs(y) <= FP16_MAX else math.copysign(FP16_MAX, x)
    y = np.rint(x / ulp) * ulp
    if abs(y) > FP16_MAX:
        return math.copysign(math.inf, x)
    return y


@kernel
def bin_patches_by_band(ext, n_bands, band_rows):
    """CSR lists (ptr (n_bands+1,), idx) of the micro-patches whose extent meets each band of
    ``band_rows`` SSM rows, each list in micro-patch (draw) order."""
    n = ext.shape[0]
    cnt = np.zeros(n_bands + 1, np.int64)
    for k in range(n):
        if ext[k, 0] <= ext[k, 1]:
            for bnd in range(ext[k, 0] // band_rows, ext[k, 1] // band_rows + 1):
                cnt[bnd + 1] += 1
    for bnd in range(n_bands):
        cnt[bnd + 1] += cnt[bnd]
    idx = np.empty(cnt[n_bands], np.int32)
    fill = cnt[:n_bands].copy()
    for k in range(n):
        if ext[k, 0] <= ext[k, 1]:
            for bnd in range(ext[k, 0] // band_rows, ext[k, 1] // band_rows + 1):
                idx[fill[bnd]] = k
                fill[bnd] += 1
    return cnt, idx


@kernel(parallel=True)
def accumulate_soft_shadow_map(
    patches,
    pmesh,
    ext,
    band_ptr,
    band_idx,
    band_rows,
    recv_depth,
    recv_mesh,
    svp,
    hx,
    hy,
    fp16,
    rtz,
    check_mesh,
    ssm,
    nslot=1,
):
    """Add every micro-patch's occlusion percentage into ``ssm`` (H,W) float32 at the texels of
    its penumbra extent. One thread per band of rows, micro-patches in draw order: race-free and
    with the same per-texel order of additions as GPU blending. ``fp16``: round the running sum to
    half precision after every addition (scalar loop; ``rtz``: toward zero). Returns the
    fragment-program invocations per band.

    ``recv_depth``: receiver depths with 0 where there is no receiver. A texel whose receiver is
    not behind the patch (or, with ``check_mesh``, belongs to the patch's own mesh: no
    self-shadowing) gets k = 0, hence a percentage of exactly 0: the float32 inner loop has no
    branch and vectorizes (adding 0.0 leaves the sum unchanged)."""
    H, W = recv_depth.shape
    l, r, b, t = svp[VP_L], svp[VP_R], svp[VP_B], svp[VP_T]
    dxs = (r - l) / W
    dys = (t - b) / H
    n_bands = band_ptr.shape[0] - 1
    touched = np.zeros(n_bands, np.int64)
    # bands dealt round-robin to ``nslot`` slots, one per thread (Numba splits a prange into equal
    # contiguous parts: with the shadow in a few bands, contiguous halves would leave a thread idle)
    for slot in prange(nslot):
        for bnd in range(slot, n_bands, nslot):
            r0 = bnd * band_rows
            r1 = min(r0 + band_rows, H) - 1
            cnt = 0
            for q in range(band_ptr[bnd], band_ptr[bnd + 1]):
                p = band_idx[q]
                x0, x1, y0, y1, zo = patches[p, 0], patches[p, 1], patches[p, 2], patches[p, 3], patches[p, 4]
                pm = pmesh[p]
                i0 = max(ext[p, 0], r0)
                i1 = min(ext[p, 1], r1)
                j0 = ext[p, 2]
                j1 = ext[p, 3] + 1
                # x terms of the fragment program are linear in the column: a0(j) = ax - j * dax
                ux0 = l + (j0 + 0.5) * dxs
                ax = (x0 - ux0 * zo) / (2.0 * hx)
                wx = (x1 - x0) / (2.0 * hx)
                dax = dxs * zo / (2.0 * hx)
                for i in range(i0, i1 + 1):
                    uy = t - (i + 0.5) * dys
                    c0 = (y0 - uy * zo) / (2.0 * hy)
                    c1 = (y1 - uy * zo) / (2.0 * hy)
                    cnt += j1 - j0
                    if fp16:
                        row = recv_depth[i, j0:j1]
                        out = ssm[i, j0:j1]
                        for jj in range(row.shape[0]):
                            zr = np.float64(row[jj])
                            if zr > zo and not (check_mesh and recv_mesh[i, j0 + jj] == pm):
                                a0 = ax - jj * dax
                                c = occlusion_percentage(zr / (zr - zo), a0, a0 + wx, c0, c1)
                                if c > 0.0:
                                    out[jj] = np.float32(round_half(np.float64(out[jj]) + round_half(c, rtz), rtz))
                    elif check_mesh:
                        ii = np.uint64(i)
                        zo32 = np.float32(zo)
                        ax32 = np.float32(ax)
                        dax32 = np.float32(dax)
                        wx32 = np.float32(wx)
                        c032 = np.float32(c0)
                        c132 = np.float32(c1)
                        for jj in range(j1 - j0):
                            jx = np.uint64(j0 + jj)
                            zr = recv_depth[ii, jx]
                            k = zr / (zr - zo32)
                            k = k if zr > zo32 else _F0
                            k = k if recv_mesh[ii, jx] != pm else _F0
                            a0 = ax32 - np.float32(jj) * dax32
                            ssm[ii, jx] += _occlusion_percentage32(k, a0, a0 + wx32, c032, c132)
                    else:
                        # float32 arithmetic (a GPU fragment program's; 16 lanes per vector); 2-D subscripts,
                        # no row views (a view costs a contended atomic refcount update); unsigned
                        # indices: no negative-index wraparound, so the loop vectorizes
                        ii = np.uint64(i)
                        zo32 = np.float32(zo)
                        ax32 = np.float32(ax)
                        dax32 = np.float32(dax)
                        wx32 = np.float32(wx)
                        c032 = np.float32(c0)
                        c132 = np.float32(c1)
                        for jj in range(j1 - j0):
                            jx = np.uint64(j0 + jj)
                            zr = recv_depth[ii, jx]
                            k = zr / (zr - zo32)
                            k = k if zr > zo32 else _F0
                            a0 = ax32 - np.float32(jj) * dax32
                            ssm[ii, jx] += _occlusion_percentage32(k, a0, a0 + wx32, c032, c132)
            touched[bnd] = cnt
    return touched


@kernel(parallel=True)
def clamp_soft_shadow_map(ssm):
    """Clamp the summed percentages to [0, 1] in place (the paper clamps at display)."""
    H, W = ssm.shape
    for i in prange(H):
        for j in range(W):
            v = ssm[i, j]
            ssm[i, j] = 0.0 if not (v > 0.0) else (1.0 if v > 1.0 else v)


# ---- 8. two-pass merge -------------------------------------------------------------------------
def merge_two_pass(front: np.ndarray, back: np.ndarray) -> np.ndarray:
    """The two soft shadow maps merged by their maximum (Sec. 3.5)."""
    return np.maximum(front, back)


# ---- 9. projection onto the eye view -----------------------------------------------------------
@kernel(parallel=True)
def project_soft_shadow_map(pts, is_receiver, svp, ssm):
    """V per eye point: receivers read the SSM (bilinear) at their projection from the light;
    V = 1 - occlusion. Outside the SSM, behind the light, or on occluder-only geometry: V = 1."""
    n = pts.shape[0]
    H, W = ssm.shape
    out = np.empty(n, np.float32)
    for k in prange(n):
        out[k] = 1.0
        if not is_receiver[k]:
            continue
        sx, sy, z = view_project(svp, pts[k, 0], pts[k, 1], pts[k, 2])
        if not (z > 0.0) or not (sx >= 0.0 and sx <= W and sy >= 0.0 and sy <= H):
            continue
        o = sample_bilinear(ssm, sx, sy)
        if o > 0.0:
            out[k] = 1.0 - min(o, 1.0)
    return out


# ---- orchestration -----------------------------------------------------------------------------
@dataclass
class SoftShadowMap:
    """The result of steps 1-8: the SSM (occlusion in [0, 1]) and what produced it."""

    view: View  # SSM / receiver-map view
    occlusion: np.ndarray  # (H,W) float32 in [0,1]
    receiver_depth: np.ndarray  # (H,W) float32, +inf where no receiver
    occluder_view: View
    passes: dict = field(default_factory=dict)  # side -> (H,W) float32 SSM of that pass
    stats: dict = field(default_factory=dict)


class _NullTimer:
    def phase(self, name):
        from contextlib import nullcontext

        return nullcontext()


def check_roles(scene) -> None:
    if not scene.has_roles:
        raise SoftShadowsError(
            f"soft-shadow-map: scene '{scene.name}' has no occluder/receiver roles (every mesh is 'both'); "
            "set role = 'occluder' or 'receiver' on its meshes (the paper splits occluders from receivers)"
        )


def compute_soft_shadow_map(
    scene,
    map_size: int = 256,
    ssm_size: int = 256,
    two_pass: bool = False,
    accumulate: str = "float32",
    margin: float = 0.02,
    timer=None,
) -> SoftShadowMap:
    """Steps 1-8 for ``scene`` (rectangle light): the clamped soft shadow map and statistics."""
    timer = timer or _NullTimer()
    if scene.light.shape != "rect":
        raise SoftShadowsError(f"soft-shadow-map supports rect lights, not '{scene.light.shape}'")
    check_roles(scene)
    flat = scene.flat
    fp16 = accumulate.startswith("float16")
    stats = {
        "map_size": int(map_size),
        "ssm_size": int(ssm_size),
        "two_pass": bool(two_pass),
        "accumulate": accumulate,
        "micro_patches": 0,
        "texels_touched": 0,
    }
    if not flat.occluder.any() or not flat.receiver.any():
        v = View.frame(scene.light.center, scene.light.normal, (0, 1, 0), (-1, 1, -1, 1), 1e-3, 1.0, ssm_size, ssm_size)
        z = np.zeros((ssm_size, ssm_size), np.float32)
        return SoftShadowMap(v, z, np.full_like(z, np.inf), v, {}, stats)
    with timer.phase("receiver_map"):
        ov, sv = compute_map_views(scene, map_size, ssm_size, margin)
        rdepth, rmesh = compute_receiver_depth_map(scene, sv)
    with timer.phase("occluder_map"):
        sides = ("front", "back") if two_pass else ("nearest",)
        omaps = {s: compute_occluder_depth_map(scene, ov, s) for s in sides}
    hx, hy = light_half_extents(scene.light, ov)
    finite = rdepth[np.isfinite(rdepth)]
    rdepth0 = np.where(np.isfinite(rdepth), rdepth, np.float32(0.0)).astype(np.float32)  # 0: no receiver
    z_plane = float(finite.max()) if finite.size else 0.0
    check_mesh = any(m.role == "both" for m in scene.meshes)
    ovp, svp = ov.params(), sv.params()
    n_bands = (ssm_size + BAND_ROWS - 1) // BAND_ROWS
    passes = {}
    fp16_safe = True
    for s in sides:
        with timer.phase("penumbra_extents"):
            patches, pmesh = discretize_occluders(omaps[s][0], omaps[s][1], ovp)
            ext = penumbra_extents(patches, hx, hy, z_plane, svp)
            ptr, idx = bin_patches_by_band(ext, n_bands, BAND_ROWS)
        with timer.phase("soft_shadow_map"):
            ssm = np.zeros((ssm_size, ssm_size), np.float32)
            touched = accumulate_soft_shadow_map(
                patches,
                pmesh,
                ext,
                ptr,
                idx,
                BAND_ROWS,
                rdepth0,
                rmesh,
                svp,
                hx,
                hy,
                fp16,
                accumulate == "float16-rtz",
                check_mesh,
                ssm,
                numba.get_num_threads(),
            )
            clamp_soft_shadow_map(ssm)
        passes[s] = ssm
        stats[f"micro_patches_{s}"] = int(len(patches))
        stats["micro_patches"] += int(len(patches))
        stats["texels_touched"] += int(touched.sum())
        if len(patches) and z_plane > 0:
            fp16_safe &= bool(np.all(fp16_condition(patches[:, 4], z_plane, hx, ov) | (patches[:, 4] >= z_plane)))
    with timer.phase("soft_shadow_map"):
        occ = merge_two_pass(passes["front"], passes["back"]) if two_pass else passes["nearest"]
    stats["texels_per_patch"] = stats["texels_touched"] / max(stats["micro_patches"], 1)
    stats["occluded_texels"] = int((occ > 0).sum())
    stats["receiver_plane_depth"] = z_plane
    stats["fp16_safe"] = fp16_safe
    return SoftShadowMap(sv, occ, rdepth, ov, passes, stats)


def fp16_condition(z_o, z_r, hx, ov: View) -> np.ndarray:
    """Appendix A, Eq. 4: FP16 blending is safe for a micro-patch at depth z_O over a receiver at
    z_R when 1/z_O < 1/z_R + 64 tan(a) / (N L), a the half-angle and N the size of the occluder map,
    L the light width (i.e. its back-projection is wider than 1/32 of the light)."""
    l, r, _, _ = ov.window
    tan_a = (r - l) / 2
    return 1.0 / np.asarray(z_o) < 1.0 / z_r + 64.0 * tan_a / (ov.width * 2.0 * hx)


@register
class SoftShadowMapMethod(Method):
    name = "soft-shadow-map"
    light_shapes = ("rect",)
    summary = "soft shadow maps: occluder-map pixels as micro-patches, occlusion summed in a projective map"
    paper = "Atty et al. 2006, Soft Shadow Maps: Efficient Sampling of Light Source Visibility"
    params = (
        Param("map_size", 256, "occluder map resolution N (N x N, light's aspect ratio)", min=8, max=4096),
        Param("ssm_size", 256, "soft shadow map resolution (N x N texels)", min=8, max=4096),
        Param("two_pass", False, "front-face and back-face occluder maps, SSMs merged by max (Sec. 3.5)"),
        Param(
            "accumulate",
            "float32",
            "precision of the blended sum; float16 (round to nearest) and float16-rtz "
            "(truncate) reproduce the paper's FP16 failure",
            choices=("float32", "float16", "float16-rtz"),
        ),
        Param("margin", 0.02, "border added around the occluders in the occluder map (fraction)", min=0.0, max=1.0),
    )

    def run(self, ctx, map_size, ssm_size, two_pass, accumulate, margin):
        smap = compute_soft_shadow_map(ctx.scene, map_size, ssm_size, two_pass, accumulate, margin, ctx.timer)
        with ctx.timer.phase("eye_projection"):
            pts, _, idx = ctx.points()
            tri = ctx.eye.tri_id.ravel()[idx]
            is_recv = ctx.flat.receiver[np.maximum(tri, 0)] & (tri >= 0)
            v = project_soft_shadow_map(pts, is_recv, smap.view.params(), smap.occlusion)
            out = ctx.scatter(v, idx)
        stats = dict(smap.stats)
        stats["eye_receiver_pixels"] = int(is_recv.sum())
        return MethodOutput(out, stats)
