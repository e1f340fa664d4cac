"""``layered-attenuation``: layered attenuation maps (Agrawala et al. 2000, Sections 4 and 6).

A precompute that depends only on the light, the geometry and its own parameters renders a depth
image from each of N x N stratified jittered points on the light, warps every depth pixel to the
view from the light's center and counts, in a layered depth image (LDI), from how many light
samples each surface layer is seen; the display warps each eye point into that LDI and reads the
attenuation of the layer at its depth. :func:`precompute` returns the LDI as an object
(:class:`LayeredAttenuationMap`); :func:`render` with this method reuses a cached LDI while the
geometry, the light and the precompute parameters are unchanged. Steps, parameters, deviations
and limits: ``docs/methods/layered-attenuation.md``.
"""

from __future__ import annotations

import hashlib
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import ClassVar

import numba
import numpy as np

from .._jit import kernel, run_slots, run_threads
from ..errors import SoftShadowsError
from ..geometry.light_samples import light_sample_points
from ..raster import View, light_view, rasterize_depth
from ..raster.kernels import view_project, view_unproject
from ..raster.view import VP_H, VP_ORIGIN, VP_W
from .base import Method, MethodOutput, Param, register


def _perfect_square(v) -> str | None:
    n = int(round(np.sqrt(v)))
    return None if n * n == v else "a perfect square (N x N samples: 16, 64, 256, ...)"


# Parameters of the precompute (they key the cache) and of the display.
PRECOMPUTE_PARAMS = ("samples", "ldi_size", "epsilon", "slope_epsilon", "max_layers", "splat", "warp")
DISPLAY_PARAMS = ("bilinear",)
#: the slope tolerance stops growing beyond this tan (about 72 degrees): larger tolerances on
#: grazing surfaces merge them with the surfaces in front of them (bias errors)
TAN_MAX = 3.0

PARAMS = (
    Param("samples", 64, "light samples N x N (the same set for every point)", min=1, max=4096, check=_perfect_square),
    Param("ldi_size", 512, "LDI resolution (square), also that of the depth images", min=16, max=4096),
    Param(
        "epsilon",
        2.0,
        "depth tolerance (the paper's epsilon) for merging layers and for the lookup, in LDI texels at that depth",
        min=0.0,
    ),
    Param(
        "max_layers", 16, "layers stored per LDI pixel at most (further ones are dropped and counted)", min=1, max=64
    ),
    Param("splat", True, "2x2 splat of each warped pixel against holes (the paper's)"),
    Param(
        "warp",
        "disparity",
        "warp to the light-center view: planar disparity (Eq. 3) or general projective reprojection",
        choices=("disparity", "projective"),
    ),
    Param(
        "slope_epsilon",
        1.0,
        "extra depth tolerance, texels x tan(surface slope to the light): at insertion from the depth image, at lookup from the normal (0 = the paper's constant epsilon)",
        min=0.0,
    ),
    Param("bilinear", False, "display: bilinear filtering of attenuation over the 2x2 LDI pixels (beyond the paper)"),
)


