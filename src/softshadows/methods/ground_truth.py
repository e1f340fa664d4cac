"""``ground-truth``: distribution ray tracing on the exact geometry with Embree (``embreex``).

For every eye pixel with a surface point p (recomputed in float64 on the triangle as Embree stores
it: :func:`hit_points`), occlusion rays from p, offset along its normal by a bound on the
floating-point error of p and of Embree's triangle test (pbrt-v4's ``OffsetRayOrigin``; no
scene-size fraction), to ``samples`` = N x N stratified, jittered points of the light (the
rectangle, or the sphere's disk facing the point) give V = unoccluded rays / N^2 (docs/design.md).
Jitter is a counter-based hash of (seed, pixel, sample), so the image does not depend on threading.

Steps, parameters, deviations and known limits: ``docs/methods/ground-truth.md``.
"""

from __future__ import annotations

import itertools
from typing import ClassVar

import numpy as np

from .._jit import kernel
from ..analytic import disk_facing_frame
from ..shading import exposure
from .base import Method, MethodOutput, Param, register

#: rays per chunk of trace_in_pipeline (see chunk_bounds)
CHUNK_RAYS = 1 << 18


def build_embree_scene(vertices: np.ndarray, faces: np.ndarray):
    """An Embree scene of the given triangles (float32)."""
    from embreex import mesh_construction, rtcore_scene

    sc = rtcore_scene.EmbreeScene()
    tris = np.ascontiguousarray(vertices[faces], dtype=np.float32)
    mesh_construction.TriangleMesh(sc, tris)
    return sc


_F32 = np.float32

#: how far past the disk's rim :func:`_concentric` may put a point, as a fraction of the radius
#: (float32 rounding of the map; tests/test_ground_truth.py measures it): _facing_class widens the
#: disk by it
DISK_SLACK = 2.0**-20


@kernel(inline=True)
def _concentric(a, b):
    """Shirley-Chiu concentric map of [0,1)^2 to the unit disk, in float32 (``a``, ``b`` and the
    result): with x, y = 2a - 1, 2b - 1, where |x| > |y| r = x and phi = pi/4 y/x, else r = y and
    phi = pi/2 - pi/4 x/y; so (r cos t, r sin t) or (r sin t, r cos t) with t = pi/4 q, q the smaller
    coordinate over the larger (one division). Without branches (selects), with Cephes' float32
    minimax polynomials for sin and cos on [-pi/4, pi/4], so that the loop over samples vectorises
    eight lanes wide. Within a few float32 ulps of the exact map of the same (a, b)
    (tests/test_ground_truth.py): the disk's points move by under 1e-6 of its radius, below the
    float32 rounding of the ray directions they end in."""
    x = _F32(2.0) * a - _F32(1.0)
    y = _F32(2.0) * b - _F32(1.0)
    big = abs(x) > abs(y)
    r = x if big else y
    t = _F32(np.pi / 4.0) * ((y if big else x) / r)
    z = t * t
    sn = t + t * z * (_F32(-1.6666654611e-1) + z * (_F32(8.3321608736e-3) + z * _F32(-1.9515295891e-4)))
    cs = (_F32(1.0) - _F32(0.5) * z) + z * z * (
        _F32(4.166664568298827e-2) + z * (_F32(-1.388731625493765e-3) + z * _F32(2.443315711809948e-5))
    )
    zero = (x == _F32(0.0)) & (y == _F32(0.0))
    dx = r * (cs if big else sn)
    dy = r * (sn if big else cs)
    return (_F32(0.0) if zero else dx), (_F32(0.0) if zero else dy)


