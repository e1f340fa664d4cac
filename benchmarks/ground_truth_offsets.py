"""Ground-truth ray origins: crease bias of a fixed scene-size offset vs the float error bound.

Two measurements (docs/results/ground-truth-offsets.md):

1. bunny (role both: it shadows itself), 256 x 192, 256 samples: on a random subset of self-shadowed
   bunny pixels (V < 0.5), V from the method (error-bound origins, and ``offset`` = 1e-4 / 1e-5 x
   scene diagonal added) against a float64 brute-force reference that traces the *same* light
   samples (same strata and jitter) from the exact hit point, against every occluder triangle but
   the pixel's own (float64 Moeller-Trumbore, t > 1e-9), with the own triangle's back side blocking;
   so the differences are the origins' alone, not sampling noise.
2. the V-groove of tests/test_ground_truth.py against its closed form.

    PYTHONPATH=src python benchmarks/ground_truth_offsets.py [--pixels 400]
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

import numpy as np
from numba import prange

import softshadows as ss
from softshadows._jit import kernel

gtm = importlib.import_module("softshadows.methods.ground_truth")


@kernel(parallel=True)
def reference_visibility(pts, nrm, tri, pix, tris, seed, n_side, shape, center, u, v, radius):
    """Float64 brute force over all occluder triangles ``tris`` (T,3,3), the same samples as
    :func:`softshadows.methods.ground_truth.generate_light_rays`."""
    K = pts.shape[0]
    out = np.zeros(K)
    for k in prange(K):
        px, py, pz = pts[k, 0], pts[k, 1], pts[k, 2]
        if shape == 1:
            wx, wy, wz = px - center[0], py - center[1], pz - center[2]
            wl = np.sqrt(wx * wx + wy * wy + wz * wz)
            wx, wy, wz = wx / wl, wy / wl, wz / wl
            ax, ay, az = (1.0, 0.0, 0.0) if abs(wx) < 0.9 else (0.0, 1.0, 0.0)
            e1x, e1y, e1z = ay * wz - az * wy, az * wx - ax * wz, ax * wy - ay * wx
            el = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
            e1x, e1y, e1z = e1x / el, e1y / el, e1z / el
            e2x, e2y, e2z = wy * e1z - wz * e1y, wz * e1x - wx * e1z, wx * e1y - wy * e1x
        c = 0
        for i in range(n_side):
            for j in range(n_side):
                ja, jb = gtm.jitter_pair(gtm.point_key(seed, pix[k]), i * n_side + j)
                a = (i + ja) / n_side
                b = (j + jb) / n_side
                if shape == 1:
                    dx, dy = gtm._concentric(np.float32(a), np.float32(b))  # as the kernel: float32
                    sx = center[0] + radius * (dx * e1x + dy * e2x)
                    sy = center[1] + radius * (dx * e1y + dy * e2y)
                    sz = center[2] + radius * (dx * e1z + dy * e2z)
                else:
                    sx = center[0] + (a - 0.5) * u[0] + (b - 0.5) * v[0]
                    sy = center[1] + (a - 0.5) * u[1] + (b - 0.5) * v[1]
                    sz = center[2] + (a - 0.5) * u[2] + (b - 0.5) * v[2]
                dx_, dy_, dz_ = sx - px, sy - py, sz - pz
                if dx_ * nrm[k, 0] + dy_ * nrm[k, 1] + dz_ * nrm[k, 2] <= 0.0:
                    continue  # leaves through the back of its own triangle
                hit = False
                for t in range(tris.shape[0]):
                    if t == tri[k]:
                        continue
                    e1 = tris[t, 1] - tris[t, 0]
                    e2 = tris[t, 2] - tris[t, 0]
                    hx = dy_ * e2[2] - dz_ * e2[1]
                    hy = dz_ * e2[0] - dx_ * e2[2]
                    hz = dx_ * e2[1] - dy_ * e2[0]
                    det = e1[0] * hx + e1[1] * hy + e1[2] * hz
                    if det == 0.0:
                        continue
                    f = 1.0 / det
                    sx_, sy_, sz_ = px - tris[t, 0, 0], py - tris[t, 0, 1], pz - tris[t, 0, 2]
                    uu = f * (sx_ * hx + sy_ * hy + sz_ * hz)
                    if uu < 0.0 or uu > 1.0:
                        continue
                    qx = sy_ * e1[2] - sz_ * e1[1]
                    qy = sz_ * e1[0] - sx_ * e1[2]
                    qz = sx_ * e1[1] - sy_ * e1[0]
                    vv = f * (dx_ * qx + dy_ * qy + dz_ * qz)
                    if vv < 0.0 or uu + vv > 1.0:
                        continue
                    tt = f * (e2[0] * qx + e2[1] * qy + e2[2] * qz)
                    if tt > 1e-9 and tt < 1.0:
                        hit = True
                        break
                if not hit:
                    c += 1
        out[k] = c / (n_side * n_side)
    return out


def bunny_creases(n_pixels: int, width=256, height=192, samples=256, seed=1, other=None):
    from softshadows.scene import builtin

    scene = builtin.bunny(object_role="both")
    flat = scene.flat
    res = {}
    for off in (0.0, 1e-5, 1e-4):
        res[off] = ss.render(scene, "ground-truth", width, height, samples=samples, seed=seed, offset=off)
    from softshadows.api import eye_view
    from softshadows.raster import rasterize

    gb = rasterize(eye_view(scene, width, height), flat.vertices, flat.faces, cull="none")
    v0 = res[0.0].visibility.reshape(-1)
    tri_all = gb.tri_id.reshape(-1)
    on_bunny = (tri_all >= 0) & flat.occluder[np.maximum(tri_all, 0)] & np.isfinite(v0)
    cand = np.flatnonzero(on_bunny & (v0 < 0.5))
    rng = np.random.default_rng(0)
    sel = np.sort(rng.choice(cand, min(n_pixels, len(cand)), replace=False))
    from softshadows.raster.gbuffer import gather_points

    _pts, nrm_all, idx_all = gather_points(gb.position, gb.normal, gb.mask, np.asarray(scene.camera.eye, float))
    pos_in = np.searchsorted(idx_all, sel)
    p, n, *_ = gtm.hit_points(flat, gb, sel, nrm_all[pos_in])
    tris = flat.vertices[flat.faces[flat.occluder]].astype(np.float32).astype(np.float64)
    # own-triangle index within the occluder list
    occ_index = np.cumsum(flat.occluder) - 1
    own = occ_index[tri_all[sel]]
    shape, center, u, v, radius = gtm.light_arrays(scene.light)
    n_side = int(round(np.sqrt(samples)))
    ref = reference_visibility(p, n, own, sel, tris, seed, n_side, shape, center, u, v, radius)
    print(f"bunny (role both) {width}x{height}, {samples} samples: {len(sel)} self-shadowed pixels (V < 0.5)")
    print(f"  float64 reference mean V: {ref.mean():.4f}")
    for off, r in res.items():
        vv = r.visibility.reshape(-1)[sel]
        name = "error bound" if off == 0 else f"bound + {off:g} x diagonal"
        d = vv - ref
        print(
            f"  {name:>26}: mean V {vv.mean():.4f}  bias {d.mean():+.4f} ({d.mean() / ref.mean() * 100:+.1f}% of the"
            f" mean)  MAE {np.abs(d).mean():.4f}  pixels differing {int((d != 0).sum())}"
        )
    if other is not None:  # V image of the same render by other code (e.g. the previous version)
        vo = np.load(other).reshape(-1)
        d = vo[sel] - ref
        print(
            f"  {other}: mean V {vo[sel].mean():.4f}  bias {d.mean():+.4f} ({d.mean() / ref.mean() * 100:+.1f}%)"
            f"  MAE {np.abs(d).mean():.4f}; all bunny pixels mean V {vo[on_bunny].mean():.4f}"
        )
    vb = {off: r.visibility.reshape(-1)[on_bunny] for off, r in res.items()}
    print(
        f"  all {int(on_bunny.sum())} bunny pixels, mean V: "
        + "  ".join(f"offset {k:g}: {x.mean():.4f}" for k, x in vb.items())
    )
    return ref, {k: r.visibility.reshape(-1)[sel] for k, r in res.items()}


def groove():
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    import test_ground_truth as t

    print("V-groove (tests/test_ground_truth.py), 96x72, 256 samples, face A's penumbra vs the closed form:")
    for off in (0.0, 1e-5, 1e-4):
        bias, mae = t._groove_bias(offset=off)
        name = "error bound" if off == 0 else f"bound + {off:g} x diagonal"
        print(f"  {name:>26}: bias {bias:+.5f}  MAE {mae:.5f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pixels", type=int, default=400)
    ap.add_argument("--other", help="a .npy V image (256x192, bunny role both, 256 samples, seed 1) to compare too")
    a = ap.parse_args()
    groove()
    bunny_creases(a.pixels, other=a.other)


if __name__ == "__main__":
    main()
