"""Rasterizer micro-benchmark: eye G-buffer 512^2 and shadow maps 1024^2 on the bunny.

python benchmarks/bench_raster.py [nthreads] [--frame-views] [--sphere]

``--frame-views``: instead of this script's own views (bunny and ground in every view), the two
that ``hard``'s frame draws on the built-in ``bunny`` scene: the eye G-buffer of ``eye_view`` at
512^2 (every face) and the 1024^2 depth map of the occluders from ``fit_light_view`` (the bunny
alone, its front and back faces); with them, ``penumbra-map``'s receiver depth pass (the faces that
receive but do not occlude, the ground, over its view bordered for the outer penumbra: 1287x1164 on
``bunny`` with the sphere light), a few large triangles over the whole map. ``--sphere``: the
sphere light (default: the rectangle).
"""

import sys
import time
from importlib import resources

import numba
import numpy as np

from softshadows.raster import View, rasterize, rasterize_depth, rasterize_fragments

d = np.load(resources.files("softshadows") / "data" / "bunny.npz")
bv, bf = d["vertices"].astype(float), d["faces"].astype(np.int64)
gv = np.array([[-3, 0, -3], [3, 0, -3], [3, 0, 3], [-3, 0, 3]], float)
gf = np.array([[0, 2, 1], [0, 3, 2]])
V = np.concatenate([bv, gv])
F = np.concatenate([bf, gf + len(bv)])
eye = View.look_at([0.4, 1.3, 2.6], [0, 0.5, 0], [0, 1, 0], 45, 512, 512, near=0.05, far=100)
light = View.look_at([2.0, 5.0, 1.5], [0, 0.3, 0], [0, 1, 0], 70, 1024, 1024, near=0.5, far=100)
lortho = View.frame(
    [2.0, 5.0, 1.5], [-2, -4.7, -1.5], [0, 1, 0], (-3.5, 3.5, -3.5, 3.5), 0.5, 100, 1024, 1024, ortho=True
)


def bench(name, fn, n=30):
    fn()
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        r = fn()
        ts.append(time.perf_counter() - t0)
    ts = np.array(ts) * 1e3
    print(f"{name:40s} median {np.median(ts):7.2f} ms  min {ts.min():7.2f} ms")
    return r


args = [x for x in sys.argv[1:] if not x.startswith("--")]
if args:
    numba.set_num_threads(int(args[0]))
print("threads", numba.get_num_threads())
if "--frame-views" in sys.argv:
    import softshadows as ss
    from softshadows.api import eye_view
    from softshadows.methods import penumbra_map as pm
    from softshadows.methods.shadowmap import fit_light_view

    scene = ss.load_scene("bunny", "sphere" if "--sphere" in sys.argv else "rect")
    flat = scene.flat
    ev = eye_view(scene, 512, 512)
    lv = fit_light_view(scene, 1024)
    occ = flat.faces_where(flat.occluder)
    _hv, pv, _border, _clipped = pm.penumbra_map_view(scene, 1024, pm.light_radius_of(scene.light))
    recv = pm._receiver_only_faces(flat)
    bench("hard's eye G-buffer 512x512", lambda: rasterize(ev, flat.vertices, flat.faces))
    bench("hard's light depth map 1024x1024", lambda: rasterize_depth(lv, flat.vertices, occ))
    bench(f"penumbra-map's receivers {pv.width}x{pv.height}", lambda: rasterize_depth(pv, flat.vertices, recv))
    sys.exit(0)
g = bench("rasterize eye 512x512 (10k+2 tris)", lambda: rasterize(eye, V, F))
print("   covered", g.mask.mean())
bench("rasterize eye 512x512 cull=back", lambda: rasterize(eye, V, F, cull="back"))
bench("rasterize_depth eye 512x512", lambda: rasterize_depth(eye, V, F))
bench("rasterize_depth light persp 1024x1024", lambda: rasterize_depth(light, V, F))
bench("rasterize_depth light ortho 1024x1024", lambda: rasterize_depth(lortho, V, F))
fr = bench("rasterize_fragments light 1024x1024", lambda: rasterize_fragments(light, V, F), n=10)
print("   fragments", len(fr))
