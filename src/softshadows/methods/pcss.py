"""``pcss``: percentage-closer soft shadows (R. Fernando, SIGGRAPH 2005 sketch), the baseline engines ship.

One shadow map from the light's center (shared with ``hard``: ``shadowmap.py``), then per eye
point the paper's three steps: :func:`blocker_search` (average depth of the blockers in a region
sized by the light and the receiver depth; no blocker: V = 1), :func:`penumbra_estimation`
(parallel planes: ``w = (z_r - z_b) * w_light / z_b``) and :func:`filtering` (PCF with that kernel
size); the search region and kernel take the light's shape (rectangle or disk).

Steps, parameters, deviations from the sketch and known limits: ``docs/methods/pcss.md``.
"""

from __future__ import annotations

from typing import ClassVar

import numba
import numpy as np

from .._jit import kernel, next_item, run_slots, run_threads, work_counter
from ..raster.kernels import view_project
from ..raster.view import VP_B, VP_FORWARD, VP_H, VP_L, VP_ORIGIN, VP_R, VP_RIGHT, VP_T, VP_UP, VP_W
from .base import Method, MethodOutput, Param, register
from .shadowmap import build_shadow_map, fit_light_view, receiver_offset

# ---- sample patterns --------------------------------------------------------------------------
_PATTERNS: dict = {}


