"""The shared software rasterizer: sort-middle, tile-parallel, watertight, near-plane clipped.

Pipeline (all Numba kernels on plain arrays; the functions at the bottom only orchestrate):

1. **setup** (parallel over chunks of triangles, fused with the binning count pass): transform the three corners to view space, cull in *world*
   space, reject triangles beyond ``far`` or behind ``near``, clip against the near plane
   (``z = near``) in view space (up to 2 pieces per triangle, both carrying the original index), project,
   snap to a 1/4096 px grid, orient, and store per piece its pixel bounding box and its three edge
   equations; per original triangle store the view-space plane (``n . X = d``) and the dual vectors
   that give its barycentrics. Depth and barycentrics of a fragment are computed from the *original*
   triangle's plane by intersecting the ray through the pixel center with it, so they are exact
   (float64) and perspective-correct whatever clipping did; clipping only decides coverage.
2. **binning**: per (chunk, tile) counts (during setup), prefix sum, fill pass (parallel over the same
   chunks); each tile's bin lists its pieces in increasing triangle index, so the result does not
   depend on the thread count.
3. **tiles** (parallel over ``TILE`` x ``TILE`` pixel tiles): each tile is rasterized by one thread into
   its own region of the outputs (no atomics). Coverage: pixel centers ``(j+0.5, i+0.5)``, float64 edge
   functions evaluated from the edge's canonically ordered endpoints (a shared edge gives exactly
   opposite values for the two triangles, always) and a top-left fill rule: a pixel center on a shared
   edge or vertex belongs to exactly one triangle. With the 1/4096 px snap the edge functions are
   exact (no rounding at all) for every piece whose bounding box is under 16384 px, and coverage
   differs from the true triangle by at most 1/8192 px, so the exact plane depth is never
   extrapolated noticeably (a coarser snap, e.g. 1/256 px, let back faces win the depth test on some
   silhouette pixels). Either winding is rasterized.

Depth is the view-space z (distance along ``forward``, world units) for both perspective and
orthographic views; the depth test runs in float64 and the outputs are float32.
"""
from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from .gbuffer import Fragments, GBuffer
from .kernels import view_coords, view_coords_to_screen
from .programs import run_program

TILE = 16  #: tile size in pixels (square)
SUBPIXEL = 4096.0  #: screen coordinates are snapped to 1/SUBPIXEL px before coverage
_PERSPECTIVE_MIN_NEAR = 1e-9

_JIT = dict(cache=True, fastmath=False, error_model="numpy")

_CULL = {"none": 0, "back": 1, "front": 2}

# modes of the tile kernel
_M_DEPTH, _M_GBUF, _M_FCOUNT, _M_FFILL, _M_MINBLEND = 0, 1, 2, 3, 4


# ----------------------------------------------------------------------------------------------
# setup
# ----------------------------------------------------------------------------------------------
@njit(**_JIT)
def _snap(v):
    return math.floor(v * SUBPIXEL + 0.5) / SUBPIXEL


@njit(**_JIT)
def _clip_point(xi, yi, zi, xo, yo, zo, near):
    """Point of segment inside->outside on z = near. Always called with (inside, outside) in this order,
    so that the two triangles sharing an edge compute bit-identical points."""
    s = (near - zi) / (zo - zi)
    return xi + s * (xo - xi), yi + s * (yo - yi), near


@njit(**_JIT)
def _store_edge(CE, slot, k, ax, ay, bx, by):
    """Directed edge a->b of a positively oriented piece; inside is E >= 0 with
    E(p) = cross(b - a, p - a), evaluated from the canonically ordered endpoints."""
    if ax < bx or (ax == bx and ay < by):
        CE[slot, k, 0] = ax
        CE[slot, k, 1] = ay
        CE[slot, k, 2] = bx - ax
        CE[slot, k, 3] = by - ay
        CE[slot, k, 4] = 1.0
    else:
        CE[slot, k, 0] = bx
        CE[slot, k, 1] = by
        CE[slot, k, 2] = ax - bx
        CE[slot, k, 3] = ay - by
        CE[slot, k, 4] = -1.0
    ddx = bx - ax
    ddy = by - ay
    # top-left rule (y down): top edges (horizontal, going right) and left edges (going up) own
    # the pixel centers lying exactly on them. Opposite directions never both qualify.
    CE[slot, k, 5] = 1.0 if (ddy < 0.0 or (ddy == 0.0 and ddx > 0.0)) else 0.0


