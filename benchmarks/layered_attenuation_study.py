"""Study of ``layered-attenuation`` (Agrawala et al. 2000, Sections 4 and 6).

Sections (``--only`` picks some; all by default). Numbers go to ``--out``/study.json and are
printed; plots go to ``--img`` (default docs/img):

* ``bench`` — the precompute of 64 samples into a 512 x 512 LDI on ``bunny`` (rect light), median
  of ``--reps`` after a warm-up (target <= 2 s on 2 cores), with its steps; the display frame at
  512 x 512 on ``bunny`` (``Result.timings["total"]``: eye G-buffer + lookup + shading, the LDI
  reused) against ``hard``'s full frame, one process, JIT warmed up, the two interleaved
  round-robin, medians of ``--reps`` (target <= 2x).
* ``complexity`` — the paper's Figure 10 (right): average depth complexity over non-empty LDI
  pixels as light samples are added (256 samples, 512^2 LDI), every built-in scene, rect light
  -> ``la_depth_complexity.png``.
* ``summary`` — error against ``ground-truth`` (``--gt-samples``) on every built-in scene, both
  lights, at ``--size`` with the defaults (``metrics.compute_metrics``: MAE / ssm_error / bias).
* ``artifacts`` — each known artifact with the parameter that provokes it, as V crops and
  signed-error maps against ground truth (``la_banding.png``, ``la_splat.png``,
  ``la_oblique.png``, ``la_bias.png``) and their MAE / bias:
  banding: ``samples`` 16 / 64 / 256 on ``square`` (the fixed set quantizes V into N steps);
  splat: ``splat`` on / off with a coarse ``ldi_size`` on ``fence`` (on: shadows lighter; off:
  holes, darker); oblique surfaces: ``ldi_size`` 128 / 512 / 1024 on ``contact`` (box walls
  perpendicular to the light); bias: ``epsilon`` / ``slope_epsilon`` on ``bunny`` (too small:
  the same surface splits into layers, dark acne; too large: surfaces merge, light leaks).

    PYTHONPATH=src python benchmarks/layered_attenuation_study.py --out /tmp/la_study
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

import softshadows as ss
from softshadows.compare import jsonable
from softshadows.methods import layered_attenuation as la
from softshadows.metrics import compute_metrics
from softshadows.scene.builtin import BUILTIN

M = "layered-attenuation"


def _machine() -> str:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"{platform.machine()}, {os.cpu_count()} cores, load average {load:.1f} at start"


def section_bench(reps: int) -> dict:
    """Precompute, display frame and hard's frame, interleaved round-robin after a warm-up."""
    import numba

    sc = ss.load_scene("bunny")
    p = {q.name: q.default for q in la.PARAMS}
    la.build_ldi(sc, p)  # warm-up (JIT)
    la.clear_cache()
    ss.render(sc, M, 512, 512)  # warm-up; builds and caches the LDI
    ss.render(sc, "hard", 512, 512)
    pre, steps, t_la, t_hard, phases = [], [], [], [], []
    for _ in range(reps):
        ldi = la.build_ldi(sc, p)
        pre.append(ldi.precompute_s)
        steps.append(ldi.steps)
        r = ss.render(sc, M, 512, 512)
        assert r.timings["precompute"] == 0.0
        t_la.append(r.timings["total"])
        phases.append(r.timings)
        t_hard.append(ss.render(sc, "hard", 512, 512).timings["total"])
    med = {k: float(np.median([s[k] for s in steps])) for k in steps[0]}
    out = {
        "threads": numba.get_num_threads(),
        "precompute_s_median": float(np.median(pre)),
        "precompute_s_all": pre,
        "precompute_steps_median_s": med,
        "ldi": ldi.stats(),
        "display_ms_median": 1e3 * float(np.median(t_la)),
        "hard_ms_median": 1e3 * float(np.median(t_hard)),
        "display_phases_ms_median": {k: 1e3 * float(np.median([t[k] for t in phases])) for k in phases[0]},
    }
    out["display_x_hard"] = out["display_ms_median"] / out["hard_ms_median"]
    out["precompute_in_hard_frames"] = 1e3 * out["precompute_s_median"] / out["hard_ms_median"]
    print(
        f"precompute 64 samples, 512^2 LDI, bunny, {out['threads']} threads: {out['precompute_s_median']:.2f} s "
        f"(median of {reps}; = {out['precompute_in_hard_frames']:.1f} hard frames); "
        f"steps { ({k: round(v, 3) for k, v in med.items()}) }"
    )
    print(
        f"display 512x512 bunny: {out['display_ms_median']:.1f} ms vs hard {out['hard_ms_median']:.1f} ms "
        f"= {out['display_x_hard']:.2f}x"
    )
    return out


