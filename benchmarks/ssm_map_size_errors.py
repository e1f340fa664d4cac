"""Error of ``soft-shadow-map`` against ground truth (256 samples, 256x192) at several occluder-map
and SSM sizes (default: occluder maps 256 (the default), 192 and 128 with the SSM at 256), on every
built-in scene, both lights: MAE / ssm_error over all surfaces and over receiver pixels (the error
table's two rows). Ground truth is rendered once per scene and light. ~10 min on 2 cores:

    PYTHONPATH=src python benchmarks/ssm_map_size_errors.py
    PYTHONPATH=src python benchmarks/ssm_map_size_errors.py --light sphere --sizes 256:256,256:192,192:192

``--sizes``: comma-separated ``map_size:ssm_size`` pairs (``map_size`` alone keeps the SSM at 256).
"""

from __future__ import annotations

import argparse
import sys

from softshadows import api
from softshadows.compare import load
from softshadows.metrics import compute_metrics, receiver_pixels

SCENES = ("square", "spheres", "fence", "contact", "plant", "bunny")


def _pairs(text: str) -> list[tuple[int, int]]:
    out = []
    for item in text.split(","):
        ms, _, ss = item.partition(":")
        out.append((int(ms), int(ss) if ss else 256))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="256,192,128", help="map_size[:ssm_size],... (default 256,192,128)")
    ap.add_argument("--light", default="rect,sphere", help="rect, sphere or both (default)")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--size", default="256x192", help="eye view WxH (default 256x192)")
    ap.add_argument("--samples", type=int, default=256, help="ground-truth samples per point")
    a = ap.parse_args()
    W, H = (int(v) for v in a.size.split("x"))
    sizes = _pairs(a.sizes)
    print("scene light map_size:ssm_size: MAE / ssm_error (all surfaces), MAE / ssm_error (receivers)")
    for scene in a.scenes.split(","):
        for light in a.light.split(","):
            sc = load(scene, light)
            gt = api.render(sc, "ground-truth", W, H, samples=a.samples)
            recv = receiver_pixels(sc, W, H)
            for ms, ss in sizes:
                r = api.render(sc, "soft-shadow-map", W, H, map_size=ms, ssm_size=ss)
                m = compute_metrics(r.visibility, gt.visibility, r.image, gt.image)
                b = compute_metrics(r.visibility, gt.visibility, r.image, gt.image, mask=recv)
                print(
                    f"{scene} {light} {ms}:{ss}: {m['mae']:.4f} / {m['ssm_error']:.3f}  "
                    f"{b['mae']:.4f} / {b['ssm_error']:.3f}",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
