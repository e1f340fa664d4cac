"""``soft-shadow-map``: Soft Shadow Maps (Atty, Holzschuch, Lapierre, Hasenfratz, Hansen, Sillion, CGF 2006),
rectangle and sphere lights.

The occluders seen from the center of the light become one micro-patch per occluder-map pixel
(:func:`discretize_occluders`); the fraction of the light each patch hides is computed at every
texel of the soft shadow map inside its penumbra extent (:func:`penumbra_extents`,
:func:`occlusion_percentage`), summed in draw order like GPU blending
(:func:`accumulate_soft_shadow_map`, optionally in FP16), clamped, and projected onto the eye view
(:func:`project_soft_shadow_map`). :func:`compute_soft_shadow_map` runs every step up to the map.
With a sphere light each patch is back-projected onto the disk facing the texel's receiver point and
its exact overlap with that disk is taken (:func:`occlusion_percentage_disk`).

Steps, parameters, deviations and known limits: ``docs/methods/soft-shadow-map.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numba
import numpy as np
from numba.cpython.unsafe.numbers import trailing_zeros

from .._jit import host_has_avx512f, kernel, py_callable, run_slots, run_threads
from ..analytic import disk_facing_frame, polygon_disk_area, quad_disk_area_small, quad_disk_area_small32
from ..errors import SoftShadowsError
from ..raster import View, rasterize_depth, rasterize_fragments
from ..raster.kernels import sample_bilinear, view_project
from ..raster.view import VP_B, VP_H, VP_L, VP_R, VP_T, VP_W, light_view
from ..scene.types import light_key
from .base import Method, MethodOutput, Param, register

BAND_ROWS = 4  # SSM rows per accumulation band (one thread sums one band; 2 until 2026-12-02)
FP16_MAX = 65504.0
CROSSING_BATCH = 4096  # sphere light: texel x patch pairs computed per vectorized batch
REFINE_ROUNDS = 2  # sphere light: narrowing passes of the penumbra extents (refine_extents_sphere)
# the SSM's resolution when ``ssm_size`` is 0 (the default): 256^2 with a rect light, 128^2 with a
# sphere light (same error against ground truth on the built-in scenes, 4x fewer texel x patch
# pairs: docs/results/soft-shadow-map.md, "Sphere light: a 128^2 soft shadow map")
SSM_SIZE_RECT = 256
SSM_SIZE_SPHERE = 128
#: the occluder map's resolution that ``map_size=0`` (the default) stands for: 256 with a rect light;
#: 208 with a sphere light, where the paper's "above 200 pixels does not bring an improvement"
#: holds on every built-in scene (the error against ground truth as at 256, within the spread that
#: the map's alignment gives between sizes; docs/methods/soft-shadow-map.md) for two thirds of the
#: micro-patches of the sphere's costlier accumulation
MAP_SIZE_RECT = 256
MAP_SIZE_SPHERE = 208


def default_ssm_size(light) -> int:
    """The SSM resolution that ``ssm_size=0`` stands for with ``light``: :data:`SSM_SIZE_SPHERE`
    for a sphere light, :data:`SSM_SIZE_RECT` for a rect light."""
    return SSM_SIZE_SPHERE if light.shape == "sphere" else SSM_SIZE_RECT


def default_map_size(light) -> int:
    """The occluder map resolution that ``map_size=0`` stands for with ``light``:
    :data:`MAP_SIZE_SPHERE` for a sphere light, :data:`MAP_SIZE_RECT` for a rect light."""
    return MAP_SIZE_SPHERE if light.shape == "sphere" else MAP_SIZE_RECT


# ---- 1. the light-aligned views ---------------------------------------------------------------
def light_half_extents(light, view: View) -> tuple[float, float]:
    """Half sizes (hx, hy) of the rectangle light along the view's right and up axes (sphere: the
    radius, twice)."""
    if light.shape == "sphere":
        return light.radius, light.radius
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


def _face_vertices(flat, which: str) -> np.ndarray:
    return flat.vertices[flat.face_vertices(which)]  # the indices: once per geometry


def compute_map_views(scene, map_size: int, ssm_size: int, margin: float = 0.02) -> tuple[View, View]:
    """(occluder-map view, SSM/receiver-map view), both from the light center along its normal,
    axis-aligned with the light and of its aspect ratio (square maps of N x N pixels). Computed once
    per geometry, light and sizes (passes over every vertex; cached on ``scene.flat``)."""
    key = ("ssm_map_views", light_key(scene.light), int(map_size), int(ssm_size), float(margin))
    return scene.flat.cached(key, lambda: _compute_map_views(scene, map_size, ssm_size, margin))


def _compute_map_views(scene, map_size: int, ssm_size: int, margin: float) -> tuple[View, View]:
    light, flat = scene.light, scene.flat
    occ_pts = _face_vertices(flat, "occluder")
    rec_pts = _face_vertices(flat, "receiver")
    ov = light_view(light, occ_pts, map_size, map_size, margin=margin)
    hx, hy = light_half_extents(light, ov)
    aspect = hx / hy
    ov = View(
        ov.origin, ov.right, ov.up, ov.forward, _with_aspect(ov.window, aspect), ov.near, ov.far, map_size, map_size
    )
    # both maps in one light frame (a sphere light's frame otherwise depends on the points)
    rv = light_view(light, rec_pts, ssm_size, ssm_size, margin=0.0, frame=(ov.right, ov.up, ov.forward))
    # Widest penumbra around the occluder window (projective units): a point at depth z_P, seen
    # from any light point, lands within hx (1/z_P - 1/z_R) of its central projection at depth z_R.
    # Sphere: light points fill a ball of radius rho (the facing disks), so also off the z = 0
    # plane: the offset is at most rho (1 + W) / (1 - rho / z_P) (1/z_P - 1/z_R), W the largest
    # |projective coordinate| of the occluder window.
    zo = ov.to_view(occ_pts)[:, 2]
    zo_min = max(float(zo[zo > ov.near * 0.5].min()) if np.any(zo > ov.near * 0.5) else ov.near, 1e-9)
    zr_max = rv.far
    l, r, b, t = ov.window
    if light.shape == "sphere":
        grow = (1.0 + max(abs(l), abs(r), abs(b), abs(t))) / (1.0 - hx / zo_min) if zo_min > hx else np.inf
        hx, hy = hx * grow, hy * grow
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
def _mesh_ids(flat, faces_mask, tri) -> np.ndarray:
    """Mesh id (int32, -1 where no triangle) per pixel of a map of the faces ``faces_mask``."""
    idx = np.flatnonzero(faces_mask)
    return np.where(tri >= 0, flat.mesh_id[idx][np.maximum(tri, 0)], -1).astype(np.int32)


def compute_receiver_depth_map(scene, view: View, mesh: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(depth (H,W) float32 +inf where empty, mesh id (H,W) int32 -1 where empty) of receivers.
    ``mesh=False``: the mesh ids are not needed (no mesh of role ``both``: the accumulation never
    reads them), zeros instead."""
    flat = scene.flat
    depth, tri = rasterize_depth(view, flat.vertices, flat.faces_where(flat.receiver), cull="none", tri=mesh)
    mesh = _mesh_ids(flat, flat.receiver, tri) if mesh else np.zeros(depth.shape, np.int32)
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


