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
3. **tiles** (parallel over ``TILE`` x ``TILE`` pixel tiles; one kernel per mode, see
   :func:`_make_tiles_kernel`): each tile is rasterized by one thread into its own region of the
   outputs (no atomics). Coverage: pixel centers ``(j+0.5, i+0.5)``, float64 edge functions evaluated
   from the edge's canonically ordered endpoints (a shared edge gives exactly opposite values for the
   two triangles, always) and a top-left fill rule: a pixel center on a shared edge or vertex belongs
   to exactly one triangle. With the 1/4096 px snap the edge functions are exact (no rounding at all)
   for every piece whose bounding box is under 16384 px, and coverage differs from the true triangle
   by at most 1/8192 px, so the exact plane depth is never extrapolated noticeably (a coarser snap,
   e.g. 1/256 px, let back faces win the depth test on some silhouette pixels). Either winding is
   rasterized.

   The coverage test is not evaluated pixel by pixel (but for pieces whose edge functions could
   overflow, ``_scan_run``): each float64 edge function is monotonic along a row (``px - ax``, the
   product and the difference round monotonically), so a row's covered columns
   are one span, whose ends are the real zero crossings of the edge functions when these are farther
   than a proven rounding margin from an integer column (``_fast_bound``, vectorized over the tile's
   rows) and are otherwise found by evaluating the exact test at the boundary columns
   (``_edge_span``): the coverage is bit for bit that of the per-pixel test. Depth, G-buffer and
   count modes then evaluate the whole tile row at once (vectorized, masked to the span); the bins list
   a tile's pieces in increasing triangle index, so the depth tie rule (equal depth: the smaller
   index wins) is "strictly nearer wins".

   Min-blend mode (``rasterize_min_blend``) runs a fragment program per fragment, branch-free over
   the whole tile row (vectorized; a kernel is compiled per program so that the program inlines),
   and can skip the pieces of a tile that cannot change the output (hierarchical culling, same
   output): those the program would discard entirely (an exact depth bound per piece and tile
   against ``programs.discard_depth``: a coarse depth test) and those whose every value is at least
   the tile's largest stored value (``programs.value_lower_bound``: a coarse test of the MIN blend).
   An optional texel mask restricts the shading to some texels: tiles without one get no pieces,
   and pieces, rows and spans without one are skipped before the vector pass.

4. **load balance**: Numba splits a ``prange`` into equal contiguous parts, one per thread,
   whatever ``set_parallel_chunksize`` says (measured: a loop with all its work in the first half
   runs on one thread), while the work of a tile pass is concentrated where the geometry is. The
   tile and setup kernels therefore run a ``prange`` over one slot per thread, and slot p takes
   tiles (chunks) p, p + n, p + 2n, ...: every thread gets a share of every busy region. No
   output depends on the thread count.

Depth is the view-space z (distance along ``forward``, world units) for both perspective and
orthographic views; the depth test runs in float64 and the outputs are float32.

Hot loops index scratch arrays with 2-D subscripts instead of taking row views: a view costs an
atomic reference-count update on the shared parent array, and with two threads these contended
updates cost more than the rasterization itself.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import prange

from .._jit import kernel
from .gbuffer import Fragments, GBuffer
from .kernels import view_coords, view_coords_to_screen
from .programs import PROGRAMS, discard_depth, run_program, value_lower_bound

TILE = 16  #: tile size in pixels (square)
SUBPIXEL = 4096.0  #: screen coordinates are snapped to 1/SUBPIXEL px before coverage
_PERSPECTIVE_MIN_NEAR = 1e-9


_CULL = {"none": 0, "back": 1, "front": 2}

#: min-blend coarse value test: the tile's largest value is recomputed (after pieces have changed
#: it) only when a piece's value bound comes within this of the stale one
_VALUE_RECOMPUTE = 0.05

# modes of the tile kernel
_M_DEPTH, _M_GBUF, _M_FCOUNT, _M_FFILL, _M_MINBLEND = 0, 1, 2, 3, 4


# ----------------------------------------------------------------------------------------------
# setup
# ----------------------------------------------------------------------------------------------
@kernel
def _snap(v):
    return math.floor(v * SUBPIXEL + 0.5) / SUBPIXEL


@kernel
def _clip_point(xi, yi, zi, xo, yo, zo, near):
    """Point of segment inside->outside on z = near. Always called with (inside, outside) in this order,
    so that the two triangles sharing an edge compute bit-identical points."""
    s = (near - zi) / (zo - zi)
    return xi + s * (xo - xi), yi + s * (yo - yi), near


# CE[slot, k, :] per edge k of a piece: the edge function's data (ax, ay, dx, dy, sg, inK: see
# _store_edge) and the data of the per-row span search (see _edge_span): 1/dy (0 if dy == 0),
# ax - 0.5, the margin M of the fast path and the kind of bound (1: the edge bounds the covered
# columns from above, -1: from below, 0: dy == 0, the edge passes or rejects whole rows).
_CE_W = 10
_U = 2.0**-53  # unit roundoff of float64
_ROBUST = 1e150  # coordinates below this never overflow the edge functions (no inf - inf = NaN)


@kernel
def _store_edge(CE, slot, k, ax, ay, bx, by, ext_x, ext_y):
    """Directed edge a->b of a positively oriented piece; inside is E >= 0 with
    E(p) = cross(b - a, p - a), evaluated from the canonically ordered endpoints.
    ext_x, ext_y: the extents of the piece's bounding box (for the span-search margin)."""
    if ax < bx or (ax == bx and ay < by):
        cax = ax
        cay = ay
        cdx = bx - ax
        cdy = by - ay
        sg = 1.0
    else:
        cax = bx
        cay = by
        cdx = ax - bx
        cdy = ay - by
        sg = -1.0
    CE[slot, k, 0] = cax
    CE[slot, k, 1] = cay
    CE[slot, k, 2] = cdx
    CE[slot, k, 3] = cdy
    CE[slot, k, 4] = sg
    ddx = bx - ax
    ddy = by - ay
    # top-left rule (y down): top edges (horizontal, going right) and left edges (going up) own
    # the pixel centers lying exactly on them. Opposite directions never both qualify.
    CE[slot, k, 5] = 1.0 if (ddy < 0.0 or (ddy == 0.0 and ddx > 0.0)) else 0.0
    # span search: e(j) = sg * (r - dy * (j + 0.5 - ax)), r = dx * (i + 0.5 - ay), crosses zero at
    # the real column j* = ax - 0.5 + r / dy, computed as x = (ax - 0.5) + r * (1/dy). With
    # K = |dx| * (ext_y + 1) / |dy|, a = |j + 0.5 - ax| <= ext_x + 1 and b = |i + 0.5 - ay| <= ext_y + 1
    # for the columns and rows searched: the rounding error of e (float64) is at most
    # 3.01u (|dx| b + |dy| a), i.e. e has the sign of the exact value wherever
    # |j - j*| > m = 3.01u (K + ext_x + 1), and |x - j*| <= 2.02u (|ax| + 0.5) + 5.03u K. So if the
    # fraction of x is farther than M >= m + |x - j*| from 0 and 1, floor(x) is the exact boundary
    # column of the float64 edge test; otherwise the kernel evaluates the test itself.
    if cdy != 0.0:
        inv = 1.0 / cdy
        K = abs(cdx) * (ext_y + 1.0) * abs(inv)
        CE[slot, k, 6] = inv
        CE[slot, k, 8] = 16.0 * _U * (K + ext_x + 1.0 + abs(cax) + 1.0) + 1e-9
        CE[slot, k, 9] = 1.0 if sg * cdy > 0.0 else -1.0
    else:
        CE[slot, k, 6] = 0.0
        CE[slot, k, 8] = 1.0
        CE[slot, k, 9] = 0.0
    CE[slot, k, 7] = cax - 0.5


