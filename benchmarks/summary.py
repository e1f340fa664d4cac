"""The summary tables of the README and docs/results/summary.md, from one command:

    python benchmarks/summary.py [--out DIR] [--size 256x192] [--samples 256] [--repeats 7]
                                 [--only errors|speed] [--scenes square,spheres,bunny]
                                 [--speed-methods all]

1. Error against ground truth of every method on square, spheres, bunny (rect and sphere light),
   through ``softshadows.compare`` (one report per scene/light under --out). Over all surface
   pixels; a method that by design shades only receivers (``Method.receivers_only``: the soft
   shadow map, no self-shadowing) gets a second row over receiver pixels only.
2. Frame time at 512x512 on bunny (rect and sphere light), medians after warm-up, with the ratio
   to ``hard`` measured in the same run (``softshadows.bench``).
Writes DIR/summary.md and prints it.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

from softshadows.bench import bench
from softshadows.compare import compare


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="summary-out")
    ap.add_argument("--size", default="256x192")
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--only", choices=("errors", "speed"), default=None, help="one of the two parts")
    ap.add_argument("--scenes", default="square,spheres,bunny", help="scenes of the error table")
    ap.add_argument(
        "--speed-methods",
        default="all",
        help="methods of the frame-time tables (all, or a,b,c; hard is always measured)",
    )
    a = ap.parse_args()
    scenes = tuple(a.scenes.split(","))
    w, h = (int(x) for x in a.size.split("x"))
    os.makedirs(a.out, exist_ok=True)
    t0 = time.time()
    lines = [
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores. "
        f"Command: `python benchmarks/summary.py --size {a.size} --samples {a.samples}`",
        "",
    ]
    err = {}
    names = None
    for scene in scenes if a.only != "speed" else ():
        for light in ("rect", "sphere"):
            r = compare(
                scene,
                "all",
                w,
                h,
                os.path.join(a.out, f"{scene}-{light}"),
                gt_samples=a.samples,
                light=light,
                verbose=False,
            )
            for m, met in r["metrics"].items():
                err.setdefault(m, {})[(scene, light)] = met
            names = names or list(r["metrics"])
    cols = [(s, l) for s in scenes for l in ("rect", "sphere")]
    lines.append(
        f"Error against ground truth ({a.samples} samples), {w}x{h}: MAE / ssm_error "
        "(mean |dV| over umbra+penumbra) over all surface pixels; '-' = light shape not supported. "
        "Methods that by design shade only receivers (no self-shadowing) have a second row, "
        "*receivers only*: the same over pixels of faces with role receiver or both."
    )
    lines.append("")
    lines.append("| method | " + " | ".join(f"{s} {l}" for s, l in cols) + " |")
    lines.append("|---|" + "---|" * len(cols))
    for m in err:
        ronly = any("receivers" in met for met in err[m].values())
        for label, pick in (
            [(f"{m} (all surfaces)", lambda x: x), (f"{m} (receivers only)", lambda x: x["receivers"])]
            if ronly
            else [(m, lambda x: x)]
        ):
            cells = []
            for c in cols:
                met = err[m].get(c)
                cells.append("-" if met is None else f"{pick(met)['mae']:.4f} / {pick(met)['ssm_error']:.3f}")
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
    if a.only == "speed":
        lines = lines[:2]
    lines.append("")
    for light in ("rect", "sphere") if a.only != "errors" else ():
        b = bench("bunny", a.speed_methods, sizes=(512,), repeats=a.repeats, warmup=1, light=light, verbose=False)
        lines.append(f"Frame time, bunny {light} light, 512x512, median of {a.repeats} after warm-up:")
        lines.append("")
        lines.append("| method | total ms | x hard | x hard per round: median (quartiles) | slowest phase |")
        lines.append("|---|---|---|---|---|")
        for rm in b["results"]:
            ph = {k: v["median"] for k, v in rm["timings"].items() if k != "total"}
            slow = max(ph, key=ph.get) if ph else ""
            pr = rm["ratio_to_hard_paired"]
            lines.append(
                f"| {rm['method']} | {rm['timings']['total']['median'] * 1e3:.1f} | {rm['ratio_to_hard']:.2f} | "
                f"{pr['median']:.2f} ({pr['q1']:.2f}-{pr['q3']:.2f}) | {slow} ({ph.get(slow, 0) * 1e3:.1f} ms) |"
            )
        lines.append("")
    lines.append(f"(wall time {time.time() - t0:.0f} s)")
    text = "\n".join(lines)
    with open(os.path.join(a.out, "summary.md"), "w") as f:
        f.write(text + "\n")
    print(text)


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    main()
