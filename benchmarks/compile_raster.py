"""Compile cost of the shared rasterizer, mode by mode, from an empty JIT cache.

    rm -rf /tmp/nbc_r; NUMBA_CACHE_DIR=/tmp/nbc_r OMP_WAIT_POLICY=PASSIVE PYTHONPATH=SRC \
        python benchmarks/compile_raster.py

Runs each public rasterizer mode once on a tiny scene (the first call compiles its kernels) and
prints the process CPU time (user + sys, all threads) each call took: the front end with the
G-buffer mode (the first call), then depth, fragments, min-blend with each program. CPU time is
the steady number on a shared machine; the wall time is printed too. Run it with ``SRC`` = the
``src/`` of each version to compare (docs/results/cold-start.md).
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np

import softshadows
from softshadows.api import eye_view
from softshadows.raster import rasterize, rasterize_depth, rasterize_fragments, rasterize_min_blend
from softshadows.raster.programs import PROGRAMS


def main() -> None:
    sc = softshadows.load_scene("spheres")
    fl = sc.flat
    view = eye_view(sc, 64, 48)
    V, F = fl.vertices, fl.faces
    steps = [
        ("front end + gbuffer", lambda: rasterize(view, V, F)),
        ("depth", lambda: rasterize_depth(view, V, F)),
        ("fragments", lambda: rasterize_fragments(view, V, F)),
    ]
    ca = np.zeros((len(F), 3))
    img = np.zeros((48, 64), np.float32)
    for p in PROGRAMS:
        out = np.full((48, 64), np.inf, np.float32)
        steps.append(
            (
                f"min-blend program {p}",
                lambda p=p, out=out: rasterize_min_blend(view, V, F, p, ca, img, np.zeros(3), out),
            )
        )
    tot_c = tot_w = 0.0
    for name, fn in steps:
        c0, w0 = time.process_time(), time.perf_counter()
        fn()
        dc, dw = time.process_time() - c0, time.perf_counter() - w0
        tot_c += dc
        tot_w += dw
        print(f"{name:24s} cpu {dc:7.2f} s  wall {dw:7.2f} s", flush=True)
    print(f"{'total':24s} cpu {tot_c:7.2f} s  wall {tot_w:7.2f} s")


if __name__ == "__main__":
    main()