@kernel
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
    if not (
        math.isfinite(sx0)
        and math.isfinite(sy0)
        and math.isfinite(sx1)
        and math.isfinite(sy1)
        and math.isfinite(sx2)
        and math.isfinite(sy2)
    ):
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
    ext_x = xmax - xmin
    ext_y = ymax - ymin
    _store_edge(CE, slot, 0, sx0, sy0, sx1, sy1, ext_x, ext_y)
    _store_edge(CE, slot, 1, sx1, sy1, sx2, sy2, ext_x, ext_y)
    _store_edge(CE, slot, 2, sx2, sy2, sx0, sy0, ext_x, ext_y)
    # robust: no edge function can overflow, so each is monotonic in the column (never NaN) and the
    # covered columns of a row are one span; otherwise the tile kernel tests pixel by pixel
    big = 0.0
    for k in range(3):
        for c in range(4):
            big = max(big, abs(CE[slot, k, c]))
    CZ[slot, 2] = 1.0 if big < _ROBUST else 0.0
    return 1


@kernel
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
@kernel(parallel=True)
def _tile_row_bits(mask, T, ntx, nty, bits, tile_any):
    """bits[tile, li]: bit k set where texel (li, k) of the tile is set in ``mask`` (H,W) uint8;
    tile_any[tile]: any of them."""
    H, W = mask.shape
    for tile in prange(ntx * nty):
        ty = tile // ntx
        tx = tile - ty * ntx
        a = 0
        for li in range(T):
            i = ty * T + li
            b = 0
            if i < H:
                for k in range(min(T, W - tx * T)):
                    b |= np.int64(mask[i, tx * T + k] != 0) << k
            bits[tile, li] = b
            a |= b
        tile_any[tile] = a != 0


@kernel
def _rect_has_bits(RN, i0, i1, j0, j1):
    """Whether rows i0..i1, columns j0..j1 of a tile (tile coordinates) hold a bit set in the row
    masks ``RN`` (see :func:`_tile_row_bits`)."""
    acc = np.int64(0)
    for li in range(i0, i1 + 1):
        acc |= RN[li]
    return ((acc >> j0) & ((np.int64(1) << (j1 - j0 + 1)) - 1)) != 0


