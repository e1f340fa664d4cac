"""Whole frames of `hard` and one method at a base revision and at the working tree, each in its own
processes run alternately (base, new, base, new...): for changes outside the method module (the
rasterizer), which ``frame_ab.py`` cannot compare (it loads only the method module from the base).
Each process renders `hard` and the method interleaved after warm-up and prints the medians and
their ratio; the base is ``git archive <base> src`` in a temporary folder (its JIT cache is kept
there, so the first base process compiles).

    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/frame_ab_processes.py --base main --light rect
    PYTHONPATH=src python benchmarks/frame_ab_processes.py --base main --light sphere --cpu   # 1 thread, CPU time
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile

_CHILD = """
import os, sys, time
if {cpu}:
    os.environ["NUMBA_NUM_THREADS"] = "1"
import numpy as np
import softshadows as ss
from softshadows import api
from softshadows.methods import get_method
ss.tune_malloc()
clock = time.process_time if {cpu} else time.perf_counter
scene = ss.load_scene({scene!r}, light={light!r}).normalized()[0]
h, m = get_method("hard"), get_method({method!r})
ph, pm = h.resolve_params({{}}), m.resolve_params({{}})
th, tm = [], []
for r in range({reps} + 2):
    t0 = clock(); api._render(scene, h, {size}, {size}, ph, 0, False); t1 = clock()
    api._render(scene, m, {size}, {size}, pm, 0, False); t2 = clock()
    if r >= 2:
        th.append(t1 - t0); tm.append(t2 - t1)
print(np.median(th), np.median(tm))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="git revision of the base")
    ap.add_argument("--method", default="penumbra-map")
    ap.add_argument("--light", default="rect", choices=("rect", "sphere"))
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--reps", type=int, default=21, help="frames per process (after 2 warm-up frames)")
    ap.add_argument("--rounds", type=int, default=3, help="base/new process pairs")
    ap.add_argument("--cpu", action="store_true", help="one Numba thread, process CPU time instead of wall time")
    a = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="frame_ab_proc_")
    tar = subprocess.run(["git", "archive", a.base, "src"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", tmp], input=tar, check=True)
    code = _CHILD.format(
        cpu=a.cpu, scene=a.scene, light=a.light, method=a.method, reps=a.reps, size=a.size
    )  # fmt: skip
    trees = {"base": os.path.join(tmp, "src"), "new": os.path.abspath("src")}
    ratios: dict[str, list] = {"base": [], "new": []}
    unit = "CPU time, 1 thread" if a.cpu else "wall time"
    print(f"{a.scene} {a.light} {a.size}^2, {a.method} / hard, medians of {a.reps} frames per process, {unit}")
    for _ in range(a.rounds):
        for name, src in trees.items():
            env = dict(os.environ, PYTHONPATH=src)
            out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            th, tm = (float(x) for x in out.stdout.split()[-2:])
            ratios[name].append(tm / th)
            print(f"  {name:4s} hard {1e3 * th:6.2f} ms  {a.method} {1e3 * tm:6.2f} ms  ratio {tm / th:.3f}")
    for name, v in ratios.items():
        print(f"{name}: ratio {min(v):.3f}-{max(v):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
