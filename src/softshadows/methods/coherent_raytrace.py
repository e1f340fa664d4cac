"""``coherent-raytrace``: coherence-based raytracing of depth images (Agrawala, Ramamoorthi, Heirich,
Moll, SIGGRAPH 2000, Sections 5 and 6), rectangle lights.

Shadow rays are traced through a few reference depth images rendered from points of the light
(its corners by default), each with min/max and connectedness quadtrees, with the paper's
accelerations (min/max clipping, hierarchical connectedness, clear miss, occlusion intervals,
ranking); the light is sampled with coherence-based sampling (a predicted visibility image from the
blocker points of the previous surface points, rays traced only where the prediction is uncertain).
Steps, parameters, deviations and limits: ``docs/methods/coherent-raytrace.md``.
"""

from __future__ import annotations

import hashlib
import math
from types import SimpleNamespace
from typing import ClassVar

import numba
import numpy as np

from .._jit import kernel, run_slots, run_threads
from ..raster.kernels import view_coords, view_coords_to_screen
from ..raster.view import VP_B, VP_FAR, VP_L, VP_NEAR, VP_R, VP_T, light_view
from ..shading import exposure
from .base import Method, MethodOutput, Param, register
from .ground_truth import jitter_pair, point_key
from .shadowmap import build_shadow_map

# acceleration switches (bit flags passed to the kernels)
F_HIER = 1  # hierarchical min/max overlap test (coarse to fine)
F_CLIP = 2  # min/max clipping of the epipolar depth interval at every level
F_CONN = 4  # hierarchical connectedness
F_CLEAR = 8  # clear miss
F_INTERVALS = 16  # occlusion intervals
F_RANK = 32  # rank reference images by clipped epipolar length
F_ALL = F_HIER | F_CLIP | F_CONN | F_CLEAR | F_INTERVALS | F_RANK
F_BASELINE = F_HIER  # the paper's "no acceleration": the plain hierarchical tracer

# per-tile counters
C_RAYS, C_NODES, C_LEAVES, C_CLEAR, C_IMAGES, C_BLOCKED, C_CONNHIT, C_SELF = range(8)
N_COUNTERS = 8

MAX_INTERVALS = 64  # occlusion intervals kept per ray and image (more: the last one is widened)


# ------------------------------------------------------------------------------------------------
# Precompute: reference depth images and their quadtrees
# ------------------------------------------------------------------------------------------------
def reference_positions(light, count: int) -> np.ndarray:
    """World positions of the reference views on the light: 1 = center, 4 = corners (the paper's
    default), 5 = corners + center, 9 = the 3 x 3 grid of corners, edge midpoints and center."""
    if count == 1:
        ab = [(0.0, 0.0)]
    elif count == 4:
        ab = [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)]
    elif count == 5:
        ab = [(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5), (0.0, 0.0)]
    else:
        ab = [(a, b) for a in (-0.5, 0.0, 0.5) for b in (-0.5, 0.0, 0.5)]
    return np.array([light.center + a * light.u + b * light.v for a, b in ab], np.float64)


def reference_views(scene, count: int, resolution: int, margin: float) -> list:
    """One perspective view per reference position, looking along the light's normal, its window
    fitted to the occluders (shared ``light_view``: square pixels, near/far bracketing them)."""
    flat = scene.flat
    which = "occluder" if flat.occluder.any() else "all"
    pts = flat.vertices[flat.face_vertices(which)]
    light = scene.light
    views = []
    for o in reference_positions(light, count):
        at = SimpleNamespace(shape="rect", center=o, normal=light.normal, u=light.u)
        views.append(light_view(at, pts, resolution, resolution, margin=margin, square_pixels=True))
    return views


@kernel
def _connected(d1, d2, gapk):
    """Adjacent depth samples form one surface when they differ by less than the gap bias
    (``gapk`` x the texel size at the nearer depth)."""
    if not (d1 < np.inf and d2 < np.inf):
        return False
    return abs(d1 - d2) < gapk * min(d1, d2)


@kernel(nogil=True, nrt=False, noalias=True)
def build_quadtree_level_slot(slot, D, gapk, offs, MN, MX, CONN, L, nslot):
    """Level ``L`` of the min/max quadtrees (leaf intervals widened by the walls to connected
    neighbours, so the coarse-to-fine overlap test never drops a wall hit) and of the connectedness
    quadtree: a node is connected when all its pixels are non-empty and every 4-adjacent pair
    inside it is connected. Level ``L`` > 0 reads level ``L - 1``. Run by ``run_slots`` (one call
    per level, :func:`build_quadtrees`): slot ``slot`` of ``nslot`` takes every ``nslot``-th row."""
    S = D.shape[0]
    if L == 0:
        for i in range(slot, S, nslot):
            for j in range(S):
                d = np.float64(D[i, j])
                q = offs[0] + i * S + j
                if d < np.inf:
                    lo = d
                    hi = d
                    for k in range(4):
                        ni = i + (1 if k == 0 else (-1 if k == 1 else 0))
                        nj = j + (1 if k == 2 else (-1 if k == 3 else 0))
                        if 0 <= ni < S and 0 <= nj < S:
                            dn = np.float64(D[ni, nj])
                            if _connected(d, dn, gapk):
                                lo = min(lo, dn)
                                hi = max(hi, dn)
                    MN[q] = lo
                    MX[q] = hi
                    CONN[q] = 1
                else:
                    MN[q] = np.inf
                    MX[q] = -np.inf
                    CONN[q] = 0
        return
    side = S >> L
    h = 1 << L
    mid = h >> 1
    for bi in range(slot, side, nslot):
        for bj in range(side):
            q = offs[L] + bi * side + bj
            cs = side * 2
            c0 = offs[L - 1] + (2 * bi) * cs + 2 * bj
            c1 = c0 + 1
            c2 = c0 + cs
            c3 = c2 + 1
            MN[q] = min(min(MN[c0], MN[c1]), min(MN[c2], MN[c3]))
            MX[q] = max(max(MX[c0], MX[c1]), max(MX[c2], MX[c3]))
            ok = CONN[c0] == 1 and CONN[c1] == 1 and CONN[c2] == 1 and CONN[c3] == 1
            if ok:
                r0 = bi * h
                col0 = bj * h
                for t in range(h):
                    if not _connected(D[r0 + t, col0 + mid - 1], D[r0 + t, col0 + mid], gapk):
                        ok = False
                        break
                    if not _connected(D[r0 + mid - 1, col0 + t], D[r0 + mid, col0 + t], gapk):
                        ok = False
                        break
            CONN[q] = 1 if ok else 0


