"""Error against ground truth of one method under several parameter sets, on the error table's
scenes and both lights: the rows of ``benchmarks/summary.py --only errors`` (MAE / ssm_error over all
surface pixels, ``metrics.compute_metrics``), for the one method only, with the ground truth
rendered once per scene and light. For checking that a default change keeps the quality.

    PYTHONPATH=src python benchmarks/param_errors.py penumbra-map \\
        '{"cone_segments": 16, "sheet_tolerance": 0.005}' '{"cone_segments": 8, "sheet_tolerance": 0.02}'
"""

from __future__ import annotations

import argparse
import json

import softshadows as ss
from softshadows import api
from softshadows.metrics import compute_metrics


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("method")
    ap.add_argument("variants", nargs="+", help="parameter sets as JSON objects ({} = the defaults)")
    ap.add_argument("--scenes", default="square,spheres,fence,contact,plant,bunny")
    ap.add_argument("--size", default="256x192")
    ap.add_argument("--samples", type=int, default=256, help="ground-truth light samples (as summary.py)")
    a = ap.parse_args()
    w, h = (int(x) for x in a.size.split("x"))
    variants = [json.loads(v) for v in a.variants]
    cols, rows = [], {json.dumps(v): [] for v in variants}
    for sc in a.scenes.split(","):
        for light in ("rect", "sphere"):
            scene = ss.load_scene(sc, light=light)
            cols.append(f"{sc} {light}")
            gt = api.render(scene, "ground-truth", w, h, samples=a.samples)
            for v in variants:
                r = api.render(scene, a.method, w, h, **v)
                m = compute_metrics(r.visibility, gt.visibility, r.image, gt.image)
                rows[json.dumps(v)].append(f"{m['mae']:.4f} / {m['ssm_error']:.3f}")
    print(f"{a.method}, {a.size}, ground truth {a.samples} samples: MAE / ssm_error over all surface pixels")
    print(f"| {a.method} | " + " | ".join(cols) + " |")
    print("|---|" + "---|" * len(cols))
    for k, r in rows.items():
        print(f"| `{k}` | " + " | ".join(r) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