@kernel(inline=True)
def _mix64(z):
    """splitmix64 finalizer: a well-mixed 64-bit hash."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@kernel(inline=True)
def point_key(seed, pixel):
    """The per-pixel half of the jitter hash (computed once per point)."""
    return _mix64(np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(pixel))


_M32 = np.uint64(0xFFFFFFFF)


@kernel(inline=True)
def _mix32(x):
    """A 32-bit integer finalizer (lowbias32) on the low 32 bits of a uint64 (Numba widens uint32
    products, so the wrap-around is explicit): cheap enough to run once per ray."""
    x &= _M32
    x ^= x >> np.uint64(16)
    x = (x * np.uint64(0x7FEB352D)) & _M32
    x ^= x >> np.uint64(15)
    x = (x * np.uint64(0x846CA68B)) & _M32
    x ^= x >> np.uint64(16)
    return x


@kernel(inline=True)
def _sample_salts(sample):
    """The per-sample halves of :func:`jitter_pair`'s hash (tabled once per call by
    :func:`generate_light_rays`)."""
    s = np.uint64(sample)
    return (s * np.uint64(0x9E3779B9)) & _M32, (s * np.uint64(0x85EBCA6B) + np.uint64(0x632BE59B)) & _M32


@kernel(inline=True)
def _salted_pair(key, salt_a, salt_b):
    """:func:`jitter_pair` from the point key and the sample's salts (:func:`_sample_salts`)."""
    ha = _mix32((key & _M32) ^ salt_a)
    hb = _mix32((key >> np.uint64(32)) ^ salt_b)
    return (ha >> np.uint64(8)) * (1.0 / 16777216.0), (hb >> np.uint64(8)) * (1.0 / 16777216.0)


@kernel(inline=True)
def jitter_pair(key, sample):
    """Two uniforms in [0,1) for (point key, sample): counter-based, so results do not depend
    on how pixels are split into chunks or threads. ``key`` = :func:`point_key` (seed, pixel)."""
    salt_a, salt_b = _sample_salts(sample)
    return _salted_pair(key, salt_a, salt_b)


#: a traced segment's end: the ray's direction runs from its origin to its light sample, and the
#: segment stops 1e-6 of that length short of the light (generate_light_rays)
RAY_END = 1.0 - 1e-6
#: unit roundoff of float32 (Embree's arithmetic) and float64 (our hit points)
U32 = 2.0**-24
U64 = 2.0**-53
#: factor over the first-order error bounds below (covers their O(u^2) terms, the reciprocal
#: Embree computes t with, and nothing else: it is not a tuning knob)
BOUND_SAFETY = 2.0


def hit_points(flat, eye, idx, nrm):
    """Hit points recomputed in float64 and their error bounds (docs/methods/ground-truth.md).

    For the eye pixels ``idx`` (flat indices into the G-buffer), with eye-facing normals ``nrm``
    (from :meth:`FrameContext.points`): the point ``p = b0 V0 + b1 V1 + b2 V2`` on the triangle
    *as Embree stores it* (float32 vertices, computed in float64 from the G-buffer's tri_id and
    barycentrics, b0 = 1 - b1 - b2), its unit geometric normal n (float64, turned like ``nrm``),
    and two distances along n, the terms of the ray-origin offset:

    * ``err_point``: the error of p itself: float64 rounding of the barycentric sum
      (gamma_5(u64) (sum_j |b_j V_j| + |V0|) per component) plus the float32 conversion of the
      origin Embree receives (u32 |p| per component), projected as pbrt's ``dot(|n|, pError)``;
    * ``err_embree``: a bound on the error of the signed distance that Embree's (robust, Pluecker)
      triangle test computes for an origin near the triangle: with R the largest distance from the
      origin to a vertex and A the area, u32 (4 R + 16 R^3 / A) (vertices relative to the origin
      and edges rounded, normal from a rounded cross product, |dN| <= 32 u32 R^2, then a rounded
      dot product);
    * ``grazing``: u32 (16 R^2 / A + 3): the error of the cosine between the computed normal and
      the ray, below which the sign of Embree's denominator (front or back) is not certain.

    Also ``own_blocks``: the pixel's triangle is an occluder (it is in the BVH), so a ray leaving
    its back side is blocked by it."""
    tri = eye.tri_id.ravel()[idx]
    bary = eye.bary.reshape(-1, 2)[idx]
    K = len(tri)
    p, n = np.empty((K, 3)), np.empty((K, 3))
    err_point, err_embree, grazing = np.empty(K), np.empty(K), np.empty(K)
    nrm = np.ascontiguousarray(nrm, dtype=np.float64)  # one specialisation
    _hit_points_kernel(flat.vertices, flat.faces, tri, bary, nrm, p, n, err_point, err_embree, grazing)
    own_blocks = flat.occluder[tri]
    return p, n, err_point, err_embree, grazing, own_blocks


