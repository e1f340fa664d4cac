"""Study of ``irregular`` (soft irregular shadow mapping, Johnson et al. 2009): docs/results/irregular.md.

    PYTHONPATH=src python benchmarks/irregular_study.py [--repeats 5] [--quick] [--out docs] [--frame-only]

1. Frame time at 512x512 on ``bunny`` (sphere light) against ``hard``, one process, the two methods
   interleaved after warm-up (median of ``repeats``), with the phase split of the paper's Table 2.
2. Table 1's trends, as plots (docs/img/irregular_*.png): time against eye samples (image size),
   against silhouette edges (tessellation of a sphere), against the light radius.
3. Overdraw: quad-bin pairs, fragments and sample tests with each optimisation off and on.
4. The two inherent errors on scenes that isolate them: the single point of projection (Sec. 5.1:
   one convex solid, growing light) and C = 0 (Sec. 5.2: two overlapping sheets, where facing and
   silhouettes are exact).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import numpy as np

from softshadows import render
from softshadows.scene import builtin
from softshadows.scene import primitives as prim
from softshadows.scene.types import Camera, Mesh, Scene, SphereLight


def timed(scene, method, w, h, **kw):
    t0 = time.perf_counter()
    r = render(scene, method, w, h, **kw)
    return time.perf_counter() - t0, r


def frame_ratio(repeats):
    sc = builtin.build("bunny", "sphere")
    timed(sc, "hard", 512, 512)
    timed(sc, "irregular", 512, 512)
    th, ti, phases = [], [], []
    for _ in range(repeats):
        th.append(timed(sc, "hard", 512, 512)[0])
        t, r = timed(sc, "irregular", 512, 512)
        ti.append(t)
        phases.append(r.timings)
    mh, mi = statistics.median(th), statistics.median(ti)
    ph = {k: statistics.median(p[k] for p in phases) for k in ("construction", "hard_kernel", "soft_kernel")}
    return {
        "hard_ms": mh * 1e3,
        "irregular_ms": mi * 1e3,
        "ratio": mi / mh,
        "phases_ms": {k: v * 1e3 for k, v in ph.items()},
        "stats": r.stats,
    }


def phase_times(scene, w, h, repeats, **kw):
    render(scene, "irregular", w, h, **kw)
    runs = [render(scene, "irregular", w, h, **kw) for _ in range(repeats)]
    # the minimum over repeats: on a shared machine the cleanest estimate of each phase's own cost
    out = {k: min(r.timings[k] for r in runs) * 1e3 for k in ("construction", "hard_kernel", "soft_kernel")}
    st = runs[-1].stats
    out.update({k: st[k] for k in ("samples", "umbra_sample_tests", "penumbra_sample_tests", "penumbra_nonzero_terms")})
    return out, st


def sphere_scene(subdiv, radius_light=0.45):
    g = Mesh(*prim.plane(8.0, 8.0, 8, 8), (0.8, 0.8, 0.8), "receiver", "ground")
    s = Mesh(*prim.icosphere(0.6, (0.0, 1.2, 0.0), subdivisions=subdiv), (0.8, 0.3, 0.3), "occluder", "sphere")
    return Scene([g, s], SphereLight((0.3, 3.0, 0.2), radius_light), Camera((0.0, 4.0, 4.0), (0.0, 0.3, 0.0)), "sphere")


def sheets_scene(radius_light=0.45):
    g = Mesh(*prim.plane(8.0, 8.0, 8, 8), (0.8, 0.8, 0.8), "receiver", "ground")
    a = Mesh(*prim.quad((-0.2, 1.0, 0.0), (0.0, 0.0, 0.8), (0.8, 0.0, 0.0)), (0.8, 0.3, 0.3), "occluder", "low")
    b = Mesh(*prim.quad((0.2, 1.4, 0.1), (0.0, 0.0, 0.8), (0.8, 0.0, 0.0)), (0.3, 0.3, 0.8), "occluder", "high")
    return Scene(
        [g, a, b], SphereLight((0.0, 3.0, 0.0), radius_light), Camera((0.0, 3.2, 3.0), (0.0, 0.3, 0.0)), "sheets"
    )


def errors(scene, w, h, samples, **kw):
    gt = render(scene, "ground-truth", w, h, samples=samples)
    r = render(scene, "irregular", w, h, **kw)
    d = (r.visibility - gt.visibility)[gt.mask]
    pen = ((gt.visibility > 0.01) & (gt.visibility < 0.99))[gt.mask]
    return {
        "mae": float(np.abs(d).mean()),
        "mae_penumbra": float(np.abs(d[pen]).mean()),
        "bias_penumbra": float(d[pen].mean()),
        "max": float(np.abs(d).max()),
    }


def main():
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="fewer points per curve")
    ap.add_argument("--out", default="docs")
    ap.add_argument("--samples", type=int, default=400)
    ap.add_argument("--frame-only", action="store_true", help="only section 1 (the ratio to hard), printed")
    a = ap.parse_args()
    res = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
    }

    res["frame"] = frame_ratio(a.repeats)
    print("frame", json.dumps({k: v for k, v in res["frame"].items() if k != "stats"}), flush=True)
    if a.frame_only:
        return

    bunny = builtin.build("bunny", "sphere")
    sizes = [128, 256, 384, 512] if not a.quick else [128, 256, 512]
    res["samples"] = []
    for n in sizes:
        ph, st = phase_times(bunny, n, n, a.repeats)
        res["samples"].append({"size": n, **ph})
        print("samples", res["samples"][-1], flush=True)

    res["edges"] = []
    for sd in (1, 2, 3, 4, 5) if not a.quick else (1, 3, 5):
        ph, st = phase_times(sphere_scene(sd), 256, 256, a.repeats)
        res["edges"].append({"subdiv": sd, "silhouette_edges": st["silhouette_edges"] + st["fold_edges"], **ph})
        print("edges", res["edges"][-1], flush=True)

    res["radius"] = []
    for f in (0.25, 0.5, 0.75, 1.0, 1.5, 2.0) if not a.quick else (0.25, 1.0, 2.0):
        sc = bunny.with_light(bunny.light.scaled(f))
        ph, st = phase_times(sc, 256, 256, a.repeats)
        res["radius"].append({"radius": sc.light.radius, **ph})
        print("radius", res["radius"][-1], flush=True)

    res["overdraw"] = {}
    for shape in ("sphere", "rect"):
        r = render(builtin.build("bunny", shape), "irregular", 512, 512, overdraw_stats=True)
        res["overdraw"][shape] = {k: v for k, v in r.stats.items() if k.startswith("overdraw_")}
        res["overdraw"][shape]["nonzero_terms"] = r.stats["penumbra_nonzero_terms"]
    print("overdraw", res["overdraw"], flush=True)

    res["sec51"] = []
    for rl in (0.15, 0.3, 0.45, 0.6):
        sc = sphere_scene(4, rl)
        e = errors(sc, 192, 144, a.samples)
        e0 = errors(sc, 192, 144, a.samples, folds=False)
        res["sec51"].append({"light_radius": rl, "folds": e, "no_folds": e0})
        print("sec51", res["sec51"][-1], flush=True)
    res["sec52"] = []
    for rl in (0.15, 0.3, 0.45, 0.6):
        e = errors(sheets_scene(rl), 192, 144, a.samples)
        res["sec52"].append({"light_radius": rl, **e})
        print("sec52", res["sec52"][-1], flush=True)

    img = os.path.join(a.out, "img")
    os.makedirs(img, exist_ok=True)
    with open(os.path.join(a.out, "results", "irregular_study.json"), "w") as f:
        json.dump(res, f, indent=1, default=float)
    plots(res, img)


def plots(res, img):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 3, figsize=(15, 8))
    phases = ("construction", "hard_kernel", "soft_kernel")
    counts = ("samples", "umbra_sample_tests", "penumbra_sample_tests", "penumbra_nonzero_terms")
    for key, xk, i, title in (
        ("samples", "samples", 0, "bunny, sphere light: vs eye samples (Table 1: O(n))"),
        ("edges", "silhouette_edges", 1, "one sphere, 256x256: vs silhouette + fold edges (O(n))"),
        ("radius", "radius", 2, "bunny, 256x256: vs light radius (O(n^2))"),
    ):
        xs = np.array([r[xk] for r in res[key]], float)
        for p in phases:
            ax[0, i].plot(xs, [r[p] for r in res[key]], "o-", label=p)
        for c in counts:
            if c != xk:
                ax[1, i].plot(xs, [r[c] for r in res[key]], "o-", label=c)
        if key == "radius":
            ys = np.array([r["penumbra_nonzero_terms"] for r in res[key]], float)
            cf = np.polyfit(xs, ys, 2)
            xx = np.linspace(xs.min(), xs.max(), 50)
            ax[1, i].plot(xx, np.polyval(cf, xx), "k:", label="quadratic fit (nonzero terms)")
        ax[0, i].set_ylabel("ms (min of repeats)")
        ax[1, i].set_ylabel("count")
        ax[0, i].set_title(title, fontsize=9)
        for r in (0, 1):
            ax[r, i].set_xlabel(xk.replace("_", " "))
            ax[r, i].legend(fontsize=7)
    plt.tight_layout()
    plt.savefig(os.path.join(img, "irregular_table1.png"), dpi=80)
    plt.close(fig)


if __name__ == "__main__":
    main()
