"""Cost and error study of ``occlusion-textures`` (Eisemann & Décoret 2006).

Writes under ``--out``: ``occlusion_textures_study.md`` (the tables below, also printed) and
``occlusion_textures_study.json`` (every number).

1. Prefilter time per filter (the paper's Fig. 2 table: mipmap < 1 ms, N-Buffers 3 / 11 ms, SAT
   32 / 139 ms at 256^2 / 512^2 on a GeForce 7800): the 16 occlusion textures of ``bunny`` (16 slices)
   at 256^2 and 512^2, every filter building its full structure (N-Buffers: all log2(size) levels,
   as in the paper), median of ``--reps`` after a warm-up; per 16 textures and per texture.
2. Full frame at 512 x 512 on ``bunny``, 16 slices of 256^2, against ``hard`` (default shadow map):
   one process, JIT warmed up, methods interleaved, median of ``--reps`` frames
   (``Result.timings["total"]``: eye G-buffer + method + shading), with the per-phase medians; also
   the minimum (the least disturbed frame: on a shared machine the median absorbs other processes).
3. Error against ground truth (Embree, ``--samples`` stratified light samples) for each filter
   (combine = product) and each combination mode (filter = each) on ``square``, ``spheres`` and
   ``plant`` at ``--size``^2: MAE, RMSE, bias and the soft-shadow error (``ssm_error``: mean |dV|
   over pixels in umbra or penumbra of either image); on ``square`` also MAE against the closed form.

    PYTHONPATH=src python benchmarks/occlusion_textures_study.py --out /tmp/ot_study
    PYTHONPATH=src python benchmarks/occlusion_textures_study.py --out /tmp/ot_quick --quick
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

import softshadows as ss
from softshadows.methods import occlusion_textures as ot
from softshadows.metrics import compute_metrics
from softshadows.scene.builtin import square_visibility


def bunny_textures(size: int, slices: int = 16, width: int = 512):
    """The occlusion textures of ``bunny`` as the method builds them for a width^2 frame."""
    from softshadows.api import eye_view
    from softshadows.raster import rasterize

    sc = ss.load_scene("bunny")
    flat = sc.flat
    g = rasterize(eye_view(sc, width, width), flat.vertices, flat.faces)
    pts = g.position[g.mask].astype(np.float64)
    occ_faces = np.ascontiguousarray(flat.faces[flat.occluder])
    setup = ot.fit_slicing_view(sc.light, flat.vertices[np.unique(occ_faces)], pts, size, slices)
    tex, _ = ot.slice_scene(setup, flat.vertices, occ_faces)
    return tex


def time_prefilters(reps: int) -> dict:
    out = {}
    for size in (256, 512):
        tex = bunny_textures(size)
        fns = {
            "mipmap": lambda tex=tex: ot.prefilter_mipmap(tex),
            "nbuffers": lambda tex=tex: ot.prefilter_nbuffers(tex),
            "sat": lambda tex=tex: ot.prefilter_sat(tex),
        }
        for name, fn in fns.items():
            fn()  # warm-up (JIT)
            ts = []
            for _ in range(reps):
                t0 = time.perf_counter()
                fn()
                ts.append(time.perf_counter() - t0)
            med = float(np.median(ts))
            out[f"{name}@{size}"] = {
                "filter": name,
                "size": size,
                "textures": int(tex.shape[0]),
                "median_ms": med * 1e3,
                "per_texture_ms": med * 1e3 / tex.shape[0],
                "min_ms": float(min(ts)) * 1e3,
            }
    return out


def time_frames(reps: int) -> dict:
    sc = ss.load_scene("bunny")
    runs = {
        "hard": ("hard", {}),
        "occlusion-textures (nbuffers)": ("occlusion-textures", dict(slices=16, texture_size=256)),
        "occlusion-textures (sat)": ("occlusion-textures", dict(slices=16, texture_size=256, filter="sat")),
        "occlusion-textures (mipmap)": ("occlusion-textures", dict(slices=16, texture_size=256, filter="mipmap")),
    }
    for m, kw in runs.values():  # warm-up: JIT + first-call costs
        ss.render(sc, m, 512, 512, **kw)
        ss.render(sc, m, 512, 512, **kw)
    tim = {k: [] for k in runs}
    for _ in range(reps):
        for k, (m, kw) in runs.items():
            tim[k].append(ss.render(sc, m, 512, 512, **kw).timings)
    out = {}
    for k, ts in tim.items():
        phases = {p: float(np.median([t.get(p, 0.0) for t in ts])) * 1e3 for p in ts[0]}
        phases["min_total"] = float(min(t["total"] for t in ts)) * 1e3
        out[k] = phases
    for k in out:
        out[k]["ratio_vs_hard"] = out[k]["total"] / out["hard"]["total"]
        out[k]["min_ratio_vs_hard"] = out[k]["min_total"] / out["hard"]["min_total"]
    return out


def errors(size: int, samples: int, scenes) -> list:
    rows = []
    for name in scenes:
        sc = ss.load_scene(name)
        gt = ss.render(sc, "ground-truth", size, size, samples=samples)
        cf = None
        if name == "square":
            cf = np.full(gt.visibility.shape, np.nan)
            m = np.isfinite(gt.visibility)
            cf[m] = square_visibility(gt.position[m])
            cf[m & (gt.position[..., 1] >= 1.0 - 1e-9)] = 1.0  # on/above the occluder: unoccluded
        for filt in ot.FILTERS:
            for comb in ot.COMBINES:
                r = ss.render(sc, "occlusion-textures", size, size, filter=filt, combine=comb)
                mt = compute_metrics(r.visibility, gt.visibility)
                row = {
                    "scene": name,
                    "filter": filt,
                    "combine": comb,
                    "mae": mt["mae"],
                    "rmse": mt["rmse"],
                    "bias": mt["bias"],
                    "ssm_error": mt["ssm_error"],
                }
                if cf is not None:
                    row["mae_closed_form"] = compute_metrics(r.visibility, cf)["mae"]
                rows.append(row)
        # ground-truth noise floor on the closed-form scene
        if cf is not None:
            rows.append(
                {
                    "scene": name,
                    "filter": "(ground truth)",
                    "combine": "-",
                    "mae_closed_form": compute_metrics(gt.visibility, cf)["mae"],
                }
            )
    return rows


def markdown(pre: dict, frames: dict, rows: list, args) -> str:
    L = [
        "# occlusion-textures study\n",
        f"Machine: {platform.processor() or platform.machine()}, numba threads "
        f"{__import__('numba').get_num_threads()}. Command: `PYTHONPATH=src python "
        f"benchmarks/occlusion_textures_study.py --out {args.out}" + (" --quick" if args.quick else "") + "`\n",
        "## Prefilter time (16 occlusion textures of bunny)\n",
        "| filter | size | 16 textures (ms, median) | per texture (ms) | paper, GeForce 7800 (ms) |",
        "|---|---|---|---|---|",
    ]
    paper = {
        ("mipmap", 256): "< 1",
        ("mipmap", 512): "< 1",
        ("nbuffers", 256): "3",
        ("nbuffers", 512): "11",
        ("sat", 256): "32",
        ("sat", 512): "139",
    }
    for v in pre.values():
        L.append(
            f"| {v['filter']} | {v['size']}^2 | {v['median_ms']:.2f} | {v['per_texture_ms']:.3f} | "
            f"{paper[(v['filter'], v['size'])]} |"
        )
    L += [
        "\n## Full frame, bunny 512 x 512, 16 slices of 256^2 (median ms)\n",
        "| method | total (median) | ratio vs hard (median) | total (min) | ratio vs hard (min) | phases (median) |",
        "|---|---|---|---|---|---|",
    ]
    for k, v in frames.items():
        ph = ", ".join(f"{p} {x:.1f}" for p, x in v.items() if "total" not in p and "ratio" not in p)
        L.append(
            f"| {k} | {v['total']:.1f} | {v['ratio_vs_hard']:.2f} | {v['min_total']:.1f} | "
            f"{v['min_ratio_vs_hard']:.2f} | {ph} |"
        )
    L += [
        f"\n## Error against ground truth ({args.size}^2, {args.samples} samples; texture 512^2, 16 slices)\n",
        "| scene | filter | combine | MAE | RMSE | bias | ssm_error | MAE vs closed form |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        f = lambda k, r=r: f"{r[k]:.4f}" if k in r and r[k] == r[k] else "-"  # noqa: E731
        L.append(
            f"| {r['scene']} | {r['filter']} | {r['combine']} | {f('mae')} | {f('rmse')} | {f('bias')} | "
            f"{f('ssm_error')} | {f('mae_closed_form')} |"
        )
    return "\n".join(L) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--size", type=int, default=256, help="eye image size of the error study")
    ap.add_argument("--samples", type=int, default=1024, help="ground-truth light samples")
    ap.add_argument("--quick", action="store_true", help="small images, few reps (smoke run)")
    ap.add_argument("--timing-only", action="store_true", help="skip the error study")
    args = ap.parse_args()
    if args.quick:
        args.reps, args.size, args.samples = 3, 96, 256
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    pre = time_prefilters(args.reps)
    frames = time_frames(args.reps)
    rows = [] if args.timing_only else errors(args.size, args.samples, ("square", "spheres", "plant"))
    md = markdown(pre, frames, rows, args)
    print(md)
    (out / "occlusion_textures_study.md").write_text(md)
    (out / "occlusion_textures_study.json").write_text(
        json.dumps({"prefilter": pre, "frames": frames, "errors": rows, "args": vars(args)}, indent=1)
    )


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    main()