@kernel(inline=True)
def _blocked_ray(dirs, dist, geo, q, nx, ny, nz):
    """Ray q is blocked by the pixel's own triangle: direction the normal (never traced: length 0),
    geometry term -1 (counted as occluded)."""
    dirs[q, 0] = nx
    dirs[q, 1] = ny
    dirs[q, 2] = nz
    dist[q] = 0.0
    geo[q] = -1.0


@kernel(inline=True)
def _ray_origin(px, py, pz, nx, ny, nz, off):
    """``p + off n`` rounded to float32 away from the surface (the next float32 outward where
    rounding to nearest came back toward it): pbrt's ``OffsetRayOrigin``."""
    ox = px + off * nx
    oy = py + off * ny
    oz = pz + off * nz
    ox32 = np.float32(ox)
    oy32 = np.float32(oy)
    oz32 = np.float32(oz)
    if (ox32 - ox) * nx < 0.0:
        ox32 = np.nextafter(ox32, np.float32(np.inf) if nx > 0.0 else np.float32(-np.inf))
    if (oy32 - oy) * ny < 0.0:
        oy32 = np.nextafter(oy32, np.float32(np.inf) if ny > 0.0 else np.float32(-np.inf))
    if (oz32 - oz) * nz < 0.0:
        oz32 = np.nextafter(oz32, np.float32(np.inf) if nz > 0.0 else np.float32(-np.inf))
    return ox32, oy32, oz32


@kernel(inline=True)
def _disk_frame(px, py, pz, center):
    """Unit vectors (w toward p, e1, e2) of the sphere light's disk facing p (:func:`disk_facing_frame`)."""
    f = disk_facing_frame(px - center[0], py - center[1], pz - center[2])
    return f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8]


@kernel(inline=True)
def _facing_class(px, py, pz, nx, ny, nz, g, shape, center, u, v, radius):
    """Where every sample of the light lies with respect to p's tangent plane: 1 when the cosine
    at p toward every sample is certainly above ``g`` (no sample needs the own-triangle test), -1
    when it is certainly negative (every sample leaves through the back), 0 otherwise. The cosine's
    numerator n . (s - p) is affine in s, so its extremes over the rectangle are at the corners
    (over the disk: within the radius of its value at the center); |s - p| <= |c - p| + the light's
    half-extent. The margins (1e-9 relative, and an absolute term for the rounding of s - p) are far
    above the rounding of the per-sample cosine, so the class never contradicts it."""
    cx, cy, cz = center[0] - px, center[1] - py, center[2] - pz
    d0 = nx * cx + ny * cy + nz * cz
    dc = np.sqrt(cx * cx + cy * cy + cz * cz)
    if shape == 1:
        ext = radius * (1.0 + DISK_SLACK)  # _concentric's points may lie that far past the rim
        half = ext
    else:
        ext = 0.5 * (abs(nx * u[0] + ny * u[1] + nz * u[2]) + abs(nx * v[0] + ny * v[1] + nz * v[2]))
        half = 0.5 * (
            np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]) + np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        )
    dmax_len = dc + half
    scale = dmax_len + abs(center[0]) + abs(center[1]) + abs(center[2]) + abs(px) + abs(py) + abs(pz) + half
    tol = 1e-9 * scale
    if d0 - ext > g * (1.0 + 1e-9) * dmax_len + tol:
        return 1
    if d0 + ext < -tol:
        return -1
    return 0


@kernel(inline=True)
def embree_coord(x):
    """A vertex coordinate as Embree holds it (float32), back in float64: the hit point's inputs
    (:func:`hit_point`, and ``irregular.error_bound_samples``, which computes the same points)."""
    return np.float64(np.float32(x))


@kernel(inline=True)
def hit_point(verts, faces, t, b1, b2, m0, m1, m2):
    """:func:`hit_points` for one point: triangle ``t``, barycentrics (b1, b2) as float64, eye-facing
    normal m. Returns (px, py, pz, nx, ny, nz, err_point, err_embree, grazing); each value is computed
    with the operations in the order the earlier NumPy version used, so the results are the same
    bits."""
    i0, i1, i2 = faces[t, 0], faces[t, 1], faces[t, 2]
    ax, ay, az = embree_coord(verts[i0, 0]), embree_coord(verts[i0, 1]), embree_coord(verts[i0, 2])
    bx, by, bz = embree_coord(verts[i1, 0]), embree_coord(verts[i1, 1]), embree_coord(verts[i1, 2])
    cx, cy, cz = embree_coord(verts[i2, 0]), embree_coord(verts[i2, 1]), embree_coord(verts[i2, 2])
    return hit_point_at(ax, ay, az, bx, by, bz, cx, cy, cz, b1, b2, m0, m1, m2)


