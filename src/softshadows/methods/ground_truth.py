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

from typing import ClassVar

import numpy as np
from numba import prange

from .._jit import kernel
from ..shading import exposure
from .base import Method, MethodOutput, Param, register

CHUNK_RAYS = 1 << 20


def build_embree_scene(vertices: np.ndarray, faces: np.ndarray):
    """An Embree scene of the given triangles (float32)."""
    from embreex import mesh_construction, rtcore_scene

    sc = rtcore_scene.EmbreeScene()
    tris = np.ascontiguousarray(vertices[faces], dtype=np.float32)
    mesh_construction.TriangleMesh(sc, tris)
    return sc


@kernel(inline=True)
def _concentric(a, b):
    """Shirley-Chiu concentric map of [0,1)^2 to the unit disk."""
    x = 2.0 * a - 1.0
    y = 2.0 * b - 1.0
    if x == 0.0 and y == 0.0:
        return 0.0, 0.0
    if abs(x) > abs(y):
        r = x
        phi = (np.pi / 4.0) * (y / x)
    else:
        r = y
        phi = np.pi / 2.0 - (np.pi / 4.0) * (x / y)
    return r * np.cos(phi), r * np.sin(phi)


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
def jitter_pair(key, sample):
    """Two uniforms in [0,1) for (point key, sample): counter-based, so results do not depend
    on how pixels are split into chunks or threads. ``key`` = :func:`point_key` (seed, pixel)."""
    s = np.uint64(sample)
    ha = _mix32((key & _M32) ^ ((s * np.uint64(0x9E3779B9)) & _M32))
    hb = _mix32((key >> np.uint64(32)) ^ ((s * np.uint64(0x85EBCA6B) + np.uint64(0x632BE59B)) & _M32))
    return (ha >> np.uint64(8)) * (1.0 / 16777216.0), (hb >> np.uint64(8)) * (1.0 / 16777216.0)


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
    _hit_points_kernel(flat.vertices, flat.faces, tri, bary, nrm, p, n, err_point, err_embree, grazing)
    own_blocks = flat.occluder[tri]
    return p, n, err_point, err_embree, grazing, own_blocks


@kernel(inline=True)
def _f32(x):
    return np.float64(np.float32(x))  # Embree's float32 vertex coordinate


@kernel(inline=True)
def hit_point(verts, faces, t, b1, b2, m0, m1, m2):
    """:func:`hit_points` for one point: triangle ``t``, barycentrics (b1, b2) as float64, eye-facing
    normal m. Returns (px, py, pz, nx, ny, nz, err_point, err_embree, grazing); each value is computed
    with the operations in the order the earlier NumPy version used, so the results are the same
    bits."""
    tiny = np.finfo(np.float64).tiny
    g5 = 5 * U64 / (1 - 5 * U64)
    i0, i1, i2 = faces[t, 0], faces[t, 1], faces[t, 2]
    ax, ay, az = _f32(verts[i0, 0]), _f32(verts[i0, 1]), _f32(verts[i0, 2])
    bx, by, bz = _f32(verts[i1, 0]), _f32(verts[i1, 1]), _f32(verts[i1, 2])
    cx, cy, cz = _f32(verts[i2, 0]), _f32(verts[i2, 1]), _f32(verts[i2, 2])
    b0 = 1.0 - b1 - b2
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    crx = e1y * e2z - e1z * e2y
    cry = e1z * e2x - e1x * e2z
    crz = e1x * e2y - e1y * e2x
    twice_area = np.sqrt(crx * crx + cry * cry + crz * crz)
    dn = max(twice_area, tiny)
    nx, ny, nz = crx / dn, cry / dn, crz / dn
    if nx * m0 + ny * m1 + nz * m2 < 0.0:
        nx, ny, nz = -nx, -ny, -nz
    px = b0 * ax + b1 * bx + b2 * cx
    py = b0 * ay + b1 * by + b2 * cy
    pz = b0 * az + b1 * bz + b2 * cz
    ex = g5 * (abs(b0 * ax) + abs(b1 * bx) + abs(b2 * cx) + abs(ax))
    ey = g5 * (abs(b0 * ay) + abs(b1 * by) + abs(b2 * cy) + abs(ay))
    ez = g5 * (abs(b0 * az) + abs(b1 * bz) + abs(b2 * cz) + abs(az))
    ep = abs(nx) * (ex + U32 * abs(px)) + abs(ny) * (ey + U32 * abs(py)) + abs(nz) * (ez + U32 * abs(pz))
    area = max(0.5 * twice_area, tiny)
    ra = np.sqrt((ax - px) * (ax - px) + (ay - py) * (ay - py) + (az - pz) * (az - pz))
    rb = np.sqrt((bx - px) * (bx - px) + (by - py) * (by - py) + (bz - pz) * (bz - pz))
    rc = np.sqrt((cx - px) * (cx - px) + (cy - py) * (cy - py) + (cz - pz) * (cz - pz))
    R = max(ra, rb, rc)
    q = R * R / area
    grazing = U32 * (16.0 * q + 3.0)
    ee = U32 * R * (4.0 + 16.0 * q)
    # the origin sits err_* above p: R grows by that much (one fixed-point step is enough, it is tiny)
    R = R + BOUND_SAFETY * (ep + ee)
    q = R * R / area
    return px, py, pz, nx, ny, nz, ep, U32 * R * (4.0 + 16.0 * q), grazing


