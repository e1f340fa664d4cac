"""Penumbra maps' inherent error on a straight edge, against the closed form.

A half-plane-like occluder (x < 0, a 3 x 6 quad at height 1, role occluder) over a receiver
ground, lit by a sphere light of radius 0.4 at height 3 (the paper's light model, so no rect
approximation is involved). The true V across the edge is 1 - circular segment / disk area
(``softshadows.analytic.disk_halfplane_visibility``). ``penumbra-map`` keeps ``hard``'s shadow as
the umbra and only darkens outside it (the outer penumbra), so:

* inner penumbra (the light's center hidden, 0 < V < 1/2): penumbra-map = hard = 0;
* outer penumbra (1/2 < V < 1): penumbra-map rises from 0 at the hard edge, where the truth is
  1/2, to 1; hard is 1 there.

Prints the mean |V - V_true| of both methods over the true penumbra and its two halves, and plots
the three profiles across the edge (docs/img/penumbra_map_edge.png).

    PYTHONPATH=src python benchmarks/penumbra_map_edge.py [--out docs/img/penumbra_map_edge.png]
"""

from __future__ import annotations

import argparse

import numpy as np

import softshadows as ss
from softshadows.analytic import disk_halfplane_visibility

LIGHT_Y, RADIUS, OCC_Y = 3.0, 0.4, 1.0
SIZE = (192, 144)


def straight_edge_scene() -> ss.Scene:
    ground = ss.Mesh([[-4, 0, -4], [4, 0, -4], [4, 0, 4], [-4, 0, 4]], [[0, 2, 1], [0, 3, 2]], role="receiver")
    occ = ss.Mesh(
        [[-3, OCC_Y, -3], [0, OCC_Y, -3], [0, OCC_Y, 3], [-3, OCC_Y, 3]], [[0, 2, 1], [0, 3, 2]], role="occluder"
    )
    light = ss.SphereLight([0, LIGHT_Y, 0], RADIUS)
    # looking down at the edge's shadow on the ground (x in about [-0.6, 0.6]) from above the lit side
    cam = ss.Camera([0.9, 2.5, 0.0], [0.0, 0.0, 0.0], up=(0, 0, -1), fov_y=30)
    return ss.Scene([ground, occ], light, cam, name="straight-edge")


def true_visibility(points) -> np.ndarray:
    """Closed form on the ground (the occluder's edge is the line x = 0, z free, at y = OCC_Y)."""
    return disk_halfplane_visibility(points, [0, LIGHT_Y, 0], RADIUS, [0, OCC_Y, 0], [0, 0, 1], [-1, OCC_Y, 0])


def edge_profiles(width: int = SIZE[0], height: int = SIZE[1], **pm_params):
    """Per ground pixel under the edge's penumbra region (|z| < 1): x, V_true, V_hard, V_pm."""
    sc = straight_edge_scene()
    hard = ss.render(sc, "hard", width, height)
    pm = ss.render(sc, "penumbra-map", width, height, **pm_params)
    pos = hard.position.reshape(-1, 3)
    sel = np.isfinite(hard.visibility.ravel()) & (np.abs(pos[:, 1]) < 1e-5) & (np.abs(pos[:, 2]) < 1.0)
    return (
        pos[sel, 0],
        true_visibility(pos[sel]),
        hard.visibility.ravel()[sel].astype(float),
        pm.visibility.ravel()[sel].astype(float),
    )


def errors(v_true, v_hard, v_pm) -> dict:
    """Mean |V - V_true| over the true penumbra and its inner (V < 1/2) and outer halves."""
    pen = (v_true > 1e-3) & (v_true < 1 - 1e-3)
    inner = pen & (v_true < 0.5)
    outer = pen & (v_true >= 0.5)
    out = {"n_penumbra": int(pen.sum()), "n_inner": int(inner.sum()), "n_outer": int(outer.sum())}
    for name, v in (("hard", v_hard), ("penumbra-map", v_pm)):
        for reg, m in (("penumbra", pen), ("inner", inner), ("outer", outer)):
            out[f"{name}:{reg}"] = float(np.abs(v[m] - v_true[m]).mean())
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/img/penumbra_map_edge.png")
    a = ap.parse_args()
    x, vt, vh, vp = edge_profiles()
    e = errors(vt, vh, vp)
    print(f"straight edge, sphere light r={RADIUS}, {SIZE[0]}x{SIZE[1]}: {e['n_penumbra']} penumbra pixels")
    print(f"{'mean |V - V_true|':<20}{'penumbra':>10}{'inner':>10}{'outer':>10}")
    for name in ("hard", "penumbra-map"):
        print(f"{name:<20}{e[name + ':penumbra']:10.4f}{e[name + ':inner']:10.4f}{e[name + ':outer']:10.4f}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    order = np.argsort(x)
    xs = np.linspace(x.min(), x.max(), 1000)
    fig, ax = plt.subplots(figsize=(7, 3.6), dpi=110)
    ax.plot(
        xs, true_visibility(np.c_[xs, np.zeros_like(xs), np.zeros_like(xs)]), "k-", lw=2, label="true V (closed form)"
    )
    ax.plot(x[order], vh[order], ".", ms=3, color="tab:blue", label="hard")
    ax.plot(x[order], vp[order], ".", ms=3, color="tab:red", label="penumbra-map")
    ax.axvline(0.0, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("x on the ground (the edge's hard shadow boundary at x = 0)")
    ax.set_ylabel("V")
    ax.set_title(
        f"straight edge: mean |V - V_true| over the penumbra: hard {e['hard:penumbra']:.3f}, "
        f"penumbra-map {e['penumbra-map:penumbra']:.3f}",
        fontsize=9,
    )
    ax.legend(fontsize=8, loc="upper left")
    ax.set_xlim(-0.6, 0.6)
    fig.tight_layout()
    fig.savefig(a.out)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
