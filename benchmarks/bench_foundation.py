"""Foundation benchmark (issue 2): per-phase times at 512x512 on `bunny` for `hard` and
`ground-truth`, and ground truth's rays/s next to a raw Embree occlusion call on the same rays.

    python benchmarks/bench_foundation.py [--size 512] [--samples 64] [--repeats 5] [--light rect|sphere]

All numbers are medians after JIT warm-up, measured in this one process. Ground truth and the raw
call alternate in rounds (``--repeats`` // 2 of them, each side first in turn); the ratio is given
both from the two sides' medians and as the median of each round's ratio.
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import time

import numpy as np

import softshadows as ss
from softshadows.api import eye_view
from softshadows.bench import summary_stats
from softshadows.methods import ground_truth as gtm
from softshadows.raster import rasterize
from softshadows.shading import facing_normals


def med_phases(results):
    keys = results[0].timings.keys()
    return {k: statistics.median(r.timings[k] for r in results) for k in keys}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--light", choices=("rect", "sphere"), default=None, help="light shape (default: the scene's)")
    a = ap.parse_args()
    scene = ss.load_scene(a.scene, light=a.light)
    n = a.size
    print(f"scene={a.scene} size={n}x{n} ({len(scene.flat.faces)} triangles)")

    # eye G-buffer alone
    view = eye_view(scene, n, n)
    flat = scene.flat
    rasterize(view, flat.vertices, flat.faces)
    ts = []
    for _ in range(max(a.repeats, 5)):
        t0 = time.perf_counter()
        rasterize(view, flat.vertices, flat.faces)
        ts.append(time.perf_counter() - t0)
    print(f"eye G-buffer: {statistics.median(ts) * 1e3:.1f} ms (target <= 20 ms)")

    ss.render(scene, "hard", n, n)
    hard = [ss.render(scene, "hard", n, n) for _ in range(a.repeats)]
    ph = med_phases(hard)
    print("hard: " + "  ".join(f"{k}={v * 1e3:.1f}ms" for k, v in ph.items()) + "  (target total <= 30 ms)")

    # ground truth against raw Embree on the same rays, one tracing thread per core on both sides,
    # interleaved: raw = the method's chunks, generated beforehand, handed to embreex's run by the
    # same threads (gtm.run_on_threads: one Python thread per Numba thread taking chunks in turn)
    import numba

    nthreads = numba.get_num_threads()
    g = rasterize(view, flat.vertices, flat.faces)
    idx = np.flatnonzero(g.mask.ravel())
    pts = g.position.reshape(-1, 3)[idx].astype(np.float64)
    nrm = facing_normals(g.normal.reshape(-1, 3)[idx].astype(np.float64), pts, scene.camera.eye)
    esc = gtm._embree_for(scene)
    S = a.samples
    side = int(round(np.sqrt(S)))
    pts, nrm, err_point, err_embree, grazing, own_blocks = gtm.hit_points(flat, g, idx, nrm)
    off = gtm.BOUND_SAFETY * (err_point + err_embree)
    grazing = gtm.BOUND_SAFETY * grazing
    shape, center, u, v, radius = gtm.light_arrays(scene.light)
    bounds = gtm.chunk_bounds(len(pts), S, nthreads)
    batches = []
    for start, stop in itertools.pairwise(bounds):
        m = stop - start
        org = np.empty((m * S, 3), np.float32)
        dirs = np.empty((m * S, 3), np.float32)
        dist = np.empty(m * S, np.float32)
        geo = np.empty(m * S, np.float32)
        gtm.generate_light_rays(
            pts[start:stop],
            nrm[start:stop],
            idx[start:stop],
            off[start:stop],
            grazing[start:stop],
            own_blocks[start:stop],
            0,
            side,
            shape,
            center,
            u,
            v,
            radius,
            org,
            dirs,
            dist,
            geo,
            False,
        )
        batches.append((org, dirs, dist))

    def trace(i, slot):
        org, dirs, dist = batches[i]
        esc.run(org, dirs, dists=dist, query="OCCLUDED")

    ss.render(scene, "ground-truth", 32, 32, samples=a.samples)
    gts, raw = [], []
    for r in range(max(1, a.repeats // 2)):  # rounds: the method and the raw call side by side,
        for side in ("method", "raw") if r % 2 == 0 else ("raw", "method"):  # in turn first
            if side == "method":
                gts.append(ss.render(scene, "ground-truth", n, n, samples=a.samples))
            else:
                t0 = time.perf_counter()
                gtm.run_on_threads(nthreads, len(batches), trace)
                raw.append(time.perf_counter() - t0)
    pg = med_phases(gts)
    rays = gts[0].stats["rays"]
    method_time = pg["rays"]  # generation, tracing and reduction on every core
    print("ground-truth: " + "  ".join(f"{k}={v * 1e3:.1f}ms" for k, v in pg.items()))
    split = {
        k: statistics.median(r.stats[k] for r in gts) / rays * 1e9
        for k in ("ray_generation_seconds", "trace_seconds", "reduce_seconds")
    }
    print(
        "  per ray, summed over threads: "
        + "  ".join(f"{k.split('_seconds')[0]}={v:.2f}ns" for k, v in split.items())
        + f"  (raw trace: {statistics.median(raw) * nthreads / rays * 1e9:.2f}ns)"
    )
    raw_t = statistics.median(raw)
    # each round's ratio (the two sides a fraction of a second apart): the host's speed, which moves
    # between rounds on a shared machine, cancels in it
    paired = summary_stats([rw / g.timings["rays"] for rw, g in zip(raw, gts, strict=True)])
    print(
        f"rays: {rays}  chunks: {len(batches)}  threads: {nthreads}  ground-truth method: "
        f"{rays / method_time / 1e6:.2f} Mrays/s   raw Embree ({nthreads} threads): {rays / raw_t / 1e6:.2f} Mrays/s"
        f"   ratio {raw_t / method_time:.2f}; per round: median {paired['median']:.2f}"
        f" (quartiles {paired['q1']:.2f}-{paired['q3']:.2f}, {paired['n']} rounds) (target >= 0.85)"
    )


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    main()