def build_quadtrees(D, gapk, offs, MN, MX, CONN) -> None:
    """Min/max quadtrees and the connectedness quadtree of depth image ``D`` (S, S), level by level
    (:func:`build_quadtree_level_slot`), one slot per thread; the small coarse levels in one slot."""
    nthreads = numba.get_num_threads()
    for L in range(offs.shape[0] - 1):
        nslot = nthreads if (D.shape[0] >> L) >= 64 else 1
        run_slots(build_quadtree_level_slot, nslot, D, gapk, offs, MN, MX, CONN, L, nslot)


class ReferenceImages:
    """The precomputed reference depth images of one scene/light/parameter set."""

    def __init__(self, scene, count: int, resolution: int, bias: float, gap: float, margin: float):
        views = reference_views(scene, count, resolution, margin)
        S = 1 << max(0, int(math.ceil(math.log2(resolution))))
        nlev = int(round(math.log2(S))) + 1
        offs = np.zeros(nlev + 1, np.int64)
        for L in range(nlev):
            offs[L + 1] = offs[L] + (S >> L) ** 2
        n = len(views)
        self.views = views
        self.S = S
        self.offs = offs
        self.vps = np.stack([v.params() for v in views])
        self.D = np.full((n, S, S), np.inf, np.float32)
        self.MN = np.empty((n, offs[-1]), np.float32)
        self.MX = np.empty((n, offs[-1]), np.float32)
        self.CONN = np.empty((n, offs[-1]), np.uint8)
        self.kpix = np.array([(v.window[1] - v.window[0]) / v.width for v in views], np.float64)
        self.gapk = gap * self.kpix
        for k, v in enumerate(views):
            z = build_shadow_map(scene, v, tri=False).depth.astype(np.float64)
            # depth (shadow) bias in texels: the stored depth moved away from the light
            self.D[k, :resolution, :resolution] = (z * (1.0 + bias * self.kpix[k])).astype(np.float32)
            build_quadtrees(self.D[k], float(self.gapk[k]), offs, self.MN[k], self.MX[k], self.CONN[k])


_PRECOMPUTE_CACHE: dict = {}


def _geometry_key(scene) -> str:
    flat = scene.flat
    h = hashlib.blake2b(digest_size=16)
    for a in (flat.vertices, flat.faces, flat.occluder):
        h.update(np.ascontiguousarray(a).tobytes())
    lt = scene.light
    for a in (lt.center, lt.u, lt.v):
        h.update(np.asarray(a, np.float64).tobytes())
    return h.hexdigest()


def reference_images(scene, count, resolution, bias, gap, margin) -> tuple[ReferenceImages, bool]:
    """The reference images, cached while geometry, light and parameters are unchanged.
    Returns (images, reused)."""
    key = (_geometry_key(scene), count, resolution, bias, gap, margin)
    hit = _PRECOMPUTE_CACHE.get(key)
    if hit is not None:
        return hit, True
    refs = ReferenceImages(scene, count, resolution, bias, gap, margin)
    _PRECOMPUTE_CACHE.clear()
    _PRECOMPUTE_CACHE[key] = refs
    return refs, False


# ------------------------------------------------------------------------------------------------
# Tracing one shadow ray through the depth images
# ------------------------------------------------------------------------------------------------
@kernel(inline=True)
def clip_line_to_box(ax, ay, dx, dy, x0, y0, x1, y1, u0, u1):
    """The parameter range [u0, u1] of the 2-D line A + u d inside the box [x0,x1] x [y0,y1]
    (empty when the returned u0 > u1)."""
    if dx != 0.0:
        ta = (x0 - ax) / dx
        tb = (x1 - ax) / dx
        if ta > tb:
            ta, tb = tb, ta
        u0 = max(u0, ta)
        u1 = min(u1, tb)
    elif ax < x0 or ax > x1:
        return 1.0, 0.0
    if dy != 0.0:
        ta = (y0 - ay) / dy
        tb = (y1 - ay) / dy
        if ta > tb:
            ta, tb = tb, ta
        u0 = max(u0, ta)
        u1 = min(u1, tb)
    elif ay < y0 or ay > y1:
        return 1.0, 0.0
    return u0, u1


@kernel(inline=True)
def _clip_plane(f0, f1, s0, s1):
    """Clip s in [s0, s1] to f0 + s (f1 - f0) >= 0."""
    if f0 < 0.0 and f1 < 0.0:
        return 1.0, 0.0
    if f0 < 0.0:
        s0 = max(s0, f0 / (f0 - f1))
    elif f1 < 0.0:
        s1 = min(s1, f0 / (f0 - f1))
    return s0, s1