@kernel(parallel=True)
def _setup_count(verts, faces, vp, near, cull, NC, CB, CE, CZ, PL, NW, T, ntx, chunk, cnt, nslot, tile_any, use_bits):
    """Setup of every triangle (parallel over chunks of triangles, dealt round-robin to ``nslot``
    slots: see ``_run_tiles``) and per (chunk, tile) bin counts. With ``use_bits``, only the tiles
    with ``tile_any`` set get pieces (min-blend's texel mask)."""
    nchunk = cnt.shape[0]
    ntiles = cnt.shape[1]
    F = NC.shape[0]
    for slot in prange(nslot):
        for c in range(slot, nchunk, nslot):
            for tt in range(ntiles):
                cnt[c, tt] = 0
            t1 = min(F, (c + 1) * chunk)
            for t in range(c * chunk, t1):
                _setup_one(t, verts, faces, vp, near, cull, NC, CB, CE, CZ, PL, NW)
                for k in range(NC[t]):
                    ct = 2 * t + k
                    for ty in range(CB[ct, 0] // T, CB[ct, 1] // T + 1):
                        for tx in range(CB[ct, 2] // T, CB[ct, 3] // T + 1):
                            tile = ty * ntx + tx
                            if use_bits and tile_any[tile] == 0:
                                continue
                            cnt[c, tile] += 1


@kernel
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


@kernel(parallel=True)
def _bin_fill(NC, CB, T, ntx, chunk, off, bins, nslot, tile_any, use_bits):
    nchunk = off.shape[0]
    F = NC.shape[0]
    for slot in prange(nslot):
        for c in range(slot, nchunk, nslot):
            t1 = min(F, (c + 1) * chunk)
            for t in range(c * chunk, t1):
                for k in range(NC[t]):
                    ct = 2 * t + k
                    for ty in range(CB[ct, 0] // T, CB[ct, 1] // T + 1):
                        for tx in range(CB[ct, 2] // T, CB[ct, 3] // T + 1):
                            tile = ty * ntx + tx
                            if use_bits and tile_any[tile] == 0:
                                continue
                            bins[off[c, tile]] = ct
                            off[c, tile] += 1


# ----------------------------------------------------------------------------------------------
# tiles
# ----------------------------------------------------------------------------------------------
@kernel
def _rect_edge_test(CE, ct, i0, i1, j0, j1, W, H):
    """Conservative tests of piece ``ct`` against the pixel centers of rows i0..i1 and columns
    j0..j1: (reject, full). reject: some edge function is below -thr at the rectangle's four corner
    centers, so no center of the rectangle is covered; full: every edge function is above thr there,
    so every center is. The edge functions are affine, so their extremes are at the corners; thr
    bounds their rounding error."""
    pa = i0 + 0.5
    pb = i1 + 0.5
    qa = j0 + 0.5
    qb = j1 + 0.5
    full = True
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
            return True, False
        if emin <= thr:
            full = False
    return False, full


@kernel
def _bary_c(q4, q5, q6, q7, q8, q9, q10, q11, xw, yw, z, ortho):
    """Barycentrics (b1, b2) of the original triangle t (q4..q11 = PL[t, 4:12]) at the plane point
    seen through window coordinates (xw, yw) at depth z; clamped into the triangle (guards
    snapped-edge extrapolation)."""
    if ortho:
        b1 = q4 * xw + q5 * yw + q6 * z - q7
        b2 = q8 * xw + q9 * yw + q10 * z - q11
    else:
        b1 = z * (q4 * xw + q5 * yw + q6) - q7
        b2 = z * (q8 * xw + q9 * yw + q10) - q11
    if not (b1 > 0.0):
        b1 = 0.0
    if not (b2 > 0.0):
        b2 = 0.0
    s = b1 + b2
    if s > 1.0:
        b1 /= s
        b2 /= s
    return b1, b2


@kernel
def _edge_in(r, ax, dy, sg, inc, j):
    """The coverage test of one edge at column j (r = dx * (i + 0.5 - ay) of the row): the pixel
    center is outside if e < 0, or e == 0 on an edge that does not own it (top-left rule)."""
    e = sg * (r - dy * ((j + 0.5) - ax))
    return not (e < 0.0 or (e == 0.0 and not inc))


@kernel
def _covered(j, r0, ax0, dy0, sg0, in0, r1, ax1, dy1, sg1, in1, r2, ax2, dy2, sg2, in2):
    return (
        _edge_in(r0, ax0, dy0, sg0, in0, j)
        and _edge_in(r1, ax1, dy1, sg1, in1, j)
        and _edge_in(r2, ax2, dy2, sg2, in2, j)
    )


@kernel
def _edge_span(lo, hi, j0, j1, r, ax, dy, sg, inc, inv, c0, M, kind):
    """Intersect the column span [lo, hi] of a row with the columns of [j0, j1] that pass the test of
    one edge, exactly as :func:`_edge_in` decides them (which is monotonic in j: px - ax, the product
    and the difference are rounded monotonically, so the passing columns are a prefix (kind 1) or a
    suffix (kind -1) of the row, or all or none of it (kind 0, dy == 0)). The boundary comes from
    the real crossing x; when x lies within the margin M of an integer, the test itself is evaluated
    at the boundary columns (stepping until exact)."""
    if kind == 0.0:
        if not _edge_in(r, ax, dy, sg, inc, j0):
            return j1 + 1, j1
        return lo, hi
    x = c0 + r * inv
    fx = np.floor(x)
    f = x - fx
    fast = f > M and f < 1.0 - M
    if kind > 0.0:
        # largest c in [j0 - 1, j1] such that every column of [j0, c] passes
        if not (fx >= j0 - 1.0):
            c = j0 - 1
        elif fx > j1:
            c = j1
        else:
            c = int(fx)
        if not fast:
            if c >= j0 and not _edge_in(r, ax, dy, sg, inc, c):
                c -= 1
                while c >= j0 and not _edge_in(r, ax, dy, sg, inc, c):
                    c -= 1
            else:
                while c < j1 and _edge_in(r, ax, dy, sg, inc, c + 1):
                    c += 1
        if c < hi:
            hi = c
    else:
        # smallest c in [j0, j1 + 1] such that every column of [c, j1] passes
        fx += 1.0
        if not (fx >= j0):
            c = j0
        elif fx > j1 + 1.0:
            c = j1 + 1
        else:
            c = int(fx)
        if not fast:
            if c <= j1 and not _edge_in(r, ax, dy, sg, inc, c):
                c += 1
                while c <= j1 and not _edge_in(r, ax, dy, sg, inc, c):
                    c += 1
            else:
                while c > j0 and _edge_in(r, ax, dy, sg, inc, c - 1):
                    c -= 1
        if c > lo:
            lo = c
    return lo, hi


@kernel
def _fast_bound(lo, hi, slow, py, j0, j1, ax, ay, dx, dy, sg, inc, inv, c0, M, kind):
    """One edge's bound of the covered columns [lo, hi] of the row at py by the fast path of
    :func:`_edge_span` (branch-free, so that the loop over a tile's rows vectorizes); slow is set
    where the fast path does not apply (the row must then be searched with :func:`_edge_span`)."""
    r = dx * (py - ay)
    x = c0 + r * inv
    fx = np.floor(x)
    f = x - fx
    near_int = not (f > M and f < 1.0 - M)
    cu = int(min(max(fx, j0 - 1.0), j1 + 0.0))
    cl = int(min(max(fx + 1.0, j0 + 0.0), j1 + 1.0))
    e = sg * (r - dy * ((j0 + 0.5) - ax))  # kind 0 (dy == 0): the same test for every column
    rej = e < 0.0 or (e == 0.0 and not inc)
    if kind > 0.0:
        hi = min(hi, cu)
        slow = slow | near_int
    elif kind < 0.0:
        lo = max(lo, cl)
        slow = slow | near_int
    elif rej:
        lo = j1 + 1
    return lo, hi, slow


@kernel
def _scan_run(js, j1, r0, ax0, dy0, sg0, in0, r1, ax1, dy1, sg1, in1, r2, ax2, dy2, sg2, in2):
    """Next run [lo, hi] of covered columns at or after js, testing pixel by pixel (lo > hi: none);
    for the pieces whose edge functions might overflow."""
    j = js
    while j <= j1 and not _covered(j, r0, ax0, dy0, sg0, in0, r1, ax1, dy1, sg1, in1, r2, ax2, dy2, sg2, in2):
        j += 1
    lo = j
    while j <= j1 and _covered(j, r0, ax0, dy0, sg0, in0, r1, ax1, dy1, sg1, in1, r2, ax2, dy2, sg2, in2):
        j += 1
    return lo, j - 1


@kernel
def _plane_depth(ortho, pnx, pny, pnz, pd, xw, yw):
    """The view depth of a triangle's plane seen through window point (xw, yw), written exactly as
    the tile kernel's per-fragment depth (same operations in the same order, so the same rounding);
    NaN where the view ray is parallel to the plane."""
    if ortho:
        zrow = pd - pny * yw
        return (zrow - pnx * xw) / pnz
    zrow = pny * yw + pnz
    return pd / (pnx * xw + zrow)


@kernel
def _rect_min_depth(ortho, pnx, pny, pnz, pd, wl, wt, wsx, wsy, i0, i1, j0, j1):
    """A lower bound of the plane depth (as :func:`_plane_depth`) over the pixel centers of rows
    i0..i1 and columns j0..j1, or -inf where there is none (the denominator may vanish). The
    denominator is an affine function of (xw, yw) whose floating-point evaluation is monotonic in
    each, so its extremes are at the four corner pixel centers; where it keeps one sign there the
    depth is monotonic too and the minimum of the four corner depths is exact."""
    xa = wl + (j0 + 0.5) * wsx
    xb = wl + (j1 + 0.5) * wsx
    ya = wt - (i0 + 0.5) * wsy
    yb = wt - (i1 + 0.5) * wsy
    if ortho:
        if pnz == 0.0:
            return -np.inf
    else:
        da = pny * ya + pnz
        db = pny * yb + pnz
        d00 = pnx * xa + da
        d01 = pnx * xb + da
        d10 = pnx * xa + db
        d11 = pnx * xb + db
        pos = (d00 > 0.0) & (d01 > 0.0) & (d10 > 0.0) & (d11 > 0.0)
        neg = (d00 < 0.0) & (d01 < 0.0) & (d10 < 0.0) & (d11 < 0.0)
        if not (pos or neg):
            return -np.inf
    z = min(
        min(_plane_depth(ortho, pnx, pny, pnz, pd, xa, ya), _plane_depth(ortho, pnx, pny, pnz, pd, xb, ya)),
        min(_plane_depth(ortho, pnx, pny, pnz, pd, xa, yb), _plane_depth(ortho, pnx, pny, pnz, pd, xb, yb)),
    )
    return z if z == z else -np.inf


def _make_tiles_kernel(mode, prog=0):
    """The tile kernel for one mode and, for mode 4, one fragment program (constants of the closure:
    each kernel compiles only its own mode's and program's code, which keeps the hot loops free of
    branches, so that they vectorize, and their register allocation clean)."""

    @kernel(parallel=True)
    def tiles(
        vp,
        near,
        T,
        ntx,
        nty,
        bstart,
        bins,
        CB,
        CE,
        CZ,
        PL,
        NW,
        scratch,
        tscratch,
        iscratch,
        fscratch,
        xscratch,
        depth_out,
        tri_out,
        pos_out,
        nrm_out,
        bary_out,
        mask_out,
        fcount,
        foff,
        fpix,
        ftri,
        fbary,
        fdepth,
        program,
        pparams,
        cattr,
        img,
        blend,
        bstats,
        split,
        cull_discarded,
        rowbits,
        use_mask,
        nslot,
    ):
        """mode 0: depth + tri; 1: full G-buffer; 2: count fragments per tile; 3: write fragments;
        4: run a fragment program per fragment and MIN-blend its value into ``blend`` (bstats[tile] =
        fragments and kept fragments for triangles below / from ``split``, pieces culled by depth,
        by value). With ``cull_discarded`` (mode 4), the pieces of a tile whose every fragment lies
        at or beyond the depth where the program discards (``discard_depth``, max over the tile) are
        skipped, and so are the pieces with a constant attribute whose value bound
        (``value_lower_bound``) is at least the tile's largest value; the result is the same. With
        ``use_mask`` (mode 4), only the texels set in ``rowbits`` (bit k of ``rowbits[tile, row]``:
        column k) are shaded, the others keep their value.

        Per piece and row, the covered columns are one span [lo, hi], found exactly from the three edge
        functions (:func:`_edge_span`); depth/G-buffer modes then run the depth of the whole tile row
        (vectorized) and keep the span's columns that pass the depth test. Bins list a tile's pieces in
        increasing triangle index, so the tie rule (equal depth: smaller index wins) is "strictly less
        wins"."""
        W = int(vp[18])
        H = int(vp[19])
        ortho = vp[20] != 0.0
        far = vp[17]
        wl = vp[12]
        wt = vp[15]
        wsx = (vp[13] - vp[12]) / vp[18]  # window units per pixel
        wsy = (vp[15] - vp[14]) / vp[19]
        ntiles = ntx * nty
        for slot in prange(nslot):
            # min-blend: tiles slot, slot + n, ... (its work sits in few tiles); dense modes: tile rows
            # slot, slot + n, ... (contiguous rows of output keep the memory traffic local)
            if mode == 4:
                nk = (ntiles - slot + nslot - 1) // nslot
            else:
                nk = (nty - slot + nslot - 1) // nslot * ntx
            for kt in range(nk):
                if mode == 4:
                    tile = slot + kt * nslot
                else:
                    tile = (slot + (kt // ntx) * nslot) * ntx + kt % ntx
                if mode >= 2 and bstart[tile] == bstart[tile + 1]:
                    continue  # nothing binned here: no fragments, ``blend`` unchanged (modes 2-4)
                ty = tile // ntx
                tx = tile - ty * ntx
                y0 = ty * T
                x0 = tx * T
                y1 = min(y0 + T, H) - 1
                x1 = min(x0 + T, W) - 1
                tid = numba.get_thread_id()
                zb = scratch[tid]
                tb = tscratch[tid]
                LO = iscratch[tid, 0]
                HI = iscratch[tid, 1]
                EX = iscratch[tid, 2]
                RW = iscratch[tid, 3]
                RN = iscratch[tid, 4]  # min-blend: texels to shade per row of the tile
                CM = xscratch[tid]
                ib = fscratch[tid]
                if mode <= 1:
                    for li in range(T):
                        zr = zb[li]
                        tr = tb[li]
                        for k in range(zr.shape[0]):
                            zr[k] = np.inf
                            tr[k] = -1
                nfrag = 0
                nculled = 0
                nvculled = 0
                w = 0
                na = 0
                nb = 0
                ka = 0
                kb = 0
                if mode == 3:
                    w = foff[tile]
                elif mode == 4:
                    # the tile's texels: current values, input image, texel mask (``mask``: only these
                    # texels are shaded) and, over the texels shaded, the bounds of the coarse tests
                    tthr = -np.inf
                    smax = -np.inf  # the largest finite input-image value
                    cmax = -np.inf  # the largest current value (an upper bound once ``dirty``)
                    # RN[li]: bit k set where texel (li, k) of the tile is to be shaded
                    if use_mask:
                        anyb = 0
                        for li in range(T):
                            RN[li] = rowbits[tile, li]
                            anyb |= RN[li]
                        if anyb == 0:
                            continue  # no texel to shade: ``blend`` unchanged
                    else:
                        for li in range(T):
                            RN[li] = ((np.int64(1) << (x1 - x0 + 1)) - 1) if li <= y1 - y0 else 0
                    for i in range(y0, y1 + 1):
                        li = i - y0
                        rb = RN[li]
                        for k in range(x1 - x0 + 1):
                            bv = np.float64(blend[i, x0 + k])
                            sv = img[i, x0 + k]
                            need = ((rb >> k) & 1) != 0
                            zb[li, k] = bv
                            ib[li, k] = sv
                            d = discard_depth(prog, pparams, sv)
                            # NaN: the program discards there whatever the depth
                            tthr = d if (need and d > tthr) else tthr
                            smax = sv if (need and sv > smax and sv < np.inf) else smax
                            cmax = bv if (need and bv > cmax) else cmax
                    dirty = False
                for bi in range(bstart[tile], bstart[tile + 1]):
                    ct = bins[bi]
                    t = ct >> 1
                    i0 = max(CB[ct, 0], y0)
                    i1 = min(CB[ct, 1], y1)
                    j0 = max(CB[ct, 2], x0)
                    j1 = min(CB[ct, 3], x1)
                    if i0 > i1 or j0 > j1:
                        continue
                    if mode == 4 and use_mask and not _rect_has_bits(RN, i0 - y0, i1 - y0, j0 - x0, j1 - x0):
                        continue  # no texel to shade in the piece's rectangle of the tile
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
                    q4 = PL[t, 4]
                    q5 = PL[t, 5]
                    q6 = PL[t, 6]
                    q7 = PL[t, 7]
                    q8 = PL[t, 8]
                    q9 = PL[t, 9]
                    q10 = PL[t, 10]
                    q11 = PL[t, 11]
                    if mode == 4 and cull_discarded:
                        # hierarchical culling (the equivalent of a GPU's coarse depth test): the nearest
                        # fragment of the piece in this tile; if the program discards at that depth on
                        # every pixel of the tile, skip the piece. The depth is evaluated exactly as per
                        # fragment; its rounding is monotonic in x and in y, so the minimum over the
                        # pixel centers is at a corner of the rectangle: exact, no margin needed.
                        zc_min = _rect_min_depth(ortho, pnx, pny, pnz, pd, wl, wt, wsx, wsy, i0, i1, j0, j1)
                        zc_min = min(max(zc_min, zlo), zhi)
                        if zc_min >= tthr:
                            nculled += 1
                            continue
                        # the coarse value test (MIN blending): if no fragment of the piece can go
                        # below the tile's largest current value, it can change no texel. Values
                        # only decrease, so cmax is recomputed only after a piece has run.
                        if cattr[t, 0] == cattr[t, 1] and cattr[t, 0] == cattr[t, 2]:
                            vb = value_lower_bound(prog, pparams, cattr[t, 0], zc_min, smax)
                            if dirty and vb >= cmax - _VALUE_RECOMPUTE:  # recompute only where it may pay
                                rb = RN[0]
                                for k in range(T):  # lane-wise maxima first (vectorizes), then across lanes
                                    CM[k] = zb[0, k] if ((rb >> k) & 1) != 0 else -np.inf
                                for li in range(1, y1 - y0 + 1):
                                    rb = RN[li]
                                    for k in range(T):
                                        c = zb[li, k] if ((rb >> k) & 1) != 0 else -np.inf
                                        CM[k] = c if c > CM[k] else CM[k]
                                cmax = CM[0]
                                for k in range(1, T):
                                    cmax = CM[k] if CM[k] > cmax else cmax
                                dirty = False
                            if vb >= cmax:
                                nvculled += 1
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
                        reject, full = _rect_edge_test(CE, ct, i0, i1, j0, j1, W + 0.0, H + 0.0)
                        if reject:
                            continue
                    robust = CZ[ct, 2] != 0.0
                    iv0 = CE[ct, 0, 6]
                    c00 = CE[ct, 0, 7]
                    M0 = CE[ct, 0, 8]
                    k0 = CE[ct, 0, 9]
                    iv1 = CE[ct, 1, 6]
                    c01 = CE[ct, 1, 7]
                    M1 = CE[ct, 1, 8]
                    k1 = CE[ct, 1, 9]
                    iv2 = CE[ct, 2, 6]
                    c02 = CE[ct, 2, 7]
                    M2 = CE[ct, 2, 8]
                    k2 = CE[ct, 2, 9]
                    if robust and not full:
                        # the spans of all the tile's rows at once (vectorizes)
                        for k in range(LO.shape[0]):
                            py = (y0 + k) + 0.5
                            lo, hi, slow = _fast_bound(
                                j0, j1, False, py, j0, j1, ax0, ay0, dx0, dy0, sg0, in0, iv0, c00, M0, k0
                            )
                            lo, hi, slow = _fast_bound(
                                lo, hi, slow, py, j0, j1, ax1, ay1, dx1, dy1, sg1, in1, iv1, c01, M1, k1
                            )
                            lo, hi, slow = _fast_bound(
                                lo, hi, slow, py, j0, j1, ax2, ay2, dx2, dy2, sg2, in2, iv2, c02, M2, k2
                            )
                            LO[k] = lo
                            HI[k] = hi
                            EX[k] = slow
                        # the rows left to visit: those with a span (min-blend: one holding a texel to
                        # shade) or a slow search (branch-free compaction; a thin piece's box has many
                        # empty rows, whose skipping branch the CPU cannot predict)
                        nrows = 0
                        for k in range(i0 - y0, i1 - y0 + 1):
                            RW[nrows] = k
                            if mode == 4:
                                width = max(HI[k] - LO[k] + 1, 0)
                                hit = ((RN[k] >> (LO[k] - x0)) & ((np.int64(1) << width) - 1)) != 0
                                nrows += hit | (EX[k] != 0)
                            else:
                                nrows += (LO[k] <= HI[k]) | (EX[k] != 0)
                        if nrows == 0:
                            continue
                    else:
                        nrows = i1 - i0 + 1
                    r0 = 0.0
                    r1 = 0.0
                    r2 = 0.0
                    ca0 = 0.0
                    ca1 = 0.0
                    ca2 = 0.0
                    side_a = t < split
                    cconst = False
                    if mode == 4:
                        dirty = True  # this piece will lower texels: the tile's largest value may fall
                        ca0 = cattr[t, 0]
                        ca1 = cattr[t, 1]
                        ca2 = cattr[t, 2]
                        cconst = (ca0 == ca1) & (ca0 == ca2)
                    for rr in range(nrows):
                        if robust and not full:
                            li = RW[rr]
                            i = li + y0
                        else:
                            i = i0 + rr
                            li = i - y0
                        if mode == 4 and use_mask and RN[li] == 0:
                            continue  # no texel of this row is shaded
                        py = i + 0.5
                        yw = wt - py * wsy
                        if ortho:
                            zrow = pd - pny * yw
                        else:
                            zrow = pny * yw + pnz
                        if full:
                            lo = j0
                            hi = j1
                        elif robust:
                            lo = LO[li]
                            hi = HI[li]
                            if EX[li] != 0:
                                r0 = dx0 * (py - ay0)
                                r1 = dx1 * (py - ay1)
                                r2 = dx2 * (py - ay2)
                                lo, hi = _edge_span(j0, j1, j0, j1, r0, ax0, dy0, sg0, in0, iv0, c00, M0, k0)
                                lo, hi = _edge_span(lo, hi, j0, j1, r1, ax1, dy1, sg1, in1, iv1, c01, M1, k1)
                                lo, hi = _edge_span(lo, hi, j0, j1, r2, ax2, dy2, sg2, in2, iv2, c02, M2, k2)
                            if lo > hi:
                                continue
                        else:
                            r0 = dx0 * (py - ay0)
                            r1 = dx1 * (py - ay1)
                            r2 = dx2 * (py - ay2)
                            lo, hi = _scan_run(
                                j0, j1, r0, ax0, dy0, sg0, in0, r1, ax1, dy1, sg1, in1, r2, ax2, dy2, sg2, in2
                            )
                        while lo <= hi:
                            if mode <= 2:
                                # the whole tile row at once (vectorizes), masked to the span
                                klo = lo - x0
                                khi = hi - x0
                                if mode == 2:
                                    cnt = 0
                                    if ortho:
                                        for k in range(T):
                                            xw = wl + ((x0 + k) + 0.5) * wsx
                                            z = (zrow - pnx * xw) / pnz
                                            if not (z >= zlo):
                                                z = zlo
                                            elif z > zhi:
                                                z = zhi
                                            cnt += (k >= klo) & (k <= khi) & (not (z > far))
                                    else:
                                        for k in range(T):
                                            xw = wl + ((x0 + k) + 0.5) * wsx
                                            z = pd / (pnx * xw + zrow)
                                            if not (z >= zlo):
                                                z = zlo
                                            elif z > zhi:
                                                z = zhi
                                            cnt += (k >= klo) & (k <= khi) & (not (z > far))
                                    nfrag += cnt
                                elif ortho:
                                    for k in range(T):
                                        xw = wl + ((x0 + k) + 0.5) * wsx
                                        z = (zrow - pnx * xw) / pnz
                                        if not (z >= zlo):
                                            z = zlo
                                        elif z > zhi:
                                            z = zhi
                                        zc = zb[li, k]
                                        take = (k >= klo) & (k <= khi) & (not (z > far)) & (z < zc)
                                        zb[li, k] = z if take else zc
                                        tb[li, k] = t if take else tb[li, k]
                                else:
                                    for k in range(T):
                                        xw = wl + ((x0 + k) + 0.5) * wsx
                                        z = pd / (pnx * xw + zrow)
                                        if not (z >= zlo):
                                            z = zlo
                                        elif z > zhi:
                                            z = zhi
                                        zc = zb[li, k]
                                        take = (k >= klo) & (k <= khi) & (not (z > far)) & (z < zc)
                                        zb[li, k] = z if take else zc
                                        tb[li, k] = t if take else tb[li, k]
                            elif mode == 4:
                                # the whole tile row at once, masked to the span (a branch-free loop of T
                                # columns: it vectorizes; cheaper than pixel by pixel even for short spans)
                                klo = lo - x0
                                khi = hi - x0
                                rn = RN[li]
                                if use_mask and ((rn >> klo) & ((np.int64(1) << (khi - klo + 1)) - 1)) == 0:
                                    if full or robust:
                                        break
                                    lo, hi = _scan_run(
                                        hi + 1,
                                        j1,
                                        r0,
                                        ax0,
                                        dy0,
                                        sg0,
                                        in0,
                                        r1,
                                        ax1,
                                        dy1,
                                        sg1,
                                        in1,
                                        r2,
                                        ax2,
                                        dy2,
                                        sg2,
                                        in2,
                                    )
                                    continue  # no texel of the span to shade
                                cin = 0  # fragments and kept fragments of the row (reductions in the vector loop)
                                ckp = 0
                                if ortho:
                                    for k in range(T):
                                        xw = wl + ((x0 + k) + 0.5) * wsx
                                        z = (zrow - pnx * xw) / pnz
                                        z = z if z >= zlo else zlo
                                        z = zhi if z > zhi else z
                                        b1, b2 = _bary_c(q4, q5, q6, q7, q8, q9, q10, q11, xw, yw, z, True)
                                        a = (1.0 - b1 - b2) * ca0 + b1 * ca1 + b2 * ca2
                                        val = run_program(prog, pparams, a, ib[li, k], z)
                                        inside = (k >= klo) & (k <= khi) & (not (z > far)) & (((rn >> k) & 1) != 0)
                                        kept = inside & (val == val)
                                        cin += inside
                                        ckp += kept
                                        zc = zb[li, k]
                                        zb[li, k] = val if (kept & (val < zc)) else zc
                                elif cconst:
                                    # the same attribute at the three corners (e.g. a cone's Z_v): no
                                    # barycentrics needed
                                    for k in range(T):
                                        xw = wl + ((x0 + k) + 0.5) * wsx
                                        z = pd / (pnx * xw + zrow)
                                        z = z if z >= zlo else zlo
                                        z = zhi if z > zhi else z
                                        val = run_program(prog, pparams, ca0, ib[li, k], z)
                                        inside = (k >= klo) & (k <= khi) & (not (z > far)) & (((rn >> k) & 1) != 0)
                                        kept = inside & (val == val)
                                        cin += inside
                                        ckp += kept
                                        zc = zb[li, k]
                                        zb[li, k] = val if (kept & (val < zc)) else zc
                                else:
                                    for k in range(T):
                                        xw = wl + ((x0 + k) + 0.5) * wsx
                                        z = pd / (pnx * xw + zrow)
                                        z = z if z >= zlo else zlo
                                        z = zhi if z > zhi else z
                                        b1, b2 = _bary_c(q4, q5, q6, q7, q8, q9, q10, q11, xw, yw, z, False)
                                        a = (1.0 - b1 - b2) * ca0 + b1 * ca1 + b2 * ca2
                                        val = run_program(prog, pparams, a, ib[li, k], z)
                                        inside = (k >= klo) & (k <= khi) & (not (z > far)) & (((rn >> k) & 1) != 0)
                                        kept = inside & (val == val)
                                        cin += inside
                                        ckp += kept
                                        zc = zb[li, k]
                                        zb[li, k] = val if (kept & (val < zc)) else zc
                                if side_a:
                                    na += cin
                                    ka += ckp
                                else:
                                    nb += cin
                                    kb += ckp
                            else:
                                for j in range(lo, hi + 1):
                                    xw = wl + (j + 0.5) * wsx
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
                                    # mode 3: write the fragment
                                    b1, b2 = _bary_c(q4, q5, q6, q7, q8, q9, q10, q11, xw, yw, z, ortho)
                                    fpix[w] = i * W + j
                                    ftri[w] = t
                                    fbary[w, 0] = b1
                                    fbary[w, 1] = b2
                                    fdepth[w] = z
                                    w += 1
                            if full or robust:
                                break
                            lo, hi = _scan_run(
                                hi + 1, j1, r0, ax0, dy0, sg0, in0, r1, ax1, dy1, sg1, in1, r2, ax2, dy2, sg2, in2
                            )
                if mode == 0:
                    for i in range(y0, y1 + 1):
                        zr = zb[i - y0]
                        tr = tb[i - y0]
                        drow = depth_out[i, x0 : x1 + 1]
                        trow = tri_out[i, x0 : x1 + 1]
                        for k in range(drow.shape[0]):
                            drow[k] = zr[k]
                            trow[k] = tr[k]
                elif mode == 1:
                    # G-buffer of the tile from the winners (branch-free per pixel, so that it vectorizes)
                    o0 = vp[0]
                    o1 = vp[1]
                    o2 = vp[2]
                    rx = vp[3]
                    ry = vp[4]
                    rz = vp[5]
                    ux = vp[6]
                    uy = vp[7]
                    uz = vp[8]
                    fx = vp[9]
                    fy = vp[10]
                    fz = vp[11]
                    for i in range(y0, y1 + 1):
                        yw = wt - (i + 0.5) * wsy
                        zr = zb[i - y0]
                        tr = tb[i - y0]
                        trow = tri_out[i, x0 : x1 + 1]
                        drow = depth_out[i, x0 : x1 + 1]
                        mrow = mask_out[i, x0 : x1 + 1]
                        prow = pos_out[i, x0 : x1 + 1]
                        nrow = nrm_out[i, x0 : x1 + 1]
                        brow = bary_out[i, x0 : x1 + 1]
                        if ortho:
                            for k in range(drow.shape[0]):
                                t = tr[k]
                                hit = t >= 0
                                tt = max(t, 0)  # PL, NW have a row 0 (read, then discarded, where no hit)
                                z = zr[k]  # +inf where no hit
                                xw = wl + ((x0 + k) + 0.5) * wsx
                                b1, b2 = _bary_c(
                                    PL[tt, 4],
                                    PL[tt, 5],
                                    PL[tt, 6],
                                    PL[tt, 7],
                                    PL[tt, 8],
                                    PL[tt, 9],
                                    PL[tt, 10],
                                    PL[tt, 11],
                                    xw,
                                    yw,
                                    z,
                                    True,
                                )
                                vx = xw
                                vy = yw
                                trow[k] = t
                                drow[k] = z
                                mrow[k] = hit
                                prow[k, 0] = (o0 + vx * rx + vy * ux + z * fx) if hit else np.nan
                                prow[k, 1] = (o1 + vx * ry + vy * uy + z * fy) if hit else np.nan
                                prow[k, 2] = (o2 + vx * rz + vy * uz + z * fz) if hit else np.nan
                                nrow[k, 0] = NW[tt, 0] if hit else np.nan
                                nrow[k, 1] = NW[tt, 1] if hit else np.nan
                                nrow[k, 2] = NW[tt, 2] if hit else np.nan
                                brow[k, 0] = b1 if hit else np.nan
                                brow[k, 1] = b2 if hit else np.nan
                        else:
                            for k in range(drow.shape[0]):
                                t = tr[k]
                                hit = t >= 0
                                tt = max(t, 0)  # PL, NW have a row 0 (read, then discarded, where no hit)
                                z = zr[k]  # +inf where no hit
                                xw = wl + ((x0 + k) + 0.5) * wsx
                                b1, b2 = _bary_c(
                                    PL[tt, 4],
                                    PL[tt, 5],
                                    PL[tt, 6],
                                    PL[tt, 7],
                                    PL[tt, 8],
                                    PL[tt, 9],
                                    PL[tt, 10],
                                    PL[tt, 11],
                                    xw,
                                    yw,
                                    z,
                                    False,
                                )
                                vx = xw * z
                                vy = yw * z
                                trow[k] = t
                                drow[k] = z
                                mrow[k] = hit
                                prow[k, 0] = (o0 + vx * rx + vy * ux + z * fx) if hit else np.nan
                                prow[k, 1] = (o1 + vx * ry + vy * uy + z * fy) if hit else np.nan
                                prow[k, 2] = (o2 + vx * rz + vy * uz + z * fz) if hit else np.nan
                                nrow[k, 0] = NW[tt, 0] if hit else np.nan
                                nrow[k, 1] = NW[tt, 1] if hit else np.nan
                                nrow[k, 2] = NW[tt, 2] if hit else np.nan
                                brow[k, 0] = b1 if hit else np.nan
                                brow[k, 1] = b2 if hit else np.nan
                elif mode == 2:
                    fcount[tile] = nfrag
                elif mode == 4:
                    bstats[tile, 0] += na
                    bstats[tile, 1] += nb
                    bstats[tile, 2] += ka
                    bstats[tile, 3] += kb
                    bstats[tile, 4] += nculled
                    bstats[tile, 5] += nvculled
                    for i in range(y0, y1 + 1):
                        zr = zb[i - y0]
                        brow = blend[i, x0 : x1 + 1]
                        for k in range(brow.shape[0]):
                            brow[k] = zr[k]

    return tiles


_KERNELS = {(m, 0): _make_tiles_kernel(m) for m in range(4)}  # indexed by (mode, program)
_KERNELS.update({(_M_MINBLEND, p): _make_tiles_kernel(_M_MINBLEND, p) for p in PROGRAMS})


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


def _front_end(vp, W, H, verts, fcs, code, near, mask=None):
    """setup + binning: returns the arrays the tile kernel reads. ``mask`` (H,W) uint8: bin a piece
    only to the tiles where its bounding box holds a set texel (min-blend's texel mask)."""
    F = len(fcs)
    NC = np.empty(F, dtype=np.int32)
    CB = np.empty((2 * F, 4), dtype=np.int32)
    CE = np.empty((2 * F, 3, _CE_W), dtype=np.float64)
    CZ = np.empty((2 * F, 3), dtype=np.float64)
    PL = np.zeros((max(F, 1), 12), dtype=np.float64)  # row 0 exists (the G-buffer pass reads it)
    NW = np.zeros((max(F, 1), 3), dtype=np.float32)
    T = TILE
    ntx = (W + T - 1) // T
    nty = (H + T - 1) // T
    nthreads = numba.get_num_threads()
    nchunk = int(min(max(1, F // 1024), 4 * nthreads))
    chunk = (F + nchunk - 1) // nchunk if F else 1
    cnt = np.empty((nchunk, ntx * nty), dtype=np.int64)
    bstart = np.empty(ntx * nty + 1, dtype=np.int64)
    if mask is not None:
        rowbits = np.empty((ntx * nty, T), dtype=np.int64)
        tile_any = np.empty(ntx * nty, dtype=np.uint8)
        _tile_row_bits(mask, T, ntx, nty, rowbits, tile_any)
    else:
        rowbits = _E2I64
        tile_any = _E1U
    use = mask is not None
    _setup_count(verts, fcs, vp, near, code, NC, CB, CE, CZ, PL, NW, T, ntx, chunk, cnt, nthreads, tile_any, use)
    _bin_offsets(cnt, bstart)
    bins = np.empty(int(bstart[-1]), dtype=np.int32)
    _bin_fill(NC, CB, T, ntx, chunk, cnt, bins, nthreads, tile_any, use)
    return T, ntx, nty, bstart, bins, CB, CE, CZ, PL, NW, near, rowbits


_E1 = np.empty(0, dtype=np.int64)
_E1I = np.empty(0, dtype=np.int32)
_E1F = np.empty(0, dtype=np.float32)
_E2F = np.empty((0, 0), dtype=np.float32)
_E2I = np.empty((0, 0), dtype=np.int32)
_E2B = np.empty((0, 0), dtype=np.bool_)
_E2I64 = np.empty((0, 0), dtype=np.int64)
_E1U = np.empty(0, dtype=np.uint8)
_E3F = np.empty((0, 0, 3), dtype=np.float32)
_EFB = np.empty((0, 2), dtype=np.float32)


_EP = np.empty(0, dtype=np.float64)
_ECA = np.empty((0, 3), dtype=np.float64)
_EBS = np.empty((0, 5), dtype=np.int64)


def _run_tiles(
    mode,
    vp,
    fe,
    depth=_E2F,
    tri=_E2I,
    pos=_E3F,
    nrm=_E3F,
    bary=_E3F,
    mask=_E2B,
    fcount=_E1,
    foff=_E1,
    fpix=_E1,
    ftri=_E1I,
    fbary=_EFB,
    fdepth=_E1F,
    program=0,
    pparams=_EP,
    cattr=_ECA,
    img=_E2F,
    blend=_E2F,
    bstats=_EBS,
    split=0,
    cull_discarded=False,
):
    T, ntx, nty, bstart, bins, CB, CE, CZ, PL, NW, near, rowbits = fe
    nthreads = numba.config.NUMBA_NUM_THREADS
    scratch = np.empty((nthreads, T, T), dtype=np.float64)
    tscratch = np.empty((nthreads, T, T), dtype=np.int32)
    iscratch = np.empty((nthreads, 5, T), dtype=np.int64)
    fscratch = np.zeros((nthreads, T, T), dtype=np.float32)
    xscratch = np.zeros((nthreads, T), dtype=np.float64)
    # load balance: Numba splits a prange into equal contiguous parts, one per thread, whatever the
    # chunk size, while the work of a tile kernel is concentrated where the geometry is. So the
    # prange runs over one slot per thread and slot p takes every n-th tile (min-blend) or tile row
    # (dense modes) from p on: every thread gets a share of every busy region.
    nslot = numba.get_num_threads()
    _KERNELS[(mode, program if mode == _M_MINBLEND else 0)](
        vp,
        near,
        T,
        ntx,
        nty,
        bstart,
        bins,
        CB,
        CE,
        CZ,
        PL,
        NW,
        scratch,
        tscratch,
        iscratch,
        fscratch,
        xscratch,
        depth,
        tri,
        pos,
        nrm,
        bary,
        mask,
        fcount,
        foff,
        fpix,
        ftri,
        fbary,
        fdepth,
        program,
        pparams,
        cattr,
        img,
        blend,
        bstats,
        split,
        bool(cull_discarded),
        rowbits,
        rowbits.size > 0,
        int(nslot),
    )


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
    fcount = np.zeros(ntiles, dtype=np.int64)  # tiles with no bins are skipped
    _run_tiles(_M_FCOUNT, vp, fe, fcount=fcount)
    foff = np.zeros(ntiles + 1, dtype=np.int64)
    np.cumsum(fcount, out=foff[1:])
    K = int(foff[-1])
    fpix = np.empty(K, dtype=np.int64)
    ftri = np.empty(K, dtype=np.int32)
    fbary = np.empty((K, 2), dtype=np.float32)
    fdepth = np.empty(K, dtype=np.float32)
    _run_tiles(_M_FFILL, vp, fe, fcount=fcount, foff=foff, fpix=fpix, ftri=ftri, fbary=fbary, fdepth=fdepth)
    return Fragments(pixel=fpix, tri=ftri, bary=fbary, depth=fdepth, width=W, height=H)


def rasterize_min_blend(
    view,
    vertices,
    faces,
    program: int,
    corner_attr,
    image,
    params,
    out,
    cull: str = "none",
    split: int = 0,
    cull_discarded: bool = False,
    mask=None,
) -> dict:
    """Run a fragment program on every fragment and MIN-blend its value into ``out`` (H,W) float32
    in place: the equivalent of a GPU fragment program with MIN blending (or of writing the value
    as depth with a LESS depth test). No depth test on the geometry itself.

    program: a code from :mod:`softshadows.raster.programs`; corner_attr (F,3): an attribute per
    triangle corner, interpolated perspective-correctly; image (H,W) float32: read at each
    fragment's pixel; params: float64 uniforms. Fragments for which the program returns NaN are
    discarded. Returns counts of fragments and kept fragments for triangles with index below
    ``split`` and from ``split`` on (e.g. two kinds of primitives drawn in one call).

    ``cull_discarded``: hierarchical culling, the equivalent of a GPU's coarse (per-tile) depth
    test. A piece of a triangle in one tile is skipped when its nearest fragment there lies at or
    beyond the depth from which the program discards on every pixel of the tile
    (``programs.discard_depth``; an exact bound, so the output is identical); ``culled_pieces``
    counts the skipped (piece, tile) pairs. A piece whose attribute is the same at its three corners
    is also skipped when no fragment can go below the tile's largest stored value
    (``programs.value_lower_bound``; MIN blending: it could change no texel; the output is
    identical); ``value_culled_pieces`` counts those. Skipped fragments are not counted in
    ``fragments_*`` / ``kept_*``.

    ``mask`` (H,W) bool or uint8: shade only the texels set (the others keep their value in
    ``out``; their fragments are neither run nor counted). The output at the texels set is
    identical to that of an unmasked pass.
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
    mk = None
    if mask is not None:
        mk = (
            np.ascontiguousarray(mask).view(np.uint8)
            if np.asarray(mask).dtype == np.bool_
            else np.ascontiguousarray(mask, dtype=np.uint8)
        )
        if mk.shape != (H, W):
            raise ValueError(f"mask must have shape {(H, W)}, got {mk.shape}")
    fe = _front_end(vp, W, H, verts, fcs, code, near, mk)
    bstats = np.zeros((fe[1] * fe[2], 6), dtype=np.int64)
    _run_tiles(
        _M_MINBLEND,
        vp,
        fe,
        program=int(program),
        pparams=np.asarray(params, dtype=np.float64),
        cattr=ca,
        img=im,
        blend=out,
        bstats=bstats,
        split=int(split),
        cull_discarded=cull_discarded,
    )
    tot = bstats.sum(axis=0)
    return {
        "fragments_a": int(tot[0]),
        "fragments_b": int(tot[1]),
        "kept_a": int(tot[2]),
        "kept_b": int(tot[3]),
        "culled_pieces": int(tot[4]),
        "value_culled_pieces": int(tot[5]),
    }
