"""Whole `hard` frames with a base revision's ``methods/hard.py``, ``methods/shadowmap.py``,
``shading.py`` and ``api._render`` against the working tree's, interleaved in one process after
warm-up (the rasterizer is the working tree's on both sides). For changes to the frame around the
rasterizer (the eye pass, shading, render's overheads), which ``frame_ab.py`` (method modules only)
does not see. Checks that V, the image and the stats are the same bit for bit.

    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/hard_frame_ab.py --base main --light rect
    PYTHONPATH=src python benchmarks/hard_frame_ab.py --base main --light sphere --cpu   # 1 thread, CPU time
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="git revision of the base")
    ap.add_argument("--light", default="rect", choices=("rect", "sphere"))
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--cpu", action="store_true", help="one Numba thread, process CPU time instead of wall time")
    a = ap.parse_args()
    if a.cpu:
        os.environ["NUMBA_NUM_THREADS"] = "1"
    import numpy as np

    import softshadows as ss
    from softshadows import api
    from softshadows.methods import get_method

    tmp = tempfile.mkdtemp(prefix="hard_frame_ab_")

    def load(name: str, path: str, edit=lambda s: s):
        text = subprocess.run(["git", "show", f"{a.base}:src/softshadows/{path}"], check=True, capture_output=True)
        file = os.path.join(tmp, path.replace("/", "_"))
        with open(file, "w") as fh:  # a file of its own: Numba caches its kernels beside it
            fh.write(edit(text.stdout.decode()))
        spec = importlib.util.spec_from_file_location(name, file)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
        return mod

    load("softshadows.methods._base_shadowmap", "methods/shadowmap.py")
    hard = load(
        "softshadows.methods._base_hard",
        "methods/hard.py",
        lambda s: s.replace("from .shadowmap import", "from ._base_shadowmap import").replace("\n@register\n", "\n"),
    )
    base_api = load("softshadows._base_api", "api.py")
    base_api.shading = load("softshadows._base_shading", "shading.py")
    ss.tune_malloc()
    clock = time.process_time if a.cpu else time.perf_counter
    scene = ss.load_scene(a.scene, light=a.light).normalized()[0]
    new_m = get_method("hard")
    params = new_m.resolve_params({})
    sides = {"base": (base_api._render, hard.Hard()), "new": (api._render, new_m)}
    times: dict = {k: [] for k in sides}
    phases: dict = {k: {} for k in sides}
    out = {}
    for r in range(a.reps + 2):  # two warm-up rounds
        for k, (render, m) in sides.items():
            t0 = clock()
            res = render(scene, m, a.size, a.size, params, 0, False)
            dt = clock() - t0
            out[k] = res
            if r >= 2:
                times[k].append(dt)
                for ph, v in res.timings.items():
                    phases[k].setdefault(ph, []).append(v)
    b, n = out["base"], out["new"]
    same = (
        np.array_equal(b.visibility, n.visibility, equal_nan=True)
        and np.array_equal(b.image, n.image, equal_nan=True)
        and b.stats == n.stats
    )
    unit = "CPU time, 1 thread" if a.cpu else "wall time"
    print(f"{a.scene} {a.light} {a.size}^2, `hard`, medians of {a.reps} frames ({unit}; phases: wall)")
    print(f"V, image and stats base vs new: {'bit for bit the same' if same else 'DIFFERENT'}")
    for k in sides:
        ph = "  ".join(f"{p} {1e3 * np.median(v):.2f}" for p, v in phases[k].items())
        print(f"  {k:4s} frame {1e3 * np.median(times[k]):7.2f} ms (min {1e3 * min(times[k]):7.2f})  {ph}")
    print(f"new / base: {np.median(times['new']) / np.median(times['base']):.3f}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
