"""``occlusion-textures``: Eisemann & Décoret, "Plausible image based soft shadows using occlusion textures", 2006.

The occluders are cut into slices parallel to the (rectangular) light and projected from a centre
of projection behind it into binary occlusion textures (:func:`fit_slicing_view`,
:func:`slice_scene`), prefiltered so that a box filter of any size is one lookup (mipmaps, N-Buffers
or summed-area tables); for each eye point every slice between it and the light blocks the mean of
its texture over the light's pyramid cut by the slice (:func:`kernel_rect`, Eq. 4), and the slices
combine as independent occluders (:func:`combine_occlusion`, Eq. 5), with the slice containing the
point faded out (:func:`slice_weight`). :func:`occlusion_visibility` runs it on arbitrary points.

Steps, parameters, deviations and known limits: ``docs/methods/occlusion-textures.md``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import ClassVar

import numba
import numpy as np

from .._jit import kernel, run_slots, run_threads
from ..errors import SoftShadowsError
from ..raster import View, rasterize_fragments
from ..raster.view import light_frame
from .base import Method, MethodOutput, Param, register

FILTERS = ("mipmap", "nbuffers", "sat")
COMBINES = ("product", "max", "sum")
SELF_SHADOW = ("fade", "skip", "include")
TEXTURE_SIZES = (32, 64, 128, 256, 512, 1024, 2048)

_FILTER_ID = {f: i for i, f in enumerate(FILTERS)}
_COMBINE_ID = {c: i for i, c in enumerate(COMBINES)}
_SELF_ID = {s: i for i, s in enumerate(SELF_SHADOW)}


# =====================================================================================
# 1. Slicing (Sec. 3.4)
# =====================================================================================
@dataclass
class SlicingSetup:
    """The slicing camera and planes.

    view:     the COP view (origin d behind the light centre, looking along the light normal)
    frame:    (origin, right, up, forward) of the light frame (origin = light centre)
    half:     (hu, hv) half extents of the light along right / up
    d:        distance of the COP behind the light plane
    z_planes: (N+1,) light-frame depths of the slice planes z_0 < ... < z_N; slice k spans
              [z_k, z_{k+1}) and its texture lies on z_{k+1}, its plane farthest from the light
    depth:    largest light-frame depth of the occluders and of the points to shade
    """

    view: View
    frame: tuple
    half: tuple
    d: float
    z_planes: np.ndarray
    depth: float = 0.0  # largest light-frame depth of the occluders and fit points

    @property
    def slices(self) -> int:
        return len(self.z_planes) - 1

    def params(self) -> np.ndarray:
        """Flat float64 array for kernels: origin(3) right(3) up(3) forward(3) hu hv d l r b t W H."""
        o, r, u, f = self.frame
        l, rr, b, t = self.view.window
        return np.concatenate(
            [o, r, u, f, [self.half[0], self.half[1], self.d, l, rr, b, t, self.view.width, self.view.height]]
        ).astype(np.float64)


def light_rect_frame(light):
    """(origin, right, up, forward, hu, hv) of a rectangle light; its edges must be orthogonal."""
    u, v = light.u, light.v
    nu, nv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
    if abs(float(np.dot(u, v))) > 1e-6 * nu * nv:
        raise SoftShadowsError("method 'occlusion-textures': the rectangle light's u and v must be orthogonal")
    r, up, f = light_frame(light)
    return light.center.astype(np.float64), r, up, f, nu / 2.0, nv / 2.0


def to_light_frame(points, frame) -> np.ndarray:
    o, r, u, f = frame
    q = np.asarray(points, dtype=np.float64).reshape(-1, 3) - o
    return np.stack([q @ r, q @ u, q @ f], axis=1)


@kernel(inline=True)
def _fit_point(px, py, pz, o, r, u, f, hu, hv, eps, dm, zm, zc):
    """One point of :func:`_fit_reduce`: the running (dm, zm, zc) updated (a NaN point leaves them)."""
    qx = px - o[0]
    qy = py - o[1]
    qz = pz - o[2]
    x = abs(qx * r[0] + qy * r[1] + qz * r[2])
    y = abs(qx * u[0] + qy * u[1] + qz * u[2])
    z = qx * f[0] + qy * f[1] + qz * f[2]
    zm = max(zm, z)
    if z > eps:
        if x > hu * (1.0 + 1e-9):
            dm = min(dm, hu * z / (x - hu))
            zc = min(zc, z)
        if y > hv * (1.0 + 1e-9):
            dm = min(dm, hv * z / (y - hv))
            zc = min(zc, z)
    return dm, zm, zc


@kernel(nogil=True)
def _fit_reduce(tslot, pts, pts2, o, r, u, f, hu, hv, eps, res, nslot=1):
    """Per point of ``pts`` and ``pts2`` in front of the light (z > eps): the largest d keeping it
    in the frustum (hu z / (|x| - hu) when |x| > hu, likewise in y; inf otherwise). Slot ``tslot``
    of ``nslot`` (run by ``run_slots``) takes its share of both arrays and writes to ``res[tslot]``
    the minimum, the max z of its ``pts2`` rows and the least z of a point that gave a bound (see
    :func:`_fit_bounds`). Rows with a NaN (pixels without a surface) count for nothing. Two arrays
    in one call: the occluders' float64 vertices and the eye G-buffer's float32 positions, one
    compile (a serial kernel: a prange body compiles twice)."""
    n = pts.shape[0]
    n2 = pts2.shape[0]
    dm = np.inf
    zm = -np.inf
    zc = np.inf
    for i in range(tslot * n // nslot, (tslot + 1) * n // nslot):
        dm, _, zc = _fit_point(pts[i, 0], pts[i, 1], pts[i, 2], o, r, u, f, hu, hv, eps, dm, zm, zc)
    for i in range(tslot * n2 // nslot, (tslot + 1) * n2 // nslot):
        x = np.float64(pts2[i, 0])  # float() keeps a float32 (a second compile of _fit_point)
        y = np.float64(pts2[i, 1])
        z = np.float64(pts2[i, 2])
        dm, zm, zc = _fit_point(x, y, z, o, r, u, f, hu, hv, eps, dm, zm, zc)
    res[tslot, 0] = dm
    res[tslot, 1] = zm
    res[tslot, 2] = zc


def _fit_bounds(op, fp, o, r, u, f, hu, hv, eps):
    """:func:`_fit_reduce` on every thread: (the least d bound, the max z of ``fp``, the least z of
    a point that gave a bound: the caller checks that a larger eps would keep the same points).
    Min and max: the same result in any order and split."""
    nslot = numba.get_num_threads()
    res = np.empty((nslot, 3))
    run_slots(_fit_reduce, nslot, op, fp, o, r, u, f, float(hu), float(hv), float(eps), res, nslot)
    return float(res[:, 0].min()), float(res[:, 1].max()), float(res[:, 2].min())


def fit_cop_distance(dmax: float, zmax: float, light_size: float) -> float:
    """The COP distance from the frustum constraint ``dmax`` (the largest d such that the frustum
    from (0, 0, -d) through the light rectangle contains the points: |x| / (z + d) <= hu / d, i.e.
    d <= hu z / (|x| - hu) for |x| > hu, likewise in y), kept 2% inside, capped at
    max(scene depth, light size) and floored at 2% of the light size (see docs/methods/occlusion-textures.md)."""
    d = min(max(zmax, light_size), dmax)
    return max(d * 0.98, 0.02 * light_size)


def _points_array(points) -> np.ndarray:
    """(K,3) C-contiguous points: float32 ones (an eye G-buffer's positions, NaN where no surface)
    as they are, anything else as float64 (the kernels read either; float32 converts exactly)."""
    a = np.asarray(points)
    if a.dtype != np.float32:
        a = a.astype(np.float64, copy=False)
    return np.ascontiguousarray(a.reshape(-1, 3))


def fit_slicing_view(
    light, occluder_points, fit_points, size: int, slices: int, cop_distance: float = 0.0
) -> SlicingSetup:
    """The slicing camera of Sec. 3.4 / Fig. 4-5: COP at distance d behind the light centre, frustum
    fitted to the light (its section at the light plane is the light), d chosen so the frustum
    contains the scene (``fit_points``: occluders and shaded points). Slice planes split the
    occluders' depth range uniformly."""
    o, r, u, f, hu, hv = light_rect_frame(light)
    frame = (o, r, u, f)
    qo = to_light_frame(occluder_points, frame)
    op = np.ascontiguousarray(np.asarray(occluder_points, dtype=np.float64).reshape(-1, 3))
    fp = _points_array(fit_points)
    light_size = 2.0 * max(hu, hv)
    zo = float(qo[:, 2].max()) if len(qo) else -np.inf
    # one pass for the points' depth and the frustum bound with the occluders' eps (the final eps
    # below is at least that); a second only when a point between the two gave a bound
    eps0 = 1e-4 * zo if zo > 0 else 0.0
    dmax, zf, zcut = _fit_bounds(op, fp, o, r, u, f, hu, hv, eps0)
    scene_depth = float(max(zo, zf))
    if not scene_depth > 0:
        raise SoftShadowsError("method 'occlusion-textures': the scene is entirely behind the light")
    eps = 1e-4 * scene_depth
    front_o = qo[qo[:, 2] > eps]
    if cop_distance > 0:
        d = float(cop_distance)
    else:
        if not zcut > eps:
            dmax = _fit_bounds(op, fp, o, r, u, f, hu, hv, eps)[0]
        d = fit_cop_distance(dmax, scene_depth, light_size)
    # window: the light's section (x/(z+d) at z=0), widened if needed to contain the occluders
    l, rr, b, t = -hu / d, hu / d, -hv / d, hv / d
    if len(front_o):
        zz = front_o[:, 2] + d
        xs, ys = front_o[:, 0] / zz, front_o[:, 1] / zz
        if xs.min() < l or xs.max() > rr or ys.min() < b or ys.max() > t:
            m = 1e-3
            l, rr = min(l, xs.min() - m * (rr - l)), max(rr, xs.max() + m * (rr - l))
            b, t = min(b, ys.min() - m * (t - b)), max(t, ys.max() + m * (t - b))
    # slice planes over the occluders' depth range
    if len(front_o):
        z0, z1 = float(front_o[:, 2].min()), float(front_o[:, 2].max())
    else:
        z0, z1 = 0.5 * scene_depth, 0.5 * scene_depth
    pad = max(1e-3 * scene_depth - (z1 - z0), 0.0) / 2 + 1e-6 * scene_depth
    z0, z1 = max(z0 - pad, eps * 0.5), z1 + pad
    z_planes = np.linspace(z0, z1, slices + 1)
    view = View(o - d * f, r, u, f, (l, rr, b, t), d + z0, d + z1, size, size, False)
    return SlicingSetup(view, frame, (hu, hv), d, z_planes, scene_depth)


@kernel
def _mark_occlusion_textures(pixel, depth, d, z_planes, leak_fix, tex, bounds):
    """Binary occlusion textures: texel of every fragment set in its slice (and in the next one
    with the leak fix), and ``bounds[k]`` (x0, x1, y0, y1) grown over the texels set in slice k
    (what :func:`occupied_bounds` finds, without a pass over the textures). Serial: a texel may be
    hit by many fragments."""
    n = tex.shape[0]
    hw = tex.shape[1] * tex.shape[2]
    z0 = z_planes[0]
    zn = z_planes[n]
    thick = (zn - z0) / n
    for i in range(pixel.shape[0]):
        z = depth[i] - d
        if z < z0 or z > zn:
            continue
        k = int((z - z0) / thick)
        if k >= n:
            k = n - 1
        # uniform planes: guard float rounding against the stored planes
        while k > 0 and z < z_planes[k]:
            k -= 1
        while k < n - 1 and z >= z_planes[k + 1]:
            k += 1
        p = pixel[i]
        if p < 0 or p >= hw:
            continue
        row = p // tex.shape[2]
        col = p - row * tex.shape[2]
        for kk in range(k, min(k + 2, n) if leak_fix else k + 1):
            tex[kk, row, col] = 1
            bounds[kk, 0] = min(bounds[kk, 0], float(col))
            bounds[kk, 1] = max(bounds[kk, 1], float(col + 1))
            bounds[kk, 2] = min(bounds[kk, 2], float(row))
            bounds[kk, 3] = max(bounds[kk, 3], float(row + 1))


def _occluder_vertices(vertices, occ_faces) -> np.ndarray:
    """The vertices that some occluder face uses (they bound the slicing frustum)."""
    return vertices[np.unique(occ_faces)] if len(occ_faces) else np.zeros((0, 3))


def slice_scene(setup: SlicingSetup, vertices, faces, leak_fix: bool = False, bounds=None):
    """One rasterization of the occluders from the COP; returns (textures uint8 (N,S,S), fragments).

    Each texel of slice k is 1 when some surface inside the slice projects on it: everything in the
    slice is projected onto its plane farthest from the light (the COP projection maps a texel of
    one plane onto the same texel of every other plane). ``leak_fix`` also marks slice k+1 (Fig. 6).
    ``bounds`` (optional, (N, 4) float64) receives :func:`occupied_bounds` of the textures."""
    v = setup.view
    n = setup.slices
    tex = np.zeros((n, v.height, v.width), np.uint8)
    bb = np.empty((n, 4)) if bounds is None else bounds
    bb[:] = (1e30, -1e30, 1e30, -1e30)  # occupied_bounds' empty slice
    if len(faces) == 0:
        return tex, 0
    frags = rasterize_fragments(v, vertices, faces, cull="none")
    _mark_occlusion_textures(
        np.ascontiguousarray(frags.pixel, dtype=np.int64),
        np.ascontiguousarray(frags.depth, dtype=np.float64),
        float(setup.d),
        setup.z_planes,
        bool(leak_fix),
        tex,
        bb,
    )
    return tex, len(frags)


def occupied_bounds(tex: np.ndarray) -> np.ndarray:
    """(N, 4) float64 texel bounds (x0, x1, y0, y1) of the set texels of each texture (for culling)."""
    out = np.zeros((tex.shape[0], 4))
    for s in range(tex.shape[0]):
        rows = np.flatnonzero(tex[s].any(axis=1))
        cols = np.flatnonzero(tex[s].any(axis=0))
        if len(rows):
            out[s] = (cols[0], cols[-1] + 1, rows[0], rows[-1] + 1)
        else:
            out[s] = (1e30, -1e30, 1e30, -1e30)
    return out


# =====================================================================================
# 2. Prefiltering (Sec. 3.2)
# =====================================================================================
@kernel(nogil=True, nrt=False)
def _mip_build_slot(slot, tex, pyr, offs, sizes, nslot):
    """The mipmap pyramid of :func:`prefilter_mipmap` (level 0 the texture, level l the 2x2 box
    average of level l-1) of the slices ``slot``, ``slot + nslot``, ... (run by ``run_slots``, one
    slot per thread): every level of a slice in turn, the slice's levels staying in cache."""
    n, h, w = tex.shape
    for s in range(slot, n, nslot):
        for i in range(h):
            for j in range(w):
                pyr[s, i * w + j] = tex[s, i, j]
        for lv in range(1, sizes.shape[0]):
            src_off = offs[lv - 1]
            src_w = sizes[lv - 1]
            dst_off = offs[lv]
            dst_w = sizes[lv]
            for i in range(dst_w):
                for j in range(dst_w):
                    a = src_off + (2 * i) * src_w + 2 * j
                    pyr[s, dst_off + i * dst_w + j] = 0.25 * (
                        pyr[s, a] + pyr[s, a + 1] + pyr[s, a + src_w] + pyr[s, a + src_w + 1]
                    )


def prefilter_mipmap(tex: np.ndarray):
    """GPU mipmap pyramid (dyadic 2x2 box downsampling) of every texture.

    Returns (pyramid float32 (N, total), level offsets int64 (L+1,), level sizes int64 (L+1,))."""
    n, _h, w = tex.shape
    sizes = [w]
    while sizes[-1] > 1:
        sizes.append(sizes[-1] // 2)
    offs = np.cumsum([0] + [s * s for s in sizes[:-1]]).astype(np.int64)
    total = int(offs[-1] + sizes[-1] ** 2)
    pyr = np.empty((n, total), np.float32)
    sizes = np.asarray(sizes, np.int64)
    run_threads(_mip_build_slot, tex, pyr, offs, sizes)
    return pyr, offs, sizes


@kernel(nogil=True, nrt=False)
def _nbuffer_levels_slot(slot, tex, nb, bounds, nslot):
    """nb[s, l, i, j] = mean of tex[s] over rows [i, i+2^l) x cols [j, j+2^l) (zero outside):
    level l from four lookups in level l-1 at offsets 0 and 2^(l-1) (Décoret's N-Buffers).
    ``bounds[s]`` (:func:`occupied_bounds`): a row whose boxes miss the set texels' rows is 0
    without reading level l-1 (the sum would be 0 too; the textures are mostly empty). Run by
    ``run_slots``: slot ``slot`` of ``nslot`` builds every level of the slices ``slot``,
    ``slot + nslot``, ... (a level reads only its own slice's previous level: no wait between
    levels, one launch)."""
    n, nl, h, w = nb.shape
    for s in range(slot, n, nslot):
        for i in range(h):
            for j in range(w):
                nb[s, 0, i, j] = tex[s, i, j]
        for lv in range(1, nl):
            o = 1 << (lv - 1)
            jm = max(w - o, 0)
            for i in range(h):
                dst = nb[s, lv, i]
                if i + 2 * o <= bounds[s, 2] or i >= bounds[s, 3]:
                    for j in range(w):
                        dst[j] = 0.0
                    continue
                a = nb[s, lv - 1, i]
                if i + o < h:
                    c = nb[s, lv - 1, i + o]
                    for j in range(jm):  # branch-free body (vectorizes)
                        dst[j] = 0.25 * (a[j] + a[j + o] + c[j] + c[j + o])
                    for j in range(jm, w):
                        dst[j] = 0.25 * (a[j] + c[j])
                else:
                    for j in range(jm):
                        dst[j] = 0.25 * (a[j] + a[j + o])
                    for j in range(jm, w):
                        dst[j] = 0.25 * a[j]


def prefilter_nbuffers(tex: np.ndarray, levels: int | None = None, bounds: np.ndarray | None = None) -> np.ndarray:
    """N-Buffers: float32 (N, L+1, S, S); level l holds the 2^l x 2^l box response at each texel.
    ``levels`` (L) defaults to log2(S), the paper's full set; ``bounds`` (optional) is
    :func:`occupied_bounds` of ``tex`` when the caller has it."""
    n, h, w = tex.shape
    full = int(round(math.log2(max(h, w))))
    nl = full if levels is None else int(min(max(levels, 0), full))
    nb = np.empty((n, nl + 1, h, w), np.float32)
    bb = occupied_bounds(tex) if bounds is None else np.ascontiguousarray(bounds, dtype=np.float64)
    run_threads(_nbuffer_levels_slot, tex, nb, bb)
    return nb


@kernel(nogil=True, nrt=False)
def _sat_build_slot(slot, tex, sat, nslot):
    """The summed-area tables of :func:`prefilter_sat` of the slices ``slot``, ``slot + nslot``, ...
    (run by ``run_slots``, one slot per thread; integer sums, exact)."""
    n, h, w = tex.shape
    for s in range(slot, n, nslot):
        for j in range(w + 1):
            sat[s, 0, j] = 0
        for i in range(h):
            row = 0
            sat[s, i + 1, 0] = 0
            for j in range(w):
                row += tex[s, i, j]
                sat[s, i + 1, j + 1] = sat[s, i, j + 1] + row


def prefilter_sat(tex: np.ndarray) -> np.ndarray:
    """Summed-area table int32 (N, S+1, S+1): sat[s, i, j] = sum of tex[s, :i, :j] (exact)."""
    n, h, w = tex.shape
    if h * w >= 2**31:
        raise SoftShadowsError("method 'occlusion-textures': texture too large for a 32-bit summed-area table")
    sat = np.empty((n, h + 1, w + 1), np.int32)
    run_threads(_sat_build_slot, tex, sat)
    return sat


# =====================================================================================
# 3. Kernel size (Eq. 4) and filtered lookups
# =====================================================================================
@kernel
def kernel_rect(px, py, pz, zs, sp):
    """Eq. 4: the pyramid (P, light) cut by the slice plane z = zs is the rectangle centred at
    P * zs / pz (the light centre being the origin) of half sizes hu |pz - zs| / pz and
    hv |pz - zs| / pz (= d(P, slice) / d(P, light) x size / 2). Returned in the slice texture's
    continuous texel coordinates (x0, x1, y0, y1): the plane is parallel to the COP image plane at
    depth d + zs, so the map is a scale."""
    hu = sp[12]
    hv = sp[13]
    d = sp[14]
    l = sp[15]
    r = sp[16]
    b = sp[17]
    t = sp[18]
    W = sp[19]
    H = sp[20]
    a = abs(pz - zs) / pz
    cx = px * zs / pz
    cy = py * zs / pz
    ax = hu * a
    ay = hv * a
    D = d + zs
    sx = W / ((r - l) * D)
    sy = H / ((t - b) * D)
    x0 = (cx - ax) * sx - l * W / (r - l)
    x1 = (cx + ax) * sx - l * W / (r - l)
    y0 = t * H / (t - b) - (cy + ay) * sy
    y1 = t * H / (t - b) - (cy - ay) * sy
    return x0, x1, y0, y1


@kernel(inline=True)
def _kernel_rect_fast(px, py, pz, ipz, zs, hu, hv, kx, ky, ox, oy):
    """:func:`kernel_rect` with its per-slice constants precomputed (``kx = W / ((r - l)(d + zs))``,
    ``ky``, ``ox = l W / (r - l)``, ``oy = t H / (t - b)``) and ``ipz = 1 / pz``: no division (the
    eye pass evaluates it for every point and slice). Equal to it up to rounding."""
    a = abs(pz - zs) * ipz
    cx = px * zs * ipz
    cy = py * zs * ipz
    ax = hu * a
    ay = hv * a
    return (cx - ax) * kx - ox, (cx + ax) * kx - ox, oy - (cy + ay) * ky, oy - (cy - ay) * ky


@kernel(inline=True)
def _mip_fetch(pyr, s, off, size, i, j):
    if i < 0 or j < 0 or i >= size or j >= size:
        return 0.0  # CLAMP_TO_BORDER, border 0 (nothing outside the frustum)
    return pyr[s, off + i * size + j]


@kernel(nrt=False)
def _mip_bilinear(pyr, s, off, size, scale, x, y):
    """Bilinear sample of one mip level at level-0 texel coordinates (x, y)."""
    u = x / scale - 0.5
    v = y / scale - 0.5
    j0 = int(math.floor(u))
    i0 = int(math.floor(v))
    fu = u - j0
    fv = v - i0
    a = _mip_fetch(pyr, s, off, size, i0, j0)
    b = _mip_fetch(pyr, s, off, size, i0, j0 + 1)
    c = _mip_fetch(pyr, s, off, size, i0 + 1, j0)
    e = _mip_fetch(pyr, s, off, size, i0 + 1, j0 + 1)
    return (1 - fv) * ((1 - fu) * a + fu * b) + fv * ((1 - fu) * c + fu * e)


@kernel(nrt=False)
def _mip_trilinear(pyr, s, offs, sizes, lod, x, y):
    nl = offs.shape[0]
    if lod <= 0.0:
        return _mip_bilinear(pyr, s, offs[0], sizes[0], 1.0, x, y)
    if lod >= nl - 1:
        return _mip_bilinear(pyr, s, offs[nl - 1], sizes[nl - 1], float(1 << (nl - 1)), x, y)
    l0 = int(math.floor(lod))
    f = lod - l0
    a = _mip_bilinear(pyr, s, offs[l0], sizes[l0], float(1 << l0), x, y)
    b = _mip_bilinear(pyr, s, offs[l0 + 1], sizes[l0 + 1], float(1 << (l0 + 1)), x, y)
    return (1 - f) * a + f * b


@kernel(inline=True)
def _probe_count(wx, wy, max_probes):
    """Probes along the long side of a wx x wy footprint: ceil(long / short), in [1, max_probes]
    (max_probes for a degenerate footprint). Shared by the mipmap and N-Buffer lookups."""
    pmax = max(wx, wy)
    pmin = min(wx, wy)
    n = int(math.ceil(pmax / pmin - 1e-9)) if pmin > 1e-12 else max_probes
    return max(1, min(n, max_probes))


@kernel(nrt=False)
def lookup_mipmap(pyr, s, offs, sizes, max_aniso, x0, x1, y0, y1):
    """Rectangular kernel through anisotropic mipmap filtering (EXT_texture_filter_anisotropic):
    Pmax, Pmin = footprint sides; N = min(ceil(Pmax/Pmin), max_aniso) trilinear probes along the
    major axis at i/(N+1) - 1/2 of its length, at LOD log2(Pmax/N)."""
    wx = x1 - x0
    wy = y1 - y0
    cx = 0.5 * (x0 + x1)
    cy = 0.5 * (y0 + y1)
    pmax = max(wx, wy)
    n = _probe_count(wx, wy, max_aniso)
    lod = math.log2(max(pmax / n, 1e-30))
    acc = 0.0
    for i in range(1, n + 1):
        o = i / (n + 1.0) - 0.5
        if wx >= wy:
            acc += _mip_trilinear(pyr, s, offs, sizes, lod, cx + o * wx, cy)
        else:
            acc += _mip_trilinear(pyr, s, offs, sizes, lod, cx, cy + o * wy)
    return acc / n


@kernel
def _mip_support(x0, x1, y0, y1, max_aniso, nl):
    """How far (level-0 texels) beyond the rectangle :func:`lookup_mipmap` reads: its probes lie
    inside the rectangle and each bilinear tap reaches 1.5 texels of the coarser level used."""
    wx = x1 - x0
    wy = y1 - y0
    pmax = max(wx, wy)
    n = _probe_count(wx, wy, max_aniso)
    lod = math.log2(max(pmax / n, 1e-30))
    if lod <= 0.0:
        return 1.5
    lv = min(int(math.floor(lod)) + 1, nl - 1)
    return 1.5 * (1 << lv) + 1e-6


@kernel(inline=True)
def _nb_box(nb, s, lv, sx, sy):
    """Bilinear lookup of N-Buffer level lv at continuous box origin (sx, sy) (texel (i, j) holds
    the box whose corner is (j, i)); clamp-to-edge."""
    h = nb.shape[2]
    w = nb.shape[3]
    j0 = int(math.floor(sx))
    i0 = int(math.floor(sy))
    fu = sx - j0
    fv = sy - i0
    ja = min(max(j0, 0), w - 1)
    jb = min(max(j0 + 1, 0), w - 1)
    ia = min(max(i0, 0), h - 1)
    ib = min(max(i0 + 1, 0), h - 1)
    return (1 - fv) * ((1 - fu) * nb[s, lv, ia, ja] + fu * nb[s, lv, ia, jb]) + fv * (
        (1 - fu) * nb[s, lv, ib, ja] + fu * nb[s, lv, ib, jb]
    )


@kernel(inline=True)
def _nb_square(nb, s, cx, cy, size):
    """Box response of a size x size square centred at (cx, cy): the two levels bracketing the
    size, interpolated linearly in size."""
    lmax = nb.shape[1] - 1
    if size <= 1.0:
        return _nb_box(nb, s, np.int64(0), cx - 0.5, cy - 0.5)  # not a literal: one specialisation
    # floor(log2(size)) from the exponent bits (size > 1 here), exact; math.log2 only within 2^-40
    # below a power of two, where its rounding might reach the next level (same l0 as before)
    bits = np.float64(size).view(np.int64)
    l0 = (bits >> 52) - 1023
    if (bits & 0xFFFFFFFFFFFFF) > 0xFFFFFFFFFF000:
        l0 = int(math.floor(math.log2(size)))
    if l0 >= lmax:
        h = 0.5 * (1 << lmax)
        return _nb_box(nb, s, lmax, cx - h, cy - h)
    s0 = float(1 << l0)
    t = size / s0 - 1.0
    bx = cx - s0
    by = cy - s0
    if l0 + 2 <= lmax:
        # every texel the eight taps below read (levels l0 and l0 + 1, after clamping) lies in the
        # 2^(l0+2) box of level l0 + 2 at the first tap of level l0 + 1: when that box is empty
        # (exactly 0: sums of non-negative dyadic means) both boxes are 0 and so is the result
        ja = min(max(int(math.floor(bx)), 0), nb.shape[3] - 1)
        ia = min(max(int(math.floor(by)), 0), nb.shape[2] - 1)
        if nb[s, l0 + 2, ia, ja] == 0.0:
            return 0.0
    a = _nb_box(nb, s, l0, cx - 0.5 * s0, cy - 0.5 * s0)
    b = _nb_box(nb, s, l0 + 1, bx, by)
    return (1 - t) * a + t * b


@kernel(inline=True)
def _lookup_nbuffers(nb, s, max_probes, x0, x1, y0, y1):
    """Rectangular kernel from square N-Buffer lookups: ceil(long/short) squares of the short side
    spread along the long side (one for a square light)."""
    wx = x1 - x0
    wy = y1 - y0
    side = min(wx, wy)
    big = max(wx, wy)
    n = _probe_count(wx, wy, max_probes)
    if n == 1:
        return _nb_square(nb, s, 0.5 * (x0 + x1), 0.5 * (y0 + y1), side)
    acc = 0.0
    for i in range(n):
        o = (big - side) * i / (n - 1.0) + 0.5 * side
        if wx >= wy:
            acc += _nb_square(nb, s, x0 + o, 0.5 * (y0 + y1), side)
        else:
            acc += _nb_square(nb, s, 0.5 * (x0 + x1), y0 + o, side)
    return acc / n


@kernel(nrt=False)
def lookup_nbuffers(nb, s, max_probes, x0, x1, y0, y1):
    """:func:`_lookup_nbuffers` as a kernel of its own (the eye pass has it inlined)."""
    return _lookup_nbuffers(nb, s, max_probes, x0, x1, y0, y1)


@kernel(nrt=False)
def _sat_at(sat, s, x, y):
    """The SAT as a continuous function: bilinear between integer corners (exact integral of the
    piecewise-constant texture), clamped (zero occlusion outside the texture)."""
    h = sat.shape[1] - 1
    w = sat.shape[2] - 1
    x = min(max(x, 0.0), float(w))
    y = min(max(y, 0.0), float(h))
    j0 = min(int(math.floor(x)), w - 1)
    i0 = min(int(math.floor(y)), h - 1)
    fu = x - j0
    fv = y - i0
    a = float(sat[s, i0, j0])
    b = float(sat[s, i0, j0 + 1])
    c = float(sat[s, i0 + 1, j0])
    e = float(sat[s, i0 + 1, j0 + 1])
    return (1 - fv) * ((1 - fu) * a + fu * b) + fv * ((1 - fu) * c + fu * e)


@kernel(nrt=False)
def lookup_sat(sat, s, x0, x1, y0, y1):
    """Exact box filter: (S(x1,y1) - S(x0,y1) - S(x1,y0) + S(x0,y0)) / area."""
    area = (x1 - x0) * (y1 - y0)
    if area < 1e-8:
        h = sat.shape[1] - 1
        w = sat.shape[2] - 1
        j = int(math.floor(0.5 * (x0 + x1)))
        i = int(math.floor(0.5 * (y0 + y1)))
        if i < 0 or j < 0 or i >= h or j >= w:
            return 0.0
        return float(sat[s, i + 1, j + 1] - sat[s, i, j + 1] - sat[s, i + 1, j] + sat[s, i, j])
    v = (_sat_at(sat, s, x1, y1) - _sat_at(sat, s, x0, y1) - _sat_at(sat, s, x1, y0) + _sat_at(sat, s, x0, y0)) / area
    return min(max(v, 0.0), 1.0)


# =====================================================================================
# 4. Combination (Sec. 3.3, Eq. 5) and 5. self-shadowing weight (Sec. 3.4)
# =====================================================================================
@kernel(inline=True)
def combine_occlusion(acc, occ, mode):
    """Accumulate one slice's (weighted) occlusion ``occ``: product -> acc = prod (1 - I_k)
    (Eq. 5, acc starts at 1); max -> acc = max I_k; sum -> acc = sum I_k (both start at 0)."""
    if mode == 0:
        return acc * (1.0 - occ)
    elif mode == 1:
        return max(acc, occ)
    return acc + occ


@kernel(inline=True)
def finish_visibility(acc, mode):
    if mode == 0:
        return acc
    return min(max(1.0 - acc, 0.0), 1.0)


@kernel(inline=True)
def slice_weight(pz, z_top, z_low, thick, mode):
    """Weight of slice [z_top, z_low) (texture on z_low) for a point at depth pz.

    fade (paper): clamp((pz - z_low) / thickness, 0, 1): the slice containing P (pz < z_low) is not
    used; the one just above fades in with P's distance to its lower plane. skip: 1 if the slice is
    entirely above P. include: 1 if the slice starts above P (the containing slice too, Fig. 7)."""
    if mode == 0:
        w = (pz - z_low) / thick
        return min(max(w, 0.0), 1.0)
    elif mode == 1:
        return 1.0 if pz >= z_low else 0.0
    return 1.0 if pz > z_top else 0.0


# =====================================================================================
# 6. Eye pass (Sec. 3.5): per point, all slices between it and the light
# =====================================================================================
@kernel(nogil=True)
def eye_pass(
    tslot, pts, sp, z_planes, slot, bbox, filt, combine, self_mode, max_aniso, pyr, offs, sizes, nb, sat, out, nslot=1
):
    """V for every point ``pts`` (K,3) world. ``slot[k]`` is the index of slice k in the filtered
    arrays, -1 for an empty slice (skipped: its occlusion is 0). ``bbox[slot]`` = (x0, x1, y0, y1)
    texel bounds of the slice's occupied texels: a kernel whose filter support (the rectangle,
    widened by what the N-Buffer boxes or the mipmap probes read beyond it) misses them has
    occlusion 0 and is skipped, so the result is unchanged. Run by ``run_slots``, one slot per thread.

    Points go in blocks of 64 (consecutive eye pixels: neighbouring kernels), dealt round-robin to
    the slots, and each block visits the slices in the outer loop: one slice's texels stay in cache
    over the block and the culling branch follows the image's coherence. Every point still
    combines its slices in order (the same products, the same V)."""
    n = z_planes.shape[0] - 1
    thick = (z_planes[n] - z_planes[0]) / n
    # per slice plane, the constants of kernel_rect's map to texels (no division per point)
    kx = np.empty(n)
    ky = np.empty(n)
    for k in range(n):
        D = sp[14] + z_planes[k + 1]
        kx[k] = sp[19] / ((sp[16] - sp[15]) * D)
        ky[k] = sp[20] / ((sp[18] - sp[17]) * D)
    ox = sp[15] * sp[19] / (sp[16] - sp[15])
    oy = sp[18] * sp[20] / (sp[18] - sp[17])
    # per point of the block: light-frame position, 1 / pz, running combination, slices left
    bx = np.empty(64)
    by = np.empty(64)
    bz = np.empty(64)
    bi = np.empty(64)
    bacc = np.empty(64)
    live = np.empty(64, np.bool_)
    # per point of the block on the current slice: kernel rectangle, weight, whether to look up
    rx0 = np.empty(64)
    rx1 = np.empty(64)
    ry0 = np.empty(64)
    ry1 = np.empty(64)
    rw = np.empty(64)
    hit = np.empty(64, np.bool_)
    acc0 = 1.0 if combine == 0 else 0.0
    npts = pts.shape[0]
    nblock = (npts + 63) // 64  # blocks of 64 dealt round-robin to one slot per thread
    for blk in range(tslot, nblock, nslot):
        i0 = blk * 64
        m = min(npts, i0 + 64) - i0
        # bounds over the block's points in front of the light: px / pz, py / pz, 1 / pz, pz
        zmax = 0.0
        umin = np.inf
        umax = -np.inf
        vmin = np.inf
        vmax = -np.inf
        imin = np.inf
        imax = 0.0
        for c in range(m):
            i = i0 + c
            qx = pts[i, 0] - sp[0]
            qy = pts[i, 1] - sp[1]
            qz = pts[i, 2] - sp[2]
            px = qx * sp[3] + qy * sp[4] + qz * sp[5]
            py = qx * sp[6] + qy * sp[7] + qz * sp[8]
            pz = qx * sp[9] + qy * sp[10] + qz * sp[11]
            bx[c] = px
            by[c] = py
            bz[c] = pz
            bacc[c] = acc0
            # at or behind the light plane: nothing lies between P and the light (V = 1)
            live[c] = pz > 0.0
            bi[c] = 1.0 / pz if pz > 0.0 else 0.0
            if pz > 0.0:
                ip = bi[c]
                umin = min(umin, px * ip)
                umax = max(umax, px * ip)
                vmin = min(vmin, py * ip)
                vmax = max(vmax, py * ip)
                imin = min(imin, ip)
                imax = max(imax, ip)
                zmax = max(zmax, pz)
        for k in range(n):
            if z_planes[k] >= zmax:
                break  # this slice and all later ones are below every point of the block
            s = slot[k]
            if s < 0:
                continue
            zt = z_planes[k]
            zl = z_planes[k + 1]
            b0 = bbox[s, 0]
            b1 = bbox[s, 1]
            b2 = bbox[s, 2]
            b3 = bbox[s, 3]
            if filt != 0:
                # the whole block at once: every point's rectangle (centre (px, py) zl / pz, half sizes
                # (hu, hv) |1 - zl / pz|, mapped by kx, ky) widened by the margin below (at most half
                # its side + 1.5) lies in these bounds, pushed out by far more than rounding; when they
                # miss the occupied texels so does every point's test below (same lookups, same V)
                am = max(abs(1.0 - zl * imin), abs(1.0 - zl * imax))
                ex = 2.0 * sp[12] * am * kx[k] + 1.5
                ey = 2.0 * sp[13] * am * ky[k] + 1.5
                cxa = umin * zl * kx[k] - ox
                cxb = umax * zl * kx[k] - ox
                cya = oy - vmax * zl * ky[k]
                cyb = oy - vmin * zl * ky[k]
                tol = 1e-3 + 1e-9 * (abs(cxa) + abs(cxb) + abs(cya) + abs(cyb) + ex + ey + abs(ox) + abs(oy))
                if cxb + ex + tol < b0 or cxa - ex - tol > b1 or cyb + ey + tol < b2 or cya - ey - tol > b3:
                    continue
            # the kernels of the block's points on this slice and their culling, branch-free (vectorizes)
            for c in range(m):
                pz = bz[c]
                w = slice_weight(pz, zt, zl, thick, self_mode)
                x0, x1, y0, y1 = _kernel_rect_fast(bx[c], by[c], pz, bi[c], zl, sp[12], sp[13], kx[k], ky[k], ox, oy)
                # the larger N-Buffer box is at most twice the short side, +1 bilinear; the exact box 1;
                # the mipmap probes' reach is tested below
                mg = 0.5 * min(x1 - x0, y1 - y0) + 1.5 if filt == 1 else 1.0
                miss = (x1 + mg < b0) | (x0 - mg > b1) | (y1 + mg < b2) | (y0 - mg > b3)
                rx0[c] = x0
                rx1[c] = x1
                ry0[c] = y0
                ry1[c] = y1
                rw[c] = w
                hit[c] = live[c] & (zt < pz) & (w > 0.0) & ((filt == 0) | ~miss)
            for c in range(m):
                if not hit[c]:
                    continue
                x0 = rx0[c]
                x1 = rx1[c]
                y0 = ry0[c]
                y1 = ry1[c]
                if filt == 0:  # probes inside the rectangle read +-1.5 texels of their upper level
                    mg = _mip_support(x0, x1, y0, y1, max_aniso, offs.shape[0])
                    if x1 + mg < b0 or x0 - mg > b1 or y1 + mg < b2 or y0 - mg > b3:
                        continue
                    o = lookup_mipmap(pyr, s, offs, sizes, max_aniso, x0, x1, y0, y1)
                elif filt == 1:
                    o = _lookup_nbuffers(nb, s, max_aniso, x0, x1, y0, y1)
                else:
                    o = lookup_sat(sat, s, x0, x1, y0, y1)
                o = min(max(o, 0.0), 1.0)
                a = combine_occlusion(bacc[c], rw[c] * o, combine)
                bacc[c] = a
                if combine == 0 and a <= 0.0:
                    live[c] = False  # product already 0
        for c in range(m):
            out[i0 + c] = finish_visibility(bacc[c], combine) if bz[c] > 0.0 else 1.0


def nbuffer_levels_needed(setup: SlicingSetup, pz_max: float) -> int:
    """Highest N-Buffer level any lookup can use: floor(log2(widest kernel in texels)) + 1, the
    widest kernel being that of the farthest eye point on each slice plane (Eq. 4)."""
    zs = setup.z_planes[1:]
    hu, hv = setup.half
    l, r, b, t = setup.view.window
    S = setup.view.width
    a = np.abs(pz_max - zs) / max(pz_max, 1e-12)
    a = np.maximum(a, (zs - setup.z_planes[:-1]) / np.maximum(setup.z_planes[:-1], 1e-12))  # "include" mode
    D = setup.d + zs
    wx = 2 * hu * a / ((r - l) * D / S)
    wy = 2 * hv * a / ((t - b) * D / S)
    wmax = float(np.max(np.minimum(wx, wy)))  # N-Buffer squares use the short side
    full = int(round(math.log2(S)))
    if wmax <= 1.0:
        return min(1, full)
    return int(min(full, math.floor(math.log2(wmax)) + 1))


def prefilter(
    tex_used: np.ndarray,
    filt: str,
    setup: SlicingSetup | None = None,
    pz_max: float | None = None,
    bounds: np.ndarray | None = None,
):
    """Run the selected prefilter on the non-empty textures (``bounds``: their
    :func:`occupied_bounds`, if known); returns the lookup arrays and stats."""
    e32 = np.zeros((1, 1), np.float32)
    pyr, offs, sizes = e32, np.zeros(1, np.int64), np.ones(1, np.int64)
    nb = np.zeros((1, 1, 1, 1), np.float32)
    sat = np.zeros((1, 2, 2), np.int32)
    st = {}
    if filt == "mipmap":
        pyr, offs, sizes = prefilter_mipmap(tex_used)
        st["mip_levels"] = int(len(sizes))
    elif filt == "nbuffers":
        lv = None if setup is None or pz_max is None else nbuffer_levels_needed(setup, pz_max)
        nb = prefilter_nbuffers(tex_used, lv, bounds)
        st["nbuffer_levels"] = int(nb.shape[1] - 1)
    else:
        sat = prefilter_sat(tex_used)
    return (pyr, offs, sizes, nb, sat), st


def occlusion_visibility(
    light,
    flat,
    points,
    slices=16,
    texture_size=256,
    filter="nbuffers",
    combine="product",
    cop_distance=0.0,
    leak_fix=False,
    anisotropy=16,
    self_shadow="fade",
    timer=None,
    scene_bounds=None,
):
    """The whole method on arbitrary points: V (K,) float64 and stats. ``flat`` is the scene's
    FlatGeometry (occluders = faces of role both|occluder); ``points`` (K,3) world points to shade
    (they also enter the frustum fit): float64, or float32 as an eye G-buffer's positions are, read
    as they are (a point with a NaN, a pixel without a surface, gets V = 1 and leaves the fit).
    ``timer`` (optional) gets the phases slicing / prefilter / eye_pass."""
    from contextlib import contextmanager, nullcontext

    own: dict = {}

    @contextmanager
    def phase(name):
        t = time.perf_counter()
        with timer.phase(name) if timer is not None else nullcontext():
            yield
        own[name] = time.perf_counter() - t

    stats: dict = {}
    if light.shape == "sphere":
        from ..scene.types import sphere_to_rect

        lo, hi = scene_bounds if scene_bounds is not None else (flat.vertices.min(0), flat.vertices.max(0))
        light = sphere_to_rect(light, direction=(np.asarray(lo) + np.asarray(hi)) / 2 - light.center)
        stats["light_approximation"] = "sphere as equal-area square"
    pos = _points_array(points)

    # 1. slicing
    with phase("slicing"):
        # per geometry, not per frame (np.unique over every occluder corner: ~0.3 s at 1.3 M triangles)
        occ_faces = flat.faces_where(flat.occluder)
        occ_pts = flat.cached(("occluder_vertices",), lambda: _occluder_vertices(flat.vertices, occ_faces))
        setup = fit_slicing_view(light, occ_pts, pos, int(texture_size), int(slices), float(cop_distance))
        bounds = np.empty((setup.slices, 4))
        tex, nfrag = slice_scene(setup, flat.vertices, occ_faces, bool(leak_fix), bounds)
        nonempty = bounds[:, 1] > bounds[:, 0]  # a slice with a texel set
        slot = np.full(tex.shape[0], -1, np.int64)
        slot[nonempty] = np.arange(int(nonempty.sum()))
        tex_used = tex if nonempty.all() else np.ascontiguousarray(tex[nonempty])
        bbox = np.ascontiguousarray(bounds[nonempty])
    # 2. prefiltering
    with phase("prefilter"):
        pz_max = max(float(setup.z_planes[-1]), setup.depth)  # bounds the N-Buffer levels needed
        arrays, pst = prefilter(tex_used, filter, setup, pz_max, bbox)
    # 3-6. eye pass
    with phase("eye_pass"):
        vis = np.ones(len(pos), np.float64)
        if len(pos) and len(tex_used):
            pyr, offs, sizes, nb, sat = arrays
            run_threads(
                eye_pass,
                pos,
                setup.params(),
                setup.z_planes,
                slot,
                bbox,
                _FILTER_ID[filter],
                _COMBINE_ID[combine],
                _SELF_ID[self_shadow],
                int(anisotropy),
                pyr,
                offs,
                sizes,
                nb,
                sat,
                vis,
            )

    l, r, b, t = setup.view.window
    stats.update(
        {
            "slices": int(slices),
            "slices_used": int(nonempty.sum()),
            "fragments": int(nfrag),
            "cop_distance": float(setup.d),
            "fov_deg": float(np.degrees(2 * np.arctan(max(r - l, t - b) / 2))),
            "texel_size": [
                float(setup.view.pixel_size_at(setup.d + setup.z_planes[1])),
                float(setup.view.pixel_size_at(setup.d + setup.z_planes[-1])),
            ],
            "slice_range": [float(setup.z_planes[0]), float(setup.z_planes[-1])],
            "slicing_s": own["slicing"],
            "prefilter_s": own["prefilter"],
            f"prefilter_s_{filter}": own["prefilter"],
            "eye_pass_s": own["eye_pass"],
        }
    )
    stats.update(pst)
    return vis, stats


@register
class OcclusionTextures(Method):
    name = "occlusion-textures"
    light_shapes = ("rect", "sphere")
    summary = (
        "Eisemann & Décoret 2006: scene sliced into binary occlusion textures, prefiltered "
        "(mipmap / N-Buffers / SAT), box-filtered per slice (Eq. 4) and combined as a product (Eq. 5)"
    )
    paper = "eisemann2006-occlusion-textures"
    light_view = True  # maps from the light's centre (limits: softshadows.limits)
    params = (
        Param("slices", 16, "number of slices parallel to the light (paper: 4-16)", min=1, max=64),
        Param(
            "texture_size",
            256,
            "occlusion texture resolution (square, power of two; the paper's Fig. 10: 512, "
            "2x slower here for no better error: docs/results/speed-targets.md)",
            choices=TEXTURE_SIZES,
        ),
        Param(
            "filter", "nbuffers", "prefilter: mipmap (anisotropic), nbuffers, sat (summed-area table)", choices=FILTERS
        ),
        Param("combine", "product", "combination of the slices: product (Eq. 5), max, sum (clamped)", choices=COMBINES),
        Param(
            "cop_distance",
            0.0,
            "distance d of the centre of projection behind the light; 0 = automatic "
            "(largest d whose frustum fitted to the light contains the scene)",
            min=0.0,
        ),
        Param("leak_fix", False, "light-leak fix for thin occluders: also mark the next slice (Fig. 6)"),
        Param(
            "anisotropy",
            16,
            "maximum anisotropy (mipmap probes; N-Buffer squares per rectangular kernel)",
            min=1,
            max=64,
        ),
        Param(
            "self_shadow",
            "fade",
            "slice containing P: fade (paper), skip (hard skip, seams), include (self-shadowing, Fig. 7)",
            choices=SELF_SHADOW,
        ),
    )

    #: what `softshadows pareto` sweeps (Method.sweep)
    sweep: ClassVar = {"slices": [4, 8, 16], "texture_size": [128, 256, 512]}

    def run(
        self,
        ctx,
        slices=16,
        texture_size=256,
        filter="nbuffers",
        combine="product",
        cop_distance=0.0,
        leak_fix=False,
        anisotropy=16,
        self_shadow="fade",
    ) -> MethodOutput:
        # straight over the eye G-buffer (NaN where no surface: V = 1 there, as ctx.scatter fills)
        g = ctx.eye
        vis, stats = occlusion_visibility(
            ctx.light,
            ctx.flat,
            g.position.reshape(-1, 3),
            slices,
            texture_size,
            filter,
            combine,
            cop_distance,
            leak_fix,
            anisotropy,
            self_shadow,
            timer=ctx.timer,
            scene_bounds=ctx.scene.bounds(),
        )
        return MethodOutput(visibility=vis.astype(np.float32).reshape(g.mask.shape), stats=stats)
