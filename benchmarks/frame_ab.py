"""Whole frames of `hard` and of methods at a base revision and at the working tree, interleaved in
one process (so that both see the same load): the base's method modules are loaded from
``git archive <base>`` under another module name and run through ``api._render`` next to the
working tree's. Prints per method the median (and min) frame time and its ratio to `hard`, and
checks that base and new give the same V bit for bit.

    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/frame_ab.py --base 6abffa9 --light rect
    PYTHONPATH=src python benchmarks/frame_ab.py --base 6abffa9 --light sphere --cpu   # 1 thread, CPU time

Only the method modules named in ``--modules`` come from the base; everything they import (the
rasterizer, shadow maps...) is the working tree's.
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
    ap.add_argument("--reps", type=int, default=9)
    ap.add_argument("--methods", default="pcss:pcss:PCSS,penumbra-map:penumbra_map:PenumbraMapMethod",
                    help="name:module:class, comma separated")  # fmt: skip
    ap.add_argument("--cpu", action="store_true", help="one Numba thread, process CPU time instead of wall time")
    a = ap.parse_args()
    if a.cpu:
        os.environ["NUMBA_NUM_THREADS"] = "1"
    import numpy as np

    import softshadows as ss
    from softshadows import api
    from softshadows.methods import get_method

    ss.tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    clock = time.process_time if a.cpu else time.perf_counter
    tmp = tempfile.mkdtemp(prefix="frame_ab_")
    tar = subprocess.run(["git", "archive", a.base, "src/softshadows/methods"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", tmp], input=tar, check=True)
    methods = {"hard": get_method("hard")}
    for spec_s in a.methods.split(","):
        name, modname, cls = spec_s.split(":")
        path = os.path.join(tmp, "src/softshadows/methods", modname + ".py")
        spec = importlib.util.spec_from_file_location(f"softshadows.methods._base_{modname}", path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod
        with open(path) as fh:
            text = fh.read()
        src = text.replace(
            "from .base import Method, MethodOutput, Param, register",
            "from .base import Method, MethodOutput, Param\nregister = lambda c: c",  # not registered again
        )
        exec(compile(src, path, "exec"), mod.__dict__)
        methods[f"{name}(base)"] = getattr(mod, cls)()
        methods[f"{name}(new)"] = get_method(name)
    scene = ss.load_scene(a.scene, light=a.light).normalized()[0]
    params = {k: m.resolve_params({}) for k, m in methods.items()}
    times = {k: [] for k in methods}
    vis = {}
    for r in range(a.reps + 2):  # two warm-up rounds
        for k, m in methods.items():
            t0 = clock()
            out = api._render(scene, m, a.size, a.size, params[k], 0, False)
            dt = clock() - t0
            if r >= 2:
                times[k].append(dt)
            vis[k] = out.visibility
    for k in methods:
        if k.endswith("(base)"):
            same = np.array_equal(vis[k], vis[k[:-6] + "(new)"], equal_nan=True)
            print(f"{k[:-6]}: V base vs new {'bit for bit the same' if same else 'DIFFERENT'}")
    h, hmin = np.median(times["hard"]), min(times["hard"])
    what = "CPU time, 1 thread" if a.cpu else "wall time"
    print(f"{a.scene} {a.light} {a.size}^2, {a.reps} frames, {what}: median ms (ratio to hard), min ms (ratio)")
    for k, v in times.items():
        print(
            f"  {k:22s} {np.median(v) * 1e3:8.1f} ({np.median(v) / h:.2f}x)  {min(v) * 1e3:8.1f} ({min(v) / hmin:.2f}x)"
        )
    # paired: each round's new against the same round's base (rendered a few ms apart), so that the
    # host's slower and faster stretches cancel; the median and quartiles of those ratios
    for k in methods:
        if k.endswith("(base)"):
            q = np.asarray(times[k[:-6] + "(new)"]) / np.asarray(times[k])
            lo, med, hi = np.percentile(q, [25, 50, 75])
            print(f"  {k[:-6]}: new / base per round, median {med:.3f} (quartiles {lo:.3f}-{hi:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
