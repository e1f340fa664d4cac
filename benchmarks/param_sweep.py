"""Frame time of one method at several parameter settings on the built-in scenes, both lights,
interleaved in one process after warm-up (medians), and whether V changes between the settings
(max |dV| against the first). For choosing a default that changes time but not V (e.g.
`irregular`'s grid, which is exact whatever its size).

    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/param_sweep.py irregular \
        "" "grid=96,slices=8" --scenes bunny,spheres,fence,contact,plant --size 512 --reps 5
"""

from __future__ import annotations

import argparse
import sys
import time


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("method")
    ap.add_argument("settings", nargs="+", help='"key=value,key=value" per setting ("" for the defaults)')
    ap.add_argument("--scenes", default="bunny")
    ap.add_argument("--lights", default="rect,sphere")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--reps", type=int, default=5)
    a = ap.parse_args()
    import numpy as np

    import softshadows as ss
    from softshadows.cli import parse_sets
    from softshadows.errors import SoftShadowsError
    from softshadows.methods import get_method

    ss.tune_malloc()
    try:
        m = get_method(a.method)
        cfgs = [m.resolve_params(parse_sets([p for p in s.split(",") if p])) for s in a.settings]
    except SoftShadowsError as exc:
        print(f"param_sweep: {exc}", file=sys.stderr)
        return 2
    print(f"{a.method} at {a.size}x{a.size}, median ms of {a.reps} interleaved frames; max |dV| against the first")
    print("| scene | light | " + " | ".join(a.settings[i] or "defaults" for i in range(len(cfgs))) + " |")
    print("|---|---|" + "---|" * len(cfgs))
    for name in a.scenes.split(","):
        for light in a.lights.split(","):
            sc = ss.load_scene(name, light)
            vs = [ss.render(sc, a.method, a.size, a.size, **c).visibility for c in cfgs]  # (warm-up too)
            t = [[] for _ in cfgs]
            for _ in range(a.reps):
                for i, c in enumerate(cfgs):
                    t0 = time.perf_counter()
                    ss.render(sc, a.method, a.size, a.size, **c)
                    t[i].append((time.perf_counter() - t0) * 1e3)
            cells = []
            for i in range(len(cfgs)):
                dv = float(np.nanmax(np.abs(vs[i] - vs[0]))) if vs[0].size else 0.0
                cells.append(f"{np.median(t[i]):.1f} (dV {dv:.2g})")
            print(f"| {name} | {light} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
