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
from softshadows.methods import get_method
from softshadows.metrics import compute_metrics, receiver_pixels


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
    # a method that by design shades only receivers also gets rows over receiver pixels only (as
    # the error table: compare.py's metrics["receivers"])
    recv_only = get_method(a.method).receivers_only
    keys = [(json.dumps(v), w_) for v in variants for w_ in (("all", "receivers") if recv_only else ("all",))]
    cols, rows = [], {k: [] for k in keys}
    for sc in a.scenes.split(","):
        for light in ("rect", "sphere"):
            scene = ss.load_scene(sc, light=light)
            cols.append(f"{sc} {light}")
            gt = api.render(scene, "ground-truth", w, h, samples=a.samples)
            recv = receiver_pixels(scene, w, h) if recv_only else None
            for v in variants:
                r = api.render(scene, a.method, w, h, **v)
                m = compute_metrics(r.visibility, gt.visibility, r.image, gt.image)
                rows[(json.dumps(v), "all")].append(f"{m['mae']:.4f} / {m['ssm_error']:.3f}")
                if recv_only:
                    m = compute_metrics(r.visibility, gt.visibility, r.image, gt.image, mask=recv)
                    rows[(json.dumps(v), "receivers")].append(f"{m['mae']:.4f} / {m['ssm_error']:.3f}")
    what = "all surface pixels" + (", then receiver pixels only" if recv_only else "")
    print(f"{a.method}, {a.size}, ground truth {a.samples} samples: MAE / ssm_error over {what}")
    print(f"| {a.method} | " + " | ".join(cols) + " |")
    print("|---|" + "---|" * len(cols))
    for (k, which), r in rows.items():
        label = f"`{k}`" + (f" ({which})" if recv_only else "")
        print(f"| {label} | " + " | ".join(r) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
