"""In-process A/B of ``irregular``'s penumbra pass (step d, ``accumulate_penumbrae``): the working
tree's against another version of ``methods/irregular.py``, on the same grid, edges and quads.

    git show REV:src/softshadows/methods/irregular.py > /tmp/irregular_old.py
    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/irregular_kernel_ab.py /tmp/irregular_old.py \\
        [--lights sphere,rect] [--size 512] [--repeats 9] [--threads 1]

Both run in one process, alternately, after a warm-up call; times are CPU seconds (process_time),
which on a shared, overloaded machine track the work better than wall time. The inputs are built
once with the working tree's code at ``origin=gbuffer offset=1e-4`` (the samples do not matter
for the comparison, only that both versions get the same ones); the other version must accept
``accumulate_penumbrae(grid, edges, qd, bins, light, per_bin, wedge)``. Prints the medians, their
ratio and the largest difference of the penumbral sums.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time

import numba
import numpy as np

from softshadows.api import eye_view
from softshadows.methods import irregular as cur
from softshadows.methods.base import FrameContext, Timer
from softshadows.raster import rasterize
from softshadows.scene import builtin


def load_other(path):
    spec = importlib.util.spec_from_file_location("softshadows.methods._irregular_other", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def inputs(light, n):
    sc = builtin.build("bunny", light)
    view = eye_view(sc, n, n)
    g = rasterize(view, sc.flat.vertices, sc.flat.faces, cull="none")
    pts, nrm, _idx = FrameContext(scene=sc, eye=g, eye_view=view, timer=Timer()).points()
    lo, hi = sc.bounds()
    p = cur.offset_points(pts, nrm, 1e-4 * float(np.linalg.norm(hi - lo)))
    grid = cur.build_sample_grid(sc.light, p, 128, 8, 16)
    fc = cur.facing_and_counted(sc.flat, sc.light.center)
    box = (grid.col_box[:, :3].min(axis=0), grid.col_box[:, 3:].max(axis=0))
    br = cur._light_params(sc.light)[1]
    edges, _st = cur.select_silhouette_edges(sc.flat, sc.light.center, "adjacency", True, box, br, fc)
    qd = cur.build_penumbra_quads(grid, edges, sc.light, br)
    return sc.light, grid, edges, qd, cur.bin_penumbra_quads(grid, qd, br, True)


def main():
    from softshadows import tune_malloc

    tune_malloc()
    ap = argparse.ArgumentParser()
    ap.add_argument("other", help="path of the other irregular.py")
    ap.add_argument("--lights", default="sphere,rect")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    numba.set_num_threads(a.threads)
    other = load_other(a.other)
    for light in a.lights.split(","):
        lt, grid, edges, qd, bins = inputs(light, a.size)
        runs = {"tree": cur, "other": other}
        pen = {k: m.accumulate_penumbrae(grid, edges, qd, bins, lt, True, True)[0] for k, m in runs.items()}  # warm-up
        ts = {k: [] for k in runs}
        for _ in range(a.repeats):
            for k, m in runs.items():
                t0 = time.process_time()
                m.accumulate_penumbrae(grid, edges, qd, bins, lt, True, True)
                ts[k].append(time.process_time() - t0)
        mt, mo = np.median(ts["tree"]), np.median(ts["other"])
        print(
            f"{light}: tree {mt * 1e3:.1f} ms, other {mo * 1e3:.1f} ms (CPU, median of {a.repeats}), "
            f"other/tree {mo / mt:.2f}, max |penumbral sum difference| {np.abs(pen['tree'] - pen['other']).max():.2g}",
            flush=True,
        )


if __name__ == "__main__":
    main()