def section_complexity(img: Path) -> dict:
    import matplotlib.pyplot as plt

    out = {}
    fig, ax = plt.subplots(figsize=(6, 4))
    for name in BUILTIN:
        ldi = la.precompute(ss.load_scene(name), samples=256, ldi_size=512)
        c = ldi.complexity
        out[name] = {"curve": c.tolist(), "final": float(c[-1]), "stats": ldi.stats()}
        ax.plot(np.arange(1, len(c) + 1), c, label=name)
        print(f"{name}: depth complexity {c[0]:.3f} (1 sample) {c[15]:.3f} (16) {c[63]:.3f} (64) {c[-1]:.3f} (256)")
    la.clear_cache()
    ax.set_xlabel("light samples")
    ax.set_ylabel("average depth complexity (non-empty LDI pixels)")
    ax.set_title("LDI depth complexity vs light samples (Fig. 10 right), 512^2 LDI", fontsize=10)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(img / "la_depth_complexity.png", dpi=110)
    plt.close(fig)
    return out


def _gt(sc, w, h, samples):
    return ss.render(sc, "ground-truth", w, h, samples=samples)


def section_summary(w: int, h: int, gt_samples: int) -> dict:
    out = {}
    for name in BUILTIN:
        for light in ("rect", "sphere"):
            sc = ss.load_scene(name, light=light)
            g = _gt(sc, w, h, gt_samples)
            la.clear_cache()
            r = ss.render(sc, M, w, h)
            met = compute_metrics(r.visibility, g.visibility)
            out[f"{name}/{light}"] = {k: met[k] for k in ("mae", "ssm_error", "bias", "mae_penumbra")}
            print(f"{name:8s} {light:6s} MAE {met['mae']:.4f} ssm {met['ssm_error']:.3f} bias {met['bias']:+.4f}")
    la.clear_cache()
    return out


def _panel(img: Path, fname: str, title: str, gt, runs: list, crop):
    """One row per setting: V crop and signed error crop; the ground truth's V on the first row."""
    import textwrap

    import matplotlib.pyplot as plt

    r0, r1, c0, c1 = crop
    fig, axes = plt.subplots(2, len(runs) + 1, figsize=(3.0 * (len(runs) + 1), 5.2))
    fig.suptitle(textwrap.fill(title, 110), fontsize=9)
    axes[0, 0].imshow(gt.visibility[r0:r1, c0:c1], cmap="gray", vmin=0, vmax=1)
    axes[0, 0].set_title("ground truth V", fontsize=9)
    axes[1, 0].axis("off")
    for i, (label, r, met) in enumerate(runs, start=1):
        axes[0, i].imshow(r.visibility[r0:r1, c0:c1], cmap="gray", vmin=0, vmax=1)
        axes[0, i].set_title(label, fontsize=9)
        d = r.visibility - gt.visibility
        axes[1, i].imshow(d[r0:r1, c0:c1], cmap="RdBu", vmin=-0.5, vmax=0.5)
        axes[1, i].set_title(f"V - V_ref (red darker)\nMAE {met['mae']:.4f}, bias {met['bias']:+.4f}", fontsize=8)
    for a in axes.ravel():
        a.set_xticks([])
        a.set_yticks([])
    fig.tight_layout()
    fig.savefig(img / fname, dpi=100)
    plt.close(fig)


