"""Triangle throughput: frame times of the real-time methods (and 16-spp ground truth) on an
icosphere over a ground quad, 5 k / 82 k / 1.3 M triangles, 512x512 eye view, methods at their
defaults, plus the same ``hard`` frame in OpenGL on Mesa llvmpipe where GL is available (issue 15).

    PYTHONPATH=src python benchmarks/triangle_throughput.py [--levels 4,6,8] [--repeats 3]
                                                          [--methods ...] [--png docs/img/triangle-throughput.png]

Protocol: per level, every method renders once (JIT compile, caches) and then ``--repeats`` rounds
render every method once each (round-robin, interleaved with the GL frame); medians in ms. The
``x hard`` columns are each method's median over hard's, measured in the same rounds.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import softshadows as ss

sys.path.insert(0, str(Path(__file__).parent))
from gl_peer import GLHard, icosphere_scene

METHODS = ("hard", "pcss", "penumbra-map", "soft-shadow-map", "occlusion-textures", "ground-truth")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", default="4,6,8")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--png", default=None)
    a = ap.parse_args(argv)
    methods = a.methods.split(",")
    rows = []
    for lvl in (int(x) for x in a.levels.split(",")):
        sc = icosphere_scene(lvl, "rect")
        ntri = len(sc.flat.faces)
        kw = {m: ({"samples": 16} if m == "ground-truth" else {}) for m in methods}
        gl = None
        try:
            p = {q.name: q.default for q in ss.methods()["hard"].params}
            gl = GLHard(sc, a.size, p["map_size"], p["bias"], p["slope_bias"])
            gl.frame()
        except Exception as exc:  # no moderngl / no EGL context: no llvmpipe column
            print(f"(no GL: {exc})", file=sys.stderr)
        for m in methods:
            ss.render(sc, m, a.size, a.size, seed=1, **kw[m])
        ts = {m: [] for m in methods}
        tgl = []
        for _ in range(a.repeats):
            for m in methods:
                ts[m].append(ss.render(sc, m, a.size, a.size, seed=1, **kw[m]).timings["total"] * 1e3)
            if gl is not None:
                t0 = time.perf_counter()
                gl.frame()
                tgl.append((time.perf_counter() - t0) * 1e3)
        med = {m: float(np.median(v)) for m, v in ts.items()}
        rows.append((ntri, med, float(np.median(tgl)) if tgl else float("nan")))
        print(
            f"level {lvl}: {ntri} triangles", {m: round(v) for m, v in med.items()}, "llvmpipe", rows[-1][2], flush=True
        )
    print()
    print("| triangles | " + " | ".join(methods) + " | llvmpipe `hard` |")
    print("|---" * (len(methods) + 2) + "|")
    for ntri, med, g in rows:
        cells = [
            f"{med[m]:.0f}" + (f" ({med[m] / med['hard']:.2f}x)" if m != "hard" and "hard" in med else "")
            for m in methods
        ]
        print(f"| {ntri:,} | " + " | ".join(cells) + f" | {g:.0f} |")
    if a.png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 4.5))
        x = [r[0] for r in rows]
        for m in methods:
            ax.plot(x, [r[1][m] for r in rows], "o-", label=m)
        ax.plot(x, [r[2] for r in rows], "k--", label="hard on llvmpipe (OpenGL)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("triangles (icosphere over a ground quad)")
        ax.set_ylabel(f"frame time, ms ({a.size}x{a.size})")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(a.png, dpi=110)
    return 0


if __name__ == "__main__":
    ss.tune_malloc()
    sys.exit(main())
