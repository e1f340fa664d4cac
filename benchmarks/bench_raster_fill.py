"""Fill-rate benchmark and bit-exactness check of the shared rasterizer's tile kernel.

    PYTHONPATH=src python benchmarks/bench_raster_fill.py --save   [--ref /tmp/raster_ref.npz]
    PYTHONPATH=src python benchmarks/bench_raster_fill.py --check  [--ref /tmp/raster_ref.npz]
    PYTHONPATH=src python benchmarks/bench_raster_fill.py --bench  [--runs 15] [--renders 9]

``--save`` writes the outputs of rasterize (G-buffer), rasterize_depth, rasterize_fragments and
rasterize_min_blend (PROGRAM_ATTRIBUTE, random per-corner attribute, and PROGRAM_PENUMBRA on a
synthetic image) on a set of views (eye view of every built-in scene, 1024^2 light view, an
orthographic light view, a perspective view whose near plane clips the ground, a view whose far plane
cuts the scene, back-face culling, random-triangle stress meshes with vertices on pixel centers)
plus the visibility of ``render(..., "hard" / "penumbra-map")``; ``--check`` recomputes them and
compares exactly (reports max abs / rel differences of float outputs if they are not identical).
The penumbra-program min-blend is also run with hierarchical culling (``cull_discarded=True``); its
output is stored only if it equals the unculled one, so ``--check`` fails if culling changes a texel.
``--bench`` times the fill-bound paths (median of ``--runs`` runs).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time

import numpy as np

import softshadows
from softshadows.api import eye_view
from softshadows.raster import View, rasterize, rasterize_depth, rasterize_fragments, rasterize_min_blend
from softshadows.raster.programs import PROGRAM_ATTRIBUTE, PROGRAM_PENUMBRA
from softshadows.scene.builtin import BUILTIN

shadowmap = importlib.import_module("softshadows.methods.shadowmap")


def stress_mesh(rng, n, W, H, mode):
    """Random triangles in screen-ish space put at z in [1, 3] in front of an ortho view."""
    if mode == "grid":  # vertices exactly on pixel centers / pixel corners: many e == 0 cases
        xy = (rng.integers(-4, 2 * W + 4, size=(n * 3, 2)) * 0.5).astype(float)
    elif mode == "big":  # large and slivery triangles, many beyond the image
        xy = rng.uniform(-3 * W, 4 * W, size=(n * 3, 2))
    elif mode == "huge":  # bounding boxes far beyond 16384 px: inexact edge functions
        xy = rng.uniform(-1e6, 1e6, size=(n * 3, 2))
        xy[::3] = rng.uniform(0, W, size=(n, 2))
    else:
        xy = rng.uniform(-8, W + 8, size=(n * 3, 2))
    z = rng.uniform(1.0, 3.0, size=(n * 3, 1))
    # ortho view along +z with up +y has right = -x; window (0, W, 0, H): x = -sx, y = H - sy
    V = np.concatenate([-xy[:, :1], H - xy[:, 1:2], z], axis=1)
    F = np.arange(n * 3, dtype=np.int64).reshape(n, 3)
    return V, F


def cases():
    """Yield (name, view, vertices, faces, cull)."""
    for name in BUILTIN:
        sc = softshadows.load_scene(name)
        fl = sc.flat
        ev = eye_view(sc, 256, 192)
        yield f"{name}/eye", ev, fl.vertices, fl.faces, "none"
        if name in ("bunny", "plant", "fence", "spheres"):
            yield f"{name}/light1024", shadowmap.fit_light_view(sc, 1024), fl.vertices, fl.faces, "none"
        if name in ("bunny", "contact", "square"):
            ov = shadowmap.fit_light_view(sc, 384, ortho=True, height=320)
            yield f"{name}/ortho", ov, fl.vertices, fl.faces, "none"
            yield f"{name}/eye_back", ev, fl.vertices, fl.faces, "back"
        if name in ("bunny", "fence", "plant"):
            lo, hi = sc.bounds()
            c = (lo + hi) / 2
            ext = float(np.linalg.norm(hi - lo))
            # low camera inside the scene's box, looking across the ground, large near plane:
            # ground (and other) triangles cross the near plane and get clipped
            eye = np.array([lo[0] + 0.1 * (hi[0] - lo[0]), lo[1] + 0.05 * ext, lo[2] + 0.1 * (hi[2] - lo[2])])
            v = View.look_at(eye, [c[0], lo[1], c[2]], [0, 1, 0], 70, 200, 160, near=0.15 * ext, far=10 * ext)
            yield f"{name}/nearclip", v, fl.vertices, fl.faces, "none"
            v2 = View.look_at(eye, [c[0], lo[1], c[2]], [0, 1, 0], 70, 200, 160, near=1e-3, far=0.5 * ext)
            yield f"{name}/farcut", v2, fl.vertices, fl.faces, "none"
    rng = np.random.default_rng(1234)
    for mode in ("grid", "big", "small", "huge"):
        W, H = 97, 71
        V, F = stress_mesh(rng, 400, W, H, mode)
        v = View.frame([0, 0, 0], [0, 0, 1], [0, 1, 0], (0, W, 0, H), 0.0, 10.0, W, H, ortho=True)
        yield f"stress_{mode}/ortho", v, V, F, "none"
        # same triangles through a perspective view (x/z, y/z window)
        Vp = V.copy()
        Vp[:, 0] = (V[:, 0] / W * 2 + 1) * V[:, 2]
        Vp[:, 1] = (V[:, 1] / H * 2 - 1) * V[:, 2]
        vp = View.frame([0, 0, 0], [0, 0, 1], [0, 1, 0], (-1, 1, -1, 1), 0.5, 10.0, W, H)
        yield f"stress_{mode}/persp", vp, Vp, F, "none"


def compute():
    out = {}
    rng = np.random.default_rng(7)
    for name, view, V, F, cull in cases():
        g = rasterize(view, V, F, cull=cull)
        for k in ("position", "normal", "depth", "tri_id", "bary", "mask"):
            out[f"{name}|gbuf.{k}"] = getattr(g, k)
        d, t = rasterize_depth(view, V, F, cull=cull)
        out[f"{name}|depth.depth"] = d
        out[f"{name}|depth.tri"] = t
        fr = rasterize_fragments(view, V, F, cull=cull)
        for k in ("pixel", "tri", "bary", "depth"):
            out[f"{name}|frag.{k}"] = getattr(fr, k)
        H, W = d.shape
        ca = rng.random((len(F), 3))
        blend = rng.random((H, W)).astype(np.float32)
        blend[rng.random((H, W)) < 0.3] = np.inf
        st = rasterize_min_blend(
            view,
            V,
            F,
            PROGRAM_ATTRIBUTE,
            ca,
            np.zeros((H, W), np.float32),
            np.zeros(1),
            blend,
            cull=cull,
            split=len(F) // 2,
        )
        out[f"{name}|minblend.attr"] = blend
        out[f"{name}|minblend.attr.stats"] = np.array([st[k] for k in _BLEND_STATS])
        # penumbra program: attribute ~ a depth, image = a depth map (the scene's own, pushed back)
        zs = float(d[np.isfinite(d)].max()) if np.isfinite(d).any() else 1.0
        za = rng.uniform(0.0, 2.0, size=(len(F), 3)) * zs
        img = np.where(np.isfinite(d), d * 1.05 + 0.01, np.inf).astype(np.float32)
        blend2 = np.ones((H, W), np.float32)
        st = rasterize_min_blend(
            view, V, F, PROGRAM_PENUMBRA, za, img, np.array([0.5, 0.001, 1.0]), blend2, cull=cull, split=len(F) // 3
        )
        out[f"{name}|minblend.pen"] = blend2
        out[f"{name}|minblend.pen.stats"] = np.array([st[k] for k in _BLEND_STATS])
        # hierarchical culling of discarded fragments must not change the output (compared with the
        # reference of the unculled pass) nor the kept counts
        blend3 = np.ones((H, W), np.float32)
        st3 = rasterize_min_blend(
            view,
            V,
            F,
            PROGRAM_PENUMBRA,
            za,
            img,
            np.array([0.5, 0.001, 1.0]),
            blend3,
            cull=cull,
            split=len(F) // 3,
            cull_discarded=True,
        )
        out[f"{name}|minblend.pen"] = blend3 if np.array_equal(blend2, blend3) else np.full_like(blend3, -1.0)
        if (st3["kept_a"], st3["kept_b"]) != (st["kept_a"], st["kept_b"]):
            out[f"{name}|minblend.pen.stats"] = -out[f"{name}|minblend.pen.stats"]
    for sc_name, light in (("bunny", "sphere"), ("plant", "rect")):
        sc = softshadows.load_scene(sc_name, light=light)
        for m in ("hard", "penumbra-map"):
            r = softshadows.render(sc, m, 160, 120)
            out[f"render/{sc_name}/{m}|visibility"] = r.visibility
    return out


_BLEND_STATS = ("fragments_a", "fragments_b", "kept_a", "kept_b")


def check(ref_path):
    ref = np.load(ref_path)
    new = compute()
    bad = 0
    for k in sorted(set(ref.files) | set(new)):
        if k not in ref.files or k not in new:
            print("MISSING", k)
            bad += 1
            continue
        a, b = ref[k], new[k]
        if a.shape != b.shape or a.dtype != b.dtype:
            print("SHAPE/DTYPE", k, a.shape, b.shape, a.dtype, b.dtype)
            bad += 1
            continue
        if np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
            continue
        bad += 1
        if a.dtype.kind == "f":
            fin = np.isfinite(a) & np.isfinite(b)
            same_inf = np.array_equal(np.isfinite(a), np.isfinite(b))
            da = np.abs(a[fin].astype(float) - b[fin].astype(float))
            rel = da / np.maximum(np.abs(a[fin].astype(float)), 1e-30)
            ndiff = int((a != b).sum() - (np.isnan(a) & np.isnan(b)).sum())
            print(
                f"DIFF {k}: {ndiff} of {a.size} differ, max abs {da.max() if da.size else 0:.3g}, "
                f"max rel {rel.max() if rel.size else 0:.3g}, same finiteness {same_inf}"
            )
        else:
            print(f"DIFF {k}: {int((a != b).sum())} of {a.size} differ")
    print(f"{len(ref.files)} arrays compared, {bad} differ")
    return bad == 0


def bench(runs, renders):
    import numba

    print("threads", numba.get_num_threads())

    def med(fn, n):
        fn()
        ts = []
        for _ in range(n):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        return np.median(ts) * 1e3, np.min(ts) * 1e3

    sc = softshadows.load_scene("bunny")
    fl = sc.flat
    ev = eye_view(sc, 512, 512)
    lv = shadowmap.fit_light_view(sc, 1024)
    occ = np.ascontiguousarray(fl.faces[fl.occluder])
    res = {}
    res["eye gbuffer 512^2 bunny"] = med(lambda: rasterize(ev, fl.vertices, fl.faces), runs)
    res["depth 1024^2 light bunny (all faces)"] = med(lambda: rasterize_depth(lv, fl.vertices, fl.faces), runs)
    res["depth 1024^2 light bunny (occluders)"] = med(lambda: rasterize_depth(lv, fl.vertices, occ), runs)
    res["fragments 1024^2 light bunny (occluders)"] = med(lambda: rasterize_fragments(lv, fl.vertices, occ), runs)
    H, W = lv.height, lv.width
    ca = np.random.default_rng(0).random((len(fl.faces), 3))
    img = np.zeros((H, W), np.float32)
    buf = np.empty((H, W), np.float32)

    def mb():
        buf.fill(np.inf)
        rasterize_min_blend(lv, fl.vertices, fl.faces, PROGRAM_ATTRIBUTE, ca, img, np.zeros(1), buf)

    res["min_blend attr 1024^2 light bunny"] = med(mb, runs)
    for k, (m, mn) in res.items():
        print(f"{k:45s} median {m:8.2f} ms   min {mn:8.2f} ms")
    scs = softshadows.load_scene("bunny", light="sphere")
    for meth in ("hard", "penumbra-map"):
        softshadows.render(scs, meth, 512, 512)
        tims = [softshadows.render(scs, meth, 512, 512).timings for _ in range(renders)]
        keys = tims[0].keys()
        s = ", ".join(f"{k} {np.median([t[k] for t in tims]) * 1e3:.2f}" for k in keys)
        print(f"render bunny/sphere {meth} 512^2 (median ms of {renders}): {s}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--save", action="store_true")
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--bench", action="store_true")
    ap.add_argument("--ref", default="/tmp/raster_ref.npz")
    ap.add_argument("--runs", type=int, default=15)
    ap.add_argument("--renders", type=int, default=9)
    a = ap.parse_args()
    ok = True
    if a.save:
        out = compute()
        np.savez(a.ref, **out)
        print(f"saved {len(out)} arrays to {a.ref}")
    if a.check:
        ok = check(a.ref)
    if a.bench or not (a.save or a.check):
        bench(a.runs, a.renders)
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    main()
