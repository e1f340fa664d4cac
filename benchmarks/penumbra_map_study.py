"""Speed and error study of ``penumbra-map`` (Wyman & Hansen 2003).

Writes under ``--out`` (``study.json`` with every number, ``summary.md``, PNG plots):

* **speed** — full frame (``Result.timings["total"]``: eye G-buffer + method + shading) of
  ``penumbra-map`` against ``hard`` at 512 x 512 on ``bunny`` with the sphere light, one process,
  JIT warmed up, methods interleaved round-robin, medians of ``--reps`` frames
  (``softshadows.bench.bench``). Also with the ``adjacency`` silhouette path and with the light
  radius halved (the penumbra map's cost grows with the penumbra area), with the whole map shaded
  (``texels=all``, the paper's pass; same V) and with 8-triangle cones. Per-phase shares are
  compared with the paper's 30% silhouettes / 35% penumbra map / 35% render pass. Targets:
  <= 2.5x ``hard`` (the paper measured 2.3-2.9x on a 2003 GPU).
* **error** — against ``ground-truth`` (Embree, ``--gt-samples`` stratified samples) on
  ``square``, ``contact`` and ``bunny`` with the sphere light at radius x0.5 and x1.0, for
  ``penumbra-map`` and ``hard`` (``metrics.compute_metrics``: MAE, ssm_error, MAE in the
  ground truth's umbra/penumbra/lit regions, bias = mean signed error).
* ``pm_light_size.png`` — error vs light radius (``softshadows.bench.sweep``, kind
  ``light-size``) on ``square`` and ``bunny``: the umbra is the hard shadow, so the error and the
  (negative) bias grow with the light; ``pm_occluder_height.png`` — the same against occluder
  height on ``square`` (the other growth factor the paper names).

    PYTHONPATH=src python benchmarks/penumbra_map_study.py --out /tmp/pm_study
    PYTHONPATH=src python benchmarks/penumbra_map_study.py --out /tmp/pm_quick --quick
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import softshadows as ss
from softshadows.bench import bench, format_table, sweep
from softshadows.compare import jsonable
from softshadows.metrics import compute_metrics

ERROR_SCENES = ("square", "contact", "bunny")
FACTORS = (0.5, 1.0)
METHODS = ("penumbra-map", "hard")
PAPER_SHARES = {"silhouettes": 0.30, "penumbra_map": 0.35, "eye_pass": 0.35}


def speed(reps: int, size: int, verbose: bool) -> dict:
    out = {}
    base = ss.load_scene("bunny", light="sphere")
    runs = {
        "brute (default)": (base, {}),
        "texels=all (whole map)": (base, {"penumbra-map": {"texels": "all"}}),
        "adjacency": (base, {"penumbra-map": {"silhouettes": "adjacency"}}),
        "light radius x0.5": (base.with_light(base.light.scaled(0.5)), {}),
        "cone_segments=8": (base, {"penumbra-map": {"cone_segments": 8}}),
    }
    for label, (scene, params) in runs.items():
        if verbose:
            print(f"speed: {label}", flush=True)
        res = bench(
            scene, "penumbra-map", sizes=(size,), repeats=reps, warmup=1, params_by_method=params, verbose=False
        )
        print(format_table(res), flush=True)
        pm = next(r for r in res["results"] if r["method"] == "penumbra-map")
        hard = next(r for r in res["results"] if r["method"] == "hard")
        med = {k: v["median"] for k, v in pm["timings"].items()}
        own = {k: med.get(k, 0.0) for k in PAPER_SHARES}
        tot = sum(own.values())
        # one more frame for the statistics (fragments, silhouettes)
        st = ss.render(scene, "penumbra-map", size, size, **params.get("penumbra-map", {})).stats
        out[label] = {
            "ratio_to_hard": pm["ratio_to_hard"],
            "ratio_to_hard_method_phases": pm["ratio_to_hard_method"],
            "pm_total_ms": med["total"] * 1e3,
            "hard_total_ms": hard["timings"]["total"]["median"] * 1e3,
            "pm_phases_ms": {k: v * 1e3 for k, v in med.items()},
            "hard_phases_ms": {k: v["median"] * 1e3 for k, v in hard["timings"].items()},
            "shares_of_paper_phases": {k: v / tot for k, v in own.items()} if tot > 0 else {},
            "light_radius": scene.light.radius,
            "stats": {
                k: st[k]
                for k in (
                    "silhouette_edges",
                    "silhouette_vertices",
                    "silhouette_vertices_degree3plus",
                    "cones",
                    "sheets",
                    "cone_fragments",
                    "sheet_fragments",
                    "cone_fragments_kept",
                    "sheet_fragments_kept",
                    "penumbra_map_width",
                    "penumbra_texels",
                    "texels_shaded",
                    "culled_tile_pieces",
                    "value_culled_tile_pieces",
                )
                if k in st
            },
            "machine": res["machine"],
        }
    return out


def errors(size: int, gt_samples: int, verbose: bool) -> list:
    rows = []
    for name in ERROR_SCENES:
        base = ss.load_scene(name, light="sphere")
        for f in FACTORS:
            sc = base.with_light(base.light.scaled(f))
            if verbose:
                print(f"error: {name} x{f} ground truth", flush=True)
            gt = ss.render(sc, "ground-truth", size, size, samples=gt_samples)
            for m in METHODS:
                r = ss.render(sc, m, size, size)
                met = compute_metrics(r.visibility, gt.visibility)
                rows.append(
                    {
                        "scene": name,
                        "factor": f,
                        "light_radius": sc.light.radius,
                        "method": m,
                        **{
                            k: met[k]
                            for k in ("mae", "ssm_error", "mae_umbra", "mae_penumbra", "mae_lit", "bias", "rmse")
                        },
                    }
                )
    return rows


def plot_sweeps(sweeps: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for (label, data), ls in zip(sweeps.items(), ("-", "--", ":")):
        x = np.array(data["x"], float) * data.get("x_scale", 1.0)
        for m, d in data["methods"].items():
            c = "C0" if m == "penumbra-map" else "C1"
            axes[0].plot(x, d["mae"], "o" + ls, color=c, label=f"{m} ({label})")
            axes[1].plot(x, d["bias"], "o" + ls, color=c, label=f"{m} ({label})")
            axes[2].plot(x, d["ssm_error"], "o" + ls, color=c, label=f"{m} ({label})")
    xl = next(iter(sweeps.values()))["x_title"]
    for ax, yl in zip(
        axes,
        ("MAE  mean |V - V_gt|", "bias  mean (V - V_gt)  (< 0: too dark)", "ssm_error  mean |dV| over umbra+penumbra"),
    ):
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
    axes[1].axhline(0, color="k", lw=0.8)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def sweeps(size: int, gt_samples: int, values, verbose: bool, out: Path) -> dict:
    res = {}
    light_sweeps = {}
    for name in ("square", "bunny"):
        base_r = ss.load_scene(name, light="sphere").light.radius
        if verbose:
            print(f"sweep light-size on {name}", flush=True)
        d = sweep(
            name,
            "light-size",
            values=values,
            methods=",".join(METHODS),
            size=(size, size),
            light="sphere",
            gt_samples=gt_samples,
            repeats=1,
            error_key="mae",
        )
        d["x_scale"] = base_r
        d["x_title"] = "sphere light radius (world units)"
        light_sweeps[name] = d
    plot_sweeps(
        light_sweeps,
        out / "pm_light_size.png",
        f"penumbra-map vs hard against ground truth ({gt_samples} spp), light-size sweep, {size}x{size}",
    )
    res["light-size"] = light_sweeps
    if verbose:
        print("sweep occluder-height on square", flush=True)
    d = sweep(
        "square",
        "occluder-height",
        values=[0.0, 0.3, 0.6, 0.9, 1.2],
        methods=",".join(METHODS),
        size=(size, size),
        light="sphere",
        gt_samples=gt_samples,
        repeats=1,
        error_key="mae",
    )
    d["x_title"] = "occluder lift above y = 1 (world units; light at y = 3)"
    plot_sweeps(
        {"square": d},
        out / "pm_occluder_height.png",
        f"penumbra-map vs hard, occluder-height sweep on square, {size}x{size}",
    )
    res["occluder-height"] = {"square": d}
    return res


def summary_md(study: dict, cmd: str) -> str:
    lines = ["# penumbra-map study", "", f"    {cmd}", ""]
    sp = study["speed"]
    first = next(iter(sp.values()))
    mi = first["machine"]
    lines.append(
        f"Machine: {mi.get('cpu', '?')}, {mi.get('numba_threads', '?')} Numba threads. "
        f"Study wall time {study['wall_s']:.0f} s."
    )
    lines += [
        "",
        f"## Speed (bunny, sphere light, {study['size']}x{study['size']}, medians of {study['reps']} frames)",
        "",
        "| variant | light radius | penumbra-map ms | hard ms | x hard (frame) | x hard (own phases) | shares sil/pm/eye | cone frags | sheet frags |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, r in sp.items():
        sh = r["shares_of_paper_phases"]
        lines.append(
            f"| {label} | {r['light_radius']:.3f} | {r['pm_total_ms']:.1f} | {r['hard_total_ms']:.1f} | "
            f"{r['ratio_to_hard']:.2f} | {r['ratio_to_hard_method_phases']:.2f} | "
            f"{sh.get('silhouettes', 0):.0%} / {sh.get('penumbra_map', 0):.0%} / {sh.get('eye_pass', 0):.0%} | "
            f"{r['stats'].get('cone_fragments', 0):,} | {r['stats'].get('sheet_fragments', 0):,} |"
        )
    lines += [
        "",
        "Phases (ms, default variant): " + ", ".join(f"{k} {v:.1f}" for k, v in first["pm_phases_ms"].items()),
        "",
        f"## Error vs ground truth ({study['gt_samples']} spp, {study['err_size']}x{study['err_size']}, sphere light)",
        "",
        "| scene | radius | method | MAE | ssm_error | MAE umbra | MAE penumbra | MAE lit | bias |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in study["errors"]:
        lines.append(
            f"| {r['scene']} | {r['light_radius']:.3f} (x{r['factor']}) | {r['method']} | {r['mae']:.4f} | "
            f"{r['ssm_error']:.4f} | {r['mae_umbra']:.4f} | {r['mae_penumbra']:.4f} | {r['mae_lit']:.4f} | "
            f"{r['bias']:+.4f} |"
        )
    lines += ["", "## Sweeps", "", "pm_light_size.png, pm_occluder_height.png", ""]
    for kind, per in study["sweeps"].items():
        for name, d in per.items():
            xs = np.array(d["x"], float) * d.get("x_scale", 1.0)
            lines.append(f"{kind} on {name}: x = " + ", ".join(f"{x:.3g}" for x in xs))
            for m, md in d["methods"].items():
                lines.append(
                    f"  {m}: MAE "
                    + ", ".join(f"{v:.4f}" for v in md["mae"])
                    + "; bias "
                    + ", ".join(f"{v:+.4f}" for v in md["bias"])
                )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--reps", type=int, default=7, help="timed frames per method (median)")
    ap.add_argument("--gt-samples", type=int, default=256)
    ap.add_argument("--quick", action="store_true", help="small sizes, few frames (a smoke run)")
    ap.add_argument("--only", default="speed,errors,sweeps", help="comma list of parts to run")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    size = 128 if args.quick else 512
    err_size = 96 if args.quick else 256
    sw_size = 64 if args.quick else 160
    reps = 2 if args.quick else args.reps
    gts = 64 if args.quick else args.gt_samples
    values = [0.25, 0.5, 1.0] if args.quick else [0.25, 0.5, 0.75, 1.0, 1.5]
    parts = set(args.only.split(","))
    t0 = time.perf_counter()
    study = {"size": size, "reps": reps, "gt_samples": gts, "err_size": err_size, "sweep_size": sw_size}
    study["speed"] = speed(reps, size, True) if "speed" in parts else {}
    study["errors"] = errors(err_size, gts, True) if "errors" in parts else []
    study["sweeps"] = sweeps(sw_size, gts, values, True, out) if "sweeps" in parts else {}
    study["wall_s"] = time.perf_counter() - t0
    (out / "study.json").write_text(json.dumps(jsonable(study), indent=1))
    cmd = (
        "PYTHONPATH=src python benchmarks/penumbra_map_study.py --out " + str(out) + (" --quick" if args.quick else "")
    )
    if study["speed"]:
        (out / "summary.md").write_text(summary_md(study, cmd))
        print((out / "summary.md").read_text())
    print(f"wrote {out}")


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    main()