@kernel(inline=True)
def hit_point_at(ax, ay, az, bx, by, bz, cx, cy, cz, b1, b2, m0, m1, m2):
    """:func:`hit_point` on the triangle's vertices (Embree's float32 values, as float64): no
    gather and no branch (the flip toward the eye is a select per component), so that a loop of it
    over contiguous arrays vectorizes (``irregular.error_bound_samples``)."""
    tiny = np.finfo(np.float64).tiny
    g5 = 5 * U64 / (1 - 5 * U64)
    b0 = 1.0 - b1 - b2
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    crx = e1y * e2z - e1z * e2y
    cry = e1z * e2x - e1x * e2z
    crz = e1x * e2y - e1y * e2x
    twice_area = np.sqrt(crx * crx + cry * cry + crz * crz)
    dn = max(twice_area, tiny)
    nx, ny, nz = crx / dn, cry / dn, crz / dn
    flip = nx * m0 + ny * m1 + nz * m2 < 0.0
    nx = -nx if flip else nx
    ny = -ny if flip else ny
    nz = -nz if flip else nz
    px = b0 * ax + b1 * bx + b2 * cx
    py = b0 * ay + b1 * by + b2 * cy
    pz = b0 * az + b1 * bz + b2 * cz
    ex = g5 * (abs(b0 * ax) + abs(b1 * bx) + abs(b2 * cx) + abs(ax))
    ey = g5 * (abs(b0 * ay) + abs(b1 * by) + abs(b2 * cy) + abs(ay))
    ez = g5 * (abs(b0 * az) + abs(b1 * bz) + abs(b2 * cz) + abs(az))
    ep = abs(nx) * (ex + U32 * abs(px)) + abs(ny) * (ey + U32 * abs(py)) + abs(nz) * (ez + U32 * abs(pz))
    area = max(0.5 * twice_area, tiny)
    ra = (ax - px) * (ax - px) + (ay - py) * (ay - py) + (az - pz) * (az - pz)
    rb = (bx - px) * (bx - px) + (by - py) * (by - py) + (bz - pz) * (bz - pz)
    rc = (cx - px) * (cx - px) + (cy - py) * (cy - py) + (cz - pz) * (cz - pz)
    R = np.sqrt(max(ra, rb, rc))  # (one square root: monotonic and correctly rounded, the same bits)
    q = R * R / area
    grazing = U32 * (16.0 * q + 3.0)
    ee = U32 * R * (4.0 + 16.0 * q)
    # the origin sits err_* above p: R grows by that much (one fixed-point step is enough, it is tiny)
    R = R + BOUND_SAFETY * (ep + ee)
    q = R * R / area
    return px, py, pz, nx, ny, nz, ep, U32 * R * (4.0 + 16.0 * q), grazing


@kernel
def _hit_points_kernel(verts, faces, tri, bary, nrm, p, n, err_point, err_embree, grazing):
    # serial: a parallel version compiled twice as long and was no faster (a few ms at 512^2)
    for k in range(tri.shape[0]):
        px, py, pz, nx, ny, nz, ep, ee, gr = hit_point(
            verts, faces, tri[k], np.float64(bary[k, 0]), np.float64(bary[k, 1]), nrm[k, 0], nrm[k, 1], nrm[k, 2]
        )
        p[k, 0], p[k, 1], p[k, 2] = px, py, pz
        n[k, 0], n[k, 1], n[k, 2] = nx, ny, nz
        err_point[k] = ep
        err_embree[k] = ee
        grazing[k] = gr


