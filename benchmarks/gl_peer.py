"""A CPU peer to measure against: the same ``hard`` frame in OpenGL on Mesa's llvmpipe
(``softshadows.peer``: the GL frame itself, shared with ``softshadows bench icosphere --sweep triangles``).

    python benchmarks/gl_peer.py [--scene bunny] [--light rect|sphere] [--size 512] [--map 1024]
                                 [--icosphere LEVEL] [--repeats 15]

llvmpipe is a JIT-compiled, multi-threaded software rasterizer: what a user without a GPU would
otherwise run. The GL frame is the same computation as our ``hard`` at its defaults:

1. a ``--map``^2 depth map from the light centre, with *our* fitted light view
   (``methods.shadowmap.fit_light_view``): linear view depth written to an R32F target under a
   depth test;
2. a ``--size``^2 eye pass over every triangle: per fragment the world position (perspective-
   correct), the face normal turned toward the eye, the Williams test with our constant +
   slope-scaled bias in texels (``shadowmap.receiver_offset``), V written to an R32F target;
3. V read back to the CPU (``glReadPixels`` into NumPy).

Both sides run in this one process, interleaved, after warm-up (JIT compile and the GL shader
compile excluded; geometry is uploaded to the GL once, as our scene keeps its flattened arrays).
Our frame is ``softshadows.render(scene, "hard")``'s total, which also shades the image (the GL
frame does not): the ``V only`` column leaves our shading phase out. The script checks that the
two V agree on all but a fraction of a percent of the pixels both cover (they differ only where a
float32 depth comparison falls the other way) and prints both frame times and their ratio.

``--icosphere LEVEL`` replaces the scene by an icosphere of 20 * 4^LEVEL triangles over a ground
quad (level 8: 1.3 M triangles), the triangle-throughput scene. Needs the optional ``peer`` extra
(``pip install -e '.[peer]'``: moderngl); exits 2 with a clear message when no GL context can be made.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import softshadows as ss
from softshadows.peer import agreement, hard_defaults, make_peer, unavailable
from softshadows.scene.builtin import icosphere


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--light", default="rect", choices=("rect", "sphere"))
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--map", type=int, default=1024)
    ap.add_argument("--icosphere", type=int, default=None, help="icosphere subdivision level instead of --scene")
    ap.add_argument("--repeats", type=int, default=15)
    a = ap.parse_args(argv)
    why = unavailable()
    if why is not None:
        print(f"gl_peer: {why}", file=sys.stderr)
        return 2
    scene = icosphere(a.icosphere, a.light) if a.icosphere is not None else ss.load_scene(a.scene, a.light)
    p = hard_defaults()
    gl, why = make_peer(scene, a.size, a.size, a.map, p["bias"], p["slope_bias"])
    if gl is None:
        print(f"gl_peer: {why}", file=sys.stderr)
        return 2
    ntri = len(scene.flat.faces)
    print(f"{scene.name} ({a.light} light), {ntri} triangles, eye {a.size}^2, map {a.map}^2; GL: {gl.renderer}")
    ours = ss.render(scene, "hard", a.size, a.size, map_size=a.map)
    v_gl = gl.frame()
    disagree, cover, nboth = agreement(ours.visibility, v_gl)
    t_ours, t_ours_v, t_gl = [], [], []
    for _ in range(a.repeats):  # interleaved
        r = ss.render(scene, "hard", a.size, a.size, map_size=a.map)
        t_ours.append(r.timings["total"])
        t_ours_v.append(r.timings["total"] - r.timings.get("shading", 0.0))
        t0 = time.perf_counter()
        gl.frame()
        t_gl.append(time.perf_counter() - t0)
    mo, mv, mg = (float(np.median(t)) * 1e3 for t in (t_ours, t_ours_v, t_gl))
    print(
        f"V agreement: {100 * (1 - disagree):.3f}% of {nboth} pixels both cover; coverage differs on {100 * cover:.3f}%"
    )
    print(f"| frame | ms (median of {a.repeats}) | x ours |")
    print("|---|---|---|")
    print(f"| ours (`hard`, full frame) | {mo:.1f} | 1.00 |")
    print(f"| ours, V only (no shading) | {mv:.1f} | {mv / mo:.2f} |")
    print(f"| OpenGL on llvmpipe | {mg:.1f} | {mg / mo:.2f} |")
    print(f"llvmpipe / ours = {mg / mo:.2f} (>1: ours is faster)")
    if not (disagree < 0.005 and cover < 0.005):
        print("gl_peer: the two V disagree on more than 0.5% of pixels", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    sys.exit(main())
