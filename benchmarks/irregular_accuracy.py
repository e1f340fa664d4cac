"""Error against ground truth of every real-time method on every built-in scene and both lights
(MAE and per region), through ``softshadows.compare``; the table of docs/results/irregular.md.

    PYTHONPATH=src python benchmarks/irregular_accuracy.py [--size 256x192] [--samples 256] [--out DIR]
        [--methods all|a,b] [--set irregular.offset=1e-4]
"""

from __future__ import annotations

import argparse
import json
import os

from softshadows.compare import compare, parse_method_sets
from softshadows.scene.builtin import builtin_scenes


def main():
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="256x192")
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--out", default="irregular-accuracy-out")
    ap.add_argument("--scenes", default=",".join(builtin_scenes()))
    ap.add_argument("--methods", default="all", help="'all' or a,b (ground truth is always rendered)")
    ap.add_argument("--set", action="append", default=[], metavar="METHOD.KEY=VALUE", help="method parameter")
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.split("x"))
    rows = {}
    for scene in a.scenes.split(","):
        for light in ("rect", "sphere"):
            r = compare(
                scene,
                a.methods,
                w,
                h,
                os.path.join(a.out, f"{scene}-{light}"),
                parse_method_sets(a.set),
                gt_samples=a.samples,
                light=light,
            )
            for m, met in r["metrics"].items():
                rows.setdefault(m, {})[f"{scene} {light}"] = met
            print(scene, light, {m: round(met["mae"], 4) for m, met in r["metrics"].items()}, flush=True)
    with open(os.path.join(a.out, "accuracy.json"), "w") as f:
        json.dump(rows, f, indent=1)
    cols = [f"{s} {l}" for s in a.scenes.split(",") for l in ("rect", "sphere")]
    print("| method | " + " | ".join(cols) + " |")
    print("|---|" + "---|" * len(cols))
    for m, r in rows.items():
        print(f"| {m} | " + " | ".join(f"{r[c]['mae']:.4f}" if c in r else "-" for c in cols) + " |")


if __name__ == "__main__":
    main()
