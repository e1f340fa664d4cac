"""V of ``irregular`` at the working tree against another version of ``methods/irregular.py``, on
every built-in scene and light, in float64 before V's cast to float32 (a change that is exact only
to rounding, such as ``rect_edge_terms``' area against ``_rect_term``'s clipping, can be checked no
closer through ``tools/v_fingerprint.py``, whose V is float32).

    git show REV:src/softshadows/methods/irregular.py > /tmp/irregular_old.py
    PYTHONPATH=src python benchmarks/irregular_dv.py /tmp/irregular_old.py [--size 96x72]

The samples are the method's defaults (ground truth's ray origins, ``error_bound_samples``) at the
given eye resolution; both versions get the same ones. Prints per scene and light the largest
difference of 1 - V (umbral count + penumbral sum, unclamped) and whether the float32 V is the same
bit for bit; exits 1 when a difference exceeds --tol (default 1e-9).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from softshadows.api import eye_view
from softshadows.methods import irregular as cur
from softshadows.methods.base import FrameContext, Timer
from softshadows.raster import rasterize
from softshadows.scene import builtin

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from irregular_kernel_ab import load_other


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("other", help="path of the other irregular.py")
    ap.add_argument("--size", default="96x72")
    ap.add_argument("--tol", type=float, default=1e-9)
    a = ap.parse_args(argv)
    w, h = (int(x) for x in a.size.split("x"))
    other = load_other(a.other)
    worst = 0.0
    for name in builtin.builtin_scenes():
        for light in ("rect", "sphere"):
            sc = builtin.build(name, light)
            view = eye_view(sc, w, h)
            g = rasterize(view, sc.flat.vertices, sc.flat.faces, cull="none")
            ctx = FrameContext(scene=sc, eye=g, eye_view=view, timer=Timer())
            _p, nrm, idx = ctx.points()
            pts, _bound, _ext = cur.error_bound_samples(ctx.flat, ctx.eye, idx, sc.camera.eye, 0.0, sc.light)
            res = {}
            for key, mod in (("tree", cur), ("other", other)):
                v, _st, umbra, pen = mod.irregular_visibility(sc, pts, nrm, raw=True)
                res[key] = (v, umbra + pen)
            d = np.nanmax(np.abs(res["tree"][1] - res["other"][1])) if len(pts) else 0.0
            same = np.array_equal(res["tree"][0], res["other"][0])
            worst = max(worst, d)
            print(f"{name:8s} {light:6s} max |d(1 - V)| = {d:.2e}  float32 V bit for bit: {same}", flush=True)
    print(f"largest: {worst:.2e} (tolerance {a.tol:g})")
    return 1 if worst > a.tol else 0


if __name__ == "__main__":
    sys.exit(main())