@kernel(nrt=False)
def epipolar_segment(vp, ox, oy, oz, lx, ly, lz, t0, t1):
    """The part t in [t0, t1] of the shadow ray o + t (l - o) clipped to the reference view's frustum
    (near, far and the window) and projected: (ok, ax, ay, bx, by, zA, zB, tA, tB), A and B the
    screen points of the clipped ends, z their view depths, t their ray parameters."""
    px = ox + t0 * (lx - ox)
    py = oy + t0 * (ly - oy)
    pz = oz + t0 * (lz - oz)
    qx = ox + t1 * (lx - ox)
    qy = oy + t1 * (ly - oy)
    qz = oz + t1 * (lz - oz)
    x0, y0, z0 = view_coords(vp, px, py, pz)
    x1, y1, z1 = view_coords(vp, qx, qy, qz)
    s0, s1 = 0.0, 1.0
    s0, s1 = _clip_plane(z0 - vp[VP_NEAR], z1 - vp[VP_NEAR], s0, s1)
    s0, s1 = _clip_plane(vp[VP_FAR] - z0, vp[VP_FAR] - z1, s0, s1)
    s0, s1 = _clip_plane(x0 - vp[VP_L] * z0, x1 - vp[VP_L] * z1, s0, s1)
    s0, s1 = _clip_plane(vp[VP_R] * z0 - x0, vp[VP_R] * z1 - x1, s0, s1)
    s0, s1 = _clip_plane(y0 - vp[VP_B] * z0, y1 - vp[VP_B] * z1, s0, s1)
    s0, s1 = _clip_plane(vp[VP_T] * z0 - y0, vp[VP_T] * z1 - y1, s0, s1)
    if not (s0 < s1):
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    xa, ya, za = x0 + s0 * (x1 - x0), y0 + s0 * (y1 - y0), z0 + s0 * (z1 - z0)
    xb, yb, zb = x0 + s1 * (x1 - x0), y0 + s1 * (y1 - y0), z0 + s1 * (z1 - z0)
    if not (za > zb):  # the ray must approach the light's plane (depth decreasing)
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ax, ay = view_coords_to_screen(vp, xa, ya, za)
    bx, by = view_coords_to_screen(vp, xb, yb, zb)
    return True, ax, ay, bx, by, za, zb, t0 + s0 * (t1 - t0), t0 + s1 * (t1 - t0)


@kernel(inline=True)
def _z_at(wA, wB, u):
    """Ray depth at screen parameter u (1/z is linear in screen space)."""
    return 1.0 / (wA + u * (wB - wA))


@kernel(inline=True)
def _t_at(z, zA, zB, tA, tB):
    """Ray parameter at depth z (depth is linear in t)."""
    return tA + (zA - z) / (zA - zB) * (tB - tA)


@kernel(inline=True, nrt=False)
def _add_interval(hid, nh, ta, tb):
    """Append [ta, tb] to the ordered occlusion interval list (merging touching intervals)."""
    if nh > 0 and ta <= hid[nh - 1, 1] + 1e-12:
        if tb > hid[nh - 1, 1]:
            hid[nh - 1, 1] = tb
        return nh
    if nh >= hid.shape[0]:  # full: widen the last interval (a superset stays conservative)
        hid[nh - 1, 1] = tb
        return nh
    hid[nh, 0] = ta
    hid[nh, 1] = tb
    return nh + 1


@kernel(inline=True, nrt=False)
def leaf_floors_and_walls(D, k, i, j, ax, ay, dx, dy, wA, wB, gapk):
    """The exact test at a leaf pixel (i, j): the floor (the pixel's depth plane, parallel to the
    image plane) and the wall at the pixel's exit edge, present only when the next pixel's depth
    differs by less than the gap bias. Uses the ray's full extent in the pixel (from the segment
    ends A, B), so the answer does not depend on how the traversal reached the pixel.
    Returns (hit, z_hit, behind, z_enter, z_exit); ``behind``: the ray is behind the floor in the
    whole pixel (no hit)."""
    S = D.shape[1]
    la, lb = clip_line_to_box(ax, ay, dx, dy, float(j), float(i), j + 1.0, i + 1.0, 0.0, 1.0)
    if la > lb:
        return False, 0.0, False, 0.0, 0.0
    za = _z_at(wA, wB, la)
    zb = _z_at(wA, wB, lb)
    d = np.float64(D[k, i, j])
    if not (d < np.inf):
        return False, 0.0, False, za, zb
    if zb <= d <= za:
        return True, d, False, za, zb
    if lb < 1.0:
        # the pixel the ray enters at its exit edge
        ux = np.inf
        uy = np.inf
        if dx > 0.0:
            ux = (j + 1.0 - ax) / dx
        elif dx < 0.0:
            ux = (j - ax) / dx
        if dy > 0.0:
            uy = (i + 1.0 - ay) / dy
        elif dy < 0.0:
            uy = (i - ay) / dy
        ni = i
        nj = j
        if ux <= uy:
            nj = j + (1 if dx > 0.0 else -1)
        if uy <= ux:
            ni = i + (1 if dy > 0.0 else -1)
        if 0 <= ni < S and 0 <= nj < S:
            d2 = np.float64(D[k, ni, nj])
            if _connected(d, d2, gapk) and min(d, d2) <= zb <= max(d, d2):
                return True, zb, False, za, zb
    return False, 0.0, zb > d, za, zb