# ---- the LDI ----------------------------------------------------------------------------------
@dataclass
class LayeredAttenuationMap:
    """The precomputed layered attenuation maps of one light + geometry + parameter set.

    Flat arrays over the ``H*W`` pixels of ``view`` (the view from the light's center), at most
    ``max_layers`` layers per pixel, sorted front to back, slot-major (layer k of all pixels is
    contiguous): ``depth[k, p]`` (view depth, float32), ``count[k, p]`` (light samples that see
    it), ``nlayers[p]``. Attenuation = count / samples.
    """

    view: View
    depth: np.ndarray  # (L, H*W) float32, +inf beyond nlayers
    count: np.ndarray  # (L, H*W) int32
    nlayers: np.ndarray  # (H*W,) int32
    samples: int
    sample_points: np.ndarray  # (samples, 3) world positions on the light
    params: dict
    key: tuple
    complexity: np.ndarray  # (samples,) average layers per non-empty pixel after each sample
    dropped: int  # splats not stored because a pixel had max_layers layers
    precompute_s: float = 0.0
    steps: dict = field(default_factory=dict)  # seconds per precompute step

    @property
    def attenuation(self) -> np.ndarray:
        """(L, H*W) float32 count / samples (0 beyond nlayers)."""
        return (self.count / np.float32(self.samples)).astype(np.float32)

    def layer_image(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(depth, attenuation) of layer ``k`` as (H, W) images, NaN where the pixel has fewer layers."""
        H, W = self.view.height, self.view.width
        has = self.nlayers > k
        d = np.where(has, self.depth[k], np.nan).reshape(H, W)
        a = np.where(has, self.count[k] / self.samples, np.nan).reshape(H, W)
        return d, a

    def stats(self) -> dict:
        nonempty = int((self.nlayers > 0).sum())
        total = int(self.nlayers.sum())
        return {
            "samples": self.samples,
            "ldi_size": self.view.width,
            "ldi_nonempty_pixels": nonempty,
            "ldi_total_layers": total,
            "ldi_max_layers": int(self.nlayers.max()) if self.nlayers.size else 0,
            "ldi_avg_depth_complexity": total / max(nonempty, 1),
            # the paper's Fig. 10 (right): average depth complexity after 1, 2, 4, ... samples and all
            "ldi_complexity_by_samples": {
                int(n): round(float(self.complexity[n - 1]), 5)
                for n in sorted({*(1 << k for k in range(int(np.log2(max(self.samples, 1))) + 1)), self.samples})
            },
            "ldi_dropped_splats": int(self.dropped),
            "ldi_precompute_s": self.precompute_s,
            "precompute_steps_s": {k: round(v, 6) for k, v in self.steps.items()},
        }


# ---- precompute, line 1: the light samples -----------------------------------------------------
def centre_view(scene, size: int) -> View:
    """The LDI's view: from the light's center along its normal (sphere: toward the scene), a
    frustum whose square-pixel window covers every vertex in front of the light (the receivers
    and the occluders: every eye point can be looked up)."""
    return light_view(scene.light, scene.flat.vertices, size, size, square_pixels=True, margin=0.02)


def light_samples(scene, n: int, seed: int, view: View) -> np.ndarray:
    """Line 1: the N x N stratified jittered sample positions (world, (N*N, 3)) on the light,
    the same set for every shaded point. Sphere light: the disk through its center facing the
    scene (the plane of ``view``), an approximation of the disk facing each point."""
    return light_sample_points(scene.light, n, seed, right=view.right, up=view.up)


# ---- line 2: the viewpoint of a sample --------------------------------------------------------
def sample_view(view: View, point) -> View:
    """Line 2 (Viewpoint <- l_i): the LDI view moved to the sample ``point`` on the light (same
    orientation and pixel size: parallel views, so Eq. 3 holds), its window widened on the side
    of the disparity just enough to see all that warps into the LDI's window at depths in
    [near, far] (a point at depth z moves by dv / z in window units)."""
    l, r, b, t = view.window
    pw, ph = (r - l) / view.width, (t - b) / view.height
    d = np.asarray(point, float) - view.origin
    dx, dy = float(d @ view.right), float(d @ view.up)
    inv = (1.0 / view.near, 1.0 / view.far)
    # x'_sample = x'_center - dv / z for z in [near, far]
    ls, rs = l + min(-dx * i for i in inv), r + max(-dx * i for i in inv)
    bs, ts = b + min(-dy * i for i in inv), t + max(-dy * i for i in inv)
    # at most the LDI's own size added on each side (geometry very close to the light plane would
    # otherwise ask for unbounded images; what lies beyond is missing from that sample's image)
    ls, rs = max(ls, l - view.width * pw), min(rs, r + view.width * pw)
    bs, ts = max(bs, b - view.height * ph), min(ts, t + view.height * ph)
    w = int(np.ceil((rs - ls) / pw)) + 2
    h = int(np.ceil((ts - bs) / ph)) + 2
    ls, ts = ls - pw, ts + ph
    return View(
        np.asarray(point, float), view.right, view.up, view.forward,
        (ls, ls + w * pw, ts - h * ph, ts), view.near, view.far, w, h, view.ortho,
    )  # fmt: skip


# ---- line 3: render from the sample ----------------------------------------------------------
def render_sample_depth(scene, view: View, one_pass: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """Line 3 (Render(SCENE)): depth images from a light sample with the shared rasterizer:
    the nearest occluder (role both|occluder) and, when the scene has receiver-only faces, the
    nearest of them where it lies in front of that occluder (a receiver-only face casts no shadow,
    so both are seen from the sample). +inf where none. With ``one_pass`` (every receiver-only
    face is at least as deep as every occluder: :func:`receivers_behind`) one depth image of all
    faces is the same thing."""
    flat = scene.flat
    if one_pass:
        return rasterize_depth(view, flat.vertices, flat.faces, tri=False)[0], None
    occ_faces, rec_faces = _role_faces(flat)
    d_occ = rasterize_depth(view, flat.vertices, occ_faces, tri=False)[0] if len(occ_faces) else None
    d_rec = rasterize_depth(view, flat.vertices, rec_faces, tri=False)[0] if len(rec_faces) else None
    if d_occ is None:
        return d_rec, None
    if d_rec is not None:
        d_rec = np.where(d_rec < d_occ, d_rec, np.float32(np.inf))
    return d_occ, d_rec


def receivers_behind(scene, view: View) -> bool:
    """True when no receiver-only face can be in front of an occluder from any light sample: its
    vertices' depths (along the light's normal, the same in every sample's view) are all >= the
    occluders'. Then a single depth image of all faces is exact (the built-in scenes with a rect
    light: the ground plane below everything, parallel to the light)."""
    flat = scene.flat
    occ_faces, rec_faces = _role_faces(flat)
    if len(occ_faces) == 0 or len(rec_faces) == 0:
        return True
    z_occ = (flat.vertices[np.unique(occ_faces)] - view.origin) @ view.forward
    z_rec = (flat.vertices[np.unique(rec_faces)] - view.origin) @ view.forward
    return bool(z_rec.min() >= z_occ.max())


def _role_faces(flat) -> tuple[np.ndarray, np.ndarray]:
    key = ("layered_attenuation_role_faces",)
    hit = flat._cache.get(key)
    if hit is None:
        hit = (
            np.ascontiguousarray(flat.faces[flat.occluder]),
            np.ascontiguousarray(flat.faces[flat.receiver & ~flat.occluder]),
        )
        flat._cache[key] = hit
    return hit


# ---- line 5: warp to the light center ---------------------------------------------------------
@kernel(inline=True)
def _slope_tan(depth, i, j, z, texel):
    """tan of the angle between a depth pixel's surface and the image plane, from the smaller
    one-sided depth difference along each axis (so a depth discontinuity on one side is ignored),
    clamped to 10."""
    Hs, Ws = depth.shape
    g = 0.0
    for a in range(2):
        best = np.inf
        for s in (-1, 1):
            ii = i + s * (1 - a)
            jj = j + s * a
            if 0 <= ii < Hs and 0 <= jj < Ws:
                dz = abs(depth[ii, jj] - z)
                if dz < best:
                    best = dz
        if np.isfinite(best) and best > g:
            g = best
    return min(g / texel, TAN_MAX)


@kernel(nogil=True, nrt=False, noalias=True)
def warp_center_slot(
    slot, depth, vps, vpc, projective, eps_texels, slope_texels, tx, ty, tz, te, row_lo, row_hi, nslot
):
    """Line 5 (WarpCenter): every depth pixel of a sample's image (view ``vps``) to continuous
    pixel coordinates (tx, ty) and depth tz in the light-center view ``vpc``. Parallel views
    (``projective`` False): the planar-light disparity of Eq. 3, dp = -dv / z (in pixels), z
    unchanged; otherwise unproject + project. Also its insertion tolerance te = texel(z) x
    (eps_texels + slope_texels x tan), tan from the depth image's local slope, and the range of
    LDI rows [row_lo, row_hi] the 2x2 splats of each source row touch (for the banded
    insertion). tx is NaN where no surface. Run by ``run_slots``: slot ``slot`` of ``nslot`` takes
    every ``nslot``-th row."""
    Hs, Ws = depth.shape
    Wc, Hc = vpc[18], vpc[19]
    kx = Wc / (vpc[13] - vpc[12])  # LDI pixels per unit of x/z
    ky = Hc / (vpc[15] - vpc[14])
    tex = (vps[13] - vps[12]) / vps[18]  # texel size per unit depth (same in both views)
    # the disparity baseline dv (in the view's right/up axes) and the pixel offset of the windows
    dvx = (vps[0] - vpc[0]) * vpc[3] + (vps[1] - vpc[1]) * vpc[4] + (vps[2] - vpc[2]) * vpc[5]
    dvy = (vps[0] - vpc[0]) * vpc[6] + (vps[1] - vpc[1]) * vpc[7] + (vps[2] - vpc[2]) * vpc[8]
    ox = (vps[12] - vpc[12]) * kx
    oy = (vpc[15] - vps[15]) * ky
    for i in range(slot, Hs, nslot):
        lo = 1 << 30
        hi = -(1 << 30)
        for j in range(Ws):
            z = depth[i, j]
            if not np.isfinite(z):
                tx[i, j] = np.nan
                continue
            if projective:
                wx, wy, wz = view_unproject(vps, j + 0.5, i + 0.5, z)
                sx, sy, zc = view_project(vpc, wx, wy, wz)
            else:
                sx = j + 0.5 + ox + dvx / z * kx
                sy = i + 0.5 + oy - dvy / z * ky
                zc = z
            tx[i, j] = sx
            ty[i, j] = sy
            tz[i, j] = zc
            texel = tex * z
            tan = _slope_tan(depth, i, j, z, texel) if slope_texels > 0.0 else 0.0
            te[i, j] = texel * (eps_texels + slope_texels * tan)
            r0 = int(np.floor(min(max(sy - 0.5, -2.0), Hc + 1.0)))
            lo = min(lo, r0)
            hi = max(hi, r0 + 1)
        row_lo[i] = lo
        row_hi[i] = hi


def warp_center(depth, vps, vpc, projective, eps_texels, slope_texels, tx, ty, tz, te, row_lo, row_hi) -> None:
    """:func:`warp_center_slot` over the whole image, one slot per thread."""
    nslot = numba.get_num_threads()
    run_slots(
        warp_center_slot, nslot, depth, vps, vpc, projective, eps_texels, slope_texels, tx, ty, tz, te,
        row_lo, row_hi, nslot,
    )  # fmt: skip


# ---- line 6: insert into the LDI --------------------------------------------------------------
@kernel(inline=True)
def _insert(p, z, eps, view_id, ldi_depth, ldi_count, ldi_n, stamp):
    """Insert depth z at LDI pixel p: the nearest layer within eps is incremented (at most once
    per viewpoint, by its stamp), else a new layer. Returns (new layer, new non-empty, dropped)."""
    n = ldi_n[p]
    best = -1
    bd = eps
    for k in range(n):
        d = abs(ldi_depth[k, p] - z)
        if d <= bd:
            bd = d
            best = k
    if best >= 0:
        if stamp[best, p] != view_id:
            stamp[best, p] = view_id
            ldi_count[best, p] += 1
        return 0, 0, 0
    if n >= ldi_depth.shape[0]:
        return 0, 0, 1
    ldi_depth[n, p] = z
    ldi_count[n, p] = 1
    stamp[n, p] = view_id
    ldi_n[p] = n + 1
    return 1, 1 if n == 0 else 0, 0


@kernel(nogil=True, nrt=False, noalias=True)
def insert_ldi_slot(
    slot, tx, ty, tz, te, row_lo, row_hi, splat, view_id, W, H, band, ldi_depth, ldi_count, ldi_n, stamp, out, nslot
):
    """Line 6 (Insert): every warped pixel into the LDI, with the paper's 2x2 splat (the four
    pixels whose centers surround the warped point) or, without it, the nearest pixel. Parallel
    over bands of ``band`` LDI rows: each band scans the source rows whose splats reach it (from
    row_lo/row_hi) in order, so the result does not depend on the thread count. Tolerance: te
    (from :func:`warp_center`).
    Per band (new layers, new non-empty pixels, dropped splats) into ``out`` (nb, 3) int64, zeroed.
    Run by ``run_slots``: slot ``slot`` of ``nslot`` takes every ``nslot``-th band."""
    nb = (H + band - 1) // band
    P, Hs, Ws = tx.shape
    for b in range(slot, nb, nslot):
        r0 = b * band
        r1 = min(H, r0 + band)
        for i in range(Hs):
            if row_hi[i] < r0 or row_lo[i] >= r1:
                continue
            for q in range(P):
                for j in range(Ws):
                    sx = tx[q, i, j]
                    if not np.isfinite(sx):
                        continue
                    sy = ty[q, i, j]
                    z = tz[q, i, j]
                    eps = te[q, i, j]
                    if splat:
                        j0 = int(np.floor(sx - 0.5))
                        i0 = int(np.floor(sy - 0.5))
                        ni = 2
                    else:
                        j0 = int(np.floor(sx))
                        i0 = int(np.floor(sy))
                        ni = 1
                    for di in range(ni):
                        r = i0 + di
                        if r < r0 or r >= r1:
                            continue
                        for dj in range(ni):
                            c = j0 + dj
                            if c < 0 or c >= W:
                                continue
                            a, e, d = _insert(r * W + c, z, eps, view_id, ldi_depth, ldi_count, ldi_n, stamp)
                            out[b, 0] += a
                            out[b, 1] += e
                            out[b, 2] += d


def insert_ldi(tx, ty, tz, te, row_lo, row_hi, splat, view_id, W, H, band, ldi_depth, ldi_count, ldi_n, stamp):
    """:func:`insert_ldi_slot` over every band, one slot per thread. Returns per band (new layers,
    new non-empty pixels, dropped splats), (nb, 3) int64."""
    out = np.zeros(((H + band - 1) // band, 3), np.int64)
    nslot = numba.get_num_threads()
    run_slots(
        insert_ldi_slot, nslot, tx, ty, tz, te, row_lo, row_hi, splat, view_id, W, H, band,
        ldi_depth, ldi_count, ldi_n, stamp, out, nslot,
    )  # fmt: skip
    return out


# ---- line 7: process the attenuation maps -----------------------------------------------------
@kernel(nogil=True, nrt=False, noalias=True)
def sort_layers_slot(slot, ldi_depth, ldi_count, ldi_n, nslot):
    """Line 7 (Process Attenuation Maps), storage part: layers of each pixel front to back
    (insertion sort; a handful of layers). Attenuation = count / samples is read at lookup.
    Run by ``run_slots``: slot ``slot`` of ``nslot`` takes the ``slot``-th contiguous block of pixels
    (an unsigned index, as a ``prange``'s: no negative-index wraparound, 2x faster)."""
    npix = ldi_n.shape[0]
    per = (npix + nslot - 1) // nslot
    for p in range(np.uint64(slot * per), np.uint64(min(npix, slot * per + per))):
        n = ldi_n[p]
        for k in range(1, n):
            d = ldi_depth[k, p]
            c = ldi_count[k, p]
            m = k - 1
            while m >= 0 and ldi_depth[m, p] > d:
                ldi_depth[m + 1, p] = ldi_depth[m, p]
                ldi_count[m + 1, p] = ldi_count[m, p]
                m -= 1
            ldi_depth[m + 1, p] = d
            ldi_count[m + 1, p] = c


def sort_layers(ldi_depth, ldi_count, ldi_n) -> None:
    """:func:`sort_layers_slot` over every pixel, one slot per thread."""
    run_threads(sort_layers_slot, ldi_depth, ldi_count, ldi_n)


def _geometry_digest(flat) -> str:
    hit = flat._cache.get("layered_attenuation_digest")
    if hit is None:
        h = hashlib.blake2b(digest_size=16)
        for a in (flat.vertices, flat.faces, flat.occluder, flat.receiver):
            h.update(np.ascontiguousarray(a).tobytes())
        hit = h.hexdigest()
        flat._cache["layered_attenuation_digest"] = hit
    return hit


def _light_key(light) -> tuple:
    if light.shape == "rect":
        return ("rect", *light.center.tolist(), *light.u.tolist(), *light.v.tolist())
    return ("sphere", *light.center.tolist(), light.radius)


def cache_key(scene, params: dict, seed: int) -> tuple:
    """What the LDI depends on: the geometry (content hash), the light, the precompute
    parameters and the seed of the sample jitter. Not the camera."""
    return (
        _geometry_digest(scene.flat),
        _light_key(scene.light),
        tuple((k, params[k]) for k in PRECOMPUTE_PARAMS),
        int(seed),
    )


_compiled = False


def _warm_kernels() -> None:
    """Compile the precompute kernels once on a tiny problem, so that no precompute time
    reported (nor cached) includes JIT compilation."""
    global _compiled
    if _compiled:
        return
    _compiled = True
    v = View.frame([0, 0, 0], [0, 0, 1], [0, 1, 0], (-1, 1, -1, 1), 0.1, 10.0, 4, 4)
    d = np.full((2, 4, 4), 1.0, np.float32)
    tx, ty, tz, te = (np.empty((2, 4, 4), np.float32) for _ in range(4))
    lo, hi = np.empty(4, np.int64), np.empty(4, np.int64)
    for proj in (False, True):
        warp_center(d[0], v.params(), v.params(), proj, 1.0, 1.0, tx[0], ty[0], tz[0], te[0], lo, hi)
    ld, lc, ln = np.zeros((2, 16), np.float32), np.zeros((2, 16), np.int32), np.zeros(16, np.int32)
    st = np.zeros((2, 16), np.int32)
    insert_ldi(tx, ty, tz, te, lo, hi, True, 1, 4, 4, 2, ld, lc, ln, st)
    sort_layers(ld, lc, ln)


def build_ldi(scene, params: dict, seed: int = 0) -> LayeredAttenuationMap:
    """The precompute, the paper's pseudocode step by step (``params``: the resolved parameters
    of the method; only those in ``PRECOMPUTE_PARAMS`` are read)."""
    _warm_kernels()
    t_all = time.perf_counter()
    steps = dict.fromkeys(("samples", "render_depth", "warp", "insert", "attenuation"), 0.0)
    n = int(round(np.sqrt(params["samples"])))
    size = int(params["ldi_size"])
    t = time.perf_counter()
    view = centre_view(scene, size)
    pts = light_samples(scene, n, seed, view)
    vpc = view.params()
    W = H = size
    L = int(params["max_layers"])
    ldi_depth = np.full((L, W * H), np.inf, np.float32)
    ldi_count = np.zeros((L, W * H), np.int32)
    ldi_n = np.zeros(W * H, np.int32)
    stamp = np.full((L, W * H), -1, np.int32)
    eps, slope_eps = float(params["epsilon"]), float(params["slope_epsilon"])
    projective = params["warp"] == "projective"
    # bands of LDI rows for the parallel insertion: 4 per thread (load balance); a source row whose
    # splats straddle bands is scanned by each, so fewer, larger bands waste less (same LDI any way)
    band = max(16, -(-H // (4 * numba.get_num_threads())))
    complexity = np.zeros(len(pts))
    total_layers = nonempty = dropped = 0
    one_pass = receivers_behind(scene, view)
    steps["samples"] += time.perf_counter() - t
    for s, p in enumerate(pts):  # line 1
        vs = sample_view(view, p)  # line 2
        t = time.perf_counter()
        d_occ, d_rec = render_sample_depth(scene, vs, one_pass)  # line 3
        steps["render_depth"] += time.perf_counter() - t
        t = time.perf_counter()
        planes = 1 if d_rec is None else 2
        vps = vs.params()
        tx, ty, tz, te = (np.empty((planes, vs.height, vs.width), np.float32) for _ in range(4))
        lo, hi = np.empty((planes, vs.height), np.int64), np.empty((planes, vs.height), np.int64)
        for q, d in enumerate((d_occ, d_rec)[:planes]):  # lines 4-5
            warp_center(d, vps, vpc, projective, eps, slope_eps, tx[q], ty[q], tz[q], te[q], lo[q], hi[q])
        row_lo, row_hi = lo.min(axis=0), hi.max(axis=0)
        steps["warp"] += time.perf_counter() - t
        t = time.perf_counter()
        res = insert_ldi(  # line 6
            tx, ty, tz, te, row_lo, row_hi, bool(params["splat"]), s, W, H, band,
            ldi_depth, ldi_count, ldi_n, stamp,
        )  # fmt: skip
        tot = res.sum(axis=0)
        total_layers += int(tot[0])
        nonempty += int(tot[1])
        dropped += int(tot[2])
        complexity[s] = total_layers / max(nonempty, 1)
        steps["insert"] += time.perf_counter() - t
    t = time.perf_counter()
    sort_layers(ldi_depth, ldi_count, ldi_n)  # line 7
    steps["attenuation"] += time.perf_counter() - t
    resolved = {k: params[k] for k in PRECOMPUTE_PARAMS}
    return LayeredAttenuationMap(
        view=view,
        depth=ldi_depth,
        count=ldi_count,
        nlayers=ldi_n,
        samples=len(pts),
        sample_points=pts,
        params=resolved,
        key=cache_key(scene, params, seed),
        complexity=complexity,
        dropped=dropped,
        precompute_s=time.perf_counter() - t_all,
        steps=steps,
    )


# ---- the cache ------------------------------------------------------------------------------
_CACHE: OrderedDict = OrderedDict()
CACHE_SIZE = 4


def clear_cache() -> None:
    _CACHE.clear()


def _cache_put(ldi: LayeredAttenuationMap) -> None:
    _CACHE[ldi.key] = ldi
    _CACHE.move_to_end(ldi.key)
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)


def precompute(scene, seed: int = 0, **params) -> LayeredAttenuationMap:
    """The precompute as an object (the Python API): validates ``params`` like ``render`` does
    (display parameters are accepted and ignored), builds the LDI and caches it, so that
    ``render(scene, "layered-attenuation", ...)`` and :func:`display` with the same geometry,
    light, precompute parameters and seed reuse it."""
    m = LayeredAttenuation()
    m.check_light(scene.light)
    resolved = m.resolve_params(params)
    ldi = build_ldi(scene, resolved, seed)
    _cache_put(ldi)
    return ldi


def display(ldi: LayeredAttenuationMap, scene, width: int = 512, height: int = 512, **display_params):
    """A frame of ``scene`` (any camera) from a precomputed LDI: ``render`` with the LDI's
    precompute parameters and seed, the precompute reused (its phase is 0). Raises when the
    scene's geometry or light is not the one the LDI was built from."""
    from ..api import render

    bad = set(display_params) - set(DISPLAY_PARAMS)
    if bad:
        raise SoftShadowsError(f"display: not a display parameter: {', '.join(sorted(bad))}; valid: {DISPLAY_PARAMS}")
    key = cache_key(scene, ldi.params, ldi.key[3])
    if key != ldi.key:
        raise SoftShadowsError("display: the scene's geometry or light differs from the LDI's (precompute again)")
    _cache_put(ldi)
    return render(scene, "layered-attenuation", width, height, seed=ldi.key[3], **ldi.params, **display_params)


# ---- display ----------------------------------------------------------------------------------
@kernel(inline=True)
def _layer_att(p, z, eps, ldi_depth, ldi_count, ldi_n, inv_samples):
    """Line 4-5 for one LDI pixel: attenuation of the layer nearest to z within eps, 0 if none."""
    best = -1
    bd = eps
    for k in range(ldi_n[p]):
        d = abs(ldi_depth[k, p] - z)
        if d <= bd:
            bd = d
            best = k
    return 0.0 if best < 0 else ldi_count[best, p] * inv_samples


@kernel(nogil=True, nrt=False, noalias=True)
def lookup_ldi_slot(
    slot, vp, ldi_depth, ldi_count, ldi_n, inv_samples, pts, nrm, eps_rel, slope_eps_rel, bilinear, out, nslot
):
    """Display lines 3-5: each eye point warped to the light-center view (WarpLDI), its nearest
    LDI pixel (or the 2x2 around it, bilinearly weighted, with ``bilinear``), the layer matching
    its depth within eps = depth x (eps_rel + slope_eps_rel x tan(theta)); V = that layer's
    attenuation, 0 when none matches, into ``out`` (K,) float32. A point outside the LDI's frustum
    is not shadowed (V = 1). Run by ``run_slots``: slot ``slot`` of ``nslot`` takes the
    ``slot``-th contiguous block of points (an unsigned index, as a ``prange``'s)."""
    n = pts.shape[0]
    W = int(vp[VP_W])
    H = int(vp[VP_H])
    per = (n + nslot - 1) // nslot
    for k in range(np.uint64(slot * per), np.uint64(min(n, slot * per + per))):
        px, py, pz = pts[k, 0], pts[k, 1], pts[k, 2]
        sx, sy, z = view_project(vp, px, py, pz)
        if not (z > 0.0) or not (np.isfinite(sx) and np.isfinite(sy)) or sx < 0 or sy < 0 or sx >= W or sy >= H:
            out[k] = 1.0
            continue
        lx, ly, lz = vp[VP_ORIGIN] - px, vp[VP_ORIGIN + 1] - py, vp[VP_ORIGIN + 2] - pz
        ln = np.sqrt(lx * lx + ly * ly + lz * lz)
        c = abs(nrm[k, 0] * lx + nrm[k, 1] * ly + nrm[k, 2] * lz) / max(ln, 1e-30)
        c = min(max(c, 1e-3), 1.0)
        tan = min(np.sqrt(1.0 - c * c) / c, TAN_MAX)
        eps = z * (eps_rel + slope_eps_rel * tan)
        if not bilinear:
            out[k] = _layer_att(int(sy) * W + int(sx), z, eps, ldi_depth, ldi_count, ldi_n, inv_samples)
            continue
        u = min(max(sx - 0.5, 0.0), W - 1.0)
        v = min(max(sy - 0.5, 0.0), H - 1.0)
        j0 = int(np.floor(u))
        i0 = int(np.floor(v))
        fx = u - j0
        fy = v - i0
        j1 = min(j0 + 1, W - 1)
        i1 = min(i0 + 1, H - 1)
        a00 = _layer_att(i0 * W + j0, z, eps, ldi_depth, ldi_count, ldi_n, inv_samples)
        a01 = _layer_att(i0 * W + j1, z, eps, ldi_depth, ldi_count, ldi_n, inv_samples)
        a10 = _layer_att(i1 * W + j0, z, eps, ldi_depth, ldi_count, ldi_n, inv_samples)
        a11 = _layer_att(i1 * W + j1, z, eps, ldi_depth, ldi_count, ldi_n, inv_samples)
        out[k] = (a00 * (1.0 - fx) + a01 * fx) * (1.0 - fy) + (a10 * (1.0 - fx) + a11 * fx) * fy


def lookup_ldi(vp, ldi_depth, ldi_count, ldi_n, inv_samples, pts, nrm, eps_rel, slope_eps_rel, bilinear) -> np.ndarray:
    """:func:`lookup_ldi_slot` over every point, one slot per thread: V (K,) float32."""
    out = np.empty(pts.shape[0], np.float32)
    nslot = numba.get_num_threads()
    run_slots(
        lookup_ldi_slot, nslot, vp, ldi_depth, ldi_count, ldi_n, inv_samples, pts, nrm, eps_rel, slope_eps_rel,
        bilinear, out, nslot,
    )  # fmt: skip
    return out


def lookup(ldi: LayeredAttenuationMap, pts, nrm, bilinear: bool) -> np.ndarray:
    """V (K,) float32 at world points ``pts`` with eye-facing normals ``nrm`` from the LDI."""
    l, r, _, _ = ldi.view.window
    texel = (r - l) / ldi.view.width
    return lookup_ldi(
        ldi.view.params(),
        ldi.depth,
        ldi.count,
        ldi.nlayers,
        1.0 / ldi.samples,
        np.ascontiguousarray(pts, dtype=np.float64),
        np.ascontiguousarray(nrm, dtype=np.float64),
        float(ldi.params["epsilon"]) * texel,
        float(ldi.params["slope_epsilon"]) * texel,
        bool(bilinear),
    )


@register
class LayeredAttenuation(Method):
    name = "layered-attenuation"
    light_view = True  # renders/projects the occluders from the light (limits: softshadows.limits)
    light_shapes = ("rect", "sphere")
    summary = "layered attenuation maps: LDI of depth images from N x N light samples, precomputed once, looked up"
    paper = "Agrawala et al. 2000 (Sections 4, 6)"
    params = PARAMS

    #: what `softshadows pareto` sweeps (Method.sweep): quality is samples and LDI resolution; the
    #: timed frame is the display (the precompute is cached across frames)
    sweep: ClassVar = {"samples": [16, 64, 256], "ldi_size": [256, 512]}

    def run(self, ctx, **params):
        key = cache_key(ctx.scene, params, ctx.seed)
        ldi = _CACHE.get(key)
        reused = ldi is not None
        if reused:
            _CACHE.move_to_end(key)
            ctx.timer.times["precompute"] = 0.0
        else:
            with ctx.timer.phase("precompute"):
                ldi = build_ldi(ctx.scene, params, ctx.seed)
            _cache_put(ldi)
        pts, nrm, idx = ctx.points()
        with ctx.timer.phase("display_lookup"):
            v = lookup(ldi, pts, nrm, params["bilinear"])
            out = ctx.scatter(v, idx)
        stats = ldi.stats()
        stats["ldi_reused"] = reused
        stats["light_approximation"] = "disk facing the scene" if ctx.light.shape == "sphere" else "none"
        return MethodOutput(out, stats)


__all__ = [
    "LayeredAttenuation",
    "LayeredAttenuationMap",
    "build_ldi",
    "clear_cache",
    "display",
    "lookup",
    "precompute",
]