def compute_occluder_depth_map(
    scene, view: View, side: str = "nearest", mesh: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """(depth (H,W) float32 +inf where empty, mesh id (H,W) int32) of the occluders.

    ``side``: ``nearest`` (one pass: the usual depth buffer, no culling), ``front`` (closest
    front-facing faces) or ``back`` (furthest back-facing faces), the two maps of Sec. 3.5.
    ``mesh=False``: zeros instead of the mesh ids (see :func:`compute_receiver_depth_map`)."""
    flat = scene.flat
    faces = flat.faces_where(flat.occluder)  # once per geometry
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
        depth, tri = rasterize_depth(view, flat.vertices, faces, cull="back" if side == "front" else "none", tri=mesh)
    mesh = _mesh_ids(flat, flat.occluder, tri) if mesh else np.zeros(depth.shape, np.int32)
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


def penumbra_extents(patches, hx, hy, z_plane, svp):
    """Per micro-patch, the SSM texels ``[i0, i1] x [j0, j1]`` (inclusive; empty when i0 > i1)
    whose centers lie in the patch's penumbra rectangle on the virtual plane at depth ``z_plane``:
    (n, 4) int32, one contiguous block of the patches per thread (:func:`_penumbra_extents_slot`)."""
    out = np.empty((patches.shape[0], 4), np.int32)
    run_threads(_penumbra_extents_slot, patches, float(hx), float(hy), float(z_plane), svp, out)
    return out


@kernel(nogil=True, nrt=False)
def _penumbra_extents_slot(slot, patches, hx, hy, z_plane, svp, out, nslot):
    """Rows of ``out`` (:func:`penumbra_extents`) of slot ``slot``'s contiguous block of the
    patches (``run_slots``; each patch's row its own: the same whatever the slot count)."""
    n = patches.shape[0]
    l, r, b, t = svp[VP_L], svp[VP_R], svp[VP_B], svp[VP_T]
    W = svp[VP_W]
    H = svp[VP_H]
    dxs = (r - l) / W
    dys = (t - b) / H
    for k in range(slot * n // nslot, (slot + 1) * n // nslot):
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


@kernel(inline=True)
def _sphere_extent(x0, x1, y0, y1, z, rho, lzb, z_max, svp):
    """Texel range (fi0, fi1, fj0, fj1) (floats, inclusive, clipped to the map; empty when fi0 > fi1
    or fj0 > fj1) that contains the penumbra of the patch ``[x0, x1] x [y0, y1]`` at depth ``z`` for
    receivers at depths up to ``z_max``, light points in the box [-rho, rho]^2 x [-lzb, lzb]
    (:func:`penumbra_extents_sphere`): :func:`_sphere_extent_at` in the map of ``svp``."""
    l, r, b, t = svp[VP_L], svp[VP_R], svp[VP_B], svp[VP_T]
    W = svp[VP_W]
    H = svp[VP_H]
    return _sphere_extent_at(x0, x1, y0, y1, z, rho, lzb, z_max, l, r, b, t, W, H, (r - l) / W, (t - b) / H)


@kernel(inline=True)
def _sphere_extent_at(x0, x1, y0, y1, z, rho, lzb, z_max, l, r, b, t, W, H, dxs, dys):
    """:func:`_sphere_extent` in the map of window (l, r, b, t), W x H texels of dxs x dys. Every
    branch is a select (the cases' values computed, one kept), so that a loop of it over patches
    vectorizes (:func:`refine_extents_sphere_slot`); the same operations in the same order as the
    branches were, so the same values."""
    # the patch in front of every receiver (z < z_max), else empty (selected at the end).
    # The shadows at z_max are divided by z_max once, after the min / max: dividing by a positive
    # number is monotone and correctly rounded, so the bounds are those of dividing each one (4
    # divisions instead of 32). l_x and l_y take the values +-rho independently: the x and y
    # bounds are separate, so one loop over +-rho serves both
    X_lo = np.inf
    X_hi = -np.inf
    Y_lo = np.inf
    Y_hi = -np.inf
    for cz in range(2):  # the box's 8 corners: s depends on l_z only (2 divisions, not 8)
        lz = lzb if cz else -lzb
        s = (z_max - lz) / (z - lz)
        for c in range(2):
            lx = rho if c else -rho
            for cx in range(2):
                qx = x0 if cx == 0 else x1
                X = lx + (qx - lx) * s
                X_lo = min(X_lo, X)
                X_hi = max(X_hi, X)
            ly = lx
            for cy in range(2):
                qy = y0 if cy == 0 else y1
                Y = ly + (qy - ly) * s
                Y_lo = min(Y_lo, Y)
                Y_hi = max(Y_hi, Y)
    x_lo = min(min(x0 / z, x1 / z), X_lo / z_max)
    x_hi = max(max(x0 / z, x1 / z), X_hi / z_max)
    y_lo = min(min(y0 / z, y1 / z), Y_lo / z_max)
    y_hi = max(max(y0 / z, y1 / z), Y_hi / z_max)
    # the patch inside the box of light points (z <= lzb): every texel
    outside = z > lzb
    x_lo = x_lo if outside else l
    x_hi = x_hi if outside else r
    y_lo = y_lo if outside else b
    y_hi = y_hi if outside else t
    fj0 = max(math.ceil((x_lo - l) / dxs - 0.5), 0.0)
    fj1 = min(math.floor((x_hi - l) / dxs - 0.5), W - 1.0)
    fi0 = max(math.ceil((t - y_hi) / dys - 0.5), 0.0)
    fi1 = min(math.floor((t - y_lo) / dys - 0.5), H - 1.0)
    front = z < z_max
    return (fi0 if front else 1.0), (fi1 if front else 0.0), (fj0 if front else 1.0), (fj1 if front else 0.0)


@kernel
def penumbra_extents_sphere(patches, rho, z_plane, svp):
    """:func:`penumbra_extents` for a sphere light (its disks facing each point lie in the ball of
    radius ``rho`` about C_L). The shadow on the plane at depth z of a patch corner q seen from a
    light point l is projective in l and in q, so it lies in the convex hull of the 32 shadows of
    the patch's 4 corners seen from the 8 corners of the box [-rho, rho]^3; in projective
    coordinates each such shadow moves monotonically in 1/z from q's own projection (depth z_O)
    to its projection at ``z_plane``, so the rectangle bounding both sets contains the patch's
    penumbra at every receiver depth. Empty when the patch is not in front of the ball.
    :func:`refine_extents_sphere` narrows these ranges."""
    n = patches.shape[0]
    out = np.empty((n, 4), np.int32)
    for k in range(n):
        _patch_sphere_extent(patches, k, rho, z_plane, svp, out)
    return out


@kernel(inline=True)
def _patch_sphere_extent(patches, k, rho, z_plane, svp, out):
    """Patch k's :func:`_sphere_extent` into ``out[k]`` (rows i0, i1, columns j0, j1; empty: 1, 0, 1, 0)."""
    fi0, fi1, fj0, fj1 = _sphere_extent(
        patches[k, 0], patches[k, 1], patches[k, 2], patches[k, 3], patches[k, 4], rho, rho, z_plane, svp
    )
    if fj0 > fj1 or fi0 > fi1:
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = 1, 0, 1, 0
    else:
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = int(fi0), int(fi1), int(fj0), int(fj1)


@kernel
def max_pyramid(depth):
    """Max-reduction pyramid of ``depth`` (H,W) (0 where no receiver): level k holds the maximum over
    blocks of 2^k x 2^k texels, down to 1 x 1. Returns (values, level offsets, level heights, level
    widths), the levels stored row-major one after the other in ``values``."""
    H, W = depth.shape
    n_lev = 1
    h, w = H, W
    total = h * w
    while h > 1 or w > 1:
        h = (h + 1) // 2
        w = (w + 1) // 2
        total += h * w
        n_lev += 1
    vals = np.zeros(total, np.float32)
    off = np.zeros(n_lev, np.int64)
    hs = np.zeros(n_lev, np.int64)
    ws = np.zeros(n_lev, np.int64)
    hs[0], ws[0] = H, W
    for i in range(H):
        for j in range(W):
            vals[i * W + j] = depth[i, j]
    for k in range(1, n_lev):
        ph, pw, po = hs[k - 1], ws[k - 1], off[k - 1]
        h = (ph + 1) // 2
        w = (pw + 1) // 2
        off[k] = po + ph * pw
        hs[k], ws[k] = h, w
        for i in range(h):
            for j in range(w):
                m = vals[po + (2 * i) * pw + 2 * j]
                if 2 * j + 1 < pw:
                    m = max(m, vals[po + (2 * i) * pw + 2 * j + 1])
                if 2 * i + 1 < ph:
                    m = max(m, vals[po + (2 * i + 1) * pw + 2 * j])
                    if 2 * j + 1 < pw:
                        m = max(m, vals[po + (2 * i + 1) * pw + 2 * j + 1])
                vals[off[k] + i * w + j] = m
    return vals, off, hs, ws


@kernel(inline=True)
def _rect_max(vals, off, ws, i0, i1, j0, j1):
    """Upper bound of the maximum over texels [i0, i1] x [j0, j1] from :func:`max_pyramid`: the
    maximum of the (at most 2 x 2) cells of the first level whose blocks cover the rectangle."""
    k = 0
    while (i1 >> k) - (i0 >> k) > 1 or (j1 >> k) - (j0 >> k) > 1:
        k += 1
    m = np.float32(0.0)
    w = ws[k]
    for i in range(i0 >> k, (i1 >> k) + 1):
        for j in range(j0 >> k, (j1 >> k) + 1):
            m = max(m, vals[off[k] + i * w + j])
    return m


#: patches per block of :func:`refine_extents_sphere_slot`
_REFINE_BLOCK = 64


@kernel(nogil=True, nrt=False)
def refine_extents_sphere_slot(slot, patches, ext, rho, pyr_vals, pyr_off, pyr_ws, svp, rounds, z_plane, sc, nslot):
    """Narrow :func:`penumbra_extents_sphere`'s ranges in place, ``rounds`` times: a texel p that the
    patch shadows lies in its current range R, so (1) its receiver depth is at most the largest one
    in R (:func:`_rect_max`, instead of the deepest receiver of the whole map) and (2) its facing
    disk's light points l satisfy |l_z| <= rho sin(theta), theta the largest angle from the light's
    axis of a texel of R (l is orthogonal to p, |l| <= rho), instead of |l_z| <= rho. The range
    recomputed with both (:func:`_sphere_extent`), intersected with R, still contains p. A range
    without receivers deeper than the patch becomes empty (and stays so). ``z_plane`` > 0:
    ``ext``'s rows are first set to :func:`penumbra_extents_sphere`'s ranges for receivers up to
    that depth (the same arithmetic, in this parallel pass instead of a serial pass of its own).

    By blocks of ``_REFINE_BLOCK`` patches, each step over the whole block: the patches copied to
    the slot's scratch ``sc[slot]`` (11, block), the ranges (:func:`_sphere_extent_at`, branch-free:
    a loop of it vectorizes), the pyramid's bounds per patch (scalar), the intersections: the same
    values as patch by patch (2.03 -> 0.76 ms on `bunny`'s 27.7k patches, two threads). Run by
    ``run_slots``: slot ``slot`` of ``nslot`` takes the ``slot``-th of ``nslot`` contiguous runs of
    patches."""
    l, r, b, t = svp[VP_L], svp[VP_R], svp[VP_B], svp[VP_T]
    W = svp[VP_W]
    H = svp[VP_H]
    dxs = (r - l) / W
    dys = (t - b) / H
    n = patches.shape[0]
    s = sc[slot]  # rows: the patch (5), z_max, lzb, the range (4)
    for q0 in range(slot * n // nslot, (slot + 1) * n // nslot, _REFINE_BLOCK):
        m = min(q0 + _REFINE_BLOCK, (slot + 1) * n // nslot) - q0
        for i in range(m):
            for c in range(5):
                s[c, i] = patches[q0 + i, c]
        if z_plane > 0.0:  # penumbra_extents_sphere's ranges (_patch_sphere_extent)
            for i in range(m):
                s[7, i], s[8, i], s[9, i], s[10, i] = _sphere_extent_at(
                    s[0, i], s[1, i], s[2, i], s[3, i], s[4, i], rho, rho, z_plane, l, r, b, t, W, H, dxs, dys
                )
            for i in range(m):
                k = q0 + i
                fi0, fi1, fj0, fj1 = s[7, i], s[8, i], s[9, i], s[10, i]
                if fj0 > fj1 or fi0 > fi1:
                    ext[k, 0], ext[k, 1], ext[k, 2], ext[k, 3] = 1, 0, 1, 0
                else:
                    ext[k, 0], ext[k, 1], ext[k, 2], ext[k, 3] = int(fi0), int(fi1), int(fj0), int(fj1)
        for _ in range(rounds):
            for i in range(m):
                k = q0 + i
                i0, i1, j0, j1 = ext[k, 0], ext[k, 1], ext[k, 2], ext[k, 3]
                if i0 > i1 or j0 > j1:
                    s[5, i] = 0.0  # (an empty range: its result is not used)
                    s[6, i] = rho
                    continue
                ux = max(abs(l + (j0 + 0.5) * dxs), abs(l + (j1 + 0.5) * dxs))
                uy = max(abs(t - (i0 + 0.5) * dys), abs(t - (i1 + 0.5) * dys))
                u2 = ux * ux + uy * uy
                s[5, i] = np.float64(_rect_max(pyr_vals, pyr_off, pyr_ws, i0, i1, j0, j1))
                s[6, i] = rho * math.sqrt(u2 / (1.0 + u2))
            for i in range(m):
                s[7, i], s[8, i], s[9, i], s[10, i] = _sphere_extent_at(
                    s[0, i], s[1, i], s[2, i], s[3, i], s[4, i], rho, s[6, i], s[5, i], l, r, b, t, W, H, dxs, dys
                )
            for i in range(m):
                k = q0 + i
                i0, i1, j0, j1 = ext[k, 0], ext[k, 1], ext[k, 2], ext[k, 3]
                if i0 > i1 or j0 > j1:
                    continue
                fi0, fi1, fj0, fj1 = s[7, i], s[8, i], s[9, i], s[10, i]
                n0 = max(int(fi0), i0) if fi0 <= fi1 else 1
                n1 = min(int(fi1), i1) if fi0 <= fi1 else 0
                m0 = max(int(fj0), j0) if fj0 <= fj1 else 1
                m1 = min(int(fj1), j1) if fj0 <= fj1 else 0
                if n0 > n1 or m0 > m1:
                    n0, n1, m0, m1 = 1, 0, 1, 0
                ext[k, 0], ext[k, 1], ext[k, 2], ext[k, 3] = n0, n1, m0, m1


def refine_extents_sphere(patches, ext, rho, pyr_vals, pyr_off, pyr_ws, svp, rounds, z_plane=0.0) -> np.ndarray:
    """:func:`refine_extents_sphere_slot` over every patch, one slot per thread: ``ext``, narrowed
    in place."""
    sc = np.empty((numba.config.NUMBA_NUM_THREADS, 11, _REFINE_BLOCK))
    run_threads(
        refine_extents_sphere_slot,
        patches,
        ext,
        float(rho),
        pyr_vals,
        pyr_off,
        pyr_ws,
        svp,
        int(rounds),
        float(z_plane),
        sc,
    )
    return ext


# ---- 6. the fragment program: percentage of occlusion ------------------------------------------
@kernel(inline=True)
def _sat(x):
    """Clamp to [0, 1] (the SAT modifier); written as selects so that loops vectorize."""
    x = x if x > 0.0 else 0.0
    return x if x < 1.0 else 1.0


_F0 = np.float32(0.0)
_F1 = np.float32(1.0)
_FH = np.float32(0.5)
_INV_PI32 = np.float32(1.0 / math.pi)


@kernel(inline=True)
def _overlap32(p, q):
    """``sat(q) - sat(p)`` for p <= q (float32), the same value bit for bit in fewer operations:
    where p < 1 and q > 0 it subtracts the same two values, sat(q) = min(q, 1) and
    sat(p) = max(p, 0); otherwise (p >= 1 or q <= 0) both give +0. Each select is written on
    its own, so that LLVM vectorizes it as one compare and one blend (nested, they took more)."""
    hi = q if q < _F1 else _F1
    lo = p if p > _F0 else _F0
    d = hi - lo
    return d if d > _F0 else _F0


@kernel(inline=True)
def _occlusion_percentage32(k, a0, a1, c0, c1):
    """:func:`occlusion_percentage` in float32 arithmetic (the precision of a GPU fragment program;
    16 vector lanes instead of 8): ``(sat(b) - sat(a)) (sat(d) - sat(c))`` with each difference
    taken by :func:`_overlap32` (a <= b and c <= d: a0 <= a1, c0 <= c1 and k >= 0)."""
    return _overlap32(k * a0 + _FH, k * a1 + _FH) * _overlap32(k * c0 + _FH, k * c1 + _FH)


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
        py_callable(occlusion_percentage)(
            k,
            (x0 - ux * zo) / (2 * hx),
            (x1 - ux * zo) / (2 * hx),
            (y0 - uy * zo) / (2 * hy),
            (y1 - uy * zo) / (2 * hy),
        )
    )


@kernel(inline=True)
def _clip_height(ix, iy, iz, ih, n, level, keep_above, ox, oy, oz, oh):
    """Sutherland-Hodgman: the polygon (ix, iy, iz)[:n] with heights ih, clipped to
    h >= level (``keep_above``) or h <= level; written to (ox, oy, oz, oh), returns its size."""
    m = 0
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        di = ih[i] - level if keep_above else level - ih[i]
        dj = ih[j] - level if keep_above else level - ih[j]
        if di >= 0.0:
            ox[m] = ix[i]
            oy[m] = iy[i]
            oz[m] = iz[i]
            oh[m] = ih[i]
            m += 1
        if (di >= 0.0) != (dj >= 0.0):
            f = di / (di - dj)
            ox[m] = ix[i] + f * (ix[j] - ix[i])
            oy[m] = iy[i] + f * (iy[j] - iy[i])
            oz[m] = iz[i] + f * (iz[j] - iz[i])
            oh[m] = level
            m += 1
    return m


@kernel(inline=True)
def _disk_frame(px, py, pz, rho, out):
    """The facing disk of receiver point p = (px, py, pz) (light frame, C_L at the origin):
    ``out`` = (w, e1, e2, |p|, kappa = rho/|p|, sqrt(1 + kappa^2)), w = p/|p| the disk's normal, e1, e2
    its in-plane axes (kappa: the tangent of the half-angle of the cone from p onto the disk)."""
    wx, wy, wz, e1x, e1y, e1z, e2x, e2y, e2z, hp = disk_facing_frame(px, py, pz)
    out[0] = wx
    out[1] = wy
    out[2] = wz
    out[3] = e1x
    out[4] = e1y
    out[5] = e1z
    out[6] = e2x
    out[7] = e2y
    out[8] = e2z
    out[9] = hp
    out[10] = rho / hp
    out[11] = math.sqrt(1.0 + out[10] * out[10])


@kernel(nogil=True)
def disk_frames_slot(slot, recv_depth, svp, rho, out, nslot):
    """:func:`_disk_frame` of every SSM texel's receiver point into ``out``: 12 planes (12,H,W)
    (contiguous along rows, for the vectorized pass), left as they are (zeros) where no receiver.
    Run by ``run_slots``: slot ``slot`` of ``nslot`` takes every ``nslot``-th row."""
    H, W = recv_depth.shape
    l, r, b, t = svp[VP_L], svp[VP_R], svp[VP_B], svp[VP_T]
    dxs = (r - l) / W
    dys = (t - b) / H
    f = np.empty(12)
    for i in range(slot, H, nslot):
        uy = t - (i + 0.5) * dys
        for j in range(W):
            zr = np.float64(recv_depth[i, j])
            if zr > 0.0:
                ux = l + (j + 0.5) * dxs
                _disk_frame(ux * zr, uy * zr, zr, rho, f)
                for k in range(12):
                    out[k, i, j] = f[k]


def disk_frames(recv_depth, svp, rho) -> np.ndarray:
    """:func:`disk_frames_slot` over the whole map, one slot per thread: (12,H,W) float64, zeros
    where no receiver."""
    out = np.zeros((12, *recv_depth.shape))
    run_threads(disk_frames_slot, recv_depth, svp, float(rho), out)
    return out


@kernel(inline=True)
def _outside_disk(u0, u1, u2, u3, v0, v1, v2, v3):
    """True when the quadrilateral's bounding circle (about its corners' mean) lies outside the
    unit disk: then it hides nothing."""
    cu = 0.25 * (u0 + u1 + u2 + u3)
    cv = 0.25 * (v0 + v1 + v2 + v3)
    r2 = max(
        max((u0 - cu) * (u0 - cu) + (v0 - cv) * (v0 - cv), (u1 - cu) * (u1 - cu) + (v1 - cv) * (v1 - cv)),
        max((u2 - cu) * (u2 - cu) + (v2 - cv) * (v2 - cv), (u3 - cu) * (u3 - cu) + (v3 - cv) * (v3 - cv)),
    )
    rq = 1.0 + math.sqrt(r2)
    return cu * cu + cv * cv >= rq * rq


@kernel(inline=True)
def _quad_heights(wx, wy, wz, x0, x1, y0, y1, zo):
    """Heights w.q above the plane of the disk of normal w of the patch corners (x0,y0) (x1,y0)
    (x1,y1) (x0,y1) at depth z_O (everything is affine in x, y)."""
    hz = wz * zo
    return wx * x0 + wy * y0 + hz, wx * x1 + wy * y0 + hz, wx * x1 + wy * y1 + hz, wx * x0 + wy * y1 + hz


@kernel(inline=True)
def _corner_heights(F, fi, fj, x0, x1, y0, y1, zo):
    """:func:`_quad_heights` for the disk facing texel (fi, fj) (``F``: :func:`disk_frames`)."""
    return _quad_heights(F[0, fi, fj], F[1, fi, fj], F[2, fi, fj], x0, x1, y0, y1, zo)


@kernel(inline=True)
def _project_quad(hp, kap, e1x, e1y, e1z, e2x, e2y, e2z, x0, x1, y0, y1, zo, h0, h1, h2, h3):
    """Disk coordinates (u0..u3, v0..v3) (radius 1) of the patch corners projected from the receiver
    point p (|p| = ``hp``, kappa = rho/|p|) onto the plane of its facing disk (axes e1, e2):
    ``(e1.q, e2.q) / (kappa (|p| - h))``, h the corner's :func:`_quad_heights` (all in (0, |p|))."""
    az = e1z * zo
    bz = e2z * zo
    d0 = 1.0 / (kap * (hp - h0))
    d1 = 1.0 / (kap * (hp - h1))
    d2 = 1.0 / (kap * (hp - h2))
    d3 = 1.0 / (kap * (hp - h3))
    return (
        (e1x * x0 + e1y * y0 + az) * d0,
        (e1x * x1 + e1y * y0 + az) * d1,
        (e1x * x1 + e1y * y1 + az) * d2,
        (e1x * x0 + e1y * y1 + az) * d3,
        (e2x * x0 + e2y * y0 + bz) * d0,
        (e2x * x1 + e2y * y0 + bz) * d1,
        (e2x * x1 + e2y * y1 + bz) * d2,
        (e2x * x0 + e2y * y1 + bz) * d3,
    )


@kernel(inline=True)
def _project_corners(F, fi, fj, x0, x1, y0, y1, zo, h0, h1, h2, h3):
    """:func:`_project_quad` for the disk facing texel (fi, fj) (``F``: :func:`disk_frames`)."""
    return _project_quad(
        F[9, fi, fj],
        F[10, fi, fj],
        F[3, fi, fj],
        F[4, fi, fj],
        F[5, fi, fj],
        F[6, fi, fj],
        F[7, fi, fj],
        F[8, fi, fj],
        x0,
        x1,
        y0,
        y1,
        zo,
        h0,
        h1,
        h2,
        h3,
    )


@kernel(inline=True)
def occlusion_percentage_disk(F, fi, fj, x0, x1, y0, y1, zo, sx, sy, sz, sh, tx, ty, tz, th):
    """Fraction of a sphere light hidden by one micro-patch at one receiver point p: the light is
    the disk of radius rho through C_L (the light frame's origin) facing p (V's definition),
    ``F[:, fi, fj]`` = :func:`_disk_frame` of p (indices, not a row view: a view costs a contended
    reference-count update). The patch ``[x0, x1] x [y0, y1]`` at depth z_O is projected
    from p onto the disk's plane (the paper's back-projection, onto that plane instead of the
    rectangle's): a patch point q lands at disk coordinates
    ``(e1.q, e2.q) / (kappa (|p| - w.q))``, kappa = rho/|p| (radius 1); the overlap is the exact
    area of that quadrilateral intersected with the unit disk
    (:func:`softshadows.analytic.polygon_disk_area`: triangles and circular sectors), over pi.
    Shortcuts with the same result: a quadrilateral whose bounding box or bounding circle misses
    the disk hides 0, one inside it hides its own area (shoelace). Parts of the patch behind the disk's plane or not
    in front of p (w.q outside (0, |p|)) hide nothing and are clipped off first.
    ``sx..th``: scratch arrays of 8."""
    hp, kap = F[9, fi, fj], F[10, fi, fj]
    hmax = hp * (1.0 - 1e-9)
    h0, h1, h2, h3 = _corner_heights(F, fi, fj, x0, x1, y0, y1, zo)
    if h0 > 0.0 and h1 > 0.0 and h2 > 0.0 and h3 > 0.0 and h0 < hmax and h1 < hmax and h2 < hmax and h3 < hmax:
        u0, u1, u2, u3, v0, v1, v2, v3 = _project_corners(F, fi, fj, x0, x1, y0, y1, zo, h0, h1, h2, h3)
        if max(u0, u1, u2, u3) <= -1.0 or min(u0, u1, u2, u3) >= 1.0:
            return 0.0
        if max(v0, v1, v2, v3) <= -1.0 or min(v0, v1, v2, v3) >= 1.0:
            return 0.0
        if _outside_disk(u0, u1, u2, u3, v0, v1, v2, v3):
            return 0.0
        if (
            u0 * u0 + v0 * v0 <= 1.0
            and u1 * u1 + v1 * v1 <= 1.0
            and u2 * u2 + v2 * v2 <= 1.0
            and u3 * u3 + v3 * v3 <= 1.0
        ):
            # a convex quadrilateral inside the (convex) disk: its own area
            return 0.5 * abs((u0 - u2) * (v1 - v3) - (u1 - u3) * (v0 - v2)) / math.pi
        a, ok = quad_disk_area_small(u0, u1, u2, u3, v0, v1, v2, v3)  # the common crossing case
        if ok:
            return a / math.pi
        tx[0] = u0
        tx[1] = u1
        tx[2] = u2
        tx[3] = u3
        ty[0] = v0
        ty[1] = v1
        ty[2] = v2
        ty[3] = v3
        return polygon_disk_area(tx, ty, 4, 1.0) / math.pi
    # general case: clip to 0 < w.q < |p| first
    sx[0] = x0
    sx[1] = x1
    sx[2] = x1
    sx[3] = x0
    sy[0] = y0
    sy[1] = y0
    sy[2] = y1
    sy[3] = y1
    sh[0] = h0
    sh[1] = h1
    sh[2] = h2
    sh[3] = h3
    for c in range(4):
        sz[c] = zo
    n = _clip_height(sx, sy, sz, sh, 4, 0.0, True, tx, ty, tz, th)
    n = _clip_height(tx, ty, tz, th, n, hmax, False, sx, sy, sz, sh)
    if n < 3:
        return 0.0
    for c in range(n):
        d = 1.0 / (kap * (hp - sh[c]))
        tx[c] = (F[3, fi, fj] * sx[c] + F[4, fi, fj] * sy[c] + F[5, fi, fj] * sz[c]) * d
        ty[c] = (F[6, fi, fj] * sx[c] + F[7, fi, fj] * sy[c] + F[8, fi, fj] * sz[c]) * d
    return polygon_disk_area(tx, ty, n, 1.0) / math.pi


def occlusion_percentage_disk_at(patch, ux, uy, z_r, rho) -> float:
    """Reference form of :func:`occlusion_percentage_disk` for one patch ``(x0, x1, y0, y1, z_O)``
    and one receiver point (projective ``ux, uy`` and depth ``z_r``); 0 unless z_O < z_r."""
    x0, x1, y0, y1, zo = (float(v) for v in patch)
    if not z_r > zo:
        return 0.0
    F = np.empty((12, 1, 1))
    f = np.empty(12)
    py_callable(_disk_frame)(ux * z_r, uy * z_r, z_r, rho, f)
    F[:, 0, 0] = f
    sc = [np.empty(8) for _ in range(8)]
    return float(py_callable(occlusion_percentage_disk)(F, 0, 0, x0, x1, y0, y1, zo, *sc))


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


#: fewer list entries than this: :func:`bin_patches_by_band` fills the lists on the calling thread
#: (`bunny`'s 126k-245k: 0.31-0.41 ms in all, against 0.56-0.63 ms with a two-slot launch)
_SERIAL_BAND_ENTRIES = 1 << 20


def bin_patches_by_band(ext, n_bands, band_rows):
    """CSR lists (ptr (n_bands+1,), idx) of the micro-patches whose extent meets each band of
    ``band_rows`` SSM rows, each list in micro-patch (draw) order: the offsets and each patch's
    range of bands in one serial pass (:func:`_band_offsets`), then the lists filled
    (:func:`_band_fill_slot`): on the calling thread up to ``_SERIAL_BAND_ENTRIES`` entries, else
    by the threads, each its own run of bands holding about an equal share of the entries (the
    same lists whatever the thread count)."""
    bands = np.empty((ext.shape[0], 2), np.int32)
    ptr = _band_offsets(ext, n_bands, band_rows, bands)
    idx = np.empty(ptr[n_bands], np.int32)
    fill = ptr[:n_bands].copy()
    nslot = numba.get_num_threads() if ptr[n_bands] >= _SERIAL_BAND_ENTRIES else 1
    split = np.empty(nslot + 1, np.int64)
    split[0], split[nslot] = 0, n_bands
    split[1:nslot] = np.searchsorted(ptr, np.arange(1, nslot) * (int(ptr[n_bands]) / nslot))
    run_slots(_band_fill_slot, nslot, bands, idx, fill, split)
    return ptr, idx


@kernel
def _band_offsets(ext, n_bands, band_rows, bands):
    """(n_bands + 1,) int64: where each band's list starts in :func:`bin_patches_by_band`'s idx;
    and each patch's bands [bands[k, 0], bands[k, 1]) (empty for an empty extent), so that the
    fill divides nothing."""
    n = ext.shape[0]
    # counts per band from a difference array (two updates per patch, not one per band it meets):
    # after the first prefix sum cnt[b + 1] is the count of band b, after the second the offsets
    cnt = np.zeros(n_bands + 2, np.int64)
    for k in range(n):
        if ext[k, 0] <= ext[k, 1]:
            b0 = ext[k, 0] // band_rows
            b1 = ext[k, 1] // band_rows
            bands[k, 0] = b0
            bands[k, 1] = b1 + 1
            cnt[b0 + 1] += 1
            cnt[b1 + 2] -= 1
        else:
            bands[k, 0] = 0
            bands[k, 1] = 0
    for bnd in range(1, n_bands + 1):
        cnt[bnd + 1] += cnt[bnd]
    for bnd in range(n_bands):
        cnt[bnd + 1] += cnt[bnd]
    return cnt[: n_bands + 1].copy()


@kernel(nogil=True, nrt=False)
def _band_fill_slot(slot, bands, idx, fill, split):
    """Slot ``slot``'s bands ``split[slot]`` to ``split[slot + 1] - 1`` of
    :func:`bin_patches_by_band`'s lists: every patch in order, appended to those of its bands
    (``bands``: each patch's [first, last + 1); ``fill``: each band's next place; no two slots
    touch one band). Run by ``run_slots``."""
    b0, b1 = split[slot], split[slot + 1]
    for k in range(bands.shape[0]):
        for bnd in range(max(np.int64(bands[k, 0]), b0), min(np.int64(bands[k, 1]), b1)):
            idx[fill[bnd]] = k
            fill[bnd] += 1


@kernel(inline=True, nrt=False)
def _clamp_rows(ssm, r0, r1):
    """Clamp the summed percentages of SSM rows ``r0..r1`` to [0, 1] in place (the paper clamps at
    display; NaN -> 0). Each slot kernel clamps a band's rows once the band is summed: no pass of
    its own over the map."""
    W = ssm.shape[1]
    for i in range(r0, r1 + 1):
        for j in range(W):
            v = ssm[i, j]
            ssm[i, j] = 0.0 if not (v > 0.0) else (1.0 if v > 1.0 else v)


def _host_lanes() -> int:
    """float32 lanes of the host's vectors as LLVM targets them: 16 with AVX-512, else 8. The row
    passes (both lights) cover whole vectors of this many texels (a row that is not a whole number
    of vectors ends in a scalar remainder loop; rounding up to 16 on an 8-lane host ran 15% more
    vectors on `bunny`'s sphere rows). Only the speed depends on it: the extra texels add exactly 0
    (and are not flagged). Without a feature query: 16, the wider vectors are always whole."""
    return 16 if host_has_avx512f(default=True) else 8


ROW_LANES = _host_lanes()  # float32 sums: the row passes cover whole vectors of this many texels


@kernel(inline=True, nrt=False)
def _rect_row_pass(recv_depth, recv_mesh, ssm, ramp, i, base, nl, lo, hi, zo, ax, dax, wx, c0, c1, pm, check_mesh):
    """One SSM row of one micro-patch for :func:`accumulate_soft_shadow_map` with float32 sums:
    the fragment program (:func:`_occlusion_percentage32`, float32 arithmetic like a GPU's) at the
    ``nl`` texels ``[base, base + nl)``, which contain the patch's columns ``[base + lo, base + hi)``.
    Branch-free, so it vectorizes; the caller makes ``nl`` a multiple of :data:`ROW_LANES` (whole
    vectors, no scalar remainder loop). A texel outside the patch's columns, whose receiver is not
    behind the patch, or (``check_mesh``) of the patch's own mesh gets k = 0: it adds exactly 0.
    ``ax - jj dax`` with jj = column - (base + lo) is the x term a0 (``jj`` as float32(ramp) -
    float32(lo): exact), so every texel of the patch's columns gets the value the per-column program gives.
    ``ramp``: 0, 1, 2, ... (int32; 8 lanes per compare and conversion, unlike int64: an int64 column
    index made LLVM convert it to float32 one lane at a time). 2-D subscripts, no row views (a view
    costs a contended atomic refcount update); unsigned indices: no negative-index wraparound."""
    ii = np.uint64(i)
    ub = np.uint64(base)
    lo32 = np.int32(lo)
    hi32 = np.int32(hi)
    lof = np.float32(lo)
    pm32 = np.int32(pm)
    not_check = not check_mesh
    zo32 = np.float32(zo)
    ax32 = np.float32(ax)
    dax32 = np.float32(dax)
    wx32 = np.float32(wx)
    c032 = np.float32(c0)
    c132 = np.float32(c1)
    for jj in range(nl):
        ju = np.uint64(jj)
        jx = ub + ju
        zr = recv_depth[ii, jx]
        rj = ramp[ju]
        k = zr / (zr - zo32)
        # no short-circuit: it vectorizes
        ok = (zr > zo32) & (not_check | (recv_mesh[ii, jx] != pm32)) & (rj >= lo32) & (rj < hi32)
        k = k if ok else _F0
        # float32(rj) - float32(lo) is exact (integers < 2^24): float32 of the column index jj
        a0 = ax32 - (np.float32(rj) - lof) * dax32
        ssm[ii, jx] += _occlusion_percentage32(k, a0, a0 + wx32, c032, c132)


@kernel(nogil=True, nrt=False)
def accumulate_soft_shadow_map_slot(
    slot,
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
    touched,
    ramp,
    nslot,
):
    """Slot ``slot`` of :func:`accumulate_soft_shadow_map` (``run_slots``): bands slot, slot + nslot, ..."""
    H, W = recv_depth.shape
    l, r, b, t = svp[VP_L], svp[VP_R], svp[VP_B], svp[VP_T]
    dxs = (r - l) / W
    dys = (t - b) / H
    n_bands = band_ptr.shape[0] - 1
    # bands dealt round-robin to the ``nslot`` slots, one per thread (with the shadow in a few
    # bands, contiguous halves would leave a thread idle)
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
            # the float32 row pass runs over whole vectors of ROW_LANES texels from ``base``
            nl = ROW_LANES * ((j1 - j0 + ROW_LANES - 1) // ROW_LANES)
            if nl <= W:
                base = min(j0, W - nl)
            else:
                base = j0
                nl = j1 - j0
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
                elif check_mesh:  # one instance per value of check_mesh: the mesh test folds away
                    _rect_row_pass(
                        recv_depth,
                        recv_mesh,
                        ssm,
                        ramp,
                        i,
                        base,
                        nl,
                        j0 - base,
                        j1 - base,
                        zo,
                        ax,
                        dax,
                        wx,
                        c0,
                        c1,
                        pm,
                        True,
                    )
                else:
                    _rect_row_pass(
                        recv_depth,
                        recv_mesh,
                        ssm,
                        ramp,
                        i,
                        base,
                        nl,
                        j0 - base,
                        j1 - base,
                        zo,
                        ax,
                        dax,
                        wx,
                        c0,
                        c1,
                        pm,
                        False,
                    )
        _clamp_rows(ssm, r0, r1)
        touched[bnd] = cnt


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
    half precision after every addition (scalar loop; ``rtz``: toward zero). Each band's sums are
    then clamped to [0, 1] (:func:`_clamp_rows`). Returns the fragment-program invocations per
    band.

    ``recv_depth``: receiver depths with 0 where there is no receiver. A texel whose receiver is
    not behind the patch (or, with ``check_mesh``, belongs to the patch's own mesh: no
    self-shadowing) gets k = 0, hence a percentage of exactly 0: the float32 inner loop has no
    branch and vectorizes (adding 0.0 leaves the sum unchanged)."""
    touched = np.zeros(band_ptr.shape[0] - 1, np.int64)
    run_slots(
        accumulate_soft_shadow_map_slot,
        nslot,
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
        touched,
        np.arange(recv_depth.shape[1], dtype=np.int32),
        nslot,
    )
    return touched


_HM32 = np.float32(1.0 - 2.0**-20)  # float32 row pass: corners this close to |p| go to the exact path
_ROUND32 = 4e-6  # float32 row pass: margin (relative to |q|^2) of the inside / outside tests


@kernel(inline=True, noalias=True)
def _disk_row_pass(F, recv_depth, recv_mesh, ssm, flags, ramp, ia, ib, fw, base, nl, j0, j1, pm, check_mesh, pk, p):
    """SSM rows ``ia..ib`` of one micro-patch for :func:`accumulate_soft_shadow_map_sphere`, each
    row one branch-free loop, in
    float32 arithmetic (8 or 16 vector lanes) and without projecting the corners (no per-corner division).
    ``F``: :func:`disk_frames32` of the texels. With h_c the corners' heights w.q (as in
    :func:`_corner_heights`) and d_c = |p| - h_c, a corner q projects inside the facing disk iff its
    distance from the axis of the cone from p onto the disk is at most kappa d_c:
    ``|q|^2 - h_c^2 <= kappa^2 d_c^2``. All four inside: the projected quadrilateral's area over
    pi rho^2 is ``A (z_R - z_O) (d1 + d3) / (2 pi kappa^2 d0 d1 d2 d3)`` (the two triangles' central
    projections: area' = t0 t1 t2 A_tri (z_R - z_O) / |p| with t_c = |p| / d_c; A the patch's
    area), which is added. Nothing hidden (adds 0): receiver not behind the patch, own mesh, or the
    patch's bounding sphere (center c, radius s) outside the cone (its distance from the axis
    exceeds kappa (|p| - w.c) + s sqrt(1 + kappa^2)). Both tests keep a margin of ``_ROUND32`` |q|^2
    (many times float32's rounding of |q|^2 - h^2), so a texel is only taken as inside or missed
    when it is so in exact arithmetic too. Every other texel (the patch near or across the cone's
    surface, or not wholly between p and the disk's plane, tested as w.c -+ s(1 + 2^-10) in
    (0, |p|): the corners' heights are within s of the center's) is flagged in
    ``flags[(i - ia) fw + j - base]`` for the exact float64 path; returns a bit mask of the rows
    where any texel is (bit i - ia). Several rows in one call: the per-patch set-up (constants,
    masks) is made once for them. The loop runs over the ``nl`` texels
    from ``base`` (``[base, base + nl)`` contains the patch's range ``[j0, j1)``; the caller makes
    ``nl`` a multiple of :data:`ROW_LANES`, so the row is whole vectors, no scalar remainder);
    texels outside ``[j0, j1)`` add 0 and are not flagged. ``pk[p]``: patch ``p``'s constants
    (:func:`_patch_constants`, float32): |q_c|^2 + margin (4), |c|^2 - margin, s, A / (2 pi), x0,
    x1, y0, y1, z_O, and s (1 + 2^-10). ``noalias``: the arrays do not overlap, so LLVM vectorizes
    the loop without checking their overlap at run time (those checks, 2 stored x 9 read arrays,
    were made at every row: ~10% of the accumulation on `bunny`)."""
    lo = np.int32(j0 - base)
    hi = np.int32(j1 - base)
    pm32 = np.int32(pm)
    ub = np.uint64(base)
    not_check = not check_mesh
    qq0, qq1, qq2, qq3, cc, sr, ak = pk[p, 0], pk[p, 1], pk[p, 2], pk[p, 3], pk[p, 4], pk[p, 5], pk[p, 6]
    x0, x1, y0, y1, zo, se = pk[p, 7], pk[p, 8], pk[p, 9], pk[p, 10], pk[p, 11], pk[p, 12]
    mask = 0
    for r in range(ib - ia + 1):
        ii = np.uint64(ia + r)
        fo = np.uint64(r * fw)
        anyf = False
        for jj in range(nl):
            ju = np.uint64(jj)
            jx = ub + ju
            zr = recv_depth[ii, jx]
            # no short-circuit: it vectorizes; the column mask from an int32 ramp (16 lanes per compare)
            rj = ramp[ju]
            ok = (zr > zo) & (not_check | (recv_mesh[ii, jx] != pm32)) & (rj >= lo) & (rj < hi)
            wx = F[ii, 0, jx]
            wy = F[ii, 1, jx]
            hz = F[ii, 2, jx] * zo
            hp = F[ii, 3, jx]
            kap = F[ii, 4, jx]
            hmax = hp * _HM32
            h0 = wx * x0 + wy * y0 + hz
            h1 = wx * x1 + wy * y0 + hz
            h2 = wx * x1 + wy * y1 + hz
            h3 = wx * x0 + wy * y1 + hz
            # every corner strictly between the disk's plane and p: |h_c - h(center)| <= s |w| = s, so
            # the center's height +- the half diagonal (times 1 + 2^-10, far above float32's rounding)
            hc = _FH * (h0 + h2)
            inr = (hc > se) & (hc + se < hmax)
            d0 = hp - h0
            d1 = hp - h1
            d2 = hp - h2
            d3 = hp - h3
            k2 = kap * kap
            ins = (
                (qq0 - h0 * h0 <= k2 * d0 * d0)
                & (qq1 - h1 * h1 <= k2 * d1 * d1)
                & (qq2 - h2 * h2 <= k2 * d2 * d2)
                & (qq3 - h3 * h3 <= k2 * d3 * d3)
            )
            rc = kap * (hp - hc) + sr * F[ii, 5, jx]
            miss = cc - hc * hc > rc * rc
            area = ak * (zr - zo) * (d1 + d3) / (k2 * (d0 * d1) * (d2 * d3))
            add = area if (ok & inr & ins) else _F0
            ssm[ii, jx] += add
            fl = ok & ~(inr & (miss | ins))
            flags[fo + ju] = fl
            anyf |= fl
        if anyf:
            mask |= 1 << r
    return mask


@kernel(inline=True)
def _queue_crossings(recv_depth, flags64, fo64, i, base, nl, x0, x1, y0, y1, zo, Q, rows, cols, m):
    """Append the texels of row ``i`` that :func:`_disk_row_pass` flagged (patch across the cone's
    surface) to the queue at position ``m``: the texel to ``rows``, ``cols``, the patch and the
    texel's receiver depth to ``Q`` (6, n) (contiguous: the batch's vector loop needs no gathers;
    the batch recomputes the texel's frame, cheaper than copying its 11 planes). ``flags64``:
    the flags viewed as uint64, the row's from ``fo64``: the flagged bytes of each 8 are found by
    their lowest set bit.
    Returns the new length."""
    for blk in range((nl + 7) // 8):
        x = flags64[fo64 + blk]
        rest = nl - 8 * blk
        if rest < 8:  # bytes past nl: stale flags of a longer row
            x &= (np.uint64(1) << np.uint64(8 * rest)) - np.uint64(1)
        # the flagged bytes of the block one by one (lowest first, little-endian): one iteration
        # per flagged texel, instead of a hard-to-predict branch per texel
        while x:
            jj = 8 * blk + (np.int64(trailing_zeros(x)) >> 3)
            x &= x - np.uint64(1)
            j = base + jj
            rows[m] = i
            cols[m] = j
            Q[0, m] = x0
            Q[1, m] = x1
            Q[2, m] = y0
            Q[3, m] = y1
            Q[4, m] = zo
            Q[5, m] = np.float64(recv_depth[i, j])
            m += 1
    return m


@kernel(inline=True)
def _crossing_batch(Q, rows, cols, vals, bad, UV, m, l, t, dxs, dys, rho):
    """The first ``m`` queued texel x patch pairs (:func:`_queue_crossings`): the texel's facing
    disk (:func:`softshadows.analytic.disk_facing_frame` of its receiver point, the same arithmetic
    as :func:`disk_frames`, so the same values) and the projected quadrilateral
    (:func:`_quad_heights`, :func:`_project_quad`) in float64, its corners stored in float32 to
    ``UV`` (8, n), then in a second loop its exact overlap with the disk over pi, branch-free, in
    float32 (:func:`softshadows.analytic.quad_disk_area_small32`; 16 lanes), into ``vals``
    (float32); ``bad`` where that does not apply (patch not wholly between p and the disk's plane,
    or a wide quadrilateral): those take :func:`occlusion_percentage_disk`. (The frame and
    projection in float32 too moved V by up to 6.8e-6 on `bunny` for 3% less time: not done.)"""
    for k in range(m):
        kx = np.uint64(k)
        x0 = Q[0, kx]
        x1 = Q[1, kx]
        y0 = Q[2, kx]
        y1 = Q[3, kx]
        zo = Q[4, kx]
        zr = Q[5, kx]
        ux = l + (cols[kx] + 0.5) * dxs
        uy = t - (rows[kx] + 0.5) * dys
        wx, wy, wz, e1x, e1y, e1z, e2x, e2y, e2z, hp = disk_facing_frame(ux * zr, uy * zr, zr)
        kap = rho / hp
        hmax = hp * (1.0 - 1e-9)
        h0, h1, h2, h3 = _quad_heights(wx, wy, wz, x0, x1, y0, y1, zo)
        inr = (h0 > 0.0) & (h1 > 0.0) & (h2 > 0.0) & (h3 > 0.0) & (h0 < hmax) & (h1 < hmax) & (h2 < hmax) & (h3 < hmax)
        u0, u1, u2, u3, v0, v1, v2, v3 = _project_quad(
            hp, kap, e1x, e1y, e1z, e2x, e2y, e2z, x0, x1, y0, y1, zo, h0, h1, h2, h3
        )
        UV[0, kx] = u0
        UV[1, kx] = u1
        UV[2, kx] = u2
        UV[3, kx] = u3
        UV[4, kx] = v0
        UV[5, kx] = v1
        UV[6, kx] = v2
        UV[7, kx] = v3
        bad[kx] = not inr
    # the area in float32 (16 lanes), in a loop of its own (a loop with float64 would run 8 lanes)
    for k in range(m):
        kx = np.uint64(k)
        a, ok = quad_disk_area_small32(
            UV[0, kx], UV[1, kx], UV[2, kx], UV[3, kx], UV[4, kx], UV[5, kx], UV[6, kx], UV[7, kx]
        )
        good = ok & ~bad[kx]
        vals[kx] = a * _INV_PI32 if good else _F0
        bad[kx] = ~good


@kernel(inline=True)
def _flush_crossings(F1, f, Q, rows, cols, vals, bad, UV, m, ssm, l, t, dxs, dys, rho, sx, sy, sz, sh, tx, ty, tz, th):
    """Add the queued pairs' occlusion (:func:`_crossing_batch`, else :func:`occlusion_percentage_disk`
    on the texel's frame, recomputed into ``F1`` (12,1,1) as :func:`disk_frames` computes it; ``f``:
    scratch of 12) to ``ssm``, in queue order."""
    _crossing_batch(Q, rows, cols, vals, bad, UV, m, l, t, dxs, dys, rho)
    for k in range(m):
        c = np.float64(vals[k])
        if bad[k]:
            zr = Q[5, k]
            _disk_frame((l + (cols[k] + 0.5) * dxs) * zr, (t - (rows[k] + 0.5) * dys) * zr, zr, rho, f)
            for c12 in range(12):
                F1[c12, 0, 0] = f[c12]
            c = occlusion_percentage_disk(
                F1, 0, 0, Q[0, k], Q[1, k], Q[2, k], Q[3, k], Q[4, k], sx, sy, sz, sh, tx, ty, tz, th
            )
        ssm[rows[k], cols[k]] += np.float32(c)


@kernel(inline=True)
def _patch_constants(x0, x1, y0, y1, zo, pk, p):
    """Per micro-patch constants of :func:`_disk_row_pass` into ``pk[p]`` (float32): |q_c|^2 of the 4
    corners plus the margin, |c|^2 of the center minus it, the half diagonal s, A / (2 pi), the
    patch x0, x1, y0, y1, z_O, and s (1 + 2^-10) (the bound of the corners' heights about the
    center's)."""
    z2 = zo * zo
    q0 = x0 * x0 + y0 * y0 + z2
    q1 = x1 * x1 + y0 * y0 + z2
    q2 = x1 * x1 + y1 * y1 + z2
    q3 = x0 * x0 + y1 * y1 + z2
    cx = 0.5 * (x0 + x1)
    cy = 0.5 * (y0 + y1)
    cc = cx * cx + cy * cy + z2
    mg = _ROUND32 * max(max(q0, q1), max(max(q2, q3), cc))
    pk[p, 0] = q0 + mg
    pk[p, 1] = q1 + mg
    pk[p, 2] = q2 + mg
    pk[p, 3] = q3 + mg
    pk[p, 4] = cc - mg
    pk[p, 5] = 0.5 * math.sqrt((x1 - x0) * (x1 - x0) + (y1 - y0) * (y1 - y0))
    pk[p, 6] = (x1 - x0) * (y1 - y0) / (2.0 * math.pi)
    pk[p, 7] = x0
    pk[p, 8] = x1
    pk[p, 9] = y0
    pk[p, 10] = y1
    pk[p, 11] = zo
    pk[p, 12] = pk[p, 5] * (1.0 + 2.0**-10)


@kernel(nogil=True)
def disk_frames32_slot(slot, recv_depth, svp, rho, out, nslot):
    """The planes of :func:`disk_frames` that :func:`_disk_row_pass` reads, in float32, into ``out``
    (H,6,W) (zeros; left as it is where no receiver): w (3), |p|, kappa, sqrt(1 + kappa^2) (the
    same arithmetic as :func:`disk_frames`, rounded; the float64 planes themselves are not kept:
    the exact path recomputes a texel's frame). Row-major by texel row, then plane (not six
    (H,W) planes): the row pass reads the six planes' rows together, and whole planes lie a
    multiple of 4 KiB apart (64 KiB for a 128^2 map), so that their rows fell in one set of the L1
    cache, 6 of its 8 ways, and the row pass ran 12 or 16 ms from one process to the next on
    `bunny`, by where the other arrays it reads happened to lie. Run by ``run_slots``: slot
    ``slot`` of ``nslot`` takes every ``nslot``-th row."""
    H, W = recv_depth.shape
    l, r, b, t = svp[VP_L], svp[VP_R], svp[VP_B], svp[VP_T]
    dxs = (r - l) / W
    dys = (t - b) / H
    f = np.empty(12)
    for i in range(slot, H, nslot):
        uy = t - (i + 0.5) * dys
        for j in range(W):
            zr = np.float64(recv_depth[i, j])
            if zr > 0.0:
                ux = l + (j + 0.5) * dxs
                _disk_frame(ux * zr, uy * zr, zr, rho, f)
                out[i, 0, j] = f[0]
                out[i, 1, j] = f[1]
                out[i, 2, j] = f[2]
                out[i, 3, j] = f[9]
                out[i, 4, j] = f[10]
                out[i, 5, j] = f[11]


def disk_frames32(recv_depth, svp, rho) -> np.ndarray:
    """:func:`disk_frames32_slot` over the whole map, one slot per thread: (H,6,W) float32, zeros
    where no receiver."""
    H, W = recv_depth.shape
    out = np.zeros((H, 6, W), np.float32)
    run_threads(disk_frames32_slot, recv_depth, svp, float(rho), out)
    return out


@kernel(nogil=True)
def accumulate_soft_shadow_map_sphere_slot(
    slot,
    patches,
    pmesh,
    ext,
    band_ptr,
    band_idx,
    band_rows,
    recv_depth,
    recv_mesh,
    frames,
    frames32,
    fp16,
    rtz,
    check_mesh,
    ssm,
    svp,
    rho,
    touched,
    nslot,
):
    """Slot ``slot`` of :func:`accumulate_soft_shadow_map_sphere` (``run_slots``): bands slot, slot + nslot, ..."""
    H, W = recv_depth.shape
    l, r, b, t = svp[VP_L], svp[VP_R], svp[VP_B], svp[VP_T]
    dxs = (r - l) / W
    dys = (t - b) / H
    n_bands = band_ptr.shape[0] - 1
    sx = np.empty(8)
    sy = np.empty(8)
    sz = np.empty(8)
    sh = np.empty(8)
    tx = np.empty(8)
    ty = np.empty(8)
    tz = np.empty(8)
    th = np.empty(8)
    fw = 8 * ((W + 7) // 8)  # the flags of one row (a whole number of uint64 words)
    flags = np.zeros(band_rows * fw, np.bool_)
    flags64 = flags.view(np.uint64)
    cap = max(CROSSING_BATCH, 2 * W)
    rows = np.zeros(cap, np.int64)
    cols = np.zeros(cap, np.int64)
    vals = np.zeros(cap, np.float32)
    UV = np.empty((8, cap + 24), np.float32)  # the crossing pairs' projected corners
    bad = np.zeros(cap, np.bool_)
    Q = np.empty((6, cap + 24))  # row stride not a multiple of 4 KiB: no cache-set conflicts
    # the row pass's per-patch constants, once per patch (not once per band it meets)
    pk = np.empty((0 if fp16 else patches.shape[0], 16), np.float32)
    for p in range(pk.shape[0]):
        _patch_constants(patches[p, 0], patches[p, 1], patches[p, 2], patches[p, 3], patches[p, 4], pk, p)
    F1 = np.empty((12, 1, 1))
    f12 = np.empty(12)
    ramp = np.empty(W, np.int32)  # 0, 1, 2, ...: the row pass's column mask
    for j in range(W):
        ramp[j] = j
    for bnd in range(slot, n_bands, nslot):
        r0 = bnd * band_rows
        r1 = min(r0 + band_rows, H) - 1
        cnt = 0
        m = 0
        for q in range(band_ptr[bnd], band_ptr[bnd + 1]):
            p = band_idx[q]
            x0, x1, y0, y1, zo = patches[p, 0], patches[p, 1], patches[p, 2], patches[p, 3], patches[p, 4]
            pm = pmesh[p]
            i0 = max(ext[p, 0], r0)
            i1 = min(ext[p, 1], r1)
            j0 = ext[p, 2]
            j1 = ext[p, 3] + 1
            # the row pass runs over whole vectors of ROW_LANES texels from ``base``
            nl = ROW_LANES * ((j1 - j0 + ROW_LANES - 1) // ROW_LANES)
            if nl <= W:
                base = min(j0, W - nl)
            else:
                base = j0
                nl = j1 - j0
            if fp16:
                for i in range(i0, i1 + 1):
                    cnt += j1 - j0
                    for j in range(j0, j1):
                        zr = np.float64(recv_depth[i, j])
                        if not (zr > zo) or (check_mesh and recv_mesh[i, j] == pm):
                            continue
                        c = occlusion_percentage_disk(frames, i, j, x0, x1, y0, y1, zo, sx, sy, sz, sh, tx, ty, tz, th)
                        if c > 0.0:
                            ssm[i, j] = np.float32(round_half(np.float64(ssm[i, j]) + round_half(c, rtz), rtz))
                continue
            cnt += max(i1 - i0 + 1, 0) * (j1 - j0)
            # float32 sums: a branch-free pass over each row (vectorizes) adds the patch's area
            # where it projects inside the disk, nothing where it misses the cone, and flags the
            # other texels (a few per row), which are queued and computed in batches (vectorized),
            # added after the band's other contributions. The patch's rows of the band in one
            # call when no flush of the queue can fall between them (a row queues at most
            # j1 - j0 pairs), else one row per call: the same order of additions either way.
            fused = m + max(i1 - i0 + 1, 0) * (j1 - j0) <= cap
            ia = i0
            while ia <= i1:
                ib = i1 if fused else ia
                # one instance per value of check_mesh: without it the mesh test folds away
                if check_mesh:
                    fmask = _disk_row_pass(
                        frames32, recv_depth, recv_mesh, ssm, flags, ramp, ia, ib, fw, base, nl, j0, j1, pm, True, pk, p
                    )
                else:
                    fmask = _disk_row_pass(
                        frames32,
                        recv_depth,
                        recv_mesh,
                        ssm,
                        flags,
                        ramp,
                        ia,
                        ib,
                        fw,
                        base,
                        nl,
                        j0,
                        j1,
                        pm,
                        False,
                        pk,
                        p,
                    )
                for i in range(ia, ib + 1):
                    if not (fmask >> (i - ia)) & 1:
                        continue
                    if m + (j1 - j0) > cap:
                        _flush_crossings(
                            F1,
                            f12,
                            Q,
                            rows,
                            cols,
                            vals,
                            bad,
                            UV,
                            m,
                            ssm,
                            l,
                            t,
                            dxs,
                            dys,
                            rho,
                            sx,
                            sy,
                            sz,
                            sh,
                            tx,
                            ty,
                            tz,
                            th,
                        )
                        m = 0
                    m = _queue_crossings(
                        recv_depth, flags64, (i - ia) * (fw // 8), i, base, nl, x0, x1, y0, y1, zo, Q, rows, cols, m
                    )
                ia = ib + 1
        if m:
            _flush_crossings(
                F1, f12, Q, rows, cols, vals, bad, UV, m, ssm, l, t, dxs, dys, rho, sx, sy, sz, sh, tx, ty, tz, th
            )
        _clamp_rows(ssm, r0, r1)
        touched[bnd] = cnt


def accumulate_soft_shadow_map_sphere(
    patches,
    pmesh,
    ext,
    band_ptr,
    band_idx,
    band_rows,
    recv_depth,
    recv_mesh,
    frames,
    frames32,
    fp16,
    rtz,
    check_mesh,
    ssm,
    svp,
    rho,
    nslot=1,
):
    """:func:`accumulate_soft_shadow_map` for a sphere light: the fragment program is
    :func:`occlusion_percentage_disk` (float64 arithmetic; the sum is stored in float32, or
    rounded to half precision with ``fp16``). Same bands, order, skipping rules and clamping. ``frames``:
    :func:`disk_frames` of the texels (read with ``fp16`` only), ``frames32``: :func:`disk_frames32`;
    ``svp``: the SSM's view parameters, ``rho``: the light's radius (the crossing pairs' frames are
    recomputed)."""
    touched = np.zeros(band_ptr.shape[0] - 1, np.int64)
    run_slots(
        accumulate_soft_shadow_map_sphere_slot,
        nslot,
        patches,
        pmesh,
        ext,
        band_ptr,
        band_idx,
        band_rows,
        recv_depth,
        recv_mesh,
        frames,
        frames32,
        fp16,
        rtz,
        check_mesh,
        ssm,
        svp,
        rho,
        touched,
        nslot,
    )
    return touched


# ---- 8. two-pass merge -------------------------------------------------------------------------
def merge_two_pass(front: np.ndarray, back: np.ndarray) -> np.ndarray:
    """The two soft shadow maps merged by their maximum (Sec. 3.5)."""
    return np.maximum(front, back)


# ---- 9. projection onto the eye view -----------------------------------------------------------
@kernel(nogil=True)
def project_soft_shadow_map_slot(slot, position, tri_id, receiver, svp, ssm, out, n_row, nslot):
    """V (H,W) float32 of the eye view into ``out``, straight from its G-buffer image (``position``
    (H,W,3), ``tri_id`` (H,W), -1 where no surface; ``receiver``: per triangle, whether it is a
    receiver): receivers read the SSM (bilinear) at their projection from the light; V = 1 -
    occlusion. Outside the SSM, behind the light, on occluder-only geometry or without a surface:
    V = 1. Per row, the positions copied and projected first (one float64 array per coordinate, no
    branch: LLVM vectorizes it), then the lookups; ``n_row[i]``: row i's number of receiver pixels.

    Run by ``run_slots``: slot ``slot`` of ``nslot`` takes every ``nslot``-th row (in row order
    the upper half of an eye image is often sky, no surface, nothing to look up: contiguous runs
    of rows left one thread idle for most of the pass)."""
    H, W = tri_id.shape
    Hs, Ws = ssm.shape
    sc = np.empty((6, W))
    for i in range(slot, H, nslot):
        # the row's positions to one float64 array per coordinate first (the G-buffer interleaves
        # them: projected straight from it, the row took 1.4x the time; as biased_light_row)
        for j in range(W):
            sc[3, j] = position[i, j, 0]
            sc[4, j] = position[i, j, 1]
            sc[5, j] = position[i, j, 2]
        for j in range(W):
            sx, sy, z = view_project(svp, sc[3, j], sc[4, j], sc[5, j])
            sc[0, j] = sx
            sc[1, j] = sy
            sc[2, j] = z
        n = 0
        for j in range(W):
            out[i, j] = 1.0
            tri = tri_id[i, j]
            if tri < 0 or not receiver[tri]:
                continue
            n += 1
            sx, sy, z = sc[0, j], sc[1, j], sc[2, j]
            if not (z > 0.0) or not (sx >= 0.0 and sx <= Ws and sy >= 0.0 and sy <= Hs):
                continue
            o = sample_bilinear(ssm, sx, sy)
            if o > 0.0:
                out[i, j] = 1.0 - min(o, 1.0)
        n_row[i] = n


def project_soft_shadow_map(position, tri_id, receiver, svp, ssm) -> tuple[np.ndarray, int]:
    """:func:`project_soft_shadow_map_slot` over the eye image, one slot per thread: (V (H,W)
    float32, the number of receiver pixels)."""
    out = np.empty(tri_id.shape, np.float32)
    n_row = np.zeros(tri_id.shape[0], np.int64)
    run_threads(project_soft_shadow_map_slot, position, tri_id, receiver, svp, ssm, out, n_row)
    return out, int(n_row.sum())


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
    map_size: int = 0,
    ssm_size: int = 0,
    two_pass: bool = False,
    accumulate: str = "float32",
    margin: float = 0.02,
    timer=None,
) -> SoftShadowMap:
    """Steps 1-8 for ``scene`` (rect or sphere light): the clamped soft shadow map and statistics.
    ``map_size`` 0: :func:`default_map_size` of the scene's light; ``ssm_size`` 0:
    :func:`default_ssm_size`."""
    timer = timer or _NullTimer()
    check_roles(scene)
    if map_size == 0:
        map_size = default_map_size(scene.light)
    if ssm_size == 0:
        ssm_size = default_ssm_size(scene.light)
    sphere = scene.light.shape == "sphere"
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
    # the mesh ids only serve the no-self-shadowing rule of meshes of role ``both``
    check_mesh = any(m.role == "both" for m in scene.meshes)
    with timer.phase("receiver_map"):
        ov, sv = compute_map_views(scene, map_size, ssm_size, margin)
        rdepth, rmesh = compute_receiver_depth_map(scene, sv, check_mesh)
    with timer.phase("occluder_map"):
        sides = ("front", "back") if two_pass else ("nearest",)
        omaps = {s: compute_occluder_depth_map(scene, ov, s, check_mesh) for s in sides}
    hx, hy = light_half_extents(scene.light, ov)
    finite = rdepth[np.isfinite(rdepth)]
    rdepth0 = np.where(np.isfinite(rdepth), rdepth, np.float32(0.0)).astype(np.float32)  # 0: no receiver
    z_plane = float(finite.max()) if finite.size else 0.0
    ovp, svp = ov.params(), sv.params()
    n_bands = (ssm_size + BAND_ROWS - 1) // BAND_ROWS
    passes = {}
    frames32 = None
    pyr = None
    fp16_safe = True
    for s in sides:
        with timer.phase("penumbra_extents"):
            patches, pmesh = discretize_occluders(omaps[s][0], omaps[s][1], ovp)
            if sphere:
                if pyr is None:
                    pyr = max_pyramid(rdepth0)
                # penumbra_extents_sphere's ranges, then narrowed, in one parallel pass
                ext = np.empty((patches.shape[0], 4), np.int32)
                ext = refine_extents_sphere(
                    patches, ext, hx, pyr[0], pyr[1], pyr[3], svp, REFINE_ROUNDS, max(z_plane, 1e-300)
                )
            else:
                ext = penumbra_extents(patches, hx, hy, z_plane, svp)
            ptr, idx = bin_patches_by_band(ext, n_bands, BAND_ROWS)
        with timer.phase("soft_shadow_map"):
            ssm = np.zeros((ssm_size, ssm_size), np.float32)
            rtz = accumulate == "float16-rtz"
            nslot = numba.get_num_threads()
            if sphere:
                if frames32 is None:
                    # float64 frames only for the FP16 path's scalar program; the float32 path
                    # recomputes the frames of its few exact pairs
                    frames = disk_frames(rdepth0, svp, hx) if fp16 else np.zeros((12, 1, 1))
                    frames32 = disk_frames32(rdepth0, svp, hx)
                touched = accumulate_soft_shadow_map_sphere(
                    patches,
                    pmesh,
                    ext,
                    ptr,
                    idx,
                    BAND_ROWS,
                    rdepth0,
                    rmesh,
                    frames,
                    frames32,
                    fp16,
                    rtz,
                    check_mesh,
                    ssm,
                    svp,
                    hx,
                    nslot,
                )
            else:
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
                    rtz,
                    check_mesh,
                    ssm,
                    nslot,
                )
        passes[s] = ssm
        stats[f"micro_patches_{s}"] = int(len(patches))
        stats["micro_patches"] += int(len(patches))
        stats["texels_touched"] += int(touched.sum())
        if len(patches) and z_plane > 0:
            # every patch in front of the plane meets the condition iff the nearest one does (1/z_O
            # decreases with z_O): one test instead of one per patch
            z_o = float(patches[:, 4].min())
            fp16_safe &= z_o >= z_plane or bool(fp16_condition(z_o, z_plane, hx, ov))
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


def _size_param(name: str, meaning: str, rect: int, sphere: int) -> Param:
    """A map resolution whose default, 0, stands for ``rect`` with a rect light and ``sphere`` with a
    sphere light (``default_map_size``, ``default_ssm_size``); otherwise >= 8. ``meaning``: the
    description, up to its open parenthesis."""
    return Param(
        name,
        0,
        f"{meaning}, N >= 8); 0: {rect} with a rect light, {sphere} with a sphere light",
        min=0,
        max=4096,
        check=lambda n: None if n == 0 or n >= 8 else "0 (the light's default) or >= 8",
    )


@register
class SoftShadowMapMethod(Method):
    name = "soft-shadow-map"
    light_shapes = ("rect", "sphere")
    summary = "soft shadow maps: occluder-map pixels as micro-patches, occlusion summed in a projective map"
    paper = "Atty et al. 2006, Soft Shadow Maps: Efficient Sampling of Light Source Visibility"
    light_view = True  # maps from the light's centre (limits: softshadows.limits)
    receivers_only = True  # only receiver faces are shadowed
    params = (
        _size_param(
            "map_size", "occluder map resolution N (N x N, light's aspect ratio", MAP_SIZE_RECT, MAP_SIZE_SPHERE
        ),
        _size_param("ssm_size", "soft shadow map resolution (N x N texels", SSM_SIZE_RECT, SSM_SIZE_SPHERE),
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

    #: what `softshadows pareto` sweeps (Method.sweep)
    sweep: ClassVar = [
        {"map_size": 64, "ssm_size": 128},
        {"map_size": 128, "ssm_size": 128},
        {"map_size": 128, "ssm_size": 256},
        {"map_size": 256, "ssm_size": 256},
        {"map_size": 256, "ssm_size": 512},
        {"map_size": 512, "ssm_size": 512},
    ]

    def run(self, ctx, map_size, ssm_size, two_pass, accumulate, margin):
        smap = compute_soft_shadow_map(ctx.scene, map_size, ssm_size, two_pass, accumulate, margin, ctx.timer)
        with ctx.timer.phase("eye_projection"):
            out, n_recv = project_soft_shadow_map(
                ctx.eye.position, ctx.eye.tri_id, ctx.flat.receiver, smap.view.params(), smap.occlusion
            )
        stats = dict(smap.stats)
        stats["eye_receiver_pixels"] = int(n_recv)
        return MethodOutput(out, stats)