@kernel(nrt=False)
def traverse_epipolar(k, ax, ay, bx, by, zA, zB, tA, tB, D, MN, MX, CONN, offs, gapk, flags, stack, hid, nh, cnt):
    """Hierarchical traversal of the epipolar segment A -> B in reference image k (coarse to fine,
    children in ray order). At each node: the overlap test of the ray's depth interval with the
    node's min/max interval (skip the node when they cannot meet), the hierarchical connectedness
    test, and min/max clipping of the ray to the part whose depth lies in the node's interval.
    Leaves get :func:`leaf_floors_and_walls`. Occlusion intervals (where the ray passes behind
    the geometry) are appended to ``hid`` in ray order (a superset at skipped nodes).
    Returns (hit, t_hit, nh)."""
    S = D.shape[1]
    nlev = offs.shape[0] - 1
    dx = bx - ax
    dy = by - ay
    wA = 1.0 / zA
    wB = 1.0 / zB
    hier = (flags & F_HIER) != 0
    clip = hier and (flags & F_CLIP) != 0
    conn = hier and (flags & F_CONN) != 0
    u0, u1 = clip_line_to_box(ax, ay, dx, dy, 0.0, 0.0, float(S), float(S), 0.0, 1.0)
    if u0 > u1:
        return False, 0.0, nh
    sp = 0
    stack[0, 0] = nlev - 1
    stack[0, 1] = 0.0
    stack[0, 2] = 0.0
    stack[0, 3] = u0
    stack[0, 4] = u1
    sp = 1
    kb = stack.shape[0] - 4  # the last 4 rows: the children of the current node, sorted
    while sp > 0:
        sp -= 1
        L = int(stack[sp, 0])
        bi = int(stack[sp, 1])
        bj = int(stack[sp, 2])
        u0 = stack[sp, 3]
        u1 = stack[sp, 4]
        cnt[C_NODES] += 1
        if L == 0:
            cnt[C_LEAVES] += 1
            hit, zh, behind, za, zb = leaf_floors_and_walls(D, k, bi, bj, ax, ay, dx, dy, wA, wB, gapk)
            if hit:
                return True, _t_at(zh, zA, zB, tA, tB), nh
            if behind:
                nh = _add_interval(hid, nh, _t_at(za, zA, zB, tA, tB), _t_at(zb, zA, zB, tA, tB))
            continue
        side = S >> L
        q = offs[L] + bi * side + bj
        if hier:
            mn = np.float64(MN[k, q])
            mx = np.float64(MX[k, q])
            if not (mn <= mx):  # empty node: the ray is in front of nothing here
                continue
            zhi = _z_at(wA, wB, u0)
            zlo = _z_at(wA, wB, u1)
            tol = 1e-9 * zhi
            if zhi < mn - tol:  # entirely in front of the node's geometry
                continue
            if zlo > mx + tol:  # entirely behind it: an occlusion interval
                nh = _add_interval(hid, nh, _t_at(zhi, zA, zB, tA, tB), _t_at(zlo, zA, zB, tA, tB))
                continue
            if conn and CONN[k, q] == 1 and zhi > mx + tol and zlo < mn - tol:
                cnt[C_CONNHIT] += 1
                return True, _t_at(0.5 * (mn + mx), zA, zB, tA, tB), nh
            if clip:
                # the part of the ray with depth in [mn, mx] (depth decreases along u)
                uc0 = (1.0 / (mx + tol) - wA) / (wB - wA)
                uc1 = (1.0 / max(mn - tol, 1e-300) - wA) / (wB - wA)
                if uc0 > u0:
                    nh = _add_interval(hid, nh, _t_at(zhi, zA, zB, tA, tB), _t_at(mx + tol, zA, zB, tA, tB))
                    u0 = uc0
                if uc1 < u1:
                    u1 = uc1
                if u0 > u1:
                    continue
        # children in ray order
        h = float(1 << (L - 1))
        nc = 0
        for a in range(2):
            for b in range(2):
                ii = 2 * bi + a
                jj = 2 * bj + b
                c0, c1 = clip_line_to_box(ax, ay, dx, dy, jj * h, ii * h, (jj + 1) * h, (ii + 1) * h, u0, u1)
                if c0 <= c1:
                    # insertion by entry parameter (descending, so the first is pushed last)
                    m = nc
                    while m > 0 and stack[kb + m - 1, 3] < c0:
                        for f in range(5):
                            stack[kb + m, f] = stack[kb + m - 1, f]
                        m -= 1
                    stack[kb + m, 0] = L - 1
                    stack[kb + m, 1] = ii
                    stack[kb + m, 2] = jj
                    stack[kb + m, 3] = c0
                    stack[kb + m, 4] = c1
                    nc += 1
        for m in range(nc):
            for f in range(5):
                stack[sp, f] = stack[kb + m, f]
            sp += 1
    return False, 0.0, nh


@kernel(nrt=False)
def rank_reference_images(vps, ox, oy, oz, lx, ly, lz, flags, seg, order):
    """Clip and project the ray in every reference image (``seg[k]`` = ok, A, B, zA, zB, tA, tB) and
    order the images by the length of the clipped epipolar segment, shortest first (the paper's
    ranking after Chang); without ``F_RANK``, in their fixed order."""
    n = vps.shape[0]
    for k in range(n):
        ok, ax, ay, bx, by, za, zb, ta, tb = epipolar_segment(vps[k], ox, oy, oz, lx, ly, lz, 0.0, 1.0)
        seg[k, 0] = 1.0 if ok else 0.0
        seg[k, 1] = ax
        seg[k, 2] = ay
        seg[k, 3] = bx
        seg[k, 4] = by
        seg[k, 5] = za
        seg[k, 6] = zb
        seg[k, 7] = ta
        seg[k, 8] = tb
        seg[k, 9] = math.hypot(bx - ax, by - ay) if ok else 0.0
        order[k] = k
    if (flags & F_RANK) != 0:
        for a in range(1, n):
            m = a
            while m > 0 and seg[order[m - 1], 9] > seg[order[m], 9]:
                order[m - 1], order[m] = order[m], order[m - 1]
                m -= 1