def section_artifacts(img: Path, gt_samples: int) -> dict:
    out = {}
    W, H = 320, 240
    cases = [
        (
            "banding",
            "square",
            "rect",
            [("samples=16", dict(samples=16)), ("samples=64", dict(samples=64)), ("samples=256", dict(samples=256))],
            (80, 200, 60, 260),
            "Banding: the same N x N light samples for every point quantize V into steps across the penumbra "
            "(parameter: samples).",
        ),
        (
            "splat",
            "fence",
            "rect",
            [
                ("splat on, ldi_size=256", dict(ldi_size=256)),
                ("splat off, ldi_size=256", dict(ldi_size=256, splat=False)),
                ("splat on, ldi_size=1024", dict(ldi_size=1024)),
            ],
            (60, 220, 40, 280),
            "Splat: each warped pixel fills 2x2 LDI pixels, so lit surfaces grow by up to one LDI pixel per "
            "sample and shadows get lighter (blue); without it, holes (red). Parameters: splat, ldi_size.",
        ),
        (
            "oblique",
            "contact",
            "rect",
            [
                ("ldi_size=128", dict(ldi_size=128)),
                ("ldi_size=512", dict(ldi_size=512)),
                ("ldi_size=1024", dict(ldi_size=1024)),
            ],
            (40, 200, 40, 240),
            "Undersampling: the box walls are perpendicular to the light, so the depth images sample them "
            "in a few pixels; their V errs, less with a finer LDI (parameter: ldi_size).",
        ),
        (
            "bias",
            "bunny",
            "rect",
            [
                ("epsilon=0.25, slope 0", dict(epsilon=0.25, slope_epsilon=0.0)),
                ("epsilon=2, slope 1 (default)", dict()),
                ("epsilon=12, slope 4", dict(epsilon=12.0, slope_epsilon=4.0)),
            ],
            (70, 230, 70, 270),
            "Bias: too small a tolerance splits one surface into several layers (dark acne, red); too large "
            "merges the bunny with the ground and itself (light leaks, blue). Parameters: epsilon, slope_epsilon.",
        ),
    ]
    for key, name, light, settings, crop, title in cases:
        sc = ss.load_scene(name, light=light)
        g = _gt(sc, W, H, gt_samples)
        runs = []
        res = {}
        for label, kw in settings:
            r = ss.render(sc, M, W, H, **kw)
            met = compute_metrics(r.visibility, g.visibility)
            runs.append((label, r, met))
            res[label] = {k: met[k] for k in ("mae", "bias", "mae_penumbra", "bias_penumbra")}
            res[label]["ldi"] = r.stats
            print(f"{key}: {name} {label}: MAE {met['mae']:.4f} bias {met['bias']:+.4f}")
        la.clear_cache()
        _panel(img, f"la_{key}.png", title, g, runs, crop)
        out[key] = res
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/la_study")
    ap.add_argument("--img", default="docs/img")
    ap.add_argument("--only", default="bench,complexity,summary,artifacts")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--size", default="256x192")
    ap.add_argument("--gt-samples", type=int, default=256)
    a = ap.parse_args()
    out, img = Path(a.out), Path(a.img)
    out.mkdir(parents=True, exist_ok=True)
    img.mkdir(parents=True, exist_ok=True)
    w, h = (int(x) for x in a.size.split("x"))
    res = {"machine": _machine(), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    t0 = time.time()
    only = a.only.split(",")
    if "bench" in only:
        res["bench"] = section_bench(a.reps)
    if "complexity" in only:
        res["complexity"] = section_complexity(img)
    if "summary" in only:
        res["summary"] = section_summary(w, h, a.gt_samples)
    if "artifacts" in only:
        res["artifacts"] = section_artifacts(img, a.gt_samples)
    res["wall_s"] = time.time() - t0
    name = "study.json" if len(only) == 4 else f"study_{'_'.join(only)}.json"
    (out / name).write_text(json.dumps(jsonable(res), indent=1))
    print(f"wrote {out / name} ({res['wall_s']:.0f} s)")


if __name__ == "__main__":
    main()
