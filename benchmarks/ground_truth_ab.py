"""Ground truth's tracing pipeline before and after a change, in one process (issue 16).

    python benchmarks/ground_truth_ab.py [--rev 6abffa9] [--light rect|sphere] [--repeats 4]

Loads ``methods/ground_truth.py`` as it was at ``--rev`` (``git show``, so it needs the git
history) next to the current one, and times, interleaved on bunny 512x512 with 64 samples:
the old ``trace_in_pipeline``, the current one, and raw embreex on the current rays (the method's
chunks, generated beforehand, traced by the same threads: ``run_on_threads``). Checks that both
give the same V, and prints Mrays/s, each one's ratio to raw, and the speed-up. Medians.
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import pathlib
import re
import statistics
import subprocess
import sys
import tempfile
import time

import numba
import numpy as np

import softshadows as ss
from softshadows.api import eye_view
from softshadows.methods import ground_truth as gtm
from softshadows.raster import rasterize
from softshadows.shading import facing_normals


def load_old(rev: str):
    """The module at ``rev``, with its package-relative imports made absolute and without
    registering its method again."""
    root = pathlib.Path(__file__).resolve().parents[1]
    src = subprocess.run(
        ["git", "show", f"{rev}:src/softshadows/methods/ground_truth.py"],
        cwd=root,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    src = re.sub(r"^from \.\.(\w)", r"from softshadows.\1", src, flags=re.M)
    src = re.sub(r"^from \.(\w)", r"from softshadows.methods.\1", src, flags=re.M).replace("\n@register\n", "\n")
    path = pathlib.Path(tempfile.mkdtemp()) / f"ground_truth_{rev}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = mod
    spec.loader.exec_module(mod)
    return mod


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rev", default="6abffa9")
    ap.add_argument("--light", choices=("rect", "sphere"), default="rect")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=4)
    a = ap.parse_args()
    old = load_old(a.rev)
    scene = ss.load_scene("bunny", light=a.light)
    flat = scene.flat
    g = rasterize(eye_view(scene, a.size, a.size), flat.vertices, flat.faces)
    idx = np.flatnonzero(g.mask.ravel())
    pts = g.position.reshape(-1, 3)[idx].astype(np.float64)
    nrm = facing_normals(g.normal.reshape(-1, 3)[idx].astype(np.float64), pts, scene.camera.eye)
    esc = gtm._embree_for(scene)
    side = int(round(np.sqrt(a.samples)))
    S = side * side
    pts, nrm, ep, ee, graz, own = gtm.hit_points(flat, g, idx, nrm)
    off, graz = gtm.BOUND_SAFETY * (ep + ee), gtm.BOUND_SAFETY * graz
    shape, center, u, v, radius = gtm.light_arrays(scene.light)
    K = len(pts)
    nthreads = numba.get_num_threads()
    batches = []
    for start, stop in itertools.pairwise(gtm.chunk_bounds(K, S, nthreads)):
        m = stop - start
        arrs = (np.empty((m * S, 3), np.float32), np.empty((m * S, 3), np.float32))
        arrs += (np.empty(m * S, np.float32), np.empty(m * S, np.float32))
        sl = slice(start, stop)
        gtm.generate_light_rays(
            pts[sl], nrm[sl], idx[sl], off[sl], graz[sl], own[sl], 0, side, shape, center, u, v, radius, *arrs, False
        )
        batches.append(arrs[:3])
    vis = {"old": np.zeros(K, np.float32), "new": np.zeros(K, np.float32)}
    irr = np.zeros(K)

    def pipeline(mod, key):
        return mod.trace_in_pipeline(esc, pts, nrm, idx, off, graz, own, 0, side, scene.light, vis[key], irr)[3]

    def raw():
        t0 = time.perf_counter()
        gtm.run_on_threads(
            nthreads, len(batches), lambda i, slot: esc.run(*batches[i][:2], dists=batches[i][2], query="OCCLUDED")
        )
        return time.perf_counter() - t0

    runs = {"old": lambda: pipeline(old, "old"), "new": lambda: pipeline(gtm, "new"), "raw": raw}
    for f in runs.values():
        f()  # JIT warm-up
    assert np.array_equal(vis["old"], vis["new"]), "the two revisions give different V"
    times = {k: [] for k in runs}
    for _ in range(a.repeats):
        for k in ("old", "raw", "new", "raw"):
            times[k].append(runs[k]())
    md = {k: statistics.median(v) for k, v in times.items()}
    R = K * S
    print(
        f"bunny {a.light} {a.size}x{a.size}, {S} samples, {R} rays, {nthreads} threads: "
        + "  ".join(f"{k} {R / t / 1e6:.2f} Mrays/s" for k, t in md.items())
    )
    print(
        f"ratio to raw: {a.rev} {md['raw'] / md['old']:.2f}, current {md['raw'] / md['new']:.2f}; "
        f"current / {a.rev} speed {md['old'] / md['new']:.2f}x (V identical)"
    )


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()
    main()