@njit(**_JIT)
def _setup_piece(vp, slot, x0, y0, z0, x1, y1, z1, x2, y2, z2, far, CB, CE, CZ):
    """Project, snap, orient one (clipped) triangle; returns 1 if it may cover a pixel center."""
    W = vp[18]
    H = vp[19]
    zmin = min(z0, min(z1, z2))
    zmax = max(z0, max(z1, z2))
    if zmin > far:
        return 0
    sx0, sy0 = view_coords_to_screen(vp, x0, y0, z0)
    sx1, sy1 = view_coords_to_screen(vp, x1, y1, z1)
    sx2, sy2 = view_coords_to_screen(vp, x2, y2, z2)
    sx0 = _snap(sx0)
    sy0 = _snap(sy0)
    sx1 = _snap(sx1)
    sy1 = _snap(sy1)
    sx2 = _snap(sx2)
    sy2 = _snap(sy2)
    if not (math.isfinite(sx0) and math.isfinite(sy0) and math.isfinite(sx1) and math.isfinite(sy1)
            and math.isfinite(sx2) and math.isfinite(sy2)):
        return 0
    xmin = min(sx0, min(sx1, sx2))
    xmax = max(sx0, max(sx1, sx2))
    ymin = min(sy0, min(sy1, sy2))
    ymax = max(sy0, max(sy1, sy2))
    # pixel centers inside the bounding box, clamped to the image (in float: no int overflow)
    fj0 = max(math.ceil(xmin - 0.5), 0.0)
    fj1 = min(math.floor(xmax - 0.5), W - 1.0)
    fi0 = max(math.ceil(ymin - 0.5), 0.0)
    fi1 = min(math.floor(ymax - 0.5), H - 1.0)
    if fj0 > fj1 or fi0 > fi1:
        return 0
    area = (sx1 - sx0) * (sy2 - sy0) - (sy1 - sy0) * (sx2 - sx0)
    if not (area != 0.0 and math.isfinite(area)):
        return 0
    if area < 0.0:
        sx1, sx2 = sx2, sx1
        sy1, sy2 = sy2, sy1
    CB[slot, 0] = int(fi0)
    CB[slot, 1] = int(fi1)
    CB[slot, 2] = int(fj0)
    CB[slot, 3] = int(fj1)
    CZ[slot, 0] = zmin
    CZ[slot, 1] = zmax
    _store_edge(CE, slot, 0, sx0, sy0, sx1, sy1)
    _store_edge(CE, slot, 1, sx1, sy1, sx2, sy2)
    _store_edge(CE, slot, 2, sx2, sy2, sx0, sy0)
    return 1


