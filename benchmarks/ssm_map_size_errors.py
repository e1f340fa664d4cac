"""Error of ``soft-shadow-map`` against ground truth (256 samples, 256x192) at occluder-map sizes
256 (the default), 192 and 128, on every built-in scene, both lights: MAE / ssm_error over all
surfaces and over receiver pixels (the error table's two rows). Ground truth is rendered once per
scene and light. ~10 min on 2 cores:

    PYTHONPATH=src python benchmarks/ssm_map_size_errors.py
"""

from __future__ import annotations

import sys

from softshadows import api
from softshadows.compare import load
from softshadows.metrics import compute_metrics, receiver_pixels

W, H = 256, 192
SIZES = (256, 192, 128)


def main() -> int:
    print("scene light map_size: MAE / ssm_error (all surfaces), MAE / ssm_error (receivers)")
    for scene in ("square", "spheres", "fence", "contact", "plant", "bunny"):
        for light in ("rect", "sphere"):
            sc = load(scene, light)
            gt = api.render(sc, "ground-truth", W, H, samples=256)
            recv = receiver_pixels(sc, W, H)
            for ms in SIZES:
                r = api.render(sc, "soft-shadow-map", W, H, map_size=ms)
                a = compute_metrics(r.visibility, gt.visibility, r.image, gt.image)
                b = compute_metrics(r.visibility, gt.visibility, r.image, gt.image, mask=recv)
                print(
                    f"{scene} {light} {ms}: {a['mae']:.4f} / {a['ssm_error']:.3f}  {b['mae']:.4f} / {b['ssm_error']:.3f}",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
