"""PCSS (Fernando 2005): contact hardening, the analytic square, range on every built-in scene."""

import numpy as np
import pytest

import softshadows as ss
from softshadows.errors import SoftShadowsError
from softshadows.methods.pcss import sample_pattern
from softshadows.scene import Camera
from softshadows.scene.builtin import square_visibility

# Top-down camera over the `contact` scene (box x in [-0.5, 0.5], z in [-0.3, 0.3], 0.8 tall; light
# at x = -1.8): image rows run along x, columns along z, so a row crosses the shadow's lateral edge
# on the +z side of the box.
TOP = Camera((0.5, 5.0, 0.0), (0.5, 0.0, 0.0), (1.0, 0.0, 0.0), 30.0)
N = 128


def _lateral_penumbra_width(res, x0: float) -> tuple[float, float]:
    """Extent in z (world units) of the ground pixels with 0.1 < V < 0.9 on the +z side, in the
    pixel row-band at x = x0; also returns the pixel size."""
    pos = res.position
    px = (np.nanmax(pos[..., 0]) - np.nanmin(pos[..., 0])) / N
    m = (np.abs(pos[..., 0] - x0) < 0.5 * px) & (pos[..., 1] < 1e-4) & (pos[..., 2] > 0.0)
    assert m.sum() > 20, "the band must cross the shadow edge"
    z, v = pos[..., 2][m], res.visibility[m]
    pen = (v > 0.1) & (v < 0.9)
    return (float(np.ptp(z[pen])) if pen.any() else 0.0), px


@pytest.mark.parametrize("light", ["rect", "sphere"])
def test_contact_hardening(light):
    """Along the box's side wall, the blocking wall is low near the lit end (x = -0.2: the
    occluding part of the wall is close to the ground) and high far from it (x = 0.9, past the
    box): the penumbra must widen with the blocker-receiver distance, as in ground truth."""
    sc = ss.load_scene("contact", light=light).with_camera(TOP)
    p = ss.render(sc, "pcss", N, N)
    gt = ss.render(sc, "ground-truth", N, N, samples=256)
    near, px = _lateral_penumbra_width(p, -0.2)
    far, _ = _lateral_penumbra_width(p, 0.9)
    g_near, _ = _lateral_penumbra_width(gt, -0.2)
    g_far, _ = _lateral_penumbra_width(gt, 0.9)
    # measured (128 px, pixel 0.021): pcss 0.06-0.08 near vs 0.21-0.23 far; ground truth 0.06-0.08 vs 0.21
    assert far > 2.0 * near, (near, far)
    assert near < 0.12 and far > 0.15, (near, far)
    # and close to ground truth: within 2 pixels + 25% (PCSS's parallel-plane estimate is approximate)
    for w, g in ((near, g_near), (far, g_far)):
        assert abs(w - g) <= 2 * px + 0.25 * g, (w, g)


def test_square_matches_closed_form():
    """Parallel square occluder and square light: the PCF kernel of the light's shape scaled by
    (z_r - z_b) / z_b is the exact soft shadow, so PCSS only has sampling error. With a 16 x 16
    grid the tap quantization is 1/256 per tap step; measured MAE 0.003 on the ground, bound 0.008."""
    sc = ss.load_scene("square")
    r = ss.render(sc, "pcss", 96, 72, pattern="grid", filter_samples=256, search_samples=64)
    pos = r.position
    m = ~np.isnan(r.visibility) & (pos[..., 1] < 1e-4)
    ref = square_visibility(pos[m].astype(float))
    err = np.abs(r.visibility[m] - ref)
    assert ((ref > 0) & (ref < 1)).sum() > 500  # the penumbra is well covered
    assert err.mean() < 0.008, err.mean()
    # default settings (16 Poisson taps): coarser but still close (measured 0.011)
    r16 = ss.render(sc, "pcss", 96, 72)
    assert np.abs(r16.visibility[m] - ref).mean() < 0.025


def test_options_and_determinism():
    sc = ss.load_scene("spheres", light="sphere")
    a = ss.render(sc, "pcss", 64, 48, rotate=True, seed=3)
    b = ss.render(sc, "pcss", 64, 48, rotate=True, seed=3)
    np.testing.assert_array_equal(a.visibility, b.visibility)
    g = ss.render(sc, "pcss", 64, 48, pattern="grid", filter_samples=20, bilinear=False, receiver_plane=False)
    assert g.stats["filter_taps"] == 16  # grid rounds to N x N, N = round(sqrt(20))
    assert 0.0 < g.stats["early_out_fraction"] < 1.0
    with pytest.raises(SoftShadowsError):
        ss.render(sc, "pcss", 16, 16, pattern="hexagon")
    with pytest.raises(SoftShadowsError):
        ss.render(sc, "pcss", 16, 16, filter_samples=0)


def test_patterns_cover_the_light_shape():
    disk = sample_pattern(32, "poisson", True)
    sq = sample_pattern(32, "poisson", False)
    assert disk.shape == (32, 2) and sq.shape == (32, 2)
    assert (np.hypot(disk[:, 0], disk[:, 1]) <= 1.0 + 1e-12).all()
    assert np.abs(sq).max() <= 1.0
    # Poisson disk: no two taps closer than half the spacing of a regular grid of the same count
    d = np.sqrt(((sq[:, None] - sq[None]) ** 2).sum(-1)) + np.eye(32) * 9
    assert d.min() > 0.5 * 2.0 / np.sqrt(32)
    g = sample_pattern(16, "grid", False)
    assert np.allclose(np.sort(np.unique(g[:, 0])), [-0.75, -0.25, 0.25, 0.75])