@njit(**_JIT)
def _setup_one(t, verts, faces, vp, near, cull, NC, CB, CE, CZ, PL, NW):
    """Triangle t: NC[t] pieces in slots 2t, 2t+1 of CB/CE/CZ; PL[t] plane data; NW[t] unit normal."""
    ortho = vp[20] != 0.0
    far = vp[17]
    NC[t] = 0
    ia = faces[t, 0]
    ib = faces[t, 1]
    ic = faces[t, 2]
    ax = verts[ia, 0]
    ay = verts[ia, 1]
    az = verts[ia, 2]
    bx = verts[ib, 0]
    by = verts[ib, 1]
    bz = verts[ib, 2]
    cx = verts[ic, 0]
    cy = verts[ic, 1]
    cz = verts[ic, 2]
    # world-space face normal (as wound) and facing
    e1x = bx - ax
    e1y = by - ay
    e1z = bz - az
    e2x = cx - ax
    e2y = cy - ay
    e2z = cz - az
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not (nn > 0.0 and math.isfinite(nn)):
        return  # degenerate or non-finite
    if cull != 0:
        if ortho:
            f = nx * vp[9] + ny * vp[10] + nz * vp[11]
        else:
            f = nx * (ax - vp[0]) + ny * (ay - vp[1]) + nz * (az - vp[2])
        # front-facing: f < 0; back-facing: f > 0; edge-on (f == 0) is dropped by either cull
        if cull == 1 and not (f < 0.0):
            return
        if cull == 2 and not (f > 0.0):
            return
    NW[t, 0] = nx / nn
    NW[t, 1] = ny / nn
    NW[t, 2] = nz / nn
    # view space
    x0, y0, z0 = view_coords(vp, ax, ay, az)
    x1, y1, z1 = view_coords(vp, bx, by, bz)
    x2, y2, z2 = view_coords(vp, cx, cy, cz)
    if min(z0, min(z1, z2)) > far or max(z0, max(z1, z2)) < near:
        return
    # plane n.X = d and dual vectors: b1 = (X - P0).m1, b2 = (X - P0).m2 for X in the plane
    f1x = x1 - x0
    f1y = y1 - y0
    f1z = z1 - z0
    f2x = x2 - x0
    f2y = y2 - y0
    f2z = z2 - z0
    vnx = f1y * f2z - f1z * f2y
    vny = f1z * f2x - f1x * f2z
    vnz = f1x * f2y - f1y * f2x
    n2 = vnx * vnx + vny * vny + vnz * vnz
    if not (n2 > 0.0 and math.isfinite(n2)):
        return
    m1x = (f2y * vnz - f2z * vny) / n2  # (e2 x n) / |n|^2
    m1y = (f2z * vnx - f2x * vnz) / n2
    m1z = (f2x * vny - f2y * vnx) / n2
    m2x = (vny * f1z - vnz * f1y) / n2  # (n x e1) / |n|^2
    m2y = (vnz * f1x - vnx * f1z) / n2
    m2z = (vnx * f1y - vny * f1x) / n2
    PL[t, 0] = vnx
    PL[t, 1] = vny
    PL[t, 2] = vnz
    PL[t, 3] = vnx * x0 + vny * y0 + vnz * z0
    PL[t, 4] = m1x
    PL[t, 5] = m1y
    PL[t, 6] = m1z
    PL[t, 7] = m1x * x0 + m1y * y0 + m1z * z0
    PL[t, 8] = m2x
    PL[t, 9] = m2y
    PL[t, 10] = m2z
    PL[t, 11] = m2x * x0 + m2y * y0 + m2z * z0
    # near-plane clipping in view space
    in0 = z0 >= near
    in1 = z1 >= near
    in2 = z2 >= near
    nin = int(in0) + int(in1) + int(in2)
    s0 = 2 * t
    if nin == 3:
        NC[t] = _setup_piece(vp, s0, x0, y0, z0, x1, y1, z1, x2, y2, z2, far, CB, CE, CZ)
        return
    # rotate the corners (keeping the cyclic order) so that the odd one out comes first
    if nin == 1:
        odd0 = in0
        odd1 = in1
    else:
        odd0 = not in0
        odd1 = not in1
    if odd0:
        px, py, pz, qx, qy, qz, rx, ry, rz = x0, y0, z0, x1, y1, z1, x2, y2, z2
    elif odd1:
        px, py, pz, qx, qy, qz, rx, ry, rz = x1, y1, z1, x2, y2, z2, x0, y0, z0
    else:
        px, py, pz, qx, qy, qz, rx, ry, rz = x2, y2, z2, x0, y0, z0, x1, y1, z1
    if nin == 1:
        # P inside, Q and R outside: triangle P, PQ', PR'
        ux, uy, uz = _clip_point(px, py, pz, qx, qy, qz, near)
        wx, wy, wz = _clip_point(px, py, pz, rx, ry, rz, near)
        NC[t] = _setup_piece(vp, s0, px, py, pz, ux, uy, uz, wx, wy, wz, far, CB, CE, CZ)
    else:
        # P outside, Q and R inside: quad Q, R, RP', QP' -> (Q, R, RP') and (Q, RP', QP')
        ux, uy, uz = _clip_point(rx, ry, rz, px, py, pz, near)
        wx, wy, wz = _clip_point(qx, qy, qz, px, py, pz, near)
        k = _setup_piece(vp, s0, qx, qy, qz, rx, ry, rz, ux, uy, uz, far, CB, CE, CZ)
        k += _setup_piece(vp, s0 + k, qx, qy, qz, ux, uy, uz, wx, wy, wz, far, CB, CE, CZ)
        NC[t] = k