@kernel(nogil=True)
def generate_light_rays(
    pts, nrm, pix, off, grazing, own_blocks, seed, n_side, shape, center, u, v, radius, org, dirs, dist, geo, need_geo
):
    """Fill origins/directions/lengths for len(pts) points x n_side^2 samples (sample s of point k
    at row k*S+s). geo = cos_p * cos_l / r^2 when ``need_geo`` (the physical mode), else 0. ``pix``: global pixel ids
    seeding the jitter.

    A ray's direction is the vector from its origin to its light sample, not normalized, and its
    length :data:`RAY_END` (Embree measures t in units of the direction): the segment ends 1e-6 of
    its length before the light, without a square root and a division per ray.

    Ray origins (pbrt's ``OffsetRayOrigin``, :func:`_ray_origin`): ``p + off[k] n``, n the normal on
    the side the ray leaves to, rounded to float32 away from the surface. ``off``: the error bound of
    :func:`hit_points`. A ray that leaves the surface on the side the eye does not see
    (cos_p <= ``grazing[k]``, the float32 resolution of that side) is blocked by the surface itself
    when the surface is an occluder (``own_blocks``): it is not traced (length 0) and marked with
    geo = -1.

    Per point, the jittered light samples are computed first (``jitter_pair`` with its per-sample
    constants tabled once per call), then the rays, in loops without branches that the compiler
    vectorises (the rows of ``org`` and ``dirs`` written through flat views, at a stride of 3 the
    compiler knows: interleaved vector stores instead of six scalar ones per ray); the per-sample
    cosine at p is computed only where it is needed (the physical mode, or an occluder point that
    :func:`_facing_class` cannot put wholly in front of or behind its tangent plane). Serial:
    trace_in_pipeline runs one chunk per thread."""
    S = n_side * n_side
    # per-sample halves of jitter_pair's hash, and the stratum of each sample
    cell_a = np.empty(S)
    cell_b = np.empty(S)
    salt_a = np.empty(S, np.uint64)
    salt_b = np.empty(S, np.uint64)
    for i in range(n_side):
        for j in range(n_side):
            s = i * n_side + j
            cell_a[s] = i
            cell_b[s] = j
            salt_a[s], salt_b[s] = _sample_salts(s)
    nsf = float(n_side)
    ja = np.empty(S)
    jb = np.empty(S)
    sx = np.empty(S)
    sy = np.empty(S)
    sz = np.empty(S)
    ja32 = np.empty(S, np.float32)
    jb32 = np.empty(S, np.float32)
    dx32 = np.empty(S, np.float32)
    dy32 = np.empty(S, np.float32)
    orgf = org.reshape(org.size)  # flat views: rows of 3 at a constant stride (the stores vectorise)
    dirf = dirs.reshape(dirs.size)
    lnx, lny, lnz = 0.0, 0.0, 0.0
    if shape != 1:
        lnx = u[1] * v[2] - u[2] * v[1]
        lny = u[2] * v[0] - u[0] * v[2]
        lnz = u[0] * v[1] - u[1] * v[0]
        ll = np.sqrt(lnx * lnx + lny * lny + lnz * lnz)
        lnx /= ll
        lny /= ll
        lnz /= ll
    for k in range(pts.shape[0]):
        px, py, pz = pts[k, 0], pts[k, 1], pts[k, 2]
        nx, ny, nz = nrm[k, 0], nrm[k, 1], nrm[k, 2]
        ox32, oy32, oz32 = _ray_origin(px, py, pz, nx, ny, nz, off[k])
        base = k * S
        cls = _facing_class(px, py, pz, nx, ny, nz, grazing[k], shape, center, u, v, radius) if own_blocks[k] else 1
        if cls == -1:  # every sample leaves through the back of the pixel's own (occluder) triangle
            for s in range(S):
                q = base + s
                org[q, 0] = ox32
                org[q, 1] = oy32
                org[q, 2] = oz32
                _blocked_ray(dirs, dist, geo, q, nx, ny, nz)
            continue
        # the stratified, jittered point (a, b) of every sample (jitter_pair, vectorised), then
        # the light's point; the disk's in float32 (eight lanes), through float32 (a, b)
        key = point_key(seed, pix[k])
        if shape == 1:  # sphere: disk facing p
            for s in range(S):
                fa, fb = _salted_pair(key, salt_a[s], salt_b[s])
                ja32[s] = _F32((cell_a[s] + fa) / nsf)
                jb32[s] = _F32((cell_b[s] + fb) / nsf)
            for s in range(S):
                dx32[s], dy32[s] = _concentric(ja32[s], jb32[s])
            wx, wy, wz, e1x, e1y, e1z, e2x, e2y, e2z = _disk_frame(px, py, pz, center)
            lnx, lny, lnz = wx, wy, wz
            for s in range(S):
                dx, dy = np.float64(dx32[s]), np.float64(dy32[s])
                sx[s] = center[0] + radius * (dx * e1x + dy * e2x)
                sy[s] = center[1] + radius * (dx * e1y + dy * e2y)
                sz[s] = center[2] + radius * (dx * e1z + dy * e2z)
        else:
            for s in range(S):
                fa, fb = _salted_pair(key, salt_a[s], salt_b[s])
                ja[s] = (cell_a[s] + fa) / nsf
                jb[s] = (cell_b[s] + fb) / nsf
            for s in range(S):
                a = ja[s]
                b = jb[s]
                sx[s] = center[0] + (a - 0.5) * u[0] + (b - 0.5) * v[0]
                sy[s] = center[1] + (a - 0.5) * u[1] + (b - 0.5) * v[1]
                sz[s] = center[2] + (a - 0.5) * u[2] + (b - 0.5) * v[2]
        if cls == 1 and not need_geo:  # the common case: every ray traced, no cosine needed
            # unsigned indices (no negative-index wrap-around) at a stride of 3: this loop vectorises
            # with interleaved stores into the rows Embree's wrapper reads
            ub = np.uint64(3 * base)
            for s in range(S):
                dist[base + s] = RAY_END
                geo[base + s] = 0.0
                q = ub + np.uint64(3) * np.uint64(s)
                orgf[q] = ox32
                orgf[q + np.uint64(1)] = oy32
                orgf[q + np.uint64(2)] = oz32
                dirf[q] = sx[s] - ox32
                dirf[q + np.uint64(1)] = sy[s] - oy32
                dirf[q + np.uint64(2)] = sz[s] - oz32
            continue
        check = own_blocks[k] and cls != 1
        g = grazing[k]
        for s in range(S):
            q = base + s
            # cosine at p toward the sample (from p itself: the side the ray leaves to)
            qx, qy, qz = sx[s] - px, sy[s] - py, sz[s] - pz
            ql = np.sqrt(qx * qx + qy * qy + qz * qz)
            cp = (nx * qx + ny * qy + nz * qz) / ql
            org[q, 0] = ox32
            org[q, 1] = oy32
            org[q, 2] = oz32
            if check and cp <= g:
                # leaves through the back of the pixel's own (occluder) triangle: blocked
                _blocked_ray(dirs, dist, geo, q, nx, ny, nz)
                continue
            rx, ry, rz = sx[s] - ox32, sy[s] - oy32, sz[s] - oz32
            dirs[q, 0] = rx
            dirs[q, 1] = ry
            dirs[q, 2] = rz
            dist[q] = RAY_END
            if need_geo:
                ri = 1.0 / np.sqrt(rx * rx + ry * ry + rz * rz)
                cl = -(lnx * rx + lny * ry + lnz * rz) * ri
                geo[q] = max(cp, 0.0) * max(cl, 0.0) * ri * ri
            else:
                geo[q] = 0.0