@kernel(parallel=True)
def _hit_points_kernel(verts, faces, tri, bary, nrm, p, n, err_point, err_embree, grazing):
    for k in prange(tri.shape[0]):
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

    Ray origins (pbrt's ``OffsetRayOrigin``): ``p + off[k] n``, n the normal on the side the ray
    leaves to, rounded to float32 away from the surface (the next float32 outward where rounding
    to nearest came back toward it). ``off``: the error bound of :func:`hit_points`. A ray that
    leaves the surface on the side the eye does not see (cos_p <= ``grazing[k]``, the float32
    resolution of that side) is blocked by the surface itself when the surface is an occluder
    (``own_blocks``): it is not traced (length 0) and marked with geo = -1."""
    S = n_side * n_side
    for k in range(pts.shape[0]):  # serial: trace_in_pipeline runs one chunk per thread
        px, py, pz = pts[k, 0], pts[k, 1], pts[k, 2]
        nx, ny, nz = nrm[k, 0], nrm[k, 1], nrm[k, 2]
        ox = px + off[k] * nx
        oy = py + off[k] * ny
        oz = pz + off[k] * nz
        ox32 = np.float32(ox)
        oy32 = np.float32(oy)
        oz32 = np.float32(oz)
        # round away from the surface: where rounding to nearest moved a coordinate back toward
        # the surface, take the next float32 outward
        if (ox32 - ox) * nx < 0.0:
            ox32 = np.nextafter(ox32, np.float32(np.inf) if nx > 0.0 else np.float32(-np.inf))
        if (oy32 - oy) * ny < 0.0:
            oy32 = np.nextafter(oy32, np.float32(np.inf) if ny > 0.0 else np.float32(-np.inf))
        if (oz32 - oz) * nz < 0.0:
            oz32 = np.nextafter(oz32, np.float32(np.inf) if nz > 0.0 else np.float32(-np.inf))
        if shape == 1:  # sphere: disk facing p
            wx, wy, wz = px - center[0], py - center[1], pz - center[2]
            wl = np.sqrt(wx * wx + wy * wy + wz * wz)
            wx /= wl
            wy /= wl
            wz /= wl
            if abs(wx) < 0.9:
                ax, ay, az = 1.0, 0.0, 0.0
            else:
                ax, ay, az = 0.0, 1.0, 0.0
            # e1 = normalize(a x w), e2 = w x e1
            e1x, e1y, e1z = ay * wz - az * wy, az * wx - ax * wz, ax * wy - ay * wx
            el = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
            e1x /= el
            e1y /= el
            e1z /= el
            e2x, e2y, e2z = wy * e1z - wz * e1y, wz * e1x - wx * e1z, wx * e1y - wy * e1x
            lnx, lny, lnz = wx, wy, wz
        else:
            lnx = u[1] * v[2] - u[2] * v[1]
            lny = u[2] * v[0] - u[0] * v[2]
            lnz = u[0] * v[1] - u[1] * v[0]
            ll = np.sqrt(lnx * lnx + lny * lny + lnz * lnz)
            lnx /= ll
            lny /= ll
            lnz /= ll
        key = point_key(seed, pix[k])
        for i in range(n_side):
            for j in range(n_side):
                s = i * n_side + j
                ja, jb = jitter_pair(key, s)
                a = (i + ja) / n_side
                b = (j + jb) / n_side
                if shape == 1:
                    dx, dy = _concentric(a, b)
                    sx = center[0] + radius * (dx * e1x + dy * e2x)
                    sy = center[1] + radius * (dx * e1y + dy * e2y)
                    sz = center[2] + radius * (dx * e1z + dy * e2z)
                else:
                    sx = center[0] + (a - 0.5) * u[0] + (b - 0.5) * v[0]
                    sy = center[1] + (a - 0.5) * u[1] + (b - 0.5) * v[1]
                    sz = center[2] + (a - 0.5) * u[2] + (b - 0.5) * v[2]
                q = k * S + s
                # cosine at p toward the sample (from p itself: the side the ray leaves to)
                qx, qy, qz = sx - px, sy - py, sz - pz
                ql = np.sqrt(qx * qx + qy * qy + qz * qz)
                cp = (nx * qx + ny * qy + nz * qz) / ql
                org[q, 0] = ox32
                org[q, 1] = oy32
                org[q, 2] = oz32
                if own_blocks[k] and cp <= grazing[k]:
                    # leaves through the back of the pixel's own (occluder) triangle: blocked
                    dirs[q, 0] = nx
                    dirs[q, 1] = ny
                    dirs[q, 2] = nz
                    dist[q] = 0.0
                    geo[q] = -1.0
                    continue
                rx, ry, rz = sx - ox32, sy - oy32, sz - oz32
                rl = np.sqrt(rx * rx + ry * ry + rz * rz)
                ri = 1.0 / rl
                dirs[q, 0] = rx * ri
                dirs[q, 1] = ry * ri
                dirs[q, 2] = rz * ri
                dist[q] = rl * (1.0 - 1e-6)
                if need_geo:
                    cl = -(lnx * rx + lny * ry + lnz * rz) * ri
                    geo[q] = max(cp, 0.0) * max(cl, 0.0) * ri * ri
                else:
                    geo[q] = 0.0


@kernel(nogil=True)
def reduce_visibility(hits, geo, S, vis, irr, offset):
    """vis[k] = unoccluded fraction; irr[k] = sum of geo over unoccluded samples / S (samples with
    geo < 0 are blocked without tracing, see :func:`generate_light_rays`)."""
    n = hits.shape[0] // S
    for k in range(n):
        c = 0
        e = 0.0
        for s in range(S):
            if hits[k * S + s] < 0 and geo[k * S + s] >= 0.0:  # embree: -1 = not occluded; geo -1: blocked
                c += 1
                e += geo[k * S + s]
        vis[offset + k] = c / S
        irr[offset + k] = e / S


def trace_in_pipeline(
    esc, pts, nrm, pix, off, grazing, own_blocks, seed, n_side, light, vis, irr, progress=False, physical=False
):
    """Generate, trace and reduce rays chunk by chunk on every core: one Python thread per Numba
    thread (``numba.get_num_threads()``) takes chunks in turn and runs ray generation, Embree's
    ``run`` and the reduction on each. All three release the GIL (the kernels are serial Numba
    ``nogil`` kernels, so this is safe under any threading layer; embreex releases it while
    tracing), so the threads trace in parallel. Each chunk writes its own slice of ``vis``/``irr``
    and the jitter hashes (seed, pixel, sample), so the output does not depend on the thread count.
    Returns (trace, generation, reduction) seconds summed over threads, and the wall time."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    import numba

    S = n_side * n_side
    K = len(pts)
    shape, center, u, v, radius = light_arrays(light)
    nthreads = max(1, numba.get_num_threads())
    # chunks of at most CHUNK_RAYS rays, and at least 4 per thread so that threads stay busy to the end
    per_chunk = max(1, min(CHUNK_RAYS // S, -(-K // (4 * nthreads))))
    starts = list(range(0, K, per_chunk))
    times = {"gen": 0.0, "trace": 0.0, "red": 0.0}
    lock = threading.Lock()
    bar = None
    if progress and K * S > 4_000_000:
        from tqdm import tqdm

        bar = tqdm(total=K * S, unit="ray", unit_scale=True, desc="ground truth", leave=False)

    def chunk(start):
        t0 = time.perf_counter()
        stop = min(K, start + per_chunk)
        m = stop - start
        org = np.empty((m * S, 3), np.float32)
        dirs = np.empty((m * S, 3), np.float32)
        dist = np.empty(m * S, np.float32)
        geo = np.empty(m * S, np.float32)
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
        reduce_visibility(hits, geo, S, vis, irr, start)
        t3 = time.perf_counter()
        with lock:
            times["gen"] += t1 - t0
            times["trace"] += t2 - t1
            times["red"] += t3 - t2
            if bar is not None:
                bar.update(len(dist))

    t_wall = time.perf_counter()
    if nthreads == 1 or len(starts) == 1:
        for start in starts:
            chunk(start)
    else:
        with ThreadPoolExecutor(max_workers=nthreads) as pool:
            list(pool.map(chunk, starts))
    t_wall = time.perf_counter() - t_wall
    if bar is not None:
        bar.close()
    return times["trace"], times["gen"], times["red"], t_wall


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
