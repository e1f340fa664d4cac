"""A CPU peer to measure against: the same ``hard`` and ``pcss`` frames in OpenGL on Mesa's llvmpipe
(``softshadows.peer``: the GL frames themselves, ``hard``'s shared with ``softshadows bench icosphere
--sweep triangles``).

    python benchmarks/gl_peer.py [--method hard|pcss|both] [--scene bunny] [--light rect|sphere]
                                 [--size 512] [--map 1024] [--icosphere LEVEL] [--repeats 15]

llvmpipe is a JIT-compiled, multi-threaded software rasterizer: what a user without a GPU would
otherwise run. Each GL frame is the same computation as ours at the method's defaults:

1. a ``--map``^2 depth map from the light centre, with *our* fitted light view
   (``methods.shadowmap.fit_light_view``): linear view depth written to an R32F target under a
   depth test; for ``pcss`` then the map's smallest depth (z_near of the search region) by a
   two-pass min reduction;
2. a ``--size``^2 eye pass over every triangle: per fragment the world position (perspective-
   correct), the face normal turned toward the eye, our constant + slope-scaled bias in texels
   (``shadowmap.receiver_offset``), then ``hard``: the Williams test; ``pcss``: Fernando's blocker
   search, penumbra estimate and PCF (bilinear 2x2 comparison per tap) with our tap patterns
   uploaded as uniforms and every tap against the receiver's tangent plane, as our ``pcss``
   (deferred: the triangles write a G-buffer, a full-screen pass takes the taps once per pixel);
   V written to an R32F target;
3. V read back to the CPU (``glReadPixels`` into NumPy).

Both sides run in this one process, interleaved, after warm-up (JIT compile and the GL shader
compile excluded; geometry is uploaded to the GL once, as our scene keeps its flattened arrays).
Our frame is ``softshadows.render(scene, method)``'s total, which also shades the image; the GL
frame above does not. So the table has four ratios: that GL frame against our whole frame (the
issue's comparison), against our frame without its shading phase (V only, like for like), and two
GL frames that also shade (``peer.GLFrame(shade=...)``: our ``shading.shade`` in GLSL) against our
whole frame (like for like): one reads back an 8-bit colour (clamped to [0, 1]: what a display
takes, less than our float32 image keeps; llvmpipe's faster target), one our float32 colour. The
script checks the two V, checks that each shaded GL frame has the same V and our shading of it
(``peer.shading_agreement``: on all but 0.5 % of the pixels), and prints the frame times and
ratios:

* ``hard``: V agrees on all but a fraction of a percent of the pixels both cover (they differ only
  where a float32 depth comparison falls the other way);
* ``pcss``: V is within ``PCSS_TOL`` = 0.02 of ours on all but 0.5 % of the pixels both cover and
  the mean |dV| is below 1e-3. The GL computes in float32, ours in float64 on the same float32
  map: where every tap reads the same texels and makes the same comparisons the two V differ by
  float32 rounding of the bilinear weights and radii (a few 1e-5); a discrete flip (a tap's
  comparison, a texel under a tap, a blocker found or not, which moves the penumbra width) moves V
  by a multiple of about 1/16 (16 filter taps): 0.02 lies between the two. On bunny such flips
  are isolated pixels (0.01-0.02 % of them).

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
from softshadows.peer import (
    AGREEMENT_TOL,
    SHADE_RTOL,
    SHADES,
    agreement,
    dv_stats,
    make_peer,
    method_defaults,
    peer_params,
    shading_agreement,
    unavailable,
)
from softshadows.scene.builtin import icosphere

#: |dV| within which a pixel of the GL ``pcss`` counts as agreeing with ours (see the docstring)
PCSS_TOL = AGREEMENT_TOL["pcss"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--method", default="both", choices=("hard", "pcss", "both"))
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
    methods = ("hard", "pcss") if a.method == "both" else (a.method,)
    gls = {}  # per method: the V-only frame, then the shaded ones (SHADES order)
    for m in methods:
        p = method_defaults(m)
        gls[m] = []
        for shade in SHADES:
            g, why = make_peer(
                scene, a.size, a.size, a.map, p["bias"], p["slope_bias"], method=m, shade=shade, **peer_params(m)
            )
            if g is None:
                print(f"gl_peer: {why}", file=sys.stderr)
                return 2
            gls[m].append(g)
    ntri = len(scene.flat.faces)
    renderer = gls[methods[0]][0].renderer
    print(f"{scene.name} ({a.light} light), {ntri} triangles, eye {a.size}^2, map {a.map}^2; GL: {renderer}")
    checks, shades = {}, {}
    for m in methods:  # warm-up (JIT and shader compile) and the V check
        ours = ss.render(scene, m, a.size, a.size, map_size=a.map)
        v_gl = gls[m][0].frame()
        if m == "hard":
            disagree, cover, nboth = agreement(ours.visibility, v_gl)
            checks[m] = (disagree < 0.005 and cover < 0.005, f"{100 * (1 - disagree):.3f}% equal")
        else:
            disagree, cover, nboth = agreement(ours.visibility, v_gl, PCSS_TOL)
            mean_dv, max_dv = dv_stats(ours.visibility, v_gl)
            checks[m] = (
                disagree < 0.005 and cover < 0.005 and mean_dv < 1e-3,
                f"{100 * (1 - disagree):.3f}% within {PCSS_TOL}, mean abs. dV {mean_dv:.1e}, max {max_dv:.2f}",
            )
        checks[m] += (f"{checks[m][1]} on the {nboth} pixels both cover; coverage differs on {100 * cover:.3f}%",)
        # the shaded frames: the same V, and our shading of that V
        shades[m] = []
        for g in gls[m][1:]:
            v_sh = g.frame()
            same_v = np.array_equal(v_sh, v_gl, equal_nan=True)
            off, ncov = shading_agreement(scene, v_sh, g.image)
            tol = f"{SHADE_RTOL:g} (relative)" if g.shade == "float" else "1/255 of ours clamped"
            shades[m].append((same_v and off < 0.005, f"{g.shade}: V {'the same' if same_v else 'DIFFERENT'}, "
                              f"colour within {tol} on {100 * (1 - off):.3f}% of {ncov} pixels"))  # fmt: skip
    t = {m: [[] for _ in range(2 + len(SHADES))] for m in methods}
    for _ in range(a.repeats):  # interleaved
        for m in methods:
            r = ss.render(scene, m, a.size, a.size, map_size=a.map)
            t[m][0].append(r.timings["total"])
            t[m][1].append(r.timings["total"] - r.timings.get("shading", 0.0))
            for k, g in enumerate(gls[m]):
                t0 = time.perf_counter()
                g.frame()
                t[m][2 + k].append(time.perf_counter() - t0)
    print(
        "| method | ours: full frame, V only (ms) | llvmpipe: V only, shaded 8-bit, shaded float (ms) | "
        "llvmpipe / ours: V only / full, V only / V only, 8-bit / full, float / full | V |"
    )
    print("|---|---|---|---|---|")
    ok = True
    for m in methods:
        col = {shade: 2 + k for k, shade in enumerate(SHADES)}  # t[m]'s column of each GL frame
        mo, mv, mg, m8, mf = (float(np.median(t[m][c])) * 1e3 for c in (0, 1, col[None], col["rgba8"], col["float"]))
        print(
            f"| `{m}` | {mo:.1f}, {mv:.1f} | {mg:.1f}, {m8:.1f}, {mf:.1f} | **{mg / mo:.2f}**, {mg / mv:.2f}, "
            f"{m8 / mo:.2f}, {mf / mo:.2f} | {checks[m][1]} |"
        )
    print(
        f"medians of {a.repeats} interleaved frames; llvmpipe / ours > 1: ours is faster. The issue's GL frame "
        "computes V only (first ratio: against our whole frame, which also shades the image). Like for like: "
        "our frame without its shading phase; and GL frames that also shade (our shading.shade in GLSL), "
        "the colour read back as 8 bits (clamped; less than ours keeps) or as our float32"
    )
    for m in methods:
        print(f"V agreement, {m}: {checks[m][2]}")
        for _good, what in shades[m]:
            print(f"shaded GL frame, {m}, {what}")
        for good, what in ((checks[m][0], "V disagree"), *((s[0], "shaded frames disagree") for s in shades[m])):
            if not good:
                ok = False
                print(f"gl_peer: the two {m} {what} beyond the tolerance", file=sys.stderr)
    for g in (g for gs in gls.values() for g in gs):
        g.release()
    return 0 if ok else 1


if __name__ == "__main__":
    from softshadows import tune_malloc

    tune_malloc()  # a benchmark owns its process: the CLI's allocator setting (softshadows._malloc)
    sys.exit(main())