@kernel(nrt=False)
def trace_shadow_ray(
    ox, oy, oz, lx, ly, lz, vps, D, MN, MX, CONN, offs, gapk, flags, stack, seg, order, hidA, hidB, cnt
):
    """Visibility along the shadow ray o -> l through all reference images, in ranked order, until
    a hit. Clear miss: an image in which the ray never passes behind geometry proves the ray
    unblocked (other images skipped). Occlusion intervals: after the first image, only the
    intervals in which the ray passed behind geometry in every image so far are traced.
    Returns (blocked, t_hit) with the blocker at o + t_hit (l - o)."""
    n = vps.shape[0]
    cnt[C_RAYS] += 1
    rank_reference_images(vps, ox, oy, oz, lx, ly, lz, flags, seg, order)
    use_iv = (flags & F_INTERVALS) != 0
    clear = (flags & F_CLEAR) != 0
    ncur = 0  # intervals to trace (hidA), valid after the first image when use_iv
    for r in range(n):
        k = order[r]
        cnt[C_IMAGES] += 1
        nnew = np.int64(0)  # typed, not the literal 0: traverse_epipolar compiles once
        if r == 0 or not use_iv:
            if seg[k, 0] != 0.0:
                hit, th, nnew = traverse_epipolar(
                    k,
                    seg[k, 1],
                    seg[k, 2],
                    seg[k, 3],
                    seg[k, 4],
                    seg[k, 5],
                    seg[k, 6],
                    seg[k, 7],
                    seg[k, 8],
                    D,
                    MN,
                    MX,
                    CONN,
                    offs,
                    gapk[k],
                    flags,
                    stack,
                    hidB,
                    np.int64(0),  # not the literal 0: one specialisation for both call sites
                    cnt,
                )
                if hit:
                    cnt[C_BLOCKED] += 1
                    return True, th
        else:
            for m in range(ncur):
                ok, ax, ay, bx, by, za, zb, ta, tb = epipolar_segment(
                    vps[k], ox, oy, oz, lx, ly, lz, hidA[m, 0], hidA[m, 1]
                )
                if not ok:
                    continue
                hit, th, nnew = traverse_epipolar(
                    k, ax, ay, bx, by, za, zb, ta, tb, D, MN, MX, CONN, offs, gapk[k], flags, stack, hidB, nnew, cnt
                )
                if hit:
                    cnt[C_BLOCKED] += 1
                    return True, th
        if nnew == 0 and (clear or use_iv):
            if r < n - 1:
                cnt[C_CLEAR] += 1
            return False, 0.0
        if use_iv:
            for m in range(nnew):
                hidA[m, 0] = hidB[m, 0]
                hidA[m, 1] = hidB[m, 1]
            ncur = nnew
    return False, 0.0


@kernel(nogil=True, noalias=True)
def trace_rays_slot(slot, org, dst, vps, D, MN, MX, CONN, offs, gapk, flags, nchunk, blocked, thit, cnt, nslot):
    """Trace independent rays org[i] -> dst[i] (for tests and studies): blocked[i], t_hit[i];
    cnt[chunk] the counters of each chunk of rays. Run by ``run_slots``: slot ``slot`` of ``nslot``
    takes every ``nslot``-th chunk."""
    n = org.shape[0]
    nref = vps.shape[0]
    nlev = offs.shape[0] - 1
    per = (n + nchunk - 1) // nchunk
    stack = np.empty((4 * nlev + 12, 5))
    seg = np.empty((nref, 10))
    order = np.empty(nref, np.int64)
    hidA = np.empty((MAX_INTERVALS, 2))
    hidB = np.empty((MAX_INTERVALS, 2))
    for c in range(slot, nchunk, nslot):
        for i in range(c * per, min(n, (c + 1) * per)):
            b, th = trace_shadow_ray(
                org[i, 0],
                org[i, 1],
                org[i, 2],
                dst[i, 0],
                dst[i, 1],
                dst[i, 2],
                vps,
                D,
                MN,
                MX,
                CONN,
                offs,
                gapk,
                flags,
                stack,
                seg,
                order,
                hidA,
                hidB,
                cnt[c],
            )
            blocked[i] = b
            thit[i] = th


def trace_rays(org, dst, vps, D, MN, MX, CONN, offs, gapk, flags, nchunk, blocked, thit, cnt) -> None:
    """:func:`trace_rays_slot` over every chunk, one slot per thread."""
    run_threads(trace_rays_slot, org, dst, vps, D, MN, MX, CONN, offs, gapk, flags, nchunk, blocked, thit, cnt)


def trace_ray_batch(refs: ReferenceImages, org: np.ndarray, dst: np.ndarray, flags: int = F_ALL):
    """Python entry for :func:`trace_rays`: (blocked (n,) bool, t_hit (n,), counters dict)."""
    org = np.ascontiguousarray(org, np.float64)
    dst = np.ascontiguousarray(dst, np.float64)
    n = len(org)
    nchunk = max(1, min(64, n))
    blocked = np.zeros(n, np.bool_)
    thit = np.zeros(n)
    cnt = np.zeros((nchunk, N_COUNTERS), np.int64)
    trace_rays(
        org,
        dst,
        refs.vps,
        refs.D,
        refs.MN,
        refs.MX,
        refs.CONN,
        refs.offs,
        refs.gapk,
        int(flags),
        nchunk,
        blocked,
        thit,
        cnt,
    )
    return blocked, thit, _counters(cnt.sum(axis=0))


def _counters(c) -> dict:
    return {
        "rays": int(c[C_RAYS]),
        "nodes": int(c[C_NODES]),
        "leaves": int(c[C_LEAVES]),
        "clear_misses": int(c[C_CLEAR]),
        "image_traversals": int(c[C_IMAGES]),
        "blocked": int(c[C_BLOCKED]),
        "connectedness_hits": int(c[C_CONNHIT]),
        "self_blocked": int(c[C_SELF]),
    }