@pytest.mark.parametrize("light", ["rect", "sphere"])
def test_same_bits_whatever_the_slots(monkeypatch, light):
    """The blocker search and the filter hand out image rows from a shared counter: V and the
    statistics must be the same bits with one slot and with more slots than rows per slot (5 slots
    on a 40-row image), whichever slot claimed a row. Fails if a row is skipped or done twice (a
    counter shared between the two kernels, or not fresh per launch)."""
    from softshadows import _jit
    from softshadows.methods import pcss

    scene = ss.load_scene("bunny", light)

    def render(nslot):
        monkeypatch.setattr(pcss, "run_threads", lambda fn, *a: _jit.run_slots(fn, nslot, *a, nslot))
        return ss.render(scene, "pcss", 48, 40)

    one, five = render(1), render(5)
    assert np.count_nonzero((one.visibility > 0.0) & (one.visibility < 1.0)) > 20  # a penumbra to compare
    assert np.array_equal(one.visibility, five.visibility, equal_nan=True)
    assert one.stats == five.stats


def test_cells_min_max_is_the_min_and_max_over_the_box():
    """``_cells_min_max`` (the smallest and largest value over a box of cells from the square sparse
    tables of ``cell_range_tables``) equals NumPy's min and max over the box, bit for bit, for every
    box of a grid whose sides are not powers of two (wide, tall, square, single cells), with +inf
    cells (empty) among them."""
    from softshadows._jit import py_callable
    from softshadows.methods.pcss import _cells_min_max, cell_range_tables

    mm = py_callable(_cells_min_max)
    rng = np.random.default_rng(3)
    ny, nx = 11, 13
    cmin = rng.uniform(0.0, 5.0, (ny, nx)).astype(np.float32)
    cmin[rng.random((ny, nx)) < 0.2] = np.inf
    cmax = cmin + rng.uniform(0.0, 1.0, (ny, nx)).astype(np.float32)
    tmin, tmax = cell_range_tables(cmin, cmax)
    n = 0
    for gy0 in range(ny):
        for gy1 in range(gy0, ny):
            for gx0 in range(nx):
                for gx1 in range(gx0, nx):
                    lo, hi = mm(tmin, tmax, gy0, gy1, gx0, gx1)
                    box = (slice(gy0, gy1 + 1), slice(gx0, gx1 + 1))
                    assert lo == cmin[box].min() and hi == cmax[box].max()
                    n += 1
    assert n == (ny * (ny + 1) // 2) * (nx * (nx + 1) // 2)


def test_region_decided_against_the_cells_and_the_texels():
    """``_region_decided`` (the filter's lit/dark test from the occupancy grid's cells, with its
    shortcut on the cell under the point) against both definitions it stands for, on random maps
    and boxes: (1) the cells: lit iff every cell under the clamped box has its smallest depth >= hi,
    dark iff the box lies inside the map and every cell under it has its largest depth < lo;
    (2) conservative on the texels: lit implies every texel of the box is >= hi (texels outside
    the map count as lit), dark implies every texel is < lo."""
    from softshadows._jit import py_callable
    from softshadows.methods.pcss import OCC_CELL, _region_decided, cell_range_tables, occupancy_grid

    decided = py_callable(_region_decided)
    rng = np.random.default_rng(11)
    H, W = 70, 90  # not multiples of the cell size
    n_lit = n_dark = 0
    for trial in range(6):
        depth = rng.uniform(1.0, 3.0, (H, W)).astype(np.float32)
        depth[rng.random((H, W)) < 0.3 * trial / 5] = np.inf  # empty texels
        if trial % 2:  # smooth regions: whole cells decided (cells of 16 texels)
            depth[:16] = np.float32(5.0)
            depth[16:, :64] = np.float32(0.5)
        _sat, _z, cmin, cmax = occupancy_grid(depth)
        tmin, tmax = cell_range_tables(cmin, cmax)
        for q in range(400):
            if q % 2:  # anywhere, partly or wholly off the map
                sx, sy = rng.uniform(-20, W + 20), rng.uniform(-20, H + 20)
                ex, ey = rng.uniform(2.0, 30.0), rng.uniform(2.0, 30.0)
            else:  # small boxes in the dark block
                sx, sy = rng.uniform(6.0, 58.0), rng.uniform(22.0, 64.0)
                ex, ey = rng.uniform(2.0, 5.0), rng.uniform(2.0, 5.0)
            lo = rng.uniform(0.0, 2.0)
            hi = lo + rng.uniform(0.0, 4.0)
            lit, dark = decided(tmin, tmax, OCC_CELL, H, W, sx, sy, ex, ey, lo, hi)
            c0, c1 = int(np.floor(sx - ex)), int(np.floor(sx + ex))
            r0, r1 = int(np.floor(sy - ey)), int(np.floor(sy + ey))
            inside = c0 >= 0 and r0 >= 0 and c1 < W and r1 < H
            a0, a1, b0, b1 = max(c0, 0), min(c1, W - 1), max(r0, 0), min(r1, H - 1)
            if a0 > a1 or b0 > b1:
                assert (lit, dark) == (True, False)
                continue
            cells = (slice(b0 // OCC_CELL, b1 // OCC_CELL + 1), slice(a0 // OCC_CELL, a1 // OCC_CELL + 1))
            assert lit == bool((cmin[cells] >= hi).all())
            assert dark == bool(inside and (cmax[cells] < lo).all())
            box = depth[b0 : b1 + 1, a0 : a1 + 1]
            if lit:
                assert (box >= hi).all()
                n_lit += 1
            if dark:
                assert inside and (box < lo).all()
                n_dark += 1
    assert n_lit > 50 and n_dark > 20  # both outcomes were exercised
