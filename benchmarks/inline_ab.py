"""Frames with two ways of inlining the kernels' helpers, in one process: package A is ``src`` with
``SOFTSHADOWS_INLINE=ir`` (every ``@kernel(inline=...)`` helper inlined in Numba's IR), package B
a copy of it (imported as ``softshadows_b``) with ``SOFTSHADOWS_INLINE=<--mode>`` (default:
each helper as declared, ``inline=True`` by LLVM). Interleaved frames after two warm-up rounds;
prints median and min per method, B/A, and whether V is the same bit for bit.

    OMP_WAIT_POLICY=PASSIVE python benchmarks/inline_ab.py --cpu --reps 9 [--mode llvm] [--light sphere]

``--cpu``: one Numba thread and process CPU time (steadier on a loaded machine). Compiles both
packages (minutes on an empty cache). See docs/results/cold-start.md.
"""

import argparse
import importlib
import os
import shutil
import sys
import tempfile
import time


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--light", default="sphere", choices=("rect", "sphere"))
    ap.add_argument("--reps", type=int, default=9)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--cpu", action="store_true", help="one Numba thread, process CPU time")
    ap.add_argument("--mode", default="", help="B's SOFTSHADOWS_INLINE ('': as declared)")
    ap.add_argument("--src", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "src"))
    ap.add_argument(
        "--methods", default="hard,pcss,penumbra-map,occlusion-textures,soft-shadow-map,irregular,layered-attenuation"
    )
    a = ap.parse_args()
    if a.cpu:
        os.environ["NUMBA_NUM_THREADS"] = "1"
    tmp = tempfile.mkdtemp(prefix="inline_ab_")
    shutil.copytree(os.path.join(a.src, "softshadows"), os.path.join(tmp, "softshadows_b"),
                    ignore=shutil.ignore_patterns("__pycache__"))  # fmt: skip
    sys.path[:0] = [a.src, tmp]
    import numpy as np

    pk = {}
    for key, pkg, mode in (("A", "softshadows", "ir"), ("B", "softshadows_b", a.mode)):
        os.environ["SOFTSHADOWS_INLINE"] = mode  # read when the package's _jit is imported
        pk[key] = (importlib.import_module(pkg), importlib.import_module(pkg + ".api"),
                   importlib.import_module(pkg + ".methods"))  # fmt: skip
    print("inlining: A", pk["A"][0]._jit.INLINE, " B", pk["B"][0]._jit.INLINE or "as declared")
    clock = time.process_time if a.cpu else time.perf_counter
    names = a.methods.split(",")
    runs = []
    for n in names:
        for key, (ss, api, methods) in pk.items():
            m = methods.get_method(n)
            sc = ss.load_scene("bunny", light=a.light).normalized()[0]
            runs.append((n, key, api, sc, m, m.resolve_params({})))
    times = {(n, k): [] for n, k, *_ in runs}
    vis = {}
    for r in range(a.reps + 2):  # two warm-up rounds
        for n, k, api, sc, m, p in runs:
            t0 = clock()
            out = api._render(sc, m, a.size, a.size, p, 0, False)
            dt = clock() - t0
            if r >= 2:
                times[n, k].append(dt)
            vis[n, k] = out.visibility
    what = "CPU time, 1 thread" if a.cpu else "wall time"
    print(f"bunny {a.light} {a.size}^2, {a.reps} frames, {what}: median A, B ms, B/A; min A, B ms, B/A; V")
    for n in names:
        ta, tb = np.array(times[n, "A"]), np.array(times[n, "B"])
        same = np.array_equal(vis[n, "A"], vis[n, "B"], equal_nan=True)
        print(
            f"  {n:20s} {np.median(ta) * 1e3:8.1f} {np.median(tb) * 1e3:8.1f} {np.median(tb) / np.median(ta):6.3f}"
            f"   {ta.min() * 1e3:8.1f} {tb.min() * 1e3:8.1f} {tb.min() / ta.min():6.3f}"
            f"  {'same V' if same else 'V DIFFERS'}"
        )
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