@kernel(nogil=True)
def reduce_visibility(hits, geo, S, vis, irr, offset, need_geo):
    """vis[k] = unoccluded fraction; irr[k] = sum of geo over unoccluded samples / S when
    ``need_geo`` (else 0: geo is 0 on every traced ray). Samples with geo < 0 are blocked without
    tracing, see :func:`generate_light_rays`. The count is a branch-free (vectorised) loop; the
    irradiance sum keeps its sample order."""
    n = hits.shape[0] // S
    for k in range(n):
        c = 0
        for s in range(S):  # embree: -1 = not occluded; geo -1: blocked
            c += (hits[k * S + s] < 0) & (geo[k * S + s] >= 0.0)
        vis[offset + k] = c / S
        e = 0.0
        if need_geo:
            for s in range(S):
                if hits[k * S + s] < 0 and geo[k * S + s] >= 0.0:
                    e += geo[k * S + s]
        irr[offset + k] = e / S


def chunk_bounds(K: int, S: int, nthreads: int) -> list[int]:
    """Point indices where the chunks of K points x S samples start, and K at the end, for
    ``nthreads`` threads taking chunks in turn. Guided sizes: about CHUNK_RAYS rays (embreex's
    ``run`` costs a few microseconds per call and the Python around a chunk some tens, under 1% of
    a chunk's milliseconds of tracing), shrinking to the remaining rays / (2 nthreads) toward the
    end, but not below CHUNK_RAYS / 16, so that the threads finish together."""
    big = max(1, CHUNK_RAYS // S)
    small = max(1, CHUNK_RAYS // (16 * S))
    bounds = [0]
    while bounds[-1] < K:
        left = K - bounds[-1]
        bounds.append(bounds[-1] + min(left, max(small, min(big, left // (2 * nthreads)))))
    return bounds


def run_on_threads(nthreads: int, n_items: int, work) -> None:
    """``work(item, slot)`` for item in range(n_items) on ``nthreads`` Python threads that take the
    next item as they finish one (slot: the thread's index, for its own buffers). ``work`` must
    release the GIL for its long parts (Numba ``nogil`` kernels, embreex's ``run``)."""
    import itertools
    import threading

    nthreads = max(1, min(nthreads, n_items))
    counter = itertools.count()  # next() on a count is atomic under the GIL
    errors = []

    def loop(slot):
        try:
            while (i := next(counter)) < n_items and not errors:
                work(i, slot)
        except BaseException as e:  # re-raised in the caller
            errors.append(e)

    if nthreads == 1:
        loop(0)
    else:
        threads = [threading.Thread(target=loop, args=(t,), daemon=True) for t in range(nthreads)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    if errors:
        raise errors[0]


def trace_in_pipeline(
    esc, pts, nrm, pix, off, grazing, own_blocks, seed, n_side, light, vis, irr, progress=False, physical=False
):
    """Generate, trace and reduce rays chunk by chunk on every core: one Python thread per Numba
    thread (``numba.get_num_threads()``) takes chunks in turn (:func:`run_on_threads`) and runs ray
    generation, Embree's ``run`` and the reduction on each, in buffers of its own allocated once.
    All three release the GIL (the kernels are serial Numba ``nogil`` kernels, so this is safe
    under any threading layer; embreex releases it while tracing), so the threads trace in
    parallel. Each chunk writes its own slice of ``vis``/``irr`` and the jitter hashes (seed,
    pixel, sample), so the output does not depend on the thread count.
    Returns (trace, generation, reduction) seconds summed over threads, and the wall time."""
    import threading
    import time

    import numba

    S = n_side * n_side
    K = len(pts)
    shape, center, u, v, radius = light_arrays(light)
    nthreads = max(1, numba.get_num_threads())
    bounds = chunk_bounds(K, S, nthreads)
    n_chunks = len(bounds) - 1
    nthreads = max(1, min(nthreads, n_chunks))
    rows = max(b - a for a, b in itertools.pairwise(bounds)) * S if n_chunks else 0
    bufs = [
        (
            np.empty((rows, 3), np.float32),
            np.empty((rows, 3), np.float32),
            np.empty(rows, np.float32),
            np.empty(rows, np.float32),
        )
        for _ in range(nthreads)
    ]
    times = [[0.0, 0.0, 0.0] for _ in range(nthreads)]  # per thread: gen, trace, reduce
    lock = threading.Lock()
    bar = None
    if progress and K * S > 4_000_000:
        from tqdm import tqdm

        bar = tqdm(total=K * S, unit="ray", unit_scale=True, desc="ground truth", leave=False)

    def chunk(c, slot):
        t0 = time.perf_counter()
        start, stop = bounds[c], bounds[c + 1]
        n = (stop - start) * S
        org, dirs, dist, geo = (b[:n] for b in bufs[slot])
        generate_light_rays(
            pts[start:stop],
            nrm[start:stop],
            pix[start:stop],
            off[start:stop],
            grazing[start:stop],
            own_blocks[start:stop],
            seed,
            n_side,
            shape,
            center,
            u,
            v,
            radius,
            org,
            dirs,
            dist,
            geo,
            physical,
        )
        t1 = time.perf_counter()
        hits = esc.run(org, dirs, dists=dist, query="OCCLUDED")
        t2 = time.perf_counter()
        reduce_visibility(hits, geo, S, vis, irr, start, physical)
        t3 = time.perf_counter()
        tt = times[slot]
        tt[0] += t1 - t0
        tt[1] += t2 - t1
        tt[2] += t3 - t2
        if bar is not None:
            with lock:
                bar.update(n)

    t_wall = time.perf_counter()
    run_on_threads(nthreads, n_chunks, chunk)
    t_wall = time.perf_counter() - t_wall
    if bar is not None:
        bar.close()
    gen_t, trace_t, red_t = (sum(t[i] for t in times) for i in range(3))
    return trace_t, gen_t, red_t, t_wall


def light_arrays(light):
    if light.shape == "rect":
        return 0, light.center, light.u, light.v, 0.0
    z = np.zeros(3)
    return 1, light.center, z, z, light.radius


@register
class GroundTruth(Method):
    name = "ground-truth"
    light_shapes = ("rect", "sphere")
    summary = "Embree occlusion rays to N x N stratified jittered light samples (reference)"
    paper = "distribution ray tracing (Cook et al. 1984) with Embree"
    params = (
        Param(
            "samples",
            256,
            "light samples per pixel (a perfect square: N x N strata)",
            min=1,
            max=65536,
            check=lambda n: None if round(n**0.5) ** 2 == n else "a perfect square (N x N strata)",
        ),
        Param("physical", False, "image = full area-light integral (cosines, 1/r^2) per sample"),
        Param(
            "offset",
            0.0,
            "extra ray-origin offset along the normal, x scene diagonal, added to the float error bound "
            "(0: the bound alone; for studies)",
            min=0.0,
        ),
    )

    #: what `softshadows pareto` sweeps (Method.sweep)
    sweep: ClassVar = {"samples": [1, 4, 16, 64]}

    def run(self, ctx, samples, physical, offset):
        n_side = int(round(np.sqrt(samples)))
        scene = ctx.scene
        _, nrm_eye, idx = ctx.points()
        with ctx.timer.phase("ray_origins"):
            pts, nrm, err_point, err_embree, grazing, own_blocks = hit_points(ctx.flat, ctx.eye, idx, nrm_eye)
            off = BOUND_SAFETY * (err_point + err_embree)
            if offset > 0.0:
                lo, hi = scene.bounds()
                off = off + offset * float(np.linalg.norm(hi - lo))
            grazing = BOUND_SAFETY * grazing
        with ctx.timer.phase("bvh_build"):
            esc = _embree_for(scene)
        S = samples
        K = len(pts)
        vis = np.zeros(K, np.float32)
        irr = np.zeros(K, np.float64)
        trace_t, gen_t, red_t, wall = trace_in_pipeline(
            esc,
            pts,
            nrm,
            idx,
            off,
            grazing,
            own_blocks,
            ctx.seed,
            n_side,
            scene.light,
            vis,
            irr,
            progress=ctx.progress,
            physical=physical,
        )
        # generation and reduction overlap tracing: the phase is their wall time; parts go to stats
        ctx.timer.times["rays"] = ctx.timer.times.get("rays", 0.0) + wall
        t_trace = wall
        out = ctx.scatter(vis, idx)
        stats = {
            "samples": S,
            "rays": int(K * S),
            "points": int(K),
            "origin_offset_median": float(np.median(off)) if K else 0.0,
            "origin_offset_max": float(np.max(off)) if K else 0.0,
            "rays_per_second": float(K * S / t_trace) if t_trace > 0 else float("nan"),
            "trace_seconds": trace_t,
            "ray_generation_seconds": gen_t,
            "reduce_seconds": red_t,
        }
        shadowed = None
        if physical:
            radiance = scene.light.intensity / scene.light.area
            shadowed = np.full(out.size, np.nan)  # float64: the irradiance sum's precision
            shadowed[idx] = irr * radiance * scene.light.area * exposure(scene)
            shadowed = shadowed.reshape(out.shape)
        return MethodOutput(out, stats, direct_shadowed=shadowed)


_EMBREE_CACHE: dict = {}


def _embree_for(scene):
    """Embree scene for a Scene, cached on the Scene object's identity (BVH built once per scene)."""
    key = id(scene)
    hit = _EMBREE_CACHE.get(key)
    if hit is not None and hit[0] is scene:
        return hit[1]
    flat = scene.flat
    esc = build_embree_scene(flat.vertices, flat.faces[flat.occluder])
    _EMBREE_CACHE.clear()
    _EMBREE_CACHE[key] = (scene, esc)
    return esc
