"""PCSS's exact shortcuts (2026-12-02): the occupancy grid and the skipped search regions, taps and
plane depths must leave V bit for bit what the full per-tap work gives."""

import importlib

import numpy as np
import pytest

import softshadows as ss

pcss = importlib.import_module("softshadows.methods.pcss")


def test_occupancy_grid_counts_and_nearest_depth():
    """The summed-area table counts the finite texels of every rectangle of cells, and the second
    value is the map's smallest depth: against numpy's counts on a map with holes and ragged
    edges (sizes that are not multiples of the cell), with negative depths too (the grid compares
    integer keys of the floats' bits, whose order flips below zero)."""
    rng = np.random.default_rng(3)
    H, W = 70, 53
    d = rng.uniform(-2.0, 4.0, (H, W)).astype(np.float32)
    d[rng.random((H, W)) < 0.6] = np.inf
    d[:20, :30] = np.inf  # whole empty cells
    sat, zmin, cmin, cmax = pcss.occupancy_grid(d)
    c = pcss.OCC_CELL
    ny, nx = -(-H // c), -(-W // c)
    assert sat.shape == (ny + 1, nx + 1)
    fin = np.isfinite(d)
    for gy0 in range(ny):
        for gx0 in range(nx):
            for gy1, gx1 in ((gy0 + 1, gx0 + 1), (ny, nx)):
                want = int(fin[gy0 * c : gy1 * c, gx0 * c : gx1 * c].sum())
                got = sat[gy1, gx1] - sat[gy0, gx1] - sat[gy1, gx0] + sat[gy0, gx0]
                assert got == want
    assert zmin == float(d[fin].min())
    for gy in range(ny):
        for gx in range(nx):
            cell = d[gy * c : (gy + 1) * c, gx * c : (gx + 1) * c]
            assert cmin[gy, gx] == cell.min() and cmax[gy, gx] == cell.max()
    assert pcss.occupancy_grid(np.full((8, 8), np.inf, np.float32))[1] == np.inf


def _full_grid(depth):
    """A grid that calls every cell occupied and its depths unknown (-inf .. +inf): no search region
    is skipped and no filter region is decided from the cells."""
    sat, zmin, cmin, cmax = _ORIG(depth)
    ones = np.zeros_like(sat)
    ones[1:, 1:] = 1
    return np.cumsum(np.cumsum(ones, axis=0), axis=1), zmin, np.full_like(cmin, -np.inf), np.full_like(cmax, np.inf)


_ORIG = pcss.occupancy_grid


@pytest.mark.parametrize(("scene", "light"), [("bunny", "rect"), ("plant", "sphere"), ("fence", "rect")])
def test_skipping_empty_regions_changes_no_bit(monkeypatch, scene, light):
    """V with the empty-region skip and the filter regions decided from the grid's cells equals V
    with every region searched and filtered tap by tap (the grid forced to 'all occupied, depths
    unknown'), bit for bit, and so do the blocker counts, averages and search radii: the skip must
    only take points without a blocker. It must also fire (a skipped point keeps its unbiased
    depth as z_receiver), else this test would check nothing."""
    sc = ss.load_scene(scene, light=light)
    runs = []
    orig = pcss.blocker_search

    def capture(*a):
        out = orig(*a)
        runs.append(out)
        return out

    monkeypatch.setattr(pcss, "blocker_search", capture)
    fast = ss.render(sc, "pcss", 96, 72, warmup=False)
    monkeypatch.setattr(pcss, "occupancy_grid", _full_grid)
    slow = ss.render(sc, "pcss", 96, 72, warmup=False)
    assert np.array_equal(fast.visibility, slow.visibility, equal_nan=True)
    (zr_f, avg_f, n_f, s_f), (zr_s, avg_s, n_s, s_s) = runs[-2], runs[-1]
    assert np.array_equal(n_f, n_s) and np.array_equal(avg_f, avg_s) and np.array_equal(s_f, s_s)
    has = n_f > 0
    assert np.array_equal(zr_f[has], zr_s[has])
    assert (zr_f != zr_s).sum() > 0.02 * len(zr_f)  # the skip fired (bunny at 96x72: 8% of the points)


def test_plane_range_bounds_every_tap():
    """``_plane_range`` bounds the comparison depth ``_plane_depth - off`` of every tap in its box,
    including the taps where the plane falls back to the receiver depth (grazing or out of
    [z/2, 2z]), and is never looser than ``_plane_bounds``: random planes and boxes on a
    perspective map (power-of-two size: the multiplied ray; other: the divided one)."""
    from softshadows._jit import py_callable
    from softshadows.raster.view import VP_H, VP_W

    prange_ = py_callable(pcss._plane_range)
    depth_ = py_callable(pcss._plane_depth)
    bounds_ = py_callable(pcss._plane_bounds)
    inv_ = py_callable(pcss._exact_inverse)
    rng = np.random.default_rng(7)
    sc = ss.load_scene("bunny", light="rect")
    view = pcss.fit_light_view(sc, 64)
    tightened = 0
    for size in (64.0, 96.0):
        vp = view.params().copy()
        vp[VP_W] = vp[VP_H] = size
        iw, ih = inv_(vp[VP_W]), inv_(vp[VP_H])
        for _ in range(300):
            n = rng.normal(size=3)
            n /= np.linalg.norm(n)
            nr, nu, nf = n
            z = rng.uniform(0.5, 5.0)
            sx, sy = rng.uniform(-10, size + 10, 2)
            xp, yp = py_callable(pcss._ray_xy)(vp, sx, sy, iw, ih)
            npo = z * (nr * xp + nu * yp + nf)  # the plane through the point at depth z on that ray
            off = rng.uniform(0.0, 0.05) * z
            ex, ey = rng.uniform(0.0, 40.0, 2)
            lo, hi = prange_(vp, nr, nu, nf, npo, sx, sy, ex, ey, z, off, iw, ih)
            lo0, hi0 = bounds_(z, off)
            assert lo0 <= lo <= hi <= hi0
            tightened += lo > lo0 or hi < hi0
            for tx, ty in zip(rng.uniform(sx - ex, sx + ex, 64), rng.uniform(sy - ey, sy + ey, 64), strict=True):
                zc = depth_(vp, nr, nu, nf, npo, tx, ty, z, iw, ih) - off
                assert lo <= zc <= hi
    assert tightened > 100  # the bounds are tighter than [z/2, 2z] for most boxes
