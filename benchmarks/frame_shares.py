"""What the two speed targets of issue 16 ask of each method: its frame split into the part it
shares with `hard`'s frame and its own, and how much of its own time it would need to lose to stay
within 2x `hard` once `hard` itself is made faster (the llvmpipe target).

    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/frame_shares.py [--light sphere] [--frames 21] [--cut 0.10]

Every method's frame contains the eye G-buffer, the shading and the render's own work outside the
timed phases (``shared``, as `hard`'s frame does); the rest is its ``own``. `hard`'s own part is
its light map and lookup. llvmpipe renders `hard`'s V-only frame ~10% faster than ours
(`benchmarks/gl_peer.py`), so meeting that target means cutting `hard`'s frame by a fraction
``--cut``. Two cases, per method (P its frame, H `hard`'s, O its own part, per-round medians):

* the cut in `hard`'s own phases (H -> H (1 - cut)): the method must lose P - 2 H (1 - cut);
* the cut in the shared phases (x = cut H off both): it must lose P - 2 H + x.

Printed as a fraction of O (0 where nothing is needed). `pcss` renders the same light map as `hard`,
so for it a cut in `hard`'s map falls between the two cases. Also printed: the two cores' use
(process CPU time over wall time x threads): the idle share is what overlapping work could still
fill. Frames are interleaved, one round of every method at a time, after warm-up.
"""

from __future__ import annotations

import argparse
import resource
import statistics as st
import time

DEFAULT_METHODS = "hard,pcss,penumbra-map,irregular,soft-shadow-map,occlusion-textures,layered-attenuation"


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--light", default="rect", choices=("rect", "sphere"))
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--frames", type=int, default=21)
    ap.add_argument("--cut", type=float, default=0.10, help="fraction of hard's frame to cut (llvmpipe target)")
    ap.add_argument("--methods", default=DEFAULT_METHODS, help="comma-separated; hard is always included")
    a = ap.parse_args()
    import numba

    import softshadows as ss

    ss.tune_malloc()  # a benchmark owns its process (softshadows._malloc)
    scene = ss.load_scene(a.scene, light=a.light)
    methods = ["hard"] + [m for m in a.methods.split(",") if m and m != "hard"]
    for m in methods:
        for _ in range(2):
            ss.render(scene, m, a.size, a.size)  # compile and warm up
    nthreads = numba.get_num_threads()
    rows = {m: [] for m in methods}  # (frame, shared, cpu) per round
    for _ in range(a.frames):
        for m in methods:
            c0 = _cpu()
            t0 = time.perf_counter()
            r = ss.render(scene, m, a.size, a.size)
            t = time.perf_counter() - t0
            c = _cpu() - c0
            phases = sum(v for k, v in r.timings.items() if k != "total")
            shared = r.timings.get("eye_gbuffer", 0.0) + r.timings.get("shading", 0.0) + (t - phases)
            rows[m].append((t, shared, c))
    print(
        f"{a.scene} {a.size}x{a.size}, {a.light} light, {a.frames} rounds, {nthreads} threads; "
        f"cut of hard's frame: {a.cut:.2f}"
    )
    print(
        f"{'method':20s} {'frame ms':>8s} {'shared':>7s} {'own':>6s} {'x hard':>7s} {'cores used':>10s}"
        f" {'own to lose: cut in hard own':>29s} {'cut in shared':>13s}"
    )
    hard = rows["hard"]
    for m in methods:
        fr = [x[0] for x in rows[m]]
        sh = [x[1] for x in rows[m]]
        own = [f - s for f, s in zip(fr, sh)]
        ratio = st.median(x[0] / h[0] for x, h in zip(rows[m], hard))
        use = st.median(x[2] / (nthreads * x[0]) for x in rows[m])
        lose_own = st.median(max(0.0, x[0] - 2 * h[0] * (1 - a.cut)) / (x[0] - x[1]) for x, h in zip(rows[m], hard))
        lose_sh = st.median(max(0.0, x[0] - 2 * h[0] + a.cut * h[0]) / (x[0] - x[1]) for x, h in zip(rows[m], hard))
        tail = "" if m == "hard" else f" {lose_own:29.1%} {lose_sh:13.1%}"
        print(
            f"{m:20s} {1e3 * st.median(fr):8.1f} {1e3 * st.median(sh):7.1f} {1e3 * st.median(own):6.1f}"
            f" {ratio:7.2f} {use:10.2f}{tail}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