# ------------------------------------------------------------------------------------------------
# Coherence-based sampling of the light (Sec. 5.2)
# ------------------------------------------------------------------------------------------------
@kernel
def _project_to_light(ox, oy, oz, bx, by, bz, cen, u, v, nl, uu, vv):
    """Light coordinates (a, b) in [0,1]^2 of the point where the line from o through the blocker b
    meets the light's plane; ok False when b is not between o and the plane."""
    dx, dy, dz = bx - ox, by - oy, bz - oz
    den = dx * nl[0] + dy * nl[1] + dz * nl[2]
    num = (cen[0] - ox) * nl[0] + (cen[1] - oy) * nl[1] + (cen[2] - oz) * nl[2]
    if den == 0.0:
        return False, 0.0, 0.0
    s = num / den
    if not (s >= 1.0):
        return False, 0.0, 0.0
    px = ox + s * dx - cen[0]
    py = oy + s * dy - cen[1]
    pz = oz + s * dz - cen[2]
    a = (px * u[0] + py * u[1] + pz * u[2]) / uu + 0.5
    b = (px * v[0] + py * v[1] + pz * v[2]) / vv + 0.5
    return True, a, b


@kernel
def predict_visibility(ox, oy, oz, blk, nblk, hires_done, cen, u, v, nl, N, H, sa, sb, pred, state, grid):
    """The Predict procedure: project every blocker point from o onto the light; drop those outside
    it, keep one per high-resolution cell (H x H per light cell), mark their cells blocked in the
    predicted visibility image ``pred`` (1 = blocked). A cell whose jittered sample lies in a
    high-resolution cell holding a blocker point is done (assumed blocked, not traced). Then every
    exterior cell and every interior cell whose 8 neighbours do not all share its prediction is
    to be traced (``state`` 1), the others use the prediction (``state`` 2). Returns the number of
    blocker points kept (compacted to the front of ``blk``)."""
    NH = N * H
    uu = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    for c in range(N * N):
        pred[c] = 0
        state[c] = 0
    for g in range(NH * NH):
        grid[g] = 0
    nk = 0
    for m in range(nblk):
        ok, a, b = _project_to_light(ox, oy, oz, blk[m, 0], blk[m, 1], blk[m, 2], cen, u, v, nl, uu, vv)
        if not ok or not (0.0 <= a < 1.0) or not (0.0 <= b < 1.0):
            continue
        ha = min(int(a * NH), NH - 1)
        hb = min(int(b * NH), NH - 1)
        g = ha * NH + hb
        if grid[g] != 0:
            continue
        grid[g] = 1
        blk[nk, 0] = blk[m, 0]
        blk[nk, 1] = blk[m, 1]
        blk[nk, 2] = blk[m, 2]
        nk += 1
        c = (ha // H) * N + hb // H
        pred[c] = 1
        if hires_done and min(int(sa[c] * NH), NH - 1) == ha and min(int(sb[c] * NH), NH - 1) == hb:
            state[c] = 3  # done: a blocker point lies next to this cell's ray
    for ci in range(N):
        for cj in range(N):
            c = ci * N + cj
            if state[c] == 3:
                continue
            if ci == 0 or cj == 0 or ci == N - 1 or cj == N - 1:
                state[c] = 1
                continue
            same = True
            for di in range(-1, 2):
                for dj in range(-1, 2):
                    if pred[(ci + di) * N + cj + dj] != pred[c]:
                        same = False
            state[c] = 2 if same else 1
    return nk


@kernel(nogil=True)
def coherent_tiles(
    slot,
    nslot,
    pts,
    nrm,
    pix,
    self_occ,
    self_sin,
    order,
    tstart,
    cen,
    u,
    v,
    nl,
    N,
    H,
    seed,
    coherence,
    hires_done,
    reset2,
    offset,
    vps,
    D,
    MN,
    MX,
    CONN,
    offs,
    gapk,
    kpix0,
    flags,
    vis,
    irr,
    nrays,
    cnt,
):
    """The SoftShad procedure, one coherent walk per tile (``order[tstart[t]:tstart[t+1]]``: the
    tile's points, serpentine), tiles in parallel; each tile starts with an empty blocker points
    list, so the output does not depend on the number of threads. Run by ``run_slots``, one slot per thread."""
    ntile = tstart.shape[0] - 1
    nref = vps.shape[0]
    nlev = offs.shape[0] - 1
    S = N * N
    cap = S * H * H + S
    for t in range(slot, ntile, nslot):  # tiles dealt round-robin to the slots
        stack = np.empty((4 * nlev + 12, 5))
        seg = np.empty((nref, 10))
        rorder = np.empty(nref, np.int64)
        hidA = np.empty((MAX_INTERVALS, 2))
        hidB = np.empty((MAX_INTERVALS, 2))
        blk = np.empty((cap, 3))
        grid = np.empty(N * H * N * H, np.uint8)
        pred = np.empty(S, np.uint8)
        state = np.empty(S, np.uint8)
        visimg = np.empty(S, np.uint8)
        queue = np.empty(S, np.int64)
        sa = np.empty(S)
        sb = np.empty(S)
        c_ = cnt[t]
        nblk = np.int64(0)  # not the literal 0: predict_visibility compiles once
        valid = False  # a prediction exists (a previous point in this walk, no reset since)
        px0 = np.nan
        py0 = np.nan
        pz0 = np.nan
        for q in range(tstart[t], tstart[t + 1]):
            k = order[q]
            px, py, pz = pts[k, 0], pts[k, 1], pts[k, 2]
            # depth of p in the first reference view -> the texel size there (origin offset)
            zp = (px - vps[0, 0]) * vps[0, 9] + (py - vps[0, 1]) * vps[0, 10] + (pz - vps[0, 2]) * vps[0, 11]
            eps = offset * kpix0 * abs(zp)
            ox = px + eps * nrm[k, 0]
            oy = py + eps * nrm[k, 1]
            oz = pz + eps * nrm[k, 2]
            d2 = (px - px0) ** 2 + (py - py0) ** 2 + (pz - pz0) ** 2
            if not (d2 <= reset2):  # far from the previous point (or the first): reset the list
                nblk = np.int64(0)
                valid = False
            px0, py0, pz0 = px, py, pz
            key = point_key(seed, pix[k])
            for c in range(S):
                ja, jb = jitter_pair(key, c)
                sa[c] = (c // N + ja) / N
                sb[c] = (c % N + jb) / N
            if coherence and valid:
                nblk = predict_visibility(
                    ox, oy, oz, blk, nblk, hires_done, cen, u, v, nl, N, H, sa, sb, pred, state, grid
                )
            else:
                nblk = np.int64(0)
                for c in range(S):
                    pred[c] = 0
                    state[c] = 1
            head = 0
            tail = 0
            for c in range(S):
                visimg[c] = pred[c]
                if state[c] == 1:
                    queue[tail] = c
                    tail += 1
            traced = 0
            while head < tail:
                c = queue[head]
                head += 1
                lx = cen[0] + (sa[c] - 0.5) * u[0] + (sb[c] - 0.5) * v[0]
                ly = cen[1] + (sa[c] - 0.5) * u[1] + (sb[c] - 0.5) * v[1]
                lz = cen[2] + (sa[c] - 0.5) * u[2] + (sb[c] - 0.5) * v[2]
                rx, ry, rz = lx - ox, ly - oy, lz - oz
                if self_occ[k] and rx * nrm[k, 0] + ry * nrm[k, 1] + rz * nrm[k, 2] < -self_sin * math.sqrt(
                    rx * rx + ry * ry + rz * rz
                ):
                    # the ray dives into the occluder surface it starts on: blocked by that surface
                    b = True
                    th = -1.0
                    c_[C_SELF] += 1
                else:
                    b, th = trace_shadow_ray(
                        ox,
                        oy,
                        oz,
                        lx,
                        ly,
                        lz,
                        vps,
                        D,
                        MN,
                        MX,
                        CONN,
                        offs,
                        gapk,
                        flags,
                        stack,
                        seg,
                        rorder,
                        hidA,
                        hidB,
                        c_,
                    )
                    traced += 1
                bv = 1 if b else 0
                if b and th >= 0.0 and coherence and nblk < cap:
                    blk[nblk, 0] = ox + th * (lx - ox)
                    blk[nblk, 1] = oy + th * (ly - oy)
                    blk[nblk, 2] = oz + th * (lz - oz)
                    nblk += 1
                if bv != visimg[c]:
                    visimg[c] = bv
                    if coherence:  # 8-connected flood fill of low confidence
                        ci = c // N
                        cj = c % N
                        for di in range(-1, 2):
                            for dj in range(-1, 2):
                                ni = ci + di
                                nj = cj + dj
                                if 0 <= ni < N and 0 <= nj < N:
                                    cn = ni * N + nj
                                    if state[cn] == 2:
                                        state[cn] = 1
                                        queue[tail] = cn
                                        tail += 1
            free = 0
            e = 0.0
            for c in range(S):
                if visimg[c] == 0:
                    free += 1
                    lx = cen[0] + (sa[c] - 0.5) * u[0] + (sb[c] - 0.5) * v[0] - ox
                    ly = cen[1] + (sa[c] - 0.5) * u[1] + (sb[c] - 0.5) * v[1] - oy
                    lz = cen[2] + (sa[c] - 0.5) * u[2] + (sb[c] - 0.5) * v[2] - oz
                    rl = math.sqrt(lx * lx + ly * ly + lz * lz)
                    cp = max(0.0, (nrm[k, 0] * lx + nrm[k, 1] * ly + nrm[k, 2] * lz) / rl)
                    cl = max(0.0, -(nl[0] * lx + nl[1] * ly + nl[2] * lz) / rl)
                    e += cp * cl / (rl * rl)
            vis[k] = free / S
            irr[k] = e / S
            nrays[k] = traced
            valid = True


def tile_order(idx: np.ndarray, width: int, tile: int) -> tuple[np.ndarray, np.ndarray]:
    """Points (flat eye-pixel indices ``idx``) grouped by ``tile`` x ``tile`` pixel tiles, serpentine
    inside each tile (rows alternate direction), so consecutive points are image neighbours.
    Returns (order into idx, tile start offsets)."""
    r = idx // width
    c = idx % width
    ntx = (width + tile - 1) // tile
    tid = (r // tile) * ntx + c // tile
    lr = r % tile
    lc = c % tile
    key = lr * tile + np.where(lr % 2 == 0, lc, tile - 1 - lc)
    order = np.lexsort((key, tid)).astype(np.int64)
    ts = tid[order]
    starts = np.flatnonzero(np.r_[True, ts[1:] != ts[:-1]])
    return order, np.r_[starts, len(order)].astype(np.int64)


def accel_flags(hierarchical, minmax_clip, connectedness, clear_miss, occlusion_intervals, ranking) -> int:
    return (
        (F_HIER if hierarchical else 0)
        | (F_CLIP if minmax_clip else 0)
        | (F_CONN if connectedness else 0)
        | (F_CLEAR if clear_miss else 0)
        | (F_INTERVALS if occlusion_intervals else 0)
        | (F_RANK if ranking else 0)
    )


def _perfect_square(n):
    return None if round(n**0.5) ** 2 == n else "a perfect square (N x N light cells)"


@register
class CoherentRaytrace(Method):
    name = "coherent-raytrace"
    light_view = True  # renders/projects the occluders from the light (limits: softshadows.limits)
    light_shapes = ("rect",)
    summary = "shadow rays traced through corner depth images with coherence-based light sampling"
    paper = (
        "Agrawala, Ramamoorthi, Heirich, Moll 2000: Efficient image-based methods for rendering soft shadows (Sec. 5)"
    )
    params = (
        Param(
            "samples",
            256,
            "light samples per point: N x N cells, one jittered sample each",
            min=1,
            max=4096,
            check=_perfect_square,
        ),
        Param(
            "refs",
            4,
            "reference depth images: 4 light corners, 1 center, 5 corners + center, 9 (3x3)",
            choices=(1, 4, 5, 9),
        ),
        Param("resolution", 1024, "reference depth image size (pixels, square)", min=16, max=4096),
        Param("bias", 1.0, "shadow (depth) bias in texels of the reference images", min=0.0),
        Param("gap", 4.0, "gap bias in texels: adjacent depths closer than this are joined by a wall", min=0.0),
        Param("offset", 1.0, "ray origin offset along the normal, in texels at the point's depth", min=0.0),
        Param(
            "self_sin",
            0.2,
            "a ray from an occluder surface diving below its plane by more than this sine is blocked by it; 1: off",
            min=0.0,
            max=1.0,
        ),
        Param("coherence", True, "coherence-based sampling of the light (Sec. 5.2); off: trace every cell"),
        Param("hierarchical", True, "hierarchical min/max overlap test (off: visit every pixel on the ray)"),
        Param("minmax_clip", True, "min/max clipping of the epipolar depth interval at every level"),
        Param("connectedness", True, "hierarchical connectedness (blocked at a coarse connected node)"),
        Param("clear_miss", True, "a ray never behind geometry in one image is unblocked"),
        Param("occlusion_intervals", True, "trace only the intervals hidden in the previous images"),
        Param("ranking", True, "rank reference images by clipped epipolar length"),
        Param("hires", 3, "blocker points kept per light cell: one per cell of an H x H grid", min=1, max=8),
        Param("hires_done", True, "a blocker point in the sample's high-res cell marks the cell blocked"),
        Param("reset_distance", 0.02, "reset the blocker points when the point moves more (x scene diagonal)", min=0.0),
        Param("tile", 8, "eye-pixel tile side: one coherent (serpentine) walk per tile", min=1, max=256),
        Param("physical", False, "image = full area-light integral of Eq. 1 (V unchanged)"),
        Param("margin", 0.02, "window margin of the reference images around the occluders", min=0.0),
    )

    #: what `softshadows pareto` sweeps (Method.sweep)
    sweep: ClassVar = {"samples": [16, 64, 256], "resolution": [512, 1024]}

    def run(
        self,
        ctx,
        samples,
        refs,
        resolution,
        bias,
        gap,
        offset,
        self_sin,
        coherence,
        hierarchical,
        minmax_clip,
        connectedness,
        clear_miss,
        occlusion_intervals,
        ranking,
        hires,
        hires_done,
        reset_distance,
        tile,
        physical,
        margin,
    ):
        scene = ctx.scene
        light = scene.light
        t_pre = ctx.timer.times.get("precompute", 0.0)
        with ctx.timer.phase("precompute"):
            ref, reused = reference_images(scene, refs, resolution, bias, gap, margin)
        if reused:  # report 0 on reuse
            ctx.timer.times["precompute"] = t_pre
        pts, nrm, idx = ctx.points()
        K = len(pts)
        N = int(round(math.sqrt(samples)))
        W = ctx.eye.mask.shape[1]
        lo, hi = scene.bounds()
        diag = float(np.linalg.norm(hi - lo))
        # points on occluder faces: a ray diving below their plane is blocked by their own surface
        self_occ = scene.flat.occluder[np.maximum(ctx.eye.tri_id.reshape(-1)[idx], 0)]
        flags = accel_flags(hierarchical, minmax_clip, connectedness, clear_miss, occlusion_intervals, ranking)
        with ctx.timer.phase("trace"):
            order, tstart = tile_order(idx, W, tile)
            ntile = len(tstart) - 1
            vis = np.zeros(K, np.float32)
            irr = np.zeros(K, np.float64)
            nrays = np.zeros(K, np.int32)
            cnt = np.zeros((max(ntile, 1), N_COUNTERS), np.int64)
            if K:
                nslot = numba.get_num_threads()
                run_slots(
                    coherent_tiles,
                    nslot,
                    nslot,
                    pts,
                    nrm,
                    idx,
                    self_occ,
                    self_sin,
                    order,
                    tstart,
                    light.center,
                    light.u,
                    light.v,
                    light.normal,
                    N,
                    hires,
                    int(ctx.seed),
                    bool(coherence),
                    bool(hires_done),
                    (reset_distance * diag) ** 2,
                    offset,
                    ref.vps,
                    ref.D,
                    ref.MN,
                    ref.MX,
                    ref.CONN,
                    ref.offs,
                    ref.gapk,
                    float(ref.kpix[0]),
                    flags,
                    vis,
                    irr,
                    nrays,
                    cnt,
                )
        c = _counters(cnt.sum(axis=0))
        hist = np.histogram(nrays, bins=16, range=(0, samples))[0]
        stats = {
            "samples": samples,
            "points": K,
            "rays": c["rays"],
            "rays_per_point": float(nrays.mean()) if K else 0.0,
            "rays_per_point_hist": hist.tolist(),
            "rays_per_point_hist_width": samples / 16,
            "nodes_visited": c["nodes"],
            "nodes_per_ray": c["nodes"] / max(c["rays"], 1),
            "leaves_tested": c["leaves"],
            "clear_misses": c["clear_misses"],
            "clear_miss_fraction": c["clear_misses"] / max(c["rays"], 1),
            "image_traversals_per_ray": c["image_traversals"] / max(c["rays"], 1),
            "connectedness_hits": c["connectedness_hits"],
            "self_blocked_per_point": c["self_blocked"] / max(K, 1),
            "blocked_fraction": c["blocked"] / max(c["rays"], 1),
            "reference_images": len(ref.views),
            "reference_resolution": resolution,
            "precompute_reused": bool(reused),
        }
        out = ctx.scatter(vis, idx)
        shadowed = None
        if physical:
            shadowed = np.full(out.size, np.nan)
            shadowed[idx] = irr * light.intensity * exposure(scene)
            shadowed = shadowed.reshape(out.shape)
        return MethodOutput(out, stats, direct_shadowed=shadowed)
