"""The error and cost study of Atty et al. 2006 (Soft Shadow Maps), reproduced for ``soft-shadow-map``.

Writes under ``--out`` (PNG plots, ``study.json`` with every number, ``summary.md``):

* ``ssm_fig17_resolution.png`` — error vs occluder-map resolution, one- and two-pass (paper Fig. 17);
* ``ssm_fig18_light_size.png`` — error vs light size, occluder maps 64/128/256 (Fig. 18 and 24(b));
* ``ssm_fig20_height.png`` — error vs occluder vertical position, one- and two-pass (Fig. 20);
* ``ssm_fig14_fp16.png`` — FP16 vs FP32 accumulation, 128^2 and 512^2 occluder maps (Fig. 14);
* ``ssm_timing.png`` — frame time vs occluder-map pixel count (Sec. 6.2.2, linear) and the
  one-pass / two-pass / ``hard`` frame times at 512 x 512 on bunny (256^2 occluder map).

Scenes: ``square`` (planar occluder aligned with the map, the paper's "square plane"), ``spheres``
(thick, curved; stands in for the paper's Buddha) and ``bunny``.

Error (paper Sec. 5.2.1): sum over pixels of |V - V_gt| divided by the number of pixels in
umbra or penumbra in either image (``metrics.compute_metrics(...)["ssm_error"]``), over the eye
pixels that lie on *receivers* (the paper measures in the soft shadow map, i.e. on receivers;
occluder pixels get V = 1 by design). Reference: ``ground-truth`` (Embree, stratified samples).

Timings: one process, JIT warmed up, methods interleaved, median of ``--reps`` frames
(``Result.timings["total"]``: eye G-buffer + method + shading).

    PYTHONPATH=src python benchmarks/soft_shadow_map_study.py --out /tmp/ssm_study
    PYTHONPATH=src python benchmarks/soft_shadow_map_study.py --out /tmp/ssm_quick --quick
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import softshadows as ss
from softshadows.api import eye_view
from softshadows.metrics import compute_metrics
from softshadows.raster import rasterize
from softshadows.scene.types import Scene

SCENES = ("square", "spheres", "bunny")
TITLES = {"square": "(a) Square plane", "spheres": "(b) Spheres", "bunny": "(c) Bunny"}


# ---- helpers -----------------------------------------------------------------------------------
def receiver_mask(scene, w, h):
    """(H,W) bool: eye pixels whose surface is a receiver face."""
    g = rasterize(eye_view(scene, w, h), scene.flat.vertices, scene.flat.faces, cull="none")
    return g.mask & scene.flat.receiver[np.maximum(g.tri_id, 0)]


def ssm_error(v, v_gt, recv):
    a = np.where(recv, v, np.nan)
    b = np.where(recv, v_gt, np.nan)
    return float(compute_metrics(a, b)["ssm_error"])


class Reference:
    """Ground truth and receiver mask per scene variant, computed once."""

    def __init__(self, w, samples):
        self.w, self.samples, self.cache = w, samples, {}

    def get(self, key, scene):
        if key not in self.cache:
            gt = ss.render(scene, "ground-truth", self.w, self.w, samples=self.samples)
            self.cache[key] = (gt.visibility, receiver_mask(scene, self.w, self.w))
        return self.cache[key]


def error_of(ref, key, scene, **params):
    v_gt, recv = ref.get(key, scene)
    r = ss.render(scene, "soft-shadow-map", ref.w, ref.w, **params)
    return ssm_error(r.visibility, v_gt, recv), r


def moved_occluders(scene, dy):
    """The scene with its occluder-only meshes translated by ``dy`` along y."""
    m = np.eye(4)
    m[1, 3] = dy
    meshes = [mm.transformed(m) if mm.role == "occluder" else mm for mm in scene.meshes]
    return Scene(meshes, scene.light, scene.camera, scene.name)


def occluder_y_range(scene):
    flat = scene.flat
    v = flat.vertices[np.unique(flat.faces[flat.occluder & ~flat.receiver])]
    return float(v[:, 1].min()), float(v[:, 1].max())


# ---- the studies -------------------------------------------------------------------------------
def study_resolution(ref, sizes, log):
    out = {}
    for name in SCENES:
        sc = ss.load_scene(name)
        rows = []
        for n in sizes:
            e1, r1 = error_of(ref, (name,), sc, map_size=n)
            e2, _ = error_of(ref, (name,), sc, map_size=n, two_pass=True)
            rows.append({"map_size": n, "one_pass": e1, "two_pass": e2, "micro_patches": r1.stats["micro_patches"]})
            log(f"  fig17 {name:8s} N={n:5d}  one-pass {e1:.4f}  two-pass {e2:.4f}")
        out[name] = rows
    return out


def study_light_size(ref, scales, map_sizes, log):
    out = {}
    for name in SCENES:
        base = ss.load_scene(name)
        occ_v = base.flat.vertices[np.unique(base.flat.faces[base.flat.occluder])]
        occ_size = float(np.ptp(occ_v[:, [0, 2]], axis=0).max())
        rows = []
        for f in scales:
            sc = base.with_light(base.light.scaled(f))
            row = {"scale": f, "light_side": sc.light.size, "relative": sc.light.size / occ_size}
            for n in map_sizes:
                row[f"N{n}"], _ = error_of(ref, (name, "light", f), sc, map_size=n)
            row["N128_two_pass"], _ = error_of(ref, (name, "light", f), sc, map_size=128, two_pass=True)
            rows.append(row)
            log(
                f"  fig18 {name:8s} light x{f:5.3f} (side {sc.light.size:.3f})  "
                + "  ".join(f"N{n} {row[f'N{n}']:.4f}" for n in map_sizes)
            )
        out[name] = {"occluder_size": occ_size, "rows": rows}
    return out


def study_height(ref, n_steps, log):
    out = {}
    for name in SCENES:
        base = ss.load_scene(name)
        y0, y1 = occluder_y_range(base)
        light_y = float(base.light.center[1])
        # bottom of the occluder from the receiver (y = 0) up to 95% of the way to the light
        lo = 0.02 * light_y
        hi = 0.95 * light_y - (y1 - y0)
        rows = []
        for t in np.linspace(lo, hi, n_steps):
            sc = moved_occluders(base, t - y0)
            e1, _ = error_of(ref, (name, "height", round(float(t), 6)), sc, map_size=128)
            e2, _ = error_of(ref, (name, "height", round(float(t), 6)), sc, map_size=128, two_pass=True)
            pos = t / light_y  # the paper's parameter: 0 = on the receiver
            top = (t + (y1 - y0)) / light_y  # 1 = touching the light
            rows.append(
                {
                    "bottom_y": float(t),
                    "position": float(pos),
                    "top_position": float(top),
                    "one_pass": e1,
                    "two_pass": e2,
                }
            )
            log(f"  fig20 {name:8s} bottom y {t:5.2f} (top at {top:.2f} of light height)  one {e1:.4f}  two {e2:.4f}")
        out[name] = rows
    return out


def study_fp16(ref, log, out_dir):
    """Fig. 14: bunny, FP16 at 128^2 and 512^2, FP32 at 512^2, ground truth."""
    from softshadows.shading import visibility_to_rgb

    sc = ss.load_scene("bunny")
    res = {}
    imgs = []
    v_gt, recv = ref.get(("bunny",), sc)
    for n, acc in ((128, "float16"), (512, "float16"), (512, "float32"), (512, "float16-rtz")):
        r = ss.render(sc, "soft-shadow-map", ref.w, ref.w, map_size=n, accumulate=acc)
        e = ssm_error(r.visibility, v_gt, recv)
        res[f"{acc}@{n}"] = e
        log(f"  fig14 bunny N={n} {acc:12s} error {e:.4f}  fp16_safe(Eq.4)={r.stats['fp16_safe']}")
        if acc != "float16-rtz":
            imgs.append((f"{n}² {acc.upper()}", r.visibility))
    imgs.append(("ground truth", v_gt))
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 4, figsize=(10, 2.8))
    for ax, (title, v) in zip(axs, imgs):
        ax.imshow(visibility_to_rgb(v))
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out_dir / "ssm_fig14_fp16.png", dpi=72)
    plt.close(fig)
    return res


def study_timing(reps, map_sizes, log):
    sc = ss.load_scene("bunny")
    configs = {
        "hard": ("hard", {}),
        "ssm_one_pass": ("soft-shadow-map", {"map_size": 256}),
        "ssm_two_pass": ("soft-shadow-map", {"map_size": 256, "two_pass": True}),
    }
    for m, kw in configs.values():  # warm-up (JIT, caches)
        ss.render(sc, m, 512, 512, **kw)
    samples = {k: [] for k in configs}
    phases = {k: [] for k in configs}
    for _ in range(reps):  # interleaved so that machine noise hits all alike
        for k, (m, kw) in configs.items():
            t = ss.render(sc, m, 512, 512, **kw).timings
            samples[k].append(t["total"])
            phases[k].append(t)
    med = {k: float(np.median(v)) for k, v in samples.items()}
    phase_med = {k: {p: float(np.median([t[p] for t in phases[k]])) for p in phases[k][0]} for k in configs}
    ratio1 = med["ssm_one_pass"] / med["hard"]
    ratio2 = med["ssm_two_pass"] / med["ssm_one_pass"]
    log(
        f"  timing bunny 512x512: hard {med['hard'] * 1e3:.1f} ms, ssm one-pass {med['ssm_one_pass'] * 1e3:.1f} ms "
        f"(x{ratio1:.2f} hard), two-pass {med['ssm_two_pass'] * 1e3:.1f} ms (x{ratio2:.2f} one-pass)"
    )
    lin = []
    for n in map_sizes:
        ss.render(sc, "soft-shadow-map", 512, 512, map_size=n)
        ts = [ss.render(sc, "soft-shadow-map", 512, 512, map_size=n) for _ in range(reps)]
        tot = float(np.median([r.timings["total"] for r in ts]))
        ssm_t = float(np.median([r.timings["soft_shadow_map"] + r.timings["penumbra_extents"] for r in ts]))
        lin.append(
            {
                "map_size": n,
                "pixels": n * n,
                "total": tot,
                "ssm_phase": ssm_t,
                "micro_patches": ts[0].stats["micro_patches"],
                "texels_touched": ts[0].stats["texels_touched"],
            }
        )
        log(
            f"  timing N={n:4d} ({n * n:7d} px): frame {tot * 1e3:7.1f} ms, micro-patch phases {ssm_t * 1e3:7.1f} ms, "
            f"{ts[0].stats['micro_patches']} patches"
        )
    px = np.array([r["pixels"] for r in lin], float)
    fits = {}
    for key in ("total", "ssm_phase"):
        y = np.array([r[key] for r in lin])
        a, b = np.polyfit(px, y, 1)
        pred = a * px + b
        r2 = 1 - np.sum((y - pred) ** 2) / np.sum((y - y.mean()) ** 2)
        fits[key] = {"slope_ms_per_kpx": a * 1e6, "intercept_ms": b * 1e3, "r2": float(r2)}
    log(
        f"  linear fit frame time: {fits['total']['slope_ms_per_kpx']:.3f} ms per 1000 px + "
        f"{fits['total']['intercept_ms']:.1f} ms, R^2 = {fits['total']['r2']:.4f}"
    )
    return {
        "median_total_s": med,
        "phases_median_s": phase_med,
        "ratio_one_pass_vs_hard": ratio1,
        "ratio_two_pass_vs_one_pass": ratio2,
        "linearity": lin,
        "fits": fits,
        "reps": reps,
    }


# ---- plots -------------------------------------------------------------------------------------
def plot_all(data, out_dir):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def save(fig, name):
        fig.tight_layout()
        fig.savefig(out_dir / name, dpi=72)
        plt.close(fig)

    if "resolution" in data:
        fig, axs = plt.subplots(1, 3, figsize=(11, 3.2))
        for ax, name in zip(axs, SCENES):
            rows = data["resolution"][name]
            n = [r["map_size"] for r in rows]
            ax.plot(n, [r["one_pass"] for r in rows], "o-", ms=3, label="single pass")
            ax.plot(n, [r["two_pass"] for r in rows], "s--", ms=3, label="double pass")
            ax.set_title(TITLES[name], fontsize=9)
            ax.set_xlabel("Occluder map resolution (pixels)", fontsize=8)
            ax.set_ylabel("Average error", fontsize=8)
            ax.set_ylim(bottom=0)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        save(fig, "ssm_fig17_resolution.png")
    if "light_size" in data:
        fig, axs = plt.subplots(1, 3, figsize=(11, 3.2))
        for ax, name in zip(axs, SCENES):
            rows = data["light_size"][name]["rows"]
            x = [r["relative"] for r in rows]
            for key in [k for k in rows[0] if k.startswith("N") and not k.endswith("two_pass")]:
                ax.plot(x, [r[key] for r in rows], "o-", ms=3, label=f"{key[1:]}² single pass")
            ax.plot(x, [r["N128_two_pass"] for r in rows], "s--", ms=3, label="128² double pass")
            ax.set_title(TITLES[name], fontsize=9)
            ax.set_xlabel("Light size / occluder size", fontsize=8)
            ax.set_ylabel("Average error", fontsize=8)
            ax.set_ylim(bottom=0)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        save(fig, "ssm_fig18_light_size.png")
    if "height" in data:
        fig, axs = plt.subplots(1, 3, figsize=(11, 3.2))
        for ax, name in zip(axs, SCENES):
            rows = data["height"][name]
            x = [r["position"] for r in rows]
            ax.plot(x, [r["one_pass"] for r in rows], "o-", ms=3, label="single pass")
            ax.plot(x, [r["two_pass"] for r in rows], "s--", ms=3, label="double pass")
            ax.set_title(TITLES[name], fontsize=9)
            ax.set_xlabel("Occluder vertical position (bottom / light height)", fontsize=8)
            ax.set_ylabel("Average error", fontsize=8)
            ax.set_ylim(bottom=0)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        save(fig, "ssm_fig20_height.png")
    if "timing" in data:
        t = data["timing"]
        fig, axs = plt.subplots(1, 2, figsize=(9, 3.2))
        lin = t["linearity"]
        px = np.array([r["pixels"] for r in lin]) / 1000
        for key, lab, mk in (("total", "frame", "o"), ("ssm_phase", "micro-patch phases", "s")):
            y = np.array([r[key] for r in lin]) * 1e3
            f = t["fits"][key]
            axs[0].plot(px, y, mk, ms=4, label=f"{lab} (R²={f['r2']:.3f})")
            axs[0].plot(px, f["slope_ms_per_kpx"] * px + f["intercept_ms"], "-", lw=0.8, color="gray")
        axs[0].set_xlabel("Occluder map pixels (thousands)", fontsize=8)
        axs[0].set_ylabel("Time (ms)", fontsize=8)
        axs[0].set_title("bunny 512x512, SSM 256²", fontsize=9)
        axs[0].grid(alpha=0.3)
        axs[0].legend(fontsize=7)
        names = ["hard", "ssm_one_pass", "ssm_two_pass"]
        axs[1].bar(
            ["hard (1024²)", "SSM one-pass", "SSM two-pass"],
            [t["median_total_s"][k] * 1e3 for k in names],
            color=["gray", "C0", "C1"],
        )
        axs[1].set_ylabel("Frame time (ms, median)", fontsize=8)
        axs[1].set_title(
            f"bunny 512x512, 256² occluder map: one-pass = {t['ratio_one_pass_vs_hard']:.2f} x hard", fontsize=9
        )
        axs[1].tick_params(labelsize=8)
        save(fig, "ssm_timing.png")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--eye", type=int, default=128, help="eye image size (square) for the error studies")
    ap.add_argument("--samples", type=int, default=256, help="ground-truth samples per pixel")
    ap.add_argument("--reps", type=int, default=9, help="timed frames per configuration")
    ap.add_argument("--quick", action="store_true", help="fewer points (a smoke run)")
    ap.add_argument("--only", default="resolution,light_size,height,fp16,timing")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    lines = []

    def log(s):
        print(s, flush=True)
        lines.append(s)

    ref = Reference(a.eye, a.samples)
    if a.quick:
        sizes, scales, msz, steps, lin_sizes = [32, 128, 384], [0.25, 1.0, 2.0], [64, 128], 3, [64, 256, 448]
    else:
        sizes = [32, 48, 64, 96, 128, 160, 200, 256, 320, 384, 512, 640, 768, 1024]
        scales = [0.05, 0.125, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0]
        msz, steps = [64, 128, 256], 8
        lin_sizes = [64, 128, 192, 256, 320, 384, 448, 512]
    data = {"args": {"eye": a.eye, "samples": a.samples, "reps": a.reps, "quick": a.quick}}
    only = set(a.only.split(","))
    t0 = time.perf_counter()
    if "timing" in only:  # first, while nothing else has filled the caches
        log("timing (bunny, 512x512)")
        data["timing"] = study_timing(a.reps if not a.quick else 3, lin_sizes, log)
    if "resolution" in only:
        log("Fig. 17: error vs occluder map resolution")
        data["resolution"] = study_resolution(ref, sizes, log)
    if "light_size" in only:
        log("Fig. 18: error vs light size")
        data["light_size"] = study_light_size(ref, scales, msz, log)
    if "height" in only:
        log("Fig. 20: error vs occluder height (map 128)")
        data["height"] = study_height(ref, steps, log)
    plot_all(data, a.out)
    if "fp16" in only:
        log("Fig. 14: FP16 accumulation")
        data["fp16"] = study_fp16(ref, log, a.out)
    log(f"done in {time.perf_counter() - t0:.0f} s")
    (a.out / "study.json").write_text(json.dumps(data, indent=1, default=float))
    (a.out / "summary.md").write_text("```\n" + "\n".join(lines) + "\n```\n")


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    main()