def _concentric_np(a, b):
    """Shirley-Chiu concentric map of [0,1)^2 to the unit disk (vectorized)."""
    x = 2.0 * a - 1.0
    y = 2.0 * b - 1.0
    r = np.where(np.abs(x) > np.abs(y), x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(np.abs(x) > np.abs(y), (np.pi / 4) * (y / x), np.pi / 2 - (np.pi / 4) * (x / y))
    phi = np.nan_to_num(phi)
    return r * np.cos(phi), r * np.sin(phi)


def sample_pattern(n: int, kind: str, disk: bool) -> np.ndarray:
    """(n', 2) float64 tap offsets in the unit disk (``disk``) or the square [-1, 1]^2.

    ``poisson``: Mitchell's best-candidate algorithm (a Poisson-disk set with exactly n points,
    fixed seed). ``grid``: N x N cell centers, N = round(sqrt(n)) (concentric-mapped on the disk).
    """
    key = (int(n), kind, bool(disk))
    if key in _PATTERNS:
        return _PATTERNS[key]
    if kind == "grid":
        s = max(1, int(round(np.sqrt(n))))
        c = (np.arange(s) + 0.5) / s
        a, b = np.meshgrid(c, c, indexing="ij")
        a, b = a.ravel(), b.ravel()
        if disk:
            x, y = _concentric_np(a, b)
        else:
            x, y = 2 * a - 1, 2 * b - 1
        pts = np.stack([x, y], axis=1)
    else:
        rng = np.random.Generator(np.random.PCG64(20050731))
        pts = np.zeros((0, 2))

        def candidates(m):
            if disk:
                r = np.sqrt(rng.random(m))
                t = 2 * np.pi * rng.random(m)
                return np.stack([r * np.cos(t), r * np.sin(t)], axis=1)
            return rng.random((m, 2)) * 2 - 1

        for i in range(int(n)):
            cand = candidates(max(1, 10 * i + 1))
            if len(pts) == 0:
                best = cand[0]
            else:
                d2 = ((cand[:, None, :] - pts[None, :, :]) ** 2).sum(-1).min(axis=1)
                best = cand[int(np.argmax(d2))]
            pts = np.vstack([pts, best[None]])
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    _PATTERNS[key] = pts
    return pts


# ---- kernels (plain arrays in, plain arrays out) ----------------------------------------------
@kernel(inline=True)
def _hash01(k, seed):
    """A uniform number in [0,1) from a point index (per-pixel pattern rotation)."""
    h = (np.uint64(k) * np.uint64(0x9E3779B97F4A7C15)) ^ np.uint64(seed * 0x85EBCA6B + 0x27D4EB2F)
    h ^= h >> np.uint64(33)
    h *= np.uint64(0xFF51AFD7ED558CCD)
    h ^= h >> np.uint64(33)
    h *= np.uint64(0xC4CEB9FE1A85EC53)
    h ^= h >> np.uint64(33)
    return float(h >> np.uint64(11)) / 9007199254740992.0


@kernel(inline=True)
def _tap_offset(pattern, i, disk, rot, c, s, shx, shy):
    """Pattern tap i, rotated (disk) or toroidally shifted (square) when ``rot``."""
    x = pattern[i, 0]
    y = pattern[i, 1]
    if rot:
        if disk:
            return c * x - s * y, s * x + c * y
        x += shx
        y += shy
        if x > 1.0:
            x -= 2.0
        if y > 1.0:
            y -= 2.0
    return x, y


@kernel(inline=True)
def _pixel_point(position, normal, i, j):
    """The G-buffer's point and normal at pixel (i, j), in float64."""
    return (
        np.float64(position[i, j, 0]),
        np.float64(position[i, j, 1]),
        np.float64(position[i, j, 2]),
        np.float64(normal[i, j, 0]),
        np.float64(normal[i, j, 1]),
        np.float64(normal[i, j, 2]),
    )


@kernel(inline=True)
def _view_normal(vp, nx, ny, nz):
    """The normal in light-view coordinates (right, up, forward components)."""
    return (
        nx * vp[VP_RIGHT] + ny * vp[VP_RIGHT + 1] + nz * vp[VP_RIGHT + 2],
        nx * vp[VP_UP] + ny * vp[VP_UP + 1] + nz * vp[VP_UP + 2],
        nx * vp[VP_FORWARD] + ny * vp[VP_FORWARD + 1] + nz * vp[VP_FORWARD + 2],
    )


@kernel(inline=True)
def _exact_inverse(n):
    """1/n where dividing by n is the same as multiplying by it (n a power of two: both are exact
    scalings), else 0.0 (divide)."""
    k = int(n)
    if k == n and k > 0 and (k & (k - 1)) == 0:
        return 1.0 / n
    return 0.0


@kernel(inline=True)
def _ray_xy(vp, sx, sy, iw, ih):
    """``view_ray`` (continuous texel coordinates -> window coordinates), bit for bit, with its two
    divisions by the map's width and height replaced by multiplications where ``iw``/``ih`` (from
    :func:`_exact_inverse`) make them exact."""
    fx = sx * iw if iw != 0.0 else sx / vp[VP_W]
    fy = sy * ih if ih != 0.0 else sy / vp[VP_H]
    return _window_of(vp, fx, fy)


@kernel(inline=True)
def _window_of(vp, fx, fy):
    """Window coordinates of the map fractions (``fx``, ``fy``) = texel coordinates over the map's
    size (:func:`_ray_xy`; the vectorized taps pass ``sx * iw`` directly, their maps being ones
    where that is exact)."""
    return vp[VP_L] + fx * (vp[VP_R] - vp[VP_L]), vp[VP_T] - fy * (vp[VP_T] - vp[VP_B])


@kernel(inline=True)
def _plane_depth(vp, nr, nu, nf, npo, sx, sy, z_center, iw, ih):
    """Depth of the receiver's tangent plane along the map ray through (sx, sy) (perspective map):
    plane n.(X - o) = npo, ray X = o + s (x' right + y' up + forward), depth = s. Falls back to
    ``z_center`` where the ray grazes the plane or the depth leaves [z/2, 2z]. ``iw``, ``ih``: see
    :func:`_ray_xy`."""
    xp, yp = _ray_xy(vp, sx, sy, iw, ih)
    return _plane_depth_bf(nr, nu, nf, npo, xp, yp, z_center)


@kernel(inline=True)
def _plane_depth_bf(nr, nu, nf, npo, xp, yp, z_center):
    """:func:`_plane_depth` from the window coordinates (``_ray_xy``'s), without branches (for the
    vector loops): the same operations and result."""
    den = nr * xp + nu * yp + nf
    d = npo / den
    bad = (abs(den) < 1e-6) | ~((d > 0.5 * z_center) & (d < 2.0 * z_center))
    return z_center if bad else d


@kernel(inline=True)
def _cmp_bilinear(depth, sx, sy, zt):
    """Hardware-PCF equivalent: 2x2 bilinearly weighted 'lit' tests (texels outside the map are lit)."""
    H, W = depth.shape
    x = sx - 0.5
    y = sy - 0.5
    x0 = int(np.floor(x))
    y0 = int(np.floor(y))
    fx = x - x0
    fy = y - y0
    acc = 0.0
    for dy in range(2):
        r = y0 + dy
        wy = fy if dy == 1 else 1.0 - fy
        for dx in range(2):
            c = x0 + dx
            wx = fx if dx == 1 else 1.0 - fx
            if r < 0 or r >= H or c < 0 or c >= W or not (depth[r, c] < zt):
                acc += wx * wy
    return acc


@kernel(inline=True)
def _texel_or_inf(depth, r, c):
    """depth[r, c], +inf outside the map (outside texels are lit: never < a comparison depth)."""
    H, W = depth.shape
    if r < 0 or r >= H or c < 0 or c >= W:
        return np.inf
    return depth[r, c]


@kernel(inline=True)
def _plane_bounds(z, off):
    """Bounds of every comparison depth ``_plane_depth(..., z, ...) - off`` (that depth lies in
    [z/2, 2z]; subtracting ``off`` rounds monotonically): a texel at or beyond ``hi`` is never a
    blocker, one below ``lo`` always is, so the plane need not be evaluated for either."""
    return 0.5 * z - off, 2.0 * z - off


@kernel(inline=True)
def _plane_range(vp, nr, nu, nf, npo, sx, sy, ex, ey, z, off, iw, ih):
    """Tighter :func:`_plane_bounds` for taps within ``ex``, ``ey`` of (sx, sy): (lo, hi) with every
    comparison depth ``_plane_depth(vp, nr, nu, nf, npo, tx, ty, z, iw, ih) - off`` of such a tap in
    [lo, hi]. The plane's denominator is evaluated at the box's corners with the same operations
    as ``_plane_depth``: each of them (products by fixed factors, sums, rounding) is monotonic in
    the tap's coordinates, so every tap's denominator lies between the corners' extremes, and where
    it keeps its sign away from the ``1e-6`` cut-off the depth ``npo / den`` is monotonic in it too;
    the fallback depth ``z`` is always included. A box where the denominator may reach 0 keeps
    :func:`_plane_bounds`. No branch (the vectorized set-up of :func:`_points_setup`)."""
    lo, hi = _plane_bounds(z, off)
    xa, ya = _ray_xy(vp, sx - ex, sy - ey, iw, ih)
    xb, yb = _ray_xy(vp, sx + ex, sy + ey, iw, ih)
    d00 = nr * xa + nu * ya + nf
    d01 = nr * xb + nu * ya + nf
    d10 = nr * xa + nu * yb + nf
    d11 = nr * xb + nu * yb + nf
    dmin = min(min(d00, d01), min(d10, d11))
    dmax = max(max(d00, d01), max(d10, d11))
    # the denominator may reach 0 in the box (also NaN): keep the plain bounds; a select, not a
    # branch: it vectorizes
    plain = ~((dmin >= 1e-6) | (dmax <= -1e-6))
    qa = npo / dmin
    qb = npo / dmax
    pmin = min(qa, qb)
    pmax = max(qa, qb)
    pmin -= 1e-12 * abs(pmin)  # a margin on top of the monotonicity
    pmax += 1e-12 * abs(pmax)
    pmin = min(max(pmin, 0.5 * z), z)  # depths outside (z/2, 2z) fall back to z
    pmax = max(min(pmax, 2.0 * z), z)
    return (lo if plain else max(lo, pmin - off)), (hi if plain else min(hi, pmax - off))


@kernel(inline=True)
def _bilinear_lit(d00, d01, d10, d11, zt, fx, fy):
    """The lit share of a 2x2 bilinear comparison: the weights of the texels not in front of ``zt``
    (fractions ``fx``, ``fy`` of the tap between the texel centers), by branch-free selects
    (adding 0.0 to the non-negative sum changes no bit)."""
    acc = 0.0
    acc += 0.0 if d00 < zt else (1.0 - fx) * (1.0 - fy)
    acc += 0.0 if d01 < zt else fx * (1.0 - fy)
    acc += 0.0 if d10 < zt else (1.0 - fx) * fy
    acc += 0.0 if d11 < zt else fx * fy
    return acc


@kernel(inline=True)
def _cmp_bilinear_plane(depth, sx, sy, vp, nr, nu, nf, npo, z, off, iw, ih, lo, hi):
    """:func:`_cmp_bilinear` against the receiver plane's depth at (sx, sy) (``_plane_depth - off``),
    bit for bit, with the plane evaluated only when the 2x2 texels straddle [lo, hi) (see
    :func:`_plane_bounds`): all at or beyond ``hi``: all lit; all below ``lo``: none lit."""
    x = sx - 0.5
    y = sy - 0.5
    x0 = int(np.floor(x))
    y0 = int(np.floor(y))
    d00 = _texel_or_inf(depth, y0, x0)
    d01 = _texel_or_inf(depth, y0, x0 + 1)
    d10 = _texel_or_inf(depth, y0 + 1, x0)
    d11 = _texel_or_inf(depth, y0 + 1, x0 + 1)
    dmin = min(min(d00, d01), min(d10, d11))
    dmax = max(max(d00, d01), max(d10, d11))
    if dmin >= hi:
        zt = -np.inf  # every texel lit
    elif dmax < lo:
        zt = np.inf  # every texel a blocker (all inside the map: outside ones are +inf)
    else:
        zt = _plane_depth(vp, nr, nu, nf, npo, sx, sy, z, iw, ih) - off
    return _bilinear_lit(d00, d01, d10, d11, zt, x - x0, y - y0)


@kernel(inline=True)
def _cmp_nearest(depth, sx, sy, zt):
    H, W = depth.shape
    c = int(np.floor(sx))
    r = int(np.floor(sy))
    if r < 0 or r >= H or c < 0 or c >= W or not (depth[r, c] < zt):
        return 1.0
    return 0.0


#: texels per side of the cells of the occupancy grid (:func:`occupancy_grid`)
OCC_CELL = 16


@kernel(nogil=True, noalias=True)
def _occupancy_rows_slot(slot, bits, cell, counts, row_min, cmin, cmax, nslot):
    """Per grid cell (``cell`` x ``cell`` texels) of a float32 map given as its bits (``bits``: the
    map viewed as int32) the number of finite texels, into ``counts`` (ny + 1, nx + 1) at
    [cy + 1, cx + 1], and the smallest and largest depth (+inf for an empty texel), into ``cmin``
    and ``cmax`` (ny, nx) float32; per grid row the smallest depth, into ``row_min``.

    Per grid row, every map column's count, smallest and largest depth over the row's ``cell``
    texel rows first, then the cells from their columns. The column pass compares integer keys
    that order as the floats do (the sign bit flips the other bits; a map holds no NaN): a loop
    of integer selects that vectorizes, which float selects without fast-math did not (1.1 ->
    0.43 ms a 1024^2 map on one thread). Minima and maxima are values of the map: no rounding.
    Run by ``run_slots``: slot ``slot`` of ``nslot`` takes every ``nslot``-th grid row."""
    H, W = bits.shape
    ny = row_min.shape[0]
    nx = counts.shape[1] - 1
    col_n = np.empty(W, np.int32)
    col_lo = np.empty(W, np.int32)
    col_hi = np.empty(W, np.int32)
    lo_f = col_lo.view(np.float32)
    hi_f = col_hi.view(np.float32)
    for cy in range(slot, ny, nslot):
        for c in range(W):
            col_n[c] = 0
            col_lo[c] = 0x7FFFFFFF
            col_hi[c] = -0x80000000
        for r in range(cy * cell, min(H, cy * cell + cell)):
            for c in range(W):
                b = bits[r, c]
                key = b ^ ((b >> 31) & np.int32(0x7FFFFFFF))
                col_n[c] += np.int32(1) if key < np.int32(0x7F800000) else np.int32(0)  # below +inf
                lo = col_lo[c]
                col_lo[c] = key if key < lo else lo
                hi = col_hi[c]
                col_hi[c] = key if key > hi else hi
        for c in range(W):  # keys back to float bits (the map's rows and columns are not empty)
            lo = col_lo[c]
            col_lo[c] = lo ^ ((lo >> 31) & np.int32(0x7FFFFFFF))
            hi = col_hi[c]
            col_hi[c] = hi ^ ((hi >> 31) & np.int32(0x7FFFFFFF))
        m = np.inf
        for cx in range(nx):
            n = 0
            lo = lo_f[cx * cell]
            hi = hi_f[cx * cell]
            for c in range(cx * cell, min(W, cx * cell + cell)):
                n += col_n[c]
                lo = min(lo, lo_f[c])
                hi = max(hi, hi_f[c])
            counts[cy + 1, cx + 1] += n
            cmin[cy, cx] = lo
            cmax[cy, cx] = hi
            m = min(m, lo)
        row_min[cy] = m


def occupancy_grid(depth: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """(summed-area table (ny + 1, nx + 1) int64 of the finite texels per ``OCC_CELL``-texel cell,
    the smallest depth of the map: +inf where it holds no occluder, the smallest and the largest
    depth per cell (ny, nx) float32: +inf for an empty texel), in one pass over the float32 map."""
    if depth.dtype != np.float32:
        raise TypeError(f"occupancy_grid: a float32 depth map, got {depth.dtype}")
    H, W = depth.shape
    ny = (H + OCC_CELL - 1) // OCC_CELL
    nx = (W + OCC_CELL - 1) // OCC_CELL
    counts = np.zeros((ny + 1, nx + 1), np.int64)
    row_min = np.empty(ny, np.float64)
    cmin = np.empty((ny, nx), np.float32)
    cmax = np.empty((ny, nx), np.float32)
    nslot = numba.get_num_threads()
    run_slots(
        _occupancy_rows_slot, nslot, np.ascontiguousarray(depth).view(np.int32), OCC_CELL, counts, row_min, cmin, cmax,
        nslot,
    )  # fmt: skip
    np.cumsum(counts, axis=0, out=counts)
    np.cumsum(counts, axis=1, out=counts)
    return counts, float(row_min.min()) if ny else np.inf, cmin, cmax


@kernel(nogil=True, nrt=False)
def _square_levels(tmin, tmax):
    """Fill levels k >= 1 of ``tmin``, ``tmax`` (L, ny, nx) from level 0 (the cells' smallest and
    largest depths): Décoret's N-Buffers (``occlusion_textures.prefilter_nbuffers`` builds them
    for box means, zero outside; here min and max, clamped to the grid, so that a box's value is
    exact, not filtered). Level k at [gy, gx] holds the smallest (largest) value over the cells
    [gy, gy + 2^k) x [gx, gx + 2^k), clamped to the grid, as the min (max) of four values of level
    k - 1: values of the grid, no rounding."""
    L, ny, nx = tmin.shape
    for k in range(1, L):
        h = 1 << (k - 1)
        for gy in range(ny):
            g2 = min(gy + h, ny - 1)
            a0 = tmin[k - 1, gy]
            a1 = tmin[k - 1, g2]
            b0 = tmax[k - 1, gy]
            b1 = tmax[k - 1, g2]
            om = tmin[k, gy]
            oM = tmax[k, gy]
            m = max(nx - h, 0)
            for gx in range(m):
                om[gx] = min(min(a0[gx], a0[gx + h]), min(a1[gx], a1[gx + h]))
                oM[gx] = max(max(b0[gx], b0[gx + h]), max(b1[gx], b1[gx + h]))
            for gx in range(m, nx):
                om[gx] = min(min(a0[gx], a0[nx - 1]), min(a1[gx], a1[nx - 1]))
                oM[gx] = max(max(b0[gx], b0[nx - 1]), max(b1[gx], b1[nx - 1]))


def cell_range_tables(cmin: np.ndarray, cmax: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Square sparse tables of :func:`occupancy_grid`'s per-cell smallest and largest depths (each
    (L, ny, nx) float32, see :func:`_square_levels`): the smallest and largest depth over a box of
    cells in a few reads (:func:`_cells_min_max`) where a loop over its cells took one read per
    cell (a filter region covers ~30-50 cells at the defaults: 1.15M cell reads a frame on
    `bunny`). 0.05 ms for the 64 x 64 grid of a 1024^2 map."""
    ny, nx = cmin.shape
    L = max(int(min(ny, nx)).bit_length(), 1)
    tmin = np.empty((L, ny, nx), np.float32)
    tmax = np.empty_like(tmin)
    tmin[0] = cmin
    tmax[0] = cmax
    _square_levels(tmin, tmax)
    return tmin, tmax


@kernel(inline=True)
def _floor_log2(n):
    """floor(log2(n)) of an int n >= 1."""
    k = 0
    while (2 << k) <= n:
        k += 1
    return k


@kernel(inline=True)
def _cells_min_max(tmin, tmax, gy0, gy1, gx0, gx1):
    """(smallest, largest) over the cells [gy0, gy1] x [gx0, gx1] (inclusive, non-empty): squares of
    2^k cells, k from the shorter side, at steps of 2^k along the longer one (the last flush with
    its end) and at both ends of the shorter one; they overlap, which min and max allow."""
    ny = gy1 - gy0 + 1
    nx = gx1 - gx0 + 1
    k = _floor_log2(min(ny, nx))
    s = 1 << k
    lo = np.float32(np.inf)
    hi = np.float32(-np.inf)
    y = gy0
    while True:
        yy = min(y, gy1 - s + 1)
        x = gx0
        while True:
            xx = min(x, gx1 - s + 1)
            lo = min(lo, tmin[k, yy, xx])
            hi = max(hi, tmax[k, yy, xx])
            if xx == gx1 - s + 1:
                break
            x += s
        if yy == gy1 - s + 1:
            break
        y += s
    return lo, hi


@kernel(inline=True)
def _region_empty(sat, cell, H, W, sx, sy, rx, ry):
    """Whether the taps around (sx, sy) within (rx, ry) texels (each tap reads the texel under it or
    the 2x2 around it) read no finite texel: their bounding box, grown by 2 texels and by a
    relative 1e-6 (rotated patterns), lies outside the map or over empty grid cells only."""
    ex = rx * (1.0 + 1e-6) + 2.0
    ey = ry * (1.0 + 1e-6) + 2.0
    c0 = max(int(np.floor(sx - ex)), 0)
    c1 = min(int(np.floor(sx + ex)), W - 1)
    r0 = max(int(np.floor(sy - ey)), 0)
    r1 = min(int(np.floor(sy + ey)), H - 1)
    if c0 > c1 or r0 > r1:
        return True
    gx0 = c0 // cell
    gx1 = c1 // cell + 1
    gy0 = r0 // cell
    gy1 = r1 // cell + 1
    return sat[gy1, gx1] - sat[gy0, gx1] - sat[gy1, gx0] + sat[gy0, gx0] == 0


@kernel(inline=True)
def _region_decided(tmin, tmax, cell, H, W, sx, sy, ex, ey, lo, hi):
    """(every texel read is >= ``hi``, every texel read is < ``lo``) for bilinear taps within
    (ex - 2, ey - 2) texels of (sx, sy), from the cells under their bounding box (grown as in
    :func:`_region_empty`; ``tmin``, ``tmax``: :func:`cell_range_tables`): texels outside the map
    count as +inf (lit, never below ``lo``)."""
    if not (abs(sx) < 1e7 and abs(sy) < 1e7 and ex < 1e7 and ey < 1e7):
        return False, False  # (also NaN)
    c0 = int(np.floor(sx - ex))
    c1 = int(np.floor(sx + ex))
    r0 = int(np.floor(sy - ey))
    r1 = int(np.floor(sy + ey))
    blk = c0 >= 0 and r0 >= 0 and c1 < W and r1 < H
    c0 = max(c0, 0)
    c1 = min(c1, W - 1)
    r0 = max(r0, 0)
    r1 = min(r1, H - 1)
    if c0 > c1 or r0 > r1:
        return True, False
    # the cell under (sx, sy) first (it is under the box when inside the map): where it holds both
    # a possible blocker and a possibly lit texel, as in most of the penumbra, neither can hold
    xc, yc = int(np.floor(sx)), int(np.floor(sy))
    if 0 <= xc < W and 0 <= yc < H:
        gc, gr = xc // cell, yc // cell
        if not (tmin[0, gr, gc] >= hi) and not (tmax[0, gr, gc] < lo):
            return False, False
    dmin, dmax = _cells_min_max(tmin, tmax, r0 // cell, r1 // cell, c0 // cell, c1 // cell)
    return dmin >= hi, blk and dmax < lo


@kernel(inline=True)
def _keep_point(P, m, sx, sy, rx, ry, zt, lo, hi, nr, nu, nf, npo, z, off):
    """Store a point's tap state as column ``m`` of ``P`` (13, n), for the vectorized taps
    (:func:`_search_taps`, :func:`_filter_taps`): its texel position, tap radii, comparison depth,
    plane-depth bounds, the plane in view coordinates, its depth and offset."""
    P[0, m] = sx
    P[1, m] = sy
    P[2, m] = rx
    P[3, m] = ry
    P[4, m] = zt
    P[5, m] = lo
    P[6, m] = hi
    P[7, m] = nr
    P[8, m] = nu
    P[9, m] = nf
    P[10, m] = npo
    P[11, m] = z
    P[12, m] = off


@kernel(inline=True)
def _keep_pixel(PP, P, m, px, py, pz, nx, ny, nz, sx, sy, rx, ry, zt, z, off):
    """Store what :func:`_points_setup` starts from as column ``m``: the point and its normal in
    ``PP`` (6, n), its texel position, radii, comparison depth, depth and offset in ``P``
    (:func:`_keep_point`'s rows)."""
    PP[0, m] = px
    PP[1, m] = py
    PP[2, m] = pz
    PP[3, m] = nx
    PP[4, m] = ny
    PP[5, m] = nz
    P[0, m] = sx
    P[1, m] = sy
    P[2, m] = rx
    P[3, m] = ry
    P[4, m] = zt
    P[11, m] = z
    P[12, m] = off


@kernel(inline=True, noalias=True)
def _points_setup(vp, PP, PS, m, bias, slope_bias, iw, ih, search):
    """The rest of a step's per-point set-up for a row's ``m`` kept points, vectorized across them:
    from each point's position and normal (``PP`` (6, n)) and its texel position, radii and depth
    (rows 0-3 and 11 of ``PS``, :func:`_keep_point`'s layout) the plane and the plane bounds, and
    with ``search`` (the blocker search) the bias and comparison depth (else, the filter: rows 4
    and 12 hold them), into the other rows, with the kernels' per-point operations: the same
    values."""
    for q in range(m):
        qx = np.uint64(q)
        px = PP[0, qx]
        py = PP[1, qx]
        pz = PP[2, qx]
        nx = PP[3, qx]
        ny = PP[4, qx]
        nz = PP[5, qx]
        sx = PS[0, qx]
        sy = PS[1, qx]
        rx = PS[2, qx]
        ry = PS[3, qx]
        z = PS[11, qx]
        if search:
            off = receiver_offset(vp, px, py, pz, nx, ny, nz, z, bias, slope_bias)
            zt = z - off
        else:
            zt = PS[4, qx]
            off = PS[12, qx]
        nr, nu, nf = _view_normal(vp, nx, ny, nz)
        npo = nx * (px - vp[VP_ORIGIN]) + ny * (py - vp[VP_ORIGIN + 1]) + nz * (pz - vp[VP_ORIGIN + 2])
        lo, hi = _plane_range(
            vp, nr, nu, nf, npo, sx, sy, rx * (1.0 + 1e-6) + 2.0, ry * (1.0 + 1e-6) + 2.0, z, off, iw, ih
        )
        _keep_point(PS, q, sx, sy, rx, ry, zt, lo, hi, nr, nu, nf, npo, z, off)


@kernel(inline=True, noalias=True)
def _search_taps(vp, depth_flat, H, W, ox, oy, m, PS, TOT, CNT, iw, ih):
    """One tap (pattern offset ``ox``, ``oy``) of the blocker search at a row's ``m`` points, vectorized
    across the points: the receiver plane on, the pattern unrotated and ``iw``, ``ih`` nonzero
    (:func:`_ray_xy`). The points' state in ``PS`` (:func:`_keep_point`); the sums in ``TOT`` and
    counts in ``CNT``. Each tap makes the
    decision of :func:`_search_point`'s, the plane depth computed at every point and kept where
    the texel lies in [lo, hi): the same bits."""
    for q in range(m):
        qx = np.uint64(q)
        tx = PS[0, qx] + ox * PS[2, qx]
        ty = PS[1, qx] - oy * PS[3, qx]
        col = np.int64(np.floor(tx))
        row = np.int64(np.floor(ty))
        inside = (row >= 0) & (row < H) & (col >= 0) & (col < W)
        d = depth_flat[np.uint64(row * W + col if inside else 0)]
        xp, yp = _window_of(vp, tx * iw, ty * ih)
        zc = _plane_depth_bf(PS[7, qx], PS[8, qx], PS[9, qx], PS[10, qx], xp, yp, PS[11, qx]) - PS[12, qx]
        blk = inside & (d < PS[6, qx]) & ((d < PS[5, qx]) | (d < zc))
        TOT[qx] += d if blk else 0.0
        CNT[qx] += np.int64(blk)


@kernel(inline=True)
def _search_point(
    vp, depth_map, pattern, disk, rotate, seed, k, plane, sx, sy, rx, ry, zt, lo, hi, nr, nu, nf, npo, z, off, iw, ih
):
    """The blocker search's taps at one point k: (blocker count, average blocker depth)."""
    H, W = depth_map.shape
    c = 1.0
    s = 0.0
    shx = 0.0
    shy = 0.0
    if rotate:
        a = _hash01(k, seed)
        c = np.cos(2.0 * np.pi * a)
        s = np.sin(2.0 * np.pi * a)
        shx = 2.0 * a
        shy = 2.0 * _hash01(k + 0x5BD1E995, seed)
    total = 0.0
    cnt = 0
    for t in range(pattern.shape[0]):
        ox, oy = _tap_offset(pattern, t, disk, rotate, c, s, shx, shy)
        tx = sx + ox * rx
        ty = sy - oy * ry
        col = int(np.floor(tx))
        row = int(np.floor(ty))
        if row < 0 or row >= H or col < 0 or col >= W:
            continue
        d = depth_map[row, col]
        zc = zt
        if plane:
            if d >= hi:
                continue  # beyond every plane depth: not a blocker (e.g. an empty texel)
            if d >= lo:
                zc = _plane_depth(vp, nr, nu, nf, npo, tx, ty, z, iw, ih) - off
            else:
                zc = np.inf  # in front of every plane depth: a blocker
        blk = d < zc  # branch-free (adding 0.0 to the non-negative sum changes no bit)
        total += d if blk else 0.0
        cnt += blk
    return cnt, (total / cnt if cnt > 0 else 0.0)


@kernel(nogil=True)
def blocker_search_kernel(
    slot,
    vp,
    depth_map,
    position,
    normal,
    mask,
    offs,
    bias,
    slope_bias,
    half_light,
    z_near,
    pattern,
    disk,
    rotate,
    seed,
    plane,
    sat,
    zr_out,
    avg_out,
    nblk_out,
    search_out,
    counter,
    nslot=1,
):
    """Step 1. Per point: receiver depth (minus bias), average blocker depth and blocker count
    over the search region (point-sampled taps). ``half_light`` = (half size x, half size y) of
    the light in world units, along the map's right/up axes. ``sat``: :func:`occupancy_grid`'s
    table (a region over empty cells has no blocker: its taps are not taken). The points are the
    eye G-buffer's surface pixels (``position``, ``normal``: (h, w, 3), ``mask``: (h, w)), read
    straight from the image: point k, the k-th surface pixel in row-major order (``offs[i]``: the
    surface pixels above row i), is written at k. The normal's sign does not matter (every use of
    it is odd in it or takes its absolute value, and negation is exact). Run by ``run_slots``, one
    slot per thread; each slot takes the next image row from ``counter`` (``next_item``) until none
    is left, so that a slot whose thread is held up (a shared machine) takes fewer rows. A point's
    outputs depend on its own inputs only: the same bits whatever slot computes it.

    At the defaults (receiver plane on, pattern unrotated, a power-of-two map: ``fast``) a row's
    points are tested one by one (depth beyond ``z_near``, the occupancy cells), the kept ones get
    their bias, plane and plane bounds across them (:func:`_points_setup`), then their taps tap by
    tap across them (:func:`_search_taps`): loops LLVM vectorizes (gathers instead of a
    hard-to-predict branch per tap). Otherwise each point is set up and takes its taps right away
    (:func:`_search_point`). Both make the same decisions and sums in the same order."""
    h, w = mask.shape
    H, W = depth_map.shape
    S = pattern.shape[0]
    texel1 = (vp[VP_R] - vp[VP_L]) / vp[VP_W]  # texel size at depth 1 (perspective)
    iw = _exact_inverse(vp[VP_W])
    ih = _exact_inverse(vp[VP_H])
    dflat = depth_map.reshape(H * W)
    PS = np.empty((13, w + 8))
    PP = np.empty((6, w + 8))
    KK = np.empty(w + 8, np.int64)
    fast = plane and not rotate and iw != 0.0 and ih != 0.0
    TOT = np.empty(w + 8)
    CNT = np.empty(w + 8, np.int64)
    while True:  # the next image row (``counter``: a work queue shared by the slots)
        i = next_item(counter)
        if i >= h:
            break
        k = offs[i] - 1
        m = 0
        for j in range(w):
            if not mask[i, j]:
                continue
            k += 1
            px, py, pz, nx, ny, nz = _pixel_point(position, normal, i, j)
            sx, sy, z = view_project(vp, px, py, pz)
            if not (z > z_near):
                zr_out[k] = z
                avg_out[k] = 0.0
                nblk_out[k] = 0
                search_out[k] = 0.0
                continue
            # similar triangles: the light seen from p, cut at depth z_near, in map texels
            f = (z - z_near) / (z * z_near) / texel1
            rx = half_light[0] * f
            ry = half_light[1] * f
            search_out[k] = max(rx, ry)
            if _region_empty(sat, OCC_CELL, H, W, sx, sy, rx, ry):  # no blocker: no bias needed
                zr_out[k] = z
                avg_out[k] = 0.0
                nblk_out[k] = 0
                continue
            if fast:  # the rest of the set-up and the taps after the row, across its kept points
                _keep_pixel(PP, PS, m, px, py, pz, nx, ny, nz, sx, sy, rx, ry, z, z, 0.0)  # (zt, off: set up later)
                KK[m] = k
                TOT[m] = 0.0
                CNT[m] = 0
                m += 1
                continue
            off = receiver_offset(vp, px, py, pz, nx, ny, nz, z, bias, slope_bias)
            zt = z - off
            zr_out[k] = zt
            nr, nu, nf = _view_normal(vp, nx, ny, nz)
            npo = nr * 0.0
            if plane:  # n.(p - o) in view coordinates: receiver plane through p
                npo = nx * (px - vp[VP_ORIGIN]) + ny * (py - vp[VP_ORIGIN + 1]) + nz * (pz - vp[VP_ORIGIN + 2])
            lo = zt
            hi = zt
            if plane:  # bounds of the taps' plane depths (see _plane_range)
                lo, hi = _plane_range(
                    vp, nr, nu, nf, npo, sx, sy, rx * (1.0 + 1e-6) + 2.0, ry * (1.0 + 1e-6) + 2.0, z, off, iw, ih
                )
            nblk_out[k], avg_out[k] = _search_point(
                vp,
                depth_map,
                pattern,
                disk,
                rotate,
                seed,
                k,
                plane,
                sx,
                sy,
                rx,
                ry,
                zt,
                lo,
                hi,
                nr,
                nu,
                nf,
                npo,
                z,
                off,
                iw,
                ih,
            )
        if m:  # (fast)
            _points_setup(vp, PP, PS, m, bias, slope_bias, iw, ih, True)
            for q in range(m):
                zr_out[KK[q]] = PS[4, q]
        for t in range(S):  # (m = 0 unless fast)
            _search_taps(vp, dflat, H, W, pattern[t, 0], pattern[t, 1], m, PS, TOT, CNT, iw, ih)
        for q in range(m):
            kq = KK[q]
            cnt = CNT[q]
            avg_out[kq] = TOT[q] / cnt if cnt > 0 else 0.0
            nblk_out[kq] = cnt


@kernel(inline=True)
def penumbra_estimation(z_receiver, z_blocker, w_light):
    """Step 2 (per point and light axis): the parallel-plane penumbra width on the receiver,
    ``(z_receiver - z_blocker) * w_light / z_blocker`` (world units; 0 if the blocker is not in
    front). Called by the filter kernel right before filtering, as the shader does."""
    if not (z_blocker > 0.0) or z_receiver <= z_blocker:
        return 0.0
    return (z_receiver - z_blocker) * w_light / z_blocker


@kernel(inline=True, noalias=True)
def _filter_taps(vp, depth_flat, H, W, ox, oy, m, FS, ACC, iw, ih):
    """One tap (pattern offset ``ox``, ``oy``) of the filter at a row's ``m`` points, vectorized
    across the points, as :func:`_search_taps` (same conditions): :func:`_cmp_bilinear_plane`'s
    operations without branches, added to ``ACC``. ``FS``: the points' state as
    :func:`_keep_point` stores it."""
    inf = np.inf
    for q in range(m):
        qx = np.uint64(q)
        tx = FS[0, qx] + ox * FS[2, qx]
        ty = FS[1, qx] - oy * FS[3, qx]
        x = tx - 0.5
        y = ty - 0.5
        x0 = np.int64(np.floor(x))
        y0 = np.int64(np.floor(y))
        x1 = x0 + 1
        y1 = y0 + 1
        in_c0 = (x0 >= 0) & (x0 < W)
        in_c1 = (x1 >= 0) & (x1 < W)
        in_r0 = (y0 >= 0) & (y0 < H)
        in_r1 = (y1 >= 0) & (y1 < H)
        d00 = depth_flat[np.uint64(y0 * W + x0 if in_r0 & in_c0 else 0)]
        d01 = depth_flat[np.uint64(y0 * W + x1 if in_r0 & in_c1 else 0)]
        d10 = depth_flat[np.uint64(y1 * W + x0 if in_r1 & in_c0 else 0)]
        d11 = depth_flat[np.uint64(y1 * W + x1 if in_r1 & in_c1 else 0)]
        d00 = d00 if in_r0 & in_c0 else inf
        d01 = d01 if in_r0 & in_c1 else inf
        d10 = d10 if in_r1 & in_c0 else inf
        d11 = d11 if in_r1 & in_c1 else inf
        dmin = min(min(d00, d01), min(d10, d11))
        dmax = max(max(d00, d01), max(d10, d11))
        xp, yp = _window_of(vp, tx * iw, ty * ih)
        zp = _plane_depth_bf(FS[7, qx], FS[8, qx], FS[9, qx], FS[10, qx], xp, yp, FS[11, qx]) - FS[12, qx]
        zt = -inf if dmin >= FS[6, qx] else (inf if dmax < FS[5, qx] else zp)
        ACC[qx] += _bilinear_lit(d00, d01, d10, d11, zt, x - x0, y - y0)


@kernel(nogil=True)
def filtering_kernel(
    slot,
    vp,
    depth_map,
    position,
    normal,
    mask,
    offs,
    zr,
    avg,
    nblk,
    light_w,
    pattern,
    disk,
    rotate,
    seed,
    bilinear,
    plane,
    tmin,
    tmax,
    out,
    wp_out,
    radius_out,
    counter,
    nslot=1,
):
    """Steps 2 and 3 per point: penumbra estimation, then percentage-closer filtering with a
    kernel of radius w / 2 (per light axis) in texels at the receiver's depth. The points, their
    indices and the slots as in :func:`blocker_search_kernel`; V goes to ``out`` (h, w) at the
    point's pixel, 1 where no surface. With the 2x2 comparisons against the receiver plane, the
    pattern unrotated and a power-of-two map (``fast``: the defaults), a row's points with a
    blocker get their plane and plane bounds across them (:func:`_points_setup`), then the cell
    test one by one, and those it leaves undecided their taps tap by tap across them
    (:func:`_filter_taps`, vectorized), as the blocker search does: the same bits."""
    h, w = mask.shape
    H, W = depth_map.shape
    S = pattern.shape[0]
    texel1 = (vp[VP_R] - vp[VP_L]) / vp[VP_W]  # texel size at depth 1 (perspective map)
    iw = _exact_inverse(vp[VP_W])
    ih = _exact_inverse(vp[VP_H])
    fast = plane and bilinear and not rotate and iw != 0.0 and ih != 0.0
    dflat = depth_map.reshape(H * W)
    FS = np.empty((13, w + 8))
    PP = np.empty((6, w + 8))
    KJ = np.empty(w + 8, np.int64)
    ACC = np.empty(w + 8)
    while True:  # the next image row (``counter``: a work queue shared by the slots)
        i = next_item(counter)
        if i >= h:
            break
        k = offs[i] - 1
        m = 0
        for j in range(w):
            if not mask[i, j]:
                out[i, j] = 1.0
                continue
            k += 1
            if nblk[k] == 0:  # early out of the blocker search: fully lit, no filtering
                out[i, j] = 1.0
                wp_out[k] = 0.0
                radius_out[k] = 0.0
                continue
            wx = penumbra_estimation(zr[k], avg[k], light_w[0])
            wy = penumbra_estimation(zr[k], avg[k], light_w[1])
            rx = 0.5 * wx / (texel1 * zr[k])
            ry = 0.5 * wy / (texel1 * zr[k])
            wp_out[k] = max(wx, wy)
            radius_out[k] = max(rx, ry)
            px, py, pz, nx, ny, nz = _pixel_point(position, normal, i, j)
            sx, sy, z = view_project(vp, px, py, pz)
            zt = zr[k]
            off = z - zt
            if fast:  # the rest after the row, across its points (_points_setup, then the cell test)
                _keep_pixel(PP, FS, m, px, py, pz, nx, ny, nz, sx, sy, rx, ry, zt, z, off)
                KJ[m] = j
                m += 1
                continue
            nr, nu, nf = _view_normal(vp, nx, ny, nz)
            npo = nx * (px - vp[VP_ORIGIN]) + ny * (py - vp[VP_ORIGIN + 1]) + nz * (pz - vp[VP_ORIGIN + 2])
            ex = rx * (1.0 + 1e-6) + 2.0
            ey = ry * (1.0 + 1e-6) + 2.0
            lo = zt
            hi = zt
            if plane:  # bounds of the taps' plane depths (see _plane_range)
                lo, hi = _plane_range(vp, nr, nu, nf, npo, sx, sy, ex, ey, z, off, iw, ih)
            lit, dark = _region_decided(tmin, tmax, OCC_CELL, H, W, sx, sy, ex, ey, lo, hi)
            if lit:  # every texel read is lit: every tap adds its whole weight, V = 1
                out[i, j] = 1.0
                continue
            if dark:  # every texel read is a blocker: no tap adds anything, V = 0
                out[i, j] = 0.0
                continue
            c = 1.0
            s = 0.0
            shx = 0.0
            shy = 0.0
            if rotate:
                a = _hash01(k + 0x2545F491, seed)
                c = np.cos(2.0 * np.pi * a)
                s = np.sin(2.0 * np.pi * a)
                shx = 2.0 * a
                shy = 2.0 * _hash01(k + 0x68E31DA4, seed)
            acc = 0.0
            for t in range(S):
                ox, oy = _tap_offset(pattern, t, disk, rotate, c, s, shx, shy)
                tx = sx + ox * rx
                ty = sy - oy * ry
                if plane and bilinear:  # the plane only where the 2x2 texels need it
                    acc += _cmp_bilinear_plane(depth_map, tx, ty, vp, nr, nu, nf, npo, z, off, iw, ih, lo, hi)
                    continue
                zc = zt
                if plane:
                    zc = _plane_depth(vp, nr, nu, nf, npo, tx, ty, z, iw, ih) - off
                if bilinear:
                    acc += _cmp_bilinear(depth_map, tx, ty, zc)
                else:
                    acc += _cmp_nearest(depth_map, tx, ty, zc)
            v = acc / S
            out[i, j] = min(max(v, 0.0), 1.0)
        if m:  # (fast) the set-up's rest, then the decided test; the others are kept for the taps
            _points_setup(vp, PP, FS, m, 0.0, 0.0, iw, ih, False)
            n = 0
            for q in range(m):
                ex = FS[2, q] * (1.0 + 1e-6) + 2.0
                ey = FS[3, q] * (1.0 + 1e-6) + 2.0
                lit, dark = _region_decided(tmin, tmax, OCC_CELL, H, W, FS[0, q], FS[1, q], ex, ey, FS[5, q], FS[6, q])
                if lit or dark:  # every texel read lit: V = 1; all blockers: V = 0
                    out[i, KJ[q]] = 1.0 if lit else 0.0
                    continue
                for c13 in range(13):
                    FS[c13, n] = FS[c13, q]
                KJ[n] = KJ[q]
                ACC[n] = 0.0
                n += 1
            m = n
        for t in range(S):  # (m = 0 unless fast)
            _filter_taps(vp, dflat, H, W, pattern[t, 0], pattern[t, 1], m, FS, ACC, iw, ih)
        for q in range(m):
            v = ACC[q] / S
            out[i, KJ[q]] = min(max(v, 0.0), 1.0)


@kernel(nogil=True)
def point_stats(nblk, search, radius, wp, taps):
    """The frame's statistics over the points in one pass: (points with a blocker, points whose
    every search tap is a blocker, the blockers' total, the search radii's sum and largest, then
    over the points with a blocker the filter radii's sum and largest and the penumbra widths'
    sum). Integer counts are exact; the float sums run in point order."""
    nh = 0
    nfull = 0
    sum_blk = 0
    s_sum = 0.0
    s_max = -np.inf
    r_sum = 0.0
    r_max = -np.inf
    w_sum = 0.0
    for k in range(nblk.shape[0]):
        b = nblk[k]
        sum_blk += b
        nfull += b == taps
        s_sum += search[k]
        s_max = max(s_max, search[k])
        if b > 0:
            nh += 1
            r_sum += radius[k]
            r_max = max(r_max, radius[k])
            w_sum += wp[k]
    return nh, nfull, sum_blk, s_sum, s_max, r_sum, r_max, w_sum


# ---- the paper's steps (orchestration) ---------------------------------------------------------
def light_extent(light) -> np.ndarray:
    """Light width along the map's (right, up) axes: rect (|u|, |v|), sphere (2r, 2r)."""
    if light.shape == "rect":
        return np.array([np.linalg.norm(light.u), np.linalg.norm(light.v)], np.float64)
    return np.array([2.0 * light.radius, 2.0 * light.radius], np.float64)


def surface_offsets(mask: np.ndarray) -> np.ndarray:
    """(h + 1,) int64: the number of surface pixels (``mask`` (h, w) True) above each row, and in all:
    the index of a row's first point among the surface pixels in row-major order."""
    offs = np.zeros(mask.shape[0] + 1, np.int64)
    np.cumsum(np.count_nonzero(mask, axis=1), out=offs[1:])
    return offs


def blocker_search(smap, eye, offs, light, bias, slope_bias, pattern, disk, rotate, seed, plane, grid=None):
    """Step 1 over the surface pixels of the eye G-buffer ``eye`` (``offs``: :func:`surface_offsets`
    of its mask) -> per point, in row-major order: (z_receiver, avg blocker depth, blocker count,
    search radius). z_receiver is the biased depth where blockers were searched for, the plain
    depth where the search was skipped (no blocker: the filter does not read it). ``grid``: the
    map's :func:`occupancy_grid` (computed here if not given)."""
    n = int(offs[-1])
    zr = np.empty(n, np.float64)
    avg = np.empty(n, np.float64)
    nblk = np.empty(n, np.int32)
    search = np.empty(n, np.float64)
    # z_near: the map's nearest blocker depth (+inf: none)
    sat, z_near = (occupancy_grid(smap.depth) if grid is None else grid)[:2]
    if not np.isfinite(z_near):
        z_near = float(smap.view.near)
    z_near = max(z_near, 1e-9)
    run_threads(
        blocker_search_kernel,
        smap.vp,
        smap.depth,
        eye.position,
        eye.normal,
        eye.mask,
        offs,
        float(bias),
        float(slope_bias),
        0.5 * light_extent(light),
        z_near,
        pattern,
        disk,
        rotate,
        int(seed),
        bool(plane),
        sat,
        zr,
        avg,
        nblk,
        search,
        work_counter(),
    )
    return zr, avg, nblk, search


def filtering(smap, eye, offs, zr, avg, nblk, light, pattern, disk, rotate, seed, bilinear, plane, grid=None):
    """Steps 2 + 3 over the surface pixels of ``eye`` (as :func:`blocker_search`) -> (V (h, w)
    float32, 1 where no surface; per point: penumbra width (world, max over axes), filter radius
    (texels, max over axes)). ``grid``: the map's :func:`occupancy_grid` (computed here if not
    given)."""
    tmin, tmax = cell_range_tables(*(occupancy_grid(smap.depth) if grid is None else grid)[2:])
    n = int(offs[-1])
    out = np.empty(eye.mask.shape, np.float32)
    wp = np.empty(n, np.float64)
    radius = np.empty(n, np.float64)
    run_threads(
        filtering_kernel,
        smap.vp,
        smap.depth,
        eye.position,
        eye.normal,
        eye.mask,
        offs,
        zr,
        avg,
        nblk,
        light_extent(light),
        pattern,
        disk,
        rotate,
        int(seed),
        bool(bilinear),
        bool(plane),
        tmin,
        tmax,
        out,
        wp,
        radius,
        work_counter(),
    )
    return out, wp, radius


@register
class PCSS(Method):
    name = "pcss"
    light_shapes = ("rect", "sphere")
    summary = "percentage-closer soft shadows: blocker search, penumbra estimate, variable-size PCF"
    paper = "Fernando 2005, Percentage-Closer Soft Shadows (SIGGRAPH sketch)"
    light_view = True  # maps from the light's centre (limits: softshadows.limits)
    params = (
        Param("map_size", 1024, "shadow map resolution (square)", min=16, max=16384),
        Param("search_samples", 16, "blocker-search taps", min=1, max=1024),
        Param("filter_samples", 16, "PCF taps", min=1, max=1024),
        Param("pattern", "poisson", "tap pattern over the light's shape", choices=("poisson", "grid")),
        Param("rotate", False, "per-pixel random rotation of the pattern (noise instead of banding)"),
        Param("bilinear", True, "2x2 bilinear comparison per PCF tap (hardware PCF)"),
        Param("bias", 1.0, "constant depth bias, in texels at the receiver", min=0.0),
        Param("slope_bias", 1.0, "slope-scaled bias: texels x tan(angle to light)", min=0.0),
        Param(
            "receiver_plane",
            True,
            "compare each tap against the receiver's tangent plane (off: the sketch's one depth)",
        ),
    )

    #: what `softshadows pareto` sweeps (Method.sweep)
    sweep: ClassVar = {"map_size": [512, 1024, 2048], "filter_samples": [16, 36, 64]}

    def run(
        self, ctx, map_size, search_samples, filter_samples, pattern, rotate, bilinear, bias, slope_bias, receiver_plane
    ):
        light = ctx.light
        disk = light.shape != "rect"
        offs = surface_offsets(ctx.eye.mask)  # the points: the G-buffer's surface pixels, read in place
        search_pat = sample_pattern(search_samples, pattern, disk)
        filter_pat = sample_pattern(filter_samples, pattern, disk)
        with ctx.timer.phase("shadow_map"):
            view = fit_light_view(ctx.scene, map_size)
            smap = build_shadow_map(ctx.scene, view, tri=False)  # (the faces are never read)
        with ctx.timer.phase("blocker_search"):
            grid = occupancy_grid(smap.depth)
            zr, avg, nblk, search = blocker_search(
                smap, ctx.eye, offs, light, bias, slope_bias, search_pat, disk, rotate, ctx.seed, receiver_plane, grid
            )
        with ctx.timer.phase("filter"):  # penumbra estimation + filtering, one pass over the points
            out, wp, radius = filtering(
                smap,
                ctx.eye,
                offs,
                zr,
                avg,
                nblk,
                light,
                filter_pat,
                disk,
                rotate,
                ctx.seed,
                bilinear,
                receiver_plane,
                grid,
            )
        n = max(int(offs[-1]), 1)
        nh, nfull, sum_blk, s_sum, s_max, r_sum, r_max, w_sum = point_stats(nblk, search, radius, wp, len(search_pat))
        stats = {
            "map_size": map_size,
            # the map's finite texels, counted by the occupancy grid: a texel is finite where a
            # triangle covers it, +inf elsewhere
            "map_coverage": float(grid[0][-1, -1] / smap.depth.size),
            "search_taps": int(len(search_pat)),
            "filter_taps": int(len(filter_pat)),
            "light_size": [float(x) for x in light_extent(light)],
            "early_out_fraction": (len(nblk) - nh) / n,
            "fully_blocked_fraction": float(nfull / n),
            "mean_blockers": float(sum_blk / nh) if nh else 0.0,
            "mean_search_radius_texels": float(s_sum / len(search)) if len(search) else 0.0,
            "max_search_radius_texels": float(s_max) if len(search) else 0.0,
            "mean_filter_radius_texels": float(r_sum / nh) if nh else 0.0,
            "max_filter_radius_texels": float(r_max) if nh else 0.0,
            "mean_penumbra_width": float(w_sum / nh) if nh else 0.0,
        }
        return MethodOutput(out, stats)
