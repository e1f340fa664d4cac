"""Reproduce the PCSS baseline numbers of docs/results/pcss.md.

1. Speed target: PCSS full frame <= 2x ``hard`` at 512x512 on ``bunny`` (rect light), both timed
   in this process after warm-up, medians of ``--repeats`` round-robin frames (``softshadows.bench``).
2. Error of PCSS (and ``hard`` for reference) against ground truth on ``square``, ``spheres`` and
   ``bunny``, rect and sphere lights: MAE, ssm_error (Atty et al. 2006), bias, FLIP.

    PYTHONPATH=src python benchmarks/compare_baselines.py [--size 512] [--repeats 7] [--samples 256]
                                                        [--json out.json]

Prints markdown tables; exits 1 if the speed target is missed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import softshadows as ss
from softshadows.bench import bench, format_table
from softshadows.compare import jsonable
from softshadows.metrics import compute_metrics


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--samples", type=int, default=256, help="ground-truth samples per pixel")
    ap.add_argument("--error-size", type=int, default=None, help="image size of the error table (default --size)")
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    out: dict = {}

    # 1. speed: pcss vs hard, same process, after warm-up
    t0 = time.perf_counter()
    b = bench("bunny", "pcss", [a.size], repeats=a.repeats, warmup=2)
    print(format_table(b))
    ratio = next(r["ratio_to_hard"] for r in b["results"] if r["method"] == "pcss")
    ok = ratio <= 2.0
    print(
        f"\nPCSS / hard, full frame, bunny {a.size}x{a.size}: {ratio:.2f}x  (target <= 2x: {'met' if ok else 'MISSED'})\n"
    )
    out["bench"] = b
    out["pcss_over_hard"] = ratio

    # 2. error against ground truth
    n = a.error_size or a.size
    rows = []
    for scene in ("square", "spheres", "bunny"):
        for light in ("rect", "sphere"):
            sc = ss.load_scene(scene, light=light)
            gt = ss.render(sc, "ground-truth", n, n, samples=a.samples)
            for m in ("pcss", "hard"):
                r = ss.render(sc, m, n, n)
                mt = compute_metrics(r.visibility, gt.visibility, r.image, gt.image)
                rows.append({"scene": scene, "light": light, "method": m, **mt, "ms": r.timings["total"] * 1e3})
    print(f"Error against ground truth ({a.samples} samples), {n}x{n}:\n")
    print("| scene | light | method | MAE | ssm_error | MAE penumbra | bias | FLIP | ms |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['scene']} | {r['light']} | {r['method']} | {r['mae']:.4f} | {r['ssm_error']:.4f} | "
            f"{r['mae_penumbra']:.4f} | {r['bias']:+.4f} | {r['flip']:.4f} | {r['ms']:.1f} |"
        )
    out["errors"] = rows
    out["seconds"] = time.perf_counter() - t0
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(jsonable(out), fh, indent=2)
        print(f"\nwrote {a.json}")
    return 0 if ok else 1


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    sys.exit(main())
