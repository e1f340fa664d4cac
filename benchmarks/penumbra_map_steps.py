"""Where a `penumbra-map` frame goes: its steps timed one by one on one frame's data, next to `hard`'s
whole frame, interleaved in one process after warm-up. CPU time with one Numba thread by default
(the measure a loaded machine disturbs least); ``--wall`` for wall time with the default threads.

    PYTHONPATH=src python benchmarks/penumbra_map_steps.py --light rect --reps 21
    OMP_WAIT_POLICY=PASSIVE PYTHONPATH=src python benchmarks/penumbra_map_steps.py --light sphere --wall

Prints per step the median (min) in ms. The steps are the module's own functions
(``softshadows.methods.penumbra_map``) and the rasterizer's front end, called as a frame calls them;
the sum of the steps is close to, not equal to, the frame (Python glue, stats, scatter).
"""

from __future__ import annotations

import argparse
import os
import time


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="bunny")
    ap.add_argument("--light", default="rect", choices=("rect", "sphere"))
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--reps", type=int, default=21)
    ap.add_argument("--wall", action="store_true", help="wall time, default threads (else CPU time, 1 thread)")
    a = ap.parse_args()
    if not a.wall:
        os.environ["NUMBA_NUM_THREADS"] = "1"
    import numpy as np

    import softshadows as ss
    from softshadows import api
    from softshadows.methods import get_method
    from softshadows.methods import penumbra_map as P
    from softshadows.raster import View, rasterize_depth
    from softshadows.raster import rasterizer as R

    ss.tune_malloc()  # a benchmark owns its process (as the CLI)
    clock = time.perf_counter if a.wall else time.process_time
    scene = ss.load_scene(a.scene, light=a.light).normalized()[0]
    hard, pm = get_method("hard"), get_method("penumbra-map")
    ph, pp = hard.resolve_params({}), pm.resolve_params({})
    captured = {}
    run = pm.run

    def capture(ctx, **kw):  # the frame's eye G-buffer
        captured["eye"] = ctx.eye
        return run(ctx, **kw)

    pm.run = capture
    for _ in range(2):
        api._render(scene, hard, a.size, a.size, ph, 0, False)
        api._render(scene, pm, a.size, a.size, pp, 0, False)
    pm.run = run
    eye = captured["eye"]
    flat = scene.flat
    lr = P.light_radius_of(scene.light)
    ms, bias, slope = pp["map_size"], pp["bias"], pp["slope_bias"]
    occ = flat.faces_where(flat.occluder)
    recv = P._receiver_only_faces(flat)
    faces = flat.faces if flat.occluder.all() else occ
    times: dict[str, list] = {}

    def timed(name, fn, *args, **kw):
        t0 = clock()
        out = fn(*args, **kw)
        times.setdefault(name, []).append(clock() - t0)
        return out

    for r in range(a.reps + 1):
        timed("hard: whole frame", api._render, scene, hard, a.size, a.size, ph, 0, False)
        timed("penumbra-map: whole frame", api._render, scene, pm, a.size, a.size, pp, 0, False)
        smp = timed("shadow_map_pass (all of the below)", P.shadow_map_pass, scene, ms, lr)
        timed("  occluder map (= hard's)", rasterize_depth, smp.hard_view, flat.vertices, occ, cull="none")
        zr, _ = timed("  receivers' Z_P raster", rasterize_depth, smp.view, flat.vertices, recv, cull="none")
        pl, _, pt, _ = smp.border
        timed("  Z_P min + pyramid (one pass)", P.build_zmax_pyramid, zr, smp.occluder_depth, (pt, pl))
        look = timed(
            "eye_lookups_image", P.eye_lookups_image, smp, eye.position, eye.normal, eye.mask, bias, slope, mark=True
        )
        view, pyr = smp.view, smp.zmax_pyramid
        sil, _ = timed("silhouettes", P.find_silhouettes, scene, view.origin, pp["silhouettes"])
        z_far = P.pyramid_max(pyr) * (1.0 + 1e-6)
        cones = timed(
            "build_cones", P.build_cones, view, flat.vertices[sil.vertices], lr, z_far, pp["cone_segments"], pyr
        )
        sheets = timed(
            "build_sheets",
            P.build_sheets,
            view,
            flat.vertices,
            faces,
            sil,
            lr,
            z_far,
            pp["sheet_tolerance"],
            pp["sheet_max_subdiv"],
            pyr,
        )
        nv = len(cones.vertices)
        prims = P.Primitives(
            np.concatenate([cones.vertices, sheets.vertices]),
            np.concatenate([cones.triangles, sheets.triangles + nv]),
            np.concatenate([cones.zv, sheets.zv]),
        )
        rview = View(
            view.origin, view.right, view.up, view.forward, view.window, view.near,
            max(z_far * (1.0 + 1e-4), view.near * 2), view.width, view.height, False,
        )  # fmt: skip
        out = np.ones((view.height, view.width), np.float32)
        timed(
            "min-blend (front end + tiles)",
            P.penumbra_fragment_program,
            rview,
            prims,
            len(cones.triangles),
            smp.surface_depth,
            bias,
            True,
            out,
            needed=look.needed,
        )
        timed("  its front end", R._front_end, *R._prepare(rview, prims.vertices, prims.triangles, "none"), look.needed)
        pmap = P.PenumbraMap(view, out, sil, z_far)
        timed("eye_gather", P.eye_gather, pmap, look)
        if r == 0:  # the first round warms the steps called here only
            times = {}
    unit = "wall ms, default threads" if a.wall else "CPU ms, 1 thread"
    print(f"{a.scene} {a.light} {a.size}^2, {a.reps} rounds, {unit}: median (min)")
    print(f"  cone triangles {len(cones.triangles)}, sheet triangles {len(sheets.triangles)}, texels read "
          f"{int(np.count_nonzero(look.needed))}, map {view.width}x{view.height}")  # fmt: skip
    for k, v in times.items():
        print(f"  {k:38s} {1e3 * np.median(v):7.2f} ({1e3 * min(v):.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