# ----------------------------------------------------------------------------------------------
# binning
# ----------------------------------------------------------------------------------------------
@njit(parallel=True, **_JIT)
def _setup_count(verts, faces, vp, near, cull, NC, CB, CE, CZ, PL, NW, T, ntx, chunk, cnt):
    """Setup of every triangle (parallel over chunks of triangles) and per (chunk, tile) bin counts."""
    nchunk = cnt.shape[0]
    ntiles = cnt.shape[1]
    F = NC.shape[0]
    for c in prange(nchunk):
        for tt in range(ntiles):
            cnt[c, tt] = 0
        t1 = min(F, (c + 1) * chunk)
        for t in range(c * chunk, t1):
            _setup_one(t, verts, faces, vp, near, cull, NC, CB, CE, CZ, PL, NW)
            for k in range(NC[t]):
                ct = 2 * t + k
                for ty in range(CB[ct, 0] // T, CB[ct, 1] // T + 1):
                    for tx in range(CB[ct, 2] // T, CB[ct, 3] // T + 1):
                        cnt[c, ty * ntx + tx] += 1


@njit(**_JIT)
def _bin_offsets(cnt, bstart):
    """cnt (nchunk, ntiles) counts -> write offsets in place; bstart (ntiles+1) tile starts.
    Serial: nchunk * ntiles is small, and a parallel region costs more than it saves."""
    nchunk = cnt.shape[0]
    ntiles = cnt.shape[1]
    o = 0
    for tt in range(ntiles):
        bstart[tt] = o
        for c in range(nchunk):
            v = cnt[c, tt]
            cnt[c, tt] = o
            o += v
    bstart[ntiles] = o


@njit(parallel=True, **_JIT)
def _bin_fill(NC, CB, T, ntx, chunk, off, bins):
    nchunk = off.shape[0]
    F = NC.shape[0]
    for c in prange(nchunk):
        t1 = min(F, (c + 1) * chunk)
        for t in range(c * chunk, t1):
            for k in range(NC[t]):
                ct = 2 * t + k
                for ty in range(CB[ct, 0] // T, CB[ct, 1] // T + 1):
                    for tx in range(CB[ct, 2] // T, CB[ct, 3] // T + 1):
                        tile = ty * ntx + tx
                        bins[off[c, tile]] = ct
                        off[c, tile] += 1


# ----------------------------------------------------------------------------------------------
# tiles
# ----------------------------------------------------------------------------------------------
@njit(**_JIT)
def _bary(PL, t, xw, yw, z, ortho):
    """Barycentrics (b1, b2) of the original triangle t at the plane point seen through window
    coordinates (xw, yw) at depth z; clamped into the triangle (guards snapped-edge extrapolation)."""
    if ortho:
        b1 = PL[t, 4] * xw + PL[t, 5] * yw + PL[t, 6] * z - PL[t, 7]
        b2 = PL[t, 8] * xw + PL[t, 9] * yw + PL[t, 10] * z - PL[t, 11]
    else:
        b1 = z * (PL[t, 4] * xw + PL[t, 5] * yw + PL[t, 6]) - PL[t, 7]
        b2 = z * (PL[t, 8] * xw + PL[t, 9] * yw + PL[t, 10]) - PL[t, 11]
    if not (b1 > 0.0):
        b1 = 0.0
    if not (b2 > 0.0):
        b2 = 0.0
    s = b1 + b2
    if s > 1.0:
        b1 /= s
        b2 /= s
    return b1, b2


@njit(parallel=True, **_JIT)
def _raster_tiles(mode, vp, near, T, ntx, nty, bstart, bins, CB, CE, CZ, PL, NW, scratch,
                  depth_out, tri_out, pos_out, nrm_out, bary_out, mask_out,
                  fcount, foff, fpix, ftri, fbary, fdepth,
                  program, pparams, cattr, img, blend, bstats, split):
    """mode 0: depth + tri; 1: full G-buffer; 2: count fragments per tile; 3: write fragments;
    4: run a fragment program per fragment and MIN-blend its value into ``blend`` (bstats[tile] =
    fragments and kept fragments for triangles below / from ``split``)."""
    W = int(vp[18])
    H = int(vp[19])
    ortho = vp[20] != 0.0
    far = vp[17]
    wl = vp[12]
    wt = vp[15]
    wsx = (vp[13] - vp[12]) / vp[18]  # window units per pixel
    wsy = (vp[15] - vp[14]) / vp[19]
    ntiles = ntx * nty
    for tile in prange(ntiles):
        ty = tile // ntx
        tx = tile - ty * ntx
        y0 = ty * T
        x0 = tx * T
        y1 = min(y0 + T, H) - 1
        x1 = min(x0 + T, W) - 1
        zb = scratch[numba.get_thread_id()]
        if mode <= 1:
            for i in range(y0, y1 + 1):
                for j in range(x0, x1 + 1):
                    zb[i - y0, j - x0] = np.inf
                    tri_out[i, j] = -1
        nfrag = 0
        w = 0
        if mode == 3:
            w = foff[tile]
        elif mode == 4:
            for i in range(y0, y1 + 1):
                for j in range(x0, x1 + 1):
                    zb[i - y0, j - x0] = blend[i, j]
        for bi in range(bstart[tile], bstart[tile + 1]):
            ct = bins[bi]
            t = ct >> 1
            i0 = max(CB[ct, 0], y0)
            i1 = min(CB[ct, 1], y1)
            j0 = max(CB[ct, 2], x0)
            j1 = min(CB[ct, 3], x1)
            if i0 > i1 or j0 > j1:
                continue
            ax0 = CE[ct, 0, 0]
            ay0 = CE[ct, 0, 1]
            dx0 = CE[ct, 0, 2]
            dy0 = CE[ct, 0, 3]
            sg0 = CE[ct, 0, 4]
            in0 = CE[ct, 0, 5] != 0.0
            ax1 = CE[ct, 1, 0]
            ay1 = CE[ct, 1, 1]
            dx1 = CE[ct, 1, 2]
            dy1 = CE[ct, 1, 3]
            sg1 = CE[ct, 1, 4]
            in1 = CE[ct, 1, 5] != 0.0
            ax2 = CE[ct, 2, 0]
            ay2 = CE[ct, 2, 1]
            dx2 = CE[ct, 2, 2]
            dy2 = CE[ct, 2, 3]
            sg2 = CE[ct, 2, 4]
            in2 = CE[ct, 2, 5] != 0.0
            # conservative whole-rectangle tests (edge functions are affine: extremes at corners)
            full = False
            if (i1 - i0 + 1) * (j1 - j0 + 1) > 16:
                full = True
                reject = False
                pa = i0 + 0.5
                pb = i1 + 0.5
                qa = j0 + 0.5
                qb = j1 + 0.5
                for k in range(3):
                    ax = CE[ct, k, 0]
                    ay = CE[ct, k, 1]
                    dx = CE[ct, k, 2]
                    dy = CE[ct, k, 3]
                    sg = CE[ct, k, 4]
                    e00 = sg * (dx * (pa - ay) - dy * (qa - ax))
                    e01 = sg * (dx * (pa - ay) - dy * (qb - ax))
                    e10 = sg * (dx * (pb - ay) - dy * (qa - ax))
                    e11 = sg * (dx * (pb - ay) - dy * (qb - ax))
                    emin = min(min(e00, e01), min(e10, e11))
                    emax = max(max(e00, e01), max(e10, e11))
                    thr = 1e-12 * (abs(dx) + abs(dy)) * (abs(ax) + abs(ay) + W + H + 1.0)
                    if emax < -thr:
                        reject = True
                        break
                    if emin <= thr:
                        full = False
                if reject:
                    continue
            # sanity bounds for the plane depth of this piece's pixels: the snapped coverage may
            # extrapolate the plane a fraction of a pixel beyond the true triangle, which near the
            # plane's horizon or for edge-on triangles can give huge, negative or NaN depths
            zmin = CZ[ct, 0]
            zmax = CZ[ct, 1]
            if ortho:
                zlo = zmin - (zmax - zmin) - 1e-9 * (abs(zmin) + abs(zmax))
                zhi = zmax + (zmax - zmin) + 1e-9 * (abs(zmin) + abs(zmax))
            else:
                zlo = 0.5 * zmin
                zhi = 2.0 * zmax
            if zlo < near:
                zlo = near
            pnx = PL[t, 0]
            pny = PL[t, 1]
            pnz = PL[t, 2]
            pd = PL[t, 3]
            for i in range(i0, i1 + 1):
                py = i + 0.5
                yw = wt - py * wsy
                if ortho:
                    zrow = pd - pny * yw
                else:
                    zrow = pny * yw + pnz
                r0 = dx0 * (py - ay0)
                r1 = dx1 * (py - ay1)
                r2 = dx2 * (py - ay2)
                for j in range(j0, j1 + 1):
                    px = j + 0.5
                    if not full:
                        e = sg0 * (r0 - dy0 * (px - ax0))
                        if e < 0.0 or (e == 0.0 and not in0):
                            continue
                        e = sg1 * (r1 - dy1 * (px - ax1))
                        if e < 0.0 or (e == 0.0 and not in1):
                            continue
                        e = sg2 * (r2 - dy2 * (px - ax2))
                        if e < 0.0 or (e == 0.0 and not in2):
                            continue
                    xw = wl + px * wsx
                    if ortho:
                        z = (zrow - pnx * xw) / pnz
                    else:
                        z = pd / (pnx * xw + zrow)
                    if not (z >= zlo):  # also catches NaN (edge-on planes)
                        z = zlo
                    elif z > zhi:
                        z = zhi
                    if z > far:
                        continue
                    if mode <= 1:
                        li = i - y0
                        lj = j - x0
                        zc = zb[li, lj]
                        if z < zc or (z == zc and t < tri_out[i, j]):
                            zb[li, lj] = z
                            tri_out[i, j] = t
                    elif mode == 2:
                        nfrag += 1
                    elif mode == 4:
                        b1, b2 = _bary(PL, t, xw, yw, z, ortho)
                        a = (1.0 - b1 - b2) * cattr[t, 0] + b1 * cattr[t, 1] + b2 * cattr[t, 2]
                        val = run_program(program, pparams, a, img[i, j], z)
                        side = 0 if t < split else 1
                        bstats[tile, side] += 1
                        if val == val:  # not discarded (NaN)
                            bstats[tile, 2 + side] += 1
                            li = i - y0
                            lj = j - x0
                            if val < zb[li, lj]:
                                zb[li, lj] = val
                    else:
                        b1, b2 = _bary(PL, t, xw, yw, z, ortho)
                        fpix[w] = i * W + j
                        ftri[w] = t
                        fbary[w, 0] = b1
                        fbary[w, 1] = b2
                        fdepth[w] = z
                        w += 1
        if mode == 0:
            for i in range(y0, y1 + 1):
                for j in range(x0, x1 + 1):
                    depth_out[i, j] = zb[i - y0, j - x0]
        elif mode == 1:
            for i in range(y0, y1 + 1):
                yw = wt - (i + 0.5) * wsy
                for j in range(x0, x1 + 1):
                    t = tri_out[i, j]
                    if t < 0:
                        depth_out[i, j] = np.inf
                        mask_out[i, j] = False
                        for c in range(3):
                            pos_out[i, j, c] = np.nan
                            nrm_out[i, j, c] = np.nan
                        bary_out[i, j, 0] = np.nan
                        bary_out[i, j, 1] = np.nan
                        continue
                    z = zb[i - y0, j - x0]
                    xw = wl + (j + 0.5) * wsx
                    b1, b2 = _bary(PL, t, xw, yw, z, ortho)
                    if ortho:
                        vx = xw
                        vy = yw
                    else:
                        vx = xw * z
                        vy = yw * z
                    for c in range(3):
                        pos_out[i, j, c] = vp[c] + vx * vp[3 + c] + vy * vp[6 + c] + z * vp[9 + c]
                        nrm_out[i, j, c] = NW[t, c]
                    depth_out[i, j] = z
                    mask_out[i, j] = True
                    bary_out[i, j, 0] = b1
                    bary_out[i, j, 1] = b2
        elif mode == 2:
            fcount[tile] = nfrag
        elif mode == 4:
            for i in range(y0, y1 + 1):
                for j in range(x0, x1 + 1):
                    blend[i, j] = zb[i - y0, j - x0]


# ----------------------------------------------------------------------------------------------
# orchestration
# ----------------------------------------------------------------------------------------------
def face_normals(vertices, faces) -> np.ndarray:
    """(F,3) float64 unit normals ``cross(v1-v0, v2-v0)/|.|`` (as wound); NaN for degenerate faces."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ln > 0, n / ln, np.nan)


def facing(view, vertices, faces) -> np.ndarray:
    """(F,) float64 facing value in world space: < 0 front-facing, > 0 back-facing, 0 edge-on.

    ``dot(n, v0 - origin)`` (perspective) or ``dot(n, forward)`` (orthographic) with
    ``n = cross(v1-v0, v2-v0)``: independent of the screen mapping's handedness."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    v0 = v[f[:, 0]]
    n = np.cross(v[f[:, 1]] - v0, v[f[:, 2]] - v0)
    if view.ortho:
        return n @ np.asarray(view.forward, float)
    return np.einsum("ij,ij->i", n, v0 - np.asarray(view.origin, float))


def cull_mask(view, vertices, faces, cull: str = "none") -> np.ndarray:
    """(F,) bool: True for the faces that ``cull`` keeps (same rule as the kernels; edge-on faces are
    dropped by "back" and "front")."""
    code = _cull_code(cull)
    if code == 0:
        return np.ones(len(faces), dtype=bool)
    f = facing(view, vertices, faces)
    return f < 0 if code == 1 else f > 0


def _cull_code(cull) -> int:
    try:
        return _CULL[cull]
    except (KeyError, TypeError):
        raise ValueError(f"cull must be one of {sorted(_CULL)}, got {cull!r}") from None


def _prepare(view, vertices, faces, cull):
    vp = np.ascontiguousarray(view.params(), dtype=np.float64)
    W, H = int(view.width), int(view.height)
    if W <= 0 or H <= 0:
        raise ValueError("view has an empty image")
    verts = np.ascontiguousarray(vertices, dtype=np.float64)
    if verts.ndim != 2 or verts.shape[1] != 3:
        verts = verts.reshape(-1, 3)
    fcs = np.ascontiguousarray(faces, dtype=np.int64)
    if fcs.ndim != 2 or fcs.shape[1] != 3:
        fcs = fcs.reshape(-1, 3)
    if fcs.size and (fcs.min() < 0 or fcs.max() >= len(verts)):
        raise ValueError("faces index out of range of vertices")
    code = _cull_code(cull)
    near = float(view.near)
    if not view.ortho:
        near = max(near, _PERSPECTIVE_MIN_NEAR)
    return vp, W, H, verts, fcs, code, near


def _front_end(vp, W, H, verts, fcs, code, near):
    """setup + binning: returns the arrays the tile kernel reads."""
    F = len(fcs)
    NC = np.empty(F, dtype=np.int32)
    CB = np.empty((2 * F, 4), dtype=np.int32)
    CE = np.empty((2 * F, 3, 6), dtype=np.float64)
    CZ = np.empty((2 * F, 2), dtype=np.float64)
    PL = np.empty((F, 12), dtype=np.float64)
    NW = np.empty((F, 3), dtype=np.float32)
    T = TILE
    ntx = (W + T - 1) // T
    nty = (H + T - 1) // T
    nthreads = numba.get_num_threads()
    nchunk = int(min(max(1, F // 1024), 4 * nthreads))
    chunk = (F + nchunk - 1) // nchunk if F else 1
    cnt = np.empty((nchunk, ntx * nty), dtype=np.int64)
    bstart = np.empty(ntx * nty + 1, dtype=np.int64)
    _setup_count(verts, fcs, vp, near, code, NC, CB, CE, CZ, PL, NW, T, ntx, chunk, cnt)
    _bin_offsets(cnt, bstart)
    bins = np.empty(int(bstart[-1]), dtype=np.int32)
    _bin_fill(NC, CB, T, ntx, chunk, cnt, bins)
    return T, ntx, nty, bstart, bins, CB, CE, CZ, PL, NW, near


_E1 = np.empty(0, dtype=np.int64)
_E1I = np.empty(0, dtype=np.int32)
_E1F = np.empty(0, dtype=np.float32)
_E2F = np.empty((0, 0), dtype=np.float32)
_E2I = np.empty((0, 0), dtype=np.int32)
_E2B = np.empty((0, 0), dtype=np.bool_)
_E3F = np.empty((0, 0, 3), dtype=np.float32)
_EFB = np.empty((0, 2), dtype=np.float32)


_EP = np.empty(0, dtype=np.float64)
_ECA = np.empty((0, 3), dtype=np.float64)
_EBS = np.empty((0, 4), dtype=np.int64)


def _run_tiles(mode, vp, fe, depth=_E2F, tri=_E2I, pos=_E3F, nrm=_E3F, bary=_E3F, mask=_E2B,
               fcount=_E1, foff=_E1, fpix=_E1, ftri=_E1I, fbary=_EFB, fdepth=_E1F,
               program=0, pparams=_EP, cattr=_ECA, img=_E2F, blend=_E2F, bstats=_EBS, split=0):
    T, ntx, nty, bstart, bins, CB, CE, CZ, PL, NW, near = fe
    nthreads = numba.config.NUMBA_NUM_THREADS
    scratch = np.empty((nthreads, T, T), dtype=np.float64)
    ntiles = ntx * nty
    old = numba.set_parallel_chunksize(max(1, ntiles // (8 * numba.get_num_threads())))
    try:
        _raster_tiles(mode, vp, near, T, ntx, nty, bstart, bins, CB, CE, CZ, PL, NW, scratch,
                      depth, tri, pos, nrm, bary, mask, fcount, foff, fpix, ftri, fbary, fdepth,
                      program, pparams, cattr, img, blend, bstats, split)
    finally:
        numba.set_parallel_chunksize(old)


def rasterize(view, vertices, faces, cull: str = "none") -> GBuffer:
    """Nearest-surface G-buffer of ``view``.

    vertices (V,3) float64 world positions, faces (F,3) int64; cull in "none" | "back" | "front"
    (facing decided in world space, see :func:`facing`). Nearest depth wins, ties go to the smaller
    triangle index. Faces with a non-finite or out-of-view vertex are handled (non-finite: skipped;
    behind the near plane: clipped); fragments beyond ``far`` are discarded.
    """
    vp, W, H, verts, fcs, code, near = _prepare(view, vertices, faces, cull)
    fe = _front_end(vp, W, H, verts, fcs, code, near)
    depth = np.empty((H, W), dtype=np.float32)
    tri = np.empty((H, W), dtype=np.int32)
    pos = np.empty((H, W, 3), dtype=np.float32)
    nrm = np.empty((H, W, 3), dtype=np.float32)
    bary = np.empty((H, W, 2), dtype=np.float32)
    mask = np.empty((H, W), dtype=np.bool_)
    _run_tiles(_M_GBUF, vp, fe, depth=depth, tri=tri, pos=pos, nrm=nrm, bary=bary, mask=mask)
    return GBuffer(position=pos, normal=nrm, depth=depth, tri_id=tri, bary=bary, mask=mask)


def rasterize_depth(view, vertices, faces, cull: str = "none") -> tuple[np.ndarray, np.ndarray]:
    """Depth-only fast path (shadow maps): (depth (H,W) float32, +inf where none; tri_id (H,W) int32,
    -1 where none). Same coverage, depth and tie rule as :func:`rasterize`."""
    vp, W, H, verts, fcs, code, near = _prepare(view, vertices, faces, cull)
    fe = _front_end(vp, W, H, verts, fcs, code, near)
    depth = np.empty((H, W), dtype=np.float32)
    tri = np.empty((H, W), dtype=np.int32)
    _run_tiles(_M_DEPTH, vp, fe, depth=depth, tri=tri)
    return depth, tri


def rasterize_fragments(view, vertices, faces, cull: str = "none") -> Fragments:
    """Every fragment (no depth test; depth > far discarded), for methods that blend.

    Order: by tile (row-major tiles of ``TILE`` px), then triangle index, then clipped piece (a
    triangle crossing the near plane may be rasterized as two pieces), then pixel (row-major).
    Deterministic regardless of the thread count. A pixel center is covered by at most one triangle of
    a watertight mesh that does not overlap itself in screen space.
    """
    vp, W, H, verts, fcs, code, near = _prepare(view, vertices, faces, cull)
    fe = _front_end(vp, W, H, verts, fcs, code, near)
    ntiles = fe[1] * fe[2]
    fcount = np.empty(ntiles, dtype=np.int64)
    _run_tiles(_M_FCOUNT, vp, fe, fcount=fcount)
    foff = np.zeros(ntiles + 1, dtype=np.int64)
    np.cumsum(fcount, out=foff[1:])
    K = int(foff[-1])
    fpix = np.empty(K, dtype=np.int64)
    ftri = np.empty(K, dtype=np.int32)
    fbary = np.empty((K, 2), dtype=np.float32)
    fdepth = np.empty(K, dtype=np.float32)
    _run_tiles(_M_FFILL, vp, fe, fcount=fcount, foff=foff, fpix=fpix, ftri=ftri, fbary=fbary,
               fdepth=fdepth)
    return Fragments(pixel=fpix, tri=ftri, bary=fbary, depth=fdepth, width=W, height=H)


def rasterize_min_blend(view, vertices, faces, program: int, corner_attr, image, params, out,
                        cull: str = "none", split: int = 0) -> dict:
    """Run a fragment program on every fragment and MIN-blend its value into ``out`` (H,W) float32
    in place: the equivalent of a GPU fragment program with MIN blending (or of writing the value
    as depth with a LESS depth test). No depth test on the geometry itself.

    program: a code from :mod:`softshadows.raster.programs`; corner_attr (F,3): an attribute per
    triangle corner, interpolated perspective-correctly; image (H,W) float32: read at each
    fragment's pixel; params: float64 uniforms. Fragments for which the program returns NaN are
    discarded. Returns counts of fragments and kept fragments for triangles with index below
    ``split`` and from ``split`` on (e.g. two kinds of primitives drawn in one call).
    """
    vp, W, H, verts, fcs, code, near = _prepare(view, vertices, faces, cull)
    if out.shape != (H, W) or out.dtype != np.float32:
        raise ValueError(f"out must be a float32 array of shape {(H, W)}")
    ca = np.ascontiguousarray(corner_attr, dtype=np.float64)
    if ca.shape != (len(faces), 3):
        raise ValueError(f"corner_attr must have shape {(len(faces), 3)}, got {ca.shape}")
    im = np.ascontiguousarray(image, dtype=np.float32)
    if im.shape != (H, W):
        raise ValueError(f"image must have shape {(H, W)}, got {im.shape}")
    fe = _front_end(vp, W, H, verts, fcs, code, near)
    bstats = np.zeros((fe[1] * fe[2], 4), dtype=np.int64)
    _run_tiles(_M_MINBLEND, vp, fe, program=int(program), pparams=np.asarray(params, dtype=np.float64),
               cattr=ca, img=im, blend=out, bstats=bstats, split=int(split))
    tot = bstats.sum(axis=0)
    return {"fragments_a": int(tot[0]), "fragments_b": int(tot[1]), "kept_a": int(tot[2]), "kept_b": int(tot[3])}
